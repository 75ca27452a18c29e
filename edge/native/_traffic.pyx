# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Compiled core of the traffic layer's per-track work (issue 30): the mounting-yaw estimator's running sums.

The reference is :class:`edge.traffic.lanes.YawEstimator` on its dict of per-track sums (``add``,
``_live_votes_small``). Here the sums are a struct-of-arrays table indexed by track id (track ids are small
recycled integers): ``acc`` (cap, 7) = n, sum x, sum y, sum x^2, sum y^2, sum xy, last age; ``live`` (cap,) 1 while
the track runs; ``seq`` (cap,) the order in which the reference's dict would hold the track (insertion order; a
recycled id keeps its place). Same float64 operations in the same order: bit-identical (built without
contraction into fused multiply-adds).
"""

cimport cython
from libc.math cimport sqrt, hypot, fabs, INFINITY

import numpy as np


cdef inline void _sort_by_seq(long long *ids, Py_ssize_t n, const long long[::1] seq) noexcept nogil:
    """Insertion sort of ``ids`` by ``seq[id]`` (a handful of running tracks)."""
    cdef Py_ssize_t i, j
    cdef long long k
    for i in range(1, n):
        k = ids[i]
        j = i - 1
        while j >= 0 and seq[ids[j]] > seq[k]:
            ids[j + 1] = ids[j]
            j -= 1
        ids[j + 1] = k


@cython.cdivision(True)
def yaw_add(double[:, ::1] acc, unsigned char[::1] live, long long[::1] seq, long long next_seq,
            const long long[::1] ids, const long long[::1] age, const double[::1] x, const double[::1] y):
    """One frame of :meth:`YawEstimator.add` on the table: accumulates the confirmed tracks ``ids`` (with their
    ``age`` and position ``x``, ``y`` in m); a recycled id (its age dropped) and a running track not in ``ids``
    end. Returns ``(ended, next_seq)``: the ended tracks' sums (k, 7) in the order the reference votes (recycled
    ones in track order, then the others in insertion order) and the next insertion stamp. The caller makes the
    table hold every id (``cap > max(ids)``)."""
    cdef Py_ssize_t n = ids.shape[0], cap = live.shape[0], i, j, k, n_end = 0, n_gone = 0
    cdef long long tid
    cdef double a, xi, yi
    seen_a = np.zeros(cap, dtype=np.uint8)
    cdef unsigned char[::1] seen = seen_a
    ended_a = np.empty((n + cap, 7))
    cdef double[:, ::1] ended = ended_a
    gone_a = np.empty(cap, dtype=np.int64)
    cdef long long[::1] gone = gone_a
    for i in range(n):
        tid = ids[i]
        a = <double>age[i]
        xi = x[i]
        yi = y[i]
        if live[tid] and a < acc[tid, 6]:  # id recycled: the old track ended
            for k in range(7):
                ended[n_end, k] = acc[tid, k]
            n_end += 1
            for k in range(7):
                acc[tid, k] = 0.0
        elif not live[tid]:
            live[tid] = 1
            seq[tid] = next_seq
            next_seq += 1
            for k in range(7):
                acc[tid, k] = 0.0
        acc[tid, 0] += 1.0
        acc[tid, 1] += xi
        acc[tid, 2] += yi
        acc[tid, 3] += xi * xi
        acc[tid, 4] += yi * yi
        acc[tid, 5] += xi * yi
        acc[tid, 6] = a
        seen[tid] = 1
    for j in range(cap):
        if live[j] and not seen[j]:
            gone[n_gone] = j
            n_gone += 1
    if n_gone > 1:
        _sort_by_seq(&gone[0], n_gone, seq)
    for i in range(n_gone):
        tid = gone[i]
        for k in range(7):
            ended[n_end, k] = acc[tid, k]
        n_end += 1
        live[tid] = 0
    return ended_a[:n_end], next_seq


@cython.cdivision(True)
def yaw_live_terms(const double[:, ::1] acc, const unsigned char[::1] live, const long long[::1] seq,
                   double min_len, double max_sd):
    """The running tracks that already vote (:meth:`YawEstimator._live_votes_small`'s test, in insertion order):
    ``(num, den, w)``, the vote being ``-0.5 atan2(num, den)`` (rad) and ``w`` its weight. ``min_len``:
    ``yaw_live_min_length_m`` (m); ``max_sd``: ``yaw_max_lateral_sd_m`` (m)."""
    cdef Py_ssize_t cap = live.shape[0], j, i, n_live = 0, n_out = 0
    cdef long long tid
    cdef double a0, n, mx, my, cxx, cyy, cxy, half_tr, det, disc, major, minor, r, mn
    ids_a = np.empty(cap, dtype=np.int64)
    cdef long long[::1] ids = ids_a
    for j in range(cap):
        if live[j]:
            ids[n_live] = j
            n_live += 1
    if n_live > 1:
        _sort_by_seq(&ids[0], n_live, seq)
    num_a = np.empty(n_live)
    den_a = np.empty(n_live)
    w_a = np.empty(n_live)
    cdef double[::1] num = num_a, den = den_a, w = w_a
    for i in range(n_live):
        tid = ids[i]
        a0 = acc[tid, 0]
        n = a0 if a0 > 1.0 else 1.0
        mx = acc[tid, 1] / n
        my = acc[tid, 2] / n
        cxx = acc[tid, 3] / n - mx * mx
        cyy = acc[tid, 4] / n - my * my
        cxy = acc[tid, 5] / n - mx * my
        half_tr = 0.5 * (cxx + cyy)
        det = cxx * cyy - cxy * cxy
        r = half_tr * half_tr - det
        if 0.0 > r:  # Python's max(r, 0.0): r unless 0.0 is larger (NaN stays)
            r = 0.0
        disc = sqrt(r)
        major = half_tr + disc
        minor = half_tr - disc
        if 0.0 > minor:
            minor = 0.0
        if a0 >= 3 and sqrt(major * 12.0) >= min_len and sqrt(minor) <= max_sd:
            mn = minor
            if 0.01 > mn:
                mn = 0.01
            num[n_out] = 2.0 * cxy
            den[n_out] = cyy - cxx
            w[n_out] = a0 * major / mn
            n_out += 1
    return num_a[:n_out], den_a[:n_out], w_a[:n_out]


def track_kin(list conf):
    """The traffic monitor's per-track table of the confirmed tracks ``conf`` (TrackState objects):
    ``(kin, ids, age)``, ``kin`` (n, 6) float64 = track id, age (frames), x, y (m), vx, vy (m/s), as the
    reference's ``np.array`` of tuples; ``ids``, ``age`` (n,) int64."""
    cdef Py_ssize_t n = len(conf), i
    kin_a = np.empty((n, 6))
    ids_a = np.empty(n, dtype=np.int64)
    age_a = np.empty(n, dtype=np.int64)
    cdef double[:, ::1] kin = kin_a
    cdef long long[::1] ids = ids_a, age = age_a
    for i in range(n):
        t = conf[i]
        ids[i] = t.track_id
        age[i] = t.age_frames
        kin[i, 0] = <double>ids[i]
        kin[i, 1] = <double>age[i]
        kin[i, 2] = t.x_m
        kin[i, 3] = t.y_m
        kin[i, 4] = t.vx_mps
        kin[i, 5] = t.vy_mps
    return kin_a, ids_a, age_a


@cython.cdivision(True)
def road_lanes(const double[:, ::1] kin, double cy, double sy, const double[::1] centers, const double[::1] half_w,
               double sure_k):
    """The road frame and the lanes of the tracks in ``kin`` (:func:`track_kin`) for a yaw of cos ``cy``, sin ``sy``:
    as Python lists, the along-road position ``s`` (m) and speed ``vs`` (m/s), the speed (m/s), the lane index
    (-1 off every lane; the nearest centre, the first on a tie), the margin inside that lane's nearer edge (m;
    -inf without lanes) and whether the lane is sure (inside it by ``sure_k`` x range; ``sure_k`` <= 0: any
    lane). The reference is the numpy code of ``TrafficMonitor.update`` with
    :func:`edge.traffic.lanes.assign_lanes_with_margin`."""
    cdef Py_ssize_t n = kin.shape[0], nl = centers.shape[0], i, l, k
    cdef double x, y, vx, vy, u, d, dmin, m
    s_l, vs_l, sp_l, lane_l, mg_l, sure_l = [], [], [], [], [], []
    for i in range(n):
        x = kin[i, 2]
        y = kin[i, 3]
        vx = kin[i, 4]
        vy = kin[i, 5]
        u = x * cy + y * sy
        s_l.append(-x * sy + y * cy)
        vs_l.append(-vx * sy + vy * cy)
        sp_l.append(hypot(vx, vy))
        if nl == 0:
            lane_l.append(-1)
            mg_l.append(-INFINITY)
            sure_l.append(False)
            continue
        k = 0
        dmin = fabs(u - centers[0])
        for l in range(1, nl):
            d = fabs(u - centers[l])
            if d < dmin:  # (argmin: the first of equal distances; NaN: numpy's argmin takes the first NaN)
                dmin = d
                k = l
        m = half_w[k] - dmin
        if not (m >= 0.0):
            k = -1
        lane_l.append(k)
        mg_l.append(m)
        sure_l.append(k >= 0 and (sure_k <= 0.0 or m >= sure_k * hypot(x, y)))
    return s_l, vs_l, sp_l, lane_l, mg_l, sure_l
