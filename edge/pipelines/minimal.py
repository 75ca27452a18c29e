"""The minimal pipeline: windowed range FFT and a peak list per channel and chirp.

Runs on any board. It is what ``radar-edge run`` shows before a profile pipeline exists for the
board, and a reference for the frame loop: it reports, for every channel, the strongest range
peaks above a fixed SNR over the median noise floor of that spectrum.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from edge.dsp.range_fft import make_window, range_fft, to_complex64
from edge.pipeline import Pipeline, StageTimer
from edge.types import Detections, FrameResult, FrontendInfo, RawFrame
from hal.waveform import SPEED_OF_LIGHT_MPS


@dataclass(frozen=True)
class MinimalConfig:
    window: str = field(default="hann", metadata={"doc": "range window", "choices": ("hann", "hamming", "blackman", "kaiser", "boxcar")})
    n_peaks: int = field(default=8, metadata={"doc": "peaks kept per channel and chirp", "min": 1, "max": 64})
    snr_threshold_db: float = field(
        default=15.0, metadata={"unit": "dB", "doc": "peak must exceed the median noise floor by this", "min": 0.0, "max": 60.0}
    )
    min_range_m: float = field(
        default=2.0, metadata={"unit": "m", "doc": "ignore bins closer than this (TX->RX leakage)", "min": 0.0, "max": 50.0}
    )


class MinimalPipeline(Pipeline):
    profile = "minimal"
    stages = ("to_complex", "range_fft", "peaks")

    def __init__(self, frontend: FrontendInfo, config: MinimalConfig) -> None:
        super().__init__(frontend, config)
        wf = frontend.waveform
        n = wf.n_samples
        self.window = make_window(config.window, n)
        self._iq = np.empty(frontend.frame_shape, dtype=np.complex64)
        # beat frequency -> range per chirp row (sign of the slope decides which half holds targets)
        rows = wf.chirp_segment_index()
        self._slope = np.array([wf.segments[k].slope_hz_per_s for k in rows], dtype=np.float64)
        fs = np.array([wf.segments[k].sample_rate_hz for k in rows], dtype=np.float64)
        freqs = np.fft.fftfreq(n)[None, :] * fs[:, None]  # (n_chirps, n)
        self._range_of_bin = (freqs / self._slope[:, None] * SPEED_OF_LIGHT_MPS / 2.0).astype(np.float32)
        self._valid = self._range_of_bin >= max(config.min_range_m, 0.0)
        self._thr = np.float32(10.0 ** (config.snr_threshold_db / 10.0))

    def process(self, frame: RawFrame, timer: StageTimer) -> FrameResult:
        cfg = self.config
        with timer.stage("to_complex"):
            iq = to_complex64(frame, self._iq)
        with timer.stage("range_fft"):
            spec = range_fft(iq, self.window)
        with timer.stage("peaks"):
            p = spec.real * spec.real + spec.imag * spec.imag  # (rx, chirp, bin) float32
            noise = np.median(p, axis=-1, keepdims=True) + np.float32(1e-12)  # noise floor per spectrum
            p = np.where(self._valid[None], p, np.float32(0))
            # keep local maxima only (a target's main lobe counts once)
            left = np.roll(p, 1, axis=-1)
            right = np.roll(p, -1, axis=-1)
            p = np.where((p >= left) & (p >= right), p, np.float32(0))
            k = min(cfg.n_peaks, p.shape[-1])
            idx = np.argpartition(p, -k, axis=-1)[..., -k:]
            val = np.take_along_axis(p, idx, axis=-1)
            snr = val / noise
            keep = snr > self._thr
            rx, ch, j = np.nonzero(keep)
            bins = idx[rx, ch, j]
            rng = self._range_of_bin[ch, bins]
            snr_db = (10.0 * np.log10(snr[rx, ch, j])).astype(np.float32)
            nan = np.full(rng.shape, np.nan, dtype=np.float32)
            det = Detections.from_polar(rng, nan, nan, snr_db, extra={"rx": rx.astype(np.int16), "chirp": ch.astype(np.int16)})
        return FrameResult(profile=self.profile, seq=frame.seq, t_ns=frame.t_ns, detections=det)
