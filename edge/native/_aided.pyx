# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Track-aided prediction kernel (edge.lane.pairs.PairStage.aided_predictions, its numpy / plain-Python reference):
per selected track its slant range, radial speed and four beat frequencies at this frame, for the tracks inside the
range limits that move and have no pairing within the aided gates. float64 as the reference, one rounding per
operation."""

cimport cython
from libc.math cimport sqrt, fabs

import numpy as np


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def predictions(const double[:, ::1] state, const long long[::1] sel, double dt, const float[::1] pair_r,
                const float[::1] pair_v, double dz2, double r_lo, double r_hi, double gate_m, double gate_mps,
                const double[::1] coef):
    """``state`` (n, >= 4) float64: x, y, vx, vy of every track; ``sel``: the rows looked at; ``pair_r``,
    ``pair_v`` (p,) float32: this frame's pairings; ``coef``: the pairing model's (a0..a3, b0..b3). Returns
    ``(range_m (m,), v_mps (m,), beats (m, 4))`` float64 of the tracks kept, in ``sel`` order."""
    cdef Py_ssize_t m = sel.shape[0], p = pair_r.shape[0], i, j, row, k = 0
    cdef double x, y, vx, vy, r, v
    cdef bint paired
    r_arr = np.empty(m, np.float64)
    v_arr = np.empty(m, np.float64)
    f_arr = np.empty((m, 4), np.float64)
    cdef double[::1] ro = r_arr
    cdef double[::1] vo = v_arr
    cdef double[:, ::1] fo = f_arr
    for i in range(m):
        row = sel[i]
        vx = state[row, 2]
        vy = state[row, 3]
        x = state[row, 0] + vx * dt
        y = state[row, 1] + vy * dt
        r = sqrt(x * x + y * y + dz2)
        v = (x * vx + y * vy) / r
        if not (r >= r_lo and r <= r_hi and fabs(v) >= 1.0):
            continue
        paired = False
        for j in range(p):
            if fabs(<double>pair_r[j] - r) < gate_m and fabs(<double>pair_v[j] - v) < gate_mps:
                paired = True
                break
        if paired:
            continue
        ro[k] = r
        vo[k] = v
        for j in range(4):
            fo[k, j] = r * coef[j] + v * coef[4 + j]
        k += 1
    return r_arr[:k], v_arr[:k], f_arr[:k]
