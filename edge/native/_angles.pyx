# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Angle kernel (edge.lane.angles.AngleStage): the Bartlett consensus of edge.dsp.angle.bartlett_consensus (its
numpy reference) after the beamforming product, in one pass per detection.

From ``y = a^H x`` per look (the matrix product stays with numpy, whose BLAS sets its rounding): each look's power
``re^2 + im^2`` normalised to its maximum (floor 1e-30), its maximum's grid angle, the median over the looks, the looks
within the outlier window of it (``kept``), the looks whose bin lies within ``shared_bins`` of another accepted
detection's at another speed (left out of the sum when ``min_clean`` agreeing looks remain: ``used``), the sum of the
used looks and the parabolic refinement of its maximum. All in float32 as the reference (sums over the looks in look
order; the first maximum on a tie).
"""

cimport cython
from libc.stdlib cimport malloc, free
from libc.math cimport fabsf

import numpy as np


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def consensus(const float[:, :, ::1] q, const float[::1] grid, const float[::1] outlier, peak_bins_obj,
              int shared_bins, int min_agreeing, int min_clean, const float[::1] speeds, float min_speed_diff):
    """``q``: ``y`` viewed as float32 ``(n, looks, 2 n_grid)`` (re, im interleaved); ``outlier`` (n,) rad;
    ``peak_bins_obj``: (n, looks) int64 or None (no shared-look test). Returns ``(az (n,) float32, spectrum (n,
    n_grid) float32, kept (n, looks) uint8, used (n, looks) uint8)``."""
    cdef Py_ssize_t n = q.shape[0], ns = q.shape[1], g = q.shape[2] // 2
    cdef Py_ssize_t i, j, s, t, k, h, kk
    cdef const long long[:, ::1] pb
    cdef bint with_bins = peak_bins_obj is not None and n > 1
    if with_bins:
        pb = peak_bins_obj
    p_arr = np.empty((n, ns, g), np.float32)
    cdef float[:, :, ::1] p = p_arr
    spec_arr = np.zeros((n, g), np.float32)
    cdef float[:, ::1] spec = spec_arr
    az_arr = np.empty(n, np.float32)
    cdef float[::1] az = az_arr
    kept_arr = np.zeros((n, ns), np.uint8)
    cdef unsigned char[:, ::1] kept = kept_arr
    used_arr = np.zeros((n, ns), np.uint8)
    cdef unsigned char[:, ::1] used = used_arr
    cdef float *each = <float *>malloc((ns + 1) * sizeof(float))
    cdef float *srt = <float *>malloc((ns + 1) * sizeof(float))
    cdef unsigned char *among = <unsigned char *>malloc(n + 1)
    cdef float re, im, mx, x, med, pm, p0, pp, den, d, step, first, u
    cdef const float* qp
    cdef float* pp_
    cdef float* sq
    cdef int cnt, n_clean
    cdef bint shared_any, sh, started
    if each == NULL or srt == NULL or among == NULL:
        free(each); free(srt); free(among)
        raise MemoryError()
    try:
        # looks and kept first (the shared-look test needs every detection's agreement)
        for i in range(n):
            for s in range(ns):
                # the look's power, normalised to its maximum (floor 1e-30), and the normalised maximum's angle
                qp = &q[i, s, 0]
                pp_ = &p[i, s, 0]
                for t in range(g):  # (bins innermost, contiguous: vectorised)
                    re = qp[2 * t]
                    im = qp[2 * t + 1]
                    pp_[t] = re * re + im * im
                mx = pp_[0]
                for t in range(1, g):
                    if pp_[t] > mx:
                        mx = pp_[t]
                if not (mx > <float>1e-30):
                    mx = <float>1e-30
                for t in range(g):
                    pp_[t] = pp_[t] / mx
                k = 0
                for t in range(g):
                    if pp_[t] > pp_[k]:
                        k = t
                each[s] = grid[k]
            # median of the looks' angles (the middle one, or the mean of the middle two)
            for s in range(ns):
                x = each[s]
                t = s
                while t > 0 and srt[t - 1] > x:
                    srt[t] = srt[t - 1]
                    t -= 1
                srt[t] = x
            h = ns // 2
            if ns % 2:
                med = srt[h]
            else:
                med = (srt[h - 1] + srt[h]) / <float>2
            cnt = 0
            for s in range(ns):
                kept[i, s] = fabsf(each[s] - med) <= outlier[i]
                used[i, s] = kept[i, s]
                cnt += kept[i, s]
            among[i] = cnt >= min_agreeing
        if with_bins:
            for i in range(n):
                shared_any = False
                n_clean = 0
                for s in range(ns):
                    sh = False
                    for j in range(n):
                        if j == i or not among[j]:
                            continue
                        if (abs(pb[i, s] - pb[j, s]) <= shared_bins
                                and fabsf(speeds[i] - speeds[j]) > min_speed_diff):
                            sh = True
                            break
                    if sh:
                        shared_any = True
                    elif kept[i, s]:
                        n_clean += 1
                    used[i, s] = kept[i, s] and not sh
                if shared_any and n_clean < min_clean:  # too few clean looks: all the agreeing ones
                    for s in range(ns):
                        used[i, s] = kept[i, s]
        step = grid[1] - grid[0]
        for i in range(n):
            # the used looks' normalised spectra summed in look order (a look not used adds p * 0)
            sq = &spec[i, 0]
            pp_ = &p[i, 0, 0]
            u = <float>used[i, 0]
            for t in range(g):
                sq[t] = pp_[t] * u
            for s in range(1, ns):  # look by look, bins innermost: the same sum per bin
                pp_ = &p[i, s, 0]
                u = <float>used[i, s]
                for t in range(g):
                    sq[t] = sq[t] + pp_[t] * u
            k = 0
            mx = spec[i, 0]
            for t in range(1, g):
                if spec[i, t] > mx:
                    mx = spec[i, t]
                    k = t
            if 1 <= k <= g - 2:
                pm = spec[i, k - 1]
                p0 = spec[i, k]
                pp = spec[i, k + 1]
                den = pm - <float>2.0 * p0 + pp
                d = <float>0.5 * (pm - pp) / den if den < 0 else <float>0.0
                if d < <float>-0.5:
                    d = <float>-0.5
                if d > <float>0.5:
                    d = <float>0.5
                az[i] = grid[k] + d * step
            else:
                az[i] = grid[k]
        return az_arr, spec_arr, kept_arr, used_arr
    finally:
        free(each); free(srt); free(among)
