"""CAN output: shipped DBC, cantools round trip over a python-can virtual bus and a log file, an
independent ARS408 byte-level decoder, cycle framing, rate limit, counted faults, never blocking."""

from __future__ import annotations

import errno
import math
import threading
from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from edge.outputs import can_db
from edge.outputs.can_out import FRAME_BITS_WORST, CanEncoder, CanSink
from edge.outputs.config import CanConfig
from edge.outputs.registers import ars_class
from tests.edge.outputs.helpers import PERIOD_NS, health, make_lane_stats, make_result, make_tracks

T0 = 2_000_000_000
N_LANES = 4
SHIPPED = Path(can_db.__file__).with_name("radar_edge.dbc")


class Capture:
    def __init__(self, channel: str) -> None:
        self.channel = channel
        self.rx = can.Bus(interface="virtual", channel=channel)

    def factory(self):
        return can.Bus(interface="virtual", channel=self.channel)

    def drain(self) -> list[can.Message]:
        out = []
        while (m := self.rx.recv(timeout=0)) is not None:
            out.append(m)
        return out


@pytest.fixture
def cap(request):
    c = Capture(f"can-{request.node.name}")
    yield c
    c.rx.shutdown()


def test_shipped_dbc_equals_the_generated_one():
    assert SHIPPED.read_text(encoding="utf-8") == can_db.dbc_text(0), "run: radar-edge dbc --out edge/outputs/radar_edge.dbc"
    db = can_db.load_shipped()
    assert {m.frame_id for m in db.messages} == {0x201, 0x60A, 0x60B, 0x60C, 0x60D, 0x700, 0x690, 0x691, 0x692, 0x693, 0x694}
    for m in db.messages:
        spec = can_db.BY_NAME[m.name]
        assert m.length == spec.length and len(m.signals) == len(spec.signals)
        for s in m.signals:
            assert s.byte_order == "big_endian"


def test_sensor_id_offsets_stay_in_their_ranges():
    for sid in range(8):
        ids = {m.name: m.id_for(sid) for m in can_db.MESSAGES}
        assert ids["Obj_1_General"] == 0x60B + 0x10 * sid and ids["RadarState"] == 0x201 + 0x10 * sid
        assert ids["VersionID"] == 0x700 + 0x10 * sid
        lane_ids = [v for k, v in ids.items() if not can_db.BY_NAME[k].ars408]
        assert all(0x690 <= i <= 0x6FF for i in lane_ids)
        ars = [v for k, v in ids.items() if can_db.BY_NAME[k].ars408]
        assert not set(lane_ids) & set(ars)
        assert cantools.database.load_string(can_db.dbc_text(sid), database_format="dbc", strict=True)
    all_lane = [m.id_for(s) for s in range(8) for m in can_db.MESSAGES if not m.ars408]
    assert len(all_lane) == len(set(all_lane))  # sensors on one bus never collide


def _publish_frames(sink, rng, n, lanes_at=0):
    published = []
    for i in range(n):
        t = T0 + i * PERIOD_NS
        res = make_result(100 + i, t, make_tracks(rng, 12), (True, False, True, False),
                          make_lane_stats(rng, N_LANES, seq=42, t_ns=t) if i == lanes_at else ())
        sink.publish(res, health(t, t, frames=i + 1))
        published.append(res)
    return published


def _cycles(db, frames):
    """Group decoded frames into cycles the way ARS408 receivers do: 0x60A flushes, join by Obj_ID."""
    cycles, cur = [], None
    for m in frames:
        if m.arbitration_id == 0x60A:
            cur = {"hdr": db.decode_message(0x60A, m.data), "60B": {}, "60D": {}, "60C": {}, "order": []}
            cycles.append(cur)
        elif m.arbitration_id in (0x60B, 0x60C, 0x60D):
            d = db.decode_message(m.arbitration_id, m.data, decode_choices=False)
            cur[f"{m.arbitration_id:X}"][d["Obj_ID"]] = d
            cur["order"].append(m.arbitration_id)
    return cycles


def _expect_close(got, want, step):
    assert abs(got - want) <= step / 2 + 1e-6, (got, want)


def test_round_trip_through_virtual_bus_and_log_file(cap, tmp_path):
    sink = CanSink(CanConfig(interface="virtual", channel=cap.channel, send_quality=True), N_LANES,
                   bus_factory=cap.factory, threaded=False, wall_clock=lambda: 1.75e9)
    try:
        published = _publish_frames(sink, np.random.default_rng(21), 5)
    finally:
        sink.close()
    frames = cap.drain()
    assert sink.faults.total() == 0 and sink.sent == len(frames)
    log_path = tmp_path / "cycle.log"
    with can.Logger(str(log_path)) as logger:
        for m in frames:
            logger.on_message_received(m)
    replayed = list(can.LogReader(str(log_path)))
    assert [(m.arbitration_id, bytes(m.data)) for m in replayed] == [(m.arbitration_id, bytes(m.data)) for m in frames]

    db = can_db.load_shipped()
    for source in (frames, replayed):
        cycles = _cycles(db, source)
        assert len(cycles) == len(published)
        for cyc, res in zip(cycles, published):
            assert cyc["hdr"]["Obj_MeasCounter"] == res.seq and cyc["hdr"]["Obj_NofObjects"] == len(res.tracks)
            order = cyc["order"]
            assert order == sorted(order)  # all 60B, then 60C, then 60D: the cycle is never interleaved
            assert len(cyc["60B"]) == len(cyc["60D"]) == len(cyc["60C"]) == len(res.tracks)
            for t in res.tracks:
                g, x = cyc["60B"][t.track_id], cyc["60D"][t.track_id]
                _expect_close(g["Obj_DistLong"], t.y_m, 0.2)
                _expect_close(g["Obj_DistLat"], -t.x_m, 0.2)
                _expect_close(g["Obj_VrelLong"], t.vy_mps, 0.25)
                _expect_close(g["Obj_VrelLat"], -t.vx_mps, 0.25)
                # not measured: raw 0 (declared not_measured in the DBC), never a plausible 0 dBm2
                _expect_close(g["Obj_RCS"], t.rcs_dbsm if t.rcs_dbsm is not None else -64.0, 0.5)
                assert x["Obj_Class"] == ars_class(t.cls)
                _expect_close(x["Obj_Length"], t.length_m if t.length_m is not None else 0.0, 0.2)
                assert x["Obj_Width"] == 0.0  # not measured
    # lane statistics of the closed interval
    by_id = {}
    for m in frames:
        if 0x690 <= m.arbitration_id <= 0x694:
            by_id.setdefault(m.arbitration_id, []).append(db.decode_message(m.arbitration_id, m.data, decode_choices=False))
    assert len(by_id[0x690]) == len(by_id[0x691]) == len(by_id[0x692]) == N_LANES
    assert len(by_id[0x693]) == len(published) and len(by_id[0x694]) == 1
    assert by_id[0x694][0]["Interval_Sequence"] == 42 and by_id[0x694][0]["Interval_UnixTime"] == 1750000000
    for a, b, c, ls in zip(by_id[0x690], by_id[0x691], by_id[0x692], published[0].lane_stats):
        assert a["LaneA_Lane"] == b["LaneB_Lane"] == c["LaneC_Lane"] == ls.lane + 1
        assert a["LaneA_Volume"] == ls.volume and a["LaneA_Sequence"] == 42
        _expect_close(a["LaneA_Occupancy"], ls.occupancy_pct, 0.01)
        for got, want, step in ((a["LaneA_MeanSpeed"], ls.mean_speed_kmh, 0.1), (b["LaneB_SpeedP85"], ls.speed_p85_kmh, 0.1),
                                (b["LaneB_Headway"], ls.headway_s, 0.01), (b["LaneB_Gap"], ls.gap_s, 0.01)):
            if math.isnan(want) or (ls.volume == 0 and step == 0.1 and got == a["LaneA_MeanSpeed"]):
                assert got == pytest.approx(6553.5 if step == 0.1 else 655.35)  # all ones = n/a
            else:
                _expect_close(got, want, step)
        assert c["LaneC_Car"] == ls.class_counts["car"] and c["LaneC_TruckBus"] == ls.class_counts["truck"] + ls.class_counts["bus"]
        assert c["LaneC_Other"] == ls.class_counts["van"]
    assert all(p["Presence_Lanes"] == 0b0101 and p["Presence_Failsafe"] == 0 for p in by_id[0x693])


def _ars408_decode(arb_id: int, d: bytes) -> dict:
    """A public-decoder-style ARS408 parser written from the byte tables, independent of cantools."""
    if arb_id == 0x60A:
        return {"n": d[0], "counter": (d[1] << 8) | d[2], "iface": d[3] >> 4}
    if arb_id == 0x60B:
        return {"id": d[0], "dist_long": ((d[1] << 5) | (d[2] >> 3)) * 0.2 - 500.0,
                "dist_lat": (((d[2] & 0x07) << 8) | d[3]) * 0.2 - 204.6,
                "vrel_long": ((d[4] << 2) | (d[5] >> 6)) * 0.25 - 128.0,
                "vrel_lat": (((d[5] & 0x3F) << 3) | (d[6] >> 5)) * 0.25 - 64.0,
                "dyn_prop": d[6] & 0x07, "rcs": d[7] * 0.5 - 64.0}
    if arb_id == 0x60D:
        return {"id": d[0], "cls": d[3] & 0x07, "length": d[6] * 0.2, "width": d[7] * 0.2}
    raise KeyError(arb_id)


def test_an_independent_ars408_decoder_reads_our_object_list():
    enc = CanEncoder(CanConfig(interface="virtual", max_bus_load=0.9))
    from edge.outputs.state import OutputState

    st = OutputState(2)
    tracks = make_tracks(np.random.default_rng(8), 20)
    snap = st.update(make_result(0x1A2B, T0, tracks, (False, False)), health(T0, T0))
    frames = enc.frames(snap, T0)
    objs = [m for m in frames if m.arbitration_id in (0x60A, 0x60B, 0x60D)]
    hdr = _ars408_decode(0x60A, bytes(objs[0].data))
    assert objs[0].arbitration_id == 0x60A and hdr == {"n": 20, "counter": 0x1A2B, "iface": 1}
    by_id = {t.track_id: t for t in tracks}
    for m in objs[1:]:
        d = _ars408_decode(m.arbitration_id, bytes(m.data))
        t = by_id[d["id"]]
        if m.arbitration_id == 0x60B:
            _expect_close(d["dist_long"], t.y_m, 0.2)
            _expect_close(d["dist_lat"], -t.x_m, 0.2)
            _expect_close(d["vrel_long"], t.vy_mps, 0.25)
            _expect_close(d["vrel_lat"], -t.vx_mps, 0.25)
            assert d["dyn_prop"] in (0, 1, 2, 6)
            if abs(t.vy_mps) > abs(t.vx_mps) and math.hypot(t.vx_mps, t.vy_mps) > 0.5:
                assert d["dyn_prop"] == (2 if t.vy_mps < 0 else 0)  # oncoming when approaching
        else:
            assert d["cls"] == ars_class(t.cls)


def test_rate_limit_keeps_bus_load_below_half_and_truncates_far_objects():
    cfg = CanConfig(interface="virtual", send_quality=True, send_extended=True, max_bus_load=0.5, bitrate=500_000)
    enc = CanEncoder(cfg)
    from edge.outputs.state import OutputState

    st = OutputState(N_LANES)
    rng = np.random.default_rng(4)
    period = 50_000_000  # 20 Hz, 200 objects x 3 messages: far above the budget
    total, seconds = 0, 5.0
    n = int(seconds * 1e9 / period)
    per_cycle = []
    for i in range(n):
        t = T0 + i * period
        tracks = make_tracks(rng, 200)
        lanes = make_lane_stats(rng, N_LANES, seq=i, t_ns=t) if i % 20 == 0 else ()
        frames = enc.frames(st.update(make_result(i, t, tracks, (True,) * N_LANES, lanes), health(t, t)), t)
        total += len(frames)
        per_cycle.append(len(frames))
        objs = [m for m in frames if m.arbitration_id == 0x60B]
        hdr = next(m for m in frames if m.arbitration_id == 0x60A)
        assert hdr.data[0] == len(objs)  # header announces exactly what follows
        if objs:  # nearest first: what was left out is farther than what was sent
            sent_ids = {m.data[0] for m in objs}
            sent = [t_ for t_ in tracks if t_.track_id & 0xFF in sent_ids]
            left = [t_ for t_ in tracks if t_.track_id & 0xFF not in sent_ids]
            if left:
                assert max(t_.range_m for t_ in sent) <= min(t_.range_m for t_ in left) + 1e-6
    load = total * FRAME_BITS_WORST / (seconds * cfg.bitrate)
    assert 0.3 < load < 0.5, load  # the budget is used, never exceeded
    per_s = int(1e9 / period)
    worst = max(sum(per_cycle[i: i + per_s]) for i in range(len(per_cycle) - per_s + 1))
    assert worst * FRAME_BITS_WORST / cfg.bitrate < 0.5  # in every 1 s window, including the first
    assert enc.counters["objects_truncated"] > 0


class FailingBus:
    def __init__(self, error_code: int | None, fail_times: int = 10**9) -> None:
        self.error_code, self.fail_times, self.sent = error_code, fail_times, []

    def send(self, msg, timeout=None):
        if self.fail_times > 0:
            self.fail_times -= 1
            raise can.CanOperationError("send failed", error_code=self.error_code)
        self.sent.append(msg)

    def shutdown(self):
        pass


def test_missing_interface_is_a_counted_fault_retried_later():
    attempts = []

    def factory():
        attempts.append(1)
        raise can.CanInterfaceNotImplementedError("no such interface")

    sink = CanSink(CanConfig(interface="socketcan", channel="can9", reconnect_s=2.0), 1, bus_factory=factory,
                   threaded=False)
    for i in range(10):  # 10 frames in 0.33 s: one attempt only
        t = T0 + i * PERIOD_NS
        sink.publish(make_result(i, t, presence=(False,)), health(t, t))
    assert len(attempts) == 1 and sink.faults["open_failed"] == 1 and sink.faults["frames_not_sent"] > 0
    t = T0 + 2_100_000_000
    sink.publish(make_result(99, t, presence=(False,)), health(t, t))
    assert len(attempts) == 2 and not sink.links.can_up
    sink.close()


@pytest.mark.parametrize("code,kind", [(errno.ENOBUFS, "enobufs"), (errno.ENETDOWN, "bus_off"), (None, "send_error")])
def test_send_errors_are_counted_and_never_raise(code, kind):
    bus = FailingBus(code, fail_times=1)
    opened = []

    def factory():
        opened.append(1)
        return bus

    sink = CanSink(CanConfig(interface="socketcan", reconnect_s=1.0), 2, bus_factory=factory, threaded=False)
    for i in range(3):
        t = T0 + i * PERIOD_NS
        sink.publish(make_result(i, t, make_tracks(np.random.default_rng(i), 4), (True, False)), health(t, t))
    assert sink.faults[kind] == 1 and sink.faults["frames_not_sent"] > 0
    if kind == "enobufs":  # the bus stays; only the rest of that cycle is dropped
        assert len(opened) == 1 and bus.sent and bus.sent[0].arbitration_id == 0x693
    else:  # bus off / error: closed, nothing sent until reconnect_s, then reopened
        assert len(opened) == 1 and sink.bus is None and not bus.sent
        t = T0 + 1_200_000_000
        sink.publish(make_result(50, t, presence=(True, False)), health(t, t))
        assert len(opened) == 2 and bus.sent
    sink.close()


def test_publish_never_waits_for_a_stuck_bus():
    release = threading.Event()
    entered = threading.Event()

    class StuckBus:
        def send(self, msg, timeout=None):
            entered.set()
            release.wait(30)

        def shutdown(self):
            pass

    sink = CanSink(CanConfig(interface="socketcan", queue_frames=4), 1, bus_factory=StuckBus).start()
    try:
        t = T0
        sink.publish(make_result(0, t, presence=(False,)), health(t, t))
        assert entered.wait(10)  # the sender thread is now stuck inside send()
        for i in range(1, 50):  # would hang here if publish waited on the bus
            t = T0 + i * PERIOD_NS
            sink.publish(make_result(i, t, presence=(False,)), health(t, t))
        assert sink.faults["queue_overflow"] >= 45 - 4
    finally:
        release.set()
        sink.close()


def test_runtime_settings_from_modbus_apply_on_the_next_cycle(cap):
    sink = CanSink(CanConfig(interface="virtual", channel=cap.channel), 1, bus_factory=cap.factory, threaded=False)
    try:
        tracks = make_tracks(np.random.default_rng(0), 3)
        sink.publish(make_result(1, T0, tracks, (True,)), health(T0, T0))
        assert {0x60B, 0x60D} <= {m.arbitration_id for m in cap.drain()}
        sink.set_runtime(True, 2, 0b11001)  # sensor id 2, objects + lane stats + presence, no 60C/60D
        t = T0 + PERIOD_NS
        sink.publish(make_result(2, t, tracks, (True,)), health(t, t))
        ids = {m.arbitration_id for m in cap.drain()}
        assert 0x62B in ids and 0x62A in ids and 0x62D not in ids and 0x60B not in ids and 0x6A3 in ids
        sink.set_runtime(False, 2, 0b11001)
        t += PERIOD_NS
        sink.publish(make_result(3, t, tracks, (True,)), health(t, t))
        assert cap.drain() == []
    finally:
        sink.close()


def test_numpy_scalars_and_nan_from_pipelines_encode():
    from edge.outputs.state import OutputState
    from edge.types import LaneStats

    enc = CanEncoder(CanConfig(interface="virtual"))
    st = OutputState(1)
    ls = LaneStats(0, 0, np.float32(60.0), 4, np.int64(3), np.float32(12.5), np.float32("nan"), np.float32(88.0),
                   np.float32("nan"), np.float32(1.5), {"car": np.int64(3)})
    frames = enc.frames(st.update(make_result(1, T0, presence=(True,), lane_stats=(ls,)), health(T0, T0)), T0)
    db = can_db.load_shipped()
    a = next(db.decode_message(m.arbitration_id, m.data) for m in frames if m.arbitration_id == 0x690)
    b = next(db.decode_message(m.arbitration_id, m.data) for m in frames if m.arbitration_id == 0x691)
    assert a["LaneA_Volume"] == 3 and a["LaneA_Occupancy"] == pytest.approx(12.5)
    assert a["LaneA_MeanSpeed"] == pytest.approx(6553.5) and b["LaneB_Headway"] == pytest.approx(655.35)  # n/a
    assert b["LaneB_SpeedP85"] == pytest.approx(88.0) and b["LaneB_Gap"] == pytest.approx(1.5)


# --- what an ARS408 consumer reads: quality, RCS, class, size ------------------------------------------------
# The public ARS408 object layout (DBC start bit = MSB in the sawtooth numbering, length, scale, offset), typed in
# from the message tables of the public ARS408 DBC, NOT read from our DBC: a consumer's decoder is built this way.
ARS408_LAYOUT = {
    0x60A: {"NofObjects": (7, 8), "MeasCounter": (15, 16), "InterfaceVersion": (31, 4)},
    0x60B: {"ID": (7, 8), "DistLong": (15, 13, 0.2, -500.0), "DistLat": (18, 11, 0.2, -204.6),
            "VrelLong": (39, 10, 0.25, -128.0), "VrelLat": (45, 9, 0.25, -64.0), "DynProp": (50, 3),
            "RCS": (63, 8, 0.5, -64.0)},
    0x60C: {"ID": (7, 8), "DistLong_rms": (15, 5), "DistLat_rms": (10, 5), "VrelLong_rms": (21, 5),
            "VrelLat_rms": (16, 5), "ArelLong_rms": (27, 5), "ArelLat_rms": (38, 5), "Orientation_rms": (33, 5),
            "MeasState": (52, 3), "ProbOfExist": (55, 3)},
    0x60D: {"ID": (7, 8), "ArelLong": (15, 11, 0.01, -10.0), "ArelLat": (20, 9, 0.01, -2.5), "Class": (26, 3),
            "OrientationAngle": (39, 10, 0.4, -180.0), "Length": (55, 8, 0.2, 0.0), "Width": (63, 8, 0.2, 0.0)},
}
#: the public DBC's rms code labels: code k means "sd < this" (m, m/s, m/s^2), 31 invalid
ARS408_RMS_LABELS = (0.005, 0.006, 0.008, 0.011, 0.014, 0.018, 0.023, 0.029, 0.038, 0.049, 0.063, 0.081, 0.105, 0.135,
                     0.174, 0.224, 0.288, 0.371, 0.478, 0.616, 0.794, 1.023, 1.317, 1.697, 2.187, 2.817, 3.630, 4.676,
                     6.025, 7.762, 10.000)
ARS408_ORIENTATION_RMS_LABELS_DEG = (0.005, 0.007, 0.010, 0.014, 0.020, 0.029, 0.041, 0.058, 0.082, 0.116, 0.165,
                                     0.234, 0.332, 0.471, 0.669, 0.949, 1.346, 1.909, 2.709, 3.843, 5.451, 7.734,
                                     10.971, 15.565, 22.081, 31.325, 44.439, 63.044, 89.437, 126.881, 180.000)
#: Obj_ProbOfExist: code k (1..7) means "probability < this" (7: <= 100 %), 0 invalid
ARS408_PROB_OF_EXIST_UPPER = {1: 0.25, 2: 0.50, 3: 0.75, 4: 0.90, 5: 0.99, 6: 0.999, 7: 1.0}
#: Obj_Class: 0 point, 1 car, 2 truck, 3 pedestrian, 4 motorcycle, 5 bicycle, 6 wide
ARS408_CLASS = {None: 0, "car": 1, "truck": 2, "bus": 2, "pedestrian": 3, "motorcycle": 4, "bicycle": 5}


def _motorola(data: bytes, start: int, length: int) -> int:
    """Raw value of a Motorola signal whose MSB is DBC bit ``start`` (bit 7 of byte 0 = 7, bit 0 of byte 1 = 8):
    bits are read MSB first, down a byte and on to bit 7 of the next byte."""
    value, bit = 0, start
    for _ in range(length):
        byte, pos = divmod(bit, 8)
        value = (value << 1) | ((data[byte] >> pos) & 1)
        bit = bit - 1 if pos else bit + 15
    return value


def _ars408_signals(arb_id: int, data: bytes) -> dict:
    out = {}
    for name, (start, length, *lin) in ARS408_LAYOUT[arb_id].items():
        raw = _motorola(data, start, length)
        out[name] = raw if not lin else raw * lin[0] + lin[1]
        out[name + "_raw"] = raw
    return out


def _ars408_cycles(frames) -> list[dict]:
    """Cycles as ARS408 receivers assemble them: 0x60A flushes, 0x60B/C/D joined by object id."""
    cycles = []
    for m in frames:
        if m.arbitration_id == 0x60A:
            cycles.append({"hdr": _ars408_signals(0x60A, bytes(m.data)), 0x60B: {}, 0x60C: {}, 0x60D: {}})
        elif m.arbitration_id in (0x60B, 0x60C, 0x60D) and cycles:
            d = _ars408_signals(m.arbitration_id, bytes(m.data))
            cycles[-1][m.arbitration_id][d["ID"]] = d
    return cycles


#: The consumer's filter. ARS408's own object filter (FilterCfg 0x202, criterion 8 "probability of existence") and
#: the drivers that expose ProbOfExist keep objects by it; 99 % is the usual cut (code >= 6: "<99.9 %" or "<=100 %",
#: both meaning at least 99 %). A consumer that fuses by covariance also needs valid standard deviations: every
#: position and velocity rms code must be a value (not 31, "invalid"), i.e. below 10 m and 10 m/s.
def _ars408_driver_keeps(obj: dict) -> bool:
    q = obj[0x60C]
    return (q["ProbOfExist"] >= 6
            and all(q[k] != 31 for k in ("DistLong_rms", "DistLat_rms", "VrelLong_rms", "VrelLat_rms")))


def test_the_layout_decoder_agrees_with_the_byte_arithmetic_one():
    enc = CanEncoder(CanConfig(interface="virtual", max_bus_load=0.9))
    from edge.outputs.state import OutputState

    tracks = make_tracks(np.random.default_rng(3), 20)
    frames = enc.frames(OutputState(1).update(make_result(7, T0, tracks, (False,)), health(T0, T0)), T0)
    n = 0
    for m in frames:
        if m.arbitration_id in (0x60A, 0x60B, 0x60D):
            a, b = _ars408_decode(m.arbitration_id, bytes(m.data)), _ars408_signals(m.arbitration_id, bytes(m.data))
            if m.arbitration_id == 0x60B:
                assert (a["id"], a["dyn_prop"]) == (b["ID"], b["DynProp"])
                for k, j in (("dist_long", "DistLong"), ("dist_lat", "DistLat"), ("vrel_long", "VrelLong"),
                             ("vrel_lat", "VrelLat"), ("rcs", "RCS")):
                    assert a[k] == pytest.approx(b[j])
                n += 1
            elif m.arbitration_id == 0x60D:
                assert (a["id"], a["cls"]) == (b["ID"], b["Class"])
                assert a["length"] == pytest.approx(b["Length"]) and a["width"] == pytest.approx(b["Width"])
    assert n == 20


def test_rms_codes_are_ars408s_table():
    from edge.outputs.can_db import ORIENTATION_RMS_BOUNDS_DEG, RMS_BOUNDS, rms_code

    assert [round(b, 3) for b in RMS_BOUNDS] == list(ARS408_RMS_LABELS)
    assert [round(b, 3) for b in ORIENTATION_RMS_BOUNDS_DEG] == list(ARS408_ORIENTATION_RMS_LABELS_DEG)
    for k, bound in enumerate(RMS_BOUNDS):  # the first code whose (unrounded) bound exceeds the sd
        assert rms_code(bound * 0.999) == k
        assert rms_code(bound * 1.001) == k + 1  # (31 above 10 m: not representable, so "invalid")
    assert rms_code(0.0) == 0 and rms_code(0.3) == 17 and rms_code(1.0) == 21
    assert rms_code(2.0, ORIENTATION_RMS_BOUNDS_DEG) == 18
    for unknown in (None, float("nan"), float("inf"), 10.0, 25.0):
        assert rms_code(unknown) == 31


def test_prob_of_exist_codes_are_ars408s_table():
    from edge.outputs.can_db import prob_of_exist_code

    for code, upper in ARS408_PROB_OF_EXIST_UPPER.items():
        lower = 0.0 if code == 1 else ARS408_PROB_OF_EXIST_UPPER[code - 1]
        assert prob_of_exist_code(lower) == code  # each class holds its lower bound ...
        assert prob_of_exist_code((lower + upper) / 2) == code
    assert prob_of_exist_code(0.99) == 6 and prob_of_exist_code(0.9899) == 5 and prob_of_exist_code(1.0) == 7
    for unknown in (None, float("nan"), -0.1, 1.5):
        assert prob_of_exist_code(unknown) == 0


def _one_track(**kw) -> "TrackState":
    from edge.types import TrackState

    base = dict(track_id=9, x_m=-3.5, y_m=120.0, vx_mps=0.3, vy_mps=-25.0, range_m=120.05, radial_speed_mps=-25.0,
                az_rad=-0.029, age_frames=40, hits=35)
    return TrackState(**{**base, **kw})


def _objects(tracks, **cfg) -> dict[int, dict]:
    from edge.outputs.state import OutputState

    enc = CanEncoder(CanConfig(interface="virtual", send_quality=True, max_bus_load=0.9, **cfg))
    frames = enc.frames(OutputState(1).update(make_result(1, T0, tracks, (False,)), health(T0, T0)), T0)
    (cyc,) = _ars408_cycles(frames)
    return {i: {k: cyc[k][i] for k in (0x60B, 0x60C, 0x60D) if i in cyc[k]} for i in cyc[0x60B]}


def test_quality_codes_come_from_the_track_covariance_and_existence():
    """Before: every track had ProbOfExist 0 and every rms code 31, and an ARS408 driver dropped it."""
    t = _one_track(x_sd_m=0.4, y_sd_m=0.12, vx_sd_mps=0.9, vy_sd_mps=0.25, existence_probability=0.9999)
    q = _objects([t])[9][0x60C]
    assert q["ProbOfExist"] == 7  # >= 99.9 %
    # DistLong is y and DistLat -x: each code is the first whose bound exceeds that coordinate's sd
    assert (q["DistLong_rms"], q["DistLat_rms"], q["VrelLong_rms"], q["VrelLat_rms"]) == (13, 18, 16, 21)
    assert ARS408_RMS_LABELS[q["DistLat_rms"] - 1] <= 0.4 < ARS408_RMS_LABELS[q["DistLat_rms"]]
    assert q["ArelLong_rms"] == q["ArelLat_rms"] == 31  # no acceleration estimate: invalid
    # heading sd bound: (|vy| sd_vx + |vx| sd_vy) / |v|^2 = (25 x 0.9 + 0.3 x 0.25) / 625.09 rad = 2.07 deg
    assert ARS408_ORIENTATION_RMS_LABELS_DEG[q["Orientation_rms"] - 1] <= 2.07 < ARS408_ORIENTATION_RMS_LABELS_DEG[q["Orientation_rms"]]
    assert q["MeasState"] == 2 and _ars408_driver_keeps({0x60C: q})
    # a track without estimates says so: invalid codes, never a made-up accuracy
    q = _objects([_one_track()])[9][0x60C]
    assert q["ProbOfExist"] == 0 and {q[k] for k in q if k.endswith("_rms")} == {31}
    q = _objects([_one_track(vx_mps=0.1, vy_mps=0.2, x_sd_m=0.4, y_sd_m=0.12, vx_sd_mps=0.9, vy_sd_mps=0.25)])[9][0x60C]
    assert q["Orientation_rms"] == 31  # standing: no heading


def test_rcs_length_and_width_send_not_measured_instead_of_plausible_values():
    """Before: RCS 0 dBm2 (raw 128) and length/width 0 for every lane track, read as measured values."""
    objs = _objects([_one_track(track_id=1), _one_track(track_id=2, rcs_dbsm=12.3, length_m=4.6),
                     _one_track(track_id=3, rcs_dbsm=-80.0, length_m=0.02)])
    g, x = objs[1][0x60B], objs[1][0x60D]
    assert g["RCS_raw"] == 0 and x["Length_raw"] == 0 and x["Width_raw"] == 0  # declared not_measured in our DBC
    assert objs[2][0x60B]["RCS"] == pytest.approx(12.5) and objs[2][0x60D]["Length"] == pytest.approx(4.6)
    assert objs[2][0x60D]["Width_raw"] == 0  # no track measures a width
    # a measured value never lands on the not-measured code
    assert objs[3][0x60B]["RCS_raw"] == 1 and objs[3][0x60D]["Length_raw"] == 1
    db = can_db.load_shipped()
    for msg, sig in (("Obj_1_General", "Obj_RCS"), ("Obj_3_Extended", "Obj_Length"), ("Obj_3_Extended", "Obj_Width")):
        assert db.get_message_by_name(msg).get_signal_by_name(sig).choices == {0: "not_measured"}


@pytest.mark.parametrize("cls,code", [("motorcycle", 4), ("car", 1), ("truck", 2), ("bus", 2), ("pedestrian", 3),
                                      ("bicycle", 5), (None, 0), ("van", 0)])
def test_object_class_is_ars408s_enum(cls, code):
    """The lane profile's length classes and the surveillance classes; unclassified is 0 (point)."""
    assert ars_class(cls) == code
    assert _objects([_one_track(cls=cls)])[9][0x60D]["Class"] == code


def test_an_ars408_driver_keeps_every_confirmed_track_of_the_lane_pipeline(cap):
    """highway4-traffic through the lane pipeline and the CAN sink onto a virtual bus, decoded with the layout
    decoder above and filtered as an ARS408 driver does (_ars408_driver_keeps): every confirmed track of every
    frame is kept, with its position, velocity, class and length."""
    from edge.pipeline import StageTimer
    from tests.edge.lane_golden import build

    pipe, frames = build("highway4-traffic", 8123, 5.0)
    timer = StageTimer(16)
    sink = CanSink(CanConfig(interface="virtual", channel=cap.channel, send_quality=True), 4,
                   bus_factory=cap.factory, threaded=False, wall_clock=lambda: 1.75e9)
    results = []
    try:
        for f in frames(120):
            res = pipe.process(f, timer)
            results.append(res)
            sink.publish(res, health(res.t_ns, res.t_ns, frames=len(results)))
    finally:
        sink.close()
    assert sink.faults.total() == 0 and sink.encoder.counters["objects_truncated"] == 0
    cycles = _ars408_cycles(cap.drain())
    assert len(cycles) == len(results)
    kept = total = 0
    for cyc, res in zip(cycles, results):
        assert cyc["hdr"]["NofObjects"] == len(res.tracks) and cyc["hdr"]["MeasCounter"] == res.seq & 0xFFFF
        objs = {i: {k: cyc[k][i] for k in (0x60B, 0x60C, 0x60D)} for i in cyc[0x60B]}
        for t in res.tracks:
            assert t.confirmed
            total += 1
            o = objs[t.track_id & 0xFF]
            kept += _ars408_driver_keeps(o)
            assert o[0x60B]["DistLong"] == pytest.approx(t.y_m, abs=0.1 + 1e-6)
            assert o[0x60B]["DistLat"] == pytest.approx(-t.x_m, abs=0.1 + 1e-6)
            assert o[0x60B]["VrelLong"] == pytest.approx(t.vy_mps, abs=0.125 + 1e-6)
            assert o[0x60D]["Class"] == ARS408_CLASS.get(t.cls, 0)
            want_len = 0.0 if t.length_m is None else min(max(t.length_m, 0.2), 51.0)
            assert o[0x60D]["Length"] == pytest.approx(want_len, abs=0.1 + 1e-6)
            assert o[0x60D]["Width_raw"] == 0 and o[0x60B]["RCS_raw"] == 0  # not measured
            q = o[0x60C]  # the codes bound the track's own standard deviations
            for code, sd in ((q["DistLong_rms"], t.y_sd_m), (q["DistLat_rms"], t.x_sd_m),
                             (q["VrelLong_rms"], t.vy_sd_mps), (q["VrelLat_rms"], t.vx_sd_mps)):
                assert (0.0 if code == 0 else ARS408_RMS_LABELS[code - 1]) - 5e-4 <= sd < ARS408_RMS_LABELS[code] + 5e-4
    assert total > 500 and len({t.track_id for r in results for t in r.tracks}) >= 10
    assert kept == total



def test_a_backend_refusing_a_message_is_a_counted_fault_not_a_dead_sender():
    """python-can's serial framing raises ValueError for a timestamp it cannot pack; before, any such error ended
    the sender thread and CAN output stopped for good."""
    class RefusingBus(FailingBus):
        def send(self, msg, timeout=None):
            if self.fail_times > 0:
                self.fail_times -= 1
                raise ValueError("Timestamp is out of range")
            self.sent.append(msg)

    bus = RefusingBus(None, fail_times=1)
    sink = CanSink(CanConfig(interface="serial", reconnect_s=1.0), 1, bus_factory=lambda: bus, threaded=False)
    sink.publish(make_result(0, T0, presence=(True,)), health(T0, T0))
    assert sink.faults["send_error"] == 1 and not bus.sent
    t = T0 + 1_100_000_000
    sink.publish(make_result(1, t, presence=(True,)), health(t, t))
    assert bus.sent
    sink.close()
