"""The live terminal view: rate-limited redraws with ANSI codes, tracks, lane counters, budget."""

from __future__ import annotations

import io
import re
import socket

from edge.cli import main
from edge.config import load_config
from edge.ops import attach
from edge.ops.recorder import EventRecorder
from edge.ops.sdnotify import NotifySink
from edge.ops.view import CLEAR_BELOW, CLEAR_EOL, HOME, SHOW_CURSOR, LiveView
from edge.pipelines.minimal import MinimalConfig, MinimalPipeline
from edge.types import ClassifiedEvent, Detections, FrameResult, LaneStats, LoopHealth, TrackState, TrafficEvent
from hal.waveform import d2g_frontend

ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def _health(k: int, state="running") -> LoopHealth:
    return LoopHealth(t_ns=k * 10_000_000, frames=k, dropped_frames=2, overruns=1, errors=0, source_ok=True,
                      last_frame_ns=k * 10_000_000, frame_p99_ms=8.25, budget_ms=33.0, state=state)


def _result(k: int) -> FrameResult:
    tracks = (TrackState(7, 1.75, 40.0, 0.0, 25.0, 40.04, 24.9, 0.0437, 12, 11, lane=2, cls="car", class_probability=0.91),
              TrackState(3, -5.25, 120.0, 0.0, -27.0, 120.1, -27.0, -0.0437, 30, 29, lane=0))
    stats = ()
    if k == 50:
        stats = (LaneStats(0, 0, 30.0, 1, 4, 12.5, 97.2, 105.0, 7.5, 6.0), LaneStats(2, 0, 30.0, 1, 3, 8.0, 88.0, 95.0, 10.0, 9.0))
    events = (TrafficEvent("wrong_way", 3, 0, k * 10_000_000),) if k == 60 else ()
    cls = (ClassifiedEvent(9, "human", {"human": 0.8, "vehicle": 0.2}, 4.2, "approaching", 0, 1),) if k == 70 else ()
    return FrameResult("lane", k, k * 10_000_000, Detections.empty(), tracks=tracks, presence=(True, False, True, False),
                       lane_stats=stats, events=events, classifications=cls)


def test_redraws_are_rate_limited_and_show_the_state():
    out = io.StringIO()
    now = [0.0]
    view = LiveView(out, max_hz=4.0, clock_s=lambda: now[0], title="sim://simo")
    for k in range(1, 101):  # 100 frames, 10 ms apart = 1 s
        now[0] = k * 0.01
        view.publish(_result(k), _health(k))
    assert 4 <= view.redraws <= 5
    view.close()
    text = out.getvalue()
    assert text.count(HOME) == view.redraws and CLEAR_EOL in text and CLEAR_BELOW in text
    assert text.endswith(SHOW_CURSOR)
    last = ANSI.sub("", text.rsplit(HOME, 1)[1])
    lines = last.splitlines()
    assert "state running" in lines[0] and "frames 100" in lines[0] and "dropped 2" in lines[0]
    assert "p99    8.25 of 33 ms" in lines[1] and "25.0%" in lines[1]
    # tracks sorted by range: #7 (40 m) first, with lane, speed, class and probability
    rows = [ln.split() for ln in lines if re.match(r"^\s+\d+\s+(\d+|-)\s+\d+\.\d", ln)]
    assert [r[0] for r in rows] == ["7", "3"]
    assert rows[0][:3] == ["7", "2", "40.0"] and "car" in rows[0] and "0.91" in rows[0] and "90.0" in rows[0]
    lanes = {r[0]: r for r in (ln.split() for ln in lines) if len(r) >= 3 and r[1] in ("occupied", "free")}
    assert lanes["0"][:3] == ["0", "occupied", "4"] and lanes["1"][:3] == ["1", "free", "0"]
    assert lanes["2"][:3] == ["2", "occupied", "3"]
    assert any("wrong_way" in ln and "#3" in ln and "+0.6 s" in ln for ln in lines)  # frame 60, 10 ms after frame 1
    assert any("human" in ln and "approaching" in ln for ln in lines)


def test_unmeasured_azimuth_is_a_dash():
    view = LiveView(io.StringIO(), clock_s=lambda: 0.0, color=False)
    t = TrackState(2, 0.0, 11.2, 0.0, 0.6, 11.2, 0.6, float("nan"), 69, 60)
    view.publish(FrameResult("surveillance", 1, 0, Detections.empty(), tracks=(t,)), _health(1))
    (row,) = [ln for ln in view.render() if ln.strip().startswith("2 ")]
    assert row.split()[:4] == ["2", "-", "11.2", "-"]


def test_stall_is_shown_and_nothing_is_drawn_before_health():
    out = io.StringIO()
    view = LiveView(out, clock_s=lambda: 0.0, color=False)
    assert view.render() == ["radar-edge: waiting for the first frame..."]
    view.publish(None, _health(5, state="stalled"))
    assert "state stalled" in ANSI.sub("", out.getvalue())


def test_attach_adds_the_ops_sinks(tmp_path):
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "n.sock"))
    try:
        cfg = load_config(env={}, overrides={"ops.recorder.enabled": True, "ops.recorder.directory": str(tmp_path / "r")})
        pipe = MinimalPipeline(d2g_frontend(), MinimalConfig())
        sinks: list = []
        wrapped = attach(cfg, pipe, sinks, view=True, env={"NOTIFY_SOCKET": str(tmp_path / "n.sock")})
        kinds = [type(s) for s in sinks]
        assert kinds == [NotifySink, EventRecorder, LiveView]
        assert wrapped is not pipe and wrapped.inner is pipe and wrapped.profile == "minimal"
        for s in sinks:
            s.close()
        sinks = []
        assert attach(load_config(env={}), pipe, sinks, env={}) is pipe and sinks == []
    finally:
        sock.close()


def test_run_view_from_the_command_line(capsys):
    rc = main(["run", "--source", "sim://d2g?scenario=tavanti-test1&frames=6&realtime=0", "--frames", "6",
               "--no-outputs", "--view"])
    out = capsys.readouterr().out
    assert rc == 0
    screen = ANSI.sub("", out.rsplit(HOME, 1)[1])
    assert "TRACKS" in screen and "frames 6" in screen and "budget" in screen
