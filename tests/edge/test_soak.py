"""Short, seeded form of the soak run (the full one is `radar-edge soak --frames 200000`)."""

from edge.config import load_config
from edge.soak import SoakMonitor, run_soak
from edge.types import Detections, FrameResult, LaneStats, TrackState


def test_short_soak_minimal_profile():
    rep = run_soak("minimal", load_config(env={}), frames=400, record_frames=40, seed=3, outputs=False)
    assert rep["frames"] == 400 and rep["errors"] == 0 and rep["n_problems"] == 0
    assert rep["stop_reason"] == "400 frames"
    assert rep["rss_mb"]["at_end"] > 0 and len(rep["rss_mb"]["samples"]) >= 10


def _track(i):
    return TrackState(i, 0, 10, 0, 1, 10, 1, 0, 3, 3)


def _stats(lane, seq):
    return LaneStats(lane, 0, 60.0, seq, 3, 5.0, 80.0, 90.0, 2.0, 1.5)


def test_monitor_flags_inconsistencies():
    m = SoakMonitor(total_frames=10)
    h = None
    m.publish(FrameResult("x", 1, 0, Detections.empty(), tracks=(_track(1), _track(1))), h)
    m.publish(FrameResult("x", 1, 0, Detections.empty(), lane_stats=(_stats(0, 65535),)), h)
    m.publish(FrameResult("x", 2, 0, Detections.empty(), lane_stats=(_stats(0, 0),)), h)  # wraps: fine
    m.publish(FrameResult("x", 3, 0, Detections.empty(), lane_stats=(_stats(0, 2),)), h)  # skipped 1
    assert any("duplicate track ids" in p for p in m.problems)
    assert any("sequence went backwards" in p for p in m.problems)
    assert any("interval sequence 0 -> 2" in p for p in m.problems)
    assert len(m.problems) == 3
