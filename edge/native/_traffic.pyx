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
from libc.math cimport sqrt, hypot, fabs, rint, INFINITY

import numpy as np

cimport numpy as cnp

cnp.import_array()

from cpython.mem cimport PyMem_Malloc, PyMem_Free
from cpython.ref cimport PyObject

include "_views.pxi"
include "_alloc.pxi"


cdef extern from *:
    """
    /* the instance dict of o when o is exactly of type cls (NULL otherwise; a new reference) */
    static PyObject *_traffic_dict_of(PyObject *o, PyObject *cls) {
        PyObject *d;
        if ((PyObject *)Py_TYPE(o) != cls) return NULL;
        d = PyObject_GenericGetDict(o, NULL);
        if (d == NULL) PyErr_Clear();  /* (read through getattr then) */
        return d;
    }
    """
    PyObject *_traffic_dict_of(object o, object cls)
    PyObject *PyDict_GetItemWithError(object d, object key) except? NULL
    void Py_XDECREF(PyObject *o)


cdef inline bint _eq(object a, object b) except -1:
    """``a == b`` as a tuple's comparison takes it item by item (PyObject_RichCompareBool: identity first)."""
    return a is b or a == b


cdef inline bint _in_range(double lo, double x, double hi) noexcept:
    """``lo <= x <= hi`` of Python floats."""
    return lo <= x and x <= hi


cdef inline object _ga(PyObject *d, object o, str name):
    """``o.<name>`` read from ``o``'s instance dict ``d`` (from ``_traffic_dict_of``): the same object as the
    attribute for an instance of a dataclass whose fields have no descriptors, skipping the type's attribute lookup;
    ``getattr`` when ``d`` is NULL or lacks the key."""
    cdef PyObject *v
    if d != NULL:
        v = PyDict_GetItemWithError(<object>d, name)
        if v != NULL:
            return <object>v
    return getattr(o, name)


cdef inline void _sort_by_seq(long long *ids, Py_ssize_t n, _V V_seq) noexcept nogil:
    """Insertion sort of ``ids`` by ``seq[id]`` (a handful of running tracks)."""
    cdef Py_ssize_t i, j
    cdef long long k
    for i in range(1, n):
        k = ids[i]
        j = i - 1
        while j >= 0 and _pll(V_seq, ids[j])[0] > _pll(V_seq, k)[0]:
            ids[j + 1] = ids[j]
            j -= 1
        ids[j + 1] = k


cdef inline list _row(_V V_acc, long long tid):
    """Row ``tid`` of the sums as Python floats (what ``acc[tid].tolist()`` gives)."""
    return [_pd2(V_acc, tid, 0)[0], _pd2(V_acc, tid, 1)[0], _pd2(V_acc, tid, 2)[0], _pd2(V_acc, tid, 3)[0],
            _pd2(V_acc, tid, 4)[0], _pd2(V_acc, tid, 5)[0], _pd2(V_acc, tid, 6)[0]]


@cython.cdivision(True)
cdef object _yaw_add_core(_V V_acc, _V V_live, _V V_seq, long long next_seq, Py_ssize_t n, bint from_kin, _V V_kin,
                          _V V_ids, _V V_age, _V V_x, _V V_y):
    """:func:`yaw_add` on views: the ids and ages from ``V_ids``, ``V_age`` (int64) or, with ``from_kin``, from the
    columns 0 and 1 of ``V_kin`` (float64, exact integers); positions from ``V_x``, ``V_y``."""
    cdef Py_ssize_t cap = V_live.n[0], i, j, k, n_gone = 0
    cdef long long tid
    cdef double a, xi, yi
    for i in range(n):
        tid = <long long>_pd2(V_kin, i, 0)[0] if from_kin else _pll(V_ids, i)[0]
        if tid < 0 or tid >= cap:
            return None
    cdef unsigned char *seen = <unsigned char*>PyMem_Malloc(cap + 1)
    cdef long long *gone = <long long*>PyMem_Malloc((cap + 1) * sizeof(long long))
    if seen == NULL or gone == NULL:
        PyMem_Free(seen)
        PyMem_Free(gone)
        raise MemoryError()
    for j in range(cap):
        seen[j] = 0
    ended = []
    try:
        for i in range(n):
            if from_kin:
                tid = <long long>_pd2(V_kin, i, 0)[0]
                a = _pd2(V_kin, i, 1)[0]
            else:
                tid = _pll(V_ids, i)[0]
                a = <double>_pll(V_age, i)[0]
            xi = _pd1(V_x, i)[0]
            yi = _pd1(V_y, i)[0]
            if _pu8(V_live, tid)[0] and a < _pd2(V_acc, tid, 6)[0]:  # id recycled: the old track ended
                ended.append(_row(V_acc, tid))
                for k in range(7):
                    _pd2(V_acc, tid, k)[0] = 0.0
            elif not _pu8(V_live, tid)[0]:
                _pu8(V_live, tid)[0] = 1
                _pll(V_seq, tid)[0] = next_seq
                next_seq += 1
                for k in range(7):
                    _pd2(V_acc, tid, k)[0] = 0.0
            _pd2(V_acc, tid, 0)[0] += 1.0
            _pd2(V_acc, tid, 1)[0] += xi
            _pd2(V_acc, tid, 2)[0] += yi
            _pd2(V_acc, tid, 3)[0] += xi * xi
            _pd2(V_acc, tid, 4)[0] += yi * yi
            _pd2(V_acc, tid, 5)[0] += xi * yi
            _pd2(V_acc, tid, 6)[0] = a
            seen[tid] = 1
        for j in range(cap):
            if _pu8(V_live, j)[0] and not seen[j]:
                gone[n_gone] = j
                n_gone += 1
        if n_gone > 1:
            _sort_by_seq(gone, n_gone, V_seq)
        for i in range(n_gone):
            tid = gone[i]
            ended.append(_row(V_acc, tid))
            _pu8(V_live, tid)[0] = 0
    finally:
        PyMem_Free(seen)
        PyMem_Free(gone)
    return ended, next_seq


def yaw_add(acc, live, seq, long long next_seq,
            ids, age, x, y):
    """One frame of :meth:`YawEstimator.add` on the table: accumulates the confirmed tracks ``ids`` (with their
    ``age`` and position ``x``, ``y`` in m); a recycled id (its age dropped) and a running track not in ``ids``
    end. Returns ``(ended, next_seq)``: the ended tracks' sums (a list of 7-float lists) in the order the reference
    votes (recycled ones in track order, then the others in insertion order) and the next insertion stamp; None,
    changing nothing, when an id does not fit the table (``id >= cap``: the caller grows it and calls again)."""
    cdef _V V_acc, V_live, V_seq, V_ids, V_age, V_x, V_y
    _aview(acc, cnp.NPY_FLOAT64, 2, True, True, &V_acc, "acc")
    _aview(live, cnp.NPY_UINT8, 1, True, True, &V_live, "live")
    _aview(seq, cnp.NPY_LONGLONG, 1, True, True, &V_seq, "seq")
    _aview(ids, cnp.NPY_LONGLONG, 1, False, False, &V_ids, "ids")
    _aview(age, cnp.NPY_LONGLONG, 1, False, False, &V_age, "age")
    _aview(x, cnp.NPY_FLOAT64, 1, False, False, &V_x, "x")
    _aview(y, cnp.NPY_FLOAT64, 1, False, False, &V_y, "y")
    return _yaw_add_core(V_acc, V_live, V_seq, next_seq, V_ids.n[0], False, V_ids, V_ids, V_age, V_x, V_y)


def yaw_add_kin(acc, live, seq, long long next_seq, kin, x):
    """:func:`yaw_add` of the traffic monitor's table ``kin`` (:func:`track_kin`: track id, age, x, y columns);
    ``x``: the positions across the boresight to take instead of its x column (None: that column)."""
    cdef _V V_acc, V_live, V_seq, V_kin, V_x, V_y
    _aview(acc, cnp.NPY_FLOAT64, 2, True, True, &V_acc, "acc")
    _aview(live, cnp.NPY_UINT8, 1, True, True, &V_live, "live")
    _aview(seq, cnp.NPY_LONGLONG, 1, True, True, &V_seq, "seq")
    _aview(kin, cnp.NPY_FLOAT64, 2, False, True, &V_kin, "kin")
    V_y = _sub(V_kin, 1, 1)  # column 3: kin[:, 3]
    V_y.data += 3 * V_kin.s[1]
    if x is None:
        V_x = _sub(V_kin, 1, 1)
        V_x.data += 2 * V_kin.s[1]
    else:
        _aview(x, cnp.NPY_FLOAT64, 1, False, False, &V_x, "x")
        if V_x.n[0] != V_kin.n[0]:
            raise ValueError("x: one value per row of kin needed")
    return _yaw_add_core(V_acc, V_live, V_seq, next_seq, V_kin.n[0], True, V_kin, V_kin, V_kin, V_x, V_y)


@cython.cdivision(True)
cdef Py_ssize_t _live_terms(_V V_acc, _V V_live, _V V_seq, double min_len, double max_sd, long long *ids,
                            double *num, double *den, double *w) noexcept:
    """:func:`yaw_live_terms` into ``num``, ``den``, ``w`` (room for every row of the table; ``ids`` scratch of the
    same size); returns how many vote."""
    cdef Py_ssize_t cap = V_live.n[0], j, i, n_live = 0, n_out = 0
    cdef long long tid
    cdef double a0, n, mx, my, cxx, cyy, cxy, half_tr, det, disc, major, minor, r, mn
    for j in range(cap):
        if _pu8(V_live, j)[0]:
            ids[n_live] = j
            n_live += 1
    if n_live > 1:
        _sort_by_seq(ids, n_live, V_seq)
    for i in range(n_live):
        tid = ids[i]
        a0 = _pd2(V_acc, tid, 0)[0]
        n = a0 if a0 > 1.0 else 1.0
        mx = _pd2(V_acc, tid, 1)[0] / n
        my = _pd2(V_acc, tid, 2)[0] / n
        cxx = _pd2(V_acc, tid, 3)[0] / n - mx * mx
        cyy = _pd2(V_acc, tid, 4)[0] / n - my * my
        cxy = _pd2(V_acc, tid, 5)[0] / n - mx * my
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
    return n_out


def yaw_live_terms(acc, live, seq,
                   double min_len, double max_sd):
    """The running tracks that already vote (:meth:`YawEstimator._live_votes_small`'s test, in insertion order):
    ``(num, den, w)``, the vote being ``-0.5 atan2(num, den)`` (rad) and ``w`` its weight. ``min_len``:
    ``yaw_live_min_length_m`` (m); ``max_sd``: ``yaw_max_lateral_sd_m`` (m)."""
    cdef _V V_acc, V_live, V_seq
    _aview(acc, cnp.NPY_FLOAT64, 2, False, True, &V_acc, "acc")
    _aview(live, cnp.NPY_UINT8, 1, False, True, &V_live, "live")
    _aview(seq, cnp.NPY_LONGLONG, 1, False, True, &V_seq, "seq")
    return _live_term_arrays(V_acc, V_live, V_seq, min_len, max_sd)


cdef tuple _live_term_arrays(_V V_acc, _V V_live, _V V_seq, double min_len, double max_sd):
    """:func:`_live_terms` into new float64 arrays ``(num, den, w)`` of the running tracks that vote."""
    cdef Py_ssize_t cap = V_live.n[0], n_out, i
    cdef char *buf = <char*>PyMem_Malloc((cap + 1) * (sizeof(long long) + 3 * sizeof(double)))
    if buf == NULL:
        raise MemoryError()
    cdef long long *ids = <long long*>buf
    cdef double *t = <double*>(buf + (cap + 1) * sizeof(long long))
    try:
        n_out = _live_terms(V_acc, V_live, V_seq, min_len, max_sd, ids, t, t + cap + 1, t + 2 * (cap + 1))
        num_a = _empty1(cnp.NPY_FLOAT64, n_out)
        den_a = _empty1(cnp.NPY_FLOAT64, n_out)
        w_a = _empty1(cnp.NPY_FLOAT64, n_out)
        for i in range(n_out):
            (<double*>cnp.PyArray_DATA(num_a))[i] = t[i]
            (<double*>cnp.PyArray_DATA(den_a))[i] = t[cap + 1 + i]
            (<double*>cnp.PyArray_DATA(w_a))[i] = t[2 * (cap + 1) + i]
    finally:
        PyMem_Free(buf)
    return num_a, den_a, w_a


def yaw_startup(acc, live, seq, Py_ssize_t n_live, votes, double min_len, double max_sd, Py_ssize_t min_tracks,
                arctan2):
    """:meth:`YawEstimator.estimate_rad` before ``min_tracks`` tracks have ended, in one call: the running tracks'
    votes (:meth:`YawEstimator.live_votes_weighted`: :func:`yaw_live_terms`, the angles ``-(0.5 * arctan2(num,
    den))`` with ``arctan2`` numpy's ufunc on the arrays of the reference, then halved and negated here: both exact)
    and :func:`weighted_median` with the ended tracks' ``votes``. ``n_live``: the running tracks (0: no live votes).
    Returns ``(0, None, None)``: fewer than ``min_tracks`` votes, no estimate; ``(1, median, stderr)``; ``(2, live,
    w)``: the votes for the caller's numpy path (more than 64, or a NaN)."""
    cdef _V V_acc, V_live, V_seq, V_l, V_w
    _aview(acc, cnp.NPY_FLOAT64, 2, False, True, &V_acc, "acc")
    _aview(live, cnp.NPY_UINT8, 1, False, True, &V_live, "live")
    _aview(seq, cnp.NPY_LONGLONG, 1, False, True, &V_seq, "seq")
    cdef Py_ssize_t n_out = 0, i
    if n_live:
        num_a, den_a, w_a = _live_term_arrays(V_acc, V_live, V_seq, min_len, max_sd)
        n_out = cnp.PyArray_DIM(<cnp.ndarray>num_a, 0)
        if len(votes) + n_out < min_tracks:
            return 0, None, None
        live_a = arctan2(num_a, den_a)  # (fresh C-contiguous arrays of n_out, as the reference's)
        _aview(live_a, cnp.NPY_FLOAT64, 1, True, True, &V_l, "live votes")
        for i in range(n_out):
            _pd1(V_l, i)[0] = -(0.5 * _pd1(V_l, i)[0])
    else:
        if len(votes) < min_tracks:
            return 0, None, None
        live_a = _empty1(cnp.NPY_FLOAT64, 0)
        w_a = _empty1(cnp.NPY_FLOAT64, 0)
    _aview(live_a, cnp.NPY_FLOAT64, 1, True, True, &V_l, "live votes")
    _aview(w_a, cnp.NPY_FLOAT64, 1, False, True, &V_w, "w")
    res = _weighted_median(votes, V_l, V_w)
    if res is None:
        return 2, live_a, w_a
    return 1, res[0], res[1]


cdef object _gather(object a, Py_ssize_t m, Py_ssize_t n, long long *sel):
    """``a[sel]`` as a new C-contiguous float64 array when ``a`` is a 1-D float64 array of ``m`` values (what
    ``np.asarray(a, dtype=np.float64)[sel]`` gives); None otherwise (the caller's numpy path)."""
    cdef _V V_a
    cdef Py_ssize_t j
    if a is None or not cnp.PyArray_Check(a):
        return None
    if not (cnp.PyArray_NDIM(<cnp.ndarray>a) == 1 and cnp.PyArray_TYPE(<cnp.ndarray>a) == cnp.NPY_FLOAT64
            and cnp.PyArray_DIM(<cnp.ndarray>a, 0) == m and cnp.PyArray_ISALIGNED(<cnp.ndarray>a)
            and cnp.PyArray_ISNOTSWAPPED(<cnp.ndarray>a)):
        return None
    _aview(a, cnp.NPY_FLOAT64, 1, False, False, &V_a, "a")
    out = _empty1(cnp.NPY_FLOAT64, n)
    cdef double *o = <double*>cnp.PyArray_DATA(out)
    for j in range(n):
        o[j] = _pd1(V_a, sel[j])[0]
    return out


def track_kin(tuple tracks, yaw_x=None, extent=None, track_cls=None):
    """The traffic monitor's per-track table of the confirmed tracks (``confirmed`` and ``track_id`` > 0) of
    ``tracks`` (TrackState objects): ``(conf, sel, kin, ids, id_list, yaw_x_sel, extent_sel)``, ``conf`` those
    tracks, ``sel`` (n,) int64 their indices in ``tracks``, ``kin`` (n, 6) float64 = track id, age (frames), x, y
    (m), vx, vy (m/s), as the reference's ``np.array`` of tuples; ``ids`` (n,) int64, ``id_list`` the same as Python
    ints; ``yaw_x_sel``, ``extent_sel``: ``yaw_x[sel]`` and ``extent[sel]`` (new C-contiguous float64 arrays) when
    those are 1-D float64 arrays with a value per track, else None. ``track_cls``: the tracks' class (TrackState),
    whose instances' fields are read from their ``__dict__`` (others through ``getattr``)."""
    cdef Py_ssize_t m = len(tracks), i, n = 0
    cdef PyObject *d
    cdef long long *sel = <long long*>PyMem_Malloc((m + 1) * sizeof(long long))
    if sel == NULL:
        raise MemoryError()
    conf = []
    id_list = []
    cdef _V V_kin, V_ids
    try:
        for i in range(m):
            t = tracks[i]
            d = _traffic_dict_of(t, track_cls)
            try:
                tid = _ga(d, t, "track_id")
                if _ga(d, t, "confirmed") and tid > 0:
                    conf.append(t)
                    id_list.append(tid)
                    sel[n] = i
                    n += 1
            finally:
                Py_XDECREF(d)
        sel_a = _empty1(cnp.NPY_INT64, n)
        kin_a = _empty2(cnp.NPY_FLOAT64, n, 6)
        ids_a = _empty1(cnp.NPY_INT64, n)
        _aview(kin_a, cnp.NPY_FLOAT64, 2, True, True, &V_kin, "kin")
        _aview(ids_a, cnp.NPY_LONGLONG, 1, True, True, &V_ids, "ids")
        for i in range(n):
            (<long long*>cnp.PyArray_DATA(sel_a))[i] = sel[i]
            t = conf[i]
            d = _traffic_dict_of(t, track_cls)
            try:
                _pll(V_ids, i)[0] = id_list[i]
                _pd2(V_kin, i, 0)[0] = <double>_pll(V_ids, i)[0]
                _pd2(V_kin, i, 1)[0] = <double>(<long long>_ga(d, t, "age_frames"))
                _pd2(V_kin, i, 2)[0] = _ga(d, t, "x_m")
                _pd2(V_kin, i, 3)[0] = _ga(d, t, "y_m")
                _pd2(V_kin, i, 4)[0] = _ga(d, t, "vx_mps")
                _pd2(V_kin, i, 5)[0] = _ga(d, t, "vy_mps")
            finally:
                Py_XDECREF(d)
        yx = _gather(yaw_x, m, n, sel)
        ex = _gather(extent, m, n, sel)
    finally:
        PyMem_Free(sel)
    return conf, sel_a, kin_a, ids_a, id_list, yx, ex


@cython.cdivision(True)
cdef inline void _road_lane(_V V_kin, Py_ssize_t i, double cy, double sy, _V V_centers, _V V_half_w, double sure_k,
                            double *s, double *vs, double *sp, long long *lane, double *mg,
                            unsigned char *sure) noexcept nogil:
    """:func:`road_lanes` of row ``i`` of ``kin``."""
    cdef Py_ssize_t nl = V_centers.n[0], l, k
    cdef double x = _pd2(V_kin, i, 2)[0], y = _pd2(V_kin, i, 3)[0], vx = _pd2(V_kin, i, 4)[0]
    cdef double vy = _pd2(V_kin, i, 5)[0], u, d, dmin, m
    u = x * cy + y * sy
    s[0] = -x * sy + y * cy
    vs[0] = -vx * sy + vy * cy
    sp[0] = hypot(vx, vy)
    if nl == 0:
        lane[0] = -1
        mg[0] = -INFINITY
        sure[0] = 0
        return
    k = 0
    dmin = fabs(u - _pd1(V_centers, 0)[0])
    for l in range(1, nl):
        d = fabs(u - _pd1(V_centers, l)[0])
        if d < dmin:  # (argmin: the first of equal distances; NaN: numpy's argmin takes the first NaN)
            dmin = d
            k = l
    m = _pd1(V_half_w, k)[0] - dmin
    if not (m >= 0.0):
        k = -1
    lane[0] = k
    mg[0] = m
    sure[0] = k >= 0 and (sure_k <= 0.0 or m >= sure_k * hypot(x, y))


def road_lanes(kin, double cy, double sy, centers, half_w,
               double sure_k):
    """The road frame and the lanes of the tracks in ``kin`` (:func:`track_kin`) for a yaw of cos ``cy``, sin ``sy``:
    as Python lists, the along-road position ``s`` (m) and speed ``vs`` (m/s), the speed (m/s), the lane index
    (-1 off every lane; the nearest centre, the first on a tie), the margin inside that lane's nearer edge (m;
    -inf without lanes) and whether the lane is sure (inside it by ``sure_k`` x range; ``sure_k`` <= 0: any
    lane). The reference is the numpy code of ``TrafficMonitor.update`` with
    :func:`edge.traffic.lanes.assign_lanes_with_margin`."""
    cdef _V V_kin, V_centers, V_half_w
    _aview(kin, cnp.NPY_FLOAT64, 2, False, True, &V_kin, "kin")
    _aview(centers, cnp.NPY_FLOAT64, 1, False, True, &V_centers, "centers")
    _aview(half_w, cnp.NPY_FLOAT64, 1, False, True, &V_half_w, "half_w")
    cdef Py_ssize_t i
    cdef double s, vs, sp, mg
    cdef long long lane
    cdef unsigned char sure
    s_l, vs_l, sp_l, lane_l, mg_l, sure_l = [], [], [], [], [], []
    for i in range(V_kin.n[0]):
        _road_lane(V_kin, i, cy, sy, V_centers, V_half_w, sure_k, &s, &vs, &sp, &lane, &mg, &sure)
        s_l.append(s)
        vs_l.append(vs)
        sp_l.append(sp)
        lane_l.append(lane)
        mg_l.append(mg)
        sure_l.append(<bint>sure)
    return s_l, vs_l, sp_l, lane_l, mg_l, sure_l


# columns of the traffic monitor's integer memo table ``mi`` (one row per track id)
DEF M_LIVE = 0        # the row holds a running track
DEF M_AGE = 1         # its age (frames) when last seen
DEF M_T = 2           # time it was last seen (ns)
DEF M_WRONG = 3       # frames in a row against its lane's direction
DEF M_WRONG_EMIT = 4  # wrong_way raised for it
DEF M_HITS = 5        # its hit count when last seen (-1: new)
DEF M_STOP_VALID = 6  # it stands (M_STOP_SINCE holds the time it stopped)
DEF M_STOP_SINCE = 7
DEF M_STOP_EMIT = 8   # stopped_vehicle raised for this stop
DEF M_COUNTED = 9     # its vehicle was counted at the detection line
M_COLS = 10
# columns of the float memo table ``mf``: along-road position when last seen (m), its largest speed (m/s)
MF_COLS = 2


cdef struct _Road:
    # per confirmed track, road_lanes' values: along-road position (m), its speed (m/s), speed (m/s), lane margin
    # (m), lane (-1: none), lane sure
    double *s
    double *vs
    double *sp
    double *mg
    long long *lane
    unsigned char *sure


@cython.cdivision(True)
def monitor_pass(tuple tracks, sel, list conf, ids, mi,
                 mf, list meters, meter_cls, kin, double cy, double sy, centers, half_w, double sure_k,
                 lane_dir, ext, long long t_ns, long long dt_ns, tuple p, list accs,
                 tuple class_names, list edges, track_cls, with_fn):
    """The per-track loop of :meth:`edge.traffic.TrafficMonitor.update` (its reference, ``_track_pass``) over the
    confirmed tracks ``conf`` (ids ``ids``) in one call, their memory in the tables ``mi`` (cap, M_COLS) int64 and
    ``mf`` (cap, MF_COLS) float64 indexed by track id and ``meters`` (their LengthMeter objects, ``meter_cls``).
    ``kin``, ``cy``, ``sy``, ``centers``, ``half_w``, ``sure_k``: the table and the road frame of :func:`road_lanes`,
    whose values the pass computes for each track; ``lane_dir``: +1/-1 per lane;
    ``ext``: body extent per track (m, NaN: none) or None; ``t_ns``, ``dt_ns``: the frame's time and duration (ns);
    ``p``: the configuration's parameters (``TrafficMonitor._pass_params``); ``accs``: each lane's
    LaneAccumulator (presence samples and frames are appended); ``tracks``: all tracks, ``sel`` the indices of
    ``conf`` in it; ``with_fn``: the TrackState copy with lane, class and length (None: copy the instance dict of
    ``track_cls``, a frozen dataclass without ``__post_init__``, as ``monitor._with`` does).

    Updates the tables, meters and lanes' samples; rows of ids not in ``ids`` end. Returns ``(published, presence,
    events, actions)``: the published tracks (a tuple like ``tracks``), a presence flag per lane, events ``(kind,
    id, lane)`` in order, and the counting decisions left to the caller in track order: ``(0, j, lane)`` a new track
    to try ``_count_late`` for, ``(1, j, lane, tc_ns)`` a crossing to count unless the lane counted its vehicle, each
    followed by the track's along-road position, speed, speed and lane margin (:func:`road_lanes`'s values).
    None, changing nothing, when an id does not fit the tables (the caller grows them and calls again)."""
    cdef _V V_sel
    _aview(sel, cnp.NPY_LONGLONG, 1, False, True, &V_sel, "sel")
    cdef _V V_ids
    _aview(ids, cnp.NPY_LONGLONG, 1, False, True, &V_ids, "ids")
    cdef _V V_mi
    _aview(mi, cnp.NPY_LONGLONG, 2, True, True, &V_mi, "mi")
    cdef _V V_mf
    _aview(mf, cnp.NPY_FLOAT64, 2, True, True, &V_mf, "mf")
    cdef _V V_lane_dir
    _aview(lane_dir, cnp.NPY_LONGLONG, 1, False, True, &V_lane_dir, "lane_dir")
    cdef _V V_kin, V_centers, V_half_w
    _aview(kin, cnp.NPY_FLOAT64, 2, False, True, &V_kin, "kin")
    _aview(centers, cnp.NPY_FLOAT64, 1, False, True, &V_centers, "centers")
    _aview(half_w, cnp.NPY_FLOAT64, 1, False, True, &V_half_w, "half_w")
    cdef Py_ssize_t n = len(conf), cap = V_mi.n[0], n_lanes = len(accs), j, i
    cdef bint has_ext = ext is not None
    cdef _V V_ext
    cdef unsigned char *seen
    cdef char *buf
    cdef _Road road
    if V_kin.n[0] != n or V_ids.n[0] != n:
        raise ValueError("kin, ids: one row per confirmed track needed")
    for j in range(n):
        if _pll(V_ids, j)[0] < 0 or _pll(V_ids, j)[0] >= cap:
            return None
    if has_ext:
        _aview(ext, cnp.NPY_FLOAT64, 1, False, False, &V_ext, "ext")
        if V_ext.n[0] != n:
            raise ValueError("ext: one value per confirmed track needed")
    sample_lists = [acc.samples for acc in accs]
    buf = <char*>PyMem_Malloc((n + 1) * (4 * sizeof(double) + sizeof(long long) + 1) + cap + 1)
    if buf == NULL:
        raise MemoryError()
    road.s = <double*>buf
    road.vs = road.s + n + 1
    road.sp = road.vs + n + 1
    road.mg = road.sp + n + 1
    road.lane = <long long*>(road.mg + n + 1)
    road.sure = <unsigned char*>(road.lane + n + 1)
    seen = road.sure + n + 1
    for i in range(cap):
        seen[i] = 0
    for j in range(n):
        _road_lane(V_kin, j, cy, sy, V_centers, V_half_w, sure_k, road.s + j, road.vs + j, road.sp + j,
                   road.lane + j, road.mg + j, road.sure + j)
    presence = [False] * n_lanes
    events = []
    actions = []
    try:
        published = _monitor_loop(tracks, V_sel, conf, V_ids, V_mi, V_mf, meters, meter_cls, road, V_lane_dir,
                                  has_ext, V_ext, t_ns, dt_ns, p, accs, sample_lists, class_names, edges, track_cls,
                                  with_fn, seen, presence, events, actions)
    finally:
        PyMem_Free(buf)
    return published, presence, events, actions



@cython.cdivision(True)
cdef object _monitor_loop(tuple tracks, _V V_sel, list conf, _V V_ids, _V V_mi, _V V_mf, list meters, meter_cls,
                          _Road road, _V V_lane_dir, bint has_ext, _V V_ext, long long t_ns, long long dt_ns, tuple p,
                          list accs, list sample_lists, tuple class_names, list edges, track_cls, with_fn,
                          unsigned char *seen, list presence, list events, list actions):
    """:func:`monitor_pass`'s loop (``seen``: a zeroed flag per table row); returns the published tracks."""
    cdef Py_ssize_t n = len(conf), cap = V_mi.n[0], j, i, k
    cdef long long tid, age, hits, tc, t0
    cdef double sj, vsj, spj, s0, f, e, est, L
    cdef bint fresh, crossed, against
    cdef PyObject *d = NULL
    cdef double line = p[0], r_lo = p[1], r_hi = p[2], default_length = p[3], zone_lo = p[4], zone_hi = p[5]
    cdef double reach = p[6], ww_speed = p[7], stopped_speed = p[8], moving_speed = p[9], same_m = p[10]
    cdef double same_v = p[11], length_min_m = p[12]
    cdef long long ww_frames = p[13], stopped_min_ns = p[14], min_frames = p[15], keep = p[16]
    cdef bint late_on = p[17], once = p[18]
    out = [None] * n
    for j in range(n):
        tr = conf[j]
        d = _traffic_dict_of(tr, track_cls)
        try:
            tid = _pll(V_ids, j)[0]
            seen[tid] = 1
            k = road.lane[j]
            lane = k if k >= 0 else None
            age = _ga(d, tr, "age_frames")
            hits_o = _ga(d, tr, "hits")  # (read once: the reference reads it twice, the same object)
            sj = road.s[j]
            vsj = road.vs[j]
            spj = road.sp[j]
            fresh = not _pll_2(V_mi, tid, M_LIVE)[0] or age < _pll_2(V_mi, tid, M_AGE)[0]
            if fresh:
                _pll_2(V_mi, tid, M_LIVE)[0] = 1
                _pll_2(V_mi, tid, M_AGE)[0] = age
                _pll_2(V_mi, tid, M_T)[0] = t_ns
                _pll_2(V_mi, tid, M_WRONG)[0] = 0
                _pll_2(V_mi, tid, M_WRONG_EMIT)[0] = 0
                _pll_2(V_mi, tid, M_HITS)[0] = -1
                _pll_2(V_mi, tid, M_STOP_VALID)[0] = 0
                _pll_2(V_mi, tid, M_STOP_SINCE)[0] = 0
                _pll_2(V_mi, tid, M_STOP_EMIT)[0] = 0
                _pll_2(V_mi, tid, M_COUNTED)[0] = 0
                _pd2(V_mf, tid, 0)[0] = sj
                _pd2(V_mf, tid, 1)[0] = spj
                meters[tid] = meter_cls(keep - 1)
            meter = meters[tid]
            if has_ext:
                e = _pd1(V_ext, j)[0]
                rng = _ga(d, tr, "range_m")
                if (_in_range(r_lo, rng, r_hi) if type(rng) is float else r_lo <= rng <= r_hi) and e == e:
                    # (e not NaN): LengthMeter.add
                    meter.frames += 1
                    top = meter.top
                    if len(top) < keep:
                        top.append(e)
                        top.sort(reverse=True)
                    elif e > top[len(top) - 1]:
                        top[len(top) - 1] = e
                        top.sort(reverse=True)
            # IntervalStatistics.measured
            length_pub = cls_pub = None
            top = meter.top
            if not (meter.frames < min_frames or len(top) < keep):
                est_o = top[len(top) - 1]
                est = est_o
                if est >= length_min_m:
                    length_pub = est_o
                if est - est == 0.0:  # length_class: bisect_right over the edges ("unknown" when not finite)
                    i = 0
                    while i < len(edges) and not (est < edges[i]):
                        i += 1
                    cls_pub = class_names[i]
                else:
                    cls_pub = "unknown"
            if fresh:
                if lane is not None and late_on:
                    actions.append((0, j, k, sj, vsj, spj, road.mg[j]))
            else:
                s0 = _pd2(V_mf, tid, 0)[0]
                crossed = (s0 - line) * (sj - line) < 0 or (sj == line and s0 != line)
                against = lane is not None and vsj * _pll(V_lane_dir, k)[0] < 0
                if crossed and lane is not None and not against and not (_pll_2(V_mi, tid, M_COUNTED)[0] and once):
                    f = (line - s0) / (sj - s0)
                    t0 = _pll_2(V_mi, tid, M_T)[0]
                    tc = t0 + <long long>rint(f * <double>(t_ns - t0))
                    actions.append((1, j, k, tc, sj, vsj, spj, road.mg[j]))
                _pll_2(V_mi, tid, M_AGE)[0] = age
                _pd2(V_mf, tid, 0)[0] = sj
                _pll_2(V_mi, tid, M_T)[0] = t_ns
                if spj > _pd2(V_mf, tid, 1)[0]:  # max(max_speed, speed)
                    _pd2(V_mf, tid, 1)[0] = spj
            if lane is not None:
                if reach <= sj <= zone_hi:
                    sample_lists[k].append((t_ns, dt_ns, sj, meter))
                    L = length_pub if length_pub is not None else default_length
                    if sj + L >= zone_lo:
                        presence[k] = True
                hits = hits_o
                if hits > _pll_2(V_mi, tid, M_HITS)[0] and road.sure[j]:
                    if vsj * _pll(V_lane_dir, k)[0] < -ww_speed:
                        _pll_2(V_mi, tid, M_WRONG)[0] += 1
                    else:
                        _pll_2(V_mi, tid, M_WRONG)[0] = 0
                if _pll_2(V_mi, tid, M_WRONG)[0] >= ww_frames and not _pll_2(V_mi, tid, M_WRONG_EMIT)[0]:
                    _pll_2(V_mi, tid, M_WRONG_EMIT)[0] = 1
                    if not _same_wrong_way_driver(conf, V_ids, V_mi, road.s, road.vs, j, same_m, same_v):
                        events.append(("wrong_way", tid, lane))
            if spj < stopped_speed and _pd2(V_mf, tid, 1)[0] >= moving_speed and lane is not None:
                if not _pll_2(V_mi, tid, M_STOP_VALID)[0]:
                    _pll_2(V_mi, tid, M_STOP_VALID)[0] = 1
                    _pll_2(V_mi, tid, M_STOP_SINCE)[0] = t_ns
                if not _pll_2(V_mi, tid, M_STOP_EMIT)[0] and t_ns - _pll_2(V_mi, tid, M_STOP_SINCE)[0] >= stopped_min_ns:
                    _pll_2(V_mi, tid, M_STOP_EMIT)[0] = 1
                    events.append(("stopped_vehicle", tid, lane))
            elif spj >= moving_speed:
                _pll_2(V_mi, tid, M_STOP_VALID)[0] = 0
                _pll_2(V_mi, tid, M_STOP_EMIT)[0] = 0
            elif spj >= stopped_speed:
                _pll_2(V_mi, tid, M_STOP_VALID)[0] = 0
            _pll_2(V_mi, tid, M_HITS)[0] = hits_o
            tcls = _ga(d, tr, "cls")
            if tcls is not None:
                cls_pub = tcls
            # (tr.lane, tr.cls, tr.length_m) == (lane, cls_pub, length_pub): the tuples' item by item comparison
            if (_eq(_ga(d, tr, "lane"), lane) and _eq(tcls, cls_pub)
                    and _eq(_ga(d, tr, "length_m"), length_pub)):
                out[j] = tr
            else:
                out[j] = _copy_with(tr, lane, cls_pub, length_pub, track_cls, with_fn)
        finally:
            Py_XDECREF(d)
            d = NULL
    for i in range(cap):
        if _pll_2(V_mi, i, M_LIVE)[0] and not seen[i]:
            _pll_2(V_mi, i, M_LIVE)[0] = 0
            meters[i] = None
    frame = (t_ns, dt_ns)
    for acc in accs:
        acc.frames.append(frame)
    if n == len(tracks):
        published = tuple(out)
    else:  # tracks not confirmed: no length measured
        pub = list(tracks)
        for i in range(len(tracks)):
            t = pub[i]
            d = _traffic_dict_of(t, track_cls)
            try:
                if _ga(d, t, "length_m") is not None:
                    pub[i] = _copy_with(t, _ga(d, t, "lane"), _ga(d, t, "cls"), None, track_cls, with_fn)
            finally:
                Py_XDECREF(d)
                d = NULL
        for j in range(n):
            pub[_pll(V_sel, j)[0]] = out[j]
        published = tuple(pub)
    return published


cdef extern from *:
    """
    /* monitor._with's copy of a frozen dataclass instance without __post_init__: a new instance of cls (its
       tp_alloc, what object.__new__(cls) allocates; no __init__ runs in either), its __dict__ a copy of tr's (the
       same keys in the same order: what an empty dict updated from it holds) with lane, cls and length_m
       replaced, set through PyObject_GenericSetDict as object.__setattr__(o, "__dict__", d) does */
    static PyObject *_traffic_copy_with(PyObject *cls, PyObject *tr, PyObject *k_lane, PyObject *lane,
                                        PyObject *k_cls, PyObject *clsv, PyObject *k_len, PyObject *length) {
        PyObject *src, *d, *out;
        src = PyObject_GenericGetDict(tr, NULL);
        if (src == NULL) return NULL;
        d = PyDict_Copy(src);
        Py_DECREF(src);
        if (d == NULL) return NULL;
        if (PyDict_SetItem(d, k_lane, lane) < 0 || PyDict_SetItem(d, k_cls, clsv) < 0
                || PyDict_SetItem(d, k_len, length) < 0) {
            Py_DECREF(d);
            return NULL;
        }
        out = ((PyTypeObject *)cls)->tp_alloc((PyTypeObject *)cls, 0);
        if (out == NULL || PyObject_GenericSetDict(out, d, NULL) < 0) {
            Py_XDECREF(out);
            Py_DECREF(d);
            return NULL;
        }
        Py_DECREF(d);
        return out;
    }
    """
    object _traffic_copy_with(object cls, object tr, object k_lane, object lane, object k_cls, object clsv,
                              object k_len, object length)


cdef object _copy_with(tr, lane, cls, length, track_cls, with_fn):
    """``monitor._with(tr, lane, cls, length)``."""
    if with_fn is not None:
        return with_fn(tr, lane, cls, length)
    return _traffic_copy_with(track_cls, tr, "lane", lane, "cls", cls, "length_m", length)


cdef bint _same_wrong_way_driver(list conf, _V V_ids, _V V_mi, double *s, double *vs,
                                 Py_ssize_t j, double same_m, double same_v):
    """TrafficMonitor._same_wrong_way_driver on the memo table (rows as they stand at track ``j``'s turn)."""
    cdef Py_ssize_t i
    cdef long long tid
    cdef double sj = s[j], vsj = vs[j]
    if same_v <= 0.0:
        return False
    for i in range(len(conf)):
        tid = _pll(V_ids, i)[0]
        if (i != j and _pll_2(V_mi, tid, M_LIVE)[0] and _pll_2(V_mi, tid, M_WRONG_EMIT)[0]
                and conf[i].age_frames >= _pll_2(V_mi, tid, M_AGE)[0]
                and fabs(s[i] - sj) <= same_m and fabs(vs[i] - vsj) <= same_v):
            return True
    return False


include "_pairwise.pxi"


def weighted_median(votes, live, w):
    """The start-up yaw estimate of :meth:`YawEstimator.estimate_rad` for up to 64 votes: the ended tracks'
    ``votes`` (rad, each weighted as the largest live weight, or 1) and the running tracks' ``live`` votes (rad)
    with weights ``w``. Returns ``(median, stderr)`` (rad): the weighted median (the first value, in stable order of
    value, whose cumulative weight reaches half the total) and ``_median_stderr``'s error, in the reference's
    operations and summation order; None for more than 64 votes or a NaN among them or their weights (the
    caller's numpy path)."""
    cdef _V V_live, V_w
    _aview(live, cnp.NPY_FLOAT64, 1, False, True, &V_live, "live")
    _aview(w, cnp.NPY_FLOAT64, 1, False, True, &V_w, "w")
    return _weighted_median(votes, V_live, V_w)


@cython.cdivision(True)
cdef object _weighted_median(votes, _V V_live, _V V_w):
    """:func:`weighted_median` on views."""
    cdef Py_ssize_t nv = len(votes), nl = V_live.n[0], n = nv + nl, i, j
    cdef double top, x, wx, sw, mean, n_eff, var, d, half, acc
    if n > 64:
        return None
    cdef double v[64]
    cdef double wt[64]
    cdef double tmp[64]
    cdef int order[64]
    cdef int oi
    top = 1.0
    if nl:
        top = _pd1(V_w, 0)[0]
        for i in range(1, nl):
            if _pd1(V_w, i)[0] > top:
                top = _pd1(V_w, i)[0]
    i = 0
    for x in votes:
        v[i] = x
        wt[i] = top
        i += 1
    for j in range(nl):
        v[nv + j] = _pd1(V_live, j)[0]
        wt[nv + j] = _pd1(V_w, j)[0]
    for i in range(n):
        if v[i] != v[i] or wt[i] != wt[i]:
            return None
    # _median_stderr
    if n < 2:
        se = INFINITY
    else:
        sw = _pairwise_sum(wt, n)
        if sw <= 0.0:
            se = INFINITY
        else:
            for i in range(n):
                tmp[i] = wt[i] * v[i]
            mean = _pairwise_sum(tmp, n) / sw
            for i in range(n):
                tmp[i] = wt[i] * wt[i]
            n_eff = sw * sw / _pairwise_sum(tmp, n)
            if n_eff <= 1.0:
                se = INFINITY
            else:
                for i in range(n):
                    d = v[i] - mean
                    tmp[i] = wt[i] * (d * d)
                var = _pairwise_sum(tmp, n) / sw * n_eff / (n_eff - 1.0)
                se = 1.2533 * sqrt(var / n_eff)
    # stable sort by value (insertion sort), cumulative weights, bisect_left at half the total
    for i in range(n):
        oi = i
        j = i - 1
        while j >= 0 and v[order[j]] > v[oi]:
            order[j + 1] = order[j]
            j -= 1
        order[j + 1] = oi
    acc = 0.0
    for i in range(n):
        acc = wt[order[i]] if i == 0 else acc + wt[order[i]]
        tmp[i] = acc
    half = 0.5 * tmp[n - 1]
    i = 0
    while i < n and tmp[i] < half:
        i += 1
    return v[order[i]], se
