"""Range processing: windowed FFT along fast time, per chirp and channel, in single precision."""

from __future__ import annotations

import numpy as np
import scipy.fft
import scipy.signal

from edge.types import RawFrame


def make_window(name: str, n: int, kaiser_beta: float = 3.0) -> np.ndarray:
    """Window of length ``n`` as float32, normalised to unit coherent gain (sum = n)."""
    if name == "kaiser":
        w = scipy.signal.windows.kaiser(n, kaiser_beta, sym=False)
    elif name in ("hann", "hamming", "blackman", "boxcar"):
        w = scipy.signal.get_window(name, n, fftbins=True)
    else:
        raise ValueError(f"unknown window {name!r}")
    w = w * (n / w.sum())
    return w.astype(np.float32)


def to_complex64(frame: RawFrame, out: np.ndarray | None = None) -> np.ndarray:
    """int16 I and Q ``(n_rx, n_chirps, n_samples)`` -> complex64, writing into ``out`` if given."""
    if out is None:
        out = np.empty(frame.i.shape, dtype=np.complex64)
    out.real = frame.i
    out.imag = frame.q
    return out


def range_fft(iq: np.ndarray, window: np.ndarray, n_fft: int | None = None) -> np.ndarray:
    """Windowed FFT over the last axis.

    ``iq``: complex64 ``(..., n_samples)``; ``window``: float32 ``(n_samples,)``.
    Returns complex64 ``(..., n_fft)`` with bin ``k`` at beat frequency ``k * fs / n_fft`` (bins past
    ``n_fft / 2`` are negative frequencies). Scaled by ``1 / n_samples`` so a full-scale tone of
    amplitude A counts reads A at its bin.
    """
    x = iq * window
    spec = scipy.fft.fft(x, n=n_fft, axis=-1, overwrite_x=True, workers=1)
    spec *= np.float32(1.0 / iq.shape[-1])
    return spec


def power_db(spec: np.ndarray) -> np.ndarray:
    """|X|^2 in dB (float32), floored at -200 dB."""
    p = spec.real * spec.real + spec.imag * spec.imag
    return (10.0 * np.log10(np.maximum(p, np.float32(1e-20)))).astype(np.float32)
