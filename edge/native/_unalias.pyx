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

include "_roadfilters.pxi"


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def unalias(const float[::1] rng, const float[::1] v, const float[::1] az, const double[::1] centre,
            const double[::1] half_w, const double[::1] dirs, float min_speed, float max_range, double period,
            double dz2, double cos_yaw, double sin_yaw):
    """``rng``, ``v``, ``az`` (n,) float32: slant range (m), radial speed (m/s), angle (rad); lanes: ``centre``,
    ``half_w`` (L,) m and ``dirs`` (L,) +-1 (L >= 1); detections with |v| >= ``min_speed`` and range <=
    ``max_range`` are looked at; ``period``: the grating-lobe period in sin az; ``dz2``: the squared height
    difference (m^2); ``cos_yaw``, ``sin_yaw``: the road's direction. Returns the new angles (n,) float32, or None
    when none moves."""
    cdef Py_ssize_t n = rng.shape[0], i, j
    cdef double s0, s, r, x, y2, u, sign, d0, dj, alt
    cdef double offs[3]
    cdef double dj_[3]
    offs[0] = 0.0
    offs[1] = period
    offs[2] = -period
    out_arr = None
    cdef float[::1] out
    for i in range(n):
        if not (fabsf(v[i]) >= min_speed and rng[i] <= max_range):
            continue
        sign = 1.0 if v[i] > 0 else (-1.0 if v[i] < 0 else (0.0 if v[i] == 0 else v[i]))
        s0 = sin(<double>az[i])
        r = <double>rng[i]
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
            dj_[j] = _lane_dir_p(u, &centre[0], &half_w[0], &dirs[0], centre.shape[0])
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
def glint(const float[::1] rng, const float[::1] v, const float[::1] az, const float[::1] x, const float[::1] y,
          const unsigned char[::1] keep, const double[::1] centre, const double[::1] half_w, const double[::1] dirs,
          double cos_yaw, double sin_yaw, float min_speed, float margin, float k_sigma, float length, float speed,
          double beamwidth_sin):
    """edge.lane.detections.AgainstLaneGlint.glint in one pass. ``rng``, ``v``, ``az``, ``x``, ``y`` (n,) float32
    (m, m/s, rad, m, m); ``keep`` (n,) uint8; lanes as :func:`unalias`; ``min_speed`` (m/s); the direction margin
    ``margin + k_sigma * range`` (m, float32 as the reference's); ``length`` (m), ``speed`` (m/s), ``beamwidth_sin``
    the gates to a nearer vehicle. Returns (n,) uint8: the kept detections that are glint of a nearer body."""
    cdef Py_ssize_t n = rng.shape[0]
    out_arr = np.zeros(n, np.uint8)
    cdef unsigned char[::1] out = out_arr
    against_arr = np.zeros(n, np.uint8)
    cdef unsigned char[::1] against = against_arr
    sin_arr = np.empty(n, np.float64)
    cdef double[::1] s = sin_arr
    if n and centre.shape[0]:
        _glint_core(&rng[0], &v[0], &az[0], &x[0], &y[0], &keep[0], n, &centre[0], &half_w[0], &dirs[0],
                    centre.shape[0], cos_yaw, sin_yaw, min_speed, margin, k_sigma, length, speed, beamwidth_sin,
                    &against[0], &s[0], &out[0])
    return out_arr
    sin_arr = np.empty(n, np.float64)
    cdef double[::1] s = sin_arr
    for j in range(n):
        s[j] = sin(<double>az[j])
    for i in range(n):
        if not against[i]:
            continue
        for j in range(n):
            if not keep[j] or against[j]:
                continue
            dr = rng[i] - rng[j]
            if dr > 0 and dr <= length and fabsf(v[i] - v[j]) <= speed and fabs(s[i] - s[j]) <= beamwidth_sin:
                out[i] = 1
                break
    return out_arr
