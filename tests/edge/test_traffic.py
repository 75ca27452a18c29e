"""Traffic layer: hand-computed interval statistics, events, presence, yaw estimate and lane learning."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.config import load_config
from edge.track import PdafTracker
from edge.traffic import TrafficConfig, TrafficMonitor
from edge.traffic.lanes import LaneLearner, YawEstimator, align_yaw, assign_lanes, configured_lanes, to_road
from edge.types import TrackState
from tests.edge.trackscene import Vehicle, frames, scene_config

DT_NS = 100_000_000  # 10 frames per second keeps the hand computation readable


def _ts(tid, x, y, vx, vy, age, length=None, cls=None, confirmed=True):
    r = math.hypot(x, y)
    return TrackState(tid, x, y, vx, vy, r, (x * vx + y * vy) / r, math.atan2(x, y), age, age, confirmed,
                      cls=cls, length_m=length)


ONE_LANE = dict(lane_centers_m=(0.0,), lane_widths_m=(3.5,), lane_directions=("away",), estimate_yaw=False)


def test_config_section_registered_and_checked():
    assert load_config(env={})["traffic"] == TrafficConfig()
    with pytest.raises(ValueError):
        load_config(env={}, overrides={"traffic.lane_directions": "toward,sideways"})
    with pytest.raises(ValueError):
        TrafficConfig(lane_centers_m=(0.0, 3.5), lane_widths_m=(3.5, 3.5, 3.5))


def _run_vehicles(mon, vehicles, n_frames=121, extents=True):
    """Vehicles ``(id, speed m/s, crossing time s, body extent m or None, class)`` crossing y = 50 m in lane 0,
    each seen 3 s either side of its crossing; the pipeline's body extent is its length in every frame."""
    closed, presence_frames, last = [], 0, {}
    for k in range(0, n_frames):
        t = k * 0.1
        tracks, ext = [], []
        for tid, v, tc, length, cls in vehicles:
            if abs(t - tc) <= 3.0:
                age = int(round((t - (tc - 3.0)) / 0.1)) + 1
                tracks.append(_ts(tid, 0.2, 50.0 + v * (t - tc), 0.0, v, age, 0.5, cls))  # tracker: 0.5 m spread
                ext.append(float("nan") if length is None else length)
        upd = mon.update(tuple(tracks), k * DT_NS, extent_m=np.array(ext) if extents else None)
        presence_frames += upd.presence[0]
        assert all(tr.lane == 0 for tr in upd.tracks)
        last.update((tr.track_id, tr) for tr in upd.tracks)
        closed.extend(upd.lane_stats)
    return closed, presence_frames, last


def test_interval_statistics_against_hand_computed_values():
    """Lengths come from the body extents, not the tracker's 0.5 m spread; gap and occupancy use them (the old
    code used the tracker's length: every vehicle a motorcycle, gap ~ headway, body centred on the near face)."""
    cfg = TrafficConfig(interval_s=10.0, detection_line_m=50.0, presence_zone_m=5.0, **ONE_LANE)
    mon = TrafficMonitor(cfg)
    # (id, speed m/s, crossing time s, length m, class from a classifier)
    vehicles = [(1, 20.0, 1.05, 4.4, None), (2, 25.0, 3.05, None, "car"), (3, 10.0, 6.02, 11.2, None)]
    closed, presence_frames, last = _run_vehicles(mon, vehicles)
    assert len(closed) == 1
    s = closed[0]
    assert (s.lane, s.sequence, s.interval_start_ns, s.interval_s) == (0, 0, 0, 10.0)
    assert s.volume == 3
    assert s.mean_speed_kmh == pytest.approx((72 + 90 + 36) / 3)
    assert s.speed_p85_kmh == pytest.approx(72 + 0.7 * 18)  # rank 0.85 * 2 = 1.7 between 72 and 90
    assert s.headway_s == pytest.approx((2.0 + 2.97) / 2)
    # gap = headway - leader length / leader speed; vehicle 2's length is unknown: its follower has no gap
    assert s.gap_s == pytest.approx(2.0 - 4.4 / 20)
    # presence: the body spans s .. s + L; the zone is 47.5 .. 52.5 -> frames 0.8..1.1 (4), 2.8..3.1 (4, the
    # unmeasured car taken as 4.5 m), 4.7..6.2 (16) -> 2.4 s of 10 s (the interval reads the lengths at its close);
    # the live flag reads the length known at the frame: at 0.7 s vehicle 1 had 8 frames measured (4.5 m: present)
    assert presence_frames == 25
    assert s.occupancy_pct == pytest.approx(24.0)
    assert s.class_counts == {"motorcycle": 0, "car": 2, "truck": 1}
    assert s.mean_length_m == pytest.approx((4.4 + 11.2) / 2)
    # the tracks carry the measured length and its class; the classifier's class is kept, no length made up
    assert (last[1].length_m, last[1].cls) == (pytest.approx(4.4), "car")
    assert (last[2].length_m, last[2].cls) == (None, "car")
    assert (last[3].length_m, last[3].cls) == (pytest.approx(11.2), "truck")


def test_without_extents_lengths_classes_and_gaps_are_not_made_up():
    cfg = TrafficConfig(interval_s=10.0, detection_line_m=50.0, presence_zone_m=5.0, **ONE_LANE)
    vehicles = [(1, 20.0, 1.05, 4.4, None), (2, 25.0, 3.05, 4.4, None)]
    closed, _, last = _run_vehicles(TrafficMonitor(cfg), vehicles, extents=False)
    s = closed[0]
    assert s.volume == 2 and s.headway_s == pytest.approx(2.0)
    assert math.isnan(s.gap_s) and math.isnan(s.mean_length_m)
    assert s.class_counts == {"motorcycle": 0, "car": 0, "truck": 0, "unknown": 2}
    assert all(t.length_m is None and t.cls is None for t in last.values())  # not the tracker's 0.5 m


def test_length_needs_frames_in_the_measuring_range_and_skips_outliers():
    from edge.traffic.stats import LengthMeter

    m = LengthMeter(outliers=2)
    for e in (4.0, 0.0, 2.9, 4.4, 0.0, 4.3, 16.0, 4.4, 9.0):
        m.add(e)
    assert m.estimate_m(min_frames=10) is None  # 9 frames
    m.add(0.0)
    assert m.estimate_m(min_frames=10) == 4.4  # the third largest: 16 and 9 m (a follower, a glint) skipped
    # a vehicle shorter than the range resolution: the shortest class, no length
    cfg = TrafficConfig(**ONE_LANE)
    mon = TrafficMonitor(cfg)
    short = LengthMeter(cfg.length_outliers)
    for _ in range(12):
        short.add(0.0)
    assert mon.stats.measured(short) == (None, "motorcycle")
    # extents measured outside length_range_m (20-150 m by default) do not count
    mon = TrafficMonitor(cfg)
    for k in range(30):
        y = 200.0 - 2.0 * k
        upd = mon.update((_ts(1, 0.2, y, 0.0, -20.0, k + 1),), k * DT_NS, extent_m=np.array([4.4]))
    assert upd.tracks[0].length_m is None and upd.tracks[0].cls is None


def test_empty_interval_gives_nan_and_sequence_rolls_over():
    mon = TrafficMonitor(TrafficConfig(interval_s=1.0, **ONE_LANE))
    mon.stats.sequence = 65535
    out = []
    for k in range(0, 25):
        out.extend(mon.update((), k * DT_NS).lane_stats)
    assert [s.sequence for s in out] == [65535, 0]
    assert [s.interval_start_ns for s in out] == [0, 1_000_000_000]
    assert out[0].volume == 0 and math.isnan(out[0].mean_speed_kmh) and math.isnan(out[0].headway_s)
    assert out[0].occupancy_pct == 0.0


def test_presence_flags_per_lane():
    mon = TrafficMonitor(TrafficConfig(detection_line_m=50.0, presence_zone_m=5.0, estimate_yaw=False))
    upd = mon.update((_ts(1, -1.7, 52.0, 0, -20, 10), _ts(2, 5.3, 80.0, 0, 20, 10)), 0)
    assert upd.presence == (False, True, False, False)
    assert [t.lane for t in upd.tracks] == [1, 3]
    upd = mon.update((_ts(1, 9.5, 52.0, 0, -20, 11),), DT_NS)  # off the road
    assert upd.presence == (False,) * 4 and upd.tracks[0].lane is None


def test_wrong_way_driver_raises_one_event():
    cfg = TrafficConfig(wrong_way_min_frames=15, estimate_yaw=False)
    mon = TrafficMonitor(cfg)
    events = []
    for k in range(40):
        y = 100.0 - 25.0 * k * 0.1
        # lane 3 runs away from the radar: track 7 comes toward it; track 8 drives lane 0 correctly
        upd = mon.update((_ts(7, 5.25, y, 0.0, -25.0, k + 1), _ts(8, -5.25, y, 0.0, -25.0, k + 1)), k * DT_NS)
        events.extend((k, e) for e in upd.events)
    assert len(events) == 1
    k, e = events[0]
    assert (e.kind, e.track_id, e.lane, k) == ("wrong_way", 7, 3, 14)


def test_stopped_vehicle_event_once_and_not_for_static_clutter():
    cfg = TrafficConfig(stopped_min_s=5.0, estimate_yaw=False)
    mon = TrafficMonitor(cfg)
    events = []
    for k in range(200):
        t = k * 0.1
        v = max(20.0 - 10.0 * t, 0.0)  # stops at t = 2 s
        y = 30.0 + (20.0 * min(t, 2.0) - 5.0 * min(t, 2.0) ** 2)
        tracks = (_ts(4, 1.75, y, 0.0, v, k + 1), _ts(5, -5.25, 90.0, 0.0, 0.0, k + 1))  # 5: never moved
        events.extend((t, e) for e in mon.update(tracks, k * DT_NS).events)
    assert len(events) == 1
    t, e = events[0]
    assert (e.kind, e.track_id, e.lane) == ("stopped_vehicle", 4, 2)
    assert t == pytest.approx(2.0 + 5.0, abs=0.11)


def _world_to_radar(x, y, yaw_rad):
    return x * math.cos(yaw_rad) - y * math.sin(yaw_rad), x * math.sin(yaw_rad) + y * math.cos(yaw_rad)


LANES_X = (-5.25, -1.75, 1.75, 5.25)
LANES_DIR = (-1, -1, 1, 1)


def _synthetic_tracks(yaw_deg, n_per_lane, seed, sd_m=0.25):
    """Confirmed tracks of vehicles driving straight along the world road, seen by a yawed radar."""
    rng = np.random.default_rng(seed)
    yaw = math.radians(yaw_deg)
    out = []  # (t_ns, tracks)
    frames_ = {}
    tid = 0
    for lane, (cx, d) in enumerate(zip(LANES_X, LANES_DIR)):
        for j in range(n_per_lane):
            tid += 1
            v = rng.uniform(20, 33)
            t0 = j * 4.0 + rng.uniform(0, 2)
            x_off = cx + rng.normal(0, 0.3)  # drivers are not on the centre line
            n = int(150.0 / v / 0.1)
            for k in range(n):
                s = 20.0 + v * k * 0.1 if d > 0 else 170.0 - v * k * 0.1
                xr, yr = _world_to_radar(x_off + rng.normal(0, sd_m), s + rng.normal(0, sd_m), yaw)
                vxr, vyr = _world_to_radar(0.0, d * v, yaw)
                kk = int(round(t0 / 0.1)) + k
                frames_.setdefault(kk, []).append(_ts(tid % 250 + 1, xr, yr, vxr, vyr, k + 1))
    for kk in sorted(frames_):
        out.append((kk * DT_NS, tuple(frames_[kk])))
    return out


@pytest.mark.parametrize("yaw_deg", [-4.0, 0.0, 3.0])
def test_yaw_estimate_and_learned_lanes_from_synthetic_tracks(yaw_deg):
    cfg = TrafficConfig(lane_mode="learned", relearn_every_s=5.0)
    mon = TrafficMonitor(cfg)
    for t_ns, tracks in _synthetic_tracks(yaw_deg, 12, seed=3):
        upd = mon.update(tracks, t_ns)
    assert mon.yaw_estimator.n_votes >= 30
    assert math.degrees(mon.yaw_rad) == pytest.approx(yaw_deg, abs=0.3)
    assert len(mon.lanes) == 4
    np.testing.assert_allclose([ln.center_m for ln in mon.lanes], LANES_X, atol=0.3)
    assert [ln.direction for ln in mon.lanes] == list(LANES_DIR)
    assert all(3.0 < ln.width_m < 4.0 for ln in mon.lanes)
    assert upd.presence is not None and len(upd.presence) == 4


def _feed(est, tid, u, s, yaw):
    xr, yr = _world_to_radar(u, s, yaw)
    for i in range(u.size):
        est.add(np.array([tid]), np.array([i + 1]), np.array([xr[i]]), np.array([yr[i]]))
    est.add(np.array([], dtype=int), np.array([], dtype=int), np.array([]), np.array([]))  # track ends


def _smoothstep(k, a, b):
    x = np.clip((k - a) / (b - a), 0.0, 1.0)
    return 3 * x * x - 2 * x * x * x


def test_yaw_estimator_ignores_weaving_and_short_tracks():
    cfg = TrafficConfig(yaw_min_tracks=1, yaw_min_track_length_m=40.0, yaw_max_lateral_sd_m=0.8)
    est = YawEstimator(cfg)
    yaw = math.radians(2.0)
    k = np.arange(100.0)
    _feed(est, 1, np.zeros(100), 20 + k, yaw)  # straight, 100 m: votes
    weave = 3.5 * (_smoothstep(k, 20, 40) - _smoothstep(k, 60, 80))  # out to the next lane and back
    _feed(est, 2, weave, 20 + k, yaw)
    _feed(est, 3, np.zeros(100), 20 + 0.2 * k, yaw)  # a 20 m stub
    assert est.n_votes == 1
    assert math.degrees(est.estimate_rad()) == pytest.approx(2.0, abs=1e-6)


def test_yaw_median_is_robust_to_a_few_lane_changes():
    cfg = TrafficConfig(yaw_min_tracks=5)
    est = YawEstimator(cfg)
    yaw = math.radians(-3.0)
    k = np.arange(150.0)
    rng = np.random.default_rng(1)
    for tid in range(1, 13):
        u = rng.normal(0, 0.2, k.size)
        if tid % 4 == 0:  # one in four changes lane (smooth 3.5 m step over 40 m)
            u = u + 3.5 * _smoothstep(k, 50, 90)
        _feed(est, tid, u, 20 + k, yaw)
    assert math.degrees(est.estimate_rad()) == pytest.approx(-3.0, abs=0.1)


def test_lane_learner_buffer_is_bounded():
    cfg = TrafficConfig(learn_buffer_samples=100, learn_min_samples=50)
    ll = LaneLearner(cfg)
    for _ in range(10):
        ll.add(np.full(30, 1.75), np.linspace(20, 100, 30), np.zeros(30), np.full(30, 25.0))
    assert ll.n_samples == 100
    lanes = ll.learn(0.0)
    assert len(lanes) == 1 and lanes[0].center_m == pytest.approx(1.75, abs=0.06) and lanes[0].direction == 1


def test_tracker_and_monitor_end_to_end_on_a_misaimed_radar():
    """Four lanes of traffic, radar yawed by 3 deg: tracker -> monitor learns yaw within 1 deg and lanes
    within 0.5 m of the true centres, then assigns every vehicle near the line to its lane."""
    yaw_deg = 3.0
    yaw = math.radians(yaw_deg)
    rng = np.random.default_rng(21)
    vehicles, lane_of = [], []
    for lane, (cx, d) in enumerate(zip(LANES_X, LANES_DIR)):
        for j in range(7):
            v = rng.uniform(22, 32)
            t0 = j * 5.0 + rng.uniform(0, 2)
            s0 = 15.0 if d > 0 else 180.0
            # world position at time t: (cx, s0 + d v (t - t0)); in radar coordinates (linear in t)
            x0, y0 = _world_to_radar(cx, s0 - d * v * t0, yaw)
            vx, vy = _world_to_radar(0.0, d * v, yaw)
            vehicles.append(Vehicle(x0, y0, vx, vy, t_start_s=t0, t_end_s=t0 + 165.0 / v))
            lane_of.append(lane)
    cfg = TrafficConfig(lane_mode="learned", relearn_every_s=5.0, learn_min_samples=1500, interval_s=10.0)
    tr, mon = PdafTracker(scene_config()), TrafficMonitor(cfg)
    assigned = []
    stats = []
    prev_s = {}
    crossings = []  # (t_s, lane) of the true crossings of the detection line
    learned_ns = None
    for t_ns, det, truth in frames(vehicles, int(42.0 / 0.033), seed=21, p_detect=0.9, clutter_per_frame=1.0,
                                   fov_deg=15.0):
        for i, x, y, _, _ in truth:
            s_now = -x * math.sin(yaw) + y * math.cos(yaw)
            if i in prev_s and (prev_s[i] - cfg.detection_line_m) * (s_now - cfg.detection_line_m) < 0:
                crossings.append((t_ns * 1e-9, lane_of[i]))
            prev_s[i] = s_now
        upd = mon.update(tr.step(det, t_ns), t_ns)
        stats.extend(upd.lane_stats)
        if learned_ns is None and mon.lanes:
            learned_ns = t_ns
        if t_ns > 30e9:
            for i, x, y, _, _ in truth:
                d = [math.hypot(o.x_m - x, o.y_m - y) for o in upd.tracks]
                if d and min(d) < 2.0 and 30 < y < 120:
                    assigned.append((lane_of[i], upd.tracks[int(np.argmin(d))].lane))
    assert math.degrees(mon.yaw_rad) == pytest.approx(yaw_deg, abs=1.0)
    assert len(mon.lanes) == 4
    np.testing.assert_allclose([ln.center_m for ln in mon.lanes], LANES_X, atol=0.5)
    assert [ln.direction for ln in mon.lanes] == list(LANES_DIR)
    assert len(assigned) > 200
    acc = np.mean([a == b for a, b in assigned])
    assert acc >= 0.99, f"lane accuracy {acc:.3f}"
    # per-lane volume of every interval closed once lanes were known equals the true line crossings
    complete = [st for st in stats if st.interval_start_ns >= learned_ns]
    assert len(complete) >= 8
    for st in complete:
        t0 = st.interval_start_ns * 1e-9
        true_n = sum(1 for t, lane in crossings if lane == st.lane and t0 <= t < t0 + st.interval_s)
        assert st.volume == true_n, (st, true_n)
    assert sum(st.volume for st in complete) >= 10, sum(st.volume for st in complete)


def test_sections_load_from_a_toml_file(tmp_path):
    p = tmp_path / "site.toml"
    p.write_text('[track.pdaf]\nassociation = "pdaf"\nconfirm_m = 4\n\n[traffic]\nlane_mode = "learned"\n'
                 'lane_centers_m = [-1.75, 1.75]\nlane_directions = ["toward", "away"]\ninterval_s = 30\n')
    cfg = load_config(p, env={})
    assert cfg["track.pdaf"].association == "pdaf" and cfg["track.pdaf"].confirm_m == 4
    t = cfg["traffic"]
    assert (t.lane_mode, t.lane_centers_m, t.lane_directions, t.interval_s) == (
        "learned", (-1.75, 1.75), ("toward", "away"), 30.0)
    again = tmp_path / "again.toml"
    again.write_text(cfg.to_toml())
    assert load_config(again, env={})["traffic"] == t


def test_a_crossing_counts_in_the_interval_of_its_interpolated_time():
    mon = TrafficMonitor(TrafficConfig(interval_s=1.0, detection_line_m=50.0, **ONE_LANE))
    out = []
    for k in range(0, 22):
        t = k * 0.1
        tracks = (_ts(1, 0.0, 50.0 + 20.0 * (t - 0.95), 0.0, 20.0, k + 1),  # crosses at 0.95 s
                  _ts(2, 0.3, 50.0 + 10.0 * (t - 1.05), 0.0, 10.0, k + 1))  # crosses at 1.05 s
        out.extend(mon.update(tracks, k * DT_NS).lane_stats)
    assert [(s.interval_start_ns, s.volume) for s in out] == [(0, 1), (1_000_000_000, 1)]
    assert out[0].mean_speed_kmh == pytest.approx(72.0) and out[1].mean_speed_kmh == pytest.approx(36.0)
    assert out[1].headway_s == pytest.approx(0.1)  # the previous crossing lies in the previous interval


def test_yaw_from_running_tracks_at_start_up():
    """No track has ended yet: straight running tracks that covered yaw_live_min_length_m vote,
    weighted by how well their line is determined; the estimate is there within a second."""
    cfg = TrafficConfig(yaw_min_tracks=5, yaw_live_min_length_m=20.0)
    est = YawEstimator(cfg)
    yaw = math.radians(3.0)
    rng = np.random.default_rng(4)
    lanes_u = np.array([-5.25, -1.75, 1.75, 5.25, -5.25, 1.75])
    s0 = np.array([250.0, 180.0, 40.0, 90.0, 120.0, 200.0])
    speed = np.array([-28.0, -25.0, 30.0, 27.0, -24.0, 26.0])
    got = None
    for k in range(30):  # 1 s at 30 frames/s
        s = s0 + speed * k / 30.0
        u = lanes_u + rng.normal(0.0, 0.02 * s0 / 10.0)  # lateral noise grows with range
        xr, yr = _world_to_radar(u, s, yaw)
        est.add(np.arange(1, 7), np.full(6, k + 1), xr, yr)
        got = est.estimate_rad()
    assert est.n_votes == 0 and got is not None
    assert math.degrees(got) == pytest.approx(3.0, abs=0.5)


def test_a_coasting_track_raises_no_wrong_way_event():
    """A track seeded with a wrong velocity that coasts (no new hits) against its lane's direction is
    not a wrong-way driver; the same track with a detection every frame is."""
    cfg = TrafficConfig(wrong_way_min_frames=15, estimate_yaw=False)
    for hits_grow, expected in ((False, 0), (True, 1)):
        mon = TrafficMonitor(cfg)
        n = 0
        for k in range(40):
            y = 100.0 - 25.0 * k * 0.1
            hits = k + 1 if hits_grow else 3
            tr = TrackState(7, 5.25, y, 0.0, -25.0, math.hypot(5.25, y), -25.0, math.atan2(5.25, y), k + 1, hits, True)
            n += len(mon.update((tr,), k * DT_NS).events)
        assert n == expected


def _wrong_way_frames(cfg, x0, y0, vy, n=60):
    """Frame index of each wrong_way event of one track in lane 3 (away) driving toward the radar."""
    mon = TrafficMonitor(cfg)
    got = []
    for k in range(n):
        got.extend(k for _ in mon.update((_ts(7, x0, y0 + vy * k * 0.1, 0.0, vy, k + 1),), k * DT_NS).events)
    return got


def test_no_wrong_way_alarm_from_the_neighbouring_lane_while_the_yaw_is_unknown():
    """A track 0.5 m inside lane 3's edge 150 m away: with the configured yaw known to 0.5 deg (and not yet
    estimated) that is 0.4 sd of lateral uncertainty, so its frames do not count; 25 m away it is 2.3 sd
    inside and raises the alarm after wrong_way_min_frames. A vehicle in the middle of the lane at 150 m
    is 1.3 sd inside: with wrong_way_lane_sigmas 1 it raises, with 2 it waits until it is nearer."""
    base = dict(wrong_way_min_frames=15, estimate_yaw=True, yaw_min_tracks=5, mounting_yaw_sigma_deg=0.5,
                wrong_way_azimuth_sigma_deg=0.0)  # the yaw's uncertainty alone (the tracks' own: the next test)
    cfg = TrafficConfig(**base)
    assert _wrong_way_frames(cfg, 4.0, 150.0, -4.0) == []  # 150 -> 126 m: never sure of its lane
    assert _wrong_way_frames(cfg, 4.0, 25.0, -4.0) == [14]
    mid = _wrong_way_frames(cfg, 5.25, 150.0, -25.0)
    # 2 sd inside 1.75 m of half-width at 0.5 deg: within 100 m, from frame 20 (y = 100 m) on
    assert mid == [20 + 14]
    assert _wrong_way_frames(TrafficConfig(**base, wrong_way_lane_sigmas=1.0), 5.25, 150.0, -25.0) == [14]
    # the installer measured the yaw (no estimate): every frame in the lane counts
    measured = TrafficConfig(wrong_way_min_frames=15, estimate_yaw=False, wrong_way_azimuth_sigma_deg=0.0)
    assert _wrong_way_frames(measured, 4.0, 150.0, -4.0) == [14]


def test_yaw_estimate_standard_error_shrinks_with_votes():
    """The standard error of the yaw median is 1.2533 sd / sqrt(n) of the votes."""
    rng = np.random.default_rng(3)
    est = YawEstimator(TrafficConfig(yaw_min_tracks=5, yaw_window_tracks=1000))
    assert est.estimate_rad() is None and est.stderr_rad is None
    votes = rng.normal(0.01, 0.004, 400)
    est._votes.extend(votes.tolist())
    est._n_voted = votes.size
    assert est.estimate_rad() == pytest.approx(float(np.median(votes)))
    assert est.stderr_rad == pytest.approx(1.2533 * np.std(votes, ddof=1) / 20.0)
    assert 0.5 * 0.004 / 20 < est.stderr_rad < 2.0 * 0.004 / 20


def test_a_crossing_against_the_lane_direction_is_not_counted():
    """A receding track in an approaching lane crossing the line is not in the volume; an approaching car in the
    same lane is."""
    cfg = TrafficConfig(estimate_yaw=False, interval_s=60.0)
    mon = TrafficMonitor(cfg)
    v = 20.0
    for k in range(40):
        mon.update((_ts(3, -1.75, 35.0 + v * k * 0.1, 0.0, v, k + 1),), k * DT_NS)
    assert len(mon.stats.lane(1).crossings) == 0
    mon = TrafficMonitor(cfg)
    for k in range(40):
        mon.update((_ts(4, -1.75, 70.0 - v * k * 0.1, 0.0, -v, k + 1),), k * DT_NS)
    assert len(mon.stats.lane(1).crossings) == 1


@pytest.mark.parametrize("lost_at_m,late_max_m,expected", [
    (52.0, 30.0, 1),  # lost before the line, re-born after it: counted once, at the extrapolated time
    (52.0, 0.0, 0),   # ... (without the late count the vehicle is missed)
    (46.0, 30.0, 1),  # lost after it crossed: the re-born track is the same vehicle, not counted again
    (52.0, 5.0, 0),   # re-born farther past the line than count_late_max_m
])
def test_a_track_reborn_past_the_line_counts_its_vehicle_once(lost_at_m, late_max_m, expected):
    cfg = TrafficConfig(estimate_yaw=False, interval_s=60.0, count_late_max_m=late_max_m)
    mon = TrafficMonitor(cfg)
    v = 25.0  # approaching in lane 1 (toward the radar)
    born_again_m = 40.0
    crossing_times = []
    for k in range(60):
        y = 80.0 - v * k * 0.1
        trs = []
        if y > lost_at_m:
            trs.append(_ts(1, -1.75, y, 0.0, -v, k + 1))
        elif y <= born_again_m:
            trs.append(_ts(2, -1.75, y, 0.0, -v, k + 1 - 16))
        mon.update(tuple(trs), k * DT_NS)
        crossing_times = [c.t_ns for c, _, _ in mon.stats.lane(1).crossings]
    assert len(crossing_times) == expected
    if expected:
        assert crossing_times[0] == pytest.approx(1.2e9, abs=1e6)  # 80 m -> 50 m at 25 m/s


@pytest.mark.parametrize("x_m,born_m,v_sign,receding_max_m,expected", [
    (5.25, 86.0, 1, 60.0, 1),  # receding, masked beside a truck until 36 m past the line: counted
    (5.25, 86.0, 1, 0.0, 0),   # ... (only count_late_max_m: missed)
    (5.25, 116.0, 1, 60.0, 0),  # first seen farther past than count_late_receding_max_m
    (3.75, 86.0, 1, 60.0, 0),  # 0.25 m inside its lane, by the boundary where a neighbour's ghost sits
    (-5.25, 14.0, -1, 60.0, 0),  # approaching, 36 m past the line: count_late_max_m holds
])
def test_a_receding_vehicle_first_tracked_far_past_the_line_is_counted(x_m, born_m, v_sign, receding_max_m,
                                                                       expected):
    """A car overtaken by a truck in the next lane is masked by the truck's body until it is well past the
    line (highway4-traffic seed 7005: first tracked 36 and 52 m past it). The extended late count is for
    receding tracks well inside their lane only."""
    cfg = TrafficConfig(estimate_yaw=False, interval_s=60.0, count_late_max_m=30.0,
                        count_late_receding_max_m=receding_max_m, count_late_far_margin_m=1.0)
    mon = TrafficMonitor(cfg)
    mon.update((_ts(9, 0.0, 150.0, 0.0, 20.0, 50),), 0)  # the monitor starts before the vehicle crosses
    v = 24.0 * v_sign
    for k in range(1, 20):
        mon.update((_ts(1, x_m, born_m + v * k * 0.1, 0.0, v, k), _ts(9, 0.0, 150.0 + 2.0 * k, 0.0, 20.0, 50 + k)),
                   3_000_000_000 + k * DT_NS)
    lane = 3 if x_m > 3.5 else 2 if x_m > 0 else 0
    crossings = [c for c, _, _ in mon.stats.lane(lane).crossings]
    assert len(crossings) == expected
    if expected:  # at the time extrapolated back: first seen 38.4 m past the line (at 3.1 s) at 24 m/s
        assert crossings[0].t_ns == pytest.approx((3.1 - 38.4 / 24.0) * 1e9, abs=1e6)


def test_tracks_already_past_the_line_at_start_are_not_counted():
    mon = TrafficMonitor(TrafficConfig(estimate_yaw=False, interval_s=60.0, count_late_max_m=30.0))
    for k in range(20):
        mon.update((_ts(1, -1.75, 40.0 - 25.0 * k * 0.1, 0.0, -25.0, k + 1),), k * DT_NS)
    assert mon.stats.lane(1).crossings == []


@pytest.mark.parametrize("once,expected", [(True, 1), (False, 3)])
def test_a_track_that_jumps_back_behind_the_line_is_counted_once(once, expected):
    """A receding car's track crosses the line, jumps 11 m back toward the radar (re-anchored onto an unclaimed
    detection at its speed) and crosses again 0.6 s after its first crossing: one vehicle with
    ``count_once_per_track``. Without it three counts: the jump back crosses the line too, with the track's
    velocity still in the lane's direction."""
    cfg = TrafficConfig(estimate_yaw=False, interval_s=60.0, count_once_per_track=once)
    mon = TrafficMonitor(cfg)
    v = 21.0  # receding in lane 2
    y = 40.0
    for k in range(30):
        y += v * 0.1
        if k == 8:
            y -= 11.0  # the jump, after the first crossing (y 57 -> 48)
        mon.update((_ts(7, 1.75, y, 0.0, v, k + 1),), k * DT_NS)
    assert len(mon.stats.lane(2).crossings) == expected


def test_far_track_by_the_lane_edge_raises_no_wrong_way_alarm_with_its_azimuth_uncertainty():
    """traffic.wrong_way_azimuth_sigma_deg: a far track's lateral position is range x its azimuth error off (a car
    of lane 1 tracked 330-350 m out sat 0.1-1 m inside receding lane 2: highway4-traffic seed 7012). With 0.1 deg,
    0.58 m of lateral sd at 330 m, a track 0.5 m inside lane 3 is 0.87 sd inside and its frames do not count (2 sd
    needs it within 143 m); one in the middle of the lane is 3 sd inside and raises the alarm after
    wrong_way_min_frames (the yaw known, not estimated)."""
    base = dict(wrong_way_min_frames=15, estimate_yaw=False)
    edge_cfg = TrafficConfig(**base, wrong_way_azimuth_sigma_deg=0.1)
    assert _wrong_way_frames(edge_cfg, 4.0, 330.0, -25.0) == []  # 330 -> 182.5 m, never 2 sd inside
    assert _wrong_way_frames(edge_cfg, 5.25, 330.0, -25.0) == [14]
    without = TrafficConfig(**base, wrong_way_azimuth_sigma_deg=0.0)
    assert _wrong_way_frames(without, 4.0, 330.0, -25.0) == [14]  # counted from the start
    assert TrafficConfig().wrong_way_azimuth_sigma_deg == 0.1


@pytest.mark.parametrize("behind_m,speed_mps,expected",
                         [(8.0, -25.0, [7]), (40.0, -25.0, [7, 9]), (8.0, -20.0, [7, 9])])
def test_a_wrong_way_drivers_second_track_raises_no_second_alarm(behind_m, speed_mps, expected):
    """A track born 1 s after a wrong-way driver's, behind it in lane 3: 8 m behind at its speed it is the same
    driver (a glint of a wrong-way truck's body seeded one 8 m behind it: wrong-way-traffic seed 1) and raises no
    alarm of its own; 40 m behind, or 5 m/s slower, it is a second driver."""
    mon = TrafficMonitor(TrafficConfig(wrong_way_min_frames=15, estimate_yaw=False))
    got = []
    for k in range(50):
        tracks = [_ts(7, 5.25, 150.0 - 25.0 * k * 0.1, 0.0, -25.0, k + 1)]
        if k >= 10:
            y9 = 150.0 - 25.0 * 1.0 + behind_m + speed_mps * (k - 10) * 0.1
            tracks.append(_ts(9, 5.25, y9, 0.0, speed_mps, k - 9))
        got.extend(e.track_id for e in mon.update(tuple(tracks), k * DT_NS).events)
    assert got == expected




def _snapshot(yaw_deg, seed, n=12, sd_per_100m=0.15):
    """One frame of straight-driving vehicles in the four configured lanes at 30-290 m, seen by a radar yawed
    ``yaw_deg``: (x, y, vy, true lane), lateral noise growing with range."""
    rng = np.random.default_rng(seed)
    lane = rng.integers(0, 4, n)
    s = rng.uniform(30.0, 290.0, n)
    u = np.array(LANES_X)[lane] + rng.normal(0.0, 0.3, n) + rng.normal(0.0, sd_per_100m * s / 100.0)
    x, y = _world_to_radar(u, s, math.radians(yaw_deg))
    _, vy = _world_to_radar(0.0, np.array(LANES_DIR)[lane] * 25.0, math.radians(yaw_deg))
    return x, y, vy, lane


@pytest.mark.parametrize("yaw_deg", [-3.0, 0.4, 3.0])
def test_align_yaw_puts_one_frame_of_tracks_into_the_configured_lanes(yaw_deg):
    """One frame of a dozen tracks fixes the yaw to a few hundredths of a degree (a direction fit needs tens of
    metres of each track), 3 sd from the configured 0 +- 1 deg included; its sigma covers the error."""
    lanes = configured_lanes(TrafficConfig())
    errs = []
    for seed in range(20):
        x, y, vy, lane = _snapshot(yaw_deg, seed)
        yaw, sigma = align_yaw(x, y, np.sign(vy), lanes, 0.0, math.radians(5.0), 5)
        errs.append((math.degrees(yaw) - yaw_deg, math.degrees(sigma)))
        # the lanes it assigns are those the true yaw gives (the noise puts a few points in the wrong lane either way)
        assert (assign_lanes(to_road(x, y, yaw)[0], lanes) == assign_lanes(to_road(x, y, math.radians(yaw_deg))[0],
                                                                           lanes)).mean() >= 0.9
    e = np.array(errs)
    assert np.abs(e[:, 0]).max() < 0.1
    assert np.mean(np.abs(e[:, 0]) < 3.0 * e[:, 1]) >= 0.9


def test_align_yaw_needs_enough_tracks_in_lanes_and_ignores_those_off_the_road():
    lanes = configured_lanes(TrafficConfig())
    x, y, vy, _ = _snapshot(2.0, 1, n=4)
    assert align_yaw(x, y, np.sign(vy), lanes, 0.0, math.radians(5.0), 5) is None
    x, y, vy, _ = _snapshot(2.0, 1, n=10)
    # four guard-rail ghosts 9 m left of the road, 40-200 m out, moving with the traffic
    gx, gy = _world_to_radar(np.full(4, -9.0), np.array([40.0, 90.0, 150.0, 200.0]), math.radians(2.0))
    yaw, _ = align_yaw(np.r_[x, gx], np.r_[y, gy], np.r_[np.sign(vy), -np.ones(4)], lanes, 0.0, math.radians(5.0), 5)
    assert math.degrees(yaw) == pytest.approx(2.0, abs=0.1)
    # the direction of travel tells the lanes apart: every track called "away" cannot sit in the toward lanes
    yaw_any, _ = align_yaw(x, y, np.zeros_like(vy), lanes, 0.0, math.radians(5.0), 5)
    assert math.degrees(yaw_any) == pytest.approx(2.0, abs=0.1)


def test_configured_lanes_are_right_from_the_first_frames_on_a_misaimed_radar():
    """A radar aimed 3 deg off the road, configured as 0 +- 1 deg: with a handful of confirmed tracks the monitor
    assigns their lanes right in its first frame, long before any track has driven the tens of metres a
    direction estimate needs."""
    cfg = TrafficConfig(yaw_min_tracks=5)
    x, y, vy, lane = _snapshot(3.0, 7, n=10, sd_per_100m=0.05)
    mon = TrafficMonitor(cfg)
    upd = mon.update(tuple(_ts(k + 1, x[k], y[k], 0.0, vy[k], 3) for k in range(x.size)), 0)
    assert math.degrees(mon.yaw_rad) == pytest.approx(3.0, abs=0.1)
    assert mon.yaw_sigma_rad < math.radians(0.1)
    assert [t.lane for t in upd.tracks] == lane.tolist()


def test_the_start_up_alignment_holds_until_the_tracks_directions_are_as_certain():
    """Configured lanes, a radar yawed 0.3 deg. Eight vehicles stand in their lanes at 50-260 m (0.3 m off their
    centres), so the alignment puts the yaw within a few hundredths of a degree. Five tracks beside them end after
    62 m on lines 1-2 deg off the road (straight enough to vote): the median of five such votes is a degree off,
    with a standard error of tenths of a degree, and the alignment's yaw holds. Then 200 tracks end on lines
    0.35 deg off the boresight, 0.05 deg from the alignment's yaw, and their median, now the more certain, takes
    over."""
    yaw0 = math.radians(0.3)
    cfg = TrafficConfig(yaw_min_tracks=5)
    mon = TrafficMonitor(cfg)
    rng = np.random.default_rng(5)
    lane = np.arange(8) % 4
    x0, y0 = _world_to_radar(np.array(LANES_X)[lane] + rng.normal(0.0, 0.3, 8), np.linspace(50.0, 260.0, 8), yaw0)
    steady = [(k + 1, x0[k], y0[k], 25.0 * LANES_DIR[lane[k]]) for k in range(8)]
    t = 0

    def frame(moving):
        nonlocal t
        tracks = [_ts(i, x, y, 0.0, vy, 50) for i, x, y, vy in steady] + moving
        mon.update(tuple(tracks), t)
        t += DT_NS

    for _ in range(5):
        frame([])
    assert math.degrees(mon.yaw_rad) == pytest.approx(0.3, abs=0.1)  # aligned
    # five tracks in lane 2 (away) on slanted lines, one after the other
    for i, drift_m in enumerate((1.0, 1.5, 2.0, 1.2, 1.8)):
        for k in range(26):
            s = 100.0 + 2.5 * k
            x, y = _world_to_radar(1.75 + drift_m * (s - 100.0) / 62.5, s, yaw0)
            frame([_ts(100 + i, x, y, 0.0, 25.0, k + 3)])
    frame([])
    assert mon.yaw_estimator.n_votes == 5
    votes = mon.yaw_estimator.estimate_rad()
    assert abs(math.degrees(votes) - 0.3) > 1.0 and mon.yaw_estimator.stderr_rad > math.radians(0.1)
    assert math.degrees(mon.yaw_rad) == pytest.approx(0.3, abs=0.1)  # the alignment holds
    # 200 straight tracks, ten at a time, on lines 0.35 deg off the boresight
    for batch in range(20):
        for k in range(26):
            moving = []
            for j in range(10):
                s = 60.0 + 10.0 * j + 2.5 * k
                x, y = _world_to_radar(1.75 + rng.normal(0.0, 0.02), s, math.radians(0.35))
                moving.append(_ts(1000 + 10 * batch + j, x, y, 0.0, 25.0, k + 3))
            frame(moving)
    frame([])
    assert mon.yaw_estimator.n_votes == 200
    assert math.degrees(mon.yaw_rad) == pytest.approx(0.35, abs=0.005)  # the directions took over
