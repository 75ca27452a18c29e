"""Short, seeded form of the soak run (the full one is `radar-edge soak --frames 200000`)."""

import pytest

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


def _stats(lane, seq, k=0):
    """Statistics of the ``k``-th consecutive 60 s interval."""
    return LaneStats(lane, k * 60_000_000_000, 60.0, seq, 3, 5.0, 80.0, 90.0, 2.0, 1.5)


def test_monitor_flags_inconsistencies():
    m = SoakMonitor(total_frames=10)
    h = None
    m.publish(FrameResult("x", 1, 0, Detections.empty(), tracks=(_track(1), _track(1))), h)
    m.publish(FrameResult("x", 1, 0, Detections.empty(), lane_stats=(_stats(0, 65535),)), h)
    m.publish(FrameResult("x", 2, 0, Detections.empty(), lane_stats=(_stats(0, 0, 1),)), h)  # wraps: fine
    m.publish(FrameResult("x", 3, 0, Detections.empty(), lane_stats=(_stats(0, 2, 2),)), h)  # skipped 1
    assert any("duplicate track ids" in p for p in m.problems)
    assert any("sequence went backwards" in p for p in m.problems)
    assert any("interval sequence 0 -> 2" in p for p in m.problems)
    assert len(m.problems) == 3


def test_monitor_counts_recycled_ids_and_checks_interval_contiguity():
    m = SoakMonitor(total_frames=10)
    m.publish(FrameResult("x", 1, 0, Detections.empty(), tracks=(_track(1), _track(2))), None)
    m.publish(FrameResult("x", 2, 0, Detections.empty(), tracks=(_track(2),)), None)  # 1 ends
    m.publish(FrameResult("x", 3, 0, Detections.empty(), tracks=(_track(1), _track(2))), None)  # 1 recycled
    assert m.id_reuses == 1 and not m.problems
    s0 = _stats(0, 5)
    later = LaneStats(0, s0.interval_start_ns + 61_000_000_000, 60.0, 6, 3, 5.0, 80.0, 90.0, 2.0, 1.5)
    m.publish(FrameResult("x", 4, 0, Detections.empty(), lane_stats=(s0,)), None)
    m.publish(FrameResult("x", 5, 0, Detections.empty(), lane_stats=(later,)), None)
    assert len(m.problems) == 1 and "does not follow" in m.problems[0]


def test_unpaced_sources_stamp_the_boards_timeline(tmp_path):
    """Offline (sim realtime=0, replay speed=0) frames are stamped open time + counter x period, across
    replay loops too: host arrival times would compress time tenfold for trackers and statistics."""
    import numpy as np

    from edge.bench import synth_frames
    from hal import open_radar
    from hal.recording import RecordingWriter

    frames = synth_frames("simo", None, 1, 12)
    period_ns = int(frames[0].frontend.waveform.frame_period_s * 1e9)
    assert np.all(np.diff([f.t_ns for f in frames]) == period_ns)
    w = RecordingWriter(frames[0].frontend)
    for f in frames[:5]:
        w.add(f)
    path = w.save(tmp_path / "r.npz")
    with open_radar(f"replay://{path}?speed=0&loop=1") as src:
        got = [src.read_frame(None) for _ in range(12)]
    assert [f.seq for f in got] == list(range(12))
    assert np.all(np.diff([f.t_ns for f in got]) == period_ns)


def test_short_lane_soak_with_outputs_wraps_and_recycles():
    """The CI form of `radar-edge soak`: the lane profile through the frame loop with Modbus TCP (read
    back over the network) and a virtual CAN bus; a frame counter starting just below 65536 and 2 s
    intervals make the 16-bit counters wrap and a small id pool makes track ids recycle."""
    import os

    pytest.importorskip("pymodbus")
    cfg = load_config(env={}, overrides={
        "outputs.modbus.tcp_port": 0, "outputs.can.interface": "virtual",
        "outputs.can.channel": f"test-soak-{os.getpid()}", "traffic.interval_s": 2.0,
        "track.pdaf.max_track_id": 24})
    rep = run_soak("lane", cfg, frames=1500, record_frames=300, seed=5, seq_start=65536 - 500)
    assert rep["frames"] == 1500 and rep["errors"] == 0 and rep["sink_errors"] == 0
    assert rep["n_problems"] == 0, rep["problems"]
    assert rep["tracks"]["max_id"] <= 24 and rep["tracks"]["id_reuses"] > 0
    assert rep["n_lanes"] == 4 and all(n >= 20 for n in rep["lane_intervals"].values())
    assert sum(rep["lane_volume"].values()) > 0
    mb = rep["modbus"]
    assert mb["reads"] >= 50 and mb["frame_counter_wraps"] == 1
    assert rep["rss_mb"]["at_end"] > 0 and mb["server_rss_mb"]["at_end"] > 0


def test_lane_count_for_the_outputs_of_each_profile():
    """`radar-edge run`, soak and pollbench size the Modbus/CAN lane blocks with ``pipeline.n_lanes``:
    the traffic layer's lanes (or, learned, the configured count) for the lane profile, 0 otherwise."""
    from edge.config import load_config
    from edge.pipeline import build_pipeline
    from hal.waveform import d2g_frontend, simo_frontend

    cfg = load_config(env={})
    assert build_pipeline("lane", simo_frontend(), cfg).n_lanes == len(cfg.section("traffic").lane_centers_m) == 4
    three = load_config(env={}, overrides={"traffic.lane_centers_m": "[-5.25, -1.75, 1.75]",
                                           "traffic.lane_widths_m": "[3.5, 3.5, 3.5]",
                                           "traffic.lane_directions": "[\"toward\", \"toward\", \"away\"]"})
    assert build_pipeline("lane", simo_frontend(), three).n_lanes == 3
    learned = load_config(env={}, overrides={"traffic.lane_mode": "learned"})
    assert build_pipeline("lane", simo_frontend(), learned).n_lanes == 4
    assert build_pipeline("surveillance", d2g_frontend(), cfg).n_lanes == 0
