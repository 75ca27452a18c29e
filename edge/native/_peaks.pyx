# cython: language_level=3
# distutils: extra_compile_args = -ffp-contract=off
"""Peak stage kernel (edge.lane.peaks.PeakStage): circular local maxima, OS-CFAR at those cells only, the split into
detected and weak (track-aided) peaks, and the parabolic sub-bin interpolation through the log-power.

The selection rules are those of the numpy reference (PeakStage.reference): a local maximum is strictly above its
left neighbour and at least its right one; the noise estimate is the ``rank``-th smallest of the ``2 n_train``
reference cells (Rohling's OS-CFAR); a peak is detected when its power exceeds ``noise * scale`` (float32
arithmetic, as numpy's). The logarithm of the interpolation is left to the caller (numpy's
float32 ``log``, so the frequencies equal the reference's bit for bit).
"""

cimport cython
cimport numpy as cnp
from libc.math cimport NAN
from libc.stdlib cimport malloc, free

cnp.import_array()

include "_arrays.pxi"


cdef extern from *:
    """
    /* OS-CFAR noise of up to 8 cells at once: their reference windows as the 8 lanes of a comparator network
       (Batcher's odd-even merge sort, pruned to the comparators the rank's output depends on), in GCC/Clang
       vector types (SSE on x86-64, NEON on arm64). A lane's comparator is min/max (no NaN, no -0 in a power: the
       values of a sort). */
    #include <string.h>
    typedef float kdet_v4 __attribute__((vector_size(16)));
    typedef int kdet_i4 __attribute__((vector_size(16)));
    #if defined(__SSE__)
    #include <xmmintrin.h>
    #define KDET_MIN(x, y) ((kdet_v4)_mm_min_ps((__m128)(x), (__m128)(y)))
    #define KDET_MAX(x, y) ((kdet_v4)_mm_max_ps((__m128)(x), (__m128)(y)))
    #elif defined(__ARM_NEON)
    #include <arm_neon.h>
    #define KDET_MIN(x, y) ((kdet_v4)vminq_f32((float32x4_t)(x), (float32x4_t)(y)))
    #define KDET_MAX(x, y) ((kdet_v4)vmaxq_f32((float32x4_t)(x), (float32x4_t)(y)))
    #else
    static inline kdet_v4 kdet_sel(kdet_v4 x, kdet_v4 y, kdet_i4 m) {
        return (kdet_v4)(((kdet_i4)x & m) | ((kdet_i4)y & ~m));
    }
    #define KDET_MIN(x, y) kdet_sel((x), (y), (x) < (y))
    #define KDET_MAX(x, y) kdet_sel((y), (x), (x) < (y))
    #endif
    #define KDET_LANES 8
    #define KDET_MAX_PAD 128
    static void kdet_os_noise(const float *const *win, int nb, int n_train, int off, int npad, int rank,
                              const int *comp, int ncomp, float *out) {
        kdet_v4 w[KDET_MAX_PAD * 2];
        float *f = (float *)w;
        int i, l, t;
        for (i = 0; i < npad; i++)
            for (l = 0; l < KDET_LANES; l++)
                f[i * KDET_LANES + l] = __builtin_inff();
        for (l = 0; l < nb; l++) {
            const float *x = win[l];
            for (i = 0; i < n_train; i++) {
                f[i * KDET_LANES + l] = x[i];
                f[(n_train + i) * KDET_LANES + l] = x[off + 1 + i];
            }
        }
        for (t = 0; t < ncomp; t++) {
            kdet_v4 *a = w + 2 * comp[2 * t], *b = w + 2 * comp[2 * t + 1];
            for (l = 0; l < 2; l++) {
                kdet_v4 x = a[l], y = b[l];
                a[l] = KDET_MIN(x, y);
                b[l] = KDET_MAX(x, y);
            }
        }
        for (l = 0; l < nb; l++)
            out[l] = f[(rank - 1) * KDET_LANES + l];
    }

    /* The same for the default window (16 reference cells a side, the 24th smallest of 32), the comparators
       fixed at compile time (kdet_net32_24 is rank_network(32, 24), which tests/native/test_peaks.py checks):
       the network unrolled on constant rows instead of read from ``comp``, and the windows moved into the
       lanes by 4 x 4 transposes of 4-cell loads instead of cell by cell. Lanes past ``nb`` repeat lane 0.
       The same comparators in the same order on the same values: the same noise bit for bit. */
    #define KDET_NET32_24_N 147
    static const unsigned char kdet_net32_24[KDET_NET32_24_N][2] = {
        {0, 1}, {2, 3}, {4, 5}, {6, 7}, {8, 9}, {10, 11}, {12, 13}, {14, 15}, {16, 17}, {18, 19}, {20, 21}, {22,
        23}, {24, 25}, {26, 27}, {28, 29}, {30, 31}, {0, 2}, {1, 3}, {4, 6}, {5, 7}, {8, 10}, {9, 11}, {12, 14},
        {13, 15}, {16, 18}, {17, 19}, {20, 22}, {21, 23}, {24, 26}, {25, 27}, {28, 30}, {29, 31}, {1, 2}, {5,
        6}, {9, 10}, {13, 14}, {17, 18}, {21, 22}, {25, 26}, {29, 30}, {0, 4}, {1, 5}, {2, 6}, {3, 7}, {8, 12},
        {9, 13}, {10, 14}, {11, 15}, {16, 20}, {17, 21}, {18, 22}, {19, 23}, {24, 28}, {25, 29}, {26, 30}, {27,
        31}, {2, 4}, {3, 5}, {10, 12}, {11, 13}, {18, 20}, {19, 21}, {26, 28}, {27, 29}, {1, 2}, {3, 4}, {5, 6},
        {9, 10}, {11, 12}, {13, 14}, {17, 18}, {19, 20}, {21, 22}, {25, 26}, {27, 28}, {29, 30}, {0, 8}, {1, 9},
        {2, 10}, {3, 11}, {4, 12}, {5, 13}, {6, 14}, {7, 15}, {16, 24}, {17, 25}, {18, 26}, {19, 27}, {20, 28},
        {21, 29}, {22, 30}, {23, 31}, {4, 8}, {5, 9}, {6, 10}, {7, 11}, {20, 24}, {21, 25}, {22, 26}, {23, 27},
        {2, 4}, {3, 5}, {6, 8}, {7, 9}, {10, 12}, {11, 13}, {18, 20}, {19, 21}, {22, 24}, {23, 25}, {26, 28},
        {27, 29}, {3, 4}, {5, 6}, {7, 8}, {9, 10}, {11, 12}, {13, 14}, {19, 20}, {21, 22}, {23, 24}, {25, 26},
        {27, 28}, {29, 30}, {4, 20}, {5, 21}, {6, 22}, {7, 23}, {8, 24}, {9, 25}, {10, 26}, {11, 27}, {12, 28},
        {13, 29}, {14, 30}, {15, 31}, {12, 20}, {13, 21}, {14, 22}, {15, 23}, {20, 24}, {21, 25}, {22, 26}, {23,
        27}, {22, 24}, {23, 25}, {23, 24}
    };
    #if defined(__clang__)
    #define KDET_SHUF(a, b, i0, i1, i2, i3) __builtin_shufflevector((a), (b), i0, i1, i2, i3)
    #else
    #define KDET_SHUF(a, b, i0, i1, i2, i3) __builtin_shuffle((a), (b), (kdet_i4){i0, i1, i2, i3})
    #endif
    static inline kdet_v4 kdet_load4(const float *p) {
        kdet_v4 v;
        memcpy(&v, p, sizeof v);
        return v;
    }
    static void kdet_os_noise_32_24(const float *const *win, int nb, int off, float *out) {
        kdet_v4 w[64];  /* reference cell i of lanes 0-3 in w[2 i], of lanes 4-7 in w[2 i + 1] */
        const float *x[KDET_LANES];
        int g, l, part, i, t;
        for (l = 0; l < KDET_LANES; l++)
            x[l] = win[l < nb ? l : 0];
        for (g = 0; g < 2; g++)
            for (part = 0; part < 2; part++)
                for (i = 0; i < 16; i += 4) {
                    int o = part * (off + 1) + i, row = part * 16 + i;
                    kdet_v4 r0 = kdet_load4(x[4 * g] + o), r1 = kdet_load4(x[4 * g + 1] + o);
                    kdet_v4 r2 = kdet_load4(x[4 * g + 2] + o), r3 = kdet_load4(x[4 * g + 3] + o);
                    kdet_v4 t0 = KDET_SHUF(r0, r1, 0, 4, 1, 5), t1 = KDET_SHUF(r2, r3, 0, 4, 1, 5);
                    kdet_v4 t2 = KDET_SHUF(r0, r1, 2, 6, 3, 7), t3 = KDET_SHUF(r2, r3, 2, 6, 3, 7);
                    w[2 * row + g] = KDET_SHUF(t0, t1, 0, 1, 4, 5);
                    w[2 * (row + 1) + g] = KDET_SHUF(t0, t1, 2, 3, 6, 7);
                    w[2 * (row + 2) + g] = KDET_SHUF(t2, t3, 0, 1, 4, 5);
                    w[2 * (row + 3) + g] = KDET_SHUF(t2, t3, 2, 3, 6, 7);
                }
    #if defined(__clang__)
        #pragma unroll
    #elif defined(__GNUC__)
        #pragma GCC unroll 160
    #endif
        for (t = 0; t < KDET_NET32_24_N; t++) {
            int a = kdet_net32_24[t][0], b = kdet_net32_24[t][1];
            kdet_v4 x0 = w[2 * a], y0 = w[2 * b], x1 = w[2 * a + 1], y1 = w[2 * b + 1];
            w[2 * a] = KDET_MIN(x0, y0);
            w[2 * b] = KDET_MAX(x0, y0);
            w[2 * a + 1] = KDET_MIN(x1, y1);
            w[2 * b + 1] = KDET_MAX(x1, y1);
        }
        for (l = 0; l < nb; l++)
            out[l] = ((const float *)&w[2 * 23 + l / 4])[l % 4];
    }
    """
    int KDET_LANES
    int KDET_MAX_PAD
    void kdet_os_noise(const float* const* win, int nb, int n_train, int off, int npad, int rank, const int* comp,
                       int ncomp, float* out) noexcept nogil
    int KDET_NET32_24_N
    const unsigned char kdet_net32_24[][2]
    void kdet_os_noise_32_24(const float* const* win, int nb, int off, float* out) noexcept nogil


def rank_network(int n_ref, int rank):
    """Comparators ``(k, 2)`` int32 of Batcher's odd-even merge sort over the next power of two >= ``n_ref`` (the
    extra inputs +inf), only those the ``rank``-th smallest (1-based) depends on, in order; and that power."""
    import numpy as np

    n = 1
    while n < n_ref:
        n *= 2
    pairs = []
    p = 1
    while p < n:
        k = p
        while k >= 1:
            for j in range(k % p, n - k, 2 * k):
                for i in range(min(k, n - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    need, kept = {rank - 1}, []
    for i, j in reversed(pairs):
        if i in need or j in need:
            need |= {i, j}
            kept.append((i, j))
    return np.array(kept[::-1], np.int32).reshape(-1, 2), n


def fixed_network():
    """The comparators ``(147, 2)`` int32 of the unrolled default network (16 reference cells a side, rank 24):
    :func:`select` takes it when ``comp`` equals it, which is :func:`rank_network` ``(32, 24)``."""
    import numpy as np

    return np.array([[kdet_net32_24[t][0], kdet_net32_24[t][1]] for t in range(KDET_NET32_24_N)], np.int32)


cdef bint _is_fixed(const int *comp, Py_ssize_t ncomp, int n_train, int rank, int npad) noexcept nogil:
    """Whether the network ``comp`` is the default one (kdet_os_noise_32_24 runs it unrolled)."""
    cdef Py_ssize_t t
    if not (n_train == 16 and rank == 24 and npad == 32 and ncomp == KDET_NET32_24_N):
        return False
    for t in range(ncomp):
        if comp[2 * t] != kdet_net32_24[t][0] or comp[2 * t + 1] != kdet_net32_24[t][1]:
            return False
    return True


cdef Py_ssize_t _select_core(const float *ppad, const unsigned char *valid, int n_seg, int n, int n_train,
                             int n_guard, int rank, const int *comp, int ncomp, int npad, float scale,
                             float aided_scale, bint want_weak, float *noise, long *rows, long *cols, float *cells,
                             unsigned char *is_hit, float *scratch) noexcept nogil:
    """:func:`select` on raw pointers (C-contiguous rows: ``ppad`` (n_seg, n + 2 half), ``valid`` and ``noise``
    (n_seg, n), ``cells`` (m, 3), ``comp`` (ncomp, 2)); returns m."""
    cdef int half = n_train + n_guard, r, c, nb
    cdef Py_ssize_t m = 0, k, n_max = 0, w = n + 2 * half
    cdef float p, nz, ub, tiny = 1e-30
    cdef const float* row
    cdef const float* win[8]
    cdef bint fixed = _is_fixed(comp, ncomp, n_train, rank, npad)
    for r in range(n_seg):  # the local maxima (strictly above the left neighbour, at least the right one)
        row = ppad + r * w + half
        for c in range(n):
            if valid[r * n + c] and row[c] > row[c - 1] and row[c] >= row[c + 1]:
                rows[n_max] = r
                cols[n_max] = c
                n_max += 1
    k = 0
    while k < n_max:  # their noise, eight at a time
        nb = n_max - k
        if nb > 8:
            nb = 8
        for c in range(nb):
            win[c] = ppad + rows[k + c] * w + cols[k + c]
        if fixed:
            kdet_os_noise_32_24(win, nb, half + n_guard, &scratch[k])
        else:
            kdet_os_noise(win, nb, n_train, half + n_guard, npad, rank, comp, ncomp, &scratch[k])
        k += nb
    for k in range(n_max):  # the decisions (rows, cols compacted in place: m <= k)
        r = rows[k]
        c = cols[k]
        row = ppad + r * w + half
        nz = scratch[k]
        noise[r * n + c] = nz
        p = row[c]
        if p > nz * scale:
            is_hit[m] = 1
        elif want_weak and p > nz * aided_scale:
            is_hit[m] = 0
        else:
            continue
        rows[m] = r
        cols[m] = c
        ub = row[c - 1]
        cells[3 * m] = ub if ub > tiny else tiny
        cells[3 * m + 1] = p if p > tiny else tiny
        ub = row[c + 1]
        cells[3 * m + 2] = ub if ub > tiny else tiny
        m += 1
    return m


@cython.boundscheck(False)
@cython.wraparound(False)
def select(const float[:, ::1] ppad, const unsigned char[:, ::1] valid, int n_train, int n_guard, int rank,
           const int[:, ::1] comp, int npad, float scale, float aided_scale, bint want_weak,
           float[:, ::1] noise, long[::1] rows, long[::1] cols, float[:, ::1] cells, unsigned char[::1] is_hit,
           float[::1] scratch):
    """Local maxima of the padded power rows ``ppad`` (seg, n + 2 half), ``half = n_train + n_guard``, inside
    ``valid`` (seg, n): their OS-CFAR noise (the ``rank``-th smallest reference cell by the network ``comp`` over
    ``npad`` inputs, :func:`rank_network`; written into ``noise`` (seg, n), which the caller filled with NaN), and
    those that are detected (power > noise * scale) or, with ``want_weak``, weak (not detected, power > noise *
    aided_scale). Writes per kept maximum, in (segment, bin) order, its ``rows``, ``cols``, its power and two
    neighbours floored at 1e-30 into ``cells`` (m, 3), and ``is_hit`` (1 detected, 0 weak); ``rows``, ``cols`` and
    ``scratch`` must hold every local maximum (seg * (n / 2 + 1)).
    Returns m."""
    cdef int n_seg = valid.shape[0], n = valid.shape[1]
    if npad > KDET_MAX_PAD or npad < 2 * n_train or rank < 1 or rank > 2 * n_train or KDET_LANES != 8:
        raise ValueError("reference window too large or rank out of range")
    cdef Py_ssize_t m = 0
    if n_seg == 0 or n == 0:
        return 0
    with nogil:
        m = _select_core(&ppad[0, 0], &valid[0, 0], n_seg, n, n_train, n_guard, rank, &comp[0, 0], comp.shape[0],
                         npad, scale, aided_scale, want_weak, &noise[0, 0], &rows[0], &cols[0],
                         &cells[0, 0], &is_hit[0], &scratch[0])
    return m


cdef inline float _vertex_offset(float lm, float l0, float lp) noexcept nogil:
    """A parabola's vertex through (-1, lm), (0, l0), (1, lp), in bins, clipped to half a bin (0 where it opens
    upwards); float32 operations, as numpy's on float32."""
    cdef float two = 2.0, hlf = 0.5, zero = 0.0
    cdef float den = (lm - two * l0) + lp
    cdef float d = zero
    if den < zero:
        d = (hlf * (lm - lp)) / den
    if d < -hlf:
        d = -hlf
    if d > hlf:
        d = hlf
    return d


@cython.boundscheck(False)
@cython.wraparound(False)
def interpolate(const float[:, ::1] lg, const long[::1] rows, const long[::1] cols, const double[::1] freq_flat,
                const double[::1] bin_hz, int n_bins, double[::1] out):
    """Signed beat frequencies (Hz) ``out[:m]`` of the peaks ``rows``, ``cols`` from the log-power ``lg`` (m, 3) of
    each peak and its neighbours: a parabola's vertex, clipped to half a bin (edge.dsp.peaks.interpolate_peak)."""
    cdef Py_ssize_t i, m = lg.shape[0]
    cdef float d
    with nogil:
        for i in range(m):
            d = _vertex_offset(lg[i, 0], lg[i, 1], lg[i, 2])
            out[i] = freq_flat[rows[i] * n_bins + cols[i]] + <double>d * bin_hz[rows[i]]


@cython.boundscheck(False)
@cython.wraparound(False)
def select_frame(ppad_a, valid_a, int n_train, int n_guard, int rank, comp_a, int npad, float scale,
                 float aided_scale, bint want_weak, noise_a, thr_a, rows_a, cols_a, cells_a, counts_a, scratch_a):
    """:func:`select` for the stage (edge.lane.peaks.PeakStage), the arrays read through the numpy C API. ``noise_a``
    (seg, n) is filled with NaN first and ``thr_a`` (seg, n) gets noise * scale everywhere. The kept maxima come with
    the detected ones first, then the weak ones, each in (segment, bin) order; ``counts_a`` (2 seg,) int64 gets their
    numbers per segment (detected, then weak). Returns ``(m_hit, m)``."""
    cdef Py_ssize_t n_seg = len(valid_a), n, ncomp = len(comp_a), cap_m = len(rows_a), i, j, w, m
    if n_seg == 0:
        return 0, 0
    n = len(valid_a[0])
    if npad > KDET_MAX_PAD or npad < 2 * n_train or rank < 1 or rank > 2 * n_train or KDET_LANES != 8:
        raise ValueError("reference window too large or rank out of range")
    if cap_m < n_seg * (n // 2 + 1):
        raise ValueError("rows_a cannot hold every local maximum")
    cdef const float *ppad = <const float *>_data2(ppad_a, cnp.NPY_FLOAT32, n_seg, n + 2 * (n_train + n_guard),
                                                   False, "ppad")
    cdef const unsigned char *valid = <const unsigned char *>_data2(valid_a, cnp.NPY_UINT8, n_seg, n, False, "valid")
    cdef const int *comp = <const int *>_data2(comp_a, cnp.NPY_INT32, ncomp, 2, False, "comp")
    cdef float *noise = <float *>_data2(noise_a, cnp.NPY_FLOAT32, n_seg, n, True, "noise")
    cdef float *thr = <float *>_data2(thr_a, cnp.NPY_FLOAT32, n_seg, n, True, "thr")
    cdef long *rows = <long *>_data(rows_a, cnp.NPY_INT64, cap_m, True, "rows")
    cdef long *cols = <long *>_data(cols_a, cnp.NPY_INT64, cap_m, True, "cols")
    cdef float *cells = <float *>_data2(cells_a, cnp.NPY_FLOAT32, cap_m, 3, True, "cells")
    cdef long long *counts = <long long *>_data(counts_a, cnp.NPY_INT64, 2 * n_seg, True, "counts")
    cdef float *scratch = <float *>_data(scratch_a, cnp.NPY_FLOAT32, cap_m, True, "scratch")
    cdef unsigned char *hit = <unsigned char *>malloc(cap_m + 1)
    cdef long *wr = <long *>malloc((2 * cap_m + 1) * sizeof(long))
    cdef float *wc = <float *>malloc((3 * cap_m + 1) * sizeof(float))
    if hit == NULL or wr == NULL or wc == NULL:
        free(hit); free(wr); free(wc)
        raise MemoryError()
    with nogil:
        for i in range(n_seg * n):
            noise[i] = NAN
        m = _select_core(ppad, valid, <int>n_seg, <int>n, n_train, n_guard, rank, comp, <int>ncomp, npad, scale,
                         aided_scale, want_weak, noise, rows, cols, cells, hit, scratch)
        for i in range(n_seg * n):
            thr[i] = noise[i] * scale
        for i in range(2 * n_seg):
            counts[i] = 0
        j = 0  # the detected ones moved to the front (in place: j <= i), the weak ones set aside, then appended
        w = 0
        for i in range(m):
            if hit[i]:
                rows[j] = rows[i]
                cols[j] = cols[i]
                cells[3 * j] = cells[3 * i]
                cells[3 * j + 1] = cells[3 * i + 1]
                cells[3 * j + 2] = cells[3 * i + 2]
                counts[rows[i]] += 1
                j += 1
            else:
                wr[2 * w] = rows[i]
                wr[2 * w + 1] = cols[i]
                wc[3 * w] = cells[3 * i]
                wc[3 * w + 1] = cells[3 * i + 1]
                wc[3 * w + 2] = cells[3 * i + 2]
                counts[n_seg + rows[i]] += 1
                w += 1
        for i in range(w):
            rows[j + i] = wr[2 * i]
            cols[j + i] = wr[2 * i + 1]
            cells[3 * (j + i)] = wc[3 * i]
            cells[3 * (j + i) + 1] = wc[3 * i + 1]
            cells[3 * (j + i) + 2] = wc[3 * i + 2]
    free(hit); free(wr); free(wc)
    return j, m


@cython.boundscheck(False)
@cython.wraparound(False)
def frame_peaks(lg_a, rows_a, cols_a, freq_flat_a, bin_hz_a, int n_bins, counts_a, Py_ssize_t m_hit, Py_ssize_t m,
                bint want_weak, Py_ssize_t max_peaks):
    """The stage's peaks after :func:`select_frame` and numpy's float32 log of its first ``m`` cells (``lg_a``
    (m, 3)): each peak's frequency as :func:`interpolate`, grouped per segment by ``counts_a``. Returns
    ``(freqs, bins, weak_freqs, weak_bins)``, tuples of new float64 and int64 arrays per segment; ``freqs`` and
    ``bins`` None when a segment holds more than ``max_peaks`` detected peaks; the weak ones None without
    ``want_weak``."""
    cdef Py_ssize_t n_seg = len(counts_a) // 2, cap_m = len(rows_a), i, k, start, cnt
    if not (0 <= m_hit <= m <= cap_m) or len(counts_a) != 2 * n_seg:
        raise ValueError("m_hit <= m <= len(rows_a) and counts for each segment needed")
    cdef const float *lg = <const float *>_data2(lg_a, cnp.NPY_FLOAT32, m, 3, False, "lg")
    cdef const long *rows = <const long *>_data(rows_a, cnp.NPY_INT64, cap_m, False, "rows")
    cdef const long *cols = <const long *>_data(cols_a, cnp.NPY_INT64, cap_m, False, "cols")
    cdef const double *freq_flat = <const double *>_data(freq_flat_a, cnp.NPY_FLOAT64, n_seg * n_bins, False,
                                                         "freq_flat")
    cdef const double *bin_hz = <const double *>_data(bin_hz_a, cnp.NPY_FLOAT64, n_seg, False, "bin_hz")
    cdef const long long *counts = <const long long *>_data(counts_a, cnp.NPY_INT64, 2 * n_seg, False, "counts")
    cdef float d
    cdef cnp.ndarray fa, ba
    cdef double *fp
    cdef long *bp
    cdef Py_ssize_t total = 0
    for k in range(2 * n_seg):
        if counts[k] < 0:
            raise ValueError("negative count")
        total += counts[k]
    if total != m:
        raise ValueError("counts do not add up to m")
    out = []
    start = 0
    for k in range(2 * n_seg if want_weak else n_seg):
        cnt = counts[k]
        fa = _new(cnp.NPY_FLOAT64, cnt)
        ba = _new(cnp.NPY_INT64, cnt)
        fp = <double *>cnp.PyArray_DATA(fa)
        bp = <long *>cnp.PyArray_DATA(ba)
        for i in range(cnt):
            d = _vertex_offset(lg[3 * (start + i)], lg[3 * (start + i) + 1], lg[3 * (start + i) + 2])
            fp[i] = freq_flat[rows[start + i] * n_bins + cols[start + i]] + <double>d * bin_hz[rows[start + i]]
            bp[i] = cols[start + i]
        out.append((fa, ba))
        start += cnt
    capped = False
    for k in range(n_seg):
        if counts[k] > max_peaks:
            capped = True
    freqs = None if capped else tuple(out[k][0] for k in range(n_seg))
    bins = None if capped else tuple(out[k][1] for k in range(n_seg))
    if not want_weak:
        return freqs, bins, None, None
    return (freqs, bins, tuple(out[k][0] for k in range(n_seg, 2 * n_seg)),
            tuple(out[k][1] for k in range(n_seg, 2 * n_seg)))
