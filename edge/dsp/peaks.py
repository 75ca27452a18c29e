"""Peak picking and sub-bin interpolation on power spectra."""

from __future__ import annotations

import numpy as np


def local_maxima(power: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Cells of ``mask`` that are circular local maxima of ``power`` along the last axis.

    ``power``: float32 ``(..., n_bins)``; ``mask``: bool, same shape. Returns a bool array.
    """
    left = np.roll(power, 1, axis=-1)
    right = np.roll(power, -1, axis=-1)
    return mask & (power > left) & (power >= right)


def interpolate_peak(power: np.ndarray, bins: np.ndarray) -> np.ndarray:
    """Sub-bin offsets ``(n,)`` float32 in (-0.5, 0.5) by a parabola through the log-power of the peak
    bin and its two neighbours (Gaussian interpolation; its bias for a Hann window is below 0.02 bin).

    ``power``: ``(n_bins,)`` float32; ``bins``: int ``(n,)`` peak indices (circular neighbours).
    """
    n = power.shape[-1]
    tiny = np.float32(1e-30)
    lm = np.log(np.maximum(power[(bins - 1) % n], tiny))
    l0 = np.log(np.maximum(power[bins], tiny))
    lp = np.log(np.maximum(power[(bins + 1) % n], tiny))
    den = lm - 2.0 * l0 + lp
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(den < 0, 0.5 * (lm - lp) / den, 0.0)
    return np.clip(d, -0.5, 0.5).astype(np.float32)
