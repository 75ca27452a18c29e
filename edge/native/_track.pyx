# cython: language_level=3
"""Compiled core of the lane tracker's association and update (issue 30), for all tracks at once.

The numpy references are in :mod:`edge.track.pdaf` (``innovations_each``, ``mahalanobis_d2``,
``pair_innovations`` + ``combined_update_pairs``); the roles call these kernels through
:mod:`edge.track.kernels` when they are built.

- :func:`innovations_each` and :func:`quad_d2` do the same float64 operations in the same order as the numpy
  reference (the cofactor inverse of :func:`edge.track.smallmat.inv_det`, the quadratic form summed term after
  term in the order i <= j): bit-identical on x86-64 (built without contraction into fused multiply-adds).
- :func:`pair_update` (the per-hypothesis PDAF update over the validated pairs) replaces small matrix products
  that numpy hands to BLAS; it equals the reference to rounding (relative 1e-12 on states and covariances).
"""

import numpy as np
cimport numpy as cnp

cnp.import_array()


cdef inline double _inv3(const double* a, double* out) noexcept nogil:
    """out = inv(a) (3x3 row-major) by cofactors in the order of smallmat.inv_det; returns det(a)."""
    cdef double adj[9]
    cdef int i, j
    cdef double det
    for i in range(3):
        for j in range(3):
            adj[3 * i + j] = (a[3 * ((j + 1) % 3) + (i + 1) % 3] * a[3 * ((j + 2) % 3) + (i + 2) % 3]
                              - a[3 * ((j + 1) % 3) + (i + 2) % 3] * a[3 * ((j + 2) % 3) + (i + 1) % 3])
    det = a[0] * adj[0] + a[1] * adj[3] + a[2] * adj[6]
    for i in range(9):
        out[i] = adj[i] / det
    return det


cdef inline double _inv2(const double* a, double* out) noexcept nogil:
    cdef double det = a[0] * a[3] - a[1] * a[2]
    out[0] = a[3] / det
    out[1] = (-a[1]) / det
    out[2] = (-a[2]) / det
    out[3] = a[0] / det
    return det


cdef inline double _quad3(const double* si, const double* v) noexcept nogil:
    """v' S^-1 v as pdaf._quad_each: terms (S^-1_ij * (1|2)) * v_i * v_j for i <= j, summed in that order."""
    cdef double acc = si[0] * v[0] * v[0]
    acc = acc + si[1] * 2.0 * v[0] * v[1]
    acc = acc + si[2] * 2.0 * v[0] * v[2]
    acc = acc + si[4] * v[1] * v[1]
    acc = acc + si[5] * 2.0 * v[1] * v[2]
    acc = acc + si[8] * v[2] * v[2]
    return acc


cdef inline double _quad2(const double* si, const double* v) noexcept nogil:
    cdef double acc = si[0] * v[0] * v[0]
    acc = acc + si[1] * 2.0 * v[0] * v[1]
    acc = acc + si[3] * v[1] * v[1]
    return acc


def innovations_each(const double[:, ::1] z, const double[:, ::1] zh, const double[:, :, ::1] st,
                     const double[:, :, ::1] rm, double lim, bint prune):
    """``v`` (T, M, n), ``d2`` (T, M), ``s``, ``s_inv`` (T, M, n, n), ``det_s`` (T, M) of
    :func:`edge.track.pdaf.innovations_each` from ``z`` (M, n), ``z_hat`` (T, n), the track part ``st`` (T, n, n)
    (``H P H' + R_t``, symmetrised) and ``rm`` (M, n, n). ``prune``: the exact pre-gate with threshold ``lim``
    (``gamma (1 + margin)``): a pair with ``v_i^2 > lim (st_ii + rm_ii)`` in a component gets ``d2 = inf``,
    ``S = S^-1 = 0``, ``|S| = 1``. n = 2 or 3."""
    cdef Py_ssize_t nt = zh.shape[0], nm = z.shape[0], n = z.shape[1]
    cdef Py_ssize_t t, m, i, nn = n * n
    v_a = np.empty((nt, nm, n))
    d2_a = np.empty((nt, nm))
    s_a = np.zeros((nt, nm, n, n))
    si_a = np.zeros((nt, nm, n, n))
    det_a = np.ones((nt, nm))
    cdef double[:, :, ::1] v = v_a
    cdef double[:, ::1] d2 = d2_a
    cdef double[:, :, :, ::1] s = s_a
    cdef double[:, :, :, ::1] si = si_a
    cdef double[:, ::1] det = det_a
    cdef double* sp
    cdef double* vp
    cdef bint far
    cdef double inf = float("inf")
    with nogil:
        for t in range(nt):
            for m in range(nm):
                vp = &v[t, m, 0]
                for i in range(n):
                    vp[i] = z[m, i] - zh[t, i]
                if prune:
                    far = False
                    for i in range(n):
                        if vp[i] * vp[i] > lim * (st[t, i, i] + rm[m, i, i]):
                            far = True
                    if far:
                        d2[t, m] = inf
                        continue
                sp = &s[t, m, 0, 0]
                for i in range(nn):
                    sp[i] = st[t, i // n, i % n] + rm[m, i // n, i % n]
                if n == 3:
                    det[t, m] = _inv3(sp, &si[t, m, 0, 0])
                    d2[t, m] = _quad3(&si[t, m, 0, 0], vp)
                else:
                    det[t, m] = _inv2(sp, &si[t, m, 0, 0])
                    d2[t, m] = _quad2(&si[t, m, 0, 0], vp)
    return v_a, d2_a, s_a, si_a, det_a


def quad_d2(const double[:, :, ::1] v, const double[:, :, ::1] s_inv):
    """(T, M) ``v' S_t^-1 v`` of innovations ``v`` (T, M, n) with one symmetric ``S_t^-1`` (T, n, n) per track:
    :func:`edge.track.pdaf._quad`, term for term. n = 2 or 3."""
    cdef Py_ssize_t nt = v.shape[0], nm = v.shape[1], n = v.shape[2], t, m
    out_a = np.empty((nt, nm))
    cdef double[:, ::1] out = out_a
    with nogil:
        for t in range(nt):
            for m in range(nm):
                if n == 3:
                    out[t, m] = _quad3(&s_inv[t, 0, 0], &v[t, m, 0])
                else:
                    out[t, m] = _quad2(&s_inv[t, 0, 0], &v[t, m, 0])
    return out_a


from libc.math cimport hypot, fabs


def same_speed_pairs(const double[:, ::1] x, double merge_speed_mps):
    """The first test of :meth:`edge.track.roles.delete.TrackDeleter.duplicates` over all track pairs ``a < b``
    (row-major, the order of ``np.triu_indices``): the pairs whose velocities agree within ``merge_speed_mps``
    along their common heading, with the same arithmetic. Returns ``ia``, ``ib`` (K,) int64, ``dx`` (K, 4) the
    state differences and ``ux``, ``uy`` (K,) the common heading."""
    cdef Py_ssize_t nt = x.shape[0], a, b, k = 0, cap = 16, i
    ia_a = np.empty(cap, dtype=np.int64)
    ib_a = np.empty(cap, dtype=np.int64)
    dx_a = np.empty((cap, 4))
    u_a = np.empty((cap, 2))
    cdef long long[::1] ia = ia_a
    cdef long long[::1] ib = ib_a
    cdef double[:, ::1] dx = dx_a
    cdef double[:, ::1] u = u_a
    cdef double s0, s1, h, nrm, ux, uy
    for a in range(nt):
        for b in range(a + 1, nt):
            s0 = x[a, 2] + x[b, 2]
            s1 = x[a, 3] + x[b, 3]
            h = hypot(s0, s1)
            nrm = h if (h >= 1e-9 or h != h) else 1e-9  # np.maximum (NaN propagates)
            ux = s0 / nrm
            uy = s1 / nrm
            if not (fabs((x[a, 2] - x[b, 2]) * ux + (x[a, 3] - x[b, 3]) * uy) < merge_speed_mps):
                continue
            if k == cap:
                cap *= 2
                ia_a = np.resize(ia_a, cap)
                ib_a = np.resize(ib_a, cap)
                dx_a = np.resize(dx_a, (cap, 4))
                u_a = np.resize(u_a, (cap, 2))
                ia, ib, dx, u = ia_a, ib_a, dx_a, u_a
            ia[k] = a
            ib[k] = b
            for i in range(4):
                dx[k, i] = x[a, i] - x[b, i]
            u[k, 0] = ux
            u[k, 1] = uy
            k += 1
    return ia_a[:k], ib_a[:k], dx_a[:k], u_a[:k, 0], u_a[:k, 1]
