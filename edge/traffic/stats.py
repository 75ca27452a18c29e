"""Per-lane interval statistics at a virtual detection line (loop-detector style).

A track *crosses* the line when its along-road distance ``s`` changes side of ``detection_line_m``
between two frames; the crossing time is interpolated linearly. Per lane and interval:

- ``volume``: crossings;
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

Intervals start at the first frame and last ``interval_s``; the frame that reaches the end closes
the interval and emits one :class:`edge.types.LaneStats` per lane with a rolling ``sequence``
(mod 65536); intervals without frames are skipped, not emitted.
"""

from __future__ import annotations

import math
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
    crossings: list[Crossing] = field(default_factory=list)
    headways_s: list[float] = field(default_factory=list)
    gaps_s: list[float] = field(default_factory=list)
    occupied_ns: int = 0
    last: Crossing | None = None  # carried over intervals

    def add(self, c: Crossing) -> None:
        if self.last is not None and c.t_ns > self.last.t_ns:
            h = (c.t_ns - self.last.t_ns) * 1e-9
            self.headways_s.append(h)
            clear = self.last.length_m / self.last.speed_mps if self.last.speed_mps > 0 else 0.0
            self.gaps_s.append(max(h - clear, 0.0))
        self.crossings.append(c)
        self.last = c

    def reset(self) -> None:
        self.crossings.clear()
        self.headways_s.clear()
        self.gaps_s.clear()
        self.occupied_ns = 0


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
        """Call once per frame before adding its data: closes the interval if ``t_ns`` reached its end."""
        if self.start_ns is None:
            self.start_ns = t_ns
            return ()
        if t_ns < self.start_ns + self.interval_ns:
            return ()
        out = tuple(self._close(k) for k in range(n_lanes))
        for acc in self.lanes.values():
            acc.reset()
        self.sequence = (self.sequence + 1) % self.SEQ_MOD
        n = (t_ns - self.start_ns) // self.interval_ns
        self.start_ns += n * self.interval_ns
        return out

    def _close(self, k: int) -> LaneStats:
        acc = self.lane(k)
        speeds = np.array([c.speed_mps for c in acc.crossings]) * 3.6
        counts = {name: 0 for name in self.class_names}
        for c in acc.crossings:
            counts[c.cls] = counts.get(c.cls, 0) + 1
        nan = float("nan")
        return LaneStats(
            lane=k,
            interval_start_ns=int(self.start_ns),
            interval_s=self.cfg.interval_s,
            sequence=self.sequence,
            volume=len(acc.crossings),
            occupancy_pct=100.0 * acc.occupied_ns / self.interval_ns,
            mean_speed_kmh=float(speeds.mean()) if speeds.size else nan,
            speed_p85_kmh=float(np.percentile(speeds, 85)) if speeds.size else nan,
            headway_s=float(np.mean(acc.headways_s)) if acc.headways_s else nan,
            gap_s=float(np.mean(acc.gaps_s)) if acc.gaps_s else nan,
            class_counts=counts,
        )
