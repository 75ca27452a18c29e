"""Per-lane interval statistics at a virtual detection line (loop-detector style).

A track *crosses* the line when its along-road distance ``s`` changes side of ``detection_line_m``
between two frames; the crossing time is interpolated linearly. Per lane and interval:

- ``volume``: crossings, one per vehicle (:class:`edge.traffic.TrafficMonitor` decides what is counted: only
  crossings in the lane's direction of travel, one per track; a track first seen up to ``count_late_max_m`` past
  the line -- its vehicle crossed untracked -- is counted at the crossing time extrapolated back unless it matches
  a counted crossing, so a vehicle whose track is lost at the line and re-born after it is counted once);
- ``mean_speed_kmh`` / ``speed_p85_kmh``: arithmetic mean and 85th percentile (linear
  interpolation, ``numpy.percentile``) of the speeds at crossing (time-mean spot speed);
- ``headway_s``: mean time between the crossing of a vehicle and the crossing of the one before it
  in the same lane (the previous crossing may lie in an earlier interval);
- ``gap_s``: mean of ``headway - L_leader / v_leader`` (rear of the leader to front of the
  follower), clipped at 0, ``L`` the leader's measured length; a headway whose leader's length is not
  measured gives no gap (NaN when none does);
- ``occupancy_pct``: share of the interval during which some vehicle overlapped the presence zone
  (``presence_zone_m`` centred on the line; a vehicle spans its near face ``s`` to ``s + L`` along the road,
  farther from the radar, ``L`` its measured length or ``default_vehicle_length_m`` while not measured),
  frame by frame, the lengths read when the interval closes;
- ``class_counts``: crossings per class (the classifier's ``cls`` if a track has one, else the
  length class, else ``unknown``);
- ``mean_length_m``: mean measured length of the crossings (NaN when none is measured).

Lengths (:class:`LengthMeter`): a track's length is the range extent of its body over its passage (the
``length_outliers + 1``-th largest, measured in ``length_range_m``), read when the interval closes, so a
vehicle that crossed the line before its body was resolved is still classified.

Intervals start at the first frame and last ``interval_s``; the first frame at or after the end
closes the interval and emits one :class:`edge.types.LaneStats` per lane with a rolling ``sequence``
(mod 65536); a crossing belongs to the interval its interpolated time falls in; intervals without
frames are skipped, not emitted. Statistics are kept per lane index: when learned lanes are
re-learned with a different count, the interval in progress mixes the two numberings.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from edge.types import LaneStats

__all__ = ["Crossing", "IntervalStatistics", "LaneAccumulator", "LengthMeter"]


class LengthMeter:
    """A vehicle's length from the range extent of its body (near face to the farthest detection behind it at its
    speed, :func:`edge.dsp.pairing.body_extent`) over its passage: the ``outliers + 1``-th largest extent measured,
    once ``min_frames`` were measured. Keeps only those largest values (constant memory and work per frame)."""

    __slots__ = ("frames", "top", "_keep")

    def __init__(self, outliers: int) -> None:
        self.frames = 0
        self.top: list[float] = []  # the largest extents, descending
        self._keep = outliers + 1

    def add(self, extent_m: float) -> None:
        self.frames += 1
        top = self.top
        if len(top) < self._keep:
            top.append(extent_m)
            top.sort(reverse=True)
        elif extent_m > top[-1]:
            top[-1] = extent_m
            top.sort(reverse=True)

    def estimate_m(self, min_frames: int) -> float | None:
        """The measured extent (possibly below the range resolution); None before ``min_frames`` frames."""
        if self.frames < min_frames or len(self.top) < self._keep:
            return None
        return self.top[-1]


@dataclass(frozen=True)
class Crossing:
    """A counted crossing. ``meter``: its track's length measurement, read when the interval closes (the vehicle's
    length is measured over its passage, partly after the line); without one, ``length_m`` (NaN: unknown)."""

    t_ns: int
    speed_mps: float
    length_m: float
    cls: str | None
    meter: LengthMeter | None = None


@dataclass
class LaneAccumulator:
    """Crossings of one lane not yet reported, each with its headway (NaN for the first) and the crossing before
    it (its leader, for the gap); per-frame presence samples of the vehicles near the presence zone."""

    crossings: list[tuple[Crossing, float, Crossing | None]] = field(default_factory=list)
    #: (frame time, frame duration, near-face along-road distance, meter or None) per track near the zone
    samples: list[tuple[int, int, float, LengthMeter | None]] = field(default_factory=list)
    frames: list[tuple[int, int]] = field(default_factory=list)  # (frame time, duration) of the interval's frames
    last: Crossing | None = None  # carried over intervals
    #: the latest counted crossings (carried over intervals): a re-born track is matched against them
    recent: deque = field(default_factory=lambda: deque(maxlen=16))

    def add(self, c: Crossing) -> None:
        h = float("nan")
        lead = None
        if self.last is not None and c.t_ns > self.last.t_ns:
            h = (c.t_ns - self.last.t_ns) * 1e-9
            lead = self.last
        self.crossings.append((c, h, lead))
        self.recent.append(c)
        if self.last is None or c.t_ns >= self.last.t_ns:
            self.last = c

    def take(self, end_ns: int) -> list[tuple[Crossing, float, Crossing | None]]:
        """Remove and return the crossings before ``end_ns`` (later ones belong to the next interval)."""
        done = [e for e in self.crossings if e[0].t_ns < end_ns]
        self.crossings = [e for e in self.crossings if e[0].t_ns >= end_ns]
        return done


class IntervalStatistics:
    """Accumulates crossings and occupancy per lane; closes intervals."""

    SEQ_MOD = 65536

    def __init__(self, cfg) -> None:
        self.cfg = cfg
        self.interval_ns = int(round(cfg.interval_s * 1e9))
        self.start_ns: int | None = None
        self.sequence = 0
        self.lanes: dict[int, LaneAccumulator] = {}
        self.class_names = tuple(cfg.length_class_names)
        self._edges = np.asarray(cfg.length_class_edges_m, dtype=np.float64)
        self._edge_list = self._edges.tolist()  # (bisect on Python floats: numpy's per-call cost, once per track)

    def length_class(self, length_m: float | None) -> str:
        if length_m is None or not math.isfinite(length_m):
            return "unknown"
        # np.searchsorted(self._edges, length_m, side="right") for a finite length
        return self.class_names[bisect.bisect_right(self._edge_list, float(length_m))]

    def measured(self, meter: LengthMeter | None) -> tuple[float | None, str | None]:
        """(published length or None, length class or None) of a length measurement: the length is n/a below
        ``length_min_m`` (shorter than the range resolution: the shortest class), both before it is measured."""
        if meter is None:
            return None, None
        est = meter.estimate_m(self.cfg.length_min_frames)
        if est is None:
            return None, None
        return (est if est >= self.cfg.length_min_m else None), self.length_class(est)

    def _resolve(self, c: Crossing) -> tuple[float, str]:
        """(length or NaN, class) of a crossing now."""
        if c.meter is not None:
            length, cls = self.measured(c.meter)
            length = float("nan") if length is None else length
        else:
            length = c.length_m
            cls = self.length_class(length) if length >= self.cfg.length_min_m else None
        if c.cls is not None:
            cls = c.cls
        return length, (cls if cls is not None else "unknown")

    def lane(self, k: int) -> LaneAccumulator:
        acc = self.lanes.get(k)
        if acc is None:
            acc = self.lanes[k] = LaneAccumulator()
        return acc

    def tick(self, t_ns: int, n_lanes: int) -> tuple[LaneStats, ...]:
        """Call once per frame after adding its data: closes the interval if ``t_ns`` reached its end
        (crossings interpolated before the end are reported in it, later ones in the next; the closing frame's
        presence counts in it)."""
        if self.start_ns is None:
            self.start_ns = t_ns
            return ()
        end = self.start_ns + self.interval_ns
        if t_ns < end:
            return ()
        out = tuple(self._close(k, end) for k in range(n_lanes))
        for k, acc in self.lanes.items():
            acc.samples.clear()
            acc.frames.clear()
            if k >= n_lanes:
                acc.take(end)
        self.sequence = (self.sequence + 1) % self.SEQ_MOD
        n = (t_ns - self.start_ns) // self.interval_ns
        self.start_ns += n * self.interval_ns
        return out

    def occupied_ns(self, acc: LaneAccumulator) -> int:
        """Time of the interval's frames during which some vehicle overlapped the presence zone: a vehicle spans
        its near face (``s``) to its far end (``s + L`` in along-road distance, whichever its direction), ``L`` its
        length as measured now (``default_vehicle_length_m`` while it is not)."""
        cfg = self.cfg
        lo = cfg.detection_line_m - 0.5 * cfg.presence_zone_m
        hi = cfg.detection_line_m + 0.5 * cfg.presence_zone_m
        present: set[int] = set()
        cache: dict[int, float] = {}
        for t, _, s, meter in acc.samples:
            if t in present or s > hi:
                continue
            key = id(meter)
            length = cache.get(key)
            if length is None:
                est = meter.estimate_m(cfg.length_min_frames) if meter is not None else None
                length = cache[key] = est if est is not None else cfg.default_vehicle_length_m
            if s + length >= lo:
                present.add(t)
        return sum(dt for t, dt in acc.frames if t in present)

    def _close(self, k: int, end_ns: int) -> LaneStats:
        acc = self.lane(k)
        done = acc.take(end_ns)
        speeds = np.array([c.speed_mps for c, _, _ in done]) * 3.6
        headways = [h for _, h, _ in done if math.isfinite(h)]
        gaps = []
        lengths = []
        counts = {name: 0 for name in self.class_names}
        for c, h, lead in done:
            length, cls = self._resolve(c)
            counts[cls] = counts.get(cls, 0) + 1
            if math.isfinite(length):
                lengths.append(length)
            if lead is not None and math.isfinite(h) and lead.speed_mps > 0:
                lead_length, _ = self._resolve(lead)
                if math.isfinite(lead_length):  # rear of the leader to the front of the follower
                    gaps.append(max(h - lead_length / lead.speed_mps, 0.0))
        nan = float("nan")
        return LaneStats(
            lane=k,
            interval_start_ns=int(self.start_ns),
            interval_s=self.cfg.interval_s,
            sequence=self.sequence,
            volume=len(done),
            occupancy_pct=min(100.0 * self.occupied_ns(acc) / self.interval_ns, 100.0),
            mean_speed_kmh=float(speeds.mean()) if speeds.size else nan,
            speed_p85_kmh=float(np.percentile(speeds, 85)) if speeds.size else nan,
            headway_s=float(np.mean(headways)) if headways else nan,
            gap_s=float(np.mean(gaps)) if gaps else nan,
            class_counts=counts,
            mean_length_m=float(np.mean(lengths)) if lengths else nan,
        )
