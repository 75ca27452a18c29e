# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Track-aided prediction kernel (edge.lane.pairs.PairStage.aided_predictions, its numpy / plain-Python reference):
per selected track its slant range, radial speed and four beat frequencies at this frame, for the tracks inside the
range limits that move and have no pairing within the aided gates. float64 as the reference, one rounding per
operation."""

cimport cython
from libc.math cimport sqrt, fabs

import numpy as np

cimport numpy as cnp

cnp.import_array()

include "_views.pxi"
include "_alloc.pxi"


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
    cdef double x, y, vx, vy, r, v
    cdef bint paired
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
        vx = _pd2(V_state, row, 2)[0]
        vy = _pd2(V_state, row, 3)[0]
        x = _pd2(V_state, row, 0)[0] + vx * dt
        y = _pd2(V_state, row, 1)[0] + vy * dt
        r = sqrt(x * x + y * y + dz2)
        v = (x * vx + y * vy) / r
        if not (r >= r_lo and r <= r_hi and fabs(v) >= 1.0):
            continue
        paired = False
        for j in range(p):
            if fabs(<double>_pf1(V_pair_r, j)[0] - r) < gate_m and fabs(<double>_pf1(V_pair_v, j)[0] - v) < gate_mps:
                paired = True
                break
        if paired:
            continue
        _pd1(V_ro, k)[0] = r
        _pd1(V_vo, k)[0] = v
        for j in range(4):
            _pd2(V_fo, k, j)[0] = r * _pd1(V_coef, j)[0] + v * _pd1(V_coef, 4 + j)[0]
        k += 1
    return r_arr[:k], v_arr[:k], f_arr[:k]
