"""Data types every layer of the firmware shares (Stone Soup ``types``: data apart from algorithms).

Units are in the field names. Radial speed is positive when the target recedes; ``x`` is lateral
(right +) and ``y`` along boresight, in the radar's ground-projected frame unless a name says
otherwise. A missed detection is an empty :class:`Detections`, never ``None``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edge.fastinit import one_dict_init
from hal.frame import RawFrame
from hal.waveform import ChirpSegment, FrontendInfo, Waveform

__all__ = [
    "ChirpSegment",
    "ClassifiedEvent",
    "Detections",
    "FrameResult",
    "FrontendInfo",
    "LaneStats",
    "LoopHealth",
    "RawFrame",
    "TrackState",
    "TrafficEvent",
    "Waveform",
]

_F32 = np.float32


@one_dict_init
@dataclass(frozen=True, eq=False)
class Detections:
    """Detections of one frame, columnar (one row each); NaN where a quantity is not measured."""

    range_m: np.ndarray
    radial_speed_mps: np.ndarray
    az_rad: np.ndarray
    snr_db: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def empty(cls) -> "Detections":
        z = np.zeros(0, dtype=_F32)
        return cls(z, z, z, z, z, z)

    @classmethod
    def from_polar(
        cls, range_m, radial_speed_mps, az_rad, snr_db, extra: dict[str, np.ndarray] | None = None
    ) -> "Detections":
        r = np.asarray(range_m, dtype=_F32)
        az = np.asarray(az_rad, dtype=_F32)
        az0 = np.where(np.isnan(az), _F32(0), az)
        return cls(
            r,
            np.asarray(radial_speed_mps, dtype=_F32),
            az,
            np.asarray(snr_db, dtype=_F32),
            (r * np.sin(az0)).astype(_F32),
            (r * np.cos(az0)).astype(_F32),
            dict(extra or {}),
        )

    def __len__(self) -> int:
        return int(self.range_m.size)


@dataclass(frozen=True)
class TrackState:
    """A track as published for one frame. ``track_id`` is a small recycled integer (fits CAN/Modbus)."""

    track_id: int
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    range_m: float
    radial_speed_mps: float
    az_rad: float
    age_frames: int
    hits: int
    confirmed: bool = True
    lane: int | None = None
    cls: str | None = None
    class_probability: float | None = None
    rcs_dbsm: float | None = None
    length_m: float | None = None
    # quality, None where not estimated: standard deviations of the published x_m, y_m, vx_mps, vy_mps (from the
    # track's state covariance) and the probability that the track is a real object (0..1)
    x_sd_m: float | None = None
    y_sd_m: float | None = None
    vx_sd_mps: float | None = None
    vy_sd_mps: float | None = None
    existence_probability: float | None = None

    @property
    def speed_mps(self) -> float:
        return float(np.hypot(self.vx_mps, self.vy_mps))


@dataclass(frozen=True)
class LaneStats:
    """Per-lane statistics of one closed interval (NaN where no vehicle gave a value)."""

    lane: int
    interval_start_ns: int
    interval_s: float
    sequence: int
    volume: int
    occupancy_pct: float
    mean_speed_kmh: float
    speed_p85_kmh: float
    headway_s: float
    gap_s: float
    class_counts: dict[str, int] = field(default_factory=dict)
    mean_length_m: float = float("nan")


TRACK_STATE_FIELDS = ("track_id", "x_m", "y_m", "vx_mps", "vy_mps", "range_m", "radial_speed_mps", "az_rad",
                      "age_frames", "hits", "confirmed", "lane", "cls", "class_probability", "rcs_dbsm", "length_m",
                      "x_sd_m", "y_sd_m", "vx_sd_mps", "vy_sd_mps", "existence_probability")
# the fast constructors (track_state, PdafTracker.published) know TrackState's fields; if they change (or it gains a
# __post_init__ or a factory default), the plain constructor is used
TRACK_STATE_PLAIN = (tuple(f.name for f in dataclasses.fields(TrackState)) == TRACK_STATE_FIELDS
                     and not hasattr(TrackState, "__post_init__")
                     and all(f.default is None for f in dataclasses.fields(TrackState)[11:]))


def track_state(tid, x, y, vx, vy, r, v, a, age, hits, conf, length_m) -> TrackState:
    """``TrackState(tid, x, ..., conf, length_m=length_m)`` without the frozen dataclass's per-field
    ``object.__setattr__``; the same ``__dict__``."""
    if not TRACK_STATE_PLAIN:
        return TrackState(tid, x, y, vx, vy, r, v, a, age, hits, conf, length_m=length_m)
    out = object.__new__(TrackState)
    object.__setattr__(out, "__dict__", {
        "track_id": tid, "x_m": x, "y_m": y, "vx_mps": vx, "vy_mps": vy, "range_m": r, "radial_speed_mps": v,
        "az_rad": a, "age_frames": age, "hits": hits, "confirmed": conf, "lane": None, "cls": None,
        "class_probability": None, "rcs_dbsm": None, "length_m": length_m, "x_sd_m": None, "y_sd_m": None,
        "vx_sd_mps": None, "vy_sd_mps": None, "existence_probability": None})
    return out


@dataclass(frozen=True)
class TrafficEvent:
    """Something a controller must know now: ``kind`` is ``wrong_way`` or ``stopped_vehicle``."""

    kind: str
    track_id: int
    lane: int | None
    t_ns: int


@dataclass(frozen=True)
class ClassifiedEvent:
    """The surveillance profile's answer for one target passage (Tavanti Tables IV-IX)."""

    track_id: int
    cls: str
    probabilities: dict[str, float]
    mean_radial_speed_kmh: float
    direction: str  # "approaching" | "receding"
    start_ns: int
    end_ns: int
    features: dict[str, float] = field(default_factory=dict)
    # the Doppler alias of mean_radial_speed_kmh could not be determined (too few frames, or the range rate lies
    # near an alias boundary): the speed is a best guess, to be published as n/a
    speed_uncertain: bool = False


@dataclass
class FrameResult:
    """Everything a pipeline produced for one frame; outputs and recorders consume it.

    ``presence`` has one flag per configured lane; ``lane_stats`` is non-empty only on the frame
    that closes an interval. ``intermediates`` holds arrays for plots (range profiles, thresholds,
    maps), never needed by outputs.
    """

    profile: str
    seq: int
    t_ns: int
    detections: Detections
    tracks: tuple[TrackState, ...] = ()
    presence: tuple[bool, ...] = ()
    lane_stats: tuple[LaneStats, ...] = ()
    events: tuple[TrafficEvent, ...] = ()
    classifications: tuple[ClassifiedEvent, ...] = ()
    intermediates: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class LoopHealth:
    """What the frame loop knows about itself, published with every result (and on stalls)."""

    t_ns: int
    frames: int
    dropped_frames: int
    overruns: int
    errors: int
    source_ok: bool
    last_frame_ns: int
    frame_p99_ms: float
    budget_ms: float
    state: str = "running"  # "starting" | "running" | "stalled" | "fault" | "stopped"
    #: share of the I and Q samples at the ADC's full scale over the frames sampled lately (None: none sampled yet)
    adc_clipped_fraction: float | None = None
