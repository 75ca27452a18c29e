# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Track-aided prediction kernel (edge.lane.pairs.PairStage.aided_predictions, its numpy / plain-Python reference):
per selected track its slant range, radial speed and four beat frequencies at this frame, for the tracks inside the
range limits that move and have no pairing within the aided gates. float64 as the reference, one rounding per
operation."""

cimport cython
from libc.math cimport sqrt, fabs, hypot, rint
from libc.stdlib cimport malloc, free

import numpy as np

cimport numpy as cnp

cnp.import_array()

include "_views.pxi"
include "_alloc.pxi"


@cython.cdivision(True)
cdef inline bint _predict_unpaired(double x0, double y0, double vx, double vy, double dt, double dz2, double r_lo,
                                   double r_hi, _V V_pair_r, _V V_pair_v, Py_ssize_t p, double gate_m,
                                   double gate_mps, double *r_out, double *v_out) noexcept nogil:
    """One track's prediction for :func:`predictions`: its range and radial speed ``dt`` later into ``r_out``,
    ``v_out``; False when it lies outside ``r_lo``..``r_hi``, moves slower than 1 m/s radially, or a pairing of this
    frame (``V_pair_r``, ``V_pair_v``, ``p`` of them) lies within the gates."""
    cdef double x = x0 + vx * dt, y = y0 + vy * dt
    cdef double r = sqrt(x * x + y * y + dz2)
    cdef double v = (x * vx + y * vy) / r
    cdef Py_ssize_t j
    if not (r >= r_lo and r <= r_hi and fabs(v) >= 1.0):
        return False
    for j in range(p):
        if fabs(<double>_pf1(V_pair_r, j)[0] - r) < gate_m and fabs(<double>_pf1(V_pair_v, j)[0] - v) < gate_mps:
            return False
    r_out[0] = r
    v_out[0] = v
    return True


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def predictions(state, sel, double dt, pair_r,
                pair_v, double dz2, double r_lo, double r_hi, double gate_m, double gate_mps,
                coef):
    """``state`` (n, >= 4) float64: x, y, vx, vy of every track; ``sel``: the rows looked at; ``pair_r``,
    ``pair_v`` (p,) float32: this frame's pairings; ``coef``: the pairing model's (a0..a3, b0..b3). Returns
    ``(range_m (m,), v_mps (m,), beats (m, 4))`` float64 of the tracks kept, in ``sel`` order."""
    cdef _V V_state
    _aview(state, cnp.NPY_FLOAT64, 2, False, True, &V_state, "state")
    cdef _V V_sel
    _aview(sel, cnp.NPY_LONGLONG, 1, False, True, &V_sel, "sel")
    cdef _V V_pair_r
    _aview(pair_r, cnp.NPY_FLOAT32, 1, False, True, &V_pair_r, "pair_r")
    cdef _V V_pair_v
    _aview(pair_v, cnp.NPY_FLOAT32, 1, False, True, &V_pair_v, "pair_v")
    cdef _V V_coef
    _aview(coef, cnp.NPY_FLOAT64, 1, False, True, &V_coef, "coef")
    cdef Py_ssize_t m = V_sel.n[0], p = V_pair_r.n[0], i, j, row, k = 0
    cdef double r, v
    r_arr = _empty1(cnp.NPY_FLOAT64, m)
    v_arr = _empty1(cnp.NPY_FLOAT64, m)
    f_arr = _empty2(cnp.NPY_FLOAT64, m, 4)
    cdef _V V_ro
    _aview(r_arr, cnp.NPY_FLOAT64, 1, True, True, &V_ro, "ro")
    cdef _V V_vo
    _aview(v_arr, cnp.NPY_FLOAT64, 1, True, True, &V_vo, "vo")
    cdef _V V_fo
    _aview(f_arr, cnp.NPY_FLOAT64, 2, True, True, &V_fo, "fo")
    for i in range(m):
        row = _pll(V_sel, i)[0]
        if not _predict_unpaired(_pd2(V_state, row, 0)[0], _pd2(V_state, row, 1)[0], _pd2(V_state, row, 2)[0],
                                 _pd2(V_state, row, 3)[0], dt, dz2, r_lo, r_hi, V_pair_r, V_pair_v, p, gate_m,
                                 gate_mps, &r, &v):
            continue
        _pd1(V_ro, k)[0] = r
        _pd1(V_vo, k)[0] = v
        for j in range(4):
            _pd2(V_fo, k, j)[0] = r * _pd1(V_coef, j)[0] + v * _pd1(V_coef, 4 + j)[0]
        k += 1
    return r_arr[:k], v_arr[:k], f_arr[:k]


cdef inline bint _is_bool1(object a, Py_ssize_t n):
    """``a`` is a 1-D bool numpy array of ``n`` elements (any stride; uint8 is not taken: the reference's ``~`` of
    a uint8 column is its bitwise complement)."""
    if not cnp.PyArray_Check(a):
        return False
    return (cnp.PyArray_NDIM(<cnp.ndarray>a) == 1 and cnp.PyArray_DIM(<cnp.ndarray>a, 0) == n
            and cnp.PyArray_TYPE(<cnp.ndarray>a) == cnp.NPY_BOOL)


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def select_predictions(state, confirmed, moved, hits, double dt, pair_r, pair_v, double dz2, double r_lo,
                       double r_hi, double gate_m, double gate_mps, coef, double far_min_range_m,
                       double far_min_hits, bint far_approaching):
    """The tracks' selection of track-aided pairing and :func:`predictions` of the selected ones in one call
    (edge.lane.pairs.PairStage.track_aided's reference: its numpy selection, then ``aided_predictions``). A track is
    looked at when ``confirmed``, or, with ``far_min_range_m`` > 0, when it ``moved``, has ``hits`` >=
    ``far_min_hits``, lies at ``hypot(x, y)`` >= ``far_min_range_m`` (libm's ``hypot``, the function numpy's calls)
    and, with ``far_approaching``, approaches (``x vx + y vy < 0``). ``state`` (n, >= 4) float64 of any strides,
    ``confirmed`` and ``moved`` (n,) bool, ``hits`` (n,) int32 or int64; the rest as :func:`predictions`. Returns
    :func:`predictions`' ``(range_m, v_mps, beats)`` (empty when no track is kept), or None when an array is not of
    these types (the caller then runs the reference)."""
    cdef Py_ssize_t n, m, p, i, j, k = 0
    cdef int th
    if not cnp.PyArray_Check(state) or cnp.PyArray_NDIM(<cnp.ndarray>state) != 2:
        return None
    n = cnp.PyArray_DIM(<cnp.ndarray>state, 0)
    if (cnp.PyArray_TYPE(<cnp.ndarray>state) != cnp.NPY_FLOAT64 or cnp.PyArray_DIM(<cnp.ndarray>state, 1) < 4
            or not _is_bool1(confirmed, n) or not _is_bool1(moved, n) or not cnp.PyArray_Check(hits)
            or cnp.PyArray_NDIM(<cnp.ndarray>hits) != 1 or cnp.PyArray_DIM(<cnp.ndarray>hits, 0) != n):
        return None
    th = cnp.PyArray_TYPE(<cnp.ndarray>hits)
    if not (th == cnp.NPY_INT32 or th == cnp.NPY_INT64) or not cnp.PyArray_Check(pair_r) or not cnp.PyArray_Check(pair_v):
        return None
    if (cnp.PyArray_TYPE(<cnp.ndarray>pair_r) != cnp.NPY_FLOAT32 or cnp.PyArray_TYPE(<cnp.ndarray>pair_v) != cnp.NPY_FLOAT32
            or cnp.PyArray_NDIM(<cnp.ndarray>pair_r) != 1 or cnp.PyArray_NDIM(<cnp.ndarray>pair_v) != 1
            or cnp.PyArray_DIM(<cnp.ndarray>pair_r, 0) != cnp.PyArray_DIM(<cnp.ndarray>pair_v, 0)):
        return None
    cdef _V V_state, V_conf, V_moved, V_hits, V_pair_r, V_pair_v, V_coef
    _aview(state, cnp.NPY_FLOAT64, 2, False, False, &V_state, "state")
    _aview(confirmed, cnp.NPY_BOOL, 1, False, False, &V_conf, "confirmed")
    _aview(moved, cnp.NPY_BOOL, 1, False, False, &V_moved, "moved")
    _aview(hits, th, 1, False, False, &V_hits, "hits")
    _aview(pair_r, cnp.NPY_FLOAT32, 1, False, False, &V_pair_r, "pair_r")
    _aview(pair_v, cnp.NPY_FLOAT32, 1, False, False, &V_pair_v, "pair_v")
    _aview(coef, cnp.NPY_FLOAT64, 1, False, True, &V_coef, "coef")
    if V_coef.n[0] != 8:
        raise ValueError("coef needs 8 values")
    p = V_pair_r.n[0]
    cdef double x0, y0, vx, vy, r, v, h
    cdef bint take
    cdef double c[8]
    for j in range(8):
        c[j] = _pd1(V_coef, j)[0]
    m = 0
    for i in range(n):
        m += _pu8(V_conf, i)[0] != 0
    if far_min_range_m > 0:
        m = n  # (an upper bound for the outputs)
    r_arr = _empty1(cnp.NPY_FLOAT64, m)
    v_arr = _empty1(cnp.NPY_FLOAT64, m)
    f_arr = _empty2(cnp.NPY_FLOAT64, m, 4)
    cdef double *ro = <double *>cnp.PyArray_DATA(r_arr)
    cdef double *vo = <double *>cnp.PyArray_DATA(v_arr)
    cdef double *fo = <double *>cnp.PyArray_DATA(f_arr)
    for i in range(n):
        x0 = _pd2(V_state, i, 0)[0]
        y0 = _pd2(V_state, i, 1)[0]
        vx = _pd2(V_state, i, 2)[0]
        vy = _pd2(V_state, i, 3)[0]
        take = _pu8(V_conf, i)[0] != 0
        if not take and far_min_range_m > 0 and _pu8(V_moved, i)[0] != 0:
            if th == cnp.NPY_INT32:
                h = <double>(<cnp.int32_t *>(V_hits.data + i * V_hits.s[0]))[0]
            else:
                h = <double>(<cnp.int64_t *>(V_hits.data + i * V_hits.s[0]))[0]
            if h >= far_min_hits and hypot(x0, y0) >= far_min_range_m:
                take = not far_approaching or x0 * vx + y0 * vy < 0.0
        if not take:
            continue
        if not _predict_unpaired(x0, y0, vx, vy, dt, dz2, r_lo, r_hi, V_pair_r, V_pair_v, p, gate_m, gate_mps, &r, &v):
            continue
        ro[k] = r
        vo[k] = v
        for j in range(4):
            fo[4 * k + j] = r * c[j] + v * c[4 + j]
        k += 1
    return r_arr[:k], v_arr[:k], f_arr[:k]


@cython.boundscheck(False)
@cython.wraparound(False)
def fit_prep(found, fsel, good, model_ab):
    """The least-squares set-up of track-aided pairing (edge.lane.pairs.PairStage._aided_fit's reference) for the
    rows of ``good`` (m,) bool/uint8: ``w = found[good]`` as float64, ``fs = fsel[good]``, the normal matrices
    ``einsum("mk,ki,kj->mij", w, A, A)`` and right-hand sides ``einsum("mk,ki,mk->mi", w, A, fs)[:, :, None]`` with
    ``A = model_ab`` (4, 2) float64. numpy's einsum of three operands (its generic sum of products) multiplies
    each term left to right and adds the four in segment order to a zero output: so here. ``found`` (m, 4)
    bool/uint8, ``fsel`` (m, 4) float64, any strides. Returns ``(w, fs, nrm (g, 2, 2), rhs (g, 2, 1), masks)``:
    ``masks`` has bit ``b`` set when a row's found segments, as bits, are ``b``."""
    cdef _V V_found, V_fsel, V_good, V_A
    _aview(good, cnp.NPY_BOOL, 1, False, False, &V_good, "good")
    _aview(found, cnp.NPY_BOOL, 2, False, False, &V_found, "found")
    _aview(fsel, cnp.NPY_FLOAT64, 2, False, False, &V_fsel, "fsel")
    _aview(model_ab, cnp.NPY_FLOAT64, 2, False, False, &V_A, "model_ab")
    cdef Py_ssize_t m = V_good.n[0], g = 0, i, k, q = 0, ii, jj
    if V_found.n[0] != m or V_found.n[1] != 4 or V_fsel.n[0] != m or V_fsel.n[1] != 4:
        raise ValueError("found and fsel: (m, 4) arrays needed")
    if V_A.n[0] != 4 or V_A.n[1] != 2:
        raise ValueError("model_ab: (4, 2) needed")
    cdef double A[4][2]
    for k in range(4):
        A[k][0] = _pd2(V_A, k, 0)[0]
        A[k][1] = _pd2(V_A, k, 1)[0]
    for i in range(m):
        g += _pu8(V_good, i)[0] != 0
    w_arr = _empty2(cnp.NPY_FLOAT64, g, 4)
    fs_arr = _empty2(cnp.NPY_FLOAT64, g, 4)
    nrm_arr = _empty3(cnp.NPY_FLOAT64, g, 2, 2)
    rhs_arr = _empty3(cnp.NPY_FLOAT64, g, 2, 1)
    cdef double *w = <double *>cnp.PyArray_DATA(w_arr)
    cdef double *fs = <double *>cnp.PyArray_DATA(fs_arr)
    cdef double *nrm = <double *>cnp.PyArray_DATA(nrm_arr)
    cdef double *rhs = <double *>cnp.PyArray_DATA(rhs_arr)
    cdef double acc
    cdef long masks = 0
    cdef int bits
    for i in range(m):
        if not _pu8(V_good, i)[0]:
            continue
        bits = 0
        for k in range(4):
            w[4 * q + k] = 1.0 if _pu8_2(V_found, i, k)[0] else 0.0
            fs[4 * q + k] = _pd2(V_fsel, i, k)[0]
            if _pu8_2(V_found, i, k)[0]:
                bits |= 1 << k
        masks |= 1L << bits
        for ii in range(2):
            for jj in range(2):
                acc = 0.0
                for k in range(4):
                    acc = acc + (w[4 * q + k] * A[k][ii]) * A[k][jj]
                nrm[4 * q + 2 * ii + jj] = acc
            acc = 0.0
            for k in range(4):
                acc = acc + (w[4 * q + k] * A[k][ii]) * fs[4 * q + k]
            rhs[2 * q + ii] = acc
        q += 1
    return w_arr, fs_arr, nrm_arr, rhs_arr, masks


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def fit_finish(w_a, fs_a, sol, pred, good, found, bsel, r_hat, v_hat, f_hat, bin_hz, long long n_bins,
               double gate_m, double gate_mps):
    """The rest of track-aided pairing's fit after the solve (edge.lane.pairs.PairStage._aided_fit's reference):
    ``w``, ``fs`` (g, 4) from :func:`fit_prep`, the solutions ``sol`` (g, 2) (range, speed) and their beats ``pred =
    sol @ model_ab.T`` (g, 4) (BLAS, the caller's); the residual ``sqrt((w (fs - pred)^2).sum(1) / w.sum(1))`` (each
    sum in segment order, as numpy's reduction of four), the gates ``|sol - (r_hat, v_hat)[good]| < (gate_m,
    gate_mps)``, and per kept track its bins: ``bsel`` where ``found``, else ``rint(f_hat / bin_hz) mod n_bins``
    (numpy's floored remainder). Returns ``(bins (c, 4) int64, range_m, v_mps, residual_hz (c,) float32)``."""
    cdef _V V_w, V_fs, V_sol, V_pred, V_good, V_found, V_bsel, V_r, V_v, V_f, V_bin
    _aview(w_a, cnp.NPY_FLOAT64, 2, False, False, &V_w, "w")
    _aview(fs_a, cnp.NPY_FLOAT64, 2, False, False, &V_fs, "fs")
    _aview(sol, cnp.NPY_FLOAT64, 2, False, False, &V_sol, "sol")
    _aview(pred, cnp.NPY_FLOAT64, 2, False, False, &V_pred, "pred")
    _aview(good, cnp.NPY_BOOL, 1, False, False, &V_good, "good")
    _aview(found, cnp.NPY_BOOL, 2, False, False, &V_found, "found")
    _aview(bsel, cnp.NPY_INT64, 2, False, False, &V_bsel, "bsel")
    _aview(r_hat, cnp.NPY_FLOAT64, 1, False, False, &V_r, "r_hat")
    _aview(v_hat, cnp.NPY_FLOAT64, 1, False, False, &V_v, "v_hat")
    _aview(f_hat, cnp.NPY_FLOAT64, 2, False, False, &V_f, "f_hat")
    _aview(bin_hz, cnp.NPY_FLOAT64, 1, False, False, &V_bin, "bin_hz")
    cdef Py_ssize_t m = V_good.n[0], g = V_w.n[0], i, q, k, c = 0, n
    if (V_w.n[1] != 4 or V_fs.n[0] != g or V_fs.n[1] != 4 or V_sol.n[0] != g or V_sol.n[1] != 2
            or V_pred.n[0] != g or V_pred.n[1] != 4 or V_found.n[0] != m or V_found.n[1] != 4 or V_bsel.n[0] != m
            or V_bsel.n[1] != 4 or V_r.n[0] != m or V_v.n[0] != m or V_f.n[0] != m or V_f.n[1] != 4
            or V_bin.n[0] != 4):
        raise ValueError("fit_finish: inconsistent shapes")
    if n_bins <= 0:
        raise ValueError("n_bins must be positive")
    q = 0
    for i in range(m):
        q += _pu8(V_good, i)[0] != 0
    if q != g:
        raise ValueError("fit_finish: good does not select g rows")
    cdef unsigned char *close = <unsigned char *>malloc(g + 1)
    cdef Py_ssize_t *row = <Py_ssize_t *>malloc((g + 1) * sizeof(Py_ssize_t))
    if close == NULL or row == NULL:
        free(close)
        free(row)
        raise MemoryError()
    cdef double d, s, ws, e
    cdef long long b
    cdef long long *bo
    cdef float *ro
    cdef float *vo
    cdef float *eo
    try:
        q = 0
        for i in range(m):
            if not _pu8(V_good, i)[0]:
                continue
            row[q] = i
            close[q] = (fabs(_pd2(V_sol, q, 0)[0] - _pd1(V_r, i)[0]) < gate_m
                        and fabs(_pd2(V_sol, q, 1)[0] - _pd1(V_v, i)[0]) < gate_mps)
            c += close[q]
            q += 1
        bins_arr = _empty2(cnp.NPY_INT64, c, 4)
        r_arr = _empty1(cnp.NPY_FLOAT32, c)
        v_arr = _empty1(cnp.NPY_FLOAT32, c)
        res_arr = _empty1(cnp.NPY_FLOAT32, c)
        bo = <long long *>cnp.PyArray_DATA(bins_arr)
        ro = <float *>cnp.PyArray_DATA(r_arr)
        vo = <float *>cnp.PyArray_DATA(v_arr)
        eo = <float *>cnp.PyArray_DATA(res_arr)
        n = 0
        for q in range(g):
            if not close[q]:
                continue
            i = row[q]
            s = 0.0
            ws = 0.0
            for k in range(4):
                d = _pd2(V_fs, q, k)[0] - _pd2(V_pred, q, k)[0]
                e = _pd2(V_w, q, k)[0] * (d * d)
                if k == 0:
                    s = e
                    ws = _pd2(V_w, q, k)[0]
                else:
                    s = s + e
                    ws = ws + _pd2(V_w, q, k)[0]
            eo[n] = <float>sqrt(s / ws)
            ro[n] = <float>_pd2(V_sol, q, 0)[0]
            vo[n] = <float>_pd2(V_sol, q, 1)[0]
            for k in range(4):
                if _pu8_2(V_found, i, k)[0]:
                    bo[4 * n + k] = _pi64_2(V_bsel, i, k)[0]
                else:
                    b = <long long>rint(_pd2(V_f, i, k)[0] / _pd1(V_bin, k)[0])
                    b = b % n_bins
                    if b < 0:
                        b += n_bins
                    bo[4 * n + k] = b
            n += 1
        return bins_arr, r_arr, v_arr, res_arr
    finally:
        free(close)
        free(row)
