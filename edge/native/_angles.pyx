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
cimport numpy as cnp
from libc.stdlib cimport malloc, free
from libc.math cimport fabsf

import numpy as np

cnp.import_array()

include "_arrays.pxi"
include "_alloc.pxi"


@cython.boundscheck(False)
@cython.wraparound(False)
@cython.cdivision(True)
def consensus(q_a, grid_a, outlier_a, peak_bins_obj, int shared_bins, int min_agreeing, int min_clean, speeds_a,
              float min_speed_diff, lateral_obj=None, float lateral_m=0.0):
    """``q_a``: ``y`` viewed as float32 ``(n, looks, 2 n_grid)`` (re, im interleaved), C-contiguous; ``grid_a``
    (n_grid,) float32; ``outlier_a`` (n,) rad float32, or a float32 scalar with ``lateral_obj`` the (n,) float32 ranges
    and ``lateral_m`` > 0: the window is then max(outlier, lateral_m / max(range, 1)) per detection, in float32 as
    numpy's (AngleStage.__call__'s); ``peak_bins_obj``: (n, looks) int64 or None (no shared-look test); ``speeds_a``
    (n,) float32. The 1-D arrays and the bins are converted to C-contiguous ones of their type when they are not
    (numpy's ascontiguousarray). Returns ``(az (n,) float32, spectrum (n, n_grid) float32, kept (n, looks) uint8,
    used (n, looks) uint8)``."""
    if not (cnp.PyArray_Check(q_a) and cnp.PyArray_NDIM(<cnp.ndarray>q_a) == 3):
        raise ValueError("q: a (n, looks, 2 n_grid) float32 array needed")
    cdef Py_ssize_t n = cnp.PyArray_DIM(<cnp.ndarray>q_a, 0), ns = cnp.PyArray_DIM(<cnp.ndarray>q_a, 1)
    cdef Py_ssize_t g = cnp.PyArray_DIM(<cnp.ndarray>q_a, 2) // 2
    cdef Py_ssize_t i, j, s, t, k, h, kk
    cdef const float *q = <const float *>_data3(q_a, cnp.NPY_FLOAT32, n, ns, 2 * g, False, "q")
    grid_a = _as_c(grid_a, cnp.NPY_FLOAT32)
    cdef const float *grid = <const float *>_data(grid_a, cnp.NPY_FLOAT32, g, False, "grid")
    speeds_a = _as_c(speeds_a, cnp.NPY_FLOAT32)
    cdef const float *speeds = <const float *>_data(speeds_a, cnp.NPY_FLOAT32, n, False, "speeds")
    cdef const float *lat_r = NULL
    cdef float out0 = 0, lat = lateral_m, one = 1.0, rr, o
    cdef const float *outlier = NULL
    if lateral_obj is not None:
        out0 = outlier_a
        lateral_obj = _as_c(lateral_obj, cnp.NPY_FLOAT32)
        lat_r = <const float *>_data(lateral_obj, cnp.NPY_FLOAT32, n, False, "range")
    else:
        outlier_a = _as_c(outlier_a, cnp.NPY_FLOAT32)
        outlier = <const float *>_data(outlier_a, cnp.NPY_FLOAT32, n, False, "outlier")
    cdef const long long *pb = NULL
    cdef bint with_bins = peak_bins_obj is not None and n > 1
    if with_bins:
        peak_bins_obj = _as_c(peak_bins_obj, cnp.NPY_INT64)
        pb = <const long long *>_data2(peak_bins_obj, cnp.NPY_INT64, n, ns, False, "peak_bins")
    if g < 2:
        raise ValueError("the grid needs two angles or more")
    spec_arr = _zeros2(cnp.NPY_FLOAT32, n, g)
    cdef float *spec = <float *>cnp.PyArray_DATA(<cnp.ndarray>spec_arr)
    az_arr = _new(cnp.NPY_FLOAT32, n)
    cdef float *az = <float *>cnp.PyArray_DATA(<cnp.ndarray>az_arr)
    kept_arr = _zeros2(cnp.NPY_UINT8, n, ns)
    cdef unsigned char *kept = <unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>kept_arr)
    used_arr = _zeros2(cnp.NPY_UINT8, n, ns)
    cdef unsigned char *used = <unsigned char *>cnp.PyArray_DATA(<cnp.ndarray>used_arr)
    cdef float *p = <float *>malloc((n * ns * g + 1) * sizeof(float))
    cdef float *outl = <float *>malloc((n + 1) * sizeof(float))
    cdef float *each = <float *>malloc((ns + 1) * sizeof(float))
    cdef float *srt = <float *>malloc((ns + 1) * sizeof(float))
    cdef unsigned char *among = <unsigned char *>malloc(n + 1)
    cdef float re, im, mx, x, med, pm, p0, pp, den, d, step, first, u, m0, m1, m2, m3, top
    cdef const float* qp
    cdef float* pp_
    cdef float* sq
    cdef int cnt, n_clean
    cdef bint shared_any, sh, started
    if each == NULL or srt == NULL or among == NULL or p == NULL or outl == NULL:
        free(each); free(srt); free(among); free(p); free(outl)
        raise MemoryError()
    try:
        for i in range(n):  # the outlier window (np.maximum: NaN kept)
            if outlier != NULL:
                outl[i] = outlier[i]
            else:
                rr = lat_r[i]
                rr = rr if (rr >= one or rr != rr) else one
                o = lat / rr
                outl[i] = out0 if (out0 >= o or out0 != out0) else o
        # looks and kept first (the shared-look test needs every detection's agreement)
        for i in range(n):
            for s in range(ns):
                # the look's power, normalised to its maximum (floor 1e-30), and the normalised maximum's angle
                qp = q + (i * ns + s) * 2 * g
                pp_ = p + (i * ns + s) * g
                for t in range(g):  # (bins innermost, contiguous: vectorised)
                    re = qp[2 * t]
                    im = qp[2 * t + 1]
                    pp_[t] = re * re + im * im
                # the largest (NaN skipped, as pp_[t] > mx does; NaN throughout when the first is), four running
                # maxima over every fourth value: the same value
                m0 = m1 = m2 = m3 = pp_[0]
                t = 0
                while t + 4 <= g:
                    x = pp_[t]
                    m0 = x if x > m0 else m0
                    x = pp_[t + 1]
                    m1 = x if x > m1 else m1
                    x = pp_[t + 2]
                    m2 = x if x > m2 else m2
                    x = pp_[t + 3]
                    m3 = x if x > m3 else m3
                    t += 4
                while t < g:
                    x = pp_[t]
                    m0 = x if x > m0 else m0
                    t += 1
                mx = m0
                if m1 > mx:
                    mx = m1
                if m2 > mx:
                    mx = m2
                if m3 > mx:
                    mx = m3
                top = mx  # the largest power (NaN: the first is NaN)
                if not (mx > <float>1e-30):
                    mx = <float>1e-30
                for t in range(g):
                    pp_[t] = pp_[t] / mx
                # the first largest normalised power (np.argmax): the division keeps the order, so the largest is
                # top / mx, rounded as the value it came from; index 0 when the first is NaN
                k = 0
                if top == top:
                    top = top / mx
                    while k < g - 1 and pp_[k] != top:
                        k += 1
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
                kept[i * ns + s] = fabsf(each[s] - med) <= outl[i]
                used[i * ns + s] = kept[i * ns + s]
                cnt += kept[i * ns + s]
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
                        if (abs(pb[i * ns + s] - pb[j * ns + s]) <= shared_bins
                                and fabsf(speeds[i] - speeds[j]) > min_speed_diff):
                            sh = True
                            break
                    if sh:
                        shared_any = True
                    elif kept[i * ns + s]:
                        n_clean += 1
                    used[i * ns + s] = kept[i * ns + s] and not sh
                if shared_any and n_clean < min_clean:  # too few clean looks: all the agreeing ones
                    for s in range(ns):
                        used[i * ns + s] = kept[i * ns + s]
        step = grid[1] - grid[0]
        for i in range(n):
            # the used looks' normalised spectra summed in look order (a look not used adds p * 0)
            sq = spec + i * g
            pp_ = p + i * ns * g
            u = <float>used[i * ns]
            for t in range(g):
                sq[t] = pp_[t] * u
            for s in range(1, ns):  # look by look, bins innermost: the same sum per bin
                pp_ = p + (i * ns + s) * g
                u = <float>used[i * ns + s]
                for t in range(g):
                    sq[t] = sq[t] + pp_[t] * u
            k = 0
            mx = sq[0]
            for t in range(1, g):
                if sq[t] > mx:
                    mx = sq[t]
                    k = t
            if 1 <= k <= g - 2:
                pm = sq[k - 1]
                p0 = sq[k]
                pp = sq[k + 1]
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
        free(each); free(srt); free(among); free(p); free(outl)
