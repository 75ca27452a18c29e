# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Pairing kernel (edge.lane.pairs.PairStage): Lim's four-segment pairing, steps 1-4 of
edge.dsp.pairing.pair_beats (its numpy reference) in one pass.

1. every (fast up, fast down) peak pair solves ``[a0 b0; a1 b1] [R; v] = [f0; f1]`` (float64, the reference's
   operations in its order: ``(f0 b1 - f1 b0) / det``, ``(a0 f1 - a1 f0) / det``);
2. candidates outside the range and speed limits are dropped;
3. the nearest slow-up and slow-down peak to the predictions ``R a_k + v b_k`` (of two at the same distance, the lower
   frequency) must lie within the tolerance (the near tolerance up to ``near_range_m``);
4. the confirmed candidates are accepted greedily by ``(d2 / t2)^2 + (d3 / t3)^2`` (stable order); one sharing more
   than ``max_shared`` peaks with accepted pairs is skipped; an accepted pair sharing more than ``max_shared`` peaks
   with the others, one of them at another speed (beyond ``ghost_speed_mps``) whose partners agree with each other,
   is dropped.

Step 5 (the least-squares refinement over the four frequencies) is left to the caller: the reference's matrix
products go through BLAS, whose summation order the kernel could not match bit for bit.
"""

cimport cython
cimport numpy as cnp
from libc.math cimport fabs, sqrt
from libc.stdlib cimport malloc, free
from libc.string cimport memcpy

import numpy as np

cnp.import_array()

include "_arrays.pxi"
include "_alloc.pxi"


cdef inline int _nearest(const double *g, const int *k, int n, double p, double *dist) noexcept nogil:
    """Index of the peak of sorted frequencies ``g`` (original indices ``k``) nearest ``p``; the lower on a tie."""
    cdef int lo = 0, hi = n, mid
    cdef double d, e
    while lo < hi:  # bisect_left
        mid = (lo + hi) >> 1
        if g[mid] < p:
            lo = mid + 1
        else:
            hi = mid
    if lo == 0:
        dist[0] = fabs(p - g[0])
        return k[0]
    if lo == n:
        dist[0] = fabs(p - g[n - 1])
        return k[n - 1]
    d = fabs(p - g[lo - 1])
    e = fabs(p - g[lo])
    if e < d:
        dist[0] = e
        return k[lo]
    dist[0] = d
    return k[lo - 1]


cdef void _sort_by_freq(const double *f, int n, double *g, int *k) noexcept nogil:
    """``g`` = ``f`` (n) sorted ascending, ``k`` the original indices (ties by index: insertion sort, stable)."""
    cdef int i, j
    cdef double x
    for i in range(n):
        x = f[i]
        j = i
        while j > 0 and g[j - 1] > x:
            g[j] = g[j - 1]
            k[j] = k[j - 1]
            j -= 1
        g[j] = x
        k[j] = i


@cython.cdivision(True)
def pair(const double[::1] f0, const double[::1] f1, const double[::1] f2, const double[::1] f3,
         const double[::1] coef, double min_range_m, double max_range_m, double max_speed_mps,
         double tol2, double tol3, double near_tol2, double near_tol3, double near_range_m,
         int max_shared, double ghost_speed_mps):
    """Steps 1-4 of ``pair_beats``. ``coef``: (a0, a1, a2, a3, b0, b1, b2, b3); ``near_range_m`` <= 0: no near
    tolerance. Returns ``(rows (n, 4) int64, n_candidates, n_ghosts)``: the accepted pairs' peak indices in
    acceptance order."""
    if coef.shape[0] != 8:
        raise ValueError("coef needs 8 values")
    return _pair_core(&f0[0], &f1[0], &f2[0], &f3[0], f0.shape[0], f1.shape[0], f2.shape[0], f3.shape[0], &coef[0],
                      min_range_m, max_range_m, max_speed_mps, tol2, tol3, near_tol2, near_tol3, near_range_m,
                      max_shared, ghost_speed_mps, False)


def pair_frame(tuple freqs, coef_a, double min_range_m, double max_range_m, double max_speed_mps,
               double tol2, double tol3, double near_tol2, double near_tol3, double near_range_m,
               int max_shared, double ghost_speed_mps, tuple bins=None):
    """:func:`pair` of the four segments' frequencies ``freqs`` (any 1-D arrays: as float64 C-contiguous arrays,
    read through the numpy C API). Returns ``(rows, n_candidates, n_ghosts, fm, pk)``: :func:`pair`'s outputs, the
    accepted pairs' frequencies ``fm`` (n, 4) float64 (each segment's peak ``rows[:, k]``) and their FFT bins ``pk``
    (n, 4) int64 from ``bins`` (the segments' int64 arrays); ``pk`` None without ``bins`` or when one is not a 1-D
    int64 array of its segment's length."""
    if len(freqs) != 4 or (bins is not None and len(bins) != 4):
        raise ValueError("four segments needed")
    f = (_as_c(freqs[0], cnp.NPY_FLOAT64), _as_c(freqs[1], cnp.NPY_FLOAT64), _as_c(freqs[2], cnp.NPY_FLOAT64),
         _as_c(freqs[3], cnp.NPY_FLOAT64))
    cdef Py_ssize_t n0 = len(f[0]), n1 = len(f[1]), n2 = len(f[2]), n3 = len(f[3])
    cdef const double *coef = <const double *>_data(coef_a, cnp.NPY_FLOAT64, 8, False, "coef")
    out = _pair_core(<const double *>_data(f[0], cnp.NPY_FLOAT64, n0, False, "f0"),
                     <const double *>_data(f[1], cnp.NPY_FLOAT64, n1, False, "f1"),
                     <const double *>_data(f[2], cnp.NPY_FLOAT64, n2, False, "f2"),
                     <const double *>_data(f[3], cnp.NPY_FLOAT64, n3, False, "f3"), <int>n0, <int>n1, <int>n2,
                     <int>n3, coef, min_range_m, max_range_m, max_speed_mps, tol2, tol3, near_tol2, near_tol3,
                     near_range_m, max_shared, ghost_speed_mps, True)
    cdef Py_ssize_t i, k, n = len(out[0])
    cdef const long long *rows
    cdef const long long *bk
    cdef long long *o
    cdef Py_ssize_t nk[4]
    nk[0], nk[1], nk[2], nk[3] = n0, n1, n2, n3
    pk = None
    cdef bint ok = bins is not None
    if ok:
        for k in range(4):
            b = bins[k]
            if not (cnp.PyArray_Check(b) and cnp.PyArray_NDIM(<cnp.ndarray>b) == 1
                    and cnp.PyArray_TYPE(<cnp.ndarray>b) == cnp.NPY_INT64 and cnp.PyArray_DIM(<cnp.ndarray>b, 0) == nk[k]):
                ok = False
    if ok:
        pk = _empty2(cnp.NPY_INT64, n, 4)
        o = <long long *>cnp.PyArray_DATA(<cnp.ndarray>pk)
        rows = <const long long *>cnp.PyArray_DATA(<cnp.ndarray>out[0])
        for k in range(4):
            b = _as_c(bins[k], cnp.NPY_INT64)
            bk = <const long long *>cnp.PyArray_DATA(<cnp.ndarray>b)
            for i in range(n):
                o[4 * i + k] = bk[rows[4 * i + k]]
    return out + (pk,)


@cython.cdivision(True)
cdef tuple _pair_core(const double *f0, const double *f1, const double *f2, const double *f3, int n0, int n1,
                      int n2, int n3, const double *coef, double min_range_m, double max_range_m, double max_speed_mps,
                      double tol2, double tol3, double near_tol2, double near_tol3, double near_range_m,
                      int max_shared, double ghost_speed_mps, bint want_fm):
    """:func:`pair` on raw pointers; with ``want_fm`` also the accepted pairs' frequencies (n, 4) float64."""
    cdef double a0 = coef[0], a1 = coef[1], a2 = coef[2], a3 = coef[3]
    cdef double b0 = coef[4], b1 = coef[5], b2 = coef[6], b3 = coef[7]
    cdef double det = a0 * b1 - a1 * b0
    cdef bint use_near = near_range_m > 0
    cdef int n_cand = 0, n_conf = 0, i0, i1, j2, j3, i, j, l, n, kk, n_keep, s
    cdef double r, v, p, d2, d3, t2, t3, e2, e3, x0b1, a1x0, c
    cdef int nmax = n0 * n1
    cdef double *g2 = <double *>malloc((n2 + 1) * sizeof(double))
    cdef double *g3 = <double *>malloc((n3 + 1) * sizeof(double))
    cdef int *k2 = <int *>malloc((n2 + 1) * sizeof(int))
    cdef int *k3 = <int *>malloc((n3 + 1) * sizeof(int))
    cdef int *rows = <int *>malloc((4 * nmax + 4) * sizeof(int))
    cdef double *vel = <double *>malloc((nmax + 1) * sizeof(double))
    cdef double *cost = <double *>malloc((nmax + 1) * sizeof(double))
    cdef int *order = <int *>malloc((nmax + 1) * sizeof(int))
    cdef int *used = <int *>malloc((n0 + n1 + n2 + n3 + 1) * sizeof(int))
    cdef int *keep = <int *>malloc((nmax + 1) * sizeof(int))
    cdef int *shared = <int *>malloc((nmax + 1) * sizeof(int))
    cdef int *ghost = <int *>malloc((nmax + 1) * sizeof(int))
    cdef int *u0
    cdef int *u1
    cdef int *u2
    cdef int *u3
    cdef int *pa
    cdef int *pb
    cdef int n_out, max_sh, sh, found
    cdef bint m_ij, hit
    cdef long long[:, ::1] o
    cdef double *fm = NULL
    if (g2 == NULL or g3 == NULL or k2 == NULL or k3 == NULL or rows == NULL or vel == NULL or cost == NULL
            or order == NULL or used == NULL or keep == NULL or shared == NULL or ghost == NULL):
        free(g2); free(g3); free(k2); free(k3); free(rows); free(vel); free(cost); free(order); free(used)
        free(keep); free(shared); free(ghost)
        raise MemoryError()
    try:
        with nogil:
            _sort_by_freq(f2, n2, g2, k2)
            _sort_by_freq(f3, n3, g3, k3)
            # steps 1-3, candidates in (up peak, down peak) order
            for i0 in range(n0):
                x0b1 = f0[i0] * b1
                a1x0 = a1 * f0[i0]
                for i1 in range(n1):
                    r = (x0b1 - f1[i1] * b0) / det
                    v = (a0 * f1[i1] - a1x0) / det
                    if not (r >= min_range_m and r <= max_range_m and fabs(v) <= max_speed_mps):
                        continue
                    n_cand += 1
                    if n2 == 0 or n3 == 0:
                        continue
                    if use_near and r <= near_range_m:
                        t2 = near_tol2
                        t3 = near_tol3
                    else:
                        t2 = tol2
                        t3 = tol3
                    p = r * a2 + v * b2
                    j2 = _nearest(g2, k2, n2, p, &d2)
                    if not d2 <= t2:
                        continue
                    p = r * a3 + v * b3
                    j3 = _nearest(g3, k3, n3, p, &d3)
                    if not d3 <= t3:
                        continue
                    rows[4 * n_conf] = i0
                    rows[4 * n_conf + 1] = i1
                    rows[4 * n_conf + 2] = j2
                    rows[4 * n_conf + 3] = j3
                    vel[n_conf] = v
                    e2 = d2 / tol2
                    e3 = d3 / tol3
                    cost[n_conf] = e2 * e2 + e3 * e3
                    n_conf += 1
            # step 4: stable order by cost (insertion sort: a handful of candidates)
            for i in range(n_conf):
                c = cost[i]
                j = i
                while j > 0 and cost[order[j - 1]] > c:
                    order[j] = order[j - 1]
                    j -= 1
                order[j] = i
            u0 = used
            u1 = used + n0
            u2 = u1 + n1
            u3 = u2 + n2
            for i in range(n0 + n1 + n2 + n3):
                used[i] = 0
            n_keep = 0
            for i in range(n_conf):
                pa = rows + 4 * order[i]
                if (u0[pa[0]] > 0) + (u1[pa[1]] > 0) + (u2[pa[2]] > 0) + (u3[pa[3]] > 0) <= max_shared:
                    u0[pa[0]] += 1
                    u1[pa[1]] += 1
                    u2[pa[2]] += 1
                    u3[pa[3]] += 1
                    keep[n_keep] = order[i]
                    n_keep += 1
            max_sh = 0
            for i in range(n_keep):
                pa = rows + 4 * keep[i]
                shared[i] = u0[pa[0]] + u1[pa[1]] + u2[pa[2]] + u3[pa[3]] - 4
                if shared[i] > max_sh:
                    max_sh = shared[i]
                ghost[i] = 0
            if n_keep > 2 and max_shared > 0 and ghost_speed_mps > 0 and max_sh > max_shared:
                # ghost[i]: i shares peaks with more than max_shared of the others' ... and has a partner j at
                # another speed (sharing a peak) and another partner l at another speed that agrees with j
                for i in range(n_keep):
                    if shared[i] <= max_shared:
                        continue
                    pa = rows + 4 * keep[i]
                    hit = False
                    for j in range(n_keep):
                        if j == i:
                            continue
                        pb = rows + 4 * keep[j]
                        sh = (pa[0] == pb[0]) + (pa[1] == pb[1]) + (pa[2] == pb[2]) + (pa[3] == pb[3])
                        if not (sh > 0 and fabs(vel[keep[i]] - vel[keep[j]]) > ghost_speed_mps):
                            continue
                        for l in range(n_keep):
                            if l == i or l == j:
                                continue
                            pb = rows + 4 * keep[l]
                            sh = (pa[0] == pb[0]) + (pa[1] == pb[1]) + (pa[2] == pb[2]) + (pa[3] == pb[3])
                            if (sh > 0 and fabs(vel[keep[i]] - vel[keep[l]]) > ghost_speed_mps
                                    and fabs(vel[keep[l]] - vel[keep[j]]) <= ghost_speed_mps):
                                hit = True
                                break
                        if hit:
                            break
                    ghost[i] = hit
        n_out = 0
        for i in range(n_keep):
            n_out += not ghost[i]
        out = _empty2(cnp.NPY_INT64, n_out, 4)
        o = out
        fm_arr = _empty2(cnp.NPY_FLOAT64, n_out, 4) if want_fm else None
        if want_fm:
            fm = <double *>cnp.PyArray_DATA(<cnp.ndarray>fm_arr)
        n = 0
        for i in range(n_keep):
            if ghost[i]:
                continue
            pa = rows + 4 * keep[i]
            for kk in range(4):
                o[n, kk] = pa[kk]
            if want_fm:
                fm[4 * n] = f0[pa[0]]
                fm[4 * n + 1] = f1[pa[1]]
                fm[4 * n + 2] = f2[pa[2]]
                fm[4 * n + 3] = f3[pa[3]]
            n += 1
        if want_fm:
            return out, n_cand, n_cand - n_conf, fm_arr
        return out, n_cand, n_cand - n_conf
    finally:
        free(g2); free(g3); free(k2); free(k3); free(rows); free(vel); free(cost); free(order); free(used)
        free(keep); free(shared); free(ghost)


cdef object _as_c2(object a, int typenum, Py_ssize_t n1):
    """:func:`_as_c` of a 2-D ``(n, n1)`` array (``np.ascontiguousarray(a, dtype).reshape(-1, n1)``)."""
    if (cnp.PyArray_Check(a) and cnp.PyArray_NDIM(<cnp.ndarray>a) == 2 and cnp.PyArray_DIM(<cnp.ndarray>a, 1) == n1
            and cnp.PyArray_TYPE(<cnp.ndarray>a) == typenum and cnp.PyArray_ISCARRAY_RO(<cnp.ndarray>a)):
        return a
    return np.ascontiguousarray(a, dtype=cnp.PyArray_DescrFromType(typenum)).reshape(-1, n1)


@cython.boundscheck(False)
@cython.wraparound(False)
def aided_search(tuple freqs, tuple bins, tuple weak_freqs, tuple weak_bins, used_a, f_hat_a, window_hz_a,
                 int min_segments):
    """The peak search of track-aided pairing (edge.lane.pairs.PairStage.track_aided's reference): for each
    predicted track (row of ``f_hat`` (m, 4), Hz) and segment, the nearest peak (detected ones, then weak ones, in
    their list order; the first of equal distances) not used by a pairing (``used`` (n, 4): peak index per segment
    of the accepted pairs), found if within ``window_hz[k]``. The arrays are taken as float64 (frequencies) and
    int64 (bins, ``used``) C-contiguous ones, converted when they are not, and read through the numpy C API.
    Returns ``(found (m, 4) uint8, f (m, 4) float64: the found peak's frequency, 0 where none, bins (m, 4) int64:
    its FFT bin, -1 where none, good (m,) uint8: at least ``min_segments`` found)``."""
    used_a = _as_c2(used_a, cnp.NPY_INT64, 4)
    f_hat_a = _as_c2(f_hat_a, cnp.NPY_FLOAT64, 4)
    cdef Py_ssize_t m = len(f_hat_a), n_used = len(used_a), i, j, nd, nw, best
    cdef int k, cnt
    cdef double d, dmin, p
    cdef const long long *used = <const long long *>_data2(used_a, cnp.NPY_INT64, n_used, 4, False, "used")
    cdef const double *f_hat = <const double *>_data2(f_hat_a, cnp.NPY_FLOAT64, m, 4, False, "f_hat")
    window_hz_a = _as_c(window_hz_a, cnp.NPY_FLOAT64)  # (the converted arrays are held while their data is read)
    cdef const double *window_hz = <const double *>_data(window_hz_a, cnp.NPY_FLOAT64, 4, False, "window_hz")
    cdef const double *fd
    cdef const double *fw
    cdef const long long *bd
    cdef const long long *bw
    if len(freqs) != 4 or len(bins) != 4 or (weak_freqs is not None and (len(weak_freqs) != 4 or len(weak_bins) != 4)):
        raise ValueError("four segments needed")
    found = _zeros2(cnp.NPY_UINT8, m, 4)
    fsel = _zeros2(cnp.NPY_FLOAT64, m, 4)
    bsel = _empty2(cnp.NPY_INT64, m, 4)  # np.full((m, 4), -1, np.int64)
    cdef long long *bs0 = <long long *>cnp.PyArray_DATA(<cnp.ndarray>bsel)
    cdef Py_ssize_t q
    for q in range(4 * m):
        bs0[q] = -1
    good = _zeros1(cnp.NPY_UINT8, m)
    cdef unsigned char *fo = <unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>found)
    cdef double *fs = <double *>cnp.PyArray_DATA(<cnp.ndarray>fsel)
    cdef long long *bs = <long long *>cnp.PyArray_DATA(<cnp.ndarray>bsel)
    cdef unsigned char *go = <unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>good)
    cdef unsigned char *taken
    for k in range(4):
        a_f = _as_c(freqs[k], cnp.NPY_FLOAT64)
        a_b = _as_c(bins[k], cnp.NPY_INT64)
        nd = len(a_f)
        fd = <const double *>_data(a_f, cnp.NPY_FLOAT64, nd, False, "freqs")
        bd = <const long long *>_data(a_b, cnp.NPY_INT64, nd, False, "bins")
        nw = 0
        fw = NULL
        bw = NULL
        if weak_freqs is not None:
            a_wf = _as_c(weak_freqs[k], cnp.NPY_FLOAT64)
            a_wb = _as_c(weak_bins[k], cnp.NPY_INT64)
            nw = len(a_wf)
            fw = <const double *>_data(a_wf, cnp.NPY_FLOAT64, nw, False, "weak_freqs")
            bw = <const long long *>_data(a_wb, cnp.NPY_INT64, nw, False, "weak_bins")
        for i in range(n_used):
            if not 0 <= used[4 * i + k] < nd:
                raise IndexError("used: a peak index out of range")
        taken = <unsigned char *>malloc(nd + 1)
        if taken == NULL:
            raise MemoryError()
        for j in range(nd):
            taken[j] = 0
        for i in range(n_used):
            taken[used[4 * i + k]] = 1
        for i in range(m):
            p = f_hat[4 * i + k]
            best = -1
            dmin = 0.0
            for j in range(nd):
                if taken[j]:
                    continue
                d = fabs(fd[j] - p)
                if best < 0 or d < dmin:
                    best, dmin = j, d
            for j in range(nw):
                d = fabs(fw[j] - p)
                if best < 0 or d < dmin:
                    best, dmin = nd + j, d
            if best >= 0 and dmin <= window_hz[k]:
                fo[4 * i + k] = 1
                if best < nd:
                    fs[4 * i + k] = fd[best]
                    bs[4 * i + k] = bd[best]
                else:
                    fs[4 * i + k] = fw[best - nd]
                    bs[4 * i + k] = bw[best - nd]
        free(taken)
    for i in range(m):
        cnt = fo[4 * i] + fo[4 * i + 1] + fo[4 * i + 2] + fo[4 * i + 3]
        go[i] = cnt >= min_segments
    return found, fsel, bsel, good


@cython.boundscheck(False)
@cython.wraparound(False)
def refine_finish(fm_a, sol_a, pred_a):
    """Step 5 of the pairing after its two BLAS products (edge.dsp.pairing._refine, the reference): ``fm`` (n, 4) the
    pairs' frequencies, ``sol = fm @ pinv_t`` (n, 2) and ``pred = sol @ matrix_t`` (n, 4), float64 C-contiguous.
    Returns ``(range_m, v_mps, residual_hz)`` (n,) float32: ``sol``'s columns and ``sqrt(sum_k (pred - fm)^2 / 4)``,
    the four squares added in segment order (numpy's reduction of four values)."""
    cdef Py_ssize_t n = cnp.PyArray_DIM(<cnp.ndarray>fm_a, 0) if cnp.PyArray_Check(fm_a) else 0, i, k
    cdef const double *fm = <const double *>_data2(fm_a, cnp.NPY_FLOAT64, n, 4, False, "fm")
    cdef const double *sol = <const double *>_data2(sol_a, cnp.NPY_FLOAT64, n, 2, False, "sol")
    cdef const double *pred = <const double *>_data2(pred_a, cnp.NPY_FLOAT64, n, 4, False, "pred")
    r_arr = _empty1(cnp.NPY_FLOAT32, n)
    v_arr = _empty1(cnp.NPY_FLOAT32, n)
    e_arr = _empty1(cnp.NPY_FLOAT32, n)
    cdef float *ro = <float *>cnp.PyArray_DATA(r_arr)
    cdef float *vo = <float *>cnp.PyArray_DATA(v_arr)
    cdef float *eo = <float *>cnp.PyArray_DATA(e_arr)
    cdef double d, s
    for i in range(n):
        ro[i] = <float>sol[2 * i]
        vo[i] = <float>sol[2 * i + 1]
        d = pred[4 * i] - fm[4 * i]
        s = d * d
        for k in range(1, 4):
            d = pred[4 * i + k] - fm[4 * i + k]
            s = s + d * d
        eo[i] = <float>sqrt(s / 4.0)
    return r_arr, v_arr, e_arr


@cython.boundscheck(False)
@cython.wraparound(False)
def drop_rows(static, tuple cols):
    """``tuple(c[~static] for c in cols)`` (edge.lane.pairs.PairStage.drop_static's reference): the rows of each
    array of ``cols`` where ``static`` ((n,) bool or uint8) is False, copied in order into new C arrays of the same
    dtype. None when no row is static (nothing to copy); False when ``static`` or an array of ``cols`` is not a
    C-contiguous, aligned, native numpy array of ``n`` rows of a number type (the caller then indexes with numpy)."""
    cdef Py_ssize_t n, i, j, m = 0, rowb, q, nd
    cdef int t
    cdef const unsigned char *st
    cdef const char *src
    cdef char *dst
    cdef cnp.npy_intp dims[8]
    if not cnp.PyArray_Check(static) or cnp.PyArray_NDIM(<cnp.ndarray>static) != 1:
        return False
    t = cnp.PyArray_TYPE(<cnp.ndarray>static)
    if not ((t == cnp.NPY_BOOL or t == cnp.NPY_UINT8) and cnp.PyArray_ISCARRAY_RO(<cnp.ndarray>static)):
        return False
    n = cnp.PyArray_DIM(<cnp.ndarray>static, 0)
    st = <const unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>static)
    for c in cols:
        if not (cnp.PyArray_Check(c) and 1 <= cnp.PyArray_NDIM(<cnp.ndarray>c) <= 8
                and cnp.PyArray_DIM(<cnp.ndarray>c, 0) == n and cnp.PyArray_ISCARRAY_RO(<cnp.ndarray>c)
                and cnp.PyArray_ISNOTSWAPPED(<cnp.ndarray>c)):
            return False
        t = cnp.PyArray_TYPE(<cnp.ndarray>c)
        if not (t <= cnp.NPY_CLONGDOUBLE and t != cnp.NPY_OBJECT):  # (the numbers: their type number is the dtype)
            return False
    for i in range(n):
        m += st[i] == 0
    if m == n:
        return None
    out = []
    for c in cols:
        nd = cnp.PyArray_NDIM(<cnp.ndarray>c)
        rowb = cnp.PyArray_ITEMSIZE(<cnp.ndarray>c)
        dims[0] = m
        for j in range(1, nd):
            dims[j] = cnp.PyArray_DIM(<cnp.ndarray>c, j)
            rowb *= dims[j]
        o = cnp.PyArray_EMPTY(<int>nd, dims, cnp.PyArray_TYPE(<cnp.ndarray>c), 0)
        src = <const char *>cnp.PyArray_DATA(<cnp.ndarray>c)
        dst = <char *>cnp.PyArray_DATA(<cnp.ndarray>o)
        q = 0
        for i in range(n):
            if st[i] == 0:
                memcpy(dst + q * rowb, src + i * rowb, rowb)
                q += 1
        out.append(o)
    return tuple(out)
