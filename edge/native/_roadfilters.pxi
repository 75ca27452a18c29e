# The road-geometry filters' loops on raw pointers, shared by _faces (near_faces), _unalias (unalias) and _detect
# (the detection stage after the projection) (`include "_roadfilters.pxi"`). Float arithmetic as the numpy references
# (edge.lane.detections), one rounding per operation.

from libc.math cimport sin, sqrt, sqrtf, fabs, fabsf, NAN


cdef inline double _lane_dir_p(double u, const double *centre, const double *half_w, const double *dirs,
                               Py_ssize_t n_lanes) noexcept nogil:
    """Direction (+1, -1) of the lane holding lateral offset ``u`` (m), 0 outside every lane (assign_lanes: the
    nearest centre, the first on a tie, must hold ``u`` within its half width); ``n_lanes`` >= 1."""
    cdef Py_ssize_t l, k = 0
    cdef double d, best = fabs(u - centre[0])
    for l in range(1, n_lanes):
        d = fabs(u - centre[l])
        if d < best:
            best = d
            k = l
    if not (half_w[k] - best >= 0.0):
        return 0.0
    return dirs[k]


cdef void _near_faces_core(const float *rng, const float *v, const float *x, const unsigned char *keep_in,
                           Py_ssize_t n, float length, float speed, float lateral, float dz2, unsigned char *keep,
                           float *ext) noexcept nogil:
    """NearFaces: ``keep`` (n) 0 where a detection lies 0 < dr <= ``length`` behind another within ``speed`` and
    ``lateral`` (and where ``keep_in`` is 0); ``ext`` (n) the kept ones' along-road body length, NaN for the
    others."""
    cdef Py_ssize_t i, j
    cdef float r, e, x2, t, near, far, fr
    for i in range(n):
        keep[i] = 1
        ext[i] = 0
    for i in range(n):  # i behind j: i is j's body
        for j in range(n):
            r = rng[i] - rng[j]
            if (r > 0 and r <= length and fabsf(x[i] - x[j]) <= lateral and fabsf(v[i] - v[j]) <= speed):
                keep[i] = 0
                if r > ext[j]:
                    ext[j] = r
    for i in range(n):
        keep[i] = keep[i] and keep_in[i]
        e = ext[i] if keep[i] else <float>NAN
        x2 = x[i] * x[i]
        t = rng[i] * rng[i] - dz2 - x2
        near = sqrtf(t if (t >= 0 or t != t) else <float>0)  # (np.maximum: -0 and NaN kept)
        fr = rng[i] + e
        t = fr * fr - dz2 - x2
        far = sqrtf(t if (t >= 0 or t != t) else <float>0)
        ext[i] = far - near
