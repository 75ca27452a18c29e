"""Ordered-statistic CFAR (Rohling 1983; Lim et al. §III-A uses it on the beat spectra).

For every cell under test the noise estimate is the ``rank``-th smallest of ``2 * n_train`` reference
cells (``n_train`` on each side, ``n_guard`` guard cells between them and the cell under test); a
cell is a detection when its power exceeds ``scale * estimate``. The spectrum is treated as
circular (the complex FFT wraps from +fs/2 to -fs/2).

``scale`` follows from the design false-alarm probability. With power that is the non-coherent sum
of ``n_looks`` complex Gaussian noise samples (Gamma(n_looks) distributed; 4 receive channels -> 4),
the false-alarm probability of OS-CFAR is

    Pfa(a) = E[ P(X > a Y_(k)) ],   X ~ Gamma(L),  Y_(k) = k-th order statistic of N Gamma(L) cells

which :func:`os_cfar_pfa` integrates numerically; for ``L = 1`` it equals Rohling's closed form
``prod_{i=0}^{k-1} (N - i) / (N - i + a)`` (tested). :func:`os_cfar_scale` inverts it.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import scipy.special


def os_cfar_pfa(scale: float, n_ref: int, rank: int, n_looks: int = 1) -> float:
    """False-alarm probability of OS-CFAR for threshold factor ``scale`` (see module docstring)."""
    if not 1 <= rank <= n_ref:
        raise ValueError(f"rank must be in 1..{n_ref}, got {rank}")
    # Gamma(n_looks) quantile and survival function as regularised incomplete gamma functions (what
    # scipy.stats.gamma evaluates; scipy.stats is not imported for it: slow to import)
    # integrate over the order statistic's distribution on a fine grid of its CDF value u = F(y)
    u = np.linspace(0.0, 1.0, 20001)[1:-1]
    y = scipy.special.gammaincinv(n_looks, u)
    log_beta = (
        math.lgamma(n_ref + 1) - math.lgamma(rank) - math.lgamma(n_ref - rank + 1)
        + (rank - 1) * np.log(u) + (n_ref - rank) * np.log1p(-u)
    )
    dens_u = np.exp(log_beta)  # density of U = F(Y_(k)) (a Beta(k, N-k+1))
    surv = scipy.special.gammaincc(n_looks, scale * y)
    return float(np.trapezoid(dens_u * surv, u))


def os_cfar_scale(pfa: float, n_ref: int, rank: int, n_looks: int = 1) -> float:
    """Threshold factor ``a`` with :func:`os_cfar_pfa` ``(a) = pfa``."""
    if not 0.0 < pfa < 1.0:
        raise ValueError(f"pfa must be in (0, 1), got {pfa}")
    if n_looks == 1:
        f = lambda a: sum(math.log((n_ref - i) / (n_ref - i + a)) for i in range(rank)) - math.log(pfa)  # noqa: E731
    else:
        f = lambda a: math.log(max(os_cfar_pfa(a, n_ref, rank, n_looks), 1e-300)) - math.log(pfa)  # noqa: E731
    hi = 1.0
    while f(hi) > 0:
        hi *= 2.0
        if hi > 1e9:
            raise ValueError("cannot reach the requested pfa with this window")
    from scipy.optimize import brentq  # here, not at import: scipy.optimize costs start-up time

    return float(brentq(f, 1e-9, hi, xtol=1e-6, rtol=1e-9))


def reference_offsets(n_train: int, n_guard: int) -> np.ndarray:
    """Offsets (int, ``(2 n_train,)``) of the reference cells around the cell under test."""
    right = np.arange(n_guard + 1, n_guard + 1 + n_train)
    return np.concatenate([-right[::-1], right])


def reference_index(n_bins: int, n_train: int, n_guard: int) -> np.ndarray:
    """Circular reference-cell indices ``(n_bins, 2 n_train)`` (int32); compute once per waveform."""
    off = reference_offsets(n_train, n_guard)
    return ((np.arange(n_bins)[:, None] + off[None, :]) % n_bins).astype(np.int32)


def os_cfar(power: np.ndarray, ref_index: np.ndarray, rank: int, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OS-CFAR along the last axis (circular).

    ``power``: float32 ``(..., n_bins)``; ``ref_index``: from :func:`reference_index`; ``rank``: 1-based.
    Returns ``(mask, threshold, noise)``, all ``(..., n_bins)``: ``mask`` bool detections,
    ``threshold = scale * noise`` and ``noise`` the ordered statistic (float32).
    """
    ref = power[..., ref_index]  # (..., n_bins, n_ref)
    noise = np.partition(ref, rank - 1, axis=-1)[..., rank - 1]
    thr = noise * np.float32(scale)
    return power > thr, thr, noise


def os_cfar_at(power: np.ndarray, rows: np.ndarray, cols: np.ndarray, ref_index: np.ndarray, rank: int) -> np.ndarray:
    """The OS-CFAR noise estimate of :func:`os_cfar` at selected cells only (float32 ``(n,)``).

    ``power``: ``(n_rows, n_bins)``; ``rows``, ``cols``: int ``(n,)`` cells (e.g. the local maxima, the
    only cells a peak detector can report). Identical to ``os_cfar(...)[2][rows, cols]`` at a fraction
    of the cost.
    """
    if rows.size == 0:
        return np.zeros(0, np.float32)
    ref = power[rows[:, None], ref_index[cols]]  # (n, n_ref)
    return np.partition(ref, rank - 1, axis=-1)[:, rank - 1]


def circular_pad(power: np.ndarray, half: int) -> np.ndarray:
    """``(rows, n_bins + 2 half)`` copy of ``power`` ``(rows, n_bins)`` with ``half`` bins of circular
    wrap-around on each side (the layout :func:`os_cfar_at_padded` reads)."""
    n = power.shape[-1]
    out = np.empty(power.shape[:-1] + (n + 2 * half,), dtype=power.dtype)
    out[..., half:half + n] = power
    out[..., :half] = power[..., n - half:]
    out[..., half + n:] = power[..., :half]
    return out


def os_cfar_at_padded(padded: np.ndarray, rows: np.ndarray, cols: np.ndarray, n_train: int, n_guard: int,
                      rank: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`os_cfar_at` on a circularly padded power array (:func:`circular_pad` with
    ``half = n_train + n_guard``), plus each cell's power and its two neighbours.

    ``padded``: float32 ``(n_rows, n_bins + 2 half)``, non-negative (a power); ``rows``, ``cols``: int
    ``(n,)`` cells in unpadded bin numbers. Returns ``(noise (n,) float32, cells (n, 3) float32)`` with
    ``cells[:, 1]`` the power of the cell under test and ``cells[:, 0]``, ``cells[:, 2]`` its circular
    neighbours. ``noise`` equals :func:`os_cfar_at`'s exactly: one gather of every cell's whole window
    (reference, guard and cell under test), its reference cells taken out and sorted in place as rows;
    for non-negative float32 the order of the bit patterns as int32 is the order of the values, and numpy
    sorts int32 rows fastest.
    """
    half = n_train + n_guard
    if rows.size == 0:
        return np.zeros(0, np.float32), np.zeros((0, 3), np.float32)
    if padded.dtype != np.float32 or not padded.flags.c_contiguous:
        padded = np.ascontiguousarray(padded, dtype=np.float32)
    width = 2 * half + 1
    r, c = padded.shape
    s0, s1 = padded.strides
    # every cell's window as a strided view (np.ndarray directly: as_strided's wrapper costs more than the gather)
    windows = np.ndarray((r, c - width + 1, width), np.float32, padded, 0, (s0, s1, s1))
    win = windows[rows, cols]  # (n, width) copy; column half is the cell under test
    cells = win[:, half - 1:half + 2].copy()
    # the reference cells alone (guard cells and the cell under test left out): rows of 2 n_train values sort
    # much faster than rows of 2 half + 1 when that is a power of two (numpy's SIMD sorting networks: 32
    # values 37 us, 37 values 54 us for 630 rows on the development machine)
    ref = win.view(np.int32).take(_reference_columns(n_train, n_guard), axis=1)
    ref.sort(axis=1)
    return ref[:, rank - 1].view(np.float32), cells


@functools.lru_cache(maxsize=8)
def _reference_columns(n_train: int, n_guard: int) -> np.ndarray:
    """Columns of the reference cells in a window of ``2 (n_train + n_guard) + 1`` cells."""
    return np.r_[0:n_train, n_train + 2 * n_guard + 1:2 * (n_train + n_guard) + 1]
