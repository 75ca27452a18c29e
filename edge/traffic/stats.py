"""Per-lane interval statistics at a virtual detection line (loop-detector style).

A track *crosses* the line when its along-road distance ``s`` changes side of ``detection_line_m``
between two frames; the crossing time is interpolated linearly. Per lane and interval:

- ``volume``: crossings, one per vehicle (:class:`edge.traffic.TrafficMonitor` decides what is counted: only
  crossings in the lane's direction of travel; a crossing within ``count_same_vehicle_s`` of a counted one in
  the lane is that vehicle's ghost track; a track first seen up to ``count_late_max_m`` past the line -- its
  vehicle crossed untracked -- is counted at the crossing time extrapolated back unless it matches a counted
  crossing, so a vehicle whose track is lost at the line and re-born after it is counted once);
- ``mean_speed_kmh`` / ``speed_p85_kmh``: arithmetic mean and 85th percentile (linear
  interpolation, ``numpy.percentile``) of the speeds at crossing (time-mean spot speed);
- ``headway_s``: mean time between the crossing of a vehicle and the crossing of the one before it
  in the same lane (the previous crossing may lie in an earlier interval);
- ``gap_s``: mean of ``headway - L_leader / v_leader`` (rear of the leader to front of the
  follower), clipped at 0, ``L`` the leader's length (or ``default_vehicle_length_m``);
- ``occupancy_pct``: share of the interval during which some vehicle overlapped the presence zone
  (``presence_zone_m`` centred on the line; a vehicle spans ``s +- L/2``), integrated frame by frame;
- ``class_counts``: crossings per class (the classifier's ``cls`` if a track has one, else the
  length class, else ``unknown``).

Intervals start at the first frame and last ``interval_s``; the first frame at or after the end
closes the interval and emits one :class:`edge.types.LaneStats` per lane with a rolling ``sequence``
(mod 65536); a crossing belongs to the interval its interpolated time falls in; intervals without
frames are skipped, not emitted. Statistics are kept per lane index: when learned lanes are
re-learned with a different count, the interval in progress mixes the two numberings.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from edge.types import LaneStats

__all__ = ["Crossing", "LaneAccumulator", "IntervalStatistics"]


@dataclass(frozen=True)
class Crossing:
    t_ns: int
    speed_mps: float
    length_m: float
    cls: str


@dataclass
class LaneAccumulator:
    """Crossings of one lane not yet reported, each with its headway and gap (NaN for the first)."""

    crossings: list[tuple[Crossing, float, float]] = field(default_factory=list)
    occupied_ns: int = 0
    last: Crossing | None = None  # carried over intervals
    #: the latest counted crossings (carried over intervals): a re-born track is matched against them
    recent: deque = field(default_factory=lambda: deque(maxlen=16))

    def add(self, c: Crossing) -> None:
        h = g = float("nan")
        if self.last is not None and c.t_ns > self.last.t_ns:
            h = (c.t_ns - self.last.t_ns) * 1e-9
            clear = self.last.length_m / self.last.speed_mps if self.last.speed_mps > 0 else 0.0
            g = max(h - clear, 0.0)
        self.crossings.append((c, h, g))
        self.recent.append(c)
        if self.last is None or c.t_ns >= self.last.t_ns:
            self.last = c

    def take(self, end_ns: int) -> list[tuple[Crossing, float, float]]:
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

    def length_class(self, length_m: float | None) -> str:
        if length_m is None or not math.isfinite(length_m):
            return "unknown"
        k = int(np.searchsorted(np.asarray(self.cfg.length_class_edges_m), length_m, side="right"))
        return self.class_names[k]

    def lane(self, k: int) -> LaneAccumulator:
        acc = self.lanes.get(k)
        if acc is None:
            acc = self.lanes[k] = LaneAccumulator()
        return acc

    def tick(self, t_ns: int, n_lanes: int) -> tuple[LaneStats, ...]:
        """Call once per frame after adding its data: closes the interval if ``t_ns`` reached its end
        (crossings interpolated before the end are reported in it, later ones in the next)."""
        if self.start_ns is None:
            self.start_ns = t_ns
            return ()
        end = self.start_ns + self.interval_ns
        if t_ns < end:
            return ()
        out = tuple(self._close(k, end) for k in range(n_lanes))
        for k, acc in self.lanes.items():
            acc.occupied_ns = 0
            if k >= n_lanes:
                acc.take(end)
        self.sequence = (self.sequence + 1) % self.SEQ_MOD
        n = (t_ns - self.start_ns) // self.interval_ns
        self.start_ns += n * self.interval_ns
        return out

    def _close(self, k: int, end_ns: int) -> LaneStats:
        acc = self.lane(k)
        done = acc.take(end_ns)
        speeds = np.array([c.speed_mps for c, _, _ in done]) * 3.6
        headways = [h for _, h, _ in done if math.isfinite(h)]
        gaps = [g for _, _, g in done if math.isfinite(g)]
        counts = {name: 0 for name in self.class_names}
        for c, _, _ in done:
            counts[c.cls] = counts.get(c.cls, 0) + 1
        nan = float("nan")
        return LaneStats(
            lane=k,
            interval_start_ns=int(self.start_ns),
            interval_s=self.cfg.interval_s,
            sequence=self.sequence,
            volume=len(done),
            occupancy_pct=min(100.0 * acc.occupied_ns / self.interval_ns, 100.0),
            mean_speed_kmh=float(speeds.mean()) if speeds.size else nan,
            speed_p85_kmh=float(np.percentile(speeds, 85)) if speeds.size else nan,
            headway_s=float(np.mean(headways)) if headways else nan,
            gap_s=float(np.mean(gaps)) if gaps else nan,
            class_counts=counts,
        )
