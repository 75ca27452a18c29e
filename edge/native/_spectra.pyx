# cython: language_level=3
"""Compiled kernels of the lane profile's spectra stage (edge/lane/spectra.py, edge/lane/clutter.py).

The numpy code of :class:`edge.lane.spectra.SpectraStage` and :class:`edge.lane.clutter.ClutterMap` is the
reference. Every operation is the same float32 arithmetic element by element (setup.py compiles with
-ffp-contract=off: no fused multiply-add, which would round differently from numpy), so the results are
bit-identical except the sums of squares over the channels: numpy's order of summation over two axes is its
own; here it is channel by channel, real before imaginary. Those sums (the change and own energies of the
static-clutter test) can differ in the last bit, and a bin whose change energy lies within that of the
threshold can then be held differently (never seen on the recorded scenes; tests/native/test_spectra.py).
"""

cimport cython
from libc.string cimport memcpy

import numpy as np


def to_complex(const short[:, :, ::1] i, const short[:, :, ::1] q, const float[::1] w,
               float complex[:, :, ::1] out):
    """``out = (i + 1j q) * w``: int16 I/Q (rx, seg, bin) to complex64, windowed (``w`` float32, per bin)."""
    cdef Py_ssize_t a, b, k, n0 = i.shape[0], n1 = i.shape[1], n2 = i.shape[2]
    cdef float re, im
    for a in range(n0):
        for b in range(n1):
            for k in range(n2):
                re = <float>i[a, b, k] * w[k]
                im = <float>q[a, b, k] * w[k]
                out[a, b, k] = re + 1j * im


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
    cdef float dr, di, sr, si, c, o, med, thr
    cdef float complex z
    for s in range(n_seg):
        for k in range(n):
            c = 0.0
            o = 0.0
            for r in range(n_rx):
                z = spec[r, s, k]
                sr = z.real
                si = z.imag
                dr = sr - prev[r, s, k].real
                di = si - prev[r, s, k].imag
                c = c + dr * dr
                c = c + di * di
                o = o + sr * sr
                o = o + si * si
            change[s, k] = c
            own[s, k] = o
    for r in range(n_rx):
        for s in range(n_seg):
            memcpy(&prev[r, s, 0], &spec[r, s, 0], n * sizeof(float complex))
    for s in range(n_seg):
        memcpy(&work[0], &change[s, 0], n * sizeof(float))
        med = _select(&work[0], n, n // 2)
        thr = med * factor
        for k in range(n):
            c = own[s, k] * rel2
            if change[s, k] > thr + c:
                for r in range(n_rx):
                    d[r, s, k] = 0
            else:
                for r in range(n_rx):
                    z = spec[r, s, k]
                    d[r, s, k] = ((z.real - background[r, s, k].real) * alpha
                                  + 1j * ((z.imag - background[r, s, k].imag) * alpha))


def apply_map(float complex[:, :, ::1] spec, float complex[:, :, ::1] background,
              const float complex[:, :, ::1] d):
    """``background += d; spec -= background`` (rx, seg, bin) complex64, in one pass."""
    cdef Py_ssize_t n0 = spec.shape[0], n1 = spec.shape[1], n2 = spec.shape[2], a, b, k
    cdef float br, bi
    for a in range(n0):
        for b in range(n1):
            for k in range(n2):
                br = background[a, b, k].real + d[a, b, k].real
                bi = background[a, b, k].imag + d[a, b, k].imag
                background[a, b, k] = br + 1j * bi
                spec[a, b, k] = (spec[a, b, k].real - br) + 1j * (spec[a, b, k].imag - bi)


def channel_power(const float complex[:, :, ::1] spec, float[:, ::1] ppad, Py_ssize_t h):
    """Non-coherent sum over the channels, ``sum_r (re^2 + im^2)`` channel by channel as numpy's ``add.reduce``,
    into ``ppad[:, h:h+n]`` with ``h`` cells of circular padding each side (seg, n + 2h) float32."""
    cdef Py_ssize_t n_rx = spec.shape[0], n_seg = spec.shape[1], n = spec.shape[2], r, s, k
    cdef float p, re, im
    for s in range(n_seg):
        for k in range(n):
            re = spec[0, s, k].real
            im = spec[0, s, k].imag
            p = re * re + im * im
            for r in range(1, n_rx):
                re = spec[r, s, k].real
                im = spec[r, s, k].imag
                p = p + (re * re + im * im)
            ppad[s, h + k] = p
        for k in range(h):
            ppad[s, k] = ppad[s, n + k]
            ppad[s, n + h + k] = ppad[s, h + k]
