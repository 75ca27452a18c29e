# cython: language_level=3
"""Compiled kernels of the lane profile's spectra stage (edge/lane/spectra.py, edge/lane/clutter.py).

The numpy code of :class:`edge.lane.spectra.SpectraStage` and :class:`edge.lane.clutter.ClutterMap` is the
reference. Every operation is the same float32 arithmetic element by element (setup.py compiles with
-ffp-contract=off: no fused multiply-add, which would round differently from numpy), and the sums of squares
over the channels are taken in numpy's order (channel by channel, real before imaginary, from zero), so the
results are bit-identical; tests/native/test_spectra.py checks it on random inputs, on recorded frames and
end to end. Should a numpy release change the order of its reductions, the change and own energies of the
static test, and the channel power, could differ in the last bit (relative 1e-7): the tests would show it.
"""

cimport cython
cimport numpy as cnp
from libc.string cimport memcpy, memset

import numpy as np

cnp.import_array()

include "_arrays.pxi"
include "_alloc.pxi"
include "_views.pxi"


cdef extern from *:
    """
    #include <string.h>
    /* The clutter map's hot loops four bins at a time in GCC/Clang vector types (SSE on x86-64, NEON on arm64,
       plain C elsewhere): element-wise float32 operations, each rounded as the scalar one (no contraction:
       -ffp-contract=off), in the scalar loop's order; the remaining bins by the same scalar expressions. */
    typedef float ksp_v4 __attribute__((vector_size(16)));
    typedef unsigned int ksp_u4 __attribute__((vector_size(16)));
    #if defined(__clang__)
    #define KSP_SHUF(a, b, i0, i1, i2, i3) __builtin_shufflevector((a), (b), i0, i1, i2, i3)
    #else
    #define KSP_SHUF(a, b, i0, i1, i2, i3) __builtin_shuffle((a), (b), (ksp_u4){i0, i1, i2, i3})
    #endif
    #define KSP_MAX_RX 16
    static inline ksp_v4 ksp_load(const float *p) { ksp_v4 v; memcpy(&v, p, sizeof v); return v; }
    static inline void ksp_store(float *p, ksp_v4 v) { memcpy(p, &v, sizeof v); }

    /* rows of int16 I/Q to interleaved complex64, each times the window: o = (float)i * w, (float)q * w. */
    static void ksp_to_complex(const short *restrict ip, const short *restrict qp, const float *restrict w,
                               float *restrict o, Py_ssize_t rows, Py_ssize_t n) {
        for (Py_ssize_t r = 0; r < rows; r++, ip += n, qp += n, o += 2 * n) {
            Py_ssize_t k = 0;
            for (; k < n; k++) {
                o[2 * k] = (float)ip[k] * w[k];
                o[2 * k + 1] = (float)qp[k] * w[k];
            }
        }
    }

    /* The kth smallest of v[:n] (NaN-free, left as it is; work: n floats), Hoare's selection in place. */
    static float ksp_hoare(float *v, Py_ssize_t n, Py_ssize_t kth) {
        Py_ssize_t lo = 0, hi = n - 1, a, b;
        float pivot, t;
        while (lo < hi) {
            pivot = v[(lo + hi) / 2];
            a = lo;
            b = hi;
            while (a <= b) {
                while (v[a] < pivot) a++;
                while (v[b] > pivot) b--;
                if (a <= b) {
                    t = v[a]; v[a] = v[b]; v[b] = t;
                    a++;
                    b--;
                }
            }
            if (kth <= b) hi = b;
            else if (kth >= a) lo = a;
            else break;
        }
        return v[kth];
    }

    /* The kth smallest of v[:n] (NaN-free; v is left as it is, work holds n floats): the value is the same whatever
       the method. From 256 values on, two values of a sample of 64 bracket it: one pass counts the values below the
       bracket and copies those in it, and Hoare's selection runs on these alone; when the bracket misses (about one
       time in twenty), on a copy of all. */
    static float ksp_select(const float *v, Py_ssize_t n, Py_ssize_t kth, float *work) {
        Py_ssize_t k, c, nlt = 0, r, step;
        float lo, hi, x;
        if (n >= 256) {
            step = n / 64;
            for (k = 0; k < 64; k++)
                work[k] = v[k * step + step / 2];
            r = kth * 64 / n;
            lo = ksp_hoare(work, 64, r >= 8 ? r - 8 : 0);
            hi = ksp_hoare(work, 64, r + 8 <= 63 ? r + 8 : 63);
            for (k = 0, c = 0; k < n; k++) {  /* (a branch per value: most lie outside the bracket) */
                x = v[k];
                if (x < lo)
                    nlt++;
                else if (x <= hi)
                    work[c++] = x;
            }
            if (nlt <= kth && kth < nlt + c)
                return ksp_hoare(work, c, kth - nlt);
        }
        memcpy(work, v, n * sizeof(float));
        return ksp_hoare(work, n, kth);
    }

    /* One segment's static test inputs: cp[k] = sum over the channels of |sp - pp|^2, op[k] = of |sp|^2, channel
       by channel from the first, real before imaginary (sp[r], pp[r]: channel r's interleaved complex bins). */
    static void ksp_change_own(const float *const *sp, const float *const *pp, int n_rx, int n, float *cp,
                               float *op) {
        int k = 0, r;
        ksp_v4 c, o, sr, si, dr, di;
    #define KSP_CHANNEL(r) do {                                                                          \
            ksp_v4 s0 = ksp_load(sp[r] + 2 * k), s1 = ksp_load(sp[r] + 2 * k + 4);                       \
            ksp_v4 p0 = ksp_load(pp[r] + 2 * k), p1 = ksp_load(pp[r] + 2 * k + 4);                       \
            sr = KSP_SHUF(s0, s1, 0, 2, 4, 6);                                                           \
            si = KSP_SHUF(s0, s1, 1, 3, 5, 7);                                                           \
            dr = sr - KSP_SHUF(p0, p1, 0, 2, 4, 6);                                                      \
            di = si - KSP_SHUF(p0, p1, 1, 3, 5, 7);                                                      \
        } while (0)
        if (n_rx == 4) {  /* the SIMO board's four channels, unrolled */
            for (; k + 4 <= n; k += 4) {
                KSP_CHANNEL(0);
                c = dr * dr + di * di;
                o = sr * sr + si * si;
                KSP_CHANNEL(1);
                c = (c + dr * dr) + di * di;
                o = (o + sr * sr) + si * si;
                KSP_CHANNEL(2);
                c = (c + dr * dr) + di * di;
                o = (o + sr * sr) + si * si;
                KSP_CHANNEL(3);
                c = (c + dr * dr) + di * di;
                o = (o + sr * sr) + si * si;
                ksp_store(cp + k, c);
                ksp_store(op + k, o);
            }
        }
        for (; k + 4 <= n; k += 4) {
            KSP_CHANNEL(0);
            c = dr * dr + di * di;
            o = sr * sr + si * si;
            for (r = 1; r < n_rx; r++) {
                KSP_CHANNEL(r);
                c = (c + dr * dr) + di * di;
                o = (o + sr * sr) + si * si;
            }
            ksp_store(cp + k, c);
            ksp_store(op + k, o);
        }
    #undef KSP_CHANNEL
        for (; k < n; k++) {
            float c = 0, o = 0;
            for (r = 0; r < n_rx; r++) {
                float sr = sp[r][2 * k], si = sp[r][2 * k + 1];
                float dr = sr - pp[r][2 * k], di = si - pp[r][2 * k + 1];
                if (r == 0) {
                    c = dr * dr + di * di;
                    o = sr * sr + si * si;
                } else {
                    c = (c + dr * dr) + di * di;
                    o = (o + sr * sr) + si * si;
                }
            }
            cp[k] = c;
            op[k] = o;
        }
    }

    /* dp = (sp - bp) * alpha over n interleaved complex bins, +0.0 where the mask keep[k] (all bits set, or
       none; written and read by memcpy: the scratch is a float array) is 0: no branch per bin. */
    static void ksp_masked_update(const float *sp, const float *bp, float *dp, const float *keep, int n,
                                  float alpha) {
        int k = 0;
        unsigned int mk;
        ksp_v4 a = {alpha, alpha, alpha, alpha};
        for (; k + 4 <= n; k += 4) {
            ksp_u4 m;
            memcpy(&m, keep + k, sizeof m);
            ksp_v4 v0 = (ksp_load(sp + 2 * k) - ksp_load(bp + 2 * k)) * a;
            ksp_v4 v1 = (ksp_load(sp + 2 * k + 4) - ksp_load(bp + 2 * k + 4)) * a;
            ksp_store(dp + 2 * k, (ksp_v4)((ksp_u4)v0 & KSP_SHUF(m, m, 0, 0, 1, 1)));
            ksp_store(dp + 2 * k + 4, (ksp_v4)((ksp_u4)v1 & KSP_SHUF(m, m, 2, 2, 3, 3)));
        }
        for (; k < n; k++) {
            float v0 = (sp[2 * k] - bp[2 * k]) * alpha, v1 = (sp[2 * k + 1] - bp[2 * k + 1]) * alpha;
            memcpy(&mk, keep + k, sizeof mk);
            dp[2 * k] = mk ? v0 : 0.0f;
            dp[2 * k + 1] = mk ? v1 : 0.0f;
        }
    }

    /* One segment of the map's update and subtraction, channel by channel per four bins: pv = sp (the raw
       spectra, for the next frame's static test); d = (sp - bp) * alpha, +0.0 where the mask keep[k] is 0;
       bp = bp + d; sp = sp - bp; pp = the channel sum of the new |sp|^2 (the first channel's re^2 + im^2, then
       pp + (re^2 + im^2)). The same element-wise expressions as ksp_masked_update, apply_map and
       channel_power, so the same bits. */
    static void ksp_update_apply(float *const *sp, float *const *bp, float *const *pv, int n_rx, int n,
                                 const float *keep, float alpha, float *pp) {
        int k = 0, r;
        unsigned int mk;
        ksp_v4 a = {alpha, alpha, alpha, alpha};
    #define KSP_UPDATE_CHANNEL(r) do {                                                                   \
            float *s = sp[r] + 2 * k, *b = bp[r] + 2 * k;                                                \
            ksp_v4 s0 = ksp_load(s), s1 = ksp_load(s + 4), b0 = ksp_load(b), b1 = ksp_load(b + 4);       \
            ksp_store(pv[r] + 2 * k, s0);                                                                \
            ksp_store(pv[r] + 2 * k + 4, s1);                                                            \
            b0 = b0 + (ksp_v4)((ksp_u4)((s0 - b0) * a) & m0);                                            \
            b1 = b1 + (ksp_v4)((ksp_u4)((s1 - b1) * a) & m1);                                            \
            s0 = s0 - b0;                                                                                \
            s1 = s1 - b1;                                                                                \
            ksp_store(b, b0);                                                                            \
            ksp_store(b + 4, b1);                                                                        \
            ksp_store(s, s0);                                                                            \
            ksp_store(s + 4, s1);                                                                        \
            re = KSP_SHUF(s0, s1, 0, 2, 4, 6);                                                           \
            im = KSP_SHUF(s0, s1, 1, 3, 5, 7);                                                           \
        } while (0)
        ksp_v4 re, im, p;
        ksp_u4 m, m0, m1;
        if (n_rx == 4) {  /* the SIMO board's four channels, unrolled */
            for (; k + 4 <= n; k += 4) {
                memcpy(&m, keep + k, sizeof m);
                m0 = KSP_SHUF(m, m, 0, 0, 1, 1);
                m1 = KSP_SHUF(m, m, 2, 2, 3, 3);
                KSP_UPDATE_CHANNEL(0);
                p = re * re + im * im;
                KSP_UPDATE_CHANNEL(1);
                p = p + (re * re + im * im);
                KSP_UPDATE_CHANNEL(2);
                p = p + (re * re + im * im);
                KSP_UPDATE_CHANNEL(3);
                p = p + (re * re + im * im);
                ksp_store(pp + k, p);
            }
        }
        for (; k + 4 <= n; k += 4) {
            memcpy(&m, keep + k, sizeof m);
            m0 = KSP_SHUF(m, m, 0, 0, 1, 1);
            m1 = KSP_SHUF(m, m, 2, 2, 3, 3);
            KSP_UPDATE_CHANNEL(0);
            p = re * re + im * im;
            for (r = 1; r < n_rx; r++) {
                KSP_UPDATE_CHANNEL(r);
                p = p + (re * re + im * im);
            }
            ksp_store(pp + k, p);
        }
    #undef KSP_UPDATE_CHANNEL
        for (; k < n; k++) {
            float p = 0;
            memcpy(&mk, keep + k, sizeof mk);
            for (r = 0; r < n_rx; r++) {
                float *s = sp[r] + 2 * k, *b = bp[r] + 2 * k;
                float sr = s[0], si = s[1];
                float v0 = (sr - b[0]) * alpha, v1 = (si - b[1]) * alpha;
                pv[r][2 * k] = sr;
                pv[r][2 * k + 1] = si;
                b[0] = b[0] + (mk ? v0 : 0.0f);
                b[1] = b[1] + (mk ? v1 : 0.0f);
                sr = sr - b[0];
                si = si - b[1];
                s[0] = sr;
                s[1] = si;
                if (r == 0)
                    p = sr * sr + si * si;
                else
                    p = p + (sr * sr + si * si);
            }
            pp[k] = p;
        }
    }

    /* ksp_update_apply for a segment whose map stands this frame: sp = sp - bp; pp = the channel sum of the new
       |sp|^2. The same element-wise expressions, so the same bits. */
    static void ksp_apply_power(float *const *sp, float *const *bp, int n_rx, int n, float *pp) {
        int k = 0, r;
        ksp_v4 re, im, s0, s1, p = {0, 0, 0, 0};
    #define KSP_APPLY_CHANNEL(s, b) do {                                                                 \
            s0 = ksp_load(s + 2 * k) - ksp_load(b + 2 * k);                                              \
            s1 = ksp_load(s + 2 * k + 4) - ksp_load(b + 2 * k + 4);                                      \
            ksp_store(s + 2 * k, s0);                                                                    \
            ksp_store(s + 2 * k + 4, s1);                                                                \
            re = KSP_SHUF(s0, s1, 0, 2, 4, 6);                                                           \
            im = KSP_SHUF(s0, s1, 1, 3, 5, 7);                                                           \
        } while (0)
        if (n_rx == 4) {  /* the SIMO board's four channels, unrolled */
            float *s_0 = sp[0], *s_1 = sp[1], *s_2 = sp[2], *s_3 = sp[3];
            const float *b_0 = bp[0], *b_1 = bp[1], *b_2 = bp[2], *b_3 = bp[3];
            for (; k + 4 <= n; k += 4) {
                KSP_APPLY_CHANNEL(s_0, b_0);
                p = re * re + im * im;
                KSP_APPLY_CHANNEL(s_1, b_1);
                p = p + (re * re + im * im);
                KSP_APPLY_CHANNEL(s_2, b_2);
                p = p + (re * re + im * im);
                KSP_APPLY_CHANNEL(s_3, b_3);
                p = p + (re * re + im * im);
                ksp_store(pp + k, p);
            }
        }
        for (; k + 4 <= n; k += 4) {
            for (r = 0; r < n_rx; r++) {
                KSP_APPLY_CHANNEL(sp[r], bp[r]);
                if (r == 0)
                    p = re * re + im * im;
                else
                    p = p + (re * re + im * im);
            }
            ksp_store(pp + k, p);
        }
    #undef KSP_APPLY_CHANNEL
        for (; k < n; k++) {
            float q = 0;
            for (r = 0; r < n_rx; r++) {
                float *s = sp[r] + 2 * k, *b = bp[r] + 2 * k;
                float sr = s[0] - b[0], si = s[1] - b[1];
                s[0] = sr;
                s[1] = si;
                if (r == 0)
                    q = sr * sr + si * si;
                else
                    q = q + (sr * sr + si * si);
            }
            pp[k] = q;
        }
    }
    """
    int KSP_MAX_RX
    void ksp_change_own(const float* const* sp, const float* const* pp, int n_rx, int n, float* cp,
                        float* op) noexcept nogil
    void ksp_masked_update(const float* sp, const float* bp, float* dp, const float* keep, int n,
                           float alpha) noexcept nogil
    float ksp_select(const float* v, Py_ssize_t n, Py_ssize_t kth, float* work) noexcept nogil
    void ksp_to_complex(const short* ip, const short* qp, const float* w, float* o, Py_ssize_t rows,
                        Py_ssize_t n) noexcept nogil
    void ksp_update_apply(float* const* sp, float* const* bp, float* const* pv, int n_rx, int n,
                          const float* keep, float alpha, float* pp) noexcept nogil
    void ksp_apply_power(float* const* sp, float* const* bp, int n_rx, int n, float* pp) noexcept nogil


def to_complex(i, q, w, out):
    """``out = (i + 1j q) * w``: int16 I/Q (rx, seg, bin) to complex64, windowed (``w`` float32, per bin). The
    arrays C-contiguous, aligned, native (read through the numpy C API)."""
    cdef cnp.ndarray a = i
    if not cnp.PyArray_Check(i) or cnp.PyArray_NDIM(a) != 3:
        raise ValueError("to_complex: i must be a (rx, seg, bin) int16 array")
    cdef Py_ssize_t n0 = cnp.PyArray_DIM(a, 0), n1 = cnp.PyArray_DIM(a, 1), n2 = cnp.PyArray_DIM(a, 2)
    cdef const short* ip = <const short*>_data3(i, cnp.NPY_INT16, n0, n1, n2, False, "i")
    cdef const short* qp = <const short*>_data3(q, cnp.NPY_INT16, n0, n1, n2, False, "q")
    cdef const float* wp = <const float*>_data(w, cnp.NPY_FLOAT32, n2, False, "w")
    cdef float* op = <float*>_data3(out, cnp.NPY_COMPLEX64, n0, n1, n2, True, "out")
    with nogil:
        ksp_to_complex(ip, qp, wp, op, n0 * n1, n2)


cdef float _select(float* v, Py_ssize_t n, Py_ssize_t kth) noexcept nogil:
    """The ``kth`` smallest of ``v[:n]`` (Hoare's selection, in place; NaN-free input)."""
    cdef Py_ssize_t lo = 0, hi = n - 1, a, b
    cdef float pivot, t
    while lo < hi:
        pivot = v[(lo + hi) // 2]
        a = lo
        b = hi
        while a <= b:
            while v[a] < pivot:
                a += 1
            while v[b] > pivot:
                b -= 1
            if a <= b:
                t = v[a]; v[a] = v[b]; v[b] = t
                a += 1
                b -= 1
        if kth <= b:
            hi = b
        elif kth >= a:
            lo = a
        else:
            break
    return v[kth]


def update_hold_moving(const float complex[:, :, ::1] spec, const float complex[:, :, ::1] background,
                       float complex[:, :, ::1] prev, float complex[:, :, ::1] d, float alpha,
                       float factor, float rel2, float[:, ::1] change, float[:, ::1] own, float[::1] work):
    """The clutter map's update with its static test (``ClutterMap.subtract`` up to ``_hold_moving``):
    ``d = alpha (spec - background)``, zero in the (seg, bin) cells whose change since ``prev`` (summed over
    the channels, |.|^2) exceeds ``factor`` x its segment's median plus ``rel2`` x the cell's own energy;
    then ``prev = spec``. ``change``, ``own`` (seg, bin) and ``work`` (bin) are scratch. Shapes (rx, seg, bin)."""
    cdef Py_ssize_t n_rx = spec.shape[0], n_seg = spec.shape[1], n = spec.shape[2], r, s, k
    cdef float dr, di, sr, si, med, thr
    cdef unsigned int keep
    cdef const float* sp
    cdef const float* pp
    cdef float* cp
    cdef float* op
    cdef const float* sps[16]
    cdef const float* pps[16]
    for s in range(n_seg):  # channel by channel (from the first, real before imaginary): the same sums per cell
        cp = &change[s, 0]
        op = &own[s, 0]
        if n_rx <= KSP_MAX_RX:  # all channels at once, four bins at a time
            for r in range(n_rx):
                sps[r] = <const float*>&spec[r, s, 0]
                pps[r] = <const float*>&prev[r, s, 0]
            ksp_change_own(sps, pps, n_rx, n, cp, op)
            continue
        for r in range(n_rx):
            sp = <const float*>&spec[r, s, 0]
            pp = <const float*>&prev[r, s, 0]
            if r == 0:
                for k in range(n):
                    sr = sp[2 * k]
                    si = sp[2 * k + 1]
                    dr = sr - pp[2 * k]
                    di = si - pp[2 * k + 1]
                    cp[k] = dr * dr + di * di
                    op[k] = sr * sr + si * si
            else:
                for k in range(n):
                    sr = sp[2 * k]
                    si = sp[2 * k + 1]
                    dr = sr - pp[2 * k]
                    di = si - pp[2 * k + 1]
                    cp[k] = (cp[k] + dr * dr) + di * di
                    op[k] = (op[k] + sr * sr) + si * si
    for r in range(n_rx):
        for s in range(n_seg):
            memcpy(&prev[r, s, 0], &spec[r, s, 0], n * sizeof(float complex))
    for s in range(n_seg):
        cp = &change[s, 0]
        op = &own[s, 0]
        memcpy(&work[0], cp, n * sizeof(float))
        med = _select(&work[0], n, n // 2)
        thr = med * factor
        for k in range(n):  # the mask: all bits where the cell stood still (its map learns), none where it moved
            keep = 0 if cp[k] > thr + op[k] * rel2 else 0xFFFFFFFF
            memcpy(&work[k], &keep, sizeof(unsigned int))
        for r in range(n_rx):
            ksp_masked_update(<const float*>&spec[r, s, 0], <const float*>&background[r, s, 0],
                              <float*>&d[r, s, 0], &work[0], n, alpha)


def apply_map(float complex[:, :, ::1] spec, float complex[:, :, ::1] background,
              const float complex[:, :, ::1] d):
    """``background += d; spec -= background`` (rx, seg, bin) complex64, in one pass."""
    cdef Py_ssize_t n0 = spec.shape[0], n1 = spec.shape[1], n2 = spec.shape[2], a, b, k
    cdef float* sp
    cdef float* bp
    cdef const float* dp
    for a in range(n0):
        for b in range(n1):
            sp = <float*>&spec[a, b, 0]
            bp = <float*>&background[a, b, 0]
            dp = <const float*>&d[a, b, 0]
            for k in range(2 * n2):  # re and im alike
                bp[k] = bp[k] + dp[k]
                sp[k] = sp[k] - bp[k]


def channel_power(const float complex[:, :, ::1] spec, float[:, ::1] ppad, Py_ssize_t h):
    """Non-coherent sum over the channels, ``sum_r (re^2 + im^2)`` channel by channel as numpy's ``add.reduce``,
    into ``ppad[:, h:h+n]`` with ``h`` cells of circular padding each side (seg, n + 2h) float32."""
    cdef Py_ssize_t n_rx = spec.shape[0], n_seg = spec.shape[1], n = spec.shape[2], r, s, k
    cdef float p, re, im
    cdef const float* sp
    for s in range(n_seg):
        for k in range(n):
            sp = <const float*>&spec[0, s, k]
            p = sp[0] * sp[0] + sp[1] * sp[1]
            for r in range(1, n_rx):
                sp = <const float*>&spec[r, s, k]
                re = sp[0]
                im = sp[1]
                p = p + (re * re + im * im)
            ppad[s, h + k] = p
        for k in range(h):
            ppad[s, k] = ppad[s, n + k]
            ppad[s, n + h + k] = ppad[s, h + k]


def apply_map_power(float complex[:, :, ::1] spec, float complex[:, :, ::1] background,
                    const float complex[:, :, ::1] d, float[:, ::1] ppad, Py_ssize_t h):
    """:func:`apply_map` and :func:`channel_power`: ``background += d; spec -= background``, and the channel sum
    of the result into ``ppad`` (same order of summation as :func:`channel_power`)."""
    cdef Py_ssize_t n_rx = spec.shape[0], n_seg = spec.shape[1], n = spec.shape[2], r, s, k
    cdef float re, im
    cdef float* sp
    cdef float* pp
    cdef const float* dp
    cdef float* bq
    for r in range(n_rx):
        for s in range(n_seg):
            sp = <float*>&spec[r, s, 0]
            bq = <float*>&background[r, s, 0]
            dp = <const float*>&d[r, s, 0]
            for k in range(2 * n):  # re and im alike
                bq[k] = bq[k] + dp[k]
                sp[k] = sp[k] - bq[k]
    for s in range(n_seg):  # channel by channel, bins innermost: the same sums per cell
        pp = &ppad[s, h]
        for r in range(n_rx):
            sp = <float*>&spec[r, s, 0]
            if r == 0:
                for k in range(n):
                    re = sp[2 * k]
                    im = sp[2 * k + 1]
                    pp[k] = re * re + im * im
            else:
                for k in range(n):
                    re = sp[2 * k]
                    im = sp[2 * k + 1]
                    pp[k] = pp[k] + (re * re + im * im)
        for k in range(h):
            ppad[s, k] = ppad[s, n + k]
            ppad[s, n + h + k] = ppad[s, h + k]


def update_apply_power(spec, background, prev, float alpha, float factor, float rel2, hold, ppad, Py_ssize_t h,
                       change, own, work, Py_ssize_t seg=-1, Py_ssize_t keep_seg=-1):
    """:func:`update_hold_moving`, the update held where ``hold`` (seg, bin) uint8 is non-zero (None: nowhere), then
    :func:`apply_map_power`, in one pass over the cells: ``prev = spec``; ``d`` as there; ``background += d``;
    ``spec -= background``; the channel power of the result into ``ppad`` (seg, bin + 2 ``h``) float32, circularly
    padded. ``spec``, ``background``, ``prev`` (rx, seg, bin) complex64, C-contiguous (read through the numpy C
    API); ``change``, ``own`` (seg, bin) and ``work`` (bin) float32 scratch. ``seg`` >= 0: only that segment's map
    learns (and its ``prev`` is kept); the others are subtracted as they stand, and ``prev`` keeps segment
    ``keep_seg``'s spectra as well (-1: none)."""
    cdef cnp.ndarray a = spec
    if not cnp.PyArray_Check(spec) or cnp.PyArray_NDIM(a) != 3:
        raise ValueError("update_apply_power: spec must be a (rx, seg, bin) complex64 array")
    cdef Py_ssize_t n_rx = cnp.PyArray_DIM(a, 0), n_seg = cnp.PyArray_DIM(a, 1), n = cnp.PyArray_DIM(a, 2), r, s, k
    if n_rx > KSP_MAX_RX or h > n:
        raise ValueError("update_apply_power: at most 16 channels and h <= bins")
    cdef float* sp0 = <float*>_data3(spec, cnp.NPY_COMPLEX64, n_rx, n_seg, n, True, "spec")
    cdef float* bp0 = <float*>_data3(background, cnp.NPY_COMPLEX64, n_rx, n_seg, n, True, "background")
    cdef float* pv0 = <float*>_data3(prev, cnp.NPY_COMPLEX64, n_rx, n_seg, n, True, "prev")
    cdef float* pp0 = <float*>_data2(ppad, cnp.NPY_FLOAT32, n_seg, n + 2 * h, True, "ppad")
    cdef float* ch0 = <float*>_data2(change, cnp.NPY_FLOAT32, n_seg, n, True, "change")
    cdef float* ow0 = <float*>_data2(own, cnp.NPY_FLOAT32, n_seg, n, True, "own")
    cdef float* wk = <float*>_data(work, cnp.NPY_FLOAT32, n, True, "work")
    cdef const unsigned char* hd = NULL
    if hold is not None:
        hd = <const unsigned char*>_data2(hold, cnp.NPY_UINT8, n_seg, n, False, "hold")
    cdef float* sps[16]
    cdef float* bps[16]
    cdef float* pvs[16]
    cdef float* cp
    cdef float* op
    cdef float* pp
    cdef float thr
    cdef unsigned int keep
    if seg >= n_seg or keep_seg >= n_seg:
        raise ValueError("update_apply_power: seg and keep_seg must be segments of spec (or -1)")
    with nogil:
        for s in range(n_seg):
            cp = ch0 + s * n
            op = ow0 + s * n
            for r in range(n_rx):
                sps[r] = sp0 + 2 * (r * n_seg + s) * n
                bps[r] = bp0 + 2 * (r * n_seg + s) * n
                pvs[r] = pv0 + 2 * (r * n_seg + s) * n
            pp = pp0 + s * (n + 2 * h)
            if seg >= 0 and s != seg:  # this segment's map stands: kept spectra (the next to learn), subtraction
                if s == keep_seg:
                    for r in range(n_rx):
                        memcpy(pvs[r], sps[r], 2 * n * sizeof(float))
                ksp_apply_power(sps, bps, <int>n_rx, <int>n, pp + h)
                for k in range(h):
                    pp[k] = pp[n + k]
                    pp[n + h + k] = pp[h + k]
                continue
            ksp_change_own(<const float* const*>sps, <const float* const*>pvs, <int>n_rx, <int>n, cp, op)
            thr = ksp_select(cp, n, n // 2, wk) * factor
            for k in range(n):  # all bits where the cell stood still (its map learns), none where it moved
                keep = 0 if cp[k] > thr + op[k] * rel2 else 0xFFFFFFFF
                memcpy(&wk[k], &keep, sizeof(unsigned int))
            if hd != NULL:  # none where it is held
                for k in range(n):
                    if hd[s * n + k]:
                        memset(&wk[k], 0, sizeof(float))
            ksp_update_apply(sps, bps, pvs, <int>n_rx, <int>n, wk, alpha, pp + h)
            for k in range(h):
                pp[k] = pp[n + k]
                pp[n + h + k] = pp[h + k]


from libc.math cimport sqrtf, NAN


@cython.boundscheck(False)
@cython.wraparound(False)
def static_residue(ref, bins, power, floor, float ratio, float noise_floors):
    """:meth:`edge.lane.clutter.ClutterMap.static_residue` with the map's echo ``ref`` (rx, seg, bin): per pairing
    (``bins`` (n, seg)), whether in every segment the peak's amplitude ``sqrt(power)`` is at most
    ``sqrt(ratio * echo) + sqrt(noise_floors * floor)`` and the echo (its power summed over the channels in numpy's
    order) exceeds ``floor``. float32, one rounding per operation as numpy's. Returns (n,) bool; None when a bin
    lies outside the map (the numpy form handles it). ``ref`` complex64 of any strides, read through the numpy C API
    as the other arrays."""
    cdef _V V_ref
    _aview(ref, cnp.NPY_COMPLEX64, 3, False, False, &V_ref, "ref")
    cdef _V V_bins
    _aview(bins, cnp.NPY_LONGLONG, 2, False, False, &V_bins, "bins")
    cdef _V V_power
    _aview(power, cnp.NPY_FLOAT32, 2, False, False, &V_power, "power")
    cdef _V V_floor
    _aview(floor, cnp.NPY_FLOAT32, 1, False, False, &V_floor, "floor")
    cdef Py_ssize_t n = V_bins.n[0], nseg = V_bins.n[1], nrx = V_ref.n[0], nb = V_ref.n[2], i, k, c
    cdef long long b
    cdef float bg, re, im, bound
    cdef const float *cell
    cdef bint ok
    if nseg > V_ref.n[1] or nseg > V_power.n[0] or nseg > V_floor.n[0]:
        return None
    for i in range(n):
        for k in range(nseg):
            if _pll_2(V_bins, i, k)[0] < 0 or _pll_2(V_bins, i, k)[0] >= nb or _pll_2(V_bins, i, k)[0] >= V_power.n[1]:
                return None
    out_arr = _empty1(cnp.NPY_BOOL, n)
    cdef unsigned char *out = <unsigned char *>cnp.PyArray_DATA(out_arr)
    with nogil:
        for i in range(n):
            ok = True
            for k in range(nseg):
                b = _pll_2(V_bins, i, k)[0]
                bg = 0.0
                for c in range(nrx):
                    cell = <const float *>(V_ref.data + c * V_ref.s[0] + k * V_ref.s[1] + b * V_ref.s[2])
                    re = cell[0]
                    im = cell[1]
                    bg = bg + (re * re + im * im)
                bound = sqrtf(ratio * bg) + sqrtf(noise_floors * _pf1(V_floor, k)[0])
                if not (sqrtf(_pf2(V_power, k, b)[0]) <= bound and bg > _pf1(V_floor, k)[0]):
                    ok = False
            out[i] = ok
    return out_arr


@cython.boundscheck(False)
@cython.wraparound(False)
def median_insert(buf, Py_ssize_t n, spec, out):
    """The clutter map's median of its first frames, a frame at a time: insert the float32 parts of ``spec`` (any
    shape, complex64, C-contiguous) into ``buf`` (2 ``spec.size``, K) float32, whose first ``n`` < K columns hold
    each part's earlier values sorted ascending (NaN last); with ``out`` (complex64, ``spec``'s shape), write there
    the median of the n + 1 values as ``edge.lane.clutter._median_of_frames`` gives it (the middle value, or the
    float32 sum of the middle two halved; NaN where a value is NaN). Equal values keep their order of arrival, so
    a median of zeros may carry another sign than numpy's sort gives it."""
    cdef cnp.ndarray a = spec
    if not cnp.PyArray_Check(spec) or cnp.PyArray_TYPE(a) != cnp.NPY_COMPLEX64 or not cnp.PyArray_IS_C_CONTIGUOUS(a):
        raise ValueError("median_insert: spec must be a C-contiguous complex64 array")
    cdef Py_ssize_t cells = 2 * cnp.PyArray_SIZE(a), k_max, c, j, m, h
    cdef cnp.ndarray b = buf
    if (not cnp.PyArray_Check(buf) or cnp.PyArray_NDIM(b) != 2 or cnp.PyArray_DIM(b, 0) != cells):
        raise ValueError("median_insert: buf must be (2 spec.size, K) float32")
    k_max = cnp.PyArray_DIM(b, 1)
    if n < 0 or n >= k_max:
        raise ValueError("median_insert: n must lie in [0, K)")
    cdef float* bp = <float*>_data2(buf, cnp.NPY_FLOAT32, cells, k_max, True, "buf")
    cdef const float* sp = <const float*>cnp.PyArray_DATA(a)
    cdef float* op = NULL
    cdef cnp.ndarray o
    if out is not None:
        o = out
        if (not cnp.PyArray_Check(out) or cnp.PyArray_TYPE(o) != cnp.NPY_COMPLEX64
                or not cnp.PyArray_IS_C_CONTIGUOUS(o) or 2 * cnp.PyArray_SIZE(o) != cells
                or not cnp.PyArray_ISWRITEABLE(o)):
            raise ValueError("median_insert: out must be a writeable C-contiguous complex64 array of spec's size")
        op = <float*>cnp.PyArray_DATA(o)
    cdef float x, t
    cdef float* row
    m = n + 1
    h = m // 2
    with nogil:
        for c in range(cells):
            row = bp + c * k_max
            x = sp[c]
            j = n
            if x == x:  # a number goes before the greater values and the NaNs
                while j > 0 and not (row[j - 1] <= x):
                    row[j] = row[j - 1]
                    j -= 1
            row[j] = x
            if op != NULL:
                if row[m - 1] != row[m - 1]:
                    op[c] = NAN
                elif m % 2:
                    op[c] = row[h]
                else:
                    t = row[h - 1] + row[h]
                    op[c] = t * <float>0.5  # (halving is exact: numpy's float32 division by 2)