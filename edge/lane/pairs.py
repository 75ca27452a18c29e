"""Stage 3, pairs (Lim §III-A): four-segment pairing of the peaks into slant range and radial speed, ghosts
of wrong pairings rejected by the slow segments (edge.dsp.pairing); then track-aided pairing: a track that got no
pairing takes the peaks nearest its predicted beats in all four segments and fits range and speed to them."""

from __future__ import annotations

import bisect
import itertools
import math

import numpy as np

from edge import native
from edge.dsp.pairing import PairingModel, Pairs, pair_beats, refine_rows
from edge.lane.records import Feedback, PairList, Peaks, Spectra
from edge.npc import count_nonzero
from edge.types import FrontendInfo

try:  # the gufunc that np.linalg.solve calls (LAPACK's dgesv per matrix), without its Python wrapper
    from numpy.linalg import _umath_linalg

    _GESV = _umath_linalg.solve
except (ImportError, AttributeError):  # pragma: no cover - another numpy layout
    _GESV = None

_SEG4 = np.arange(4)  # the four segments, as an index

#: speed difference (m/s) beyond which an accepted pair sharing peaks with others is a wrong pairing on one long
#: vehicle (pair_beats' ``ghost_speed_mps``, its default)
_GHOST_SPEED_MPS = 1.5

#: up to this many tracks the track-aided pairing predicts them in plain Python floats
_AIDED_SMALL = 10


class PairStage(native.KernelUser):
    """Pairing of the four segments' peaks, with the tracks' help (``aided_*``)."""

    def __init__(self, frontend: FrontendInfo, config, bin_hz: np.ndarray) -> None:
        cfg = self.config = config
        wf = frontend.waveform
        self.n_bins = wf.n_samples
        self.bin_hz = bin_hz  # (4,) Hz per FFT bin of each segment
        self.model = PairingModel.from_waveform(wf)
        self._model_ab = np.stack([self.model.a, self.model.b], axis=1)  # (4, 2): beat = a R + b v per segment
        self._model_ab_t = self._model_ab.T  # (2, 4): the view _aided_fit multiplies by
        self._bin_hz64 = np.ascontiguousarray(bin_hz, dtype=np.float64)  # (what f / bin_hz divides by)
        self._singular = None  # bit b: np.linalg.solve refuses the normal matrix of the found segments b (lazily)
        self.tol = (cfg.pair_tolerance_bins * bin_hz[2], cfg.pair_tolerance_bins * bin_hz[3])
        self._near_tol = (cfg.pair_near_tolerance_bins * bin_hz[2], cfg.pair_near_tolerance_bins * bin_hz[3])
        self._aided_window_hz = cfg.aided_window_bins * bin_hz  # (4,)
        self._aided = bool(cfg.aided_pairing and cfg.tracking)
        self._pad_inf, self._pad_zero = np.zeros(0), np.zeros(0, np.int64)  # padding rows of track_aided
        self._aided_empty = (np.zeros((0, 4), np.int64), np.zeros(0, np.float32), np.zeros(0, np.float32),
                             np.zeros(0, np.float32))  # no track-aided pairs (read, never written)
        self._no_bins = np.zeros((0, 4), np.int64)
        self._no_bins.flags.writeable = False
        #: the compiled pairing kernel (edge/native/_pairs.pyx), None: the numpy reference (pair_beats) runs
        self.kernel = native.load("_pairs")
        self._coef = np.array(self.model.coefficients, np.float64)
        #: the compiled track-aided predictions (edge/native/_aided.pyx), None: :meth:`reference_predictions`
        self._k_aided_pred = native.load("_aided")
        #: the static-clutter map (edge.lane.clutter.ClutterMap) for ``pair_static_residue_db``; None: not tested
        self.clutter = None
        self._static_ratio = 10.0 ** (cfg.pair_static_residue_db / 10.0) if cfg.pair_static_residue_db > 0 else 0.0

    def pair(self, freqs: tuple) -> Pairs:
        """The four-segment pairing of ``freqs`` (Hz, per segment): the compiled kernel when built, else
        :func:`edge.dsp.pairing.pair_beats` (:meth:`reference`)."""
        if self.kernel is None:
            return self.reference(freqs)
        return self._pair_kernel(freqs)[0]

    def _pair_kernel(self, freqs: tuple, bins: tuple | None = None) -> tuple[Pairs, np.ndarray | None]:
        """:meth:`pair` by the kernel, and the pairs' FFT bins (n, 4) from ``bins`` (None without them or when
        they are not int64 arrays)."""
        cfg = self.config
        near = cfg.pair_near_range_m if cfg.pair_near_range_m > 0 else 0.0
        rows, n_cand, n_ghost, fm, pk = self.kernel.pair_frame(
            tuple(freqs), self._coef, cfg.min_range_m, cfg.max_range_m, cfg.max_speed_kmh / 3.6, self.tol[0],
            self.tol[1], self._near_tol[0], self._near_tol[1], near, cfg.pair_max_shared_peaks, _GHOST_SPEED_MPS,
            None if bins is None else tuple(bins))
        # (refine_pairs with the pairs' frequencies)
        return refine_rows(rows, fm, self.model, n_cand, n_ghost, self.kernel), pk

    def reference(self, freqs: tuple) -> Pairs:
        """The numpy pairing (the kernel's reference and fallback)."""
        cfg = self.config
        return pair_beats(freqs, self.model, min_range_m=cfg.min_range_m, max_range_m=cfg.max_range_m,
                          max_speed_mps=cfg.max_speed_kmh / 3.6, tolerance_hz=self.tol,
                          max_shared=cfg.pair_max_shared_peaks, near_tolerance_hz=self._near_tol,
                          near_range_m=cfg.pair_near_range_m, ghost_speed_mps=_GHOST_SPEED_MPS)

    def __call__(self, peaks: Peaks, t_ns: int, feedback: Feedback, spectra: Spectra | None = None) -> PairList:
        """Pairings of ``peaks`` at frame time ``t_ns`` (ns), the tracks of ``feedback`` helping; with ``spectra``
        and ``pair_static_residue_db``, the residue of static echoes dropped (:meth:`drop_static`)."""
        cfg = self.config
        freqs, bins = peaks.freqs_hz, peaks.bins
        pk = None
        if self.kernel is not None:  # the pairs' bins from the kernel as well
            pairs, pk = self._pair_kernel(freqs, bins)
        else:
            pairs = self.pair(freqs)
        if pk is None:
            # (n, 4 seg) bins: the peaks of the four segments are consecutive in ``all_bins``
            all_bins = np.concatenate(bins)
            seg_start = np.array(list(itertools.accumulate((b.size for b in bins[:-1]), initial=0)))
            pk = all_bins[pairs.peak_index + seg_start] if pairs.range_m.size else self._no_bins
        elif not pairs.range_m.size:
            pk = self._no_bins
        if self._static_ratio > 0 and spectra is not None and self.clutter is not None and pk.shape[0]:
            pairs, pk = self.drop_static(pairs, pk, spectra, peaks.floor)
        p_rng, p_vel, p_res = pairs.range_m, pairs.radial_speed_mps, pairs.residual_hz
        n_aided = 0
        if self._aided and feedback.n_tracks:
            weak = (peaks.weak_freqs_hz, peaks.weak_bins) if peaks.weak_freqs_hz is not None else None
            a_bins, a_rng, a_vel, a_res = self.track_aided(freqs, bins, pairs, t_ns, feedback, weak)
            n_aided = a_rng.size
            if n_aided:
                pk = np.concatenate([pk, a_bins])
                cat = np.concatenate
                p_rng, p_vel, p_res = cat([p_rng, a_rng]), cat([p_vel, a_vel]), cat([p_res, a_res])
        return PairList(pk, p_rng, p_vel, p_res, pairs.n_candidates, pairs.n_ghosts, n_aided)

    def drop_static(self, pairs: Pairs, pk: np.ndarray, spectra: Spectra, floor: np.ndarray) -> tuple[Pairs, np.ndarray]:
        """``pairs`` and their bins ``pk`` (n, 4) without the pairings of static residue: every peak no stronger
        than ``pair_static_residue_db`` over the clutter map's echo in its bin (a vehicle shadowing guard-rail
        posts leaves their negative images, and an up-chirp image of one post pairs with the down-chirp image of
        another at a speed proportional to their spacing)."""
        static = self.clutter.static_residue(pk, spectra.power, floor, self._static_ratio)
        if self.kernel is not None:  # the kept rows copied in one call (the same arrays as below)
            out = self.kernel.drop_rows(static, (pairs.peak_index, pairs.range_m, pairs.radial_speed_mps,
                                                 pairs.residual_hz, pk))
            if out is None:
                return pairs, pk
            if out is not False:
                return Pairs(out[0], out[1], out[2], out[3], pairs.n_candidates, pairs.n_ghosts), out[4]
        if not count_nonzero(static):
            return pairs, pk
        keep = ~static
        return Pairs(pairs.peak_index[keep], pairs.range_m[keep], pairs.radial_speed_mps[keep],
                     pairs.residual_hz[keep], pairs.n_candidates, pairs.n_ghosts), pk[keep]

    def track_aided(self, freqs, bins, pairs, t_ns: int, feedback: Feedback, weak=None):
        """Pairings of confirmed tracks that the four-segment pairing missed (a near vehicle's echo is smeared
        over several bins by its body, and the peaks of the four segments no longer agree within a bin), and of
        tentative tracks that approach from at least ``aided_tentative_min_range_m`` with
        ``aided_tentative_min_hits`` hits (a far car's peaks cross the detection threshold in all four segments
        in only part of its frames, and its track must confirm before it gets to 300 m).

        Each such track without a pairing near it predicts its beat frequency in every segment (slant
        range and speed from its state at this frame's time); the nearest unused peak within
        ``aided_window_bins`` is taken in each segment, at least ``aided_min_segments`` must be found, and
        range and speed are fitted to them by least squares; the fit must lie within ``aided_gate_m`` and
        ``aided_gate_mps`` of the prediction. A segment without a peak is read at its predicted bin for
        the angle. ``weak``: per segment, the frequencies and bins of local maxima above the lower ``aided_pfa``
        threshold only (searched as well, after the detected peaks). Returns ``(bins (m, 4), range_m, v_mps,
        residual_hz)``."""
        cfg = self.config
        tr = feedback
        empty = self._aided_empty
        k_pred = self._k_aided_pred
        if k_pred is not None and self.kernel is not None:  # selection, predictions, search and fit in kernels
            if tr.t_ns is None:
                return empty
            dz = cfg.mounting_height_m - cfg.target_height_m
            pred = k_pred.select_predictions(
                tr.track_state, tr.confirmed, tr.moved, tr.hits, max((t_ns - tr.t_ns) * 1e-9, 0.0), pairs.range_m,
                pairs.radial_speed_mps, dz * dz, cfg.min_range_m, cfg.max_range_m, cfg.aided_gate_m,
                cfg.aided_gate_mps, self._coef, cfg.aided_tentative_min_range_m, cfg.aided_tentative_min_hits,
                cfg.aided_tentative_approaching)
            if pred is not None:  # (None: arrays of other types, the numpy selection below)
                r_hat, v_hat, f_hat = pred
                if not r_hat.size:
                    return empty
                found, fsel, bsel, good = self.kernel.aided_search(
                    tuple(freqs), tuple(bins), None if weak is None else tuple(weak[0]),
                    None if weak is None else tuple(weak[1]), pairs.peak_index, f_hat, self._aided_window_hz,
                    cfg.aided_min_segments)
                if not count_nonzero(good):
                    return empty
                out = self._aided_fit_kernel(found, fsel, good, r_hat, v_hat, f_hat, bsel)
                if out is None:
                    return self._aided_fit(found.view(bool), fsel, good.view(bool), r_hat, v_hat, f_hat, bsel)
                return out
        sel = self.aided_selection(tr)
        if sel.size == 0 or tr.t_ns is None:
            return empty
        dt = max((t_ns - tr.t_ns) * 1e-9, 0.0)
        pred = self.aided_predictions(tr.track_state, sel, dt, pairs)
        if pred is None:
            return empty
        r_hat, v_hat, f_hat = pred
        if self.kernel is not None:  # the nearest unused peaks in the kernel (the same picks as below)
            found, fsel, bsel, good = self.kernel.aided_search(
                tuple(freqs), tuple(bins), None if weak is None else tuple(weak[0]),
                None if weak is None else tuple(weak[1]), pairs.peak_index, f_hat, self._aided_window_hz,
                cfg.aided_min_segments)  # (the kernel takes float64 and int64 C-contiguous arrays, converting others)
            found, good = found.view(bool), good.view(bool)
            if not count_nonzero(good):
                return empty
            return self._aided_fit(found, fsel, good, r_hat, v_hat, f_hat, bsel)
        # all four segments at once: peaks in a (segment, peak) table padded with +inf, used peaks at +inf
        counts = [fk.size for fk in freqs]
        w_counts = [fk.size for fk in weak[0]] if weak is not None else [0, 0, 0, 0]
        width = max(c + w for c, w in zip(counts, w_counts))
        if width == 0:
            return empty
        # four segments; the weak peaks after the detected ones (pairs.peak_index stays valid); one concatenation
        # each (padding: views of cached +inf / 0 rows)
        if self._pad_inf.size < width:
            self._pad_inf, self._pad_zero = np.full(2 * width, np.inf), np.zeros(2 * width, np.int64)
        fp, bp = [], []
        for k in range(4):
            fp.append(freqs[k])
            bp.append(bins[k])
            if w_counts[k]:
                fp.append(weak[0][k])
                bp.append(weak[1][k])
            fp.append(self._pad_inf[:width - counts[k] - w_counts[k]])
            bp.append(self._pad_zero[:width - counts[k] - w_counts[k]])
        table = np.concatenate(fp, dtype=np.float64).reshape(4, width)
        btab = np.concatenate(bp, dtype=np.int64).reshape(4, width)
        seg = _SEG4
        if pairs.range_m.size:
            table[seg, pairs.peak_index] = np.inf
        d = np.abs(table - f_hat[:, :, None])  # (m, 4, peaks)
        j = d.argmin(axis=2)  # (m, 4): the first nearest in each segment's peak order
        found = np.minimum.reduce(d, axis=2) <= self._aided_window_hz  # the minimum is d at j
        fsel = np.where(found, table[seg, j], 0.0)
        good = np.add.reduce(found, axis=1) >= cfg.aided_min_segments
        if not count_nonzero(good):
            return empty
        return self._aided_fit(found, fsel, good, r_hat, v_hat, f_hat, np.where(found, btab[seg, j], -1))

    def aided_selection(self, tr: Feedback) -> np.ndarray:
        """Rows of ``tr``'s tracks that search for their own peaks (see :meth:`track_aided`): the confirmed ones,
        and far tentative ones that moved and have a few hits (the reference of the kernel's selection)."""
        cfg = self.config
        sel = tr.confirmed
        if cfg.aided_tentative_min_range_m > 0:  # far tentative tracks with a few hits search as well
            far = ~sel & tr.moved & (tr.hits >= cfg.aided_tentative_min_hits)  # moved: not static clutter
            if count_nonzero(far):
                x = tr.track_state
                far &= np.hypot(x[:, 0], x[:, 1]) >= cfg.aided_tentative_min_range_m
                if cfg.aided_tentative_approaching:
                    far &= x[:, 0] * x[:, 2] + x[:, 1] * x[:, 3] < 0.0
                sel = sel | far
        return sel.nonzero()[0]

    def _aided_fit(self, found, fsel, good, r_hat, v_hat, f_hat, bsel):
        """Least-squares range and speed of the tracks with enough peaks (``good``) from their found peaks
        (``found``, ``fsel`` (m, 4) Hz, ``bsel`` their bins), gated against the predictions; see track_aided."""
        cfg = self.config
        A = self._model_ab  # (4, 2)
        w = found[good].astype(np.float64)
        fs = fsel[good]
        nrm = np.einsum("mk,ki,kj->mij", w, A, A)
        rhs = np.einsum("mk,ki,mk->mi", w, A, fs)
        sol = np.linalg.solve(nrm, rhs[:, :, None])[:, :, 0]  # (g, 2): range, speed
        resid = np.sqrt((w * (fs - sol @ A.T) ** 2).sum(axis=1) / w.sum(axis=1))
        close = (np.abs(sol[:, 0] - r_hat[good]) < cfg.aided_gate_m) & (np.abs(sol[:, 1] - v_hat[good]) < cfg.aided_gate_mps)
        g = good.nonzero()[0][close]
        # a segment without a peak is read at its predicted bin (np.round's value)
        out_bins = np.where(found[g], bsel[g], np.rint(f_hat[g] / self.bin_hz).astype(np.int64) % self.n_bins)
        return (out_bins, sol[close, 0].astype(np.float32), sol[close, 1].astype(np.float32),
                resid[close].astype(np.float32))

    def _aided_fit_kernel(self, found, fsel, good, r_hat, v_hat, f_hat, bsel):
        """:meth:`_aided_fit` by the kernels (edge/native/_aided.pyx ``fit_prep``, ``fit_finish``) around the same
        LAPACK solve and BLAS product; ``found``, ``good`` bool or uint8. None when a normal matrix is one that
        np.linalg.solve refuses (the reference then raises as before)."""
        k = self._k_aided_pred
        w, fs, nrm, rhs, masks = k.fit_prep(found, fsel, good, self._model_ab)
        sing = self._singular
        if masks & (sing if sing is not None else self.singular_masks()):
            return None
        if _GESV is not None:
            sol = _GESV(nrm, rhs, signature="dd->d")[:, :, 0]
        else:  # pragma: no cover
            sol = np.linalg.solve(nrm, rhs)[:, :, 0]
        cfg = self.config
        return k.fit_finish(w, fs, sol, sol @ self._model_ab_t, good, found, bsel, r_hat, v_hat, f_hat,
                            self._bin_hz64, self.n_bins, cfg.aided_gate_m, cfg.aided_gate_mps)

    def singular_masks(self) -> int:
        """Bit ``b`` set when the normal matrix of :meth:`_aided_fit` for the found segments ``b`` (bit k: segment
        k) is one np.linalg.solve refuses as singular (it depends on the found segments only)."""
        if self._singular is None:
            bits = 0
            for b in range(16):
                w = np.array([[(b >> k) & 1 for k in range(4)]], np.float64)
                nrm = np.einsum("mk,ki,kj->mij", w, self._model_ab, self._model_ab)
                try:
                    np.linalg.solve(nrm, np.zeros((1, 2, 1)))
                except np.linalg.LinAlgError:
                    bits |= 1 << b
            self._singular = bits
        return self._singular

    def aided_predictions(self, track_state: np.ndarray, sel: np.ndarray, dt: float, pairs) -> tuple | None:
        """``(range_m (m,), v_mps (m,), beats (m, 4))`` predicted at this frame for the tracks ``sel`` (rows of
        ``track_state``, (n, 4) x, y, vx, vy) that lie inside the range limits, move (|v| >= 1 m/s) and have no
        pairing within the aided gates; None if none. The compiled kernel (edge/native/_aided.pyx) when built,
        else :meth:`reference_predictions` (the same values)."""
        k = self._k_aided_pred
        if k is None or track_state.dtype != np.float64:
            return self.reference_predictions(track_state, sel, dt, pairs)
        cfg = self.config
        dz = cfg.mounting_height_m - cfg.target_height_m
        r, v, f = k.predictions(np.ascontiguousarray(track_state), np.ascontiguousarray(sel, np.int64), dt,
                                np.ascontiguousarray(pairs.range_m, np.float32),
                                np.ascontiguousarray(pairs.radial_speed_mps, np.float32), dz * dz, cfg.min_range_m,
                                cfg.max_range_m, cfg.aided_gate_m, cfg.aided_gate_mps, self._coef)
        return (r, v, f) if r.size else None

    def reference_predictions(self, track_state: np.ndarray, sel: np.ndarray, dt: float, pairs) -> tuple | None:
        """:meth:`aided_predictions` without the kernel: a handful of tracks in plain Python floats (the float64
        operations of the array form in the same order; the pairings looked at only within twice the range gate,
        found by a binary search), more as arrays."""
        cfg = self.config
        dz = cfg.mounting_height_m - cfg.target_height_m
        r_lo, r_hi, gate_m, gate_mps = cfg.min_range_m, cfg.max_range_m, cfg.aided_gate_m, cfg.aided_gate_mps
        if sel.size > _AIDED_SMALL:
            st = track_state[sel]
            x, y = st[:, 0] + st[:, 2] * dt, st[:, 1] + st[:, 3] * dt
            r_hat = np.sqrt(x * x + y * y + dz * dz)
            v_hat = (x * st[:, 2] + y * st[:, 3]) / r_hat
            ok = (r_hat >= r_lo) & (r_hat <= r_hi) & (np.abs(v_hat) >= 1.0)
            if pairs.range_m.size:  # already paired
                near = (np.abs(pairs.range_m[None, :] - r_hat[:, None]) < gate_m) & (
                    np.abs(pairs.radial_speed_mps[None, :] - v_hat[:, None]) < gate_mps)
                ok &= ~near.any(axis=1)
            idx = ok.nonzero()[0]
            if idx.size == 0:
                return None
            r_hat, v_hat = r_hat[idx], v_hat[idx]
            return r_hat, v_hat, self.model.predict(r_hat, v_hat)
        dz2 = dz * dz
        paired = sorted(zip(pairs.range_m.tolist(), pairs.radial_speed_mps.tolist()))
        paired_r = [pr for pr, _ in paired]
        ordered = math.isfinite(sum(paired_r))  # (a NaN would leave the order undefined: then all are looked at)
        r_l, v_l = [], []
        for x0, y0, vx, vy in track_state.take(sel, axis=0)[:, :4].tolist():  # x, y, vx, vy
            x, y = x0 + vx * dt, y0 + vy * dt
            r = math.sqrt(x * x + y * y + dz2)
            v = (x * vx + y * vy) / r
            if not (r >= r_lo and r <= r_hi and abs(v) >= 1.0):
                continue
            near = paired
            if ordered:  # (rounding cannot move a pairing across a window twice the gate)
                lo = bisect.bisect_left(paired_r, r - 2.0 * gate_m)
                near = paired[lo:bisect.bisect_right(paired_r, r + 2.0 * gate_m, lo)]
            if any(abs(pr - r) < gate_m and abs(pv - v) < gate_mps for pr, pv in near):
                continue  # already paired
            r_l.append(r)
            v_l.append(v)
        if not r_l:
            return None
        a0, a1, a2, a3, b0, b1, b2, b3 = self.model.coefficients
        f_hat = np.array([(r * a0 + v * b0, r * a1 + v * b1, r * a2 + v * b2, r * a3 + v * b3)
                          for r, v in zip(r_l, v_l)])  # (m, 4): PairingModel.predict's values
        return np.array(r_l), np.array(v_l), f_hat
