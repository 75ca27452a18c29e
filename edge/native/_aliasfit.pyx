# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""The candidate search of the surveillance speed's alias fit (edge.classify.features.RadialSpeedEstimator.fit_alias):
every candidate reference's unaliased speeds, integrated range path, robust fit to each observable and the rivals'
test, in one call in place of the reference's (candidates, offsets, frames) arrays.

Each value is computed with the reference's operations in its order: ``np.round`` is ``rint``, a cumulative sum
adds in frame order, and a sum over frames is numpy's pairwise sum (`_pairwise.pxi`), so the results are
bit-identical.
"""

cimport cython
from libc.math cimport rint, fabs, isfinite, isnan, INFINITY, NAN
from libc.stdlib cimport malloc, free


include "_pairwise.pxi"


cdef double _median(double *d, Py_ssize_t k) noexcept nogil:
    """``np.median`` of ``k`` values (sorted in place; NaN when one is NaN)."""
    cdef Py_ssize_t i, j
    cdef double v
    for i in range(k):
        if isnan(d[i]):
            return NAN
    for i in range(1, k):
        v = d[i]
        j = i - 1
        while j >= 0 and d[j] > v:
            d[j + 1] = d[j]
            j -= 1
        d[j + 1] = v
    if k % 2:
        return d[k // 2]
    return ((0.0 + d[k // 2 - 1]) + d[k // 2]) / 2.0


cdef double _offset_cost(const double *res, const unsigned char *ok, const unsigned char *low, double off,
                         double tol2, double *e2, Py_ssize_t n) noexcept nogil:
    """Each frame's cost ``min((res - off)^2, tol2)`` (``tol2`` where not usable; 0 where ``low`` and ``res < off``:
    a lower bound nearer than the path) into ``e2``; their pairwise sum."""
    cdef Py_ssize_t i
    cdef double d
    for i in range(n):
        if ok[i]:
            d = res[i] - off
            if low[i] and d < 0.0:
                d = 0.0
            d = d * d
            e2[i] = d if d < tol2 else tol2
        else:
            e2[i] = tol2
    return _pairwise_sum(e2, n)


@cython.cdivision(True)
def fit_candidates(const double[::1] t, const double[::1] vw, const double[::1] refs, const double[:, ::1] obs,
                   const unsigned char[:, ::1] lower, double period, double static_kmh, double tol2, double vmax,
                   double margin2, unsigned char[::1] on_path):
    """The best candidate of ``refs`` for frames at times ``t`` (s) with wrapped Doppler ``vw`` (km/h) and the
    observables ``obs`` (rows of ranges in m, NaN where not observed; ``lower``, of the same shape, nonzero where
    one is only a lower bound of the body's range): ``(best, rivals_clear)``. ``on_path`` (n,)
    gets the best candidate's frames on its path; ``rivals_clear`` is whether every candidate that gives most of
    those frames another alias costs at least ``margin2`` (m^2) more. Candidates as in the reference: each frame
    unaliased to the alias nearest the candidate, the path integrated over the frames (trapezoids, km/h to m/s),
    laid on each observable at the offset (one of its usable frames' residuals) that fits it best, each frame
    costing ``min(e^2, tol2)``; frames below ``static_kmh`` do not vote unless fewer than three move. At most
    48 frames (the reference spreads its offsets over the residuals' range beyond that)."""
    cdef Py_ssize_t n = t.shape[0], C = refs.shape[0], K = obs.shape[0]
    cdef Py_ssize_t c, i, j, k, bj, best, m_ok, n_mov, mine_n
    cdef double ref, cost, cj, bc, gap, med
    if (n < 1 or n > 48 or C < 1 or vw.shape[0] != n or obs.shape[1] != n or on_path.shape[0] != n
            or lower.shape[0] != K or lower.shape[1] != n):
        raise ValueError("fit_candidates: 1 to 48 frames, one value of each per frame, and candidates")
    cdef double *speeds = <double *> malloc(C * n * sizeof(double))
    cdef double *costs = <double *> malloc(C * sizeof(double))
    cdef unsigned char *onp = <unsigned char *> malloc(C * n)
    cdef double *path = <double *> malloc(n * sizeof(double))
    cdef double *res = <double *> malloc(n * sizeof(double))
    cdef double *e2 = <double *> malloc(n * sizeof(double))
    cdef double *fe2 = <double *> malloc(n * sizeof(double))
    cdef unsigned char *moving = <unsigned char *> malloc(n)
    cdef unsigned char *ok = <unsigned char *> malloc(n)
    cdef unsigned char *mine = <unsigned char *> malloc(n)
    if not (speeds and costs and onp and path and res and e2 and fe2 and moving and ok and mine):
        free(speeds); free(costs); free(onp); free(path); free(res); free(e2); free(fe2); free(moving); free(ok)
        free(mine)
        raise MemoryError()
    cdef double *s
    with nogil:
        for c in range(C):
            ref = refs[c]
            s = speeds + c * n
            for i in range(n):
                s[i] = vw[i] + period * rint((ref - vw[i]) / period)
            path[0] = 0.0
            for i in range(1, n):
                path[i] = path[i - 1] + (0.5 * (s[i] + s[i - 1])) * (t[i] - t[i - 1])
            for i in range(n):
                path[i] = path[i] / 3.6
            n_mov = 0
            for i in range(n):
                moving[i] = fabs(s[i]) >= static_kmh
                n_mov += moving[i]
            if n_mov < 3:
                for i in range(n):
                    moving[i] = 1
            cost = 0.0
            for i in range(n):
                fe2[i] = tol2
            for k in range(K):
                m_ok = 0
                for i in range(n):
                    ok[i] = isfinite(obs[k, i]) and moving[i]
                    m_ok += ok[i]
                    res[i] = obs[k, i] - path[i] if ok[i] else NAN
                if m_ok == 0:
                    cost += tol2 * <double> n
                    continue
                bj = 0
                bc = INFINITY
                for j in range(n):  # argmin: the first least cost
                    if ok[j]:
                        cj = _offset_cost(res, ok, &lower[k, 0], res[j], tol2, e2, n)
                        if cj < bc:
                            bc = cj
                            bj = j
                cost += _offset_cost(res, ok, &lower[k, 0], res[bj], tol2, e2, n)  # e2: the best offset's frames
                for i in range(n):
                    if e2[i] < fe2[i]:
                        fe2[i] = e2[i]
            costs[c] = cost
            for i in range(n):
                onp[c * n + i] = fe2[i] < tol2
        best = 0
        for c in range(1, C):
            if costs[c] < costs[best]:
                best = c
        mine_n = 0
        for i in range(n):
            mine[i] = onp[best * n + i]
            mine_n += mine[i]
        if mine_n == 0:
            for i in range(n):
                mine[i] = 1
            mine_n = n
        gap = INFINITY
        for c in range(C):
            k = 0
            for i in range(n):
                if mine[i]:
                    res[k] = speeds[c * n + i] - speeds[best * n + i]
                    k += 1
            med = _median(res, k)
            if fabs(med) >= vmax and costs[c] - costs[best] < gap:
                gap = costs[c] - costs[best]
        for i in range(n):
            on_path[i] = onp[best * n + i]
    free(speeds); free(costs); free(onp); free(path); free(res); free(e2); free(fe2); free(moving); free(ok)
    free(mine)
    return best, gap >= margin2
