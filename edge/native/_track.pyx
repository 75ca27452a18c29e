# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Compiled core of the lane tracker's association and update (issue 30), for all tracks at once.

The numpy references are in :mod:`edge.track.pdaf` (``innovations_each``, ``mahalanobis_d2``,
``pair_innovations`` + ``combined_update_pairs``); the roles call these kernels through
:mod:`edge.track.kernels` when they are built.

- :func:`innovations_each` and :func:`quad_d2` do the same float64 operations in the same order as the numpy
  reference (``H P H'`` in the order of :func:`edge.track.pdaf.hph_product`, the cofactor inverse of
  :func:`edge.track.smallmat.inv_det`, the quadratic form summed term after term in the order i <= j): bit-identical
  on x86-64 (built without contraction into fused multiply-adds).
- :func:`pair_update` (the per-hypothesis PDAF update over the validated pairs) replaces small matrix products
  that numpy hands to BLAS; it equals the reference to rounding (relative 1e-12 on states and covariances).
"""

import numpy as np
cimport numpy as cnp
from cpython.mem cimport PyMem_Malloc, PyMem_Free
from libc.string cimport memcpy
from libc.math cimport M_PI, pow, cos, sin

cnp.import_array()

include "_views.pxi"
include "_alloc.pxi"


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


cdef inline void _hph(_V V_h, _V V_p, Py_ssize_t t, Py_ssize_t n, double* out) noexcept nogil:
    """``out`` (n, n) row-major = ``H_t P_t H_t'`` of ``h`` (T, n, 4), ``p`` (T, 4, 4) in the order of
    :func:`edge.track.pdaf.hph_product`: ``HP`` summed over k = 0..3 left to right, then ``(HP) H'`` the same."""
    cdef double hp[3][4]
    cdef Py_ssize_t i, j
    for i in range(n):
        for j in range(4):
            hp[i][j] = (((_pd3(V_h, t, i, 0)[0] * _pd3(V_p, t, 0, j)[0]
                          + _pd3(V_h, t, i, 1)[0] * _pd3(V_p, t, 1, j)[0])
                         + _pd3(V_h, t, i, 2)[0] * _pd3(V_p, t, 2, j)[0])
                        + _pd3(V_h, t, i, 3)[0] * _pd3(V_p, t, 3, j)[0])
    for i in range(n):
        for j in range(n):
            out[i * n + j] = (((hp[i][0] * _pd3(V_h, t, j, 0)[0] + hp[i][1] * _pd3(V_h, t, j, 1)[0])
                               + hp[i][2] * _pd3(V_h, t, j, 2)[0]) + hp[i][3] * _pd3(V_h, t, j, 3)[0])


cdef cnp.ndarray _view(object flat, Py_ssize_t t, Py_ssize_t m, Py_ssize_t n, int nd):
    """A C-contiguous float64 view (t, m, n) (``nd`` 3) or (t, m, n, n) (``nd`` 4) of the start of ``flat``, a
    writeable C-contiguous float64 vector at least that long; or a new array when ``flat`` is None."""
    cdef cnp.npy_intp dims[4]
    cdef cnp.ndarray base, out
    dims[0], dims[1], dims[2], dims[3] = t, m, n, n
    if flat is None:
        return cnp.PyArray_EMPTY(nd, dims, cnp.NPY_FLOAT64, 0)
    if not (_column(flat, cnp.NPY_FLOAT64, -1) and cnp.PyArray_ISCARRAY(<cnp.ndarray> flat)
            and cnp.PyArray_DIMS(<cnp.ndarray> flat)[0] >= t * m * n * (n if nd == 4 else 1)):
        raise ValueError(f"output buffer must be a writeable C-contiguous float64 vector of at least "
                         f"{t * m * n * (n if nd == 4 else 1)} values")
    base = <cnp.ndarray> flat
    out = cnp.PyArray_SimpleNewFromData(nd, dims, cnp.NPY_FLOAT64, cnp.PyArray_DATA(base))
    cnp.set_array_base(out, base)
    return out


def innovations_each(z, zh, h, p,
                     r_track, rm, double lim, bint prune,
                     buffers=None):
    """``v`` (T, M, n), ``d2`` (T, M), ``s``, ``s_inv`` (T, M, n, n), ``det_s`` (T, M) and the track part ``st``
    (T, n, n) of :func:`edge.track.pdaf.innovations_each` from ``z`` (M, n), ``z_hat`` (T, n), ``h`` (T, n, 4),
    ``p`` (T, 4, 4), the track's part of ``R`` ``r_track`` (T, n, n) and ``rm`` (M, n, n): ``st = 0.5 (a + a')`` with
    ``a = H P H' + r_track`` (``H P H'`` as :func:`edge.track.pdaf.hph_product`), as numpy. ``prune``: the exact
    pre-gate with threshold ``lim`` (``gamma (1 + margin)``): a pair with ``v_i^2 > lim (st_ii + rm_ii)`` in a
    component gets ``d2 = inf``, ``S = S^-1 = 0``, ``|S| = 1``. n = 2 or 3. ``buffers``: three writeable
    C-contiguous float64 vectors whose starts become ``v``, ``s`` and ``s_inv`` (every entry is written;
    :class:`edge.track.pdaf.PairBuffers`), or None: new arrays."""
    cdef _V V_z
    _aview(z, cnp.NPY_FLOAT64, 2, False, False, &V_z, "z")
    cdef _V V_zh
    _aview(zh, cnp.NPY_FLOAT64, 2, False, False, &V_zh, "zh")
    cdef _V V_h
    _aview(h, cnp.NPY_FLOAT64, 3, False, False, &V_h, "h")
    cdef _V V_p
    _aview(p, cnp.NPY_FLOAT64, 3, False, False, &V_p, "p")
    cdef _V V_r_track
    _aview(r_track, cnp.NPY_FLOAT64, 3, False, False, &V_r_track, "r_track")
    cdef _V V_rm
    _aview(rm, cnp.NPY_FLOAT64, 3, False, True, &V_rm, "rm")
    cdef Py_ssize_t nt = V_zh.n[0], nm = V_z.n[0], n = V_z.n[1]
    cdef Py_ssize_t t, m, i, j, nn = n * n, tm
    if not 2 <= n <= 3 or V_zh.n[1] != n or V_h.n[0] != nt or V_p.n[0] != nt or V_r_track.n[0] != nt \
            or V_rm.n[0] != nm or V_h.n[1] != n or V_h.n[2] != 4 or V_p.n[1] != 4 or V_p.n[2] != 4 \
            or V_r_track.n[1] != n or V_r_track.n[2] != n or V_rm.n[1] != n or V_rm.n[2] != n:
        raise ValueError("innovations_each: inconsistent shapes")
    if buffers is not None and len(buffers) != 3:
        raise ValueError("output buffer: three vectors (v, s, s_inv)")
    cdef cnp.ndarray v_a = _view(None if buffers is None else buffers[0], nt, nm, n, 3)
    cdef cnp.ndarray s_a = _view(None if buffers is None else buffers[1], nt, nm, n, 4)
    cdef cnp.ndarray si_a = _view(None if buffers is None else buffers[2], nt, nm, n, 4)
    cdef cnp.ndarray st_a = _empty3(cnp.NPY_FLOAT64, nt, n, n)
    cdef cnp.ndarray d2_a = _empty2(cnp.NPY_FLOAT64, nt, nm)
    cdef cnp.ndarray det_a = _empty2(cnp.NPY_FLOAT64, nt, nm)
    cdef double* st = _f64(st_a)
    cdef double* v = _f64(v_a)
    cdef double* d2 = _f64(d2_a)
    cdef double* s_ = _f64(s_a)
    cdef double* si = _f64(si_a)
    cdef double* det = _f64(det_a)
    cdef double* sp
    cdef double* sip
    cdef const double* stp
    cdef const double* rmp
    cdef double* vp
    cdef bint far
    cdef double inf = float("inf")
    cdef double hph[9]
    with nogil:
        for t in range(nt):
            _hph(V_h, V_p, t, n, hph)
            for i in range(n):
                for j in range(n):
                    st[(t * n + i) * n + j] = 0.5 * ((hph[i * n + j] + _pd3(V_r_track, t, i, j)[0])
                                                     + (hph[j * n + i] + _pd3(V_r_track, t, j, i)[0]))
        for t in range(nt):
            stp = &st[t * nn]
            for m in range(nm):
                tm = t * nm + m
                vp = &v[tm * n]
                sp = &s_[tm * nn]
                sip = &si[tm * nn]
                for i in range(n):
                    vp[i] = _pd2(V_z, m, i)[0] - _pd2(V_zh, t, i)[0]
                if prune:
                    far = False
                    for i in range(n):
                        if vp[i] * vp[i] > lim * (stp[i * n + i] + _pd3(V_rm, m, i, i)[0]):
                            far = True
                    if far:
                        d2[tm] = inf
                        det[tm] = 1.0
                        for i in range(nn):
                            sp[i] = 0.0
                            sip[i] = 0.0
                        continue
                rmp = &_pd3(V_rm, m, 0, 0)[0]
                for i in range(nn):
                    sp[i] = stp[i] + rmp[i]
                if n == 3:
                    det[tm] = _inv3(sp, sip)
                    d2[tm] = _quad3(sip, vp)
                else:
                    det[tm] = _inv2(sp, sip)
                    d2[tm] = _quad2(sip, vp)
    return v_a, d2_a, s_a, si_a, det_a, st_a


def quad_d2(const double[:, :, ::1] v, const double[:, :, ::1] s_inv):
    """(T, M) ``v' S_t^-1 v`` of innovations ``v`` (T, M, n) with one symmetric ``S_t^-1`` (T, n, n) per track:
    :func:`edge.track.pdaf._quad`, term for term. n = 2 or 3."""
    cdef Py_ssize_t nt = v.shape[0], nm = v.shape[1], n = v.shape[2], t, m
    out_a = _empty2(cnp.NPY_FLOAT64, nt, nm)
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


cdef inline double _max_nan(double a, double b) noexcept nogil:
    """np.maximum: the larger, NaN if either is NaN."""
    if a != a or b != b:
        return a + b
    return a if a >= b else b


def duplicate_pairs(x, double merge_speed_mps, double merge_lateral_m,
                    reach_m, double merge_lateral_speed_mps, pdx,
                    pdy, double state_gamma, pair,
                    det, bint resolved, close_run, long persist_frames):
    """The pair tests of :meth:`edge.track.roles.delete.TrackDeleter.duplicates` over all track pairs ``a < b``
    (row-major), with its arithmetic: velocities alike along the common heading (and not the two members of a
    resolved pair: ``pair``, ``det`` per track when ``resolved``); then a pair is *boxed* (within
    ``merge_lateral_m`` across and ``max(reach_a, reach_b)`` along) or, with lateral speeds alike, a candidate for the
    state test when its marginal distances pass (``dx^2 < gamma (pdx_a + pdx_b)``, the same in y).

    Returns the tracks' new ``close_run`` (T,) int32 (one more for a track in a boxed pair, else 0), the boxed pairs
    that are duplicates ``ka``, ``kb`` (K,) int64 (lateral speeds alike, or both tracks boxed for
    ``persist_frames``), and the state-test candidates ``ra``, ``rb`` (R,) with their state differences ``rdx``
    (R, 4)."""
    cdef _V V_x
    _aview(x, cnp.NPY_FLOAT64, 2, False, False, &V_x, "x")
    cdef _V V_reach_m
    _aview(reach_m, cnp.NPY_FLOAT64, 1, False, True, &V_reach_m, "reach_m")
    cdef _V V_pdx
    _aview(pdx, cnp.NPY_FLOAT64, 1, False, True, &V_pdx, "pdx")
    cdef _V V_pdy
    _aview(pdy, cnp.NPY_FLOAT64, 1, False, True, &V_pdy, "pdy")
    cdef _V V_pair
    _aview(pair, cnp.NPY_INT64, 1, False, True, &V_pair, "pair")
    cdef _V V_det
    _aview(det, cnp.NPY_INT64, 1, False, True, &V_det, "det")
    cdef _V V_close_run
    _aview(close_run, cnp.NPY_INT32, 1, False, False, &V_close_run, "close_run")
    cdef Py_ssize_t nt = V_x.n[0], a, b, i, nb = 0, nr = 0, nk = 0
    cdef Py_ssize_t npairs = nt * (nt - 1) // 2 if nt > 1 else 0
    if V_reach_m.n[0] != nt or V_pdx.n[0] != nt or V_pdy.n[0] != nt or V_close_run.n[0] != nt \
            or V_x.n[1] < 4 or (resolved and (V_pair.n[0] != nt or V_det.n[0] != nt)):
        raise ValueError("duplicate_pairs: inconsistent shapes")
    # per pair candidate: the boxed ones (a, b, keep) and the state-test ones (a, b); their differences (4)
    cdef cnp.ndarray bx_a = _empty1(cnp.NPY_INT64, 5 * npairs + nt + 1)  # scratch (freed however the call ends)
    cdef cnp.ndarray rd_a = _empty1(cnp.NPY_FLOAT64, 4 * npairs + 1)
    cdef long long* bx = <long long*> cnp.PyArray_DATA(bx_a)
    cdef double* rd = _f64(rd_a)
    cdef long long* rx = bx + 3 * npairs
    cdef long long* run = rx + 2 * npairs
    cdef double s0, s1, h, nrm, ux, uy, d0, d1, d2_, d3
    cdef bint is_boxed, keep
    for a in range(nt):
        run[a] = 0
    for a in range(nt):
        for b in range(a + 1, nt):
            s0 = _pd2(V_x, a, 2)[0] + _pd2(V_x, b, 2)[0]
            s1 = _pd2(V_x, a, 3)[0] + _pd2(V_x, b, 3)[0]
            h = hypot(s0, s1)
            nrm = _max_nan(h, 1e-9)
            ux = s0 / nrm
            uy = s1 / nrm
            d2_ = _pd2(V_x, a, 2)[0] - _pd2(V_x, b, 2)[0]
            d3 = _pd2(V_x, a, 3)[0] - _pd2(V_x, b, 3)[0]
            if not (fabs(d2_ * ux + d3 * uy) < merge_speed_mps):
                continue
            if (resolved and _pi64(V_pair, a)[0] >= 0 and _pi64(V_pair, a)[0] == _pi64(V_pair, b)[0]
                    and _pi64(V_det, a)[0] != _pi64(V_det, b)[0]):
                continue
            d0 = _pd2(V_x, a, 0)[0] - _pd2(V_x, b, 0)[0]
            d1 = _pd2(V_x, a, 1)[0] - _pd2(V_x, b, 1)[0]
            keep = fabs(d2_ * uy - d3 * ux) < merge_lateral_speed_mps
            is_boxed = (fabs(d0) < merge_lateral_m) and (
                fabs(d1) < _max_nan(_pd1(V_reach_m, a)[0], _pd1(V_reach_m, b)[0]))
            if is_boxed:
                run[a] = run[b] = 1
                bx[3 * nb] = a
                bx[3 * nb + 1] = b
                bx[3 * nb + 2] = keep
                nb += 1
            elif (keep and d0 * d0 < state_gamma * (_pd1(V_pdx, a)[0] + _pd1(V_pdx, b)[0])
                    and d1 * d1 < state_gamma * (_pd1(V_pdy, a)[0] + _pd1(V_pdy, b)[0])):
                rx[2 * nr] = a
                rx[2 * nr + 1] = b
                rd[4 * nr] = d0
                rd[4 * nr + 1] = d1
                rd[4 * nr + 2] = d2_
                rd[4 * nr + 3] = d3
                nr += 1
    # the runs: one more frame in the box, else 0 (all 0 without a boxed pair); a boxed pair that lasted is kept
    cdef cnp.ndarray run_a = _empty1(cnp.NPY_INT32, nt)
    cdef cnp.int32_t* cr = <cnp.int32_t*> cnp.PyArray_DATA(run_a)
    for a in range(nt):
        cr[a] = <cnp.int32_t> (<cnp.uint32_t> _pi32(V_close_run, a)[0] + 1u) if (nb and run[a]) else 0
    for i in range(nb):
        a, b = bx[3 * i], bx[3 * i + 1]
        if bx[3 * i + 2] or (cr[a] if cr[a] < cr[b] else cr[b]) >= persist_frames:
            bx[2 * nk] = a
            bx[2 * nk + 1] = b
            nk += 1
    cdef cnp.ndarray ka = _empty1(cnp.NPY_INT64, nk)
    cdef cnp.ndarray kb = _empty1(cnp.NPY_INT64, nk)
    cdef cnp.ndarray ra = _empty1(cnp.NPY_INT64, nr)
    cdef cnp.ndarray rb = _empty1(cnp.NPY_INT64, nr)
    cdef cnp.ndarray rdx = _empty2(cnp.NPY_FLOAT64, nr, 4)
    for i in range(nk):
        (<cnp.int64_t*> cnp.PyArray_DATA(ka))[i] = bx[2 * i]
        (<cnp.int64_t*> cnp.PyArray_DATA(kb))[i] = bx[2 * i + 1]
    for i in range(nr):
        (<cnp.int64_t*> cnp.PyArray_DATA(ra))[i] = rx[2 * i]
        (<cnp.int64_t*> cnp.PyArray_DATA(rb))[i] = rx[2 * i + 1]
    memcpy(cnp.PyArray_DATA(rdx), rd, 4 * nr * sizeof(double))
    return run_a, ka, kb, ra, rb, rdx


cdef void _update_rows(const double* xs, const double* ps, const double* h, Py_ssize_t nr, Py_ssize_t n,
                       const long long* rows, Py_ssize_t npair, const double* v, const double* s_inv, const double* w,
                       double* x, double* p) noexcept nogil:
    """The per-hypothesis PDAF update of :func:`edge.track.pdaf.combined_update_pairs` (pairs with ``w > 0``):
    ``x = x^- + sum w dx``, ``P = P^- - (sum w K) H P^- + sum w dx dx' - dx_bar dx_bar'``, symmetrised. C-contiguous
    arrays: ``xs``, ``x`` (nr, 4), ``ps``, ``p`` (nr, 4, 4), ``h`` (nr, n, 4), ``rows``, ``w`` (npair,), ``v``
    (npair, n), ``s_inv`` (npair, n, n)."""
    cdef Py_ssize_t r, q, i, j, l
    cdef double ph[4][3]
    cdef double kk[4][3]
    cdef double dx[4]
    cdef double wq, acc
    # accumulators per row: dx_bar (4), k_bar (4 x n), spread (4 x 4), in x and p (x starts at 0, p at 0)
    for r in range(nr):
        for i in range(4):
            x[4 * r + i] = 0.0
            for j in range(4):
                p[16 * r + 4 * i + j] = 0.0
    # p holds sum w dx dx' and the k_bar terms are applied per pair as -w K (H P^-): the same sums, per pair
    for q in range(npair):
        wq = w[q]
        if not (wq > 0.0):
            continue
        r = rows[q]
        for i in range(4):
            for j in range(n):
                acc = 0.0
                for l in range(4):
                    acc = acc + ps[16 * r + 4 * i + l] * h[(r * n + j) * 4 + l]
                ph[i][j] = acc
        for i in range(4):
            for j in range(n):
                acc = 0.0
                for l in range(n):
                    acc = acc + ph[i][l] * s_inv[(q * n + l) * n + j]
                kk[i][j] = acc
        for i in range(4):
            acc = 0.0
            for j in range(n):
                acc = acc + kk[i][j] * v[q * n + j]
            dx[i] = acc
        for i in range(4):
            x[4 * r + i] += wq * dx[i]
            for j in range(4):
                # K_q H P^- = K_q (P^- H')' = K_q ph'
                acc = 0.0
                for l in range(n):
                    acc = acc + kk[i][l] * ph[j][l]
                p[16 * r + 4 * i + j] += wq * dx[i] * dx[j] - wq * acc
    for r in range(nr):
        for i in range(4):
            for j in range(4):
                p[16 * r + 4 * i + j] = ps[16 * r + 4 * i + j] + p[16 * r + 4 * i + j] - x[4 * r + i] * x[4 * r + j]
        for i in range(4):
            for j in range(i + 1, 4):
                acc = 0.5 * (p[16 * r + 4 * i + j] + p[16 * r + 4 * j + i])
                p[16 * r + 4 * i + j] = acc
                p[16 * r + 4 * j + i] = acc
        for i in range(4):
            x[4 * r + i] = xs[4 * r + i] + x[4 * r + i]


cdef inline double* _f64(cnp.ndarray a) noexcept nogil:
    """The data of a C-contiguous float64 array this module made (np.empty / np.zeros)."""
    return <double*> cnp.PyArray_DATA(a)


def update_pairs(const double[:, ::1] xs, const double[:, :, ::1] ps, const double[:, :, ::1] h,
                 const long long[::1] rows, const double[:, ::1] v, const double[:, :, ::1] s_inv,
                 const double[::1] w):
    """:func:`edge.track.pdaf.combined_update_pairs` for pairs ``rows`` (P,) with innovations ``v`` (P, n), inverse
    covariances ``s_inv`` (P, n, n) and weights ``w`` (P,) -> (x (R, 4), P (R, 4, 4)); equal to rounding."""
    cdef Py_ssize_t nr = xs.shape[0], npair = rows.shape[0], n = h.shape[1]
    if ps.shape[0] != nr or h.shape[0] != nr or v.shape[0] != npair or s_inv.shape[0] != npair \
            or w.shape[0] != npair or v.shape[1] != n or not 1 <= n <= 3:
        raise ValueError("update_pairs: inconsistent shapes")
    cdef cnp.ndarray x_a = _empty2(cnp.NPY_FLOAT64, nr, 4)
    cdef cnp.ndarray p_a = _empty3(cnp.NPY_FLOAT64, nr, 4, 4)
    if nr:
        with nogil:
            _update_rows(&xs[0, 0], &ps[0, 0, 0], &h[0, 0, 0], nr, n, &rows[0] if npair else NULL, npair,
                         &v[0, 0] if npair else NULL, &s_inv[0, 0, 0] if npair else NULL, &w[0] if npair else NULL,
                         _f64(x_a), _f64(p_a))
    return x_a, p_a


cdef void _pair_rows(const double* ps, const double* h, const double* zh, const double* r_track, int r_shift,
                     const double* z, const double* r_meas, Py_ssize_t n, const long long* rows,
                     const long long* cols, Py_ssize_t npair, const double* scale, bint scaled, double* v,
                     double* d2, double* det, double* si) noexcept nogil:
    """The pairs of :func:`edge.track.pdaf.pair_innovations`: ``S = H P H' + R_t (position block scaled) + R_m`` per
    pair (state row ``rows[q]``, detection ``cols[q]``), its inverse ``si``, determinant ``det``, the innovation ``v``
    and ``d2``. The track part of row ``r`` is ``r_track[r >> r_shift]`` (1: rows (track, mode) share their track's).
    C-contiguous arrays: ``ps`` (R, 4, 4), ``h`` (R, n, 4), ``zh`` (R, n), ``z`` (M, n), ``r_meas`` (M, n, n)."""
    cdef Py_ssize_t q, i, j, l, r, m, rt
    cdef double hp[3][4]
    cdef double s[9]
    cdef double acc, f
    for q in range(npair):
        r = rows[q]
        m = cols[q]
        rt = r >> r_shift
        for i in range(n):
            for j in range(4):
                acc = 0.0
                for l in range(4):
                    acc = acc + h[(r * n + i) * 4 + l] * ps[16 * r + 4 * l + j]
                hp[i][j] = acc
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for l in range(4):
                    acc = acc + hp[i][l] * h[(r * n + j) * 4 + l]
                f = r_track[(rt * n + i) * n + j]
                if scaled and i < 2 and j < 2:
                    f = f * scale[q]
                s[i * n + j] = acc + f
        for i in range(n):
            for j in range(i + 1, n):
                acc = 0.5 * (s[i * n + j] + s[j * n + i])
                s[i * n + j] = acc
                s[j * n + i] = acc
        for i in range(n * n):
            s[i] = s[i] + r_meas[m * n * n + i]
        for i in range(n):
            v[q * n + i] = z[m * n + i] - zh[r * n + i]
        if n == 3:
            det[q] = _inv3(s, &si[q * 9])
            d2[q] = _quad3(&si[q * 9], &v[q * 3])
        else:
            det[q] = _inv2(s, &si[q * 4])
            d2[q] = _quad2(&si[q * 4], &v[q * 2])


def pair_update(const double[:, ::1] xs, const double[:, :, ::1] ps, const double[:, :, ::1] h,
                const double[:, ::1] zh, const double[:, :, ::1] r_track, const double[:, ::1] z,
                const double[:, :, ::1] r_meas, const long long[::1] rows, const long long[::1] cols,
                const double[::1] scale, bint scaled, const double[::1] w):
    """:func:`edge.track.pdaf.pair_innovations` (``S = H P H' + R_t (position block scaled) + R_m`` per pair,
    ``rows`` into the state rows, ``cols`` into the detections) followed by :func:`update_pairs`: returns ``x``,
    ``P`` and the pairs' ``v`` (P, n), ``d2`` (P,), ``det_s`` (P,) for the mode likelihoods. Equal to rounding
    (``H P H'`` is summed here, numpy hands it to BLAS)."""
    cdef Py_ssize_t nr = xs.shape[0], npair = rows.shape[0], n = z.shape[1]
    if not 2 <= n <= 3 or h.shape[1] != n or zh.shape[1] != n or cols.shape[0] != npair or w.shape[0] != npair \
            or (scaled and scale.shape[0] != npair) or ps.shape[0] != nr or h.shape[0] != nr or zh.shape[0] != nr \
            or r_track.shape[0] != nr:
        raise ValueError("pair_update: inconsistent shapes")
    cdef cnp.ndarray v_a = _empty2(cnp.NPY_FLOAT64, npair, n)
    cdef cnp.ndarray d2_a = _empty1(cnp.NPY_FLOAT64, npair)
    cdef cnp.ndarray det_a = _empty1(cnp.NPY_FLOAT64, npair)
    cdef cnp.ndarray si_a = _empty3(cnp.NPY_FLOAT64, npair, n, n)
    cdef cnp.ndarray x_a = _empty2(cnp.NPY_FLOAT64, nr, 4)
    cdef cnp.ndarray p_a = _empty3(cnp.NPY_FLOAT64, nr, 4, 4)
    if nr:
        with nogil:
            if npair:
                _pair_rows(&ps[0, 0, 0], &h[0, 0, 0], &zh[0, 0], &r_track[0, 0, 0], 0, &z[0, 0], &r_meas[0, 0, 0], n,
                           &rows[0], &cols[0], npair, &scale[0] if scaled else NULL, scaled, _f64(v_a), _f64(d2_a),
                           _f64(det_a), _f64(si_a))
            _update_rows(&xs[0, 0], &ps[0, 0, 0], &h[0, 0, 0], nr, n, &rows[0] if npair else NULL, npair,
                         _f64(v_a), _f64(si_a), &w[0] if npair else NULL, _f64(x_a), _f64(p_a))
    return x_a, p_a, v_a, d2_a, det_a


include "_pairwise.pxi"


cdef inline double _min_nan(double a, double b) noexcept nogil:
    """np.minimum: the smaller, NaN if either is NaN."""
    if a != a or b != b:
        return a + b
    return a if a <= b else b


def update_extent(v, s2_track, s_pair,
                  bint per_pair, beta, u, w,
                  ext_var, double alpha, double max_var):
    """:meth:`edge.track.roles.measure.MeasurementModel.update_extent` with the same arithmetic, summation order
    included (numpy's pairwise sums over the detections, sequential sums of ``S``): the new (T,) along-heading
    spread. ``s2_track`` (T, 4): the position block of the track's ``S`` (when not ``per_pair``); ``s_pair``
    (T, M, n, n): ``S`` per pair (when ``per_pair``)."""
    cdef _V V_v
    _aview(v, cnp.NPY_FLOAT64, 3, False, True, &V_v, "v")
    cdef _V V_s2_track
    _aview(s2_track, cnp.NPY_FLOAT64, 2, False, True, &V_s2_track, "s2_track")
    cdef _V V_s_pair
    _aview(s_pair, cnp.NPY_FLOAT64, 4, False, True, &V_s_pair, "s_pair")
    cdef _V V_beta
    _aview(beta, cnp.NPY_FLOAT64, 2, False, True, &V_beta, "beta")
    cdef _V V_u
    _aview(u, cnp.NPY_FLOAT64, 2, False, True, &V_u, "u")
    cdef _V V_w
    _aview(w, cnp.NPY_FLOAT64, 1, False, True, &V_w, "w")
    cdef _V V_ext_var
    _aview(ext_var, cnp.NPY_FLOAT64, 1, False, True, &V_ext_var, "ext_var")
    cdef Py_ssize_t nt = V_beta.n[0], nm = V_beta.n[1], n = V_v.n[2], t, m, k
    out_a = _empty1(cnp.NPY_FLOAT64, nt)
    cdef _V V_out
    _aview(out_a, cnp.NPY_FLOAT64, 1, True, True, &V_out, "out")
    buf_a = _empty1(cnp.NPY_FLOAT64, max(nm, 1))
    cdef _V V_buf
    _aview(buf_a, cnp.NPY_FLOAT64, 1, True, True, &V_buf, "buf")
    cdef double wsum, m2, den, a, b, along, sample, u0, u1
    cdef double s2[4]
    with nogil:
        for t in range(nt):
            wsum = _pairwise_sum(&_pd2(V_beta, t, 0)[0], nm) if nm else 0.0
            if not (wsum > 0.5 and _pd1(V_w, t)[0] >= 1.0):
                _pd1(V_out, t)[0] = _pd1(V_ext_var, t)[0]
                continue
            u0 = _pd2(V_u, t, 0)[0]
            u1 = _pd2(V_u, t, 1)[0]
            for m in range(nm):
                a = _pd3(V_v, t, m, 0)[0] * u0 + _pd3(V_v, t, m, 1)[0] * u1
                _pd1(V_buf, m)[0] = _pd2(V_beta, t, m)[0] * a * a
            den = _max_nan(wsum, 1e-12)
            m2 = _pairwise_sum(<double*>V_buf.data, nm) / den
            if per_pair:
                for k in range(4):
                    s2[k] = 0.0
                for m in range(nm):
                    b = _pd2(V_beta, t, m)[0]
                    s2[0] = s2[0] + _pd4(V_s_pair, t, m, 0, 0)[0] * b
                    s2[1] = s2[1] + _pd4(V_s_pair, t, m, 0, 1)[0] * b
                    s2[2] = s2[2] + _pd4(V_s_pair, t, m, 1, 0)[0] * b
                    s2[3] = s2[3] + _pd4(V_s_pair, t, m, 1, 1)[0] * b
                for k in range(4):
                    s2[k] = s2[k] / den
            else:
                for k in range(4):
                    s2[k] = _pd2(V_s2_track, t, k)[0]
            along = u0 * (s2[0] * u0 + s2[1] * u1) + u1 * (s2[2] * u0 + s2[3] * u1)
            sample = _min_nan(_max_nan(m2 - (along - _pd1(V_ext_var, t)[0]), 0.0), max_var)
            _pd1(V_out, t)[0] = (1.0 - alpha) * _pd1(V_ext_var, t)[0] + alpha * sample
    return out_a


from libc.math cimport exp, sqrt, INFINITY


def associate_each(d2, det_s, double gamma, double vol_factor,
                   double norm_factor, double prob_detect, double b, bint jpda, confirmed, seniority, pair=None):
    """The association of :class:`edge.track.roles.associate.PdaAssociator` with one ``S`` per (track, detection)
    (:func:`edge.track.pdaf.association_weights` on :class:`edge.track.pdaf.InnovationsEach`), with its arithmetic
    and summation order: seniority when some track is not ``confirmed`` (T,) (a tentative track only sees detections
    no more senior track validated: confirmed first, then more ``seniority`` (T,), its hits; unless the detection's
    resolved ``pair`` (M,) int64 is >= 0), the gate ``d2 <= gamma``, the gate volume ``vol_factor * mean sqrt|S|``
    over the validated detections, the likelihoods ``P_D N(v; 0, S) V / M_t`` and the PDAF (or, ``jpda``, cheap
    JPDA) weights with ``b = 1 - P_G P_D``. ``norm_factor`` is ``(2 pi)^(n/2)``. Returns ``beta`` (T, M), ``beta0``
    (T,), ``gated`` (T, M) bool and the gate volumes (T,)."""
    cdef _V V_d2
    _aview(d2, cnp.NPY_FLOAT64, 2, False, False, &V_d2, "d2")
    cdef _V V_det_s
    _aview(det_s, cnp.NPY_FLOAT64, 2, False, False, &V_det_s, "det_s")
    cdef Py_ssize_t nt = V_d2.n[0], nm = V_d2.n[1], t, m
    cdef cnp.ndarray conf_a, sen_a, pair_a
    cdef bint with_pairs = pair is not None
    if V_det_s.n[0] != nt or V_det_s.n[1] != nm:
        raise ValueError("associate_each: d2 and det_s differ in shape")
    conf_a = confirmed if _column(confirmed, cnp.NPY_BOOL, nt) else np.ascontiguousarray(confirmed, dtype=bool)
    if cnp.PyArray_NDIM(conf_a) != 1 or cnp.PyArray_DIMS(conf_a)[0] != nt:
        raise ValueError("associate_each: one confirmed flag per track")
    if _column(seniority, cnp.NPY_INT32, nt) or _column(seniority, cnp.NPY_INT64, nt) \
            or _column(seniority, cnp.NPY_FLOAT64, nt):
        sen_a = seniority
    else:
        sen_a = np.ascontiguousarray(seniority, dtype=np.float64)
        if cnp.PyArray_NDIM(sen_a) != 1 or cnp.PyArray_DIMS(sen_a)[0] != nt:
            raise ValueError("associate_each: one seniority per track")
    if with_pairs:
        pair_a = pair if _column(pair, cnp.NPY_INT64, nm) else np.ascontiguousarray(pair, dtype=np.int64)
        if cnp.PyArray_NDIM(pair_a) != 1 or cnp.PyArray_DIMS(pair_a)[0] != nm:
            raise ValueError("associate_each: one pair value per detection")
    cdef int sen_type = cnp.PyArray_TYPE(sen_a)
    cdef cnp.ndarray beta_a = _empty2(cnp.NPY_FLOAT64, nt, nm)
    cdef cnp.ndarray beta0_a = _empty1(cnp.NPY_FLOAT64, nt)
    cdef cnp.ndarray gated_a = _empty2(cnp.NPY_BOOL, nt, nm)
    cdef cnp.ndarray vol_a = _empty1(cnp.NPY_FLOAT64, nt)
    cdef double* beta = _f64(beta_a)
    cdef double* beta0 = _f64(beta0_a)
    cdef cnp.npy_bool* gated = <cnp.npy_bool*> cnp.PyArray_DATA(gated_a)
    cdef double* vol = _f64(vol_a)
    # scratch: sqrt|S| (T, M), each detection's most senior rank and column sum (M), one row's validated roots (M),
    # the row sums and the ranks (T)
    cdef double* root = <double*> PyMem_Malloc((nt * nm + 3 * nm + 2 * nt + 1) * sizeof(double))
    if root == NULL:
        raise MemoryError()
    cdef double* owner = root + nt * nm
    cdef double* sm = owner + nm
    cdef double* buf = sm + nm
    cdef double* st = buf + nm + 1
    cdef double* rank = st + nt
    cdef const cnp.npy_bool* conf = <const cnp.npy_bool*> cnp.PyArray_BYTES(conf_a)
    cdef Py_ssize_t conf_s = cnp.PyArray_STRIDES(conf_a)[0]
    cdef const char* sen = cnp.PyArray_BYTES(sen_a)
    cdef Py_ssize_t sen_s = cnp.PyArray_STRIDES(sen_a)[0]
    cdef const char* pr = cnp.PyArray_BYTES(pair_a) if with_pairs else NULL
    cdef Py_ssize_t pr_s = cnp.PyArray_STRIDES(pair_a)[0] if with_pairs else 0
    cdef bint seniority_on = False
    cdef long long k
    cdef double scale, mean_root, lik, q
    with nogil:
        for t in range(nt):
            if conf[t * conf_s]:
                rank[t] = INFINITY
            else:
                seniority_on = True
                if sen_type == cnp.NPY_INT32:
                    rank[t] = <double> (<const cnp.int32_t*> (sen + t * sen_s))[0]
                elif sen_type == cnp.NPY_INT64:
                    rank[t] = <double> (<const cnp.int64_t*> (sen + t * sen_s))[0]
                else:
                    rank[t] = (<const double*> (sen + t * sen_s))[0]
        for m in range(nm):
            sm[m] = 0.0
        if seniority_on:  # the most senior rank among the tracks that validated each detection
            for m in range(nm):
                owner[m] = -INFINITY
            for t in range(nt):
                for m in range(nm):
                    if _pd2(V_d2, t, m)[0] <= gamma and rank[t] > owner[m]:
                        owner[m] = rank[t]
        for t in range(nt):
            k = 0
            for m in range(nm):
                gated[t * nm + m] = _pd2(V_d2, t, m)[0] <= gamma and (
                    not seniority_on or conf[t * conf_s] or rank[t] >= owner[m]
                    or (with_pairs and (<const cnp.int64_t*> (pr + m * pr_s))[0] >= 0))
                k += gated[t * nm + m]
                root[t * nm + m] = sqrt(_pd2(V_det_s, t, m)[0])
                buf[m] = root[t * nm + m] * (1.0 if gated[t * nm + m] else 0.0)
            if k > 0:
                mean_root = _pairwise_sum(buf, nm) / <double> k
            else:
                mean_root = _pairwise_sum(&root[t * nm], nm) / <double> nm
            vol[t] = vol_factor * mean_root
            scale = prob_detect * vol[t] / <double> (k if k > 1 else 1)
            for m in range(nm):
                if gated[t * nm + m]:
                    q = _pd2(V_d2, t, m)[0]
                    q = q if q <= gamma or q != q else gamma  # np.minimum(d2, gamma)
                    beta[t * nm + m] = exp(-0.5 * q) * scale / (norm_factor * root[t * nm + m])
                else:
                    beta[t * nm + m] = 0.0
                sm[m] = sm[m] + beta[t * nm + m]
            st[t] = _pairwise_sum(&beta[t * nm], nm)
        if nm == 1:  # numpy reduces a single column pairwise (its only axis left), not row after row
            sm[0] = _pairwise_sum(beta, nt)
        for t in range(nt):
            if jpda:
                for m in range(nm):
                    lik = beta[t * nm + m]
                    beta[t * nm + m] = lik / (st[t] + sm[m] - lik + b)
                beta0[t] = 1.0 - _pairwise_sum(&beta[t * nm], nm)
            else:
                for m in range(nm):
                    beta[t * nm + m] = beta[t * nm + m] / (b + st[t])
                beta0[t] = b / (b + st[t])
    PyMem_Free(root)
    return beta_a, beta0_a, gated_a, vol_a


def near_tracks(const double[:, ::1] xt, const double[:, ::1] z, const double[::1] lat_m, const double[::1] along_m,
                const cnp.npy_bool[::1] resolved, double pair_lateral_m, const double[::1] vr_t, bint radial,
                double merge_speed_mps):
    """(M,) bool: detection ``m`` lies in some track's same-vehicle box (``|dx| < lat_m[t]``, or ``pair_lateral_m``
    for a resolved detection, and ``|dy| < along_m[t]``) and, with ``radial``, moves like it (``|vr_t[t] - z[m, 2]|
    < merge_speed_mps``): the seed block of :meth:`edge.track.roles.initiate.SeedInitiator.initiate`, same
    arithmetic."""
    cdef Py_ssize_t nt = xt.shape[0], nm = z.shape[0], t, m
    out_a = _zeros1(cnp.NPY_BOOL, nm)
    cdef cnp.npy_bool[::1] out = out_a
    cdef double lat
    with nogil:
        for m in range(nm):
            for t in range(nt):
                lat = pair_lateral_m if resolved[m] else lat_m[t]
                if (fabs(xt[t, 0] - z[m, 0]) < lat and fabs(xt[t, 1] - z[m, 1]) < along_m[t]
                        and (not radial or fabs(vr_t[t] - z[m, 2]) < merge_speed_mps)):
                    out[m] = True
                    break
    return out_a


cdef inline void _moment_match_row(const double* xm, const double* pm, double w0, double w1, double* x,
                                   double* p) noexcept nogil:
    """Two-mode moment matching of one track: ``x = w0 x_0 + w1 x_1``, ``P = w0 P_0 + w1 P_1 + d d'``,
    ``d = (x_0 - x_1) sqrt(w0 w1)``."""
    cdef double d[4]
    cdef double r = sqrt(w0 * w1)
    cdef int i, j
    for i in range(4):
        x[i] = w0 * xm[i] + w1 * xm[4 + i]
        d[i] = (xm[i] - xm[4 + i]) * r
    for i in range(4):
        for j in range(4):
            p[4 * i + j] = w0 * pm[4 * i + j] + w1 * pm[16 + 4 * i + j] + d[i] * d[j]


def imm_predict(xm, pm, mu,
                pi, f, q,
                x_far=None, double far_from_m=0.0, double far_span_m=1.0,
                double log_p_near=0.0, double log_p_far=0.0):
    """IMM mixing, mode-matched prediction and moment matching of all tracks (:func:`edge.track.imm.mix`,
    :func:`edge.track.imm.predict_modes`, :func:`edge.track.imm.moment_match`): ``xm`` (T, 2, 4), ``pm``
    (T, 2, 4, 4), ``mu`` (T, 2), ``pi`` (1, 2, 2) or (T, 2, 2), ``f``, ``q`` (2, 4, 4) -> ``x`` (T, 4), ``p``
    (T, 4, 4), ``xpm`` (T, 2, 4), ``ppm`` (T, 2, 4, 4), ``c`` (T, 2). Equal to numpy to rounding (its small matrix
    products are BLAS's).

    ``x_far`` (T, 4), the tracks' states: the first row of each track's switching matrix from its ground range
    instead (``ImmPredictor._far_switch``, the same operations: ``u = min(max((rho - far_from_m) / far_span_m, 0),
    1)``, ``p = exp((1 - u) log_p_near + u log_p_far)``, row ``(1 - p, p)``); the second row is ``pi[0, 1]``."""
    cdef _V V_xm
    _aview(xm, cnp.NPY_FLOAT64, 3, False, False, &V_xm, "xm")
    cdef _V V_pm
    _aview(pm, cnp.NPY_FLOAT64, 4, False, False, &V_pm, "pm")
    cdef _V V_mu
    _aview(mu, cnp.NPY_FLOAT64, 2, False, False, &V_mu, "mu")
    cdef _V V_pi
    _aview(pi, cnp.NPY_FLOAT64, 3, False, True, &V_pi, "pi")
    cdef _V V_f
    _aview(f, cnp.NPY_FLOAT64, 3, False, True, &V_f, "f")
    cdef _V V_q
    _aview(q, cnp.NPY_FLOAT64, 3, False, True, &V_q, "q")
    cdef _V V_x_far
    if x_far is not None:
        _aview(x_far, cnp.NPY_FLOAT64, 2, False, False, &V_x_far, "x_far")
    cdef Py_ssize_t nt = V_xm.n[0], t, i, j, k, l, mode, src
    cdef bint far = x_far is not None
    cdef double pi_t[2][2]
    cdef double u, pk
    if far and (V_x_far.n[0] != nt or V_x_far.n[1] < 2):
        raise ValueError("imm_predict: x_far must be (T, 4)")
    if V_xm.n[1] != 2 or V_xm.n[2] != 4 or V_pm.n[0] != nt or V_pm.n[1] != 2 or V_pm.n[2] != 4 \
            or V_pm.n[3] != 4 or V_mu.n[0] != nt or V_mu.n[1] != 2 or V_pi.n[1] != 2 or V_pi.n[2] != 2 \
            or (V_pi.n[0] != 1 and V_pi.n[0] != nt) or V_f.n[0] != 2 or V_q.n[0] != 2 or V_f.n[1] != 4 \
            or V_f.n[2] != 4 or V_q.n[1] != 4 or V_q.n[2] != 4:
        raise ValueError("imm_predict: inconsistent shapes")
    cdef cnp.ndarray x_a = _empty2(cnp.NPY_FLOAT64, nt, 4)
    cdef cnp.ndarray p_a = _empty3(cnp.NPY_FLOAT64, nt, 4, 4)
    cdef cnp.ndarray xpm_a = _empty3(cnp.NPY_FLOAT64, nt, 2, 4)
    cdef cnp.ndarray ppm_a = _empty4(cnp.NPY_FLOAT64, nt, 2, 4, 4)
    cdef cnp.ndarray c_a = _empty2(cnp.NPY_FLOAT64, nt, 2)
    cdef double* x = _f64(x_a)
    cdef double* p = _f64(p_a)
    cdef double* xpm = _f64(xpm_a)
    cdef double* ppm = _f64(ppm_a)
    cdef double* c = _f64(c_a)
    cdef double w[2][2]
    cdef double joint[2][2]
    cdef double x0[4]
    cdef double p0[4][4]
    cdef double fp[4][4]
    cdef double dvec[4]
    cdef double acc, den
    with nogil:
        for t in range(nt):
            src = t if V_pi.n[0] > 1 else 0
            if far:
                u = _np_min(_np_max((hypot(_pd2(V_x_far, t, 0)[0], _pd2(V_x_far, t, 1)[0]) - far_from_m) / far_span_m,
                                    0.0), 1.0)
                pk = exp((1.0 - u) * log_p_near + u * log_p_far)
                pi_t[0][0] = 1.0 - pk
                pi_t[0][1] = pk
                pi_t[1][0] = _pd3(V_pi, 0, 1, 0)[0]
                pi_t[1][1] = _pd3(V_pi, 0, 1, 1)[0]
            else:
                for i in range(2):
                    for j in range(2):
                        pi_t[i][j] = _pd3(V_pi, src, i, j)[0]
            for i in range(2):
                for j in range(2):
                    joint[i][j] = _pd2(V_mu, t, i)[0] * pi_t[i][j]
            for j in range(2):
                c[2 * t + j] = joint[0][j] + joint[1][j]
                den = _max_nan(c[2 * t + j], 1e-300)
                for i in range(2):
                    w[i][j] = joint[i][j] / den
            for k in range(4):
                dvec[k] = _pd3(V_xm, t, 0, k)[0] - _pd3(V_xm, t, 1, k)[0]
            for mode in range(2):
                for k in range(4):
                    x0[k] = w[0][mode] * _pd3(V_xm, t, 0, k)[0] + w[1][mode] * _pd3(V_xm, t, 1, k)[0]
                for k in range(4):
                    for l in range(4):
                        p0[k][l] = (w[0][mode] * _pd4(V_pm, t, 0, k, l)[0] + w[1][mode] * _pd4(V_pm, t, 1, k, l)[0]
                                    + (w[0][mode] * w[1][mode]) * (dvec[k] * dvec[l]))
                for k in range(4):
                    acc = 0.0
                    for l in range(4):
                        acc = acc + _pd3(V_f, mode, k, l)[0] * x0[l]
                    xpm[8 * t + 4 * mode + k] = acc
                for k in range(4):
                    for l in range(4):
                        acc = 0.0
                        for i in range(4):
                            acc = acc + _pd3(V_f, mode, k, i)[0] * p0[i][l]
                        fp[k][l] = acc
                for k in range(4):
                    for l in range(4):
                        acc = 0.0
                        for i in range(4):
                            acc = acc + fp[k][i] * _pd3(V_f, mode, l, i)[0]
                        ppm[32 * t + 16 * mode + 4 * k + l] = acc + _pd3(V_q, mode, k, l)[0]
            _moment_match_row(&xpm[8 * t], &ppm[32 * t], c[2 * t], c[2 * t + 1], &x[4 * t], &p[16 * t])
    return x_a, p_a, xpm_a, ppm_a, c_a


def keep_model_into(f, q, double dt, double yaw, double tau, double q_across,
                    double q_along, double d3, double d2):
    """Write :func:`edge.track.imm.keep_model` ``(dt, yaw, tau, q_across, q_along)`` into ``f[0]`` and ``q[0]`` (each
    (4, 4)) with its operations; ``d3``, ``d2``: ``dt**3 / 3`` and ``dt**2 / 2`` as Python computes them."""
    cdef _V V_f
    _aview(f, cnp.NPY_FLOAT64, 3, True, True, &V_f, "f")
    cdef _V V_q
    _aview(q, cnp.NPY_FLOAT64, 3, True, True, &V_q, "q")
    if V_f.n[0] < 1 or V_q.n[0] < 1 or V_f.n[1] != 4 or V_f.n[2] != 4 or V_q.n[1] != 4 or V_q.n[2] != 4:
        raise ValueError("keep_model_into: f and q must be (k, 4, 4)")
    cdef double c = cos(yaw), s = sin(yaw)
    cdef double decay = exp(-dt / tau) if tau > 0 else 1.0
    cdef double cc = c * c, ss = s * s, cs = c * s
    cdef double p00 = cc * decay + ss, p01 = cs * (decay - 1.0), p11 = ss * decay + cc
    cdef double a00 = cc * q_across + ss * q_along
    cdef double a01 = cs * (q_across - q_along)
    cdef double a11 = ss * q_across + cc * q_along
    cdef double d1 = dt
    cdef int i, j
    for i in range(4):
        for j in range(4):
            _pd3(V_f, 0, i, j)[0] = 0.0
    _pd3(V_f, 0, 0, 0)[0] = 1.0
    _pd3(V_f, 0, 0, 2)[0] = dt
    _pd3(V_f, 0, 1, 1)[0] = 1.0
    _pd3(V_f, 0, 1, 3)[0] = dt
    _pd3(V_f, 0, 2, 2)[0] = p00
    _pd3(V_f, 0, 2, 3)[0] = p01
    _pd3(V_f, 0, 3, 2)[0] = p01
    _pd3(V_f, 0, 3, 3)[0] = p11
    _pd3(V_q, 0, 0, 0)[0] = d3 * a00
    _pd3(V_q, 0, 0, 1)[0] = d3 * a01
    _pd3(V_q, 0, 0, 2)[0] = d2 * a00
    _pd3(V_q, 0, 0, 3)[0] = d2 * a01
    _pd3(V_q, 0, 1, 0)[0] = d3 * a01
    _pd3(V_q, 0, 1, 1)[0] = d3 * a11
    _pd3(V_q, 0, 1, 2)[0] = d2 * a01
    _pd3(V_q, 0, 1, 3)[0] = d2 * a11
    _pd3(V_q, 0, 2, 0)[0] = d2 * a00
    _pd3(V_q, 0, 2, 1)[0] = d2 * a01
    _pd3(V_q, 0, 2, 2)[0] = d1 * a00
    _pd3(V_q, 0, 2, 3)[0] = d1 * a01
    _pd3(V_q, 0, 3, 0)[0] = d2 * a01
    _pd3(V_q, 0, 3, 1)[0] = d2 * a11
    _pd3(V_q, 0, 3, 2)[0] = d1 * a01
    _pd3(V_q, 0, 3, 3)[0] = d1 * a11


def moment_match(const double[:, :, ::1] xm, const double[:, :, :, ::1] pm, const double[:, ::1] w):
    """:func:`edge.track.imm.moment_match` of all tracks -> ``x`` (T, 4), ``p`` (T, 4, 4); equal to rounding."""
    cdef Py_ssize_t nt = xm.shape[0], t
    x_a = _empty2(cnp.NPY_FLOAT64, nt, 4)
    p_a = _empty3(cnp.NPY_FLOAT64, nt, 4, 4)
    cdef double[:, ::1] x = x_a
    cdef double[:, :, ::1] p = p_a
    with nogil:
        for t in range(nt):
            _moment_match_row(&xm[t, 0, 0], &pm[t, 0, 0, 0], w[t, 0], w[t, 1], &x[t, 0], &p[t, 0, 0])
    return x_a, p_a


def imm_mode_update(xs, ps, hm,
                    zhm, r_track, z,
                    r_meas, gated, beta,
                    double near_factor, bint scaled, vol, double prob_detect, double prob_gate):
    """Both IMM modes' PDAF posteriors over the validated pairs and the modes' likelihoods
    (:meth:`edge.track.roles.measure.SnrNoiseModel.mode_update`, :func:`edge.track.imm.mode_likelihood_pairs`):
    rows ``(track, mode)`` of ``xs`` (2T, 4), ``ps``, ``hm``, ``zhm``; ``r_track`` (T, n, n) the track's part of
    ``R``; ``gated``, ``beta`` (T, M); with ``scaled`` a detection nearer than the mode's prediction counts
    ``near_factor`` of the position block of ``r_track``; ``vol`` (T,) the gate volumes. Returns ``xm`` (2T, 4),
    ``pm`` (2T, 4, 4) and the likelihoods (T, 2). Equal to numpy to rounding."""
    cdef _V V_xs
    _aview(xs, cnp.NPY_FLOAT64, 2, False, True, &V_xs, "xs")
    cdef _V V_ps
    _aview(ps, cnp.NPY_FLOAT64, 3, False, True, &V_ps, "ps")
    cdef _V V_hm
    _aview(hm, cnp.NPY_FLOAT64, 3, False, True, &V_hm, "hm")
    cdef _V V_zhm
    _aview(zhm, cnp.NPY_FLOAT64, 2, False, True, &V_zhm, "zhm")
    cdef _V V_r_track
    _aview(r_track, cnp.NPY_FLOAT64, 3, False, True, &V_r_track, "r_track")
    cdef _V V_z
    _aview(z, cnp.NPY_FLOAT64, 2, False, True, &V_z, "z")
    cdef _V V_r_meas
    _aview(r_meas, cnp.NPY_FLOAT64, 3, False, True, &V_r_meas, "r_meas")
    cdef _V V_gated
    _aview(gated, cnp.NPY_BOOL, 2, False, True, &V_gated, "gated")
    cdef _V V_beta
    _aview(beta, cnp.NPY_FLOAT64, 2, False, True, &V_beta, "beta")
    cdef _V V_vol
    _aview(vol, cnp.NPY_FLOAT64, 1, False, True, &V_vol, "vol")
    cdef Py_ssize_t nt = V_gated.n[0], nm = V_gated.n[1], n = V_z.n[1], t, m, k = 0, npair = 0, half, q
    cdef Py_ssize_t mode, row
    cdef long long ng
    if not 2 <= n <= 3 or V_xs.n[0] != 2 * nt or V_ps.n[0] != 2 * nt or V_hm.n[0] != 2 * nt \
            or V_zhm.n[0] != 2 * nt or V_r_track.n[0] != nt or V_beta.n[0] != nt or V_beta.n[1] != nm \
            or V_z.n[0] != nm or V_r_meas.n[0] != nm or V_vol.n[0] != nt or V_hm.n[1] != n:
        raise ValueError("imm_mode_update: inconsistent shapes")
    for t in range(nt):
        for m in range(nm):
            npair += _pu8_2(V_gated, t, m)[0]
    # the pairs' rows, detections, weights and scales in one int64 and one float64 scratch array
    cdef cnp.ndarray idx_a = _empty1(cnp.NPY_INT64, 4 * npair)
    cdef cnp.ndarray ws_a = _empty1(cnp.NPY_FLOAT64, 4 * npair)
    cdef long long* rows = <long long*> cnp.PyArray_DATA(idx_a)
    cdef long long* cols = rows + 2 * npair
    cdef double* w = _f64(ws_a)
    cdef double* sc = w + 2 * npair
    cdef double a0, a1
    half = npair
    for t in range(nt):
        for m in range(nm):
            if _pu8_2(V_gated, t, m)[0]:
                for mode in range(2):
                    q = k + mode * half
                    rows[q] = 2 * t + mode
                    cols[q] = m
                    w[q] = _pd2(V_beta, t, m)[0]
                    sc[q] = 1.0
                    if scaled:
                        row = 2 * t + mode
                        a0 = (_pd2(V_z, m, 0)[0] - _pd2(V_zhm, row, 0)[0]) * _pd2(V_zhm, row, 0)[0]
                        a1 = (_pd2(V_z, m, 1)[0] - _pd2(V_zhm, row, 1)[0]) * _pd2(V_zhm, row, 1)[0]
                        sc[q] = near_factor if a0 + a1 < 0.0 else 1.0
                k += 1
    # the pairs' v, S^-1 (scratch), d2 and det, then the updates (pair_update's steps, without its arrays)
    cdef cnp.ndarray pv_a = _empty1(cnp.NPY_FLOAT64, 2 * npair * (n + n * n + 2))
    cdef double* pv = _f64(pv_a)
    cdef double* psi = pv + 2 * npair * n
    cdef double* d2 = psi + 2 * npair * n * n
    cdef double* det = d2 + 2 * npair
    cdef cnp.ndarray x_a = _empty2(cnp.NPY_FLOAT64, 2 * nt, 4)
    cdef cnp.ndarray p_a = _empty3(cnp.NPY_FLOAT64, 2 * nt, 4, 4)
    cdef cnp.ndarray lik_a = _empty2(cnp.NPY_FLOAT64, nt, 2)
    cdef double* lik = _f64(lik_a)
    cdef double* dens
    cdef double c_norm = pow(2.0 * M_PI, n / 2.0)
    cdef double dq
    if nt == 0:
        return x_a, p_a, lik_a
    dens = <double*> PyMem_Malloc(2 * nt * sizeof(double))
    if dens == NULL:
        raise MemoryError()
    with nogil:
        if npair:
            _pair_rows(<double*>V_ps.data, <double*>V_hm.data, <double*>V_zhm.data, <double*>V_r_track.data, 1,
                       <double*>V_z.data, <double*>V_r_meas.data, n, rows, cols, 2 * npair, sc, scaled, pv, d2, det,
                       psi)
        _update_rows(<double*>V_xs.data, <double*>V_ps.data, <double*>V_hm.data, 2 * nt, n, rows, 2 * npair, pv, psi, w,
                     _f64(x_a), _f64(p_a))
        for q in range(2 * nt):
            dens[q] = 0.0
        for q in range(2 * npair):
            dq = d2[q]
            dq = dq if dq <= 700.0 or dq != dq else 700.0
            dens[rows[q]] += exp(-0.5 * dq) / (c_norm * sqrt(det[q]))
        for t in range(nt):
            ng = 0
            for m in range(nm):
                ng += _pu8_2(V_gated, t, m)[0]
            for mode in range(2):
                lik[2 * t + mode] = (1.0 - prob_gate * prob_detect) \
                    + prob_detect * _pd1(V_vol, t)[0] / <double> (ng if ng > 1 else 1) * dens[2 * t + mode]
    PyMem_Free(dens)
    return x_a, p_a, lik_a


from libc.math cimport log


cdef void _lateral_rows(_V V_lat0, _V V_lat_p0, _V V_age,
                        int seed_age, double seed_var, double dt, double q, _V V_beta,
                        _V V_z0, _V V_var_track, _V V_var_meas, bint per_detection,
                        _V V_x_ref, _V V_var_ref, _V V_cusum0, _V V_ref,
                        _V V_ref_p, double gamma, double min_fraction, double cusum_nats,
                        _V V_x, _V V_p, _V V_cusum, _V V_off) noexcept nogil:
    """One frame of the straight-line lateral filter of every track, row by row (strided inputs): the numpy
    reference's :func:`edge.track.kalman.lateral_predict`, :func:`edge.track.kalman.lateral_log_likelihood_ratio`,
    the CUSUM, :func:`edge.track.kalman.lateral_pda_update` and :func:`edge.track.kalman.lateral_inconsistent`, with
    the association weights ``beta`` (T, M), the detections' lateral positions ``z0`` (M,) and variances
    ``var_track[t] (+ var_meas[m])``, the motion model's prediction ``x_ref``, ``var_ref`` (T,) and posterior ``ref``
    (T, 2), ``ref_p`` (T, 2, 2) = ``[x, vx]``; writes ``x``, ``p``, ``cusum`` and ``off`` (the line disagrees with
    the motion model: restart). Rows whose ``age`` is ``seed_age`` first get the seeded line's lateral speed
    variance ``min(p11, seed_var)`` and no covariance."""
    cdef Py_ssize_t nt = V_beta.n[0], nm = V_beta.n[1], t, m
    cdef double q3 = q * dt ** 3 / 3.0, q2 = q * dt ** 2 / 2.0, q1 = q * dt
    cdef double p00, p01, p11, xs, vs, w, r, s_s, s_r, v_s, v_r, llr, k0, k1, dx0, dx1, d, vr0, vr1, c
    cdef double sx0, sx1, sk0, sk1, s00, s01, s10, s11
    cdef bint any_pair
    for t in range(nt):
        p00 = _pd3(V_lat_p0, t, 0, 0)[0]
        p01 = _pd3(V_lat_p0, t, 0, 1)[0]
        p11 = _pd3(V_lat_p0, t, 1, 1)[0]
        if _pi32(V_age, t)[0] == seed_age:  # seeded last frame (LateralSmoother.run's first step)
            p11 = _np_min(p11, seed_var)
            p01 = 0.0
        xs = _pd2(V_lat0, t, 0)[0] + dt * _pd2(V_lat0, t, 1)[0]
        vs = _pd2(V_lat0, t, 1)[0]
        p00 = p00 + 2.0 * dt * p01 + dt * dt * p11 + q3
        p01 = p01 + dt * p11 + q2
        p11 = p11 + q1
        llr = 0.0
        any_pair = False
        sx0 = sx1 = sk0 = sk1 = s00 = s01 = s10 = s11 = 0.0
        for m in range(nm):
            w = _pd2(V_beta, t, m)[0]
            if not (w > 0.0):
                continue
            any_pair = True
            r = _pd1(V_var_track, t)[0] + _pd1(V_var_meas, m)[0] if per_detection else _pd1(V_var_track, t)[0]
            s_s = p00 + r
            s_r = _pd1(V_var_ref, t)[0] + r
            v_s = _pd1(V_z0, m)[0] - xs
            v_r = _pd1(V_z0, m)[0] - _pd1(V_x_ref, t)[0]
            llr += w * (0.5 * (log(s_s / s_r) + v_s * v_s / s_s - v_r * v_r / s_r))
            k0 = p00 / s_s
            k1 = p01 / s_s
            dx0 = k0 * v_s
            dx1 = k1 * v_s
            sx0 += w * dx0
            sx1 += w * dx1
            sk0 += w * k0
            sk1 += w * k1
            s00 += w * dx0 * dx0
            s01 += w * dx0 * dx1
            s10 += w * dx1 * dx0
            s11 += w * dx1 * dx1
        if any_pair:
            c = _pd1(V_cusum0, t)[0] + llr
            _pd1(V_cusum, t)[0] = c if c > 0.0 else 0.0
        else:
            _pd1(V_cusum, t)[0] = _pd1(V_cusum0, t)[0]
        _pd2(V_x, t, 0)[0] = xs + sx0
        _pd2(V_x, t, 1)[0] = vs + sx1
        # P - k_bar P[0, :] + S - dx_bar dx_bar', symmetrised
        _pd3(V_p, t, 0, 0)[0] = p00 - sk0 * p00 + s00 - sx0 * sx0
        _pd3(V_p, t, 1, 1)[0] = p11 - sk1 * p01 + s11 - sx1 * sx1
        d = 0.5 * ((p01 - sk0 * p01 + s01 - sx0 * sx1) + (p01 - sk1 * p00 + s10 - sx1 * sx0))
        _pd3(V_p, t, 0, 1)[0] = d
        _pd3(V_p, t, 1, 0)[0] = d
        # the Hausman test against the motion model, and the CUSUM
        vr0 = _pd3(V_ref_p, t, 0, 0)[0]
        vr1 = _pd3(V_ref_p, t, 1, 1)[0]
        d = _max_nan(vr0 - _pd3(V_p, t, 0, 0)[0], min_fraction * vr0)
        _pu8(V_off, t)[0] = (_pd2(V_x, t, 0)[0] - _pd2(V_ref, t, 0)[0]) ** 2 > gamma * _max_nan(d, 1e-12)
        d = _max_nan(vr1 - _pd3(V_p, t, 1, 1)[0], min_fraction * vr1)
        _pu8(V_off, t)[0] = (_pu8(V_off, t)[0]
                             or (_pd2(V_x, t, 1)[0] - _pd2(V_ref, t, 1)[0]) ** 2 > gamma * _max_nan(d, 1e-12))
        _pu8(V_off, t)[0] = _pu8(V_off, t)[0] or _pd1(V_cusum, t)[0] > cusum_nats


cdef inline Py_ssize_t _argmax_row(_V V_a, Py_ssize_t t) noexcept nogil:
    """``np.argmax(a[t])`` of a non-empty row: the first largest value, or the first NaN."""
    cdef Py_ssize_t best = 0, m
    cdef double bv = _pd2(V_a, t, 0)[0], v
    if bv != bv:
        return 0
    for m in range(1, V_a.n[1]):
        v = _pd2(V_a, t, m)[0]
        if v != v:
            return m
        if v > bv:
            bv = v
            best = m
    return best


def lateral_frame(age, double seed_var, lat0, lat_p0,
                  double dt, double q, beta, z, r,
                  rm, bint per_detection, xp, pp,
                  cusum0, xs, ps, double gamma,
                  double min_fraction, double cusum_nats, bint has_hold, manoeuvre_prob,
                  xk, pk, double hold_prob, bint has_unresolved,
                  unresolved):
    """The whole frame of :class:`edge.track.roles.post.LateralSmoother` (``run``) for every track: the seeded
    lines' (``age`` 2) lateral speed variance capped at ``seed_var``, the line step (``_lateral_rows``) on the column
    views the role passes (``z[:, 0]``, ``r[:, 0, 0]``, ``rm[:, 0, 0]``, ``xp[:, 0]``, ``pp[:, 0, 0]``; the motion model's
    ``[x, vx]`` from ``xs``, ``ps``), then the restarts: a track is held on the motion model when the line
    disagrees, when its manoeuvring mode's probability exceeds ``hold_prob`` (``has_hold``; then with the
    lane-keeping mode's ``xk``, ``pk`` lateral speed) or when its carrying detection (largest weight, > 0.5) is
    ``unresolved`` (``has_unresolved``). Returns ``lat`` (T, 2), ``lat_p`` (T, 2, 2), ``cusum`` (T,); equal to the
    role's numpy path to rounding."""
    cdef _V V_age
    _aview(age, cnp.NPY_INT32, 1, False, False, &V_age, "age")
    cdef _V V_lat0
    _aview(lat0, cnp.NPY_FLOAT64, 2, False, False, &V_lat0, "lat0")
    cdef _V V_lat_p0
    _aview(lat_p0, cnp.NPY_FLOAT64, 3, False, False, &V_lat_p0, "lat_p0")
    cdef _V V_beta
    _aview(beta, cnp.NPY_FLOAT64, 2, False, False, &V_beta, "beta")
    cdef _V V_z
    _aview(z, cnp.NPY_FLOAT64, 2, False, False, &V_z, "z")
    cdef _V V_r
    _aview(r, cnp.NPY_FLOAT64, 3, False, False, &V_r, "r")
    cdef _V V_rm
    _aview(rm, cnp.NPY_FLOAT64, 3, False, False, &V_rm, "rm")
    cdef _V V_xp
    _aview(xp, cnp.NPY_FLOAT64, 2, False, False, &V_xp, "xp")
    cdef _V V_pp
    _aview(pp, cnp.NPY_FLOAT64, 3, False, False, &V_pp, "pp")
    cdef _V V_cusum0
    _aview(cusum0, cnp.NPY_FLOAT64, 1, False, False, &V_cusum0, "cusum0")
    cdef _V V_xs
    _aview(xs, cnp.NPY_FLOAT64, 2, False, False, &V_xs, "xs")
    cdef _V V_ps
    _aview(ps, cnp.NPY_FLOAT64, 3, False, False, &V_ps, "ps")
    cdef _V V_manoeuvre_prob
    _aview(manoeuvre_prob, cnp.NPY_FLOAT64, 1, False, False, &V_manoeuvre_prob, "manoeuvre_prob")
    cdef _V V_xk
    _aview(xk, cnp.NPY_FLOAT64, 2, False, False, &V_xk, "xk")
    cdef _V V_pk
    _aview(pk, cnp.NPY_FLOAT64, 3, False, False, &V_pk, "pk")
    cdef _V V_unresolved
    _aview(unresolved, cnp.NPY_BOOL, 1, False, False, &V_unresolved, "unresolved")
    cdef Py_ssize_t nt = V_beta.n[0], nm = V_beta.n[1], t, best
    lat_a = _empty2(cnp.NPY_FLOAT64, nt, 2)
    lat_p_a = _empty3(cnp.NPY_FLOAT64, nt, 2, 2)
    cusum_a = _empty1(cnp.NPY_FLOAT64, nt)
    off_a = _empty1(cnp.NPY_BOOL, nt)
    cdef _V V_x
    _aview(lat_a, cnp.NPY_FLOAT64, 2, True, True, &V_x, "x")
    cdef _V V_p
    _aview(lat_p_a, cnp.NPY_FLOAT64, 3, True, True, &V_p, "p")
    cdef _V V_cusum
    _aview(cusum_a, cnp.NPY_FLOAT64, 1, True, True, &V_cusum, "cusum")
    cdef _V V_off
    _aview(off_a, cnp.NPY_BOOL, 1, True, True, &V_off, "off")
    cdef bint o, h
    has_unresolved = has_unresolved and nm > 0
    # the column views z[:, 0], r[:, 0, 0], rm[:, 0, 0], xp[:, 0], pp[:, 0, 0], xs[:, ::2], ps[:, ::2, ::2]
    cdef _V zc = _sub(V_z, 1, 1), rc = _sub(V_r, 1, 1), rmc = _sub(V_rm, 1, 1), xpc = _sub(V_xp, 1, 1)
    cdef _V ppc = _sub(V_pp, 1, 1), xs2 = _sub(V_xs, 0, 2), ps2 = _sub(V_ps, 0, 2)
    with nogil:
        _lateral_rows(V_lat0, V_lat_p0, V_age, 2, seed_var, dt, q, V_beta, zc, rc, rmc, per_detection, xpc, ppc,
                      V_cusum0, xs2, ps2, gamma, min_fraction, cusum_nats, V_x, V_p, V_cusum, V_off)
        for t in range(nt):
            o = _pu8(V_off, t)[0]
            h = has_hold and _pd1(V_manoeuvre_prob, t)[0] > hold_prob
            o = o or h
            if has_unresolved and not o:
                best = _argmax_row(V_beta, t)
                o = _pu8(V_unresolved, best)[0] and _pd2(V_beta, t, best)[0] > 0.5
            if not o:
                continue
            _pd2(V_x, t, 0)[0] = _pd2(V_xs, t, 0)[0]
            _pd2(V_x, t, 1)[0] = _pd2(V_xs, t, 2)[0]
            _pd3(V_p, t, 0, 0)[0] = _pd3(V_ps, t, 0, 0)[0]
            _pd3(V_p, t, 0, 1)[0] = _pd3(V_ps, t, 0, 2)[0]
            _pd3(V_p, t, 1, 0)[0] = _pd3(V_ps, t, 2, 0)[0]
            _pd3(V_p, t, 1, 1)[0] = _pd3(V_ps, t, 2, 2)[0]
            _pd1(V_cusum, t)[0] = 0.0
            if h:
                _pd2(V_x, t, 1)[0] = _pd2(V_xk, t, 2)[0]
                _pd3(V_p, t, 1, 1)[0] = _pd3(V_pk, t, 2, 2)[0]
                _pd3(V_p, t, 0, 1)[0] = _pd3(V_pk, t, 0, 2)[0]
                _pd3(V_p, t, 1, 0)[0] = _pd3(V_pk, t, 0, 2)[0]
    return lat_a, lat_p_a, cusum_a


from libc.math cimport atan2, NAN

#: columns of :func:`publish_rows`' output
PUBLISH_COLUMNS = ("x_m", "y_m", "vx_mps", "vy_mps", "range_m", "radial_speed_mps", "az_rad", "length_m", "has_length",
                   "x_sd_m", "y_sd_m", "vx_sd_mps", "vy_sd_mps", "existence_probability", "motion_x_m")


cdef inline double _np_max(double a, double b) noexcept nogil:
    """numpy.maximum for one pair (a NaN in either gives NaN)."""
    return a if (a >= b or a != a) else b


def publish_rows(const double[:, :] x, const double[:, :, :] p, const cnp.int64_t[::1] idx, const double[:, :] lat,
                 const double[:, :, :] lat_p, const double[:] lat_cusum, const double[:] ext_var, const double[:] score,
                 const cnp.uint8_t[:] confirmed, bint smoother, double cusum_threshold, bint publish_length,
                 double confirmed_log_odds):
    """The numbers of :meth:`edge.track.tracker.PdafTracker.published` for the rows ``idx`` of the track table, in one
    call: ``(n, 15)`` float64 with the columns :data:`PUBLISH_COLUMNS` (``length_m`` is read where ``has_length`` is
    1). The same elementwise operations as the numpy reference (``lateral_blend``, ``hypot``, ``arctan2``, ``sqrt``,
    ``exp``; libm's): bit-identical."""
    out_arr = _empty2(cnp.NPY_FLOAT64, idx.shape[0], 15)
    _publish_rows(x, p, idx, lat, lat_p, lat_cusum, ext_var, score, confirmed, smoother, cusum_threshold,
                  publish_length, confirmed_log_odds, out_arr)
    return out_arr


cdef void _publish_rows(const double[:, :] x, const double[:, :, :] p, const cnp.int64_t[::1] idx,
                        const double[:, :] lat, const double[:, :, :] lat_p, const double[:] lat_cusum,
                        const double[:] ext_var, const double[:] score, const cnp.uint8_t[:] confirmed, bint smoother,
                        double cusum_threshold, bint publish_length, double confirmed_log_odds,
                        double[:, ::1] out) noexcept:
    """:func:`publish_rows` into ``out`` (n, 15)."""
    cdef Py_ssize_t n = idx.shape[0], k, i
    cdef bint blend = False
    cdef double p0 = 0.0
    if smoother:
        for k in range(n):
            if lat_cusum[idx[k]] != 0.0:
                blend = True
                break
        p0 = _blend_p0(cusum_threshold)
    for k in range(n):
        i = idx[k]
        _publish_row(x[i, 0], x[i, 1], x[i, 2], x[i, 3], p[i, 0, 0], p[i, 1, 1], p[i, 2, 2], p[i, 3, 3],
                     smoother, blend, p0, cusum_threshold, lat[i, 0] if smoother else 0.0,
                     lat_p[i, 0, 0] if smoother else 0.0, lat_cusum[i] if smoother else 0.0, publish_length,
                     ext_var[i], score[i], confirmed[i] != 0, confirmed_log_odds, &out[k, 0])


cdef inline double _blend_p0(double cusum_threshold) noexcept nogil:
    """The lateral blend's probability at a CUSUM of 0 (``kalman.lateral_blend``)."""
    cdef double t = cusum_threshold if cusum_threshold < 700.0 else 700.0
    return 1.0 / (1.0 + exp(t))


cdef inline void _publish_row(double xr, double x1, double x2, double x3, double p00, double p11, double p22,
                              double p33, bint smoother, bint blend, double p0, double cusum_threshold, double lat0,
                              double lat_p00, double cusum, bint publish_length, double ext_var, double score,
                              bint confirmed, double confirmed_log_odds, double* out) noexcept nogil:
    """One published track's 15 numbers (:data:`PUBLISH_COLUMNS`) from its table row, as ``PdafTracker.published``
    computes them."""
    cdef int c_i
    cdef double t, pr, w, xs, rho, num, d, lat_sd, lo
    cdef double pd[4]
    out[14] = xr
    if smoother:
        xs = lat0
        if blend:
            t = cusum_threshold - cusum
            if t > 700.0:
                t = 700.0
            pr = 1.0 / (1.0 + exp(t))
            w = (pr - p0) / (1.0 - p0)
            xs = xs + w * (xr - xs)
        out[0] = xs
    else:
        out[0] = xr
    out[1] = x1
    out[2] = x2
    out[3] = x3
    rho = hypot(out[0], out[1])
    num = out[0] * out[2] + out[1] * out[3]
    out[4] = rho
    out[5] = num / rho if rho > 0.0 else 0.0
    out[6] = atan2(out[0], out[1])
    if publish_length and hypot(out[2], out[3]) >= 1.0:
        out[7] = sqrt(12.0 * ext_var)
        out[8] = 1.0
    else:
        out[7] = NAN
        out[8] = 0.0
    pd[0], pd[1], pd[2], pd[3] = p00, p11, p22, p33
    for c_i in range(4):
        d = pd[c_i]
        out[9 + c_i] = sqrt(d if (d >= 0.0 or d != d) else 0.0)
    if smoother:
        d = lat_p00
        lat_sd = sqrt(d if (d >= 0.0 or d != d) else 0.0)
        out[9] = _np_max(lat_sd, out[9]) if cusum > 0.0 else lat_sd
    lo = score
    if confirmed:
        lo = _np_max(lo, confirmed_log_odds)
    if lo < -700.0:
        lo = -700.0
    elif lo > 700.0:
        lo = 700.0
    out[13] = 1.0 / (1.0 + exp(-lo))


cdef inline double _np_min(double a, double b) noexcept nogil:
    """numpy.minimum for one pair (a NaN in either gives NaN)."""
    return a if (a <= b or a != a) else b


def measure_predict(xp, Py_ssize_t t, bint with_rs, ext_var, double rs_var):
    """:meth:`edge.track.roles.measure.MeasurementModel.predict`'s numbers without the sensor noise (the SNR noise
    model), in one call: ``z_hat`` (N, n) and ``H`` (N, n, 4) of every row of ``xp`` (N, 4) (``kalman.
    measurement_prediction``), and for its first ``t`` rows the heading ``u`` (t, 2) and weight ``w`` (t,)
    (``measure.heading``) and the track's part of ``R`` (t, n, n): the extent ``ext_var`` along the heading
    (``measure.extent_cov``) and the radial-speed variance ``rs_var``. The same elementwise operations as the numpy
    reference: bit-identical."""
    cdef _V V_xp
    _aview(xp, cnp.NPY_FLOAT64, 2, False, False, &V_xp, "xp")
    cdef _V V_ext_var
    _aview(ext_var, cnp.NPY_FLOAT64, 1, False, False, &V_ext_var, "ext_var")
    cdef Py_ssize_t nrow = V_xp.n[0], i
    cdef int n = 3 if with_rs else 2
    zh_arr = _empty2(cnp.NPY_FLOAT64, nrow, n)
    h_arr = _zeros3(cnp.NPY_FLOAT64, nrow, n, 4)
    r_arr = _zeros3(cnp.NPY_FLOAT64, t, n, n)
    u_arr = _empty2(cnp.NPY_FLOAT64, t, 2)
    w_arr = _empty1(cnp.NPY_FLOAT64, t)
    cdef _V V_zh
    _aview(zh_arr, cnp.NPY_FLOAT64, 2, True, True, &V_zh, "zh")
    cdef _V V_h
    _aview(h_arr, cnp.NPY_FLOAT64, 3, True, True, &V_h, "h")
    cdef _V V_r
    _aview(r_arr, cnp.NPY_FLOAT64, 3, True, True, &V_r, "r")
    cdef _V V_u
    _aview(u_arr, cnp.NPY_FLOAT64, 2, True, True, &V_u, "u")
    cdef _V V_w
    _aview(w_arr, cnp.NPY_FLOAT64, 1, True, True, &V_w, "w")
    cdef double x, y, vx, vy, rho, vr, sp, d, u0, u1, wi, e
    for i in range(nrow):
        x, y, vx, vy = _pd2(V_xp, i, 0)[0], _pd2(V_xp, i, 1)[0], _pd2(V_xp, i, 2)[0], _pd2(V_xp, i, 3)[0]
        _pd3(V_h, i, 0, 0)[0] = 1.0
        _pd3(V_h, i, 1, 1)[0] = 1.0
        _pd2(V_zh, i, 0)[0] = x
        _pd2(V_zh, i, 1)[0] = y
        if with_rs:
            rho = hypot(x, y)
            rho = rho if (rho >= 1e-3 or rho != rho) else 1e-3
            vr = (x * vx + y * vy) / rho
            _pd2(V_zh, i, 2)[0] = vr
            _pd3(V_h, i, 2, 0)[0] = (vx - vr * x / rho) / rho
            _pd3(V_h, i, 2, 1)[0] = (vy - vr * y / rho) / rho
            _pd3(V_h, i, 2, 2)[0] = x / rho
            _pd3(V_h, i, 2, 3)[0] = y / rho
    for i in range(t):
        x, y, vx, vy = _pd2(V_xp, i, 0)[0], _pd2(V_xp, i, 1)[0], _pd2(V_xp, i, 2)[0], _pd2(V_xp, i, 3)[0]
        sp = hypot(vx, vy)
        d = sp if (sp >= 1e-9 or sp != sp) else 1e-9
        u0 = vx / d
        u1 = vy / d
        wi = sp if (sp >= 0.0 or sp != sp) else 0.0
        wi = wi if (wi <= 1.0 or wi != wi) else 1.0
        _pd2(V_u, i, 0)[0] = u0
        _pd2(V_u, i, 1)[0] = u1
        _pd1(V_w, i)[0] = wi
        e = _pd1(V_ext_var, i)[0]
        _pd3(V_r, i, 0, 0)[0] = 0.0 + e * (wi * (u0 * u0) + 1.0 * (1.0 - wi))
        _pd3(V_r, i, 0, 1)[0] = 0.0 + e * (wi * (u0 * u1) + 0.0 * (1.0 - wi))
        _pd3(V_r, i, 1, 0)[0] = 0.0 + e * (wi * (u1 * u0) + 0.0 * (1.0 - wi))
        _pd3(V_r, i, 1, 1)[0] = 0.0 + e * (wi * (u1 * u1) + 1.0 * (1.0 - wi))
        if with_rs:
            _pd3(V_r, i, 2, 2)[0] = rs_var
    return zh_arr, h_arr, r_arr, u_arr, w_arr


from libc.math cimport pow


def snr_noise(z, snr_db, double lo_db, double hi_db, double range_var0,
              double range_floor_var, double az_var0, double az_floor_var, double floor_var, int n):
    """``(M, n, n)`` sensor noise of each detection from its SNR (:func:`edge.track.kalman.snr_polar_noise` in the
    first two rows and columns, zeros elsewhere; the arguments are its sigmas squared): the same elementwise
    operations as numpy, bit-identical."""
    cdef _V V_z
    _aview(z, cnp.NPY_FLOAT64, 2, False, False, &V_z, "z")
    cdef _V V_snr_db
    _aview(snr_db, cnp.NPY_FLOAT64, 1, False, False, &V_snr_db, "snr_db")
    cdef Py_ssize_t m = V_z.n[0], i
    out_arr = _zeros3(cnp.NPY_FLOAT64, m, n, n)
    cdef _V V_out
    _aview(out_arr, cnp.NPY_FLOAT64, 3, True, True, &V_out, "out")
    cdef double v, snr, var_r, var_az, r, rs, s, c, rr2
    for i in range(m):
        v = _pd1(V_snr_db, i)[0]
        v = v if (v >= lo_db or v != v) else lo_db
        v = v if (v <= hi_db or v != v) else hi_db
        snr = pow(10.0, v / 10.0)
        var_r = range_var0 / snr + range_floor_var
        var_az = az_var0 / snr + az_floor_var
        r = hypot(_pd2(V_z, i, 0)[0], _pd2(V_z, i, 1)[0])
        rs = r if (r >= 1e-6 or r != r) else 1e-6
        s = _pd2(V_z, i, 0)[0] / rs
        c = _pd2(V_z, i, 1)[0] / rs
        rr2 = r * r * var_az
        _pd3(V_out, i, 0, 0)[0] = s * s * var_r + c * c * rr2 + floor_var
        _pd3(V_out, i, 1, 1)[0] = c * c * var_r + s * s * rr2 + floor_var
        _pd3(V_out, i, 0, 1)[0] = s * c * (var_r - rr2)
        _pd3(V_out, i, 1, 0)[0] = _pd3(V_out, i, 0, 1)[0]
    return out_arr


cdef inline void _height_add(_V* r, Py_ssize_t i, Py_ssize_t n, double x, double y, double vr, double dz,
                             double h_var) noexcept nogil:
    """``r[i] += h_var g g'``, ``g = dz / rho^2 (-x, -y[, vr])`` (``rho`` at least 1 m; the speed row when n = 3):
    :func:`edge.track.roles.measure.height_cov`'s operations."""
    cdef double rho = hypot(x, y)
    rho = rho if (rho >= 1.0 or rho != rho) else 1.0
    cdef double k = dz / (rho * rho)
    cdef double g0 = -x * k, g1 = -y * k
    cdef double s0 = h_var * g0, s1 = h_var * g1
    cdef double c = s0 * g1, g2
    _pd3(r[0], i, 0, 0)[0] = _pd3(r[0], i, 0, 0)[0] + s0 * g0
    _pd3(r[0], i, 0, 1)[0] = _pd3(r[0], i, 0, 1)[0] + c
    _pd3(r[0], i, 1, 0)[0] = _pd3(r[0], i, 1, 0)[0] + c
    _pd3(r[0], i, 1, 1)[0] = _pd3(r[0], i, 1, 1)[0] + s1 * g1
    if n == 3:
        g2 = vr * k
        c = s0 * g2
        _pd3(r[0], i, 0, 2)[0] = _pd3(r[0], i, 0, 2)[0] + c
        _pd3(r[0], i, 2, 0)[0] = _pd3(r[0], i, 2, 0)[0] + c
        c = s1 * g2
        _pd3(r[0], i, 1, 2)[0] = _pd3(r[0], i, 1, 2)[0] + c
        _pd3(r[0], i, 2, 1)[0] = _pd3(r[0], i, 2, 1)[0] + c
        _pd3(r[0], i, 2, 2)[0] = _pd3(r[0], i, 2, 2)[0] + (h_var * g2) * g2


def moving_expired(x, p, history,
                   age, misses, confirmed,
                   moved, score, double moving_gamma, double min_speed_mps,
                   bint by_score, cnp.uint32_t mask_n, int confirm_m, int confirm_n, double score_drop,
                   double keep_from_m, int keep_min_hits):
    """The confirmer's per-frame flags in one pass (:class:`edge.track.roles.confirm.Confirmer`): ``moved`` |= the
    velocity is significantly non-zero and fast enough (``update_moving``, in place), and the tentative tracks that
    can no longer confirm (``tentative_expired``; ``by_score``: Wald's lower threshold, else M of N with the far
    tracks' ``keep_*`` rule), returned as uint8 ``(T,)``. The same operations as numpy (``smallmat.inv_quad2``):
    bit-identical."""
    cdef _V V_x
    _aview(x, cnp.NPY_FLOAT64, 2, False, False, &V_x, "x")
    cdef _V V_p
    _aview(p, cnp.NPY_FLOAT64, 3, False, False, &V_p, "p")
    cdef _V V_history
    _aview(history, cnp.NPY_UINT32, 1, False, False, &V_history, "history")
    cdef _V V_age
    _aview(age, cnp.NPY_INT32, 1, False, False, &V_age, "age")
    cdef _V V_misses
    _aview(misses, cnp.NPY_INT32, 1, False, False, &V_misses, "misses")
    cdef _V V_confirmed
    _aview(confirmed, cnp.NPY_UINT8, 1, False, False, &V_confirmed, "confirmed")
    cdef _V V_moved
    _aview(moved, cnp.NPY_UINT8, 1, True, False, &V_moved, "moved")
    cdef _V V_score
    _aview(score, cnp.NPY_FLOAT64, 1, False, False, &V_score, "score")
    cdef Py_ssize_t t = V_x.n[0], i
    out_arr = _zeros1(cnp.NPY_UINT8, t)
    cdef _V V_out
    _aview(out_arr, cnp.NPY_UINT8, 1, True, True, &V_out, "out")
    cdef double v0, v1, num, d2v
    cdef int counts
    cdef bint e
    for i in range(t):
        v0, v1 = _pd2(V_x, i, 2)[0], _pd2(V_x, i, 3)[0]
        num = ((_pd3(V_p, i, 3, 3)[0] * v0 * v0 - (_pd3(V_p, i, 2, 3)[0] + _pd3(V_p, i, 3, 2)[0]) * v0 * v1)
               + _pd3(V_p, i, 2, 2)[0] * v1 * v1)
        d2v = num / (_pd3(V_p, i, 2, 2)[0] * _pd3(V_p, i, 3, 3)[0] - _pd3(V_p, i, 2, 3)[0] * _pd3(V_p, i, 3, 2)[0])
        if d2v > moving_gamma and hypot(v0, v1) >= min_speed_mps:
            _pu8(V_moved, i)[0] = 1
        if _pu8(V_confirmed, i)[0]:
            continue
        if by_score:
            e = _pd1(V_score, i)[0] <= score_drop
        else:
            counts = _popcount32(_pu32(V_history, i)[0] & mask_n)
            e = _pi32(V_age, i)[0] >= confirm_n and counts < confirm_m and _pi32(V_misses, i)[0] > 0
            if (e and keep_from_m > 0.0 and hypot(_pd2(V_x, i, 0)[0], _pd2(V_x, i, 1)[0]) > keep_from_m
                    and not counts < keep_min_hits):
                e = False
        _pu8(V_out, i)[0] = e
    return out_arr


cdef inline int _popcount32(cnp.uint32_t v) noexcept nogil:
    cdef int c = 0
    while v:
        v &= v - 1
        c += 1
    return c


def claimed_any(const double[:, :, ::1] v, const double[:, :, ::1] s, double gamma):
    """(M,) uint8: detections with ``v' S_t^-1 v <= gamma`` for some track ``t`` -- ``(mahalanobis_d2(v, s) <=
    gamma).any(axis=0)`` of :mod:`edge.track.pdaf` (the inverse of :func:`edge.track.smallmat.inv_det` and the terms
    of ``_quad``, bit-identical) in one pass: innovations ``v`` (T, M, n), one ``S`` (T, n, n) per track. n = 2, 3."""
    cdef Py_ssize_t nt = v.shape[0], nm = v.shape[1], n = v.shape[2]
    out_a = _zeros1(cnp.NPY_UINT8, nm)
    cdef cnp.uint8_t[::1] out = out_a
    if n != 2 and n != 3:
        raise ValueError("claimed_any: n must be 2 or 3")
    if s.shape[0] != nt or s.shape[1] != n or s.shape[2] != n:
        raise ValueError("claimed_any: s must be (T, n, n) with v's T and n")
    if nt:
        _claimed(v, &s[0, 0, 0], gamma, &out[0] if nm else NULL)
    return out_a


def claimed_any_polar(v, s_track, xy, double var_r, double var_az,
                      double floor_var, double gamma, double dz=0.0, double h_var=0.0):
    """:func:`claimed_any` with ``S = s_track`` plus the converted polar noise ``rr`` (:func:`polar_noise` at the
    ground points ``xy`` (T, >= 2; columns x, y) without its floor) on its position block and ``floor_var`` on that
    block's diagonal: the ``S`` of ``MeasurementModel.with_sensor`` (``s_track.copy()``, then ``+= rr`` after
    ``rr``'s diagonal ``+= floor_var``; with ``dz`` > 0 then the scatterer height's term at the states ``xy`` (T, 4),
    ``measure.height_cov``), the same operations."""
    cdef _V V_v
    _aview(v, cnp.NPY_FLOAT64, 3, False, True, &V_v, "v")
    cdef _V V_s_track
    _aview(s_track, cnp.NPY_FLOAT64, 3, False, True, &V_s_track, "s_track")
    cdef _V V_xy
    _aview(xy, cnp.NPY_FLOAT64, 2, False, False, &V_xy, "xy")
    cdef Py_ssize_t nt = V_v.n[0], nm = V_v.n[1], n = V_v.n[2], t, i, k
    cdef double rr[4]
    cdef double x, y, vr, rs
    out_a = _zeros1(cnp.NPY_UINT8, nm)
    cdef _V V_out
    _aview(out_a, cnp.NPY_UINT8, 1, True, True, &V_out, "out")
    if n != 2 and n != 3:
        raise ValueError("claimed_any_polar: n must be 2 or 3")
    if V_s_track.n[0] != nt or V_s_track.n[1] != n or V_s_track.n[2] != n:
        raise ValueError("claimed_any_polar: s_track must be (T, n, n) with v's T and n")
    if V_xy.n[0] != nt or V_xy.n[1] < 2:
        raise ValueError("claimed_any_polar: xy must be (T, >= 2) with v's T")
    if dz > 0.0 and h_var > 0.0 and n == 3 and V_xy.n[1] < 4:
        raise ValueError("claimed_any_polar: the height term with n = 3 needs the states (T, 4)")
    s_a = _empty3(cnp.NPY_FLOAT64, nt, n, n)
    cdef _V V_s
    _aview(s_a, cnp.NPY_FLOAT64, 3, True, True, &V_s, "s")
    for t in range(nt):
        _polar_noise(_pd2(V_xy, t, 0)[0], _pd2(V_xy, t, 1)[0], var_r, var_az, rr)
        for i in range(n):
            for k in range(n):
                if i < 2 and k < 2:
                    _pd3(V_s, t, i, k)[0] = _pd3(V_s_track, t, i, k)[0] + (
                        (rr[2 * i + k] + floor_var) if i == k else rr[2 * i + k])
                else:
                    _pd3(V_s, t, i, k)[0] = _pd3(V_s_track, t, i, k)[0]
        if dz > 0.0 and h_var > 0.0:
            x, y = _pd2(V_xy, t, 0)[0], _pd2(V_xy, t, 1)[0]
            vr = 0.0
            if n == 3:
                rs = hypot(x, y)
                rs = rs if (rs >= 1e-3 or rs != rs) else 1e-3
                vr = (x * _pd2(V_xy, t, 2)[0] + y * _pd2(V_xy, t, 3)[0]) / rs
            _height_add(&V_s, t, n, x, y, vr, dz, h_var)
    if nt:
        _claimed(v, <double*>V_s.data, gamma, <cnp.uint8_t*>V_out.data if nm else NULL)
    return out_a


cdef void _claimed(const double[:, :, ::1] v, const double* s, double gamma, cnp.uint8_t* out) noexcept nogil:
    """:func:`claimed_any`'s pass over the tracks, ``s`` the (T, n, n) ``S`` contiguous, ``out`` (M,) zeroed."""
    cdef Py_ssize_t nt = v.shape[0], nm = v.shape[1], n = v.shape[2], t, m, i
    cdef double a[9]
    cdef double si[9]
    cdef double d2
    for t in range(nt):
        for i in range(n * n):
            a[i] = s[t * n * n + i]
        if n == 3:
            _inv3(a, si)
        else:
            _inv2(a, si)
        for m in range(nm):
            if out[m]:
                continue
            if n == 3:
                d2 = _quad3(si, &v[t, m, 0])
            else:
                d2 = _quad2(si, &v[t, m, 0])
            if d2 <= gamma:
                out[m] = 1


cdef inline void _polar_noise(double x, double y, double var_r, double var_az, double* rr) noexcept nogil:
    """``rr`` (2, 2) row-major = ``J diag(var_r, var_az) J'`` at the ground point (x, y), the operations of
    ``kalman.polar_position_noise`` before its floor: ``J`` as there, ``jd = J diag(d)``,
    ``rr_ik = jd_i0 j_k0 + jd_i1 j_k1``."""
    cdef double r = hypot(x, y)
    cdef double rs = _np_max(r, 1e-6)
    cdef double sn = x / rs, cs = y / rs
    cdef double j00 = sn, j01 = r * cs, j10 = cs, j11 = (-r) * sn
    cdef double jd00 = j00 * var_r, jd01 = j01 * var_az, jd10 = j10 * var_r, jd11 = j11 * var_az
    rr[0] = jd00 * j00 + jd01 * j01
    rr[1] = jd00 * j10 + jd01 * j11
    rr[2] = jd10 * j00 + jd11 * j01
    rr[3] = jd10 * j10 + jd11 * j11


def polar_noise(xy, double var_r, double var_az, double floor_var):
    """``kalman.polar_position_noise`` (T, 2, 2) at the ground points ``xy`` (T, >= 2; columns x, y) with the
    variances ``var_r``, ``var_az`` and ``floor_var`` (the floor's variance) on the diagonal: the same operations."""
    cdef _V V_xy
    _aview(xy, cnp.NPY_FLOAT64, 2, False, False, &V_xy, "xy")
    cdef Py_ssize_t nt = V_xy.n[0], t
    if V_xy.n[1] < 2:
        raise ValueError("polar_noise: xy needs the columns x, y")
    rr_a = _empty3(cnp.NPY_FLOAT64, nt, 2, 2)
    cdef double* rr = _f64(rr_a)
    with nogil:
        for t in range(nt):
            _polar_noise(_pd2(V_xy, t, 0)[0], _pd2(V_xy, t, 1)[0], var_r, var_az, &rr[4 * t])
            rr[4 * t] = rr[4 * t] + floor_var
            rr[4 * t + 3] = rr[4 * t + 3] + floor_var
    return rr_a


def imm_seeded(mu, pm, p, Py_ssize_t k, double w,
               bint with_speed, double cy, double sy, double var_k, double speed_var,
               speed_vars=None):
    """:meth:`edge.track.roles.predict.ImmPredictor.seeded` in place on the table's last ``k`` rows: the mode
    probabilities ``(w, 1 - w)``; ``with_speed``: the lane-keeping mode's covariance with the road's speed variances
    (``cy``, ``sy`` the road yaw's cosine and sine, ``var_k`` across, the seeds' ``speed_var`` along, or per seed
    ``speed_vars`` (k,)) and the combined ``P = w P_keep + (1 - w) P``. The same operations as numpy."""
    cdef _V V_mu
    _aview(mu, cnp.NPY_FLOAT64, 2, True, False, &V_mu, "mu")
    cdef _V V_pm
    _aview(pm, cnp.NPY_FLOAT64, 4, True, False, &V_pm, "pm")
    cdef _V V_p
    _aview(p, cnp.NPY_FLOAT64, 3, True, False, &V_p, "p")
    cdef _V V_speed_vars
    if speed_vars is not None:
        _aview(speed_vars, cnp.NPY_FLOAT64, 1, False, False, &V_speed_vars, "speed_vars")
    cdef Py_ssize_t nt = V_mu.n[0], r, i, j
    cdef double sv, pk[16]
    if k < 0 or k > nt or V_pm.n[0] != nt or V_p.n[0] != nt or V_mu.n[1] != 2 or V_pm.n[1] != 2 \
            or V_pm.n[2] != 4 or V_pm.n[3] != 4 or V_p.n[1] != 4 or V_p.n[2] != 4 \
            or (speed_vars is not None and V_speed_vars.n[0] != k):
        raise ValueError("imm_seeded: inconsistent shapes")
    for r in range(nt - k, nt):
        _pd2(V_mu, r, 0)[0] = w
        _pd2(V_mu, r, 1)[0] = 1.0 - w
    if not with_speed:
        return
    for r in range(nt - k, nt):
        sv = _pd1(V_speed_vars, r - (nt - k))[0] if speed_vars is not None else speed_var
        for i in range(4):
            for j in range(4):
                pk[4 * i + j] = _pd3(V_p, r, i, j)[0]
        pk[10] = cy * cy * var_k + sy * sy * sv
        pk[15] = sy * sy * var_k + cy * cy * sv
        pk[11] = cy * sy * (var_k - sv)
        pk[14] = pk[11]
        for i in range(4):
            for j in range(4):
                _pd4(V_pm, r, 0, i, j)[0] = pk[4 * i + j]
                _pd3(V_p, r, i, j)[0] = w * pk[4 * i + j] + (1.0 - w) * _pd3(V_p, r, i, j)[0]


def mode_probabilities_match(c, lik, double floor,
                             xm, pm):
    """The IMM's step 4 and moment matching in one pass: ``mu`` (T, 2) of
    :func:`edge.track.imm.update_mode_probabilities` (``c``, ``lik`` (T, 2), ``floor``; the same operations, NaN
    handling of ``np.maximum`` included: bit-identical), then ``x`` (T, 4), ``p`` (T, 4, 4) of :func:`moment_match`
    with ``mu`` (equal to rounding) -> (mu, x, p)."""
    cdef _V V_c
    _aview(c, cnp.NPY_FLOAT64, 2, False, True, &V_c, "c")
    cdef _V V_lik
    _aview(lik, cnp.NPY_FLOAT64, 2, False, True, &V_lik, "lik")
    cdef _V V_xm
    _aview(xm, cnp.NPY_FLOAT64, 3, False, True, &V_xm, "xm")
    cdef _V V_pm
    _aview(pm, cnp.NPY_FLOAT64, 4, False, True, &V_pm, "pm")
    cdef Py_ssize_t nt = V_c.n[0], t
    if V_lik.n[0] != nt or V_xm.n[0] != nt or V_pm.n[0] != nt or V_c.n[1] != 2 or V_lik.n[1] != 2:
        raise ValueError("mode_probabilities_match: c, lik (T, 2), xm (T, 2, 4), pm (T, 2, 4, 4)")
    mu_a = _empty2(cnp.NPY_FLOAT64, nt, 2)
    x_a = _empty2(cnp.NPY_FLOAT64, nt, 4)
    p_a = _empty3(cnp.NPY_FLOAT64, nt, 4, 4)
    cdef _V V_mu
    _aview(mu_a, cnp.NPY_FLOAT64, 2, True, True, &V_mu, "mu")
    cdef _V V_x
    _aview(x_a, cnp.NPY_FLOAT64, 2, True, True, &V_x, "x")
    cdef _V V_p
    _aview(p_a, cnp.NPY_FLOAT64, 3, True, True, &V_p, "p")
    cdef double m0, m1, den
    with nogil:
        for t in range(nt):
            m0 = _pd2(V_c, t, 0)[0] * _pd2(V_lik, t, 0)[0]
            m1 = _pd2(V_c, t, 1)[0] * _pd2(V_lik, t, 1)[0]
            den = _max_nan(m0 + m1, 1e-300)
            m0 = _max_nan(m0 / den, floor)
            m1 = _max_nan(m1 / den, floor)
            den = m0 + m1
            _pd2(V_mu, t, 0)[0] = m0 / den
            _pd2(V_mu, t, 1)[0] = m1 / den
            _moment_match_row(&_pd3(V_xm, t, 0, 0)[0], &_pd4(V_pm, t, 0, 0, 0)[0], _pd2(V_mu, t, 0)[0],
                              _pd2(V_mu, t, 1)[0], &_pd2(V_x, t, 0)[0], &_pd3(V_p, t, 0, 0)[0])
    return mu_a, x_a, p_a


def reanchor_match(x, confirmed, hit,
                   gated, z, double speed_mps, bint receding_only,
                   double min_m, double max_m, double lateral_m, double height_k=0.0,
                   double min_range_m=0.0, double height_k_slow=-1.0):
    """The matches of ``edge.track.roles.post.Reanchor.run`` (the same operations): each confirmed track that
    missed (``confirmed``, ``hit`` (T,)) and the nearest detection no track validated (``gated`` (T, M)) that lies
    between ``min_m`` (exclusive) and ``max_m`` nearer than the track in ground range, within ``lateral_m`` across
    and ``speed_mps`` in radial speed, widened by ``Reanchor.speed_widening`` of ``height_k`` for a faster
    detection and of ``height_k_slow`` (< 0: ``height_k``) for a slower one, the detection at least
    ``min_range_m`` out (``receding_only``: receding tracks only); ``x`` (T, 4), ``z`` (M, 3) ->
    track rows ``i`` and detection rows ``j`` (int64, tracks in row order; the first of equally near)."""
    cdef _V V_x
    _aview(x, cnp.NPY_FLOAT64, 2, False, False, &V_x, "x")
    cdef _V V_confirmed
    _aview(confirmed, cnp.NPY_BOOL, 1, False, False, &V_confirmed, "confirmed")
    cdef _V V_hit
    _aview(hit, cnp.NPY_BOOL, 1, False, False, &V_hit, "hit")
    cdef _V V_gated
    _aview(gated, cnp.NPY_BOOL, 2, False, False, &V_gated, "gated")
    cdef _V V_z
    _aview(z, cnp.NPY_FLOAT64, 2, False, False, &V_z, "z")
    cdef Py_ssize_t nt = V_x.n[0], nm = V_z.n[0], t, m, k = 0
    if V_confirmed.n[0] != nt or V_hit.n[0] != nt or V_gated.n[0] != nt or V_gated.n[1] != nm \
            or V_z.n[1] < 3 or V_x.n[1] < 4:
        raise ValueError("reanchor_match: x (T, 4), confirmed, hit (T,), gated (T, M), z (M, 3)")
    for t in range(nt):  # the usual frame: no confirmed track missed
        if _pu8(V_confirmed, t)[0] and not _pu8(V_hit, t)[0]:
            break
    else:
        return _empty1(cnp.NPY_INT64, 0), _empty1(cnp.NPY_INT64, 0)
    cdef cnp.ndarray scratch = _empty1(cnp.NPY_INT64, 2 * nt + nm + 1)  # freed however the call ends
    cdef cnp.int64_t* io = <cnp.int64_t*> cnp.PyArray_DATA(scratch)
    cdef cnp.int64_t* jo = io + nt
    cdef cnp.int64_t* free = jo + nt
    cdef double rho_t, vr_t, nearer, best, kv, kvs, av, rt, rz, rz2, ht, hz, hzs, sgn, faster
    cdef Py_ssize_t arg
    if height_k_slow < 0.0:
        height_k_slow = height_k
    with nogil:
        for m in range(nm):
            free[m] = 1
        for t in range(nt):
            for m in range(nm):
                if _pu8_2(V_gated, t, m)[0]:
                    free[m] = 0
        for t in range(nt):
            if not _pu8(V_confirmed, t)[0] or _pu8(V_hit, t)[0]:
                continue
            rho_t = _np_max(hypot(_pd2(V_x, t, 0)[0], _pd2(V_x, t, 1)[0]), 1e-3)
            vr_t = (_pd2(V_x, t, 0)[0] * _pd2(V_x, t, 2)[0] + _pd2(V_x, t, 1)[0] * _pd2(V_x, t, 3)[0]) / rho_t
            if receding_only and not (vr_t > 0.0):
                continue
            av = fabs(vr_t)
            kv = height_k * av
            kvs = height_k_slow * av
            rt = _np_max(rho_t, 1.0)
            ht = kv / (rt * rt)
            sgn = -1.0 if vr_t < 0.0 else 1.0
            arg = -1
            best = -INFINITY
            for m in range(nm):
                if not free[m]:
                    continue
                rz = hypot(_pd2(V_z, m, 0)[0], _pd2(V_z, m, 1)[0])
                if not (rz >= min_range_m):
                    continue
                rz2 = _np_max(rz, 1.0) * _np_max(rz, 1.0)
                hz = kv / rz2
                hzs = kvs / rz2
                faster = sgn * (_pd2(V_z, m, 2)[0] - vr_t)
                if not (faster < speed_mps + sqrt(ht * ht + hz * hz)
                        and -faster < speed_mps + sqrt(ht * ht + hzs * hzs)):
                    continue
                nearer = rho_t - rz
                if (nearer > min_m and nearer <= max_m and fabs(_pd2(V_x, t, 0)[0] - _pd2(V_z, m, 0)[0]) < lateral_m
                        and nearer > best):
                    best = nearer
                    arg = m
            if arg >= 0:
                io[k] = t
                jo[k] = arg
                k += 1
    cdef cnp.ndarray i_a = _empty1(cnp.NPY_INT64, k)
    cdef cnp.ndarray j_a = _empty1(cnp.NPY_INT64, k)
    memcpy(cnp.PyArray_DATA(i_a), io, k * sizeof(cnp.int64_t))
    memcpy(cnp.PyArray_DATA(j_a), jo, k * sizeof(cnp.int64_t))
    return i_a, j_a


def delete_tests(x, p, misses, ext_var,
                 int delete_after_misses, double max_sigma_m, double min_range_m, double max_range_m,
                 double max_azimuth_rad, double merge_along_m, double merge_headway_s, double merge_extent_factor):
    """Per track the deletion tests of :meth:`edge.track.roles.delete.TrackDeleter.delete` (misses in a row, position
    sd, range and azimuth out of the field) and the inputs of the duplicate test: the position spreads of
    ``TrackDeleter._position_spread`` and the box half-lengths of ``SameVehicleBox.along_m``. Returns ``dead`` (T,)
    bool, ``pdx``, ``pdy``, ``along`` (T,); the same float64 operations as the numpy forms (identical)."""
    cdef _V V_x
    _aview(x, cnp.NPY_FLOAT64, 2, False, False, &V_x, "x")
    cdef _V V_p
    _aview(p, cnp.NPY_FLOAT64, 3, False, False, &V_p, "p")
    cdef _V V_misses
    _aview(misses, cnp.NPY_INT32, 1, False, False, &V_misses, "misses")
    cdef _V V_ext_var
    _aview(ext_var, cnp.NPY_FLOAT64, 1, False, False, &V_ext_var, "ext_var")
    cdef Py_ssize_t nt = V_x.n[0], t
    dead_a = _empty1(cnp.NPY_BOOL, nt)
    pdx_a = _empty1(cnp.NPY_FLOAT64, nt)
    pdy_a = _empty1(cnp.NPY_FLOAT64, nt)
    along_a = _empty1(cnp.NPY_FLOAT64, nt)
    cdef _V V_dead
    _aview(dead_a, cnp.NPY_BOOL, 1, True, True, &V_dead, "dead")
    cdef _V V_pdx
    _aview(pdx_a, cnp.NPY_FLOAT64, 1, True, True, &V_pdx, "pdx")
    cdef _V V_pdy
    _aview(pdy_a, cnp.NPY_FLOAT64, 1, True, True, &V_pdy, "pdy")
    cdef _V V_along
    _aview(along_a, cnp.NPY_FLOAT64, 1, True, True, &V_along, "along")
    cdef double rho, sig, sp, nrm, ux, uy, w, iso
    with nogil:
        for t in range(nt):
            rho = hypot(_pd2(V_x, t, 0)[0], _pd2(V_x, t, 1)[0])
            sig = sqrt(_np_max(_pd3(V_p, t, 0, 0)[0], _pd3(V_p, t, 1, 1)[0]))
            _pu8(V_dead, t)[0] = ((_pi32(V_misses, t)[0] >= delete_after_misses) or (sig > max_sigma_m)
                                  or (rho < min_range_m) or (rho > max_range_m)
                                  or fabs(atan2(_pd2(V_x, t, 0)[0], _pd2(V_x, t, 1)[0])) > max_azimuth_rad)
            sp = hypot(_pd2(V_x, t, 2)[0], _pd2(V_x, t, 3)[0])
            nrm = _np_max(sp, 1e-9)
            ux = _pd2(V_x, t, 2)[0] / nrm
            uy = _pd2(V_x, t, 3)[0] / nrm
            w = _np_min(_np_max(sp, 0.0), 1.0)
            iso = 1.0 - w
            _pd1(V_pdx, t)[0] = _pd3(V_p, t, 0, 0)[0] + _pd1(V_ext_var, t)[0] * (w * (ux * ux) + iso)
            _pd1(V_pdy, t)[0] = _pd3(V_p, t, 1, 1)[0] + _pd1(V_ext_var, t)[0] * (w * (uy * uy) + iso)
            _pd1(V_along, t)[0] = _np_max(_np_max(merge_along_m, merge_headway_s * sp),
                                          merge_extent_factor * sqrt(_pd1(V_ext_var, t)[0]))
    return dead_a, pdx_a, pdy_a, along_a


from libc.math cimport isfinite


cdef inline bint _column(object a, int type_num, Py_ssize_t n):
    """``a`` is a one-dimensional aligned array of ``type_num`` in native byte order (of length ``n`` if ``n >= 0``)."""
    cdef cnp.ndarray arr
    if not cnp.PyArray_Check(a):
        return False
    arr = <cnp.ndarray> a
    return (cnp.PyArray_NDIM(arr) == 1 and cnp.PyArray_TYPE(arr) == type_num and cnp.PyArray_ISNOTSWAPPED(arr)
            and cnp.PyArray_ISALIGNED(arr) and (n < 0 or cnp.PyArray_DIMS(arr)[0] == n))


cdef inline float _f32_at(cnp.ndarray a, Py_ssize_t i) noexcept nogil:
    return (<const float*> (cnp.PyArray_BYTES(a) + i * cnp.PyArray_STRIDES(a)[0]))[0]


def measurements(x, y, snr, vr, rng, bint use_radial_speed, pair=None, unresolved=None):
    """The float64 measurements of :meth:`edge.track.table.Measurements.from_detections` from the float32 columns
    ``x``, ``y``, ``snr``, ``vr``, ``rng`` of one size M: ``z`` (M, 3) ground x, y and the ground radial speed (``vr``
    times range over ground range, times 1 within 1e-6 m of the radar) with ``use_radial_speed``, else (M, 2), the
    SNR (M,) in float64, and the detections' extra columns ``pair`` (``resolved_pair``, int32 or int64: as int64, None
    when absent or without a pair) and ``unresolved`` (``unresolved_pair``, bool: None when absent or all false), as
    ``from_detections`` makes them. None (the numpy form handles the frame) when a column is not a float32 vector,
    a value is not finite, or an extra column is present in another form."""
    cdef Py_ssize_t n, i
    cdef double xi, yi, rho, ratio
    cdef cnp.ndarray ax, ay, asnr, avr, arng, pair_a
    cdef int pair_type = 0
    if not _column(x, cnp.NPY_FLOAT32, -1):
        return None
    n = cnp.PyArray_DIMS(<cnp.ndarray> x)[0]
    if not (_column(y, cnp.NPY_FLOAT32, n) and _column(snr, cnp.NPY_FLOAT32, n) and _column(vr, cnp.NPY_FLOAT32, n)
            and _column(rng, cnp.NPY_FLOAT32, n)):
        return None
    if pair is not None:
        if _column(pair, cnp.NPY_INT32, n):
            pair_type = cnp.NPY_INT32
        elif _column(pair, cnp.NPY_INT64, n):
            pair_type = cnp.NPY_INT64
        else:
            return None
    if unresolved is not None and not _column(unresolved, cnp.NPY_BOOL, n):
        return None
    ax, ay, asnr, avr, arng = x, y, snr, vr, rng
    with nogil:
        for i in range(n):
            if not (isfinite(_f32_at(ax, i)) and isfinite(_f32_at(ay, i)) and isfinite(_f32_at(asnr, i))
                    and isfinite(_f32_at(avr, i)) and isfinite(_f32_at(arng, i))):
                break
        else:
            i = n
    if i < n:
        return None
    cdef cnp.ndarray z_a = _empty2(cnp.NPY_FLOAT64, n, 3 if use_radial_speed else 2)
    cdef cnp.ndarray snr_a = _empty1(cnp.NPY_FLOAT64, n)
    cdef double* z = _f64(z_a)
    cdef double* s = _f64(snr_a)
    cdef Py_ssize_t nc = 3 if use_radial_speed else 2
    with nogil:
        for i in range(n):
            xi = _f32_at(ax, i)
            yi = _f32_at(ay, i)
            z[nc * i] = xi
            z[nc * i + 1] = yi
            s[i] = _f32_at(asnr, i)
            if use_radial_speed:
                rho = hypot(xi, yi)
                ratio = 1.0 if rho <= 1e-6 else <double> _f32_at(arng, i) / rho
                z[nc * i + 2] = <double> _f32_at(avr, i) * ratio
    return z_a, snr_a, _pair_column(pair, pair_type, n), _any_column(unresolved, n)


cdef object _pair_column(object pair, int pair_type, Py_ssize_t n):
    """``pair`` (int32 or int64, n) as int64 (the same array if int64), or None when no value is >= 0."""
    cdef cnp.ndarray a, out
    cdef Py_ssize_t i, k = 0
    cdef char* src
    cdef Py_ssize_t stride
    cdef cnp.int64_t* dst
    if pair is None:
        return None
    a = <cnp.ndarray> pair
    src, stride = cnp.PyArray_BYTES(a), cnp.PyArray_STRIDES(a)[0]
    if pair_type == cnp.NPY_INT64:
        for i in range(n):
            if (<cnp.int64_t*> (src + i * stride))[0] >= 0:
                return pair
        return None
    for i in range(n):
        if (<cnp.int32_t*> (src + i * stride))[0] >= 0:
            k += 1
    if k == 0:
        return None
    out = _empty1(cnp.NPY_INT64, n)
    dst = <cnp.int64_t*> cnp.PyArray_DATA(out)
    for i in range(n):
        dst[i] = (<cnp.int32_t*> (src + i * stride))[0]
    return out


cdef object _any_column(object col, Py_ssize_t n):
    """The bool column ``col`` (n), or None when it is None or all false."""
    cdef cnp.ndarray a
    cdef Py_ssize_t i
    if col is None:
        return None
    a = <cnp.ndarray> col
    for i in range(n):
        if (<cnp.npy_bool*> (cnp.PyArray_BYTES(a) + i * cnp.PyArray_STRIDES(a)[0]))[0]:
            return col
    return None


def seed_candidates(z, used, pair, bint has_pair,
                    xt, ext_var, double min_range_m, double max_range_m,
                    bint radial, double seed_min_speed_mps, double lateral_sigmas, double az_sigma_rad,
                    double merge_lateral_m, double lateral_cap_m, double merge_along_m, double headway_s,
                    double extent_factor, double merge_speed_mps):
    """The candidate seeds of :meth:`edge.track.roles.initiate.SeedInitiator.initiate`: detections not claimed by a
    track (or split from a merged one: ``pair >= 0`` with ``has_pair``), in the field's range, with ``radial`` at
    least ``seed_min_speed_mps`` of radial speed, and in no track's same-vehicle box at its speed (:func:`near_tracks`
    with the boxes of ``SameVehicleBox.lateral_m`` (``lateral_sigmas``, ``az_sigma_rad``, clipped to
    ``[merge_lateral_m, lateral_cap_m]``) and ``SameVehicleBox.along_m``). Returns ``(idx (k,) int64, resolved (M,)
    bool)``; the same float64 operations as the numpy form."""
    cdef _V V_z
    _aview(z, cnp.NPY_FLOAT64, 2, False, False, &V_z, "z")
    cdef _V V_used
    _aview(used, cnp.NPY_BOOL, 1, False, False, &V_used, "used")
    cdef _V V_pair
    _aview(pair, cnp.NPY_INT64, 1, False, False, &V_pair, "pair")
    cdef _V V_xt
    _aview(xt, cnp.NPY_FLOAT64, 2, False, False, &V_xt, "xt")
    cdef _V V_ext_var
    _aview(ext_var, cnp.NPY_FLOAT64, 1, False, False, &V_ext_var, "ext_var")
    cdef Py_ssize_t nm = V_z.n[0], nt = V_xt.n[0], m, t, k = 0
    resolved_a = _zeros1(cnp.NPY_BOOL, nm)
    idx_a = _empty1(cnp.NPY_INT64, nm)
    box_a = _empty2(cnp.NPY_FLOAT64, nt, 3)
    cdef _V V_resolved
    _aview(resolved_a, cnp.NPY_BOOL, 1, True, True, &V_resolved, "resolved")
    cdef _V V_idx
    _aview(idx_a, cnp.NPY_INT64, 1, True, True, &V_idx, "idx")
    cdef _V V_box
    _aview(box_a, cnp.NPY_FLOAT64, 2, True, True, &V_box, "box")
    cdef double r, lat, sp, rho_t
    cdef bint c, res
    with nogil:
        for t in range(nt):  # lateral_m, along_m, radial speed of each track
            r = hypot(_pd2(V_xt, t, 0)[0], _pd2(V_xt, t, 1)[0])
            lat = lateral_sigmas * r * az_sigma_rad
            _pd2(V_box, t, 0)[0] = _np_min(_np_max(lat, merge_lateral_m), lateral_cap_m)
            sp = hypot(_pd2(V_xt, t, 2)[0], _pd2(V_xt, t, 3)[0])
            _pd2(V_box, t, 1)[0] = _np_max(_np_max(merge_along_m, headway_s * sp),
                                           extent_factor * sqrt(_pd1(V_ext_var, t)[0]))
            if radial:
                rho_t = _np_max(hypot(_pd2(V_xt, t, 0)[0], _pd2(V_xt, t, 1)[0]), 1e-3)
                _pd2(V_box, t, 2)[0] = (_pd2(V_xt, t, 0)[0] * _pd2(V_xt, t, 2)[0]
                                        + _pd2(V_xt, t, 1)[0] * _pd2(V_xt, t, 3)[0]) / rho_t
        for m in range(nm):
            res = has_pair and _pi64(V_pair, m)[0] >= 0
            _pu8(V_resolved, m)[0] = res
            r = hypot(_pd2(V_z, m, 0)[0], _pd2(V_z, m, 1)[0])
            c = (not _pu8(V_used, m)[0] or res) and r >= min_range_m and r <= max_range_m
            if radial:
                c = c and fabs(_pd2(V_z, m, 2)[0]) >= seed_min_speed_mps
            if not c:
                continue
            for t in range(nt):
                lat = merge_lateral_m if res else _pd2(V_box, t, 0)[0]
                if (fabs(_pd2(V_xt, t, 0)[0] - _pd2(V_z, m, 0)[0]) < lat
                        and fabs(_pd2(V_xt, t, 1)[0] - _pd2(V_z, m, 1)[0]) < _pd2(V_box, t, 1)[0]
                        and (not radial or fabs(_pd2(V_box, t, 2)[0] - _pd2(V_z, m, 2)[0]) < merge_speed_mps)):
                    c = False
                    break
            if c:
                _pi64(V_idx, k)[0] = m
                k += 1
    return idx_a[:k], resolved_a


def carrying_pairs(beta, pair):
    """The numbers of :func:`edge.track.roles.delete.resolved_pairs` for weights ``beta`` (T, M >= 1): per track the
    detection of largest weight (``np.argmax``) and, when that weight exceeds 0.5, its resolved ``pair`` (M,), else
    -1. Returns ``(pair_of (T,) int64, best (T,) int64)``."""
    cdef _V V_beta
    _aview(beta, cnp.NPY_FLOAT64, 2, False, False, &V_beta, "beta")
    cdef _V V_pair
    _aview(pair, cnp.NPY_INT64, 1, False, False, &V_pair, "pair")
    cdef Py_ssize_t nt = V_beta.n[0], t, b
    if V_beta.n[1] == 0 or V_pair.n[0] != V_beta.n[1]:
        raise ValueError("carrying_pairs needs one pair value per detection and at least one detection")
    pair_a = _empty1(cnp.NPY_INT64, nt)
    best_a = _empty1(cnp.NPY_INT64, nt)
    cdef _V V_pair_of
    _aview(pair_a, cnp.NPY_INT64, 1, True, True, &V_pair_of, "pair_of")
    cdef _V V_best
    _aview(best_a, cnp.NPY_INT64, 1, True, True, &V_best, "best")
    with nogil:
        for t in range(nt):
            b = _argmax_row(V_beta, t)
            _pi64(V_best, t)[0] = b
            _pi64(V_pair_of, t)[0] = _pi64(V_pair, b)[0] if _pd2(V_beta, t, b)[0] > 0.5 else -1
    return pair_a, best_a


def count_hits(gated, age, hits,
               misses, history):
    """One frame of :meth:`edge.track.table.TrackTable.count` with ``hit = gated.any(axis=1)`` (``gated`` (T, M)):
    ``age`` and ``hits`` in place. Returns ``(hit (T,) bool, misses (T,) int32, history (T,) uint32)``, new arrays:
    misses 0 on a hit, else one more; the history shifted by one with bit 0 the hit."""
    cdef _V V_gated
    _aview(gated, cnp.NPY_BOOL, 2, False, False, &V_gated, "gated")
    cdef _V V_age
    _aview(age, cnp.NPY_INT32, 1, True, False, &V_age, "age")
    cdef _V V_hits
    _aview(hits, cnp.NPY_INT32, 1, True, False, &V_hits, "hits")
    cdef _V V_misses
    _aview(misses, cnp.NPY_INT32, 1, False, False, &V_misses, "misses")
    cdef _V V_history
    _aview(history, cnp.NPY_UINT32, 1, False, False, &V_history, "history")
    cdef Py_ssize_t nt = V_gated.n[0], nm = V_gated.n[1], t, m
    if V_age.n[0] != nt or V_hits.n[0] != nt or V_misses.n[0] != nt or V_history.n[0] != nt:
        raise ValueError("count_hits needs one row per track in every column")
    hit_a = _empty1(cnp.NPY_BOOL, nt)
    misses_a = _empty1(cnp.NPY_INT32, nt)
    history_a = _empty1(cnp.NPY_UINT32, nt)
    cdef _V V_hit
    _aview(hit_a, cnp.NPY_BOOL, 1, True, True, &V_hit, "hit")
    cdef _V V_mo
    _aview(misses_a, cnp.NPY_INT32, 1, True, True, &V_mo, "mo")
    cdef _V V_ho
    _aview(history_a, cnp.NPY_UINT32, 1, True, True, &V_ho, "ho")
    cdef bint h
    with nogil:
        for t in range(nt):
            h = False
            for m in range(nm):
                if _pu8_2(V_gated, t, m)[0]:
                    h = True
                    break
            _pu8(V_hit, t)[0] = h
            _pi32(V_age, t)[0] += 1
            _pi32(V_hits, t)[0] += h
            _pi32(V_mo, t)[0] = 0 if h else _pi32(V_misses, t)[0] + 1
            _pu32(V_ho, t)[0] = (_pu32(V_history, t)[0] << 1) | (<cnp.uint32_t>h)
    return hit_a, misses_a, history_a


cdef inline double _height_speed_sd(_V V_x, Py_ssize_t r, double height_k) noexcept nogil:
    """Confirmer.height_speed_sd of row ``r``: ``height_k |v_r| / rho^2``, ``v_r`` as kalman.measurement_prediction
    gives it, ``rho`` at least 1 m."""
    cdef double x = _pd2(V_x, r, 0)[0], y = _pd2(V_x, r, 1)[0], h = hypot(x, y)
    cdef double vr = (x * _pd2(V_x, r, 2)[0] + y * _pd2(V_x, r, 3)[0]) / _np_max(h, 1e-3)
    cdef double rho = _np_max(h, 1.0)
    return height_k * fabs(vr) / (rho * rho)


def confirm_ready(x, history, confirmed,
                  moved, score, int mode, double score_confirm,
                  cnp.uint32_t mask_n, int confirm_m, double block_along_m, double merge_lateral_m,
                  double merge_speed_mps, double block_lateral_m, double block_behind_m, double block_speed_mps,
                  double height_k=0.0):
    """The rows that :meth:`edge.track.roles.confirm.Confirmer.confirm` confirms this frame, in row order (a list of
    int): tentative, moved and passing the test (``mode`` 0: M of N, 1: score, 2: either), and not blocked by a
    confirmed track (``block_along_m`` > 0), its speed tests widened by ``height_k`` (m^2: the radar's height above
    the assumed scatterers times twice their height sd; :meth:`Confirmer.height_speed_sd`). The numpy reference's
    comparisons and arithmetic (``heading``'s libm ``hypot``, ``np.maximum``): the same rows."""
    cdef _V V_x
    _aview(x, cnp.NPY_FLOAT64, 2, False, False, &V_x, "x")
    cdef _V V_history
    _aview(history, cnp.NPY_UINT32, 1, False, False, &V_history, "history")
    cdef _V V_confirmed
    _aview(confirmed, cnp.NPY_UINT8, 1, False, False, &V_confirmed, "confirmed")
    cdef _V V_moved
    _aview(moved, cnp.NPY_UINT8, 1, False, False, &V_moved, "moved")
    cdef _V V_score
    _aview(score, cnp.NPY_FLOAT64, 1, False, False, &V_score, "score")
    cdef Py_ssize_t nt = V_x.n[0], r, k
    if (V_history.n[0] != nt or V_confirmed.n[0] != nt or V_moved.n[0] != nt or V_score.n[0] != nt
            or V_x.n[1] < 4):
        raise ValueError("confirm_ready needs one row per track in every column and x of width 4")
    cdef list out = []
    cdef bint ok, any_confirmed = False, blocked
    cdef double d0, d1, dv, sp, den, hr, hk, wide
    for r in range(nt):
        if _pu8(V_confirmed, r)[0]:
            any_confirmed = True
    for r in range(nt):
        if _pu8(V_confirmed, r)[0] or not _pu8(V_moved, r)[0]:
            continue
        if mode == 1:
            ok = _pd1(V_score, r)[0] >= score_confirm
        else:
            ok = _popcount32(_pu32(V_history, r)[0] & mask_n) >= confirm_m
            if mode == 2 and _pd1(V_score, r)[0] >= score_confirm:
                ok = True
        if not ok:
            continue
        if block_along_m > 0.0 and any_confirmed:
            blocked = False
            hr = _height_speed_sd(V_x, r, height_k)
            for k in range(nt):
                if not _pu8(V_confirmed, k)[0]:
                    continue
                d1 = _pd2(V_x, r, 1)[0] - _pd2(V_x, k, 1)[0]
                if not fabs(d1) < block_along_m:
                    continue
                d0 = _pd2(V_x, r, 0)[0] - _pd2(V_x, k, 0)[0]
                sp = hypot(_pd2(V_x, k, 2)[0], _pd2(V_x, k, 3)[0])
                den = _np_max(sp, 1e-9)
                dv = ((_pd2(V_x, r, 2)[0] - _pd2(V_x, k, 2)[0]) * (_pd2(V_x, k, 2)[0] / den)
                      + (_pd2(V_x, r, 3)[0] - _pd2(V_x, k, 3)[0]) * (_pd2(V_x, k, 3)[0] / den))
                hk = _height_speed_sd(V_x, k, height_k)
                wide = sqrt(hr * hr + hk * hk)
                if ((fabs(d0) < merge_lateral_m and fabs(dv) < merge_speed_mps + wide)
                        or (fabs(d0) < block_lateral_m and d1 > block_behind_m
                            and fabs(dv) < block_speed_mps + wide)):
                    blocked = True
                    break
            if blocked:
                continue
        out.append(r)
    return out




cdef inline bint _plain(cnp.ndarray a):
    """A bool or number array, C-contiguous, aligned, in native byte order, of 1 to 8 dimensions: its rows are one
    block of bytes, and its type number alone gives its dtype."""
    return (cnp.PyArray_ISCARRAY_RO(a) and 1 <= cnp.PyArray_NDIM(a) <= 8
            and cnp.PyArray_TYPE(a) <= cnp.NPY_CLONGDOUBLE)


def concat_rows(list olds, list news):
    """``[np.concatenate([a, b]) for a, b in zip(olds, news)]``: for two arrays of one dtype and row shape, a new
    array with ``a``'s rows then ``b``'s, copied; any other pair goes to ``np.concatenate``."""
    cdef Py_ssize_t i, j, nd
    cdef cnp.ndarray a, b, c
    cdef cnp.npy_intp dims[8]
    cdef bint same
    cdef list out = []
    if len(olds) != len(news):
        raise ValueError("concat_rows needs as many new parts as columns")
    for i in range(len(olds)):
        a, b = olds[i], news[i]
        if not cnp.PyArray_ISCARRAY_RO(b):
            b = np.ascontiguousarray(b)
        nd = cnp.PyArray_NDIM(a)
        same = (_plain(a) and _plain(b) and nd == cnp.PyArray_NDIM(b)
                and cnp.PyArray_TYPE(a) == cnp.PyArray_TYPE(b) and cnp.PyArray_EquivTypes(a.dtype, b.dtype))
        if same:
            for j in range(1, nd):
                if cnp.PyArray_DIMS(a)[j] != cnp.PyArray_DIMS(b)[j]:
                    same = False
        if not same:
            out.append(np.concatenate([a, b]))
            continue
        for j in range(nd):
            dims[j] = cnp.PyArray_DIMS(a)[j]
        dims[0] += cnp.PyArray_DIMS(b)[0]
        c = cnp.PyArray_EMPTY(<int>nd, dims, cnp.PyArray_TYPE(a), 0)
        memcpy(cnp.PyArray_BYTES(c), cnp.PyArray_BYTES(a), cnp.PyArray_NBYTES(a))
        memcpy(cnp.PyArray_BYTES(c) + cnp.PyArray_NBYTES(a), cnp.PyArray_BYTES(b), cnp.PyArray_NBYTES(b))
        out.append(c)
    return out


#: the track table's columns (``TrackTable._COLUMNS``' order): name, type number and row shape
_TABLE_COLUMNS = (
    ("x", cnp.NPY_FLOAT64, (4,)), ("p", cnp.NPY_FLOAT64, (4, 4)), ("track_id", cnp.NPY_INT32, ()),
    ("age", cnp.NPY_INT32, ()), ("hits", cnp.NPY_INT32, ()), ("misses", cnp.NPY_INT32, ()),
    ("history", cnp.NPY_UINT32, ()), ("confirmed", cnp.NPY_BOOL, ()), ("moved", cnp.NPY_BOOL, ()),
    ("ext_var", cnp.NPY_FLOAT64, ()), ("close_run", cnp.NPY_INT32, ()), ("score", cnp.NPY_FLOAT64, ()),
    ("xm", cnp.NPY_FLOAT64, (2, 4)), ("pm", cnp.NPY_FLOAT64, (2, 4, 4)), ("mu", cnp.NPY_FLOAT64, (2,)),
    ("lat", cnp.NPY_FLOAT64, (2,)), ("lat_p", cnp.NPY_FLOAT64, (2, 2)), ("lat_cusum", cnp.NPY_FLOAT64, ()))


def append_rows(tr, x, p, double ext_var, double keep_prob):
    """:meth:`edge.track.table.TrackTable.append` of ``k`` tentative tracks at ``x`` (k, 4), ``p`` (k, 4, 4) float64
    (any strides) to the table ``tr``: every column a new array, the old rows then the new ones (both IMM modes at the
    state with the probabilities ``(keep_prob, 1 - keep_prob)``, the straight-line filter at its lateral part). True
    when done; False (nothing changed) when a column or the states are not of the table's dtypes and shapes."""
    cdef Py_ssize_t n, k, r, i, j, m, c, nd
    cdef cnp.ndarray xa, pa, old, new
    cdef cnp.npy_intp dims[5]
    cdef const char* xb
    cdef const char* pb
    cdef Py_ssize_t xs0, xs1, ps0, ps1, ps2
    cdef char* dst
    cdef double* d
    cdef cnp.int32_t* di
    cdef int type_num
    cdef tuple shape
    if not (_column_nd(x, cnp.NPY_FLOAT64, 2) and _column_nd(p, cnp.NPY_FLOAT64, 3)):
        return False
    xa, pa = <cnp.ndarray> x, <cnp.ndarray> p
    k = cnp.PyArray_DIMS(xa)[0]
    if cnp.PyArray_DIMS(xa)[1] != 4 or cnp.PyArray_DIMS(pa)[0] != k or cnp.PyArray_DIMS(pa)[1] != 4 \
            or cnp.PyArray_DIMS(pa)[2] != 4:
        return False
    cdef list olds = [getattr(tr, spec[0]) for spec in _TABLE_COLUMNS]
    n = -1
    for c in range(len(_TABLE_COLUMNS)):
        type_num, shape = _TABLE_COLUMNS[c][1], _TABLE_COLUMNS[c][2]
        if not (cnp.PyArray_Check(olds[c]) and _plain(<cnp.ndarray> olds[c])
                and cnp.PyArray_ISNOTSWAPPED(<cnp.ndarray> olds[c])):
            return False
        old = <cnp.ndarray> olds[c]
        if cnp.PyArray_TYPE(old) != type_num or cnp.PyArray_NDIM(old) != 1 + len(shape):
            return False
        for i in range(len(shape)):
            if cnp.PyArray_DIMS(old)[1 + i] != shape[i]:
                return False
        if n < 0:
            n = cnp.PyArray_DIMS(old)[0]
        elif cnp.PyArray_DIMS(old)[0] != n:
            return False
    xb, xs0, xs1 = cnp.PyArray_BYTES(xa), cnp.PyArray_STRIDES(xa)[0], cnp.PyArray_STRIDES(xa)[1]
    pb, ps0 = cnp.PyArray_BYTES(pa), cnp.PyArray_STRIDES(pa)[0]
    ps1, ps2 = cnp.PyArray_STRIDES(pa)[1], cnp.PyArray_STRIDES(pa)[2]
    for c in range(len(_TABLE_COLUMNS)):
        old = <cnp.ndarray> olds[c]
        nd = cnp.PyArray_NDIM(old)
        for i in range(nd):
            dims[i] = cnp.PyArray_DIMS(old)[i]
        dims[0] = n + k
        new = cnp.PyArray_EMPTY(<int> nd, dims, cnp.PyArray_TYPE(old), 0)
        memcpy(cnp.PyArray_BYTES(new), cnp.PyArray_BYTES(old), cnp.PyArray_NBYTES(old))
        dst = cnp.PyArray_BYTES(new) + cnp.PyArray_NBYTES(old)
        d = <double*> dst
        di = <cnp.int32_t*> dst
        if c == 0:  # x
            for r in range(k):
                for j in range(4):
                    d[4 * r + j] = (<const double*> (xb + r * xs0 + j * xs1))[0]
        elif c == 1:  # p
            for r in range(k):
                for i in range(4):
                    for j in range(4):
                        d[16 * r + 4 * i + j] = (<const double*> (pb + r * ps0 + i * ps1 + j * ps2))[0]
        elif c == 2 or c == 5 or c == 10:  # track_id, misses, close_run: 0
            for r in range(k):
                di[r] = 0
        elif c == 3 or c == 4:  # age, hits: 1
            for r in range(k):
                di[r] = 1
        elif c == 6:  # history: this frame hit
            for r in range(k):
                (<cnp.uint32_t*> dst)[r] = 1
        elif c == 7 or c == 8:  # confirmed, moved
            for r in range(k):
                (<cnp.npy_bool*> dst)[r] = 0
        elif c == 9:  # ext_var
            for r in range(k):
                d[r] = ext_var
        elif c == 11 or c == 17:  # score, lat_cusum
            for r in range(k):
                d[r] = 0.0
        elif c == 12:  # xm: both modes at the state
            for r in range(k):
                for m in range(2):
                    for j in range(4):
                        d[8 * r + 4 * m + j] = (<const double*> (xb + r * xs0 + j * xs1))[0]
        elif c == 13:  # pm
            for r in range(k):
                for m in range(2):
                    for i in range(4):
                        for j in range(4):
                            d[32 * r + 16 * m + 4 * i + j] = (<const double*> (pb + r * ps0 + i * ps1 + j * ps2))[0]
        elif c == 14:  # mu
            for r in range(k):
                d[2 * r] = keep_prob
                d[2 * r + 1] = 1.0 - keep_prob
        elif c == 15:  # lat: x[:, 0::2]
            for r in range(k):
                d[2 * r] = (<const double*> (xb + r * xs0))[0]
                d[2 * r + 1] = (<const double*> (xb + r * xs0 + 2 * xs1))[0]
        elif c == 16:  # lat_p: p[:, 0::2, 0::2]
            for r in range(k):
                for i in range(2):
                    for j in range(2):
                        d[4 * r + 2 * i + j] = (<const double*> (pb + r * ps0 + 2 * i * ps1 + 2 * j * ps2))[0]
        setattr(tr, _TABLE_COLUMNS[c][0], new)
    return True


def take_rows(list cols, const cnp.intp_t[::1] rows):
    """``[a.take(rows, axis=0) for a in cols]`` for row indices ``rows`` in ``0..len(a) - 1``: the rows copied into new
    arrays; an array that is not one block of rows goes to ``take``."""
    cdef Py_ssize_t i, j, k, nd, nr = rows.shape[0], row_bytes, n0
    cdef cnp.ndarray a, c
    cdef cnp.npy_intp dims[8]
    cdef char* src
    cdef char* dst
    cdef list out = []
    for i in range(len(cols)):
        a = cols[i]
        if not _plain(a):
            out.append(a.take(np.asarray(rows), axis=0))
            continue
        nd = cnp.PyArray_NDIM(a)
        n0 = cnp.PyArray_DIMS(a)[0]
        for k in range(nr):
            if rows[k] < 0 or rows[k] >= n0:
                raise IndexError("take_rows: row index out of range")
        for j in range(nd):
            dims[j] = cnp.PyArray_DIMS(a)[j]
        dims[0] = nr
        c = cnp.PyArray_EMPTY(<int>nd, dims, cnp.PyArray_TYPE(a), 0)
        row_bytes = cnp.PyArray_NBYTES(a) // n0 if n0 else 0
        src, dst = cnp.PyArray_BYTES(a), cnp.PyArray_BYTES(c)
        for k in range(nr):
            memcpy(dst + k * row_bytes, src + rows[k] * row_bytes, row_bytes)
        out.append(c)
    return out


cdef extern from *:
    """
    /* object.__new__(cls) for a class whose instances object.__new__ makes (what tp_new_wrapper ends in) */
    static PyObject *ktr_new_instance(PyObject *cls) {
        static PyObject *no_args = NULL;
        if (no_args == NULL && (no_args = PyTuple_New(0)) == NULL)
            return NULL;
        return PyBaseObject_Type.tp_new((PyTypeObject *)cls, no_args, NULL);
    }
    """
    object ktr_new_instance(object cls)
    int PyObject_GenericSetAttr(object o, object name, object value) except -1


#: a published TrackState's ``__dict__`` with every value None, keys in field order (``publish_states`` copies it)
cdef dict _STATE_DICT = dict.fromkeys((
    "track_id", "x_m", "y_m", "vx_mps", "vy_mps", "range_m", "radial_speed_mps", "az_rad", "age_frames", "hits",
    "confirmed", "lane", "cls", "class_probability", "rcs_dbsm", "length_m", "x_sd_m", "y_sd_m", "vx_sd_mps",
    "vy_sd_mps", "existence_probability"))


def publish_states(type cls, const double[:, :] x, const double[:, :, :] p, const cnp.int64_t[::1] idx,
                   const double[:, :] lat, const double[:, :, :] lat_p, const double[:] lat_cusum,
                   const double[:] ext_var, const double[:] score, const cnp.uint8_t[:] confirmed, bint smoother,
                   double cusum_threshold, bint publish_length, double confirmed_log_odds,
                   const cnp.int32_t[:] track_id, const cnp.int32_t[:] age, const cnp.int32_t[:] hits):
    """The published tracks of the rows ``idx``: a tuple of ``cls`` instances (``TrackState``, made by
    ``object.__new__(cls)`` with the ``__dict__`` that ``PdafTracker.published`` writes, keys in field order), and the
    ``(n, 15)`` numbers of :func:`publish_rows` they were made from."""
    if cls.__new__ is not object.__new__:
        raise TypeError("publish_states: cls must be made by object.__new__")
    cdef Py_ssize_t n = idx.shape[0], k, i
    num_arr = _empty2(cnp.NPY_FLOAT64, n, 15)
    cdef double[:, ::1] num = num_arr
    _publish_rows(x, p, idx, lat, lat_p, lat_cusum, ext_var, score, confirmed, smoother, cusum_threshold,
                  publish_length, confirmed_log_odds, num)
    cdef list out = []
    cdef dict d
    for k in range(n):
        i = idx[k]
        o = ktr_new_instance(cls)
        d = _STATE_DICT.copy()  # every key in field order; lane, cls, class_probability and rcs_dbsm stay None
        d["track_id"] = track_id[i]
        d["x_m"] = num[k, 0]
        d["y_m"] = num[k, 1]
        d["vx_mps"] = num[k, 2]
        d["vy_mps"] = num[k, 3]
        d["range_m"] = num[k, 4]
        d["radial_speed_mps"] = num[k, 5]
        d["az_rad"] = num[k, 6]
        d["age_frames"] = age[i]
        d["hits"] = hits[i]
        d["confirmed"] = True if confirmed[i] else False
        if num[k, 8] != 0.0:
            d["length_m"] = num[k, 7]
        d["x_sd_m"] = num[k, 9]
        d["y_sd_m"] = num[k, 10]
        d["vx_sd_mps"] = num[k, 11]
        d["vy_sd_mps"] = num[k, 12]
        d["existence_probability"] = num[k, 13]
        PyObject_GenericSetAttr(o, "__dict__", d)
        out.append(o)
    return tuple(out), num_arr


cdef struct _Col:
    # a column of the track table: element (i, j, k) at data + i * s0 + j * s1 + k * s2
    const char* data
    Py_ssize_t s0, s1, s2


cdef bint _table_col(object tr, str name, int type_num, Py_ssize_t n, Py_ssize_t d1, Py_ssize_t d2,
                     _Col* out) except -1:
    """``tr.<name>`` as a column of ``n`` rows of ``type_num`` in native byte order, aligned, of row shape ``()``
    (``d1`` 0), ``(d1,)`` (``d2`` 0) or ``(d1, d2)``; False when it is not one."""
    cdef object a = getattr(tr, name)
    cdef cnp.ndarray arr
    cdef int nd = 1 + (d1 > 0) + (d2 > 0)
    if not _column_nd(a, type_num, nd):
        return False
    arr = <cnp.ndarray> a
    if cnp.PyArray_DIMS(arr)[0] != n or (d1 and cnp.PyArray_DIMS(arr)[1] != d1) \
            or (d2 and cnp.PyArray_DIMS(arr)[2] != d2):
        return False
    out.data = cnp.PyArray_BYTES(arr)
    out.s0 = cnp.PyArray_STRIDES(arr)[0]
    out.s1 = cnp.PyArray_STRIDES(arr)[1] if nd > 1 else 0
    out.s2 = cnp.PyArray_STRIDES(arr)[2] if nd > 2 else 0
    return True


cdef inline bint _column_nd(object a, int type_num, int nd):
    """``a`` is an ``nd``-dimensional aligned array of ``type_num`` in native byte order."""
    cdef cnp.ndarray arr
    if not cnp.PyArray_Check(a):
        return False
    arr = <cnp.ndarray> a
    return (cnp.PyArray_NDIM(arr) == nd and cnp.PyArray_TYPE(arr) == type_num and cnp.PyArray_ISNOTSWAPPED(arr)
            and cnp.PyArray_ISALIGNED(arr))


cdef inline double _f64_at(_Col c, Py_ssize_t i, Py_ssize_t j, Py_ssize_t k) noexcept nogil:
    return (<const double*> (c.data + i * c.s0 + j * c.s1 + k * c.s2))[0]


cdef inline cnp.int32_t _i32_at(_Col c, Py_ssize_t i) noexcept nogil:
    return (<const cnp.int32_t*> (c.data + i * c.s0))[0]


def publish_table(type cls, tr, bint tentative, long max_misses, bint smoother, double cusum_threshold,
                  bint publish_length, double confirmed_log_odds):
    """:meth:`edge.track.tracker.PdafTracker.published` read straight from the track table ``tr``: the rows with at
    most ``max_misses`` misses (confirmed ones only unless ``tentative``), in row order, as ``cls`` instances
    (``TrackState``; the ``__dict__`` of :func:`publish_states`), and their motion-model x (n,) (None when no row is
    published). None when a column of ``tr`` is not of the table's dtypes and shapes (``publish_states`` then)."""
    if cls.__new__ is not object.__new__:
        raise TypeError("publish_table: cls must be made by object.__new__")
    cdef Py_ssize_t nt = len(tr), n = 0, k, i
    cdef _Col x, p, lat, lat_p, lat_cusum, ext_var, score, confirmed, misses, track_id, age, hits
    if not (_table_col(tr, "x", cnp.NPY_FLOAT64, nt, 4, 0, &x) and _table_col(tr, "p", cnp.NPY_FLOAT64, nt, 4, 4, &p)
            and _table_col(tr, "lat", cnp.NPY_FLOAT64, nt, 2, 0, &lat)
            and _table_col(tr, "lat_p", cnp.NPY_FLOAT64, nt, 2, 2, &lat_p)
            and _table_col(tr, "lat_cusum", cnp.NPY_FLOAT64, nt, 0, 0, &lat_cusum)
            and _table_col(tr, "ext_var", cnp.NPY_FLOAT64, nt, 0, 0, &ext_var)
            and _table_col(tr, "score", cnp.NPY_FLOAT64, nt, 0, 0, &score)
            and _table_col(tr, "confirmed", cnp.NPY_BOOL, nt, 0, 0, &confirmed)
            and _table_col(tr, "misses", cnp.NPY_INT32, nt, 0, 0, &misses)
            and _table_col(tr, "track_id", cnp.NPY_INT32, nt, 0, 0, &track_id)
            and _table_col(tr, "age", cnp.NPY_INT32, nt, 0, 0, &age)
            and _table_col(tr, "hits", cnp.NPY_INT32, nt, 0, 0, &hits)):
        return None
    cdef cnp.ndarray rows_a = _empty1(cnp.NPY_INTP, nt)  # scratch (freed however the call ends)
    cdef Py_ssize_t* rows = <Py_ssize_t*> cnp.PyArray_DATA(rows_a)
    cdef bint blend = False, conf
    for i in range(nt):
        if (tentative or confirmed.data[i * confirmed.s0]) and _i32_at(misses, i) <= max_misses:
            rows[n] = i
            n += 1
            if smoother and _f64_at(lat_cusum, i, 0, 0) != 0.0:
                blend = True
    if n == 0:
        return (), None
    cdef double p0 = _blend_p0(cusum_threshold) if smoother else 0.0
    cdef double num[15]
    cdef cnp.ndarray mx_a = _empty1(cnp.NPY_FLOAT64, n)
    cdef double* mx = _f64(mx_a)
    cdef list out = []
    cdef dict d
    for k in range(n):
        i = rows[k]
        conf = confirmed.data[i * confirmed.s0] != 0
        _publish_row(_f64_at(x, i, 0, 0), _f64_at(x, i, 1, 0), _f64_at(x, i, 2, 0), _f64_at(x, i, 3, 0),
                     _f64_at(p, i, 0, 0), _f64_at(p, i, 1, 1), _f64_at(p, i, 2, 2), _f64_at(p, i, 3, 3), smoother,
                     blend, p0, cusum_threshold, _f64_at(lat, i, 0, 0) if smoother else 0.0,
                     _f64_at(lat_p, i, 0, 0) if smoother else 0.0, _f64_at(lat_cusum, i, 0, 0) if smoother else 0.0,
                     publish_length, _f64_at(ext_var, i, 0, 0), _f64_at(score, i, 0, 0), conf, confirmed_log_odds,
                     num)
        mx[k] = num[14]
        o = ktr_new_instance(cls)
        d = _STATE_DICT.copy()  # every key in field order; lane, cls, class_probability and rcs_dbsm stay None
        d["track_id"] = _i32_at(track_id, i)
        d["x_m"] = num[0]
        d["y_m"] = num[1]
        d["vx_mps"] = num[2]
        d["vy_mps"] = num[3]
        d["range_m"] = num[4]
        d["radial_speed_mps"] = num[5]
        d["az_rad"] = num[6]
        d["age_frames"] = _i32_at(age, i)
        d["hits"] = _i32_at(hits, i)
        d["confirmed"] = True if conf else False
        if num[8] != 0.0:
            d["length_m"] = num[7]
        d["x_sd_m"] = num[9]
        d["y_sd_m"] = num[10]
        d["vx_sd_mps"] = num[11]
        d["vy_sd_mps"] = num[12]
        d["existence_probability"] = num[13]
        PyObject_GenericSetAttr(o, "__dict__", d)
        out.append(o)
    return tuple(out), mx_a


def seed_states(seeds, r, bint with_rs, double cy, double sy, double var_u,
                double var_along, double var_speed):
    """New tracks' states ``x0`` (k, 4) and covariances ``p0`` (k, 4, 4) at the seeds (k, n; x, y[, radial speed]) with
    position noise ``r`` (k, 2, 2), as :meth:`edge.track.roles.initiate.SeedInitiator.seed_states_numpy`: with a radial
    speed (``with_rs``) the speed along the road (``cy``, ``sy``: the road yaw's cosine and sine) from it, variances
    ``var_along`` along and ``var_u`` across, else (and for a seed with ``|e_s . p| <= 1``) speed 0 and ``var_speed``.
    The same operations in numpy's order. Returns ``(x0, p0, var_s, all_along)``: the seeds' speed variance along the
    road (k,) and whether every seed took ``var_along``."""
    cdef _V V_seeds
    _aview(seeds, cnp.NPY_FLOAT64, 2, False, False, &V_seeds, "seeds")
    cdef _V V_r
    _aview(r, cnp.NPY_FLOAT64, 3, False, False, &V_r, "r")
    cdef Py_ssize_t k = V_seeds.n[0], i
    if V_r.n[0] != k or V_r.n[1] < 2 or V_r.n[2] < 2 or V_seeds.n[1] < (3 if with_rs else 2):
        raise ValueError("seed_states: one r (2, 2) per seed, seeds with x, y[, radial speed]")
    x_a = _zeros2(cnp.NPY_FLOAT64, k, 4)
    p_a = _zeros3(cnp.NPY_FLOAT64, k, 4, 4)
    vs_a = _empty1(cnp.NPY_FLOAT64, k)
    cdef _V V_x0
    _aview(x_a, cnp.NPY_FLOAT64, 2, True, True, &V_x0, "x0")
    cdef _V V_p0
    _aview(p_a, cnp.NPY_FLOAT64, 3, True, True, &V_p0, "p0")
    cdef _V V_var_s
    _aview(vs_a, cnp.NPY_FLOAT64, 1, True, True, &V_var_s, "var_s")
    cdef double proj, rho, v_s, vs
    cdef bint all_along = True
    for i in range(k):
        _pd2(V_x0, i, 0)[0] = _pd2(V_seeds, i, 0)[0]
        _pd2(V_x0, i, 1)[0] = _pd2(V_seeds, i, 1)[0]
        _pd3(V_p0, i, 0, 0)[0] = _pd3(V_r, i, 0, 0)[0]
        _pd3(V_p0, i, 0, 1)[0] = _pd3(V_r, i, 0, 1)[0]
        _pd3(V_p0, i, 1, 0)[0] = _pd3(V_r, i, 1, 0)[0]
        _pd3(V_p0, i, 1, 1)[0] = _pd3(V_r, i, 1, 1)[0]
        if not with_rs:
            _pd3(V_p0, i, 2, 2)[0] = var_speed
            _pd3(V_p0, i, 3, 3)[0] = var_speed
            _pd1(V_var_s, i)[0] = var_speed
            continue
        proj = cy * _pd2(V_seeds, i, 1)[0] - sy * _pd2(V_seeds, i, 0)[0]
        rho = hypot(_pd2(V_seeds, i, 0)[0], _pd2(V_seeds, i, 1)[0])
        if fabs(proj) > 1.0:
            v_s = _pd2(V_seeds, i, 2)[0] * rho / proj
            vs = var_along
        else:
            v_s = 0.0
            vs = var_speed
            all_along = False
        _pd1(V_var_s, i)[0] = vs
        _pd2(V_x0, i, 2)[0] = (-sy) * v_s
        _pd2(V_x0, i, 3)[0] = cy * v_s
        _pd3(V_p0, i, 2, 2)[0] = cy * cy * var_u + sy * sy * vs
        _pd3(V_p0, i, 3, 3)[0] = sy * sy * var_u + cy * cy * vs
        _pd3(V_p0, i, 2, 3)[0] = cy * sy * (var_u - vs)
        _pd3(V_p0, i, 3, 2)[0] = _pd3(V_p0, i, 2, 3)[0]
    return x_a, p_a, vs_a, all_along
