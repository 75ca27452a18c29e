# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Near-face kernel (edge.lane.detections.NearFaces, whose numpy reference is edge.dsp.pairing.nearest_of_clusters
with its extent and NearFaces.body_extent): in one pass over the detection pairs, which detections are the body of a
nearer one (up to ``length`` nearer in range, within ``speed`` in radial speed and ``lateral`` across) and each
kept detection's body length along the road. float32 as the reference, one rounding per operation."""

cimport cython

import numpy as np

include "_roadfilters.pxi"


@cython.boundscheck(False)
@cython.wraparound(False)
def near_faces(const float[::1] rng, const float[::1] v, const float[::1] x, const unsigned char[::1] keep_in,
               float length, float speed, float lateral, float dz2):
    """``rng``, ``v``, ``x`` (n,) float32: slant range (m), radial speed (m/s), lateral position (m); ``keep_in``
    (n,) uint8: still kept. Returns ``(keep (n,) uint8, body_extent (n,) float32)``: a detection is dropped when
    another lies 0 < dr <= ``length`` nearer with |dv| <= ``speed`` and |dx| <= ``lateral``; the extent of a kept
    one is the along-road ground length to the farthest detection dropped behind it (NaN for dropped ones)."""
    cdef Py_ssize_t n = rng.shape[0]
    keep_arr = np.empty(n, np.uint8)
    cdef unsigned char[::1] keep = keep_arr
    ext_arr = np.zeros(n, np.float32)
    cdef float[::1] ext = ext_arr
    if n:
        _near_faces_core(&rng[0], &v[0], &x[0], &keep_in[0], n, length, speed, lateral, dz2, &keep[0], &ext[0])
    return keep_arr, ext_arr



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
