# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Angle stage output kernel (edge.lane.angles.AngleStage.__call__ after the consensus; its numpy form is
AngleStage.reference_output): each pairing's SNR in the first segment against the CFAR noise (the segment's floor
where a track-aided pairing reads a bin that is no local maximum), the pairings whose looks agreed and, for the
resolver, their looks with those not summed into the angle zeroed. The SNR's logarithm in float64, rounded to float32
once, as the reference."""

cimport cython
from libc.math cimport log10, isfinite

import numpy as np


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def finish(const float[:, ::1] power_padded, Py_ssize_t pad, const float[:, ::1] noise, float floor0,
           const long long[:, ::1] pk, const float[::1] rng, const float[::1] vel, const float[::1] res,
           const float[::1] az, const unsigned char[:, ::1] kept, const unsigned char[:, ::1] used,
           const float[:, :, ::1] snaps, int min_agreeing, bint want_looks):
    """``pk`` (n, seg) bins; ``snaps`` the (n, seg, rx) complex64 snapshots' float32 view (n, seg, 2 rx) (read
    with ``want_looks``). Returns ``(range, speed, residual, az, snr_db, looks or None)`` of the kept pairings."""
    cdef Py_ssize_t n = pk.shape[0], ns = kept.shape[1], i, s, t, k = 0, m = 0, w = snaps.shape[2]
    cdef int cnt
    cdef float p0, n0, x
    for i in range(n):
        cnt = 0
        for s in range(ns):
            cnt += kept[i, s]
        if cnt >= min_agreeing:
            m += 1
    o_rng = np.empty(m, np.float32)
    o_vel = np.empty(m, np.float32)
    o_res = np.empty(m, np.float32)
    o_az = np.empty(m, np.float32)
    o_snr = np.empty(m, np.float32)
    cdef float[::1] a_rng = o_rng, a_vel = o_vel, a_res = o_res, a_az = o_az, a_snr = o_snr
    o_looks = np.empty((m, ns, w), np.float32) if want_looks else None
    cdef float[:, :, ::1] looks
    if want_looks:
        looks = o_looks
    for i in range(n):
        cnt = 0
        for s in range(ns):
            cnt += kept[i, s]
        if cnt < min_agreeing:
            continue
        a_rng[k] = rng[i]
        a_vel[k] = vel[i]
        a_res[k] = res[i]
        a_az[k] = az[i]
        p0 = power_padded[0, pad + pk[i, 0]]
        n0 = noise[0, pk[i, 0]]
        if not isfinite(n0):
            n0 = floor0
        if not (n0 >= <float>1e-30 or n0 != n0):  # np.maximum (NaN kept)
            n0 = <float>1e-30
        x = p0 / n0
        a_snr[k] = <float>(10.0 * log10(<double>x))  # float64, rounded once (as the reference)
        if want_looks:
            for s in range(ns):
                for t in range(w // 2):
                    # a complex look times 1 or 0 (numpy's complex product of exact factors)
                    looks[k, s, 2 * t] = snaps[i, s, 2 * t] * <float>used[i, s] - snaps[i, s, 2 * t + 1] * <float>0.0
                    looks[k, s, 2 * t + 1] = snaps[i, s, 2 * t] * <float>0.0 + snaps[i, s, 2 * t + 1] * <float>used[i, s]
        k += 1
    return o_rng, o_vel, o_res, o_az, o_snr, (o_looks.view(np.complex64) if want_looks else None)
