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
include "_alloc.pxi"

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


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def glint(rng, v, az, x, y,
          keep, centre, half_w, dirs,
          double cos_yaw, double sin_yaw, float min_speed, float margin, float k_sigma, float length, float speed,
          double beamwidth_sin):
    """edge.lane.detections.AgainstLaneGlint.glint in one pass. ``rng``, ``v``, ``az``, ``x``, ``y`` (n,) float32
    (m, m/s, rad, m, m); ``keep`` (n,) uint8; lanes as :func:`unalias`; ``min_speed`` (m/s); the direction margin
    ``margin + k_sigma * range`` (m, float32 as the reference's); ``length`` (m), ``speed`` (m/s), ``beamwidth_sin``
    the gates to a nearer vehicle. Returns (n,) uint8: the kept detections that are glint of a nearer body."""
    cdef _V V_rng
    _aview(rng, cnp.NPY_FLOAT32, 1, False, True, &V_rng, "rng")
    cdef _V V_v
    _aview(v, cnp.NPY_FLOAT32, 1, False, True, &V_v, "v")
    cdef _V V_az
    _aview(az, cnp.NPY_FLOAT32, 1, False, True, &V_az, "az")
    cdef _V V_x
    _aview(x, cnp.NPY_FLOAT32, 1, False, True, &V_x, "x")
    cdef _V V_y
    _aview(y, cnp.NPY_FLOAT32, 1, False, True, &V_y, "y")
    cdef _V V_keep
    _aview(keep, cnp.NPY_UINT8, 1, False, True, &V_keep, "keep")
    cdef _V V_centre
    _aview(centre, cnp.NPY_FLOAT64, 1, False, True, &V_centre, "centre")
    cdef _V V_half_w
    _aview(half_w, cnp.NPY_FLOAT64, 1, False, True, &V_half_w, "half_w")
    cdef _V V_dirs
    _aview(dirs, cnp.NPY_FLOAT64, 1, False, True, &V_dirs, "dirs")
    cdef Py_ssize_t n = V_rng.n[0]
    out_arr = _zeros1(cnp.NPY_UINT8, n)
    cdef _V V_out
    _aview(out_arr, cnp.NPY_UINT8, 1, True, True, &V_out, "out")
    against_arr = _zeros1(cnp.NPY_UINT8, n)
    cdef _V V_against
    _aview(against_arr, cnp.NPY_UINT8, 1, True, True, &V_against, "against")
    sin_arr = _empty1(cnp.NPY_FLOAT64, n)
    cdef double[::1] s = sin_arr
    if n and V_centre.n[0]:
        _glint_core(<float*>V_rng.data, <float*>V_v.data, <float*>V_az.data, <float*>V_x.data, <float*>V_y.data,
                    <cnp.uint8_t*>V_keep.data, n, <double*>V_centre.data, <double*>V_half_w.data, <double*>V_dirs.data,
                    V_centre.n[0], cos_yaw, sin_yaw, min_speed, margin, k_sigma, length, speed, beamwidth_sin,
                    <cnp.uint8_t*>V_against.data, &s[0], <cnp.uint8_t*>V_out.data)
    return out_arr
    sin_arr = _empty1(cnp.NPY_FLOAT64, n)
    cdef double[::1] s = sin_arr
    for j in range(n):
        s[j] = sin(<double>_pf1(V_az, j)[0])
    for i in range(n):
        if not _pu8(V_against, i)[0]:
            continue
        for j in range(n):
            if not _pu8(V_keep, j)[0] or _pu8(V_against, j)[0]:
                continue
            dr = _pf1(V_rng, i)[0] - _pf1(V_rng, j)[0]
            if (dr > 0 and dr <= length and fabsf(_pf1(V_v, i)[0] - _pf1(V_v, j)[0]) <= speed
                    and fabs(s[i] - s[j]) <= beamwidth_sin):
                _pu8(V_out, i)[0] = 1
                break
    return out_arr
