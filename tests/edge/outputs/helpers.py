"""Synthetic frame results and health for output tests (the profiles fill the real ones later)."""

from __future__ import annotations

import numpy as np

from edge.types import Detections, FrameResult, LaneStats, LoopHealth, TrafficEvent, TrackState

CLASSES = ("car", "truck", "pedestrian", "motorcycle", "bicycle", "bus", None)
PERIOD_NS = 33_000_000


def make_tracks(rng: np.random.Generator, n: int) -> tuple[TrackState, ...]:
    out = []
    for i in range(n):
        x, y = float(rng.uniform(-12, 12)), float(rng.uniform(2, 150))
        vx, vy = float(rng.uniform(-3, 3)), float(rng.uniform(-35, 35))
        r = float(np.hypot(x, y))
        out.append(TrackState(
            track_id=int(i * 7 % 250), x_m=x, y_m=y, vx_mps=vx, vy_mps=vy, range_m=r,
            radial_speed_mps=(x * vx + y * vy) / r, az_rad=float(np.arctan2(x, y)), age_frames=int(rng.integers(1, 500)),
            hits=int(rng.integers(1, 400)), lane=int(rng.integers(0, 4)) if rng.random() < 0.8 else None,
            cls=CLASSES[int(rng.integers(0, len(CLASSES)))], class_probability=float(rng.uniform(0.3, 1.0)),
            rcs_dbsm=float(rng.uniform(-10, 30)) if rng.random() < 0.5 else None,
            length_m=float(rng.uniform(0.5, 18)) if rng.random() < 0.5 else None,
        ))
    return tuple(out)


def make_lane_stats(rng: np.random.Generator, n_lanes: int, seq: int, t_ns: int = 0) -> tuple[LaneStats, ...]:
    out = []
    for k in range(n_lanes):
        vol = int(rng.integers(0, 60))
        out.append(LaneStats(
            lane=k, interval_start_ns=t_ns, interval_s=60.0, sequence=seq, volume=vol,
            occupancy_pct=float(rng.uniform(0, 60)), mean_speed_kmh=float(rng.uniform(20, 120)) if vol else float("nan"),
            speed_p85_kmh=float(rng.uniform(30, 140)) if vol else float("nan"),
            headway_s=float(rng.uniform(1, 30)) if vol > 1 else float("nan"), gap_s=float(rng.uniform(0.5, 25)) if vol > 1 else float("nan"),
            class_counts={"car": vol // 2, "truck": vol // 6, "bus": vol // 12, "motorcycle": 1, "pedestrian": 0, "van": 2},
        ))
    return tuple(out)


def make_result(seq: int, t_ns: int, tracks=(), presence=(), lane_stats=(), events=(), profile="lane") -> FrameResult:
    return FrameResult(profile=profile, seq=seq, t_ns=t_ns, detections=Detections.empty(), tracks=tuple(tracks),
                       presence=tuple(presence), lane_stats=tuple(lane_stats), events=tuple(events))


def health(t_ns: int, last_frame_ns: int, state: str = "running", frames: int = 0) -> LoopHealth:
    return LoopHealth(t_ns=t_ns, frames=frames, dropped_frames=3, overruns=1, errors=0, source_ok=state == "running",
                      last_frame_ns=last_frame_ns, frame_p99_ms=7.25, budget_ms=33.0, state=state)


def wrong_way(track_id: int, lane: int, t_ns: int) -> TrafficEvent:
    return TrafficEvent("wrong_way", track_id, lane, t_ns)
