"""The outputs behind the real frame loop (edge.loop.FrameLoop) on a fake clock.

A probe sink placed after the outputs reads, on every publish, what a Modbus TCP client and a CAN
receiver see, and compares it with the pipeline's own result for that frame. The source then
stalls: the fault and the fail-safe presence must show on both within 2 s of the last frame.
"""

from __future__ import annotations

import can
import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient

from edge.config import LoopConfig
from edge.loop import FrameLoop
from edge.outputs import registers as R
from edge.outputs.can_db import load_shipped
from edge.outputs.can_out import CanSink
from edge.outputs.config import CanConfig, ModbusConfig
from edge.outputs.modbus import ModbusSink
from edge.types import Detections, FrameResult
from hal.clock import FakeClock
from tests.edge.outputs.helpers import make_lane_stats, make_tracks
from tests.edge.test_loop import ScriptedPipeline, StallSource

N_LANES = 2


class TrackPipeline(ScriptedPipeline):
    """Publishes synthetic tracks, presence and (on frame 1) a closed interval."""

    n_lanes = N_LANES

    def process(self, frame, timer):
        super().process(frame, timer)
        rng = np.random.default_rng(frame.seq)
        lanes = make_lane_stats(rng, N_LANES, seq=9, t_ns=frame.t_ns) if frame.seq == 1 else ()
        return FrameResult("lane", frame.seq, frame.t_ns, Detections.empty(), make_tracks(rng, 6 + frame.seq),
                           (frame.seq % 2 == 0, False), lanes)


class Probe:
    """Reads both outputs right after they published (sinks are called in order)."""

    def __init__(self, client, can_rx, db, sync):
        self.client, self.rx, self.db, self.sync = client, can_rx, db, sync
        self.seen = []

    def publish(self, result, health):
        assert self.sync()  # the Modbus server process took the image the output just built
        status = self.client.read_input_registers(R.STATUS.base, count=R.STATUS.size, device_id=1).registers
        lanes = [self.client.read_input_registers(R.LANE_BASE + k * R.LANE_STRIDE, count=R.LANE_STRIDE,
                                                  device_id=1).registers for k in range(N_LANES)]
        tracks = self.client.read_input_registers(R.TRACK_HEADER, count=125, device_id=1).registers
        frames = []
        while (m := self.rx.recv(timeout=0)) is not None:
            frames.append(m)
        self.seen.append((result, health, status, lanes, tracks, frames))

    def close(self):
        pass


@pytest.fixture
def outputs(request):
    clk = FakeClock(start_ns=50_000_000_000)
    channel = f"loop-{request.node.name}"
    rx = can.Bus(interface="virtual", channel=channel)
    # fake clock: the server process's own silence watch (real clock, stale_image_s) is kept out of this test
    mb = ModbusSink(ModbusConfig(tcp_port=0, stale_image_s=600.0), N_LANES, clock_ns=clk.now_ns,
                    watchdog_period_s=3600.0).start()
    cs = CanSink(CanConfig(interface="virtual", channel=channel), N_LANES, clock_ns=clk.now_ns,
                 bus_factory=lambda: can.Bus(interface="virtual", channel=channel), threaded=False)
    client = ModbusTcpClient(*mb.tcp_address[:1], port=mb.tcp_address[1], timeout=2, retries=0)
    assert client.connect()
    yield clk, mb, cs, Probe(client, rx, load_shipped(), mb.sync)
    client.close()
    mb.close()
    cs.close()
    rx.shutdown()


def test_outputs_equal_the_pipeline_state_and_fail_safe_on_stall(outputs):
    clk, mb, cs, probe = outputs
    loop = FrameLoop(StallSource(clk, stall_reads=8), TrackPipeline(clk, lambda n: 5.0), LoopConfig(health_period_s=0.5),
                     sinks=[mb, cs, probe], clock=clk, read_timeout_s=1.0, pace="source")
    summary = loop.run()
    assert summary.frames == 3
    db = probe.db

    frames_seen = [s for s in probe.seen if s[0] is not None]
    assert len(frames_seen) == 3
    for result, health, status, lanes, tracks, can_frames in frames_seen:
        st = R.decode_block(R.STATUS, status)
        assert st["frame_counter"] == result.seq and st["alarm"] == 0 and st["track_count"] == len(result.tracks)
        hdr = R.decode_block(R.TRACK_HDR, tracks[:8])
        assert hdr["frame_counter"] == result.seq and hdr["valid_records"] == len(result.tracks)
        for k, t in enumerate(sorted(result.tracks, key=lambda t: t.range_m)):
            rec = R.decode_block(R.TRACK, tracks[8 + 8 * k: 16 + 8 * k])
            assert rec["track_id"] == t.track_id and rec["y"] == pytest.approx(t.y_m, abs=0.051)
        for k in range(N_LANES):
            lane = R.decode_block(R.LANE, lanes[k])
            assert bool(lane["live"] & 1) == result.presence[k]
            if result.seq >= 1:
                ls = make_lane_stats(np.random.default_rng(1), N_LANES, seq=9)[k]
                assert lane["volume"] == ls.volume and lane["interval_seq"] == 9
        ids = [m.arbitration_id for m in can_frames]
        hdr_can = db.decode_message(0x60A, can_frames[ids.index(0x60A)].data)
        assert hdr_can["Obj_MeasCounter"] == result.seq and hdr_can["Obj_NofObjects"] == len(result.tracks)
        got = {db.decode_message(0x60B, m.data)["Obj_ID"] for m in can_frames if m.arbitration_id == 0x60B}
        assert got == {t.track_id for t in result.tracks}

    last_frame_ns = frames_seen[-1][1].t_ns
    mb_fault = next(h.t_ns for r, h, status, *_ in probe.seen
                    if r is None and R.decode_block(R.STATUS, status)["status_bits"] & (1 << R.ST_ANY_FAULT))
    can_fault = None
    for r, h, status, lanes, tracks, can_frames in probe.seen:
        for m in can_frames:
            if m.arbitration_id == 0x201 and db.decode_message(0x201, m.data)["RadarState_Temporary_Error"]:
                can_fault = can_fault or h.t_ns
            if m.arbitration_id == 0x693 and can_fault:
                assert db.decode_message(0x693, m.data)["Presence_Lanes"] == 0b11  # fail-safe: all on
        if can_fault and r is None:
            assert all(R.decode_block(R.LANE, lanes[k])["live"] & 1 for k in range(N_LANES))
    assert mb_fault - last_frame_ns <= 2_000_000_000
    assert can_fault is not None and can_fault - last_frame_ns <= 2_000_000_000
