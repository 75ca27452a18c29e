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
from libc.string cimport memcpy

import numpy as np


def to_complex(const short[:, :, ::1] i, const short[:, :, ::1] q, const float[::1] w,
               float complex[:, :, ::1] out):
    """``out = (i + 1j q) * w``: int16 I/Q (rx, seg, bin) to complex64, windowed (``w`` float32, per bin)."""
    cdef Py_ssize_t a, b, k, n0 = i.shape[0], n1 = i.shape[1], n2 = i.shape[2]
    cdef float* o
    for a in range(n0):
        for b in range(n1):
            o = <float*>&out[a, b, 0]  # interleaved re, im
            for k in range(n2):
                o[2 * k] = <float>i[a, b, k] * w[k]
                o[2 * k + 1] = <float>q[a, b, k] * w[k]


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
    cdef float dr, di, sr, si, med, thr, v0, v1
    cdef const float* sp
    cdef const float* pp
    cdef const float* bp
    cdef float* dp
    cdef float* cp
    cdef float* op
    for s in range(n_seg):  # channel by channel, bins innermost (contiguous): the same sums per cell
        cp = &change[s, 0]
        op = &own[s, 0]
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
        for k in range(n):  # 1 where the cell moved (its map holds), else 0
            work[k] = 1.0 if cp[k] > thr + op[k] * rel2 else 0.0
        for r in range(n_rx):
            sp = <const float*>&spec[r, s, 0]
            bp = <const float*>&background[r, s, 0]
            dp = <float*>&d[r, s, 0]
            for k in range(n):
                v0 = (sp[2 * k] - bp[2 * k]) * alpha
                v1 = (sp[2 * k + 1] - bp[2 * k + 1]) * alpha
                if work[k] != 0.0:
                    v0 = 0.0
                    v1 = 0.0
                dp[2 * k] = v0
                dp[2 * k + 1] = v1


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


from libc.math cimport sqrtf


@cython.boundscheck(False)
@cython.wraparound(False)
def static_residue(const float complex[:, :, :] ref, const long long[:, :] bins, const float[:, :] power,
                   const float[:] floor, float ratio, float noise_floors):
    """:meth:`edge.lane.clutter.ClutterMap.static_residue` with the map's echo ``ref`` (rx, seg, bin): per pairing
    (``bins`` (n, seg)), whether in every segment the peak's amplitude ``sqrt(power)`` is at most
    ``sqrt(ratio * echo) + sqrt(noise_floors * floor)`` and the echo (its power summed over the channels in numpy's
    order) exceeds ``floor``. float32, one rounding per operation as numpy's. Returns (n,) bool; None when a bin
    lies outside the map (the numpy form handles it)."""
    cdef Py_ssize_t n = bins.shape[0], nseg = bins.shape[1], nrx = ref.shape[0], nb = ref.shape[2], i, k, c
    cdef long long b
    cdef float bg, re, im, bound
    cdef bint ok
    if nseg > ref.shape[1] or nseg > power.shape[0] or nseg > floor.shape[0]:
        return None
    for i in range(n):
        for k in range(nseg):
            if bins[i, k] < 0 or bins[i, k] >= nb or bins[i, k] >= power.shape[1]:
                return None
    out_arr = np.empty(n, dtype=bool)
    cdef unsigned char[::1] out = out_arr.view(np.uint8)
    with nogil:
        for i in range(n):
            ok = True
            for k in range(nseg):
                b = bins[i, k]
                bg = 0.0
                for c in range(nrx):
                    re = ref[c, k, b].real
                    im = ref[c, k, b].imag
                    bg = bg + (re * re + im * im)
                bound = sqrtf(ratio * bg) + sqrtf(noise_floors * floor[k])
                if not (sqrtf(power[k, b]) <= bound and bg > floor[k]):
                    ok = False
            out[i] = ok
    return out_arr
