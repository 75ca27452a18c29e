"""Stage 1, spectra (Lim §III-A): int16 I/Q -> windowed range FFT of every segment and channel -> the static-clutter
map subtracted -> power summed non-coherently over the channels (circularly padded rows for the OS-CFAR)."""

from __future__ import annotations

import numpy as np
import scipy.fft

from edge import native
from edge.dsp.range_fft import make_window
from edge.lane.clutter import ClutterMap
from edge.lane.records import Feedback, Spectra
from edge.types import FrontendInfo, RawFrame

#: scipy.fft.fft as imported (SpectraStage calls its transform directly only while it is this one)
_SCIPY_FFT = scipy.fft.fft


class SpectraStage(native.KernelUser):
    """Windowed range FFT and clutter removal; keeps the frame's scratch buffers and the :class:`ClutterMap`."""

    def __init__(self, frontend: FrontendInfo, config, clutter: ClutterMap, pad: int) -> None:
        n = frontend.waveform.n_samples
        self.n_bins = n
        self.window = make_window(config.window, n)
        self.clutter = clutter
        self.pad = pad  # the OS-CFAR's reference and guard cells per side
        self._iq = np.empty(frontend.frame_shape, dtype=np.complex64)
        # the window times the FFT's 1/n scale when n is a power of two (scaling by 2^-k before the FFT
        # is exact, the same spectrum bit for bit as scaling after it); one multiply less per frame
        self._post_scale = n & (n - 1) != 0
        self._window_scaled = self.window if self._post_scale else self.window * np.float32(1.0 / n)
        self._sq = np.empty(frontend.frame_shape + (2,), dtype=np.float32)  # |re|^2, |im|^2 scratch
        self._sq_sum = np.empty(frontend.frame_shape, dtype=np.float32)
        self.kernel = native.load("_spectra")  # compiled windowing and channel sum (edge/native); None: numpy
        #: with the kernels, scipy.fft's pocketfft transform called on :meth:`to_complex`'s buffer without
        #: scipy.fft's dispatch (the same call, the same spectrum); None: ``scipy.fft.fft`` (:func:`direct_fft`)
        self._c2c = direct_fft() if self.kernel is not None else None

    def to_complex(self, frame: RawFrame) -> np.ndarray:
        """int16 I/Q -> (rx, seg, bin) complex64, windowed on the way (a buffer the stage keeps)."""
        iq = self._iq
        k = self.kernel
        if (k is not None and frame.i.shape == iq.shape == frame.q.shape and frame.i.dtype == frame.q.dtype == np.int16
                and frame.i.flags.c_contiguous and frame.q.flags.c_contiguous):  # else numpy (and its errors)
            k.to_complex(frame.i, frame.q, self._window_scaled, iq)
            return iq
        np.multiply(frame.i, self._window_scaled, out=iq.real)
        np.multiply(frame.q, self._window_scaled, out=iq.imag)
        return iq

    def __call__(self, iq: np.ndarray, feedback: Feedback) -> Spectra:
        """Range FFT of :meth:`to_complex`'s output (overwritten), clutter map subtracted, channel power."""
        # its own buffer (complex64, C-contiguous, aligned) and scipy.fft.fft the one imported (not replaced, e.g. by
        # a test that records the spectra): what scipy.fft.fft(iq, axis=-1, overwrite_x=True, workers=1) calls
        if iq is self._iq and self._c2c is not None and scipy.fft.fft is _SCIPY_FFT:
            spec = self._c2c(iq, (-1,), True, 0, iq, 1)
        else:
            spec = scipy.fft.fft(iq, axis=-1, overwrite_x=True, workers=1)  # (rx, seg, bin) complex64
        if self._post_scale:
            spec *= np.float32(1.0 / self.n_bins)
        # non-coherent sum over the channels, written into the middle of a circularly padded row per
        # segment (the OS-CFAR windows read across the ends); ``power`` is a view of it
        h, n = self.pad, self.n_bins
        # a new array each frame: the power is published with the frame's intermediates
        ppad = np.empty((spec.shape[1], n + 2 * h), np.float32)
        if self.clutter.subtract(spec, feedback, ppad if self.kernel is not None else None, h):
            return Spectra(spec, ppad, h)  # the compiled clutter map wrote the power in the same pass
        if self.kernel is not None:
            self.kernel.channel_power(spec, ppad, h)
            return Spectra(spec, ppad, h)
        sq = np.multiply(spec.view(np.float32), spec.view(np.float32), out=self._sq.reshape(spec.shape[:-1] + (-1,)))
        sq = sq.reshape(self._sq.shape)
        np.add(sq[..., 0], sq[..., 1], out=self._sq_sum)
        power = ppad[:, h:h + n]
        np.add.reduce(self._sq_sum, axis=0, out=power)  # (seg, bin) float32 (ndarray.sum without its wrapper)
        ppad[:, :h] = ppad[:, n:n + h]
        ppad[:, n + h:] = ppad[:, h:2 * h]
        return Spectra(spec, ppad, h)


def direct_fft():
    """The transform that ``scipy.fft.fft(x, axis=-1, overwrite_x=True, workers=1)`` runs on an aligned complex64
    array, ``c2c(x, (-1,), True, 0, x, 1)`` of scipy's pocketfft module, when this scipy has it and it gives
    ``scipy.fft.fft``'s spectrum on a probe; else None."""
    try:
        from scipy.fft._pocketfft.pypocketfft import c2c
    except ImportError:
        return None
    rng = np.random.default_rng(0)
    probe = (rng.standard_normal((2, 3, 48)) + 1j * rng.standard_normal((2, 3, 48))).astype(np.complex64)
    want = scipy.fft.fft(probe, axis=-1, workers=1)
    try:
        x = probe.copy()
        got = c2c(x, (-1,), True, 0, x, 1)
    except Exception:  # another signature
        return None
    if got is not x or got.dtype != want.dtype or got.tobytes() != want.tobytes():
        return None
    return c2c
