"""FFT bound and peer for the minimal pipeline (range FFT + peak list)."""

from __future__ import annotations

import numpy as np
import scipy.fft

PEER_DESCRIPTION = "float64 numpy FFT with a Hann window and a per-spectrum peak search"


def fft_bound(frontend, config=None):
    """Only the unavoidable transform: one complex64 FFT per channel and chirp."""
    buf = np.empty(frontend.frame_shape, dtype=np.complex64)

    def run(frame):
        buf.real = frame.i
        buf.imag = frame.q
        return scipy.fft.fft(buf, axis=-1, overwrite_x=True, workers=1)

    return run


def peer(frontend, config):
    """A straightforward float64 numpy version: numpy.fft, Hann window, per-spectrum peak search."""
    n = frontend.waveform.n_samples
    win = np.hanning(n)

    def run(frame):
        x = frame.i.astype(np.float64) + 1j * frame.q.astype(np.float64)
        spec = np.fft.fft(x * win, axis=-1)
        p = np.abs(spec) ** 2
        peaks = []
        for row in p.reshape(-1, n):
            noise = np.median(row)
            idx = np.argsort(row)[::-1][:8]
            peaks.append([k for k in idx if row[k] > 31.6 * noise])
        return peaks

    return run
