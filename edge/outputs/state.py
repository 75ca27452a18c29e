"""What every output publishes, derived once from the loop's results and health.

:class:`OutputState` is fed by one writer (the frame loop's ``publish`` calls) and turns each
``(result | None, health)`` into an immutable :class:`Snapshot`: the current tracks and presence,
the last closed interval per lane, and the fail-safe decision. The fail-safe rule is the same for
Modbus and CAN: no frame result for ``stale_after_s`` (measured on the loop's monotonic clock), or
the loop reporting ``stalled``/``fault``/``stopped``, is a fault; then tracks are cleared, presence
goes to the configured fail-safe state and lane statistics are flagged stale.

Lane numbering: ``LaneStats.lane``, ``TrackState.lane`` and ``TrafficEvent.lane`` are lane indices
0..n_lanes-1, the same index as ``FrameResult.presence``; Modbus and CAN publish them as lane
numbers 1..N. The lanes' directions come from the traffic layer's lanes in use (a ``lanes`` callable,
read on every update: configured lanes, or learned ones once learned).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Sequence

from edge.outputs.config import FailsafeConfig

if TYPE_CHECKING:  # no numpy import in the Modbus server process
    from edge.types import FrameResult, LaneStats, LoopHealth, TrackState

MAX_LANES = 8

#: alarm codes (status register 17, CAN RadarState error bits)
ALARM_NONE = 0
ALARM_STALLED = 1  # no frames from the source
ALARM_PIPELINE = 2  # the pipeline or the source reported a fault
ALARM_STOPPED = 3  # the frame loop stopped
ALARM_NO_PUBLISH = 4  # the outputs got neither results nor heartbeats (loop hung)
ALARMS = {
    ALARM_NONE: "none",
    ALARM_STALLED: "source stalled: no frames",
    ALARM_PIPELINE: "pipeline or source fault",
    ALARM_STOPPED: "frame loop stopped",
    ALARM_NO_PUBLISH: "no results or heartbeats from the frame loop",
}
LOOP_STATES = ("starting", "running", "stalled", "fault", "stopped")


@dataclass(frozen=True)
class Snapshot:
    """The state all outputs publish for one update (immutable; safe to hand to other threads)."""

    t_ns: int  # loop monotonic time of this update
    health: LoopHealth
    frame_seq: int  # seq of the last frame result (-1 = none yet)
    frame_t_ns: int
    new_frame: bool  # this update carries a new frame result
    tracks: tuple[TrackState, ...]
    presence: tuple[bool, ...]  # n_lanes flags, fail-safe applied
    wrong_way: tuple[bool, ...]  # per lane, this frame
    lane_stats: tuple[LaneStats | None, ...]  # last closed interval per lane (index = lane)
    new_interval: bool  # this update closed an interval
    interval_seq: int  # 0..255, last closed interval (NTCIP volumeOccupancySequence)
    interval_end_ns: int  # loop time the last interval closed (0 = none yet)
    stats_stale: tuple[bool, ...]
    cumulative_volume: tuple[int, ...]
    wrong_way_count: tuple[int, ...]
    fault: bool
    alarm: int
    frame_rate_hz: float
    profile: str
    n_lanes: int
    failsafe_presence: bool = False
    #: per lane: +1 away from the radar (receding), -1 toward it (approaching), 0 both, None unknown
    lane_directions: tuple[int | None, ...] = ()


class OutputState:
    """Single-writer state machine: ``update(result, health) -> Snapshot`` and ``check(now_ns)``."""

    def __init__(self, n_lanes: int, failsafe: FailsafeConfig | None = None,
                 lanes: Callable[[], Sequence[Any]] | None = None) -> None:
        if not 0 <= n_lanes <= MAX_LANES:
            raise ValueError(f"n_lanes must be 0..{MAX_LANES}, got {n_lanes}")
        self.n_lanes = n_lanes
        self.cfg = failsafe or FailsafeConfig()
        self._stale_ns = int(self.cfg.stale_after_s * 1e9)
        self._last: Snapshot | None = None
        self._last_frame_seq = -1
        self._last_frame_t = 0
        self._last_result_ns: int | None = None
        self._tracks: tuple[TrackState, ...] = ()
        self._presence: tuple[bool, ...] = (False,) * n_lanes
        self._lane_stats: list[LaneStats | None] = [None] * n_lanes
        self._lane_closed_ns = [0] * n_lanes
        self._interval_seq = 0
        self._interval_end_ns = 0
        self._cum = [0] * n_lanes
        self._ww = [0] * n_lanes
        self._rate_hz = 0.0
        self._profile = ""
        self._started_ns: int | None = None
        self._lanes = lanes
        self._dirs: tuple[Any, tuple[int | None, ...]] = (None, (None,) * n_lanes)

    @property
    def last(self) -> Snapshot | None:
        return self._last

    def update(self, result: FrameResult | None, health: LoopHealth) -> Snapshot:
        now = health.t_ns
        if self._started_ns is None:
            self._started_ns = now
        new_interval = False
        wrong = [False] * self.n_lanes
        if result is not None:
            if self._last_result_ns is not None and result.t_ns > self._last_frame_t > 0:
                dt = (result.t_ns - self._last_frame_t) / 1e9
                inst = 1.0 / dt if dt > 0 else 0.0
                self._rate_hz = inst if self._rate_hz == 0 else 0.9 * self._rate_hz + 0.1 * inst
            self._last_result_ns = now
            self._last_frame_seq = result.seq
            self._last_frame_t = result.t_ns
            self._profile = result.profile
            self._tracks = tuple(result.tracks)
            pres = tuple(bool(p) for p in result.presence[: self.n_lanes])
            self._presence = pres + (False,) * (self.n_lanes - len(pres))
            for ls in result.lane_stats:
                if 0 <= ls.lane < self.n_lanes:
                    self._lane_stats[ls.lane] = ls
                    self._lane_closed_ns[ls.lane] = now
                    self._cum[ls.lane] += max(0, int(ls.volume))
                    self._interval_seq = int(ls.sequence) & 0xFF
                    self._interval_end_ns = now
                    new_interval = True
            for ev in result.events:
                if ev.kind == "wrong_way" and ev.lane is not None and 0 <= ev.lane < self.n_lanes:
                    wrong[ev.lane] = True
                    self._ww[ev.lane] += 1
        alarm = self._alarm(health, now)
        return self._snapshot(now, health, result is not None, new_interval, tuple(wrong), alarm)

    def check(self, now_ns: int) -> Snapshot | None:
        """Watchdog for an output's own thread: a fault snapshot when the loop went silent, else None.

        Pure (does not change the state), so the frame loop stays the single writer.
        """
        last = self._last
        if last is None or now_ns - last.t_ns <= self._stale_ns:
            return None
        return self._snapshot(now_ns, last.health, False, False, (False,) * self.n_lanes, ALARM_NO_PUBLISH,
                              store=False)

    def _directions(self) -> tuple[int | None, ...]:
        """Direction per lane of the lanes in use (cached while the provider returns the same object)."""
        if self._lanes is None:
            return self._dirs[1]
        lanes = self._lanes()
        if lanes is not self._dirs[0]:
            known = [_direction(ln) for ln in list(lanes)[: self.n_lanes]]
            self._dirs = (lanes, tuple(known) + (None,) * (self.n_lanes - len(known)))
        return self._dirs[1]

    def _alarm(self, health: LoopHealth, now: int) -> int:
        if health.state == "stopped":
            return ALARM_STOPPED
        if health.state == "fault":
            return ALARM_PIPELINE
        if health.state == "stalled":
            return ALARM_STALLED
        ref = self._last_result_ns if self._last_result_ns is not None else self._started_ns
        if now - ref > self._stale_ns:
            return ALARM_STALLED
        return ALARM_NONE

    def _snapshot(self, now, health, new_frame, new_interval, wrong, alarm, store=True) -> Snapshot:
        fault = alarm != ALARM_NONE
        if fault:
            mode = self.cfg.presence
            presence = (True,) * self.n_lanes if mode == "on" else (False,) * self.n_lanes if mode == "off" else self._presence
            tracks: tuple[TrackState, ...] = ()
        else:
            presence, tracks = self._presence, self._tracks
        stale = []
        for k in range(self.n_lanes):
            ls = self._lane_stats[k]
            if ls is None:
                stale.append(True)
            else:
                limit = self.cfg.stats_stale_intervals * max(float(ls.interval_s), 1e-3) * 1e9
                stale.append(fault or (now - self._lane_closed_ns[k]) > limit)
        snap = Snapshot(
            t_ns=now, health=health, frame_seq=self._last_frame_seq, frame_t_ns=self._last_frame_t,
            new_frame=new_frame, tracks=tracks, presence=presence, wrong_way=wrong,
            lane_stats=tuple(self._lane_stats), new_interval=new_interval, interval_seq=self._interval_seq,
            interval_end_ns=self._interval_end_ns, stats_stale=tuple(stale), cumulative_volume=tuple(self._cum),
            wrong_way_count=tuple(self._ww), fault=fault, alarm=alarm,
            frame_rate_hz=0.0 if fault else self._rate_hz, profile=self._profile, n_lanes=self.n_lanes,
            failsafe_presence=fault and self.cfg.presence != "hold", lane_directions=self._directions(),
        )
        if store:
            self._last = snap
        return snap


def _direction(lane: Any) -> int:
    d = int(lane.direction)
    return 1 if d > 0 else -1 if d < 0 else 0


def finite(x: float | None) -> float | None:
    """``None`` for None/NaN/inf (published as "not available")."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None
