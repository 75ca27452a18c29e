# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Near-face kernel (edge.lane.detections.NearFaces, whose numpy reference is edge.dsp.pairing.nearest_of_clusters
with its extent and NearFaces.body_extent): in one pass over the detection pairs, which detections are the body of a
nearer one (up to ``length`` nearer in range, within ``speed`` in radial speed and ``lateral`` across) and each
kept detection's body length along the road. float32 as the reference, one rounding per operation."""

cimport cython
from libc.math cimport sqrtf, fabsf, NAN

import numpy as np


@cython.boundscheck(False)
@cython.wraparound(False)
def near_faces(const float[::1] rng, const float[::1] v, const float[::1] x, const unsigned char[::1] keep_in,
               float length, float speed, float lateral, float dz2):
    """``rng``, ``v``, ``x`` (n,) float32: slant range (m), radial speed (m/s), lateral position (m); ``keep_in``
    (n,) uint8: still kept. Returns ``(keep (n,) uint8, body_extent (n,) float32)``: a detection is dropped when
    another lies 0 < dr <= ``length`` nearer with |dv| <= ``speed`` and |dx| <= ``lateral``; the extent of a kept
    one is the along-road ground length to the farthest detection dropped behind it (NaN for dropped ones)."""
    cdef Py_ssize_t n = rng.shape[0], i, j
    cdef float r, e, x2, t, near, far, fr
    keep_arr = np.empty(n, np.uint8)
    cdef unsigned char[::1] keep = keep_arr
    ext_arr = np.zeros(n, np.float32)
    cdef float[::1] ext = ext_arr
    for i in range(n):
        keep[i] = 1
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
    return keep_arr, ext_arr


from libc.math cimport fabs


@cython.boundscheck(False)
@cython.wraparound(False)
def track_extents(object tracks, const float[::1] d_range, const float[::1] d_speed, const float[::1] body,
                  double range_gate, double speed_gate):
    """Per published track (``range_m``, ``radial_speed_mps`` of each of ``tracks``) the ``body`` extent of the
    detection it follows: the nearest in range (the first of equals) within ``range_gate`` of its range and
    ``speed_gate`` of its radial speed, the differences in float64; NaN without one. The numpy form is
    ``edge.pipelines.lane.LanePipeline.track_extents`` (the same values)."""
    cdef Py_ssize_t nt = len(tracks), nd = d_range.shape[0], i = 0, j, best
    cdef double tr, tv, dr, bd
    out_arr = np.empty(nt)
    cdef double[::1] out = out_arr
    for t in tracks:
        tr = t.range_m
        tv = t.radial_speed_mps
        best = -1
        bd = 0.0
        for j in range(nd):
            dr = fabs(<double>d_range[j] - tr)
            if dr <= range_gate and fabs(<double>d_speed[j] - tv) <= speed_gate and (best < 0 or dr < bd):
                best = j
                bd = dr
        out[i] = body[best] if best >= 0 else NAN
        i += 1
    return out_arr
