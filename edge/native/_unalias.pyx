# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Grating-lobe unaliasing kernel (edge.lane.detections.UnaliasByLane.unalias, its numpy reference): per near moving
detection its direction and the two neighbouring grating lobes (sin az +- lambda / d) projected to the ground and to
the road's lateral offset, each assigned to a lane; a detection in a lane of the other direction of travel is moved
to an alias that lies in a lane of its own. float64 as the reference, one rounding per operation; sin and asin are
the C library's (numpy's float64 sin and arcsin on x86-64 without AVX-512 and on arm64)."""

cimport cython
from libc.math cimport sin, asin, sqrt, fabs, fabsf

import numpy as np


cdef inline double _lane_dir(double u, const double[::1] centre, const double[::1] half_w,
                             const double[::1] dirs) noexcept nogil:
    """Direction (+1, -1) of the lane holding lateral offset ``u`` (m), 0 outside every lane (assign_lanes: the
    nearest centre, the first on a tie, must hold ``u`` within its half width)."""
    cdef Py_ssize_t l, k = 0, n = centre.shape[0]
    cdef double d, best = fabs(u - centre[0])
    for l in range(1, n):
        d = fabs(u - centre[l])
        if d < best:
            best = d
            k = l
    if not (half_w[k] - best >= 0.0):
        return 0.0
    return dirs[k]


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
            dj_[j] = _lane_dir(u, centre, half_w, dirs)
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
    cdef Py_ssize_t n = rng.shape[0], i, j
    cdef double u, sv
    cdef float half, dr
    out_arr = np.zeros(n, np.uint8)
    cdef unsigned char[::1] out = out_arr
    against_arr = np.zeros(n, np.uint8)
    cdef unsigned char[::1] against = against_arr
    cdef bint any_against = False
    cdef double neg = -<double>min_speed
    for i in range(n):
        if not keep[i]:
            continue
        sv = <double>v[i]
        u = <double>x[i] * cos_yaw + <double>y[i] * sin_yaw
        if not (_lane_dir(u, centre, half_w, dirs) * sv < neg):
            continue
        half = margin + k_sigma * rng[i]
        if (_lane_dir(u - <double>half, centre, half_w, dirs) * sv < neg
                and _lane_dir(u + <double>half, centre, half_w, dirs) * sv < neg):
            against[i] = 1
            any_against = True
    if not any_against:
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
