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
from libc.math cimport fabs
from libc.stdlib cimport malloc, free

import numpy as np


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


cdef void _sort_by_freq(const double[::1] f, double *g, int *k) noexcept nogil:
    """``g`` = ``f`` sorted ascending, ``k`` the original indices (ties by index: insertion sort, stable)."""
    cdef int n = f.shape[0], i, j
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
    cdef int n0 = f0.shape[0], n1 = f1.shape[0], n2 = f2.shape[0], n3 = f3.shape[0]
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
    if (g2 == NULL or g3 == NULL or k2 == NULL or k3 == NULL or rows == NULL or vel == NULL or cost == NULL
            or order == NULL or used == NULL or keep == NULL or shared == NULL or ghost == NULL):
        free(g2); free(g3); free(k2); free(k3); free(rows); free(vel); free(cost); free(order); free(used)
        free(keep); free(shared); free(ghost)
        raise MemoryError()
    try:
        with nogil:
            _sort_by_freq(f2, g2, k2)
            _sort_by_freq(f3, g3, k3)
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
        out = np.empty((n_out, 4), np.int64)
        o = out
        n = 0
        for i in range(n_keep):
            if ghost[i]:
                continue
            pa = rows + 4 * keep[i]
            for kk in range(4):
                o[n, kk] = pa[kk]
            n += 1
        return out, n_cand, n_cand - n_conf
    finally:
        free(g2); free(g3); free(k2); free(k3); free(rows); free(vel); free(cost); free(order); free(used)
        free(keep); free(shared); free(ghost)


@cython.boundscheck(False)
@cython.wraparound(False)
def aided_search(tuple freqs, tuple bins, tuple weak_freqs, tuple weak_bins, const long long[:, ::1] used,
                 const double[:, ::1] f_hat, const double[::1] window_hz, int min_segments):
    """The peak search of track-aided pairing (edge.lane.pairs.PairStage.track_aided's reference): for each
    predicted track (row of ``f_hat`` (m, 4), Hz) and segment, the nearest peak (detected ones, then weak ones, in
    their list order; the first of equal distances) not used by a pairing (``used`` (n, 4): peak index per segment
    of the accepted pairs), found if within ``window_hz[k]``. Returns ``(found (m, 4) uint8, f (m, 4) float64: the
    found peak's frequency, 0 where none, bins (m, 4) int64: its FFT bin, -1 where none, good (m,) uint8: at least
    ``min_segments`` found)``."""
    cdef int m = f_hat.shape[0], n_used = used.shape[0], i, k, j, nd, nw, best, cnt
    cdef double d, dmin, p
    cdef const double[::1] fd
    cdef const double[::1] fw
    cdef const long long[::1] bd
    cdef const long long[::1] bw
    found = np.zeros((m, 4), np.uint8)
    fsel = np.zeros((m, 4), np.float64)
    bsel = np.full((m, 4), -1, np.int64)
    good = np.zeros(m, np.uint8)
    cdef unsigned char[:, ::1] fo = found
    cdef double[:, ::1] fs = fsel
    cdef long long[:, ::1] bs = bsel
    cdef unsigned char[::1] go = good
    cdef unsigned char *taken
    for k in range(4):
        fd = freqs[k]
        bd = bins[k]
        nd = fd.shape[0]
        if weak_freqs is not None:
            fw = weak_freqs[k]
            bw = weak_bins[k]
            nw = fw.shape[0]
        else:
            fw = fd[:0]
            bw = bd[:0]
            nw = 0
        taken = <unsigned char *>malloc(nd + 1)
        if taken == NULL:
            raise MemoryError()
        for j in range(nd):
            taken[j] = 0
        for i in range(n_used):
            taken[used[i, k]] = 1
        for i in range(m):
            p = f_hat[i, k]
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
                fo[i, k] = 1
                if best < nd:
                    fs[i, k] = fd[best]
                    bs[i, k] = bd[best]
                else:
                    fs[i, k] = fw[best - nd]
                    bs[i, k] = bw[best - nd]
        free(taken)
    for i in range(m):
        cnt = fo[i, 0] + fo[i, 1] + fo[i, 2] + fo[i, 3]
        go[i] = cnt >= min_segments
    return found, fsel, bsel, good
