# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Near-face kernel (edge.lane.detections.NearFaces, whose numpy reference is edge.dsp.pairing.nearest_of_clusters
with its extent and NearFaces.body_extent): in one pass over the detection pairs, which detections are the body of a
nearer one (up to ``length`` nearer in range, within ``speed`` in radial speed and ``lateral`` across) and each
kept detection's body length along the road. float32 as the reference, one rounding per operation."""

cimport cython

import numpy as np

cimport numpy as cnp

cnp.import_array()

include "_views.pxi"
include "_alloc.pxi"

include "_roadfilters.pxi"


@cython.boundscheck(False)
@cython.wraparound(False)
def near_faces(rng, v, x, keep_in,
               float length, float speed, float lateral, float dz2):
    """``rng``, ``v``, ``x`` (n,) float32: slant range (m), radial speed (m/s), lateral position (m); ``keep_in``
    (n,) uint8: still kept. Returns ``(keep (n,) uint8, body_extent (n,) float32)``: a detection is dropped when
    another lies 0 < dr <= ``length`` nearer with |dv| <= ``speed`` and |dx| <= ``lateral``; the extent of a kept
    one is the along-road ground length to the farthest detection dropped behind it (NaN for dropped ones)."""
    cdef _V V_rng
    _aview(rng, cnp.NPY_FLOAT32, 1, False, True, &V_rng, "rng")
    cdef _V V_v
    _aview(v, cnp.NPY_FLOAT32, 1, False, True, &V_v, "v")
    cdef _V V_x
    _aview(x, cnp.NPY_FLOAT32, 1, False, True, &V_x, "x")
    cdef _V V_keep_in
    _aview(keep_in, cnp.NPY_UINT8, 1, False, True, &V_keep_in, "keep_in")
    cdef Py_ssize_t n = V_rng.n[0]
    keep_arr = _empty1(cnp.NPY_UINT8, n)
    cdef _V V_keep
    _aview(keep_arr, cnp.NPY_UINT8, 1, True, True, &V_keep, "keep")
    ext_arr = _zeros1(cnp.NPY_FLOAT32, n)
    cdef _V V_ext
    _aview(ext_arr, cnp.NPY_FLOAT32, 1, True, True, &V_ext, "ext")
    if n:
        _near_faces_core(<float*>V_rng.data, <float*>V_v.data, <float*>V_x.data, <cnp.uint8_t*>V_keep_in.data, n,
                         length, speed, lateral, dz2, <cnp.uint8_t*>V_keep.data, <float*>V_ext.data)
    return keep_arr, ext_arr



@cython.boundscheck(False)
@cython.wraparound(False)
def track_extents(object tracks, d_range, d_speed, body,
                  double range_gate, double speed_gate):
    """Per published track (``range_m``, ``radial_speed_mps`` of each of ``tracks``) the ``body`` extent of the
    detection it follows: the nearest in range (the first of equals) within ``range_gate`` of its range and
    ``speed_gate`` of its radial speed, the differences in float64; NaN without one. The numpy form is
    ``edge.pipelines.lane.LanePipeline.track_extents`` (the same values)."""
    cdef _V V_d_range
    _aview(d_range, cnp.NPY_FLOAT32, 1, False, True, &V_d_range, "d_range")
    cdef _V V_d_speed
    _aview(d_speed, cnp.NPY_FLOAT32, 1, False, True, &V_d_speed, "d_speed")
    cdef _V V_body
    _aview(body, cnp.NPY_FLOAT32, 1, False, True, &V_body, "body")
    cdef Py_ssize_t nt = len(tracks), nd = V_d_range.n[0], i = 0, j, best
    cdef double tr, tv, dr, bd
    out_arr = _empty1(cnp.NPY_FLOAT64, nt)
    cdef _V V_out
    _aview(out_arr, cnp.NPY_FLOAT64, 1, True, True, &V_out, "out")
    for t in tracks:
        tr = t.range_m
        tv = t.radial_speed_mps
        best = -1
        bd = 0.0
        for j in range(nd):
            dr = fabs(<double>_pf1(V_d_range, j)[0] - tr)
            if dr <= range_gate and fabs(<double>_pf1(V_d_speed, j)[0] - tv) <= speed_gate and (best < 0 or dr < bd):
                best = j
                bd = dr
        _pd1(V_out, i)[0] = _pf1(V_body, best)[0] if best >= 0 else NAN
        i += 1
    return out_arr
