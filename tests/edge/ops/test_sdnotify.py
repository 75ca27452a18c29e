"""sd_notify over a real AF_UNIX datagram socket: READY, WATCHDOG only while frames flow, STATUS."""

from __future__ import annotations

import os
import socket
import uuid

import numpy as np
import pytest

from edge.config import LoopConfig
from edge.loop import FrameLoop
from edge.ops.sdnotify import Notifier, NotifySink, watchdog_period_s
from edge.pipeline import Pipeline
from edge.types import Detections, FrameResult, LoopHealth
from hal.base import RadarSource, RawRead
from hal.clock import FakeClock
from hal.errors import SourceClosedError
from hal.waveform import d2g_frontend


def _drain(sock: socket.socket) -> list[str]:
    out = []
    while True:
        try:
            out.append(sock.recv(4096).decode())
        except BlockingIOError:
            return out


@pytest.fixture
def notify_socket(tmp_path):
    path = tmp_path / "notify.sock"
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(str(path))
    s.setblocking(False)
    yield str(path), s
    s.close()


class StallingSource(RadarSource):
    """Frames ``[0, n_ok)`` at once, then ``n_stall`` read timeouts (the board stops), then the end."""

    scheme = "stall"
    paces_itself = True

    def __init__(self, clock, n_ok, n_stall):
        super().__init__(clock_ns=clock.now_ns)
        self.clock, self.n_ok, self.n_stall = clock, n_ok, n_stall
        self.k = 0
        self._fe = d2g_frontend()

    @property
    def frontend(self):
        return self._fe

    def _open(self):
        pass

    def _close(self):
        pass

    def _read_raw(self, timeout_s):
        k = self.k
        self.k += 1
        if k < self.n_ok:
            self.clock.advance_ns(200_000_000)  # the board's frame period
            z = np.zeros(self._fe.frame_shape, dtype=np.int16)
            return RawRead(seq=k, i=z, q=z, t_ns=self.clock.now_ns())
        if k < self.n_ok + self.n_stall:
            self.clock.advance_ns(int(timeout_s * 1e9))
            return None
        raise SourceClosedError("end")


class NullPipeline(Pipeline):
    profile = "null"

    def __init__(self):
        super().__init__(d2g_frontend(), None)

    def process(self, frame, timer):
        return FrameResult("null", frame.seq, frame.t_ns, Detections.empty())


def test_watchdog_is_fed_while_frames_flow_and_stops_when_the_source_stalls(notify_socket):
    path, rx = notify_socket
    clock = FakeClock()
    sink = NotifySink(Notifier(path), watchdog_s=1.0, clock_ns=clock.now_ns)  # ping every 0.5 s
    src = StallingSource(clock, n_ok=25, n_stall=20)  # 5 s of frames, then 10 s of silence
    loop = FrameLoop(src, NullPipeline(), LoopConfig(health_period_s=0.5), sinks=[sink], clock=clock,
                     pace="source", read_timeout_s=0.5)
    log: list[tuple[int, str]] = []  # (frames so far, message)

    real_publish = sink.publish

    def publish(result, health):
        real_publish(result, health)
        for m in _drain(rx):
            log.append((health.frames, health.state, m))

    sink.publish = publish
    loop.run()
    log.extend((-1, "closed", m) for m in _drain(rx))

    msgs = [m for _, _, m in log]
    assert msgs[0].splitlines()[0] == "READY=1"
    assert sum("READY=1" in m for m in msgs) == 1
    pings = [(f, st) for f, st, m in log if "WATCHDOG=1" in m.splitlines()]
    # 5 s of frames at a ping every 0.5 s: about ten pings, all while running
    assert 8 <= len(pings) <= 11
    assert all(st == "running" for _, st in pings)
    # after the last frame: no ping at all during 10 s of stall heartbeats
    stall_msgs = [m for f, st, m in log if st == "stalled"]
    assert stall_msgs, "the stall must be reported"
    assert not any("WATCHDOG=1" in m for m in stall_msgs)
    assert any(m.startswith("STATUS=stalled") or "\nSTATUS=stalled" in m for m in stall_msgs)
    assert max(f for f, _ in pings) <= 25
    assert "STOPPING=1" in msgs[-1]


def test_status_line_carries_frames_drops_and_p99(notify_socket):
    path, rx = notify_socket
    sink = NotifySink(Notifier(path), watchdog_s=2.0, clock_ns=lambda: 0)
    h = LoopHealth(t_ns=0, frames=123, dropped_frames=4, overruns=1, errors=0, source_ok=True, last_frame_ns=0,
                   frame_p99_ms=12.5, budget_ms=200.0)
    sink.publish(FrameResult("x", 1, 0, Detections.empty()), h)
    (msg,) = _drain(rx)
    lines = msg.splitlines()
    assert lines[:2] == ["READY=1", "WATCHDOG=1"]
    assert lines[2] == "STATUS=running: 123 frames, 4 dropped, 1 overruns, 0 errors, p99 12.5 of 200 ms"
    # same instant, same frames: nothing new to say
    sink.publish(None, h)
    assert _drain(rx) == []


def test_abstract_namespace_socket():
    name = f"radar-edge-test-{uuid.uuid4().hex}"
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        s.bind(b"\0" + name.encode())
    except OSError as exc:  # pragma: no cover - non-Linux
        pytest.skip(f"abstract AF_UNIX namespace not available: {exc}")
    try:
        n = Notifier(env={"NOTIFY_SOCKET": "@" + name})
        assert n.enabled
        assert n.notify("READY=1", "STATUS=ok")
        assert s.recv(100) == b"READY=1\nSTATUS=ok"
        n.close()
    finally:
        s.close()


def test_missing_socket_is_counted_not_raised(tmp_path):
    n = Notifier(str(tmp_path / "nobody-listens"))
    assert not n.notify("WATCHDOG=1")
    assert n.errors == 1
    assert not Notifier(env={}).enabled
    assert not Notifier(env={"NOTIFY_SOCKET": "relative/path"}).enabled


def test_watchdog_period_from_environment():
    assert watchdog_period_s({"WATCHDOG_USEC": "10000000"}) == 10.0
    assert watchdog_period_s({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": str(os.getpid())}) == 10.0
    assert watchdog_period_s({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": str(os.getpid() + 1)}) is None
    assert watchdog_period_s({}) is None


def test_radar_edge_run_notifies_systemd(notify_socket, monkeypatch):
    """End to end: `radar-edge run` with $NOTIFY_SOCKET set speaks the protocol (as under systemd)."""
    from edge.cli import main

    path, rx = notify_socket
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    monkeypatch.setenv("WATCHDOG_USEC", "2000000")
    rc = main(["run", "--source", "sim://d2g?scenario=tavanti-test1&frames=8&realtime=0", "--frames", "8",
               "--no-outputs", "--status-every", "0"])
    assert rc == 0
    msgs = _drain(rx)
    lines = [ln for m in msgs for ln in m.splitlines()]
    assert lines[0] == "READY=1"
    assert "WATCHDOG=1" in lines
    assert any(ln.startswith("STATUS=running: ") for ln in lines)
    assert lines[-2:] == ["STOPPING=1", "STATUS=stopping"]


def test_watchdog_stops_while_the_emulated_distance2go_stalls(notify_socket):
    """Real loop, real d2g:// backend, the board emulator stops answering: no WATCHDOG=1 until it is back."""
    d2g_device = pytest.importorskip("hw_sim.d2g_device", reason="the Distance2Go emulator is not in this build")
    from edge.pipelines.minimal import MinimalConfig, MinimalPipeline
    from hal import open_radar

    path, rx = notify_socket
    log: list[tuple[str, str]] = []  # (phase, message)
    phase = {"now": "before", "heartbeats": 0}
    notify = NotifySink(Notifier(path), watchdog_s=0.02)  # ping on every processed frame

    with d2g_device.D2GEmulator("tavanti-test1", seed=1) as emu:

        class Driver:
            def publish(self, result, health):
                notify.publish(result, health)
                log.extend((phase["now"], m) for m in _drain(rx))
                if result is not None and health.frames == 5 and phase["now"] == "before":
                    phase["now"] = "stalled"
                    emu.stall()
                elif result is None and phase["now"] == "stalled":
                    phase["heartbeats"] += 1
                    if phase["heartbeats"] == 4:
                        phase["now"] = "after"
                        emu.recover()

            def close(self):
                notify.close()

        url = f"d2g://{emu.port}?period_ms=50&timeout_s=0.3&gap_s=0.02&backoff_s=0.02&backoff_max_s=0.1"
        with open_radar(url) as src:
            loop = FrameLoop(src, MinimalPipeline(src.frontend, MinimalConfig()), LoopConfig(health_period_s=0.1),
                             sinks=[Driver()], read_timeout_s=0.2)
            summary = loop.run(max_frames=10)
    assert summary.frames == 10 and phase["now"] == "after"
    pings = {p: sum("WATCHDOG=1" in m.splitlines() for ph, m in log if ph == p) for p in ("before", "stalled", "after")}
    assert pings["before"] >= 3 and pings["after"] >= 1
    assert pings["stalled"] == 0  # the stall starves the watchdog: systemd would restart the service
    assert any(ph == "stalled" and "STATUS=" in m for ph, m in log)


def test_a_board_missing_at_start_is_ready_and_feeds_the_watchdog_while_it_is_awaited(notify_socket):
    """The loop serves the missing board as a fault: systemd gets READY=1 and pings, so it neither kills the
    start after TimeoutStartSec nor restarts it into the start limit; once frames flow, the usual rule."""
    path, rx = notify_socket
    clock = FakeClock()
    sink = NotifySink(Notifier(path), watchdog_s=1.0, clock_ns=clock.now_ns)  # ping every 0.5 s

    def h(state, frames):
        return LoopHealth(t_ns=clock.now_ns(), frames=frames, dropped_frames=0, overruns=0, errors=3,
                          source_ok=False, last_frame_ns=0, frame_p99_ms=0.0, budget_ms=200.0, state=state)

    msgs = []
    for _ in range(8):  # 4 s of fault heartbeats, no frame yet
        sink.publish(None, h("fault", 0))
        msgs += _drain(rx)
        clock.advance_ns(500_000_000)
    assert msgs[0].splitlines()[0] == "READY=1" and sum("READY=1" in m for m in msgs) == 1
    assert sum("WATCHDOG=1" in m.splitlines() for m in msgs) == 8
    assert any("STATUS=fault" in m for m in msgs)
    msgs = []
    for _ in range(4):  # frames flowed, then the source stalled: no ping (systemd restarts as before)
        sink.publish(None, h("stalled", 10))
        msgs += _drain(rx)
        clock.advance_ns(500_000_000)
    assert not any("WATCHDOG=1" in m for m in msgs)
