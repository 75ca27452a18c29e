"""Event segmentation: when does a passage start and end (Tavanti §II, before Fig. 2).

An event starts when the echo crosses the detection threshold (the strongest cell of the filtered
range-Doppler map reaches ``th_RD``) and ends when it stays below it. Two guards from the paper:

* scintillation: a crossing that does not persist is not an event -- an event is *confirmed* only
  after ``min_event_frames`` frames at or above the threshold (consecutive or not, counted from the
  first crossing while the event is pending), otherwise the pending event is discarded when the echo
  falls quiet;
* premature stop: an event ends only after ``release_frames`` consecutive quiet frames, and a frame
  is quiet only when its level is below ``release_ratio * threshold`` (hysteresis in time and in
  level), so a target fading for a frame or two keeps its event open.

The segmenter is a small state machine fed one level per frame; it never looks ahead. The
surveillance tracker closes every open track when a confirmed event ends (a track already waiting for its
successor waits on).
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["EventConfig", "EventSegmenter", "SegmentStep"]


@dataclass(frozen=True)
class EventConfig:
    """Start/stop rules of a passage (the paper states the rules, not the numbers)."""

    min_event_frames: int = field(
        default=2,
        metadata={"unit": "frames", "doc": "frames above threshold before an event is confirmed (shorter = "
                  "scintillation)", "min": 1, "max": 1000},
    )
    release_frames: int = field(
        default=7,
        metadata={"unit": "frames", "doc": "consecutive quiet frames that end an event (N_u of Table III by "
                  "default: a track would end after as many misses)", "min": 1, "max": 10000},
    )
    release_ratio: float = field(
        default=1.0,
        metadata={"doc": "a frame is quiet when its level is below release_ratio * threshold (< 1 adds level "
                  "hysteresis)", "min": 0.01, "max": 1.0},
    )


@dataclass(frozen=True)
class SegmentStep:
    """State after one frame. ``started``/``ended`` are true on the frame the event is confirmed/ends;
    ``discarded`` on the frame a pending (unconfirmed) crossing is dropped as scintillation."""

    active: bool
    pending: bool
    started: bool = False
    ended: bool = False
    discarded: bool = False
    event_start_ns: int | None = None


class EventSegmenter:
    """``step(t_ns, level)`` once per frame against a fixed ``threshold`` (same unit as ``level``)."""

    IDLE, PENDING, ACTIVE = "idle", "pending", "active"

    def __init__(self, config: EventConfig, threshold: float) -> None:
        if not threshold > 0:
            raise ValueError(f"threshold must be positive, got {threshold!r}")
        self.config = config
        self.threshold = float(threshold)
        self.state = self.IDLE
        self._above = 0
        self._quiet = 0
        self.start_ns: int | None = None
        self.events = 0
        self.discarded = 0

    def step(self, t_ns: int, level: float) -> SegmentStep:
        cfg = self.config
        above = level >= self.threshold
        quiet = level < cfg.release_ratio * self.threshold
        if self.state == self.IDLE:
            if not above:
                return SegmentStep(False, False)
            self.state, self._above, self._quiet, self.start_ns = self.PENDING, 0, 0, t_ns
        if self.state == self.PENDING:
            self._above += int(above)
            self._quiet = self._quiet + 1 if quiet else 0
            if self._above >= cfg.min_event_frames:
                self.state, self._quiet = self.ACTIVE, 0
                self.events += 1
                return SegmentStep(True, False, started=True, event_start_ns=self.start_ns)
            if self._quiet >= cfg.release_frames:
                self.state, self.start_ns = self.IDLE, None
                self.discarded += 1
                return SegmentStep(False, False, discarded=True)
            return SegmentStep(False, True, event_start_ns=self.start_ns)
        # ACTIVE
        self._quiet = self._quiet + 1 if quiet else 0
        if self._quiet >= cfg.release_frames:
            start = self.start_ns
            self.state, self.start_ns = self.IDLE, None
            return SegmentStep(False, False, ended=True, event_start_ns=start)
        return SegmentStep(True, False, event_start_ns=self.start_ns)

    @property
    def active(self) -> bool:
        return self.state == self.ACTIVE
