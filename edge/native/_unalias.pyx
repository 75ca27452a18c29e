# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Grating-lobe unaliasing kernel (edge.lane.detections.UnaliasByLane.unalias, its numpy reference): per near moving
detection its direction and the two neighbouring grating lobes (sin az +- lambda / d) projected to the ground and to
the road's lateral offset, each assigned to a lane; a detection in a lane of the other direction of travel is moved
to an alias that lies in a lane of its own. float64 as the reference, one rounding per operation; sin and asin are
the C library's (numpy's float64 sin and arcsin on x86-64 without AVX-512 and on arm64)."""

cimport cython
from libc.math cimport asin

import numpy as np

cimport numpy as cnp

cnp.import_array()

include "_views.pxi"
include "_roadfilters.pxi"


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def unalias(rng, v, az, centre,
            half_w, dirs, float min_speed, float max_range, double period,
            double dz2, double cos_yaw, double sin_yaw):
    """``rng``, ``v``, ``az`` (n,) float32: slant range (m), radial speed (m/s), angle (rad); lanes: ``centre``,
    ``half_w`` (L,) m and ``dirs`` (L,) +-1 (L >= 1); detections with |v| >= ``min_speed`` and range <=
    ``max_range`` are looked at; ``period``: the grating-lobe period in sin az; ``dz2``: the squared height
    difference (m^2); ``cos_yaw``, ``sin_yaw``: the road's direction. Returns the new angles (n,) float32, or None
    when none moves."""
    cdef _V V_rng
    _aview(rng, cnp.NPY_FLOAT32, 1, False, True, &V_rng, "rng")
    cdef _V V_v
    _aview(v, cnp.NPY_FLOAT32, 1, False, True, &V_v, "v")
    cdef _V V_az
    _aview(az, cnp.NPY_FLOAT32, 1, False, True, &V_az, "az")
    cdef _V V_centre
    _aview(centre, cnp.NPY_FLOAT64, 1, False, True, &V_centre, "centre")
    cdef _V V_half_w
    _aview(half_w, cnp.NPY_FLOAT64, 1, False, True, &V_half_w, "half_w")
    cdef _V V_dirs
    _aview(dirs, cnp.NPY_FLOAT64, 1, False, True, &V_dirs, "dirs")
    cdef Py_ssize_t n = V_rng.n[0], i, j
    cdef double s0, s, r, x, y2, u, sign, d0, dj, alt
    cdef double offs[3]
    cdef double dj_[3]
    offs[0] = 0.0
    offs[1] = period
    offs[2] = -period
    out_arr = None
    cdef float[::1] out
    for i in range(n):
        if not (fabsf(_pf1(V_v, i)[0]) >= min_speed and _pf1(V_rng, i)[0] <= max_range):
            continue
        sign = 1.0 if _pf1(V_v, i)[0] > 0 else (
            -1.0 if _pf1(V_v, i)[0] < 0 else (0.0 if _pf1(V_v, i)[0] == 0 else _pf1(V_v, i)[0]))
        s0 = sin(<double>_pf1(V_az, i)[0])
        r = <double>_pf1(V_rng, i)[0]
        for j in range(3):
            s = s0 + offs[j]
            if s < -1.0:
                s = -1.0
            if s > 1.0:
                s = 1.0
            x = r * s
            y2 = (r * r) * (1.0 - s * s) - dz2
            if y2 < 0.0:
                y2 = 0.0
            u = x * cos_yaw + sqrt(y2) * sin_yaw
            dj_[j] = _lane_dir_p(u, <double*>V_centre.data, <double*>V_half_w.data, <double*>V_dirs.data, V_centre.n[0])
        if not (dj_[0] == -sign):
            continue
        for j in range(1, 3):
            alt = s0 + offs[j]
            if fabs(alt) <= 1.0 and dj_[j] == sign:
                if out_arr is None:
                    out_arr = np.array(az, np.float32)
                    out = out_arr
                out[i] = <float>asin(alt)
                break
    return out_arr
