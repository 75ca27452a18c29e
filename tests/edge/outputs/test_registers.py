"""The register table: invariants, encoding, the image builder against the published state, docs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.outputs import registers as R
from edge.outputs.state import OutputState
from tests.edge.outputs.helpers import PERIOD_NS, health, make_lane_stats, make_result, make_tracks, wrong_way

T0 = 10_000_000_000


def test_blocks_do_not_overlap_and_fit_their_size():
    used: dict[int, str] = {}
    for block, inst, reg, addr in R.iter_registers():
        assert 0 <= reg.offset and reg.offset + reg.size <= block.size, f"{block.name}.{reg.name} outside its block"
        for a in range(addr, addr + reg.size):
            assert a not in used, f"{block.name}[{inst}].{reg.name} overlaps {used[a]} at {a}"
            used[a] = f"{block.name}[{inst}].{reg.name}"
    spans = sorted((b.base, b.end, b.name) for b in R.BLOCKS)
    for (a0, e0, n0), (a1, _, n1) in zip(spans, spans[1:]):
        assert e0 <= a1, f"blocks {n0} and {n1} overlap"
    assert max(used) < R.IMAGE_SIZE


def test_every_register_is_served_and_blocks_fit_one_read_where_promised():
    for _, _, reg, addr in R.iter_registers():
        assert any(a <= addr and addr + reg.size <= b for a, b in R.READ_RANGES), f"{reg.name} at {addr} not served"
    for block in (R.IDENT, R.STATUS, R.LANE, R.TRACK_HDR, R.TRACK):
        assert block.size <= 125  # one FC3/FC4 read per block instance
    assert R.TRACK_BASE - R.TRACK_HEADER + 14 * R.TRACK_RECORD <= 125  # header + 14 records in one read


def test_scaling_units_and_na_are_documented():
    doc = R.markdown()
    for block, _, reg, addr in R.iter_registers():
        if block.repeat > 1 and addr != block.address(reg, 0):
            continue
        assert reg.doc, reg.name
        if reg.scale != 1.0:
            assert reg.unit, f"{reg.name} is scaled but has no unit"
            assert f"x {reg.scale:g} {reg.unit}" in doc
        assert f"| {reg.name} |" in doc
        assert f"| {addr} " in doc or f"| {addr}-{addr + 1} " in doc
        assert f"| {30001 + addr} | {40001 + addr} |" in doc
    for code in ("0xFFFF", "0x8000", "0xFFFFFFFF", "high word first"):
        assert code in doc


def test_writable_registers_are_only_in_the_configuration_block():
    for block, _, reg, _ in R.iter_registers():
        if reg.writable:
            assert block is R.CONFIG and reg.lo is not None and reg.hi is not None
    assert not any(b.writable for b in R.BLOCKS if b is not R.CONFIG)


def test_word_order_and_32_bit_encoding():
    reg = R.IDENT.regs[2]
    assert R.encode(reg, R.WORD_ORDER_TEST) == [0x1234, 0x5678]
    assert R.decode(reg, [0x1234, 0x5678]) == 0x12345678


@pytest.mark.parametrize("kind,na", [("u16", 0xFFFF), ("s16", 0x8000), ("u32", None)])
def test_not_available_and_saturation(kind, na):
    reg = R.Reg("x", 0, kind, "test", "m", 0.1)
    words = R.encode(reg, float("nan"))
    assert words == ([na] if na is not None else [0xFFFF, 0xFFFF])
    assert R.decode(reg, words) is None
    big = R.encode(reg, 1e12)
    assert R.decode(reg, big) is not None  # saturates below the n/a code
    if kind == "s16":
        assert R.decode(reg, R.encode(reg, -1e12)) == pytest.approx(-3276.7)


@settings(max_examples=300, deadline=None)
@given(kind=st.sampled_from(["u16", "s16", "u32"]), scale=st.sampled_from([1.0, 0.1, 0.01]),
       raw=st.integers(min_value=-40000, max_value=70000))
def test_encode_decode_round_trip(kind, scale, raw):
    reg = R.Reg("x", 0, kind, "test", "u", scale)
    lo, hi = {"u16": (0, 0xFFFE), "s16": (-0x7FFF, 0x7FFF), "u32": (0, 0xFFFFFFFE)}[kind]
    value = raw * scale
    got = R.decode(reg, R.encode(reg, value))
    assert got == pytest.approx(min(max(raw, lo), hi) * scale)


def _decode_instance(img, block, k=0):
    a = block.base + k * block.stride
    return R.decode_block(block, img[a: a + block.size])


def test_image_equals_the_published_state():
    rng = np.random.default_rng(7)
    n_lanes = 4
    st_ = OutputState(n_lanes)
    b = R.ImageBuilder(n_lanes, serial_number=123456, wall_clock=lambda: 1.7e9, temperature=lambda: 48.3)
    tracks = make_tracks(rng, 40)
    lanes = make_lane_stats(rng, n_lanes, seq=17)
    res = make_result(4242, T0, tracks, (True, False, True, False), lanes, events=(wrong_way(5, 2, T0),))
    img = b.build(st_.update(res, health(T0, T0, frames=4242)))

    ident = _decode_instance(img, R.IDENT)
    assert ident["magic"] == 0x5452 and ident["word_order_test"] == 0x12345678
    assert ident["serial_number"] == 123456 and ident["lanes"] == n_lanes and ident["device_type"] == 2

    status = _decode_instance(img, R.STATUS)
    assert status["frame_counter"] == 4242 and status["alarm"] == 0
    assert status["status_bits"] & (1 << R.ST_RADAR_OK) and not status["status_bits"] & (1 << R.ST_ANY_FAULT)
    assert status["track_count"] == R.TRACK_SLOTS and status["interval_seq"] == 17
    assert status["temperature"] == pytest.approx(48.3) and status["supply_voltage"] is None
    assert status["frame_p99"] == pytest.approx(7.2, abs=0.051) and status["budget"] == pytest.approx(33.0)
    assert status["dropped_frames"] == 3 and status["loop_state"] == 1

    for k, ls in enumerate(lanes):
        lane = _decode_instance(img, R.LANE, k)
        assert lane["lane_id"] & 0xFF == k + 1
        assert lane["volume"] == ls.volume
        assert lane["occupancy"] == pytest.approx(ls.occupancy_pct, abs=0.005)
        assert lane["ntcip_occupancy"] == min(200, round(ls.occupancy_pct * 2))
        assert lane["ntcip_volume"] == min(ls.volume, 255)
        for name, value in (("mean_speed", ls.mean_speed_kmh), ("speed_p85", ls.speed_p85_kmh)):
            if ls.volume == 0 or math.isnan(value):
                assert lane[name] is None
            else:
                assert lane[name] == pytest.approx(value, abs=0.05)
        assert lane["count_car"] == ls.class_counts["car"]
        assert lane["count_truck_bus"] == ls.class_counts["truck"] + ls.class_counts["bus"]
        assert lane["count_other"] == ls.class_counts["van"]
        assert lane["interval_seq"] == 17 and lane["cumulative_volume"] == ls.volume
        assert bool(lane["live"] & 1) == (True, False, True, False)[k]
        assert bool(lane["live"] & (1 << R.LV_WRONG_WAY)) == (k == 2)
        assert not lane["live"] & (1 << R.LV_STALE)
    for k in range(n_lanes, R.MAX_LANES):  # unconfigured lanes read n/a
        assert _decode_instance(img, R.LANE, k)["volume"] is None

    hdr = _decode_instance(img, R.TRACK_HDR)
    assert hdr["frame_counter"] == 4242 and hdr["valid_records"] == R.TRACK_SLOTS
    expected = sorted(tracks, key=lambda t: t.range_m)[: R.TRACK_SLOTS]
    for k, t in enumerate(expected):
        rec = _decode_instance(img, R.TRACK, k)
        assert rec["track_id"] == t.track_id
        cls, lane = rec["class_lane"]
        assert cls == R.ars_class(t.cls) and lane == (None if t.lane is None else t.lane + 1)
        assert rec["x"] == pytest.approx(t.x_m, abs=0.051) and rec["y"] == pytest.approx(t.y_m, abs=0.051)
        assert rec["vx"] == pytest.approx(t.vx_mps, abs=0.051) and rec["vy"] == pytest.approx(t.vy_mps, abs=0.051)
        assert rec["speed"] == pytest.approx(t.speed_mps * 3.6, abs=0.051)
        prob, tear = rec["prob_tear"]
        assert prob == round(100 * t.class_probability) and tear == 4242 & 0xFF


def test_empty_track_slots_and_fewer_tracks():
    st_ = OutputState(2)
    b = R.ImageBuilder(2, wall_clock=lambda: 0.0, temperature=lambda: None)
    tracks = make_tracks(np.random.default_rng(1), 3)
    img = b.build(st_.update(make_result(9, T0, tracks, (False, False)), health(T0, T0)))
    assert _decode_instance(img, R.TRACK_HDR)["valid_records"] == 3
    for k in range(3, R.TRACK_SLOTS):
        rec = _decode_instance(img, R.TRACK, k)
        assert rec["track_id"] is None and rec["prob_tear"][1] == 9
    for k in range(2):  # no interval closed yet: statistics n/a and flagged
        lane = _decode_instance(img, R.LANE, k)
        assert lane["volume"] is None and lane["live"] & (1 << R.LV_NO_INTERVAL) and lane["live"] & (1 << R.LV_STALE)
        assert lane["ntcip_occupancy"] == R.NTCIP_OCC_WATCHDOG_FAULT


def test_builder_returns_a_new_list_every_time():
    st_ = OutputState(1)
    b = R.ImageBuilder(1, wall_clock=lambda: 0.0, temperature=lambda: None)
    a = b.build(st_.update(make_result(1, T0), health(T0, T0)))
    a_copy = list(a)
    b.build(st_.update(make_result(2, T0 + PERIOD_NS), health(T0 + PERIOD_NS, T0 + PERIOD_NS)))
    assert a == a_copy  # the previous image is never modified in place (readers may hold it)


def test_live_lane_words_update_every_frame_between_intervals():
    rng = np.random.default_rng(3)
    st_ = OutputState(2)
    b = R.ImageBuilder(2, wall_clock=lambda: 0.0, temperature=lambda: None)
    lanes = make_lane_stats(rng, 2, seq=1)
    b.build(st_.update(make_result(1, T0, presence=(False, False), lane_stats=lanes), health(T0, T0)))
    t = T0 + PERIOD_NS
    img = b.build(st_.update(make_result(2, t, presence=(True, False), events=(wrong_way(3, 1, t),)), health(t, t)))
    l0, l1 = _decode_instance(img, R.LANE, 0), _decode_instance(img, R.LANE, 1)
    assert l0["live"] & 1 and not l1["live"] & 1
    assert l1["live"] & (1 << R.LV_WRONG_WAY) and l1["wrong_way_count"] == 1 and l0["wrong_way_count"] == 0
    assert l1["volume"] == lanes[1].volume  # the interval's statistics stay until the next one
    t += PERIOD_NS
    lanes2 = make_lane_stats(rng, 2, seq=2)
    img = b.build(st_.update(make_result(3, t, presence=(False, False), lane_stats=lanes2), health(t, t)))
    l1 = _decode_instance(img, R.LANE, 1)
    assert l1["volume"] == lanes2[1].volume and l1["cumulative_volume"] == lanes[1].volume + lanes2[1].volume
    assert l1["interval_seq"] == 2 and not l1["live"] & (1 << R.LV_WRONG_WAY)


def test_numpy_scalars_from_pipelines_are_encoded():
    from edge.types import LaneStats, TrackState

    st_ = OutputState(1)
    b = R.ImageBuilder(1, wall_clock=lambda: 0.0, temperature=lambda: None)
    ls = LaneStats(0, 0, np.float32(60.0), np.int64(4), np.int64(3), np.float32(12.5), np.float32("nan"),
                   np.float32(88.0), np.float32("nan"), np.float32(1.5), {"car": np.int64(3)})
    tr = TrackState(np.int64(5), np.float32(1.25), np.float32(30.0), np.float32(0.0), np.float32(-20.0),
                    np.float32(30.03), np.float32(-20.0), np.float32(0.04), 10, 9, lane=np.int64(0), cls="car",
                    class_probability=np.float32(0.5))
    img = b.build(st_.update(make_result(1, T0, (tr,), (True,), (ls,)), health(T0, T0)))
    lane = _decode_instance(img, R.LANE, 0)
    assert lane["volume"] == 3 and lane["occupancy"] == pytest.approx(12.5) and lane["mean_speed"] is None
    assert lane["speed_p85"] == pytest.approx(88.0) and lane["headway"] is None and lane["count_car"] == 3
    rec = _decode_instance(img, R.TRACK, 0)
    assert rec["track_id"] == 5 and rec["class_lane"] == (1, 1) and rec["vy"] == pytest.approx(-20.0)
    assert rec["x"] == pytest.approx(1.2, abs=0.11) and rec["prob_tear"] == (50, 1)


# --- issue 27: truthful values ------------------------------------------------------------------
def _lane(center, width, direction):
    from edge.traffic.lanes import Lane

    return Lane(center, width, direction)


def test_lane_id_high_byte_is_the_direction_of_the_lanes_in_use():
    """Before, the high byte was 0xFF (unknown) whatever the lanes' directions."""
    in_use = [()]  # learned lanes not learned yet
    st_ = OutputState(4, lanes=lambda: in_use[0])
    b = R.ImageBuilder(4, wall_clock=lambda: 0.0, temperature=lambda: None)
    lanes = make_lane_stats(np.random.default_rng(3), 4, seq=1)
    img = b.build(st_.update(make_result(1, T0, (), (False,) * 4, lanes), health(T0, T0)))
    assert [_decode_instance(img, R.LANE, k)["lane_id"] for k in range(4)] == [0xFF01, 0xFF02, 0xFF03, 0xFF04]
    in_use[0] = (_lane(-5.25, 3.5, -1), _lane(-1.75, 3.5, -1), _lane(1.75, 3.5, 1), _lane(5.25, 3.5, 1))
    img = b.build(st_.update(make_result(2, T0 + PERIOD_NS, (), (False,) * 4), health(T0 + PERIOD_NS, T0 + PERIOD_NS)))
    ids = [_decode_instance(img, R.LANE, k)["lane_id"] for k in range(4)]
    assert [i & 0xFF for i in ids] == [1, 2, 3, 4]
    assert [i >> 8 for i in ids] == [R.DIR_APPROACHING, R.DIR_APPROACHING, R.DIR_RECEDING, R.DIR_RECEDING]
    in_use[0] = (_lane(0.0, 7.0, 0),)  # one lane carrying both directions; lanes 2-4 unknown
    img = b.build(st_.update(make_result(3, T0 + 2 * PERIOD_NS, (), (False,) * 4), health(T0 + 2 * PERIOD_NS, T0)))
    assert [_decode_instance(img, R.LANE, k)["lane_id"] >> 8 for k in range(4)] == [R.DIR_BOTH, 0xFF, 0xFF, 0xFF]


def test_mean_length_from_lane_stats_and_gap_na():
    """mean_length read n/a whatever LaneStats said; a NaN gap or length must read n/a, never a number."""
    from dataclasses import replace

    st_ = OutputState(2)
    b = R.ImageBuilder(2, wall_clock=lambda: 0.0, temperature=lambda: None)
    a, c = make_lane_stats(np.random.default_rng(4), 2, seq=3)
    lanes = (replace(a, volume=12, mean_length_m=4.63, gap_s=2.5), replace(c, volume=1, gap_s=float("nan")))
    img = b.build(st_.update(make_result(1, T0, (), (False, False), lanes), health(T0, T0)))
    l1, l2 = _decode_instance(img, R.LANE, 0), _decode_instance(img, R.LANE, 1)
    assert l1["mean_length"] == pytest.approx(4.6) and l1["gap"] == pytest.approx(2.5)
    assert l2["mean_length"] is None and l2["gap"] is None
    assert img[R.LANE_BASE + R.LANE_STRIDE + 9] == R.NA_U16 and img[R.LANE_BASE + R.LANE_STRIDE + 8] == R.NA_U16


def test_configuration_words_show_the_running_configuration():
    """Register 2004 read 60 and the lane geometry 0/disabled whatever the traffic layer ran with."""
    from edge.outputs.config import CanConfig, ModbusConfig
    from edge.outputs.modbus import initial_config_words

    lanes = (_lane(-1.75, 3.5, -1), _lane(1.75, 3.5, 1), _lane(5.5, 4.0, 1))
    words = initial_config_words(ModbusConfig(unit_id=7), 3, CanConfig(bitrate=250_000, sensor_id=2), 10.0, lanes)
    v = R.config_values(words)
    assert v["interval_s"] == 10 and v["lanes"] == 3 and v["unit_id"] == 7
    assert v["can_bitrate_code"] == 1 and v["can_sensor_id"] == 2 and v["can_enable"] == 0
    assert [v[f"lane{k}_enabled"] for k in range(1, 9)] == [1, 1, 1, 0, 0, 0, 0, 0]
    assert (v["lane1_x_min"], v["lane1_x_max"], v["lane1_direction"]) == (pytest.approx(-3.5), 0.0, R.DIR_APPROACHING)
    assert (v["lane3_x_min"], v["lane3_x_max"], v["lane3_direction"]) == (pytest.approx(3.5), 7.5, R.DIR_RECEDING)
    assert R.lane_geometry(v) == [(pytest.approx(-3.5), 0.0, -1), (0.0, pytest.approx(3.5), 1),
                                  (pytest.approx(3.5), 7.5, 1)]


def test_no_image_fault_view():
    """What the Modbus server process serves when the frame loop went silent (before: the last image, healthy)."""
    st_ = OutputState(2)
    b = R.ImageBuilder(2, wall_clock=lambda: 0.0, temperature=lambda: None)
    tracks = make_tracks(np.random.default_rng(2), 5)
    img = b.build(st_.update(make_result(7, T0, tracks, (False, True), make_lane_stats(np.random.default_rng(2), 2, 1)),
                             health(T0 + 300_000_000, T0)))
    assert _decode_instance(img, R.STATUS)["since_last_frame"] == pytest.approx(0.3)
    for presence, bit0 in (("on", (1, 1)), ("off", (0, 0)), ("hold", (0, 1))):
        f = R.no_image_fault(img, 2.5, presence)
        s = _decode_instance(f, R.STATUS)
        assert s["status_bits"] & (1 << R.ST_ANY_FAULT) and s["status_bits"] & (1 << R.ST_STATS_STALE)
        assert not s["status_bits"] & (1 << R.ST_RADAR_OK)
        assert bool(s["status_bits"] & (1 << R.ST_FAILSAFE)) == (presence != "hold")
        assert s["alarm"] == 4 and s["loop_state"] == R.LOOP_STATE_NO_IMAGE and s["frame_rate"] == 0
        assert s["since_last_frame"] == pytest.approx(2.8) and s["track_count"] == 0
        assert _decode_instance(f, R.TRACK_HDR)["valid_records"] == 0
        assert _decode_instance(f, R.TRACK, 0)["track_id"] is None
        for k in range(2):
            lane = _decode_instance(f, R.LANE, k)
            assert lane["live"] & (1 << R.LV_STALE) and lane["ntcip_occupancy"] == R.NTCIP_OCC_WATCHDOG_FAULT
            assert lane["live"] & 1 == bit0[k]
    assert _decode_instance(img, R.STATUS)["alarm"] == 0  # the image itself is not changed


def test_docs_give_addresses_as_mbpoll_and_a_plc_type_them():
    """The docs said mbpoll -r takes the 30001/40001 numbers: -r 30001 is an illegal address."""
    doc = R.markdown()
    assert "mbpoll `-r` takes these" not in doc
    assert "| Offset | Address | mbpoll -r | Input | Holding |" in doc
    assert "| +0 | 0 | 1 | 30001 | 40001 | magic |" in doc
    assert "| +4 | 2004 | 2005 | 32005 | 42005 | interval_s |" in doc
    assert "`mbpoll -m tcp -p 5020 -t 3 -r 1 -1 127.0.0.1`" in doc


@pytest.mark.parametrize("clipped, degraded", [(None, False), (0.0, False), (5e-5, False), (2e-4, True), (0.41, True)])
def test_status_degraded_bit_follows_the_adc_saturation(clipped, degraded):
    import dataclasses

    st_ = OutputState(1)
    b = R.ImageBuilder(1, wall_clock=lambda: 0.0, temperature=lambda: None)
    h = dataclasses.replace(health(T0, T0), adc_clipped_fraction=clipped)
    bits = _decode_instance(b.build(st_.update(make_result(1, T0), h)), R.STATUS)["status_bits"]
    assert bool(bits & (1 << R.ST_DEGRADED)) == degraded
    assert bits & (1 << R.ST_RADAR_OK) and not bits & (1 << R.ST_ANY_FAULT)  # degraded is no fault
