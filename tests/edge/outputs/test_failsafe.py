"""Fail-safe: frames stop or the pipeline faults -> status, CAN state and presence show it within 2 s.

Driven with a fake clock: the loop's heartbeats (``publish(None, health)`` every 0.5 s) and the
outputs' own watchdog are called explicitly; nothing sleeps.
"""

from __future__ import annotations

import can
import numpy as np
import pytest

from edge.outputs import registers as R
from edge.outputs.can_db import load_shipped
from edge.outputs.can_out import CanSink
from edge.outputs.config import CanConfig, FailsafeConfig, ModbusConfig
from edge.outputs.modbus import ModbusSink
from edge.outputs.state import ALARM_NO_PUBLISH, ALARM_NONE, ALARM_PIPELINE, ALARM_STALLED, OutputState
from tests.edge.outputs.helpers import PERIOD_NS, health, make_lane_stats, make_result, make_tracks

T0 = 5_000_000_000
HB = 500_000_000  # the loop's heartbeat period
N_LANES = 3


def _status(img):
    return R.decode_block(R.STATUS, img[R.STATUS.base: R.STATUS.base + R.STATUS.size])


def _lane(img, k):
    a = R.LANE_BASE + k * R.LANE_STRIDE
    return R.decode_block(R.LANE, img[a: a + R.LANE_STRIDE])


def _run_frames(sinks, n, t_start, rng, close_interval_at=None):
    t = t_start
    for i in range(n):
        lanes = make_lane_stats(rng, N_LANES, seq=i % 256, t_ns=t) if i == close_interval_at else ()
        res = make_result(i, t, make_tracks(rng, 5), (False, True, False), lanes)
        for s in sinks:
            s.publish(res, health(t, t, frames=i + 1))
        t += PERIOD_NS
    return t - PERIOD_NS


class CanCapture:
    """A python-can virtual bus pair: the sink sends on one end, the test reads the other."""

    def __init__(self, channel):
        self.rx = can.Bus(interface="virtual", channel=channel)
        self.channel = channel

    def factory(self):
        return can.Bus(interface="virtual", channel=self.channel)

    def drain(self):
        out = []
        while (m := self.rx.recv(timeout=0)) is not None:
            out.append(m)
        return out

    def close(self):
        self.rx.shutdown()


@pytest.fixture
def capture(request):
    c = CanCapture(f"failsafe-{request.node.name}")
    yield c
    c.close()


@pytest.mark.parametrize("presence_mode,expected", [("on", (True,) * N_LANES), ("off", (False,) * N_LANES),
                                                      ("hold", (False, True, False))])
def test_source_stall_is_shown_within_2s_on_modbus_and_can(capture, presence_mode, expected):
    fs = FailsafeConfig(presence=presence_mode)
    mb = ModbusSink(ModbusConfig(tcp_enabled=False), N_LANES, failsafe=fs, wall_clock=lambda: 1.7e9)
    cs = CanSink(CanConfig(interface="virtual", channel=capture.channel), N_LANES, failsafe=fs,
                 bus_factory=capture.factory, threaded=False, wall_clock=lambda: 1.7e9)
    db = load_shipped()
    rng = np.random.default_rng(3)
    try:
        t_last = _run_frames([mb, cs], 40, T0, rng, close_interval_at=5)
        assert _status(mb.image())["alarm"] == ALARM_NONE
        assert _lane(mb.image(), 0)["live"] & (1 << R.LV_STALE) == 0
        capture.drain()
        # frames stop: the loop keeps sending heartbeats with state "running" first, "stalled" after 1 s
        seen_fault_at = {}
        t = t_last
        for step in range(1, 5):
            t = t_last + step * HB
            state = "stalled" if t - t_last > 1_000_000_000 else "running"
            for s in (mb, cs):
                s.publish(None, health(t, t_last, state=state))
            st = _status(mb.image())
            if st["status_bits"] & (1 << R.ST_ANY_FAULT) and "modbus" not in seen_fault_at:
                seen_fault_at["modbus"] = t - t_last
            for m in capture.drain():
                if m.arbitration_id == 0x201:
                    d = db.decode_message(0x201, m.data)
                    if d["RadarState_Temporary_Error"] and "can" not in seen_fault_at:
                        seen_fault_at["can"] = t - t_last
                if m.arbitration_id == 0x693 and "can" in seen_fault_at:
                    d = db.decode_message(0x693, m.data)
                    assert d["Presence_Failsafe"] == (presence_mode != "hold")
                    assert tuple(bool(d["Presence_Lanes"] >> k & 1) for k in range(N_LANES)) == expected
        assert seen_fault_at["modbus"] <= 2_000_000_000 and seen_fault_at["can"] <= 2_000_000_000
        img = mb.image()
        st = _status(img)
        assert st["alarm"] == ALARM_STALLED and not st["status_bits"] & (1 << R.ST_RADAR_OK)
        assert bool(st["status_bits"] & (1 << R.ST_FAILSAFE)) == (presence_mode != "hold")
        assert st["frame_rate"] == 0
        hdr = R.decode_block(R.TRACK_HDR, img[R.TRACK_HEADER: R.TRACK_HEADER + 8])
        assert hdr["valid_records"] == 0  # no stale tracks
        for k in range(N_LANES):
            lane = _lane(img, k)
            assert bool(lane["live"] & 1) == expected[k]
            assert lane["live"] & (1 << R.LV_STALE)
            assert lane["ntcip_occupancy"] == R.NTCIP_OCC_WATCHDOG_FAULT
            assert lane["volume"] is not None  # the last statistics stay readable, flagged stale
    finally:
        mb.close()
        cs.close()


def test_pipeline_fault_is_persistent_error_on_can_and_alarm_on_modbus(capture):
    mb = ModbusSink(ModbusConfig(tcp_enabled=False), N_LANES, wall_clock=lambda: 0.0)
    cs = CanSink(CanConfig(interface="virtual", channel=capture.channel), N_LANES, bus_factory=capture.factory,
                 threaded=False)
    db = load_shipped()
    try:
        t = _run_frames([mb, cs], 3, T0, np.random.default_rng(1))
        capture.drain()
        for s in (mb, cs):
            s.publish(None, health(t + 10_000_000, t, state="fault"))
        assert _status(mb.image())["alarm"] == ALARM_PIPELINE
        states = [db.decode_message(0x201, m.data) for m in capture.drain() if m.arbitration_id == 0x201]
        assert states and states[-1]["RadarState_Persistent_Error"] == 1
        # recovery: the next frame clears the fault
        for s in (mb, cs):
            s.publish(make_result(4, t + HB, presence=(True, False, False)), health(t + HB, t + HB))
        assert _status(mb.image())["alarm"] == ALARM_NONE
        states = [db.decode_message(0x201, m.data) for m in capture.drain() if m.arbitration_id == 0x201]
        assert states and states[-1]["RadarState_Persistent_Error"] == 0 and states[-1]["RadarState_Temporary_Error"] == 0
    finally:
        mb.close()
        cs.close()


def test_watchdog_when_the_loop_stops_publishing(capture):
    """The loop hangs (no results, no heartbeats): the outputs' own watchdog faults them."""
    mb = ModbusSink(ModbusConfig(tcp_enabled=False), N_LANES, wall_clock=lambda: 0.0)
    cs = CanSink(CanConfig(interface="virtual", channel=capture.channel), N_LANES, bus_factory=capture.factory,
                 threaded=False)
    db = load_shipped()
    try:
        t = _run_frames([mb, cs], 3, T0, np.random.default_rng(2))
        capture.drain()
        assert not mb.watchdog(t + 900_000_000) and not cs.watchdog(t + 900_000_000)
        assert mb.watchdog(t + 1_100_000_000) and cs.watchdog(t + 1_100_000_000)
        st = _status(mb.image())
        assert st["alarm"] == ALARM_NO_PUBLISH and st["status_bits"] & (1 << R.ST_ANY_FAULT)
        frames = capture.drain()
        ids = [m.arbitration_id for m in frames]
        assert 0x201 in ids and 0x693 in ids
        pres = db.decode_message(0x693, frames[ids.index(0x693)].data)
        assert pres["Presence_Lanes"] == 0b111 and pres["Presence_Alarm"] == ALARM_NO_PUBLISH
        assert db.decode_message(0x60A, frames[ids.index(0x60A)].data)["Obj_NofObjects"] == 0
    finally:
        mb.close()
        cs.close()


def test_stats_become_stale_after_two_intervals_without_a_new_one():
    st = OutputState(1, FailsafeConfig(stats_stale_intervals=2.0))
    ls = make_lane_stats(np.random.default_rng(0), 1, seq=3, t_ns=T0)
    snap = st.update(make_result(0, T0, lane_stats=ls, presence=(False,)), health(T0, T0))
    assert snap.stats_stale == (False,) and snap.interval_seq == 3
    t = T0 + 119_000_000_000
    assert st.update(make_result(1, t, presence=(False,)), health(t, t)).stats_stale == (False,)
    t = T0 + 121_000_000_000
    assert st.update(make_result(2, t, presence=(False,)), health(t, t)).stats_stale == (True,)
