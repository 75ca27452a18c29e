# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Detection-stage kernel (edge.lane.detections.DetectionStage after the direction filters, whose numpy reference is
DetectionStage.reference): the ground projection from numpy's sin and cos of the angles (eq. 16), the near faces and
the body lengths (NearFaces) and the kept rows of every output column, in one call. The arrays are read through the
numpy C API (_arrays.pxi), not typed memoryviews. float32 as the reference, one rounding per operation."""

cimport cython
cimport numpy as cnp
from libc.stdlib cimport malloc, free
from libc.string cimport memcpy

cnp.import_array()

include "_arrays.pxi"
include "_roadfilters.pxi"


cdef object _take(object a, int typenum, Py_ssize_t itemsize, const unsigned char *keep, Py_ssize_t n,
                  Py_ssize_t m):
    """The ``m`` rows of the 1-D array ``a`` (``n`` rows, checked by the caller) where ``keep`` is 1."""
    cdef cnp.ndarray out = _new(typenum, m)
    cdef const char *src = <const char *>cnp.PyArray_DATA(<cnp.ndarray>a)
    cdef char *dst = <char *>cnp.PyArray_DATA(out)
    cdef Py_ssize_t i, j = 0
    for i in range(n):
        if keep[i]:
            memcpy(dst + j * itemsize, src + i * itemsize, itemsize)
            j += 1
    return out


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def finish(rng_a, vel_a, az_a, sin_a, cos_a, snr_a, res_a, pair_a, unresolved_a, float dz,
           bint faces, float length, float speed, float lateral, float dz2):
    """``rng_a``, ``vel_a``, ``az_a``, ``snr_a``, ``res_a`` (n,) float32 (m, m/s, rad, dB, Hz), ``sin_a``, ``cos_a``
    (n,) float32 numpy's sin and cos of ``az_a``, ``pair_a`` (n,) int32 resolved pairs, ``unresolved_a`` (n,) bool
    or None. ``dz``: the height difference (m, float32). With ``faces``: NearFaces (``length``, ``speed``,
    ``lateral``, ``dz2`` its float32 squared height difference). Returns the kept detections' ``(range, v, az, snr,
    x, y, residual, resolved_pair, body_extent or None, unresolved_pair or None)``: the given arrays themselves when
    every detection is kept."""
    cdef Py_ssize_t n = len(rng_a), i, m
    cdef const float *rng = <const float *>_data(rng_a, cnp.NPY_FLOAT32, n, False, "rng")
    cdef const float *vel = <const float *>_data(vel_a, cnp.NPY_FLOAT32, n, False, "vel")
    cdef const float *az = <const float *>_data(az_a, cnp.NPY_FLOAT32, n, False, "az")
    cdef const float *sn = <const float *>_data(sin_a, cnp.NPY_FLOAT32, n, False, "sin")
    cdef const float *cs = <const float *>_data(cos_a, cnp.NPY_FLOAT32, n, False, "cos")
    _data(snr_a, cnp.NPY_FLOAT32, n, False, "snr")
    _data(res_a, cnp.NPY_FLOAT32, n, False, "residual")
    _data(pair_a, cnp.NPY_INT32, n, False, "resolved_pair")
    if unresolved_a is not None:
        _data(unresolved_a, cnp.NPY_BOOL, n, False, "unresolved_pair")
    cdef cnp.ndarray x_arr = _new(cnp.NPY_FLOAT32, n)
    cdef cnp.ndarray y_arr = _new(cnp.NPY_FLOAT32, n)
    cdef float *x = <float *>cnp.PyArray_DATA(x_arr)
    cdef float *y = <float *>cnp.PyArray_DATA(y_arr)
    cdef float rc, t, dd = dz * dz
    body_arr = None
    cdef float *body = NULL
    cdef unsigned char *buf = <unsigned char *>malloc(2 * n + 1)
    if buf == NULL:
        raise MemoryError()
    cdef unsigned char *keep = buf
    cdef unsigned char *ones = buf + n
    try:
        for i in range(n):  # polar_to_ground: x = r sin az, y = sqrt(max((r cos az)^2 - dz^2, 0))
            x[i] = rng[i] * sn[i]
            rc = rng[i] * cs[i]
            t = rc * rc - dd
            y[i] = sqrtf(t if (t >= 0 or t != t) else <float>0)
            keep[i] = 1
            ones[i] = 1
        if faces:
            body_arr = _new(cnp.NPY_FLOAT32, n)
            body = <float *>cnp.PyArray_DATA(<cnp.ndarray>body_arr)
            if n <= 1:  # one detection or none: no body behind it
                for i in range(n):
                    body[i] = 0
            else:
                _near_faces_core(rng, vel, x, ones, n, length, speed, lateral, dz2, keep, body)
        m = 0
        for i in range(n):
            m += keep[i]
        if m == n:
            return rng_a, vel_a, az_a, snr_a, x_arr, y_arr, res_a, pair_a, body_arr, unresolved_a
        return (_take(rng_a, cnp.NPY_FLOAT32, 4, keep, n, m), _take(vel_a, cnp.NPY_FLOAT32, 4, keep, n, m),
                _take(az_a, cnp.NPY_FLOAT32, 4, keep, n, m), _take(snr_a, cnp.NPY_FLOAT32, 4, keep, n, m),
                _take(x_arr, cnp.NPY_FLOAT32, 4, keep, n, m), _take(y_arr, cnp.NPY_FLOAT32, 4, keep, n, m),
                _take(res_a, cnp.NPY_FLOAT32, 4, keep, n, m), _take(pair_a, cnp.NPY_INT32, 4, keep, n, m),
                None if body_arr is None else _take(body_arr, cnp.NPY_FLOAT32, 4, keep, n, m),
                None if unresolved_a is None else _take(unresolved_a, cnp.NPY_BOOL, 1, keep, n, m))
    finally:
        free(buf)
