"""Stage 2, peaks (Lim §III-A): OS-CFAR per segment (Rohling), evaluated at the local maxima only; sub-bin
interpolation by a parabola through the log-power; signed beat frequencies. Local maxima above a lower threshold
(``aided_pfa``) are kept apart for the track-aided pairing."""

from __future__ import annotations

import numpy as np

from edge.dsp.cfar import os_cfar, os_cfar_at_padded, os_cfar_scale, reference_index
from edge.dsp.peaks import interpolate_peak, local_maxima
from edge.lane.records import Peaks, Spectra
from edge import native
from edge.types import FrontendInfo
from hal.waveform import SPEED_OF_LIGHT_MPS


class PeakStage(native.KernelUser):
    """OS-CFAR detection and peak interpolation of the four segments' power rows."""

    def __init__(self, frontend: FrontendInfo, config) -> None:
        cfg = self.config = config
        wf = frontend.waveform
        n = self.n_bins = wf.n_samples
        n_seg = len(wf.segments)
        fs = np.array([s.sample_rate_hz for s in wf.segments])
        self.bin_hz = fs / n  # (4,)
        self.freq = (np.fft.fftfreq(n)[None, :] * fs[:, None])  # (4, n) float64 signed Hz per bin
        self._freq_flat = self.freq.ravel()
        # search region per segment: beats of targets in [min_range, max_range] at any allowed speed
        slope = np.array([s.slope_hz_per_s for s in wf.segments])
        c = SPEED_OF_LIGHT_MPS
        fd = 2.0 * (cfg.max_speed_kmh / 3.6) / wf.wavelength_m
        lo = np.minimum(slope * 2 * cfg.min_range_m / c, slope * 2 * cfg.max_range_m / c) - fd
        hi = np.maximum(slope * 2 * cfg.min_range_m / c, slope * 2 * cfg.max_range_m / c) + fd
        self.valid = (self.freq >= lo[:, None]) & (self.freq <= hi[:, None])  # (4, n) bool
        self._n_ref = 2 * cfg.cfar_train_cells
        self._rank = max(1, min(self._n_ref, int(round(cfg.cfar_rank_fraction * self._n_ref))))
        self.cfar_scale = os_cfar_scale(cfg.cfar_pfa, self._n_ref, self._rank, n_looks=frontend.n_rx)
        self.scale32 = np.float32(self.cfar_scale)
        #: the lower threshold of track-aided pairing (weak peaks); None when there is none
        self.aided_scale32 = None
        if cfg.aided_pairing and 0 < cfg.aided_pfa and cfg.tracking:
            self.aided_scale32 = np.float32(min(os_cfar_scale(cfg.aided_pfa, self._n_ref, self._rank,
                                                              n_looks=frontend.n_rx), self.cfar_scale))
        self._ref_index = reference_index(n, cfg.cfar_train_cells, cfg.cfar_guard_cells)
        self.pad = cfg.cfar_train_cells + cfg.cfar_guard_cells  # circular padding of the power rows
        self._bin_shift = n.bit_length() - 1 if n & (n - 1) == 0 else None
        self._nan_rows = np.full((n_seg, n), np.nan, np.float32)
        self._is_max, self._ge = np.empty((n_seg, n), bool), np.empty((n_seg, n), bool)  # local-maximum scratch
        self._tiny = np.float32(1e-30)
        self._seg_ends = np.arange(1, n_seg + 1)
        #: the compiled kernel (edge/native/_peaks.pyx), None: the numpy reference runs
        self.kernel = native.load("_peaks")
        if self.kernel is not None:
            m = n_seg * (n // 2 + 1)  # at most this many local maxima (strict on the left)
            self._valid_u8 = np.ascontiguousarray(self.valid, dtype=np.uint8)
            self._k_rows, self._k_cols = np.empty(m, np.int64), np.empty(m, np.int64)
            self._k_cells = np.empty((m, 3), np.float32)
            self._k_scratch = np.empty(m, np.float32)
            self._k_counts = np.zeros(2 * n_seg, np.int64)  # detected, then weak peaks per segment
            self._k_comp, self._k_npad = self.kernel.rank_network(self._n_ref, self._rank)
            self._k_bin_hz = np.ascontiguousarray(self.bin_hz, dtype=np.float64)
            self._k_aided = np.float32(0.0 if self.aided_scale32 is None else self.aided_scale32)

    def __call__(self, spectra: Spectra, want_weak: bool) -> Peaks:
        """Peaks of ``spectra``; ``want_weak``: also the local maxima between the aided and the detection
        threshold (only when a confirmed track may use them). The compiled kernel when built, else (and for the
        full threshold curve) :meth:`reference`; the two give the same peaks bit for bit."""
        if self.kernel is None or self.config.cfar_full_threshold:
            return self.reference(spectra, want_weak)
        return self._compiled(spectra, want_weak)

    def _compiled(self, spectra: Spectra, want_weak: bool) -> Peaks:
        """:meth:`reference` by the kernel: selection, OS-CFAR, threshold and the split into detected and weak peaks
        in one pass over the cells, then numpy's float32 log and the interpolation per segment."""
        cfg, n, k = self.config, self.n_bins, self.kernel
        power = spectra.power
        floor = np.partition(power.view(np.int32), n // 2, axis=-1)[:, n // 2].view(np.float32)
        ppad = spectra.power_padded
        if ppad.dtype != np.float32 or not ppad.flags.c_contiguous:
            ppad = np.ascontiguousarray(ppad, dtype=np.float32)
        want_weak = bool(want_weak and self.aided_scale32 is not None)
        noise, thr = np.empty(power.shape, np.float32), np.empty(power.shape, np.float32)
        m_hit, m = k.select_frame(ppad, self._valid_u8, cfg.cfar_train_cells, cfg.cfar_guard_cells, self._rank,
                                  self._k_comp, self._k_npad, self.scale32, self._k_aided, want_weak,
                                  noise, thr, self._k_rows, self._k_cols, self._k_cells, self._k_counts,
                                  self._k_scratch)
        lg = np.log(self._k_cells[:m])  # numpy's float32 log, as the reference's (the cells are floored at 1e-30)
        freqs, bins, weak_f, weak_b = k.frame_peaks(lg, self._k_rows, self._k_cols, self._freq_flat, self._k_bin_hz,
                                                    n, self._k_counts, m_hit, m, want_weak, cfg.max_peaks_per_segment)
        if freqs is None:  # a segment with more than max_peaks_per_segment (rare)
            freqs, bins = self._strongest_peaks(power, self._k_rows[:m_hit].copy(), self._k_cols[:m_hit].copy())
            freqs, bins = tuple(freqs), tuple(bins)
        return Peaks(freqs, bins, noise, thr, floor, weak_f, weak_b)

    def reference(self, spectra: Spectra, want_weak: bool) -> Peaks:
        """The numpy implementation of :meth:`__call__` (the kernel's reference and fallback)."""
        cfg = self.config
        ppad, power, h, n = spectra.power_padded, spectra.power, self.pad, self.n_bins
        weak = None
        # median per segment; the power is non-negative, so its float32 bit patterns as int32 sort like the
        # values and numpy selects int32 faster (the same element)
        floor = np.partition(power.view(np.int32), n // 2, axis=-1)[:, n // 2].view(np.float32)
        if cfg.cfar_full_threshold:  # the whole threshold curve, for plots
            _, _, noise = os_cfar(power, self._ref_index, self._rank, self.cfar_scale)
            thr = noise * self.scale32
            rows, cols = np.nonzero(local_maxima(power, (power > thr) & self.valid))
            cells = np.stack([ppad[rows, cols + h + o] for o in (-1, 0, 1)], axis=1)
            if want_weak:
                wr, wc = np.nonzero(local_maxima(power, (power > noise * self.aided_scale32) & (power <= thr)
                                                 & self.valid))
                weak = (wr, wc, np.stack([ppad[wr, wc + h + o] for o in (-1, 0, 1)], axis=1))
        else:  # only local maxima can be reported: evaluate the ordered statistic there
            is_max = np.greater(power, ppad[:, h - 1:h - 1 + n], out=self._is_max)
            is_max &= np.greater_equal(power, ppad[:, h + 1:h + 1 + n], out=self._ge)
            is_max &= self.valid
            flat = is_max.reshape(-1).nonzero()[0]
            if self._bin_shift is not None:  # a power of two: np.divmod's values by a shift and a mask
                rows, cols = flat >> self._bin_shift, flat & (n - 1)
            else:
                rows, cols = np.divmod(flat, n)
            nz, cells = os_cfar_at_padded(ppad, rows, cols, cfg.cfar_train_cells, cfg.cfar_guard_cells, self._rank)
            hit = cells[:, 1] > nz * self.scale32
            noise = self._nan_rows.copy()  # (np.full's value; NaN away from local maxima; published)
            noise.reshape(-1)[flat] = nz
            thr = noise * self.scale32
            if want_weak:
                wk = ~hit & (cells[:, 1] > nz * self.aided_scale32)
                weak = (rows[wk], cols[wk], cells[wk])
            rows, cols, cells = rows[hit], cols[hit], cells[hit]
        # peaks in (segment, bin) order; sub-bin offsets by a parabola through the log-power
        # (edge.dsp.peaks.interpolate_peak, all segments at once)
        bounds = self._segment_bounds(rows)
        wf = None
        if max(e - b for b, e in bounds) > cfg.max_peaks_per_segment:
            freqs, bins = self._strongest_peaks(power, rows, cols)
        else:
            if weak is None:
                f = self._peak_freqs(rows, cols, cells)
            else:  # the detected and the weak peaks in one interpolation (elementwise; the cost is per call)
                f = self._peak_freqs(*(np.concatenate([a, b]) for a, b in zip((rows, cols, cells), weak)))
                f, wf = f[:rows.size], f[rows.size:]
            freqs, bins = [f[b:e] for b, e in bounds], [cols[b:e] for b, e in bounds]
        weak_f = weak_b = None
        if weak is not None:  # the same interpolation, grouped by segment
            wr, wc, wcells = weak
            wf = self._peak_freqs(wr, wc, wcells) if wf is None else wf
            bounds = self._segment_bounds(wr)
            weak_f, weak_b = tuple(wf[b:e] for b, e in bounds), tuple(wc[b:e] for b, e in bounds)
        return Peaks(tuple(freqs), tuple(bins), noise, thr, floor, weak_f, weak_b)

    def _segment_bounds(self, rows: np.ndarray) -> list[tuple[int, int]]:
        """``(start, end)`` of each segment's run in ``rows`` (sorted segment numbers of peaks)."""
        ends = np.searchsorted(rows, self._seg_ends).tolist()
        return list(zip([0] + ends[:-1], ends))

    def _peak_freqs(self, rows: np.ndarray, cols: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """Signed beat frequencies (Hz) of peaks ``(segment rows, bin cols)`` with their power and its two
        neighbours ``cells (n, 3)``: a parabola through the log-power (edge.dsp.peaks.interpolate_peak)."""
        lg = np.log(np.maximum(cells, self._tiny))
        lm, l0, lp = lg[:, 0], lg[:, 1], lg[:, 2]
        den = lm - 2.0 * l0 + lp
        d = np.zeros(den.shape, np.float32)
        np.divide(0.5 * (lm - lp), den, out=d, where=den < 0)
        np.minimum(np.maximum(d, np.float32(-0.5), out=d), np.float32(0.5), out=d)  # np.clip
        return self._freq_flat[rows * self.n_bins + cols] + d * self.bin_hz[rows]

    def _strongest_peaks(self, power: np.ndarray, rows: np.ndarray, cols: np.ndarray):
        """Per segment the ``max_peaks_per_segment`` strongest peaks (a segment with more): their
        frequencies and bins, ordered by power (rare)."""
        cfg = self.config
        freqs, bins = [], []
        for k in range(power.shape[0]):
            b = cols[rows == k]
            if b.size > cfg.max_peaks_per_segment:
                b = b[np.argsort(power[k, b])[-cfg.max_peaks_per_segment:]]
            d = interpolate_peak(np.ascontiguousarray(power[k]), b)
            freqs.append(self.freq[k, b] + d * self.bin_hz[k])
            bins.append(b)
        return freqs, bins
