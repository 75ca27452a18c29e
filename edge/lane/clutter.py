"""Static-clutter map of the lane profile (Lim §III-A): an exponential average of each channel's complex range
spectrum, subtracted from the frame's spectra before detection, so guard rails, gantries, poles and the TX->RX
leakage at DC vanish while moving vehicles stay."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from edge import native
from edge.lane.records import Feedback
from edge.npc import count_nonzero

_SEG4 = np.arange(4)  # the four segments, as an index
_MEDIAN_MIN_FRAMES = 3  # frames from which their median stands for the static echo in static_residue
#: noise power at a residue's peak that static_residue allows, in segment floors (median powers): exponential noise
#: of mean floor / ln 2 exceeds it with probability 2^-4
_NOISE_FLOORS = 4.0


def _median_of_frames(frames: np.ndarray) -> np.ndarray:
    """``np.median(z.real, axis=0) + 1j * np.median(z.imag, axis=0)`` of the complex64 spectra ``z`` (frames on the
    first axis) of the first frames: np.median's value (the middle element, or the mean of the middle two: their
    float32 sum halved; NaN where a NaN is among the values) from one sort of contiguous rows, each cell's real or
    imaginary part over the frames. np.median selects along the strided frame axis instead: 9 ms of CPU time for
    16 frames of 4 x 4 x 1024 bins on the development machine, in a single frame; the transpose and sort take
    1.5 ms. (Storing each frame straight into the transposed layout would spread the transpose over the first
    frames, but its strided writes cost more than the copy.)"""
    k = frames.shape[0]
    v = frames.view(np.float32).reshape(k, -1).T.copy()  # (cells x re/im, frames)
    v.sort(axis=1)
    h = k // 2
    if k % 2:
        m = v[:, h]
    else:
        m = v[:, h - 1] + v[:, h]
        m /= 2
    last = np.isnan(v[:, -1])  # NaN sorts last
    if np.count_nonzero(last):
        m[last] = np.nan
    return np.ascontiguousarray(m).view(np.complex64).reshape(frames.shape[1:])  # (re and im alternate)


class ClutterMap(native.KernelUser):
    """The static-clutter map: (rx, seg, bin) complex64 background, subtracted in place every frame; once started,
    one chirp segment learns a frame, in turn (docs/decisions/0039).

    ``config`` is the lane profile's :class:`edge.pipelines.lane.LaneConfig` (``clutter_map_*``, mounting and
    target height); ``bins_per_m`` a static echo's FFT bins per metre of slant range in each segment (negative on
    a down-chirp). Off (``enabled`` False) when ``clutter_map_time_s`` is 0."""

    def __init__(self, config: Any, frame_shape: tuple[int, ...], frame_period_s: float,
                 bins_per_m: list[float]) -> None:
        cfg = config
        self.config = cfg
        self.n_bins = int(frame_shape[-1])
        self._bins_per_m = list(bins_per_m)
        self._alpha = np.float32(1.0 - math.exp(-frame_period_s / cfg.clutter_map_time_s)) if cfg.clutter_map_time_s > 0 else 0.0
        self._background = np.zeros(frame_shape, dtype=np.complex64)  # (rx, seg, bin) static-clutter map
        self._diff = np.empty(frame_shape, dtype=np.complex64)  # clutter-map scratch
        self._map_frames = 0
        self._prev = None  # the last frame's raw spectra (of the segment that learns next, once started)
        self._turn = 0  # the segment whose map learns next
        k_init = cfg.clutter_map_init_frames if self._alpha > 0 else 0
        self._map_init = np.zeros((k_init,) + tuple(frame_shape), np.complex64) if k_init > 1 else None
        self.kernel = native.load("_spectra")  # compiled update, static test and subtraction; None: numpy
        #: with the kernel, while the first frames are kept: each cell's real and imaginary parts so far, sorted,
        #: and their median
        self._sorted = None
        self._init_median = np.empty(frame_shape, np.complex64) if self._map_init is not None else None
        if self.kernel is not None:
            self._change = np.empty(frame_shape[1:], np.float32)  # (seg, bin) scratch of the static test
            self._own = np.empty(frame_shape[1:], np.float32)
            self._work = np.empty(frame_shape[-1], np.float32)

    @property
    def enabled(self) -> bool:
        return self._alpha > 0

    @property
    def background(self) -> np.ndarray:
        """(rx, seg, bin) complex64: the map as it stands."""
        return self._background

    def subtract(self, spec: np.ndarray, feedback: Feedback, power_out: np.ndarray | None = None, pad: int = 0) -> bool:
        """Update the map with the spectra ``spec`` (rx, seg, bin) complex64 and subtract it from them in place.
        The map learns only bins that stand still from frame to frame (``clutter_map_static_factor``) and is held
        in the range bins of stopped confirmed tracks of ``feedback`` (``clutter_map_hold_speed_mps``).
        With the compiled kernel and ``power_out`` (seg, bin + 2 ``pad``) float32, it also writes the channel power
        of the result there, circularly padded (as :class:`edge.lane.spectra.SpectraStage` does), and returns True;
        False when the caller must compute the power."""
        if not self._alpha > 0:
            return False
        cfg = self.config
        # the map starts empty and learns as a running mean over the first frames (weight
        # 1/(n + warm-up)), then with the time constant: guard-rail posts are gone within seconds
        # of a start instead of a minute (their wrong pairings made tracks hop along the rail);
        # initialising it with the first frame alone would leave that frame's vehicles' images
        alpha = np.float32(max(self._alpha, 1.0 / (self._map_frames + cfg.clutter_map_warmup_frames)))
        if self._map_init is None and self._prev is not None:
            return self._learn_in_turn(spec, feedback, power_out, pad, alpha)
        k = self.kernel
        if k is not None and cfg.clutter_map_static_factor > 0 and self._prev is not None and spec.flags.c_contiguous:
            d = self._diff  # the update and _hold_moving in one kernel (edge/native/_spectra.pyx)
            k.update_hold_moving(spec, self._background, self._prev, d, alpha,
                                 np.float32(cfg.clutter_map_static_factor), np.float32(cfg.clutter_map_static_rel ** 2),
                                 self._change, self._own, self._work)
        else:
            d = np.subtract(spec, self._background, out=self._diff)
            d *= alpha
            if cfg.clutter_map_static_factor > 0:
                self._hold_moving(spec, d)
        if cfg.clutter_map_hold_speed_mps > 0:
            self._hold_standing(d, feedback)
        if k is not None and self._map_init is None and spec.flags.c_contiguous:
            self._map_frames += 1
            if power_out is not None:  # background += d; spec -= background; channel power: one pass
                k.apply_map_power(spec, self._background, d, power_out, pad)
                return True
            k.apply_map(spec, self._background, d)  # background += d; spec -= background
            return False
        self._background += d
        if self._map_init is not None:  # the first frames are kept; then the map is their median
            self._map_init[self._map_frames] = spec
            # each cell's values sorted as they come (kernel); their median from the third frame (static_residue)
            # and at the last
            kept = self._map_frames + 1
            last = kept == self._map_init.shape[0]
            sorted_ = self._insert_sorted(self._map_frames, spec,
                                          self._init_median if kept >= _MEDIAN_MIN_FRAMES or last else None)
            if last:
                self._background[...] = self._init_median if sorted_ else _median_of_frames(self._map_init)
                self._map_init = self._sorted = self._init_median = None
        self._map_frames += 1
        spec -= self._background
        return False

    def _insert_sorted(self, i: int, spec: np.ndarray, out: np.ndarray | None) -> bool:
        """With the kernel, add this frame (the ``i``-th kept) to each cell's sorted values and write their median to
        ``out`` when given; False (and no sorted values kept from now on) without the kernel."""
        if self.kernel is None or not spec.flags.c_contiguous or (self._sorted is None and i > 0):
            self._sorted = None
            return False
        if self._sorted is None:
            self._sorted = np.empty((2 * spec.size, self._map_init.shape[0]), np.float32)
        self.kernel.median_insert(self._sorted, i, spec, out)
        return True

    def _learn_in_turn(self, spec: np.ndarray, feedback: Feedback, power_out: np.ndarray | None, pad: int,
                       alpha_frame: np.float32) -> bool:
        """:meth:`subtract` once the map has started: one segment's map learns this frame, in turn, with the weight
        of as many frames as there are segments (``alpha_frame`` each); every segment is subtracted. The static test
        compares that segment with the last frame, whose spectra of it were kept then."""
        cfg = self.config
        n_seg = spec.shape[1]
        s = self._turn
        nxt = (s + 1) % n_seg
        alpha = np.float32(min(1.0, n_seg * float(alpha_frame)))
        self._turn = nxt
        self._map_frames += 1
        k = self.kernel
        if (k is not None and power_out is not None and cfg.clutter_map_static_factor > 0 and spec.flags.c_contiguous
                and spec.shape[0] <= 16 and pad <= spec.shape[-1]):
            hold = None
            if cfg.clutter_map_hold_speed_mps > 0:
                cells = [idx for seg, idx in self._standing_cells(feedback) if seg == s]
                if cells:
                    hold = np.zeros(spec.shape[1:], np.uint8)
                    for idx in cells:
                        hold[s, idx] = 1
            k.update_apply_power(spec, self._background, self._prev, alpha,
                                 np.float32(cfg.clutter_map_static_factor), np.float32(cfg.clutter_map_static_rel ** 2),
                                 hold, power_out, pad, self._change, self._own, self._work, s, nxt)
            return True
        sp = spec[:, s]  # (rx, bin)
        d = (sp - self._background[:, s]) * alpha
        if cfg.clutter_map_static_factor > 0:
            d[:, self._moving(sp, self._prev[:, s])] = 0
        if cfg.clutter_map_hold_speed_mps > 0:
            for seg, idx in self._standing_cells(feedback):
                if seg == s:
                    d[:, idx] = 0
        self._background[:, s] += d
        self._prev[:, s] = sp
        self._prev[:, nxt] = spec[:, nxt]
        spec -= self._background
        return False

    def _hold_moving(self, spec: np.ndarray, d: np.ndarray) -> None:
        """Zero the update ``d`` (rx, seg, bin) where the spectra changed since the last frame by more than noise
        and phase noise explain (:meth:`_moving`): what moves stays out of the map. Keeps ``spec`` for the next
        frame."""
        prev = self._prev
        if prev is None:
            self._prev = spec.copy()
            return
        for s in range(spec.shape[1]):
            d[:, s, self._moving(spec[:, s], prev[:, s])] = 0
        np.copyto(prev, spec)

    def _moving(self, sp: np.ndarray, last: np.ndarray) -> np.ndarray:
        """(bin,) bool: the bins of one segment's spectra ``sp`` (rx, bin) whose change since ``last``, summed over
        the channels, exceeds ``clutter_map_static_factor`` times the segment's median change plus
        ``clutter_map_static_rel``^2 times the bin's own energy."""
        cfg = self.config
        n_rx, n = sp.shape
        dv = (sp - last).view(np.float32)
        change = (dv * dv).reshape(n_rx, n, 2).sum(axis=(0, 2))  # sum over rx of |change|^2
        med = np.partition(change, n // 2)[n // 2]
        sv = sp.view(np.float32)
        own = (sv * sv).reshape(n_rx, n, 2).sum(axis=(0, 2))
        return change > med * np.float32(cfg.clutter_map_static_factor) + own * np.float32(
            cfg.clutter_map_static_rel ** 2)

    def _hold_standing(self, d: np.ndarray, feedback: Feedback) -> None:
        """Zero the clutter-map update ``d`` (rx, seg, bin) in the range bins of stopped confirmed tracks
        (``clutter_map_hold_speed_mps``): a static echo at zero Doppler, beat a_k R in segment k."""
        for k, idx in self._standing_cells(feedback):
            d[:, k, idx] = 0

    def _standing_cells(self, feedback: Feedback) -> list[tuple[int, np.ndarray]]:
        """The (segment, bins) where :meth:`_hold_standing` holds the map: per stopped confirmed track of
        ``feedback`` and segment k, the bins of its body's range (beat a_k R) and one more each side."""
        cfg = self.config
        tr = feedback
        if not count_nonzero(tr.confirmed):
            return []
        x = tr.track_state
        stop = tr.confirmed & tr.moved & (np.hypot(x[:, 2], x[:, 3]) < cfg.clutter_map_hold_speed_mps)
        if not count_nonzero(stop):
            return []
        h = cfg.mounting_height_m - cfg.target_height_m
        n = self.n_bins
        cells = []
        for g in np.hypot(x[stop, 0], x[stop, 1]).tolist():
            r0 = math.sqrt(max(g - 3.0, 0.0) ** 2 + h * h)
            r1 = math.sqrt((g + cfg.clutter_map_hold_length_m) ** 2 + h * h)
            for k, a in enumerate(self._bins_per_m):
                lo, hi = sorted((a * r0, a * r1))
                cells.append((k, np.arange(math.floor(lo) - 1, math.ceil(hi) + 2) % n))
        return cells

    def static_residue(self, bins: np.ndarray, power: np.ndarray, floor: np.ndarray, ratio: float) -> np.ndarray:
        """(n,) bool: pairings whose peaks (``bins`` (n, 4 seg)) are, in every segment, no stronger in ``power``
        (seg, bin) than ``ratio`` times the map's echo in the same bin plus the noise (amplitudes add), where the
        map holds an echo above the segment's noise ``floor`` (seg,): what is left of static echoes, not a moving
        body. While the map still learns its first frames (``clutter_map_init_frames``) the echo is their median so
        far, from the third on (of one or two frames a median is a moving body's echo as well)."""
        ref = self._background
        if self._map_init is not None and self._map_frames >= _MEDIAN_MIN_FRAMES:  # still learning: the frames' median
            ref = self._init_median if self._sorted is not None else _median_of_frames(self._map_init[:self._map_frames])
        if self.kernel is not None and bins.dtype == np.int64:
            out = self.kernel.static_residue(ref, bins, power, floor, ratio, _NOISE_FLOORS)
            if out is not None:
                return out
        b = ref[:, _SEG4, bins]  # (rx, n, 4)
        bg = np.add.reduce(b.real * b.real + b.imag * b.imag, axis=0)
        # amplitudes: the image plus the noise at the peak, whose power exceeds NOISE_FLOORS floors 1 time in 16
        bound = np.sqrt(np.float32(ratio) * bg) + np.sqrt(np.float32(_NOISE_FLOORS) * floor)
        return ((np.sqrt(power[_SEG4, bins]) <= bound) & (bg > floor)).all(axis=1)

