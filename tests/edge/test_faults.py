"""Fault and abuse tests (issue 9): each fault gives a clear error or a counted fault, the process keeps
serving, and nothing is lost but the faulty frames.

Covered here, through the real frame loop and the real lane pipeline where it matters: source stall,
garbage and disconnect; Modbus TCP flood from several clients plus malformed requests as raw bytes;
CAN bus-off; disk full while recording; bad configuration values from the CLI; a corrupted model file.
Unit-level companions live next to their modules (tests/edge/test_loop.py, outputs/test_can.py,
ops/test_recorder.py, test_onnx_knn.py, test_config.py).
"""

from __future__ import annotations

import errno
import os
import socket
import struct
import threading

import numpy as np
import pytest

from edge.bench import synth_frames
from edge.config import LoopConfig, load_config
from edge.loop import FrameLoop
from edge.pipeline import build_pipeline
from hal.base import RadarSource, RawRead
from hal.clock import FakeClock
from hal.errors import DeviceError, SourceClosedError

N_FRAMES = 40


@pytest.fixture(scope="module")
def lane_frames():
    return synth_frames("simo", None, 3, N_FRAMES)


class Collect:
    """A sink keeping every result and heartbeat."""

    def __init__(self):
        self.results, self.health = [], []

    def publish(self, result, health):
        (self.results.append(result) if result is not None else None)
        self.health.append(health)

    def close(self):
        pass


class ScriptedSource(RadarSource):
    """Plays recorded frames; ``script`` maps a read index to a fault:

    * ``stall``: no frame this read (the board is silent; no frame is consumed);
    * ``disconnect``: the device is gone (:class:`DeviceError`); the frame of that read is lost;
    * ``shape`` / ``range`` / ``dtype``: the frame of that read arrives mangled (wrong sample count,
      samples beyond the ADC range, float samples).

    Each read advances the fake clock by one frame period, like a board.
    """

    scheme = "scripted"
    paces_itself = False

    def __init__(self, frames, script, clock):
        super().__init__(clock_ns=clock.now_ns)
        self.frames, self.script, self.clock = frames, dict(script), clock
        self.reads = self.pos = self.opens = 0
        self.period_ns = int(frames[0].frontend.waveform.frame_period_s * 1e9)

    @property
    def frontend(self):
        return self.frames[0].frontend

    def _open(self):
        self.opens += 1

    def _close(self):
        pass

    def _read_raw(self, timeout_s):
        kind = self.script.get(self.reads)
        self.reads += 1
        self.clock.advance_ns(self.period_ns)
        if kind == "stall":
            return None
        if self.pos >= len(self.frames):
            raise SourceClosedError("end of the scripted frames")
        f = self.frames[self.pos]
        self.pos += 1
        if kind == "disconnect":
            raise DeviceError("USB device disconnected")
        i, q = f.i, f.q
        if kind == "shape":
            i, q = i[..., :-7], q[..., :-7]
        elif kind == "range":
            i = i.copy()
            i[0, 0, 5] = f.frontend.adc_max + 1
        elif kind == "dtype":
            i = i.astype(np.float32)
        return RawRead(seq=f.seq, i=i, q=q, truth=f.truth, t_ns=f.t_ns)


@pytest.mark.parametrize("policy", ["skip", "reconnect"])
def test_source_stall_garbage_and_disconnect_through_the_loop(lane_frames, policy):
    """Lane pipeline in the real frame loop: every good frame is published, each faulty read is counted
    (timeouts for stalls, source errors for garbage/disconnects, reconnects under that policy), health
    reports the fault while it lasts, and the loop runs to the end of the data."""
    clk = FakeClock()
    script = {3: "stall", 4: "stall", 5: "stall", 9: "shape", 14: "range", 20: "dtype", 25: "disconnect",
              31: "stall", 32: "disconnect"}
    src = ScriptedSource(lane_frames, script, clk)
    cfg = load_config(env={})
    sink = Collect()
    loop = FrameLoop(src, build_pipeline("lane", src.frontend, cfg),
                     LoopConfig(error_policy=policy, reconnect_backoff_s=0.5), sinks=[sink], clock=clk,
                     pace="none")
    s = loop.run()
    # frames consumed by the faulty reads; read index -> frame index: stalls consume none
    faulty_reads = [9, 14, 20, 25, 32]
    lost = {lane_frames[r - sum(1 for k, v in script.items() if v == "stall" and k < r)].seq for r in faulty_reads}
    good = [f.seq for f in lane_frames if f.seq not in lost]
    assert [r.seq for r in sink.results] == good  # nothing lost but the faulty frames, in order
    assert s.stop_reason == "end of source"
    assert s.errors == len(faulty_reads) and s.timeouts == 4
    assert s.frames == len(good)
    # the reconnect policy reopens the device after any source fault (a garbled stream may need a resync)
    assert s.reconnects == (len(faulty_reads) if policy == "reconnect" else 0) and src.opens == 1 + s.reconnects
    states = {h.state for h in sink.health}
    assert {"fault", "running", "stopped"} <= states
    assert any(len(r.tracks) for r in sink.results)  # the tracker kept working across the faults


def test_a_source_that_keeps_failing_stops_the_loop_with_a_clear_reason(lane_frames):
    clk = FakeClock()
    src = ScriptedSource(lane_frames, {k: "shape" for k in range(5, 100)}, clk)
    sink = Collect()
    loop = FrameLoop(src, build_pipeline("minimal", src.frontend, load_config(env={})),
                     LoopConfig(error_policy="skip", max_consecutive_errors=10), sinks=[sink], clock=clk, pace="none")
    s = loop.run()
    assert s.frames == 5 and s.errors == 10
    assert s.stop_reason.startswith("source error") and "shape" in s.stop_reason
    assert sink.health[-1].state == "stopped"


# --- Modbus TCP: flood and malformed requests ------------------------------------------------------------

_MBAP = struct.Struct(">HHHBB")


def _request(tid, fc, start, count, unit=1):
    return _MBAP.pack(tid, 0, 6, unit, fc) + struct.pack(">HH", start, count)


def _reply(sock):
    head = b""
    while len(head) < 7:
        chunk = sock.recv(7 - len(head))
        if not chunk:
            raise ConnectionError("closed")
        head += chunk
    tid, proto, length, unit = _MBAP.unpack(head + b"\0")[:4]
    body = b""
    while len(body) < length - 1:
        chunk = sock.recv(length - 1 - len(body))
        if not chunk:
            raise ConnectionError("closed")
        body += chunk
    return tid, body


@pytest.fixture
def modbus_sink():
    pytest.importorskip("pymodbus")
    from edge.outputs.config import ModbusConfig
    from edge.outputs.modbus import ModbusSink

    sink = ModbusSink(ModbusConfig(tcp_host="127.0.0.1", tcp_port=0), 4).start()
    yield sink
    sink.close()


def test_modbus_malformed_requests_are_refused_and_the_server_keeps_answering(modbus_sink):
    """Raw bytes: unknown function code and out-of-range counts get an exception reply (pymodbus 3.16
    answers a request it cannot decode with function 0x80, exception 01); bad MBAP lengths, a foreign
    protocol id, a truncated header and garbage get no reply. Half-open connections holding such
    bytes do not stop other clients."""
    from edge.soak import modbus_read_registers

    addr = modbus_sink.tcp_address
    hanging = []
    for junk in (_MBAP.pack(9, 0, 0, 1, 3) + b"\0\0\0\1",  # length 0
                 _MBAP.pack(9, 0, 300, 1, 3) + b"\0\0\0\1",  # length beyond the data
                 b"\x00\x09\x00",  # truncated MBAP
                 _MBAP.pack(9, 5, 6, 1, 3) + b"\0\0\0\1",  # protocol id 5
                 bytes(range(256))):  # garbage
        s = socket.create_connection(addr, timeout=2)
        s.sendall(junk)
        hanging.append(s)
    try:
        for s in hanging[:2]:
            s.settimeout(0.3)
            with pytest.raises((socket.timeout, ConnectionError)):
                _reply(s)
        with socket.create_connection(addr, timeout=2) as s:
            for fc, start, count in ((0x55, 0, 1), (3, 0, 0), (3, 0, 200), (4, 0, 126)):
                s.sendall(_request(11, fc, start, count))
                tid, body = _reply(s)
                assert tid == 11 and body[0] & 0x80, (fc, count, body)  # an exception response
            s.sendall(_request(12, 3, 2090 + 0, 1))
            _, body = _reply(s)
            assert body[0] == 3  # the same connection still works after the refusals
        # while the half-open junk connections are still there, others are served
        assert modbus_read_registers(addr, 0, 1) == [0x5452]
    finally:
        for s in hanging:
            s.close()
    assert modbus_read_registers(addr, 0, 1) == [0x5452]


def test_modbus_flood_from_several_clients_while_the_loop_publishes(lane_frames, modbus_sink):
    """Eight clients read the whole map as fast as they can while the frame loop publishes every frame
    to the server: every frame is processed and shipped (none dropped or failed), every read is
    answered correctly, and the served frame counter is the last frame's."""
    from edge.outputs.registers import READ_RANGES
    from edge.soak import modbus_read_registers

    addr = modbus_sink.tcp_address
    stop = threading.Event()
    answered, failures = [0] * 8, []
    started = [threading.Event() for _ in range(8)]

    class KeepOpen:  # the loop closes its sinks at the end; the clients must stop first
        def publish(self, result, health):
            modbus_sink.publish(result, health)

        def close(self):
            pass

    def flood(k):
        try:
            with socket.create_connection(addr, timeout=5) as s:
                tid = 0
                while not stop.is_set():
                    for a, b in READ_RANGES:
                        for start in range(a, b, 125):
                            tid = (tid + 1) & 0xFFFF
                            s.sendall(_request(tid, 3, start, min(125, b - start)))
                            got, body = _reply(s)
                            if got != tid or body[0] != 3:
                                failures.append((k, got, body[:3]))
                                return
                            answered[k] += 1
                            started[k].set()
        except OSError as exc:  # noqa: PERF203 - a failure is what the test looks for
            failures.append((k, repr(exc)))

    threads = [threading.Thread(target=flood, args=(k,), daemon=True) for k in range(8)]
    for t in threads:
        t.start()
    assert all(e.wait(10) for e in started)  # every client is being served before the loop starts
    clk = FakeClock()
    src = ScriptedSource(lane_frames, {}, clk)
    sink = Collect()
    loop = FrameLoop(src, build_pipeline("lane", src.frontend, load_config(env={})), LoopConfig(),
                     sinks=[KeepOpen(), sink], clock=clk, pace="none")
    try:
        s = loop.run()
        before = sum(answered)
        assert modbus_sink.sync()
        last = modbus_read_registers(addr, 16 + 4, 1)[0]
    finally:
        stop.set()
        for t in threads:
            t.join(10)
    assert s.frames == N_FRAMES and s.errors == 0 and loop.counters.sink_errors == 0
    assert [r.seq for r in sink.results] == [f.seq for f in lane_frames]
    assert not failures, failures[:3]
    assert all(n > 0 for n in answered) and sum(answered) >= before
    assert last == lane_frames[-1].seq & 0xFFFF
    assert modbus_sink.counters["images_sent"] >= N_FRAMES and modbus_sink.counters["images_dropped"] == 0


def test_modbus_serves_the_last_frame_after_a_flood(modbus_sink):
    """After a flood by several connections that then vanish mid-request, the image the loop
    published last is served."""
    from edge.soak import modbus_read_registers
    from tests.edge.outputs.helpers import health, make_result

    addr = modbus_sink.tcp_address
    socks = [socket.create_connection(addr, timeout=2) for _ in range(16)]
    for k, s in enumerate(socks):
        for j in range(20):
            s.sendall(_request(j, 3, 0, 125))
        s.sendall(_request(99, 3, 0, 125)[:5])  # and leave in the middle of a request
    for s in socks:
        s.close()
    t = 5_000_000_000
    modbus_sink.publish(make_result(65539, t), health(t, t))
    assert modbus_sink.sync()
    assert modbus_read_registers(addr, 16 + 4, 1) == [65539 & 0xFFFF]


# --- CAN bus-off ---------------------------------------------------------------------------------------


class BusOffBus:
    """A CAN bus that goes bus-off (ENETDOWN) on its ``fail_from``-th send, for ``fail_sends`` sends."""

    opened = 0

    def __init__(self, fail_from, fail_sends):
        type(self).opened += 1
        self.fail_from, self.fail_sends, self.calls, self.sent = fail_from, fail_sends, 0, []

    def send(self, msg, timeout=None):
        import can

        self.calls += 1
        if self.fail_from <= self.calls < self.fail_from + self.fail_sends:
            raise can.CanOperationError("bus off", error_code=errno.ENETDOWN)
        self.sent.append(msg)

    def shutdown(self):
        pass


def test_can_bus_off_is_counted_and_recovered_while_the_loop_runs(lane_frames):
    """The bus goes off in the middle of a run: the fault is counted, the loop keeps processing every
    frame, the sink backs off for ``reconnect_s`` and then reopens the bus and sends again."""
    can = pytest.importorskip("can")  # noqa: F841 - python-can is what raises the real errors
    from edge.outputs.can_out import CanSink
    from edge.outputs.config import CanConfig

    buses = []

    def factory():
        bus = BusOffBus(fail_from=30, fail_sends=1) if not buses else BusOffBus(10**9, 0)
        buses.append(bus)
        return bus

    clk = FakeClock()
    sink = CanSink(CanConfig(interface="socketcan", reconnect_s=0.3), 4, bus_factory=factory, clock_ns=clk.now_ns,
                   threaded=False)
    src = ScriptedSource(lane_frames, {}, clk)
    collect = Collect()
    loop = FrameLoop(src, build_pipeline("lane", src.frontend, load_config(env={})), LoopConfig(),
                     sinks=[sink, collect], clock=clk, pace="none")
    s = loop.run()
    assert s.frames == N_FRAMES and s.errors == 0 and loop.counters.sink_errors == 0
    assert len(collect.results) == N_FRAMES
    assert sink.faults["bus_off"] == 1 and sink.faults["frames_not_sent"] > 0
    assert buses[0].sent and len(buses) == 2 and buses[1].sent  # sent, went off, reopened after the back-off


def test_can_virtual_bus_survives_the_receiver_going_away():
    """python-can virtual bus end to end: frames arrive; with the receiver gone, sending continues
    without faults (a virtual bus, like a real one, does not need listeners)."""
    can = pytest.importorskip("can")
    from edge.outputs.can_out import CanSink
    from edge.outputs.config import CanConfig
    from tests.edge.outputs.helpers import health, make_result

    ch = f"faults-{os.getpid()}"
    rx = can.Bus(interface="virtual", channel=ch)
    sink = CanSink(CanConfig(interface="virtual", channel=ch), 1, threaded=False)
    t = 1_000_000_000
    sink.publish(make_result(1, t, presence=(True,)), health(t, t))
    assert rx.recv(1.0) is not None
    rx.shutdown()
    for k in range(2, 6):
        t += 33_000_000
        sink.publish(make_result(k, t, presence=(True,)), health(t, t))
    assert sum(sink.faults[k] for k in ("bus_off", "send_error", "enobufs")) == 0 and sink.sent > 1
    sink.close()


# --- disk full while recording ---------------------------------------------------------------------------


def test_disk_full_while_recording_is_counted_and_the_loop_keeps_running(lane_frames, tmp_path, monkeypatch):
    """The event recorder attached as `radar-edge run` attaches it; every save fails with ENOSPC: the
    segments are counted as lost, the recorder reports disk_full, and the loop publishes every frame."""
    from edge.ops import attach
    from edge.ops.recorder import EventRecorder
    from hal.recording import RecordingWriter

    def full(self, path):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(RecordingWriter, "save", full)
    cfg = load_config(env={}, overrides={"ops.recorder.enabled": True, "ops.recorder.directory": str(tmp_path),
                                         "ops.recorder.trigger": "always", "ops.recorder.max_frames_per_file": 10,
                                         "ops.recorder.min_free_mb": 0.0, "ops.recorder.retry_s": 0.0})
    clk = FakeClock()
    src = ScriptedSource(lane_frames, {}, clk)
    sinks, collect = [], Collect()
    pipe = attach(cfg, build_pipeline("lane", src.frontend, cfg), sinks, env={})
    rec = next(s for s in sinks if isinstance(s, EventRecorder))
    loop = FrameLoop(src, pipe, LoopConfig(), sinks=[*sinks, collect], clock=clk, pace="none")
    s = loop.run()
    assert s.frames == N_FRAMES and s.errors == 0 and loop.counters.sink_errors == 0
    assert [r.seq for r in collect.results] == [f.seq for f in lane_frames]
    assert rec.stats.disk_full_events >= 1 and rec.stats.segments_lost + rec.stats.segments_dropped == N_FRAMES // 10
    assert rec.stats.files_written == 0 and rec.state == "disk_full"
    assert list(tmp_path.glob("*.npz")) == [] and list(tmp_path.glob("*.part")) == []


# --- bad configuration and corrupt model files from the CLI ---------------------------------------------


@pytest.mark.parametrize("argv,message", [
    (["run", "--no-outputs", "--set", "pipeline.lane.cfar_pfa=2"], "pipeline.lane.cfar_pfa"),
    (["run", "--no-outputs", "--set", "track.pdaf.prob_detect=abc"], "track.pdaf.prob_detect"),
    (["run", "--no-outputs", "--set", "outputs.modbus.tcp_port=70000"], "outputs.modbus.tcp_port"),
    (["run", "--no-outputs", "--set", "nosuch.key=1"], "nosuch"),
    (["bench", "--profile", "lane", "--frames", "12", "--set", "pipeline.lane.window=triangle"],
     "pipeline.lane.window"),
    (["soak", "--frames", "10", "--set", "traffic.interval_s=0"], "traffic.interval_s"),
])
def test_bad_configuration_values_exit_2_naming_the_key(argv, message, capsys):
    from edge.cli import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1  # one clear line, no traceback


def test_bad_configuration_file_exits_2(tmp_path, capsys):
    from edge.cli import main

    bad = tmp_path / "radar-edge.toml"
    bad.write_text("[loop]\nerror_policy = \n", encoding="utf-8")
    assert main(["run", "--no-outputs", "--config", str(bad)]) == 2
    assert str(bad) in capsys.readouterr().err
    bad.write_text("[loop]\nerror_policy = 'sometimes'\n", encoding="utf-8")
    assert main(["run", "--no-outputs", "--config", str(bad)]) == 2
    assert "loop.error_policy" in capsys.readouterr().err


def test_corrupt_model_file_is_a_clear_error_naming_the_file(tmp_path, capsys):
    """`radar-edge run` on the Distance2Go with a corrupted ONNX model refuses to start (exit 2) and
    names the file; the same configuration with the numpy backend runs."""
    pytest.importorskip("onnxruntime")
    from edge.cli import main
    from edge.classify.onnx_runtime import default_model_path

    data = default_model_path().read_bytes()
    bad = tmp_path / "model.onnx"
    bad.write_bytes(data[: len(data) // 3])
    argv = ["run", "--source", "sim://d2g?realtime=0&frames=3", "--no-outputs", "--status-every", "0",
            "--set", f"classify.onnx.model={bad}"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and err.count("\n") == 1
    assert main(argv + ["--set", "classify.onnx.backend=numpy"]) == 0
