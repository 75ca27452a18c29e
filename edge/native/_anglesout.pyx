# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Angle stage output kernel (edge.lane.angles.AngleStage.__call__ after the consensus; its numpy form is
AngleStage.reference_output): each pairing's SNR in the first segment against the CFAR noise (the segment's floor
where a track-aided pairing reads a bin that is no local maximum), the pairings whose looks agreed and, for the
resolver, their looks with those not summed into the angle zeroed. The SNR's logarithm in float64, rounded to float32
once, as the reference."""

cimport cython
cimport numpy as cnp
from libc.math cimport log10, isfinite

import numpy as np

cnp.import_array()

include "_arrays.pxi"
include "_alloc.pxi"


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def finish(power_padded_a, Py_ssize_t pad, noise_a, float floor0, pk_a, rng_a, vel_a, res_a, az_a, kept_a, used_a,
           snaps_a, int min_agreeing, bint want_looks):
    """``power_padded_a`` (seg, bin + 2 pad) and ``noise_a`` (seg, bin) float32; ``pk_a`` (n, seg) int64 bins;
    ``rng_a``, ``vel_a``, ``res_a``, ``az_a`` (n,) float32; ``kept_a``, ``used_a`` (n, seg) bool or uint8;
    ``snaps_a`` the (n, seg, rx) complex64 snapshots (read with ``want_looks``). Arrays that are not C-contiguous
    are converted (numpy's ascontiguousarray), and all are read through the numpy C API. Returns ``(range, speed,
    residual, az, snr_db, looks or None, resolved_pair)`` of the kept pairings, ``resolved_pair`` all -1 (int32)."""
    if not (cnp.PyArray_Check(pk_a) and cnp.PyArray_NDIM(<cnp.ndarray>pk_a) == 2):
        raise ValueError("pk: an (n, seg) int64 array needed")
    cdef Py_ssize_t n = cnp.PyArray_DIM(<cnp.ndarray>pk_a, 0), ns = cnp.PyArray_DIM(<cnp.ndarray>pk_a, 1)
    cdef Py_ssize_t i, s, t, k = 0, m = 0, n_seg, n_bins, w
    pk_a = _as_c(pk_a, cnp.NPY_INT64)
    cdef const long long *pk = <const long long *>_data2(pk_a, cnp.NPY_INT64, n, ns, False, "pk")
    if not (cnp.PyArray_Check(noise_a) and cnp.PyArray_NDIM(<cnp.ndarray>noise_a) == 2):
        raise ValueError("noise: a (seg, bin) float32 array needed")
    n_seg = cnp.PyArray_DIM(<cnp.ndarray>noise_a, 0)
    n_bins = cnp.PyArray_DIM(<cnp.ndarray>noise_a, 1)
    noise_a = _as_c(noise_a, cnp.NPY_FLOAT32)
    power_padded_a = _as_c(power_padded_a, cnp.NPY_FLOAT32)
    cdef const float *noise = <const float *>_data2(noise_a, cnp.NPY_FLOAT32, n_seg, n_bins, False, "noise")
    cdef const float *ppad = <const float *>_data2(power_padded_a, cnp.NPY_FLOAT32, n_seg, n_bins + 2 * pad, False,
                                                   "power_padded")
    rng_a = _as_c(rng_a, cnp.NPY_FLOAT32)
    vel_a = _as_c(vel_a, cnp.NPY_FLOAT32)
    res_a = _as_c(res_a, cnp.NPY_FLOAT32)
    az_a = _as_c(az_a, cnp.NPY_FLOAT32)
    cdef const float *rng = <const float *>_data(rng_a, cnp.NPY_FLOAT32, n, False, "rng")
    cdef const float *vel = <const float *>_data(vel_a, cnp.NPY_FLOAT32, n, False, "vel")
    cdef const float *res = <const float *>_data(res_a, cnp.NPY_FLOAT32, n, False, "res")
    cdef const float *az = <const float *>_data(az_a, cnp.NPY_FLOAT32, n, False, "az")
    kept_a = _as_c(kept_a, cnp.NPY_BOOL if cnp.PyArray_Check(kept_a) and cnp.PyArray_TYPE(<cnp.ndarray>kept_a) == cnp.NPY_BOOL else cnp.NPY_UINT8)
    used_a = _as_c(used_a, cnp.NPY_BOOL if cnp.PyArray_Check(used_a) and cnp.PyArray_TYPE(<cnp.ndarray>used_a) == cnp.NPY_BOOL else cnp.NPY_UINT8)
    cdef const unsigned char *kept = <const unsigned char *>_data2(kept_a, cnp.PyArray_TYPE(<cnp.ndarray>kept_a), n,
                                                                   ns, False, "kept")
    cdef const unsigned char *used = <const unsigned char *>_data2(used_a, cnp.PyArray_TYPE(<cnp.ndarray>used_a), n,
                                                                   ns, False, "used")
    cdef const float *snaps = NULL
    w = 0
    if want_looks:
        if not (cnp.PyArray_Check(snaps_a) and cnp.PyArray_NDIM(<cnp.ndarray>snaps_a) == 3):
            raise ValueError("snaps: an (n, seg, rx) complex64 array needed")
        w = 2 * cnp.PyArray_DIM(<cnp.ndarray>snaps_a, 2)
        snaps_a = _as_c(snaps_a, cnp.NPY_COMPLEX64)
        snaps = <const float *>_data3(snaps_a, cnp.NPY_COMPLEX64, n, ns, w // 2, False, "snaps")
    for i in range(n):
        if not 0 <= pk[i * ns] < n_bins:
            raise IndexError("pk: a bin out of range")
    cdef int cnt
    cdef float p0, n0, x
    for i in range(n):
        cnt = 0
        for s in range(ns):
            cnt += kept[i * ns + s]
        if cnt >= min_agreeing:
            m += 1
    o_rng = _new(cnp.NPY_FLOAT32, m)
    o_vel = _new(cnp.NPY_FLOAT32, m)
    o_res = _new(cnp.NPY_FLOAT32, m)
    o_az = _new(cnp.NPY_FLOAT32, m)
    o_snr = _new(cnp.NPY_FLOAT32, m)
    o_pair = _new(cnp.NPY_INT32, m)
    cdef float *a_rng = <float *>cnp.PyArray_DATA(<cnp.ndarray>o_rng)
    cdef float *a_vel = <float *>cnp.PyArray_DATA(<cnp.ndarray>o_vel)
    cdef float *a_res = <float *>cnp.PyArray_DATA(<cnp.ndarray>o_res)
    cdef float *a_az = <float *>cnp.PyArray_DATA(<cnp.ndarray>o_az)
    cdef float *a_snr = <float *>cnp.PyArray_DATA(<cnp.ndarray>o_snr)
    cdef int *a_pair = <int *>cnp.PyArray_DATA(<cnp.ndarray>o_pair)
    o_looks = _empty3(cnp.NPY_COMPLEX64, m, ns, w // 2) if want_looks else None
    cdef float *looks = NULL
    cdef const float *sp
    cdef float *lp
    cdef float u
    if want_looks:
        looks = <float *>cnp.PyArray_DATA(<cnp.ndarray>o_looks)
    for i in range(n):
        cnt = 0
        for s in range(ns):
            cnt += kept[i * ns + s]
        if cnt < min_agreeing:
            continue
        a_rng[k] = rng[i]
        a_vel[k] = vel[i]
        a_res[k] = res[i]
        a_az[k] = az[i]
        a_pair[k] = -1
        p0 = ppad[pad + pk[i * ns]]
        n0 = noise[pk[i * ns]]
        if not isfinite(n0):
            n0 = floor0
        if not (n0 >= <float>1e-30 or n0 != n0):  # np.maximum (NaN kept)
            n0 = <float>1e-30
        x = p0 / n0
        a_snr[k] = <float>(10.0 * log10(<double>x))  # float64, rounded once (as the reference)
        if want_looks:
            for s in range(ns):
                sp = snaps + (i * ns + s) * w
                lp = looks + (k * ns + s) * w
                u = <float>used[i * ns + s]
                for t in range(w // 2):
                    # a complex look times 1 or 0 (numpy's complex product of exact factors)
                    lp[2 * t] = sp[2 * t] * u - sp[2 * t + 1] * <float>0.0
                    lp[2 * t + 1] = sp[2 * t] * <float>0.0 + sp[2 * t + 1] * u
        k += 1
    return o_rng, o_vel, o_res, o_az, o_snr, o_looks, o_pair
