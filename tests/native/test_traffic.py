"""The traffic layer's kernel (edge/native/_traffic.pyx) against its Python reference: the yaw estimator's running
sums and start-up votes on random track histories, and the whole traffic monitor on the tracks of a seeded
highway4-traffic run, output for output."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge import native
from edge.pipeline import StageTimer
from edge.traffic import TrafficConfig, TrafficMonitor
from edge.traffic.lanes import YawEstimator
from edge.types import TrackState
from tests.native.conftest import require_kernel


def _same_float(a, b) -> bool:
    return a == b or (a is not None and b is not None and math.isnan(a) and math.isnan(b))


def _random_frames(seed: int, n_frames: int):
    """Seeded frames of confirmed tracks: ids recycled (age drops), tracks ending and appearing, ids up to 200
    (the table grows), straight and wandering paths."""
    rng = np.random.default_rng(seed)
    tracks: dict[int, list[float]] = {}  # id -> [age, x, y, vx, vy]
    for _ in range(n_frames):
        for tid in list(tracks):
            if rng.random() < 0.03:
                del tracks[tid]
            elif rng.random() < 0.01:
                tracks[tid][0] = 0.0  # recycled: a new track under the same id
        while len(tracks) < rng.integers(0, 30):
            tid = int(rng.integers(1, 200 if rng.random() < 0.2 else 40))
            tracks.setdefault(tid, [0.0, rng.normal(0, 6), rng.uniform(5, 150), rng.normal(0, 0.3), rng.normal(0, 25)])
        order = list(tracks)
        rng.shuffle(order)
        for tid in order:
            t = tracks[tid]
            t[0] += 1.0
            t[1] += 0.05 * t[3] + rng.normal(0, 0.05 if tid % 3 else 0.6)
            t[2] += 0.05 * t[4]
        yield (np.array(order, dtype=np.int64), np.array([tracks[k][0] for k in order], dtype=np.int64),
               np.array([tracks[k][1] for k in order]), np.array([tracks[k][2] for k in order]))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_yaw_estimator_kernel_equals_the_python_reference_bit_for_bit(seed):
    require_kernel("_traffic")
    cfg = TrafficConfig(yaw_min_tracks=8, yaw_window_tracks=12, yaw_live_min_length_m=5.0)
    fast, ref = YawEstimator(cfg), YawEstimator(cfg, kernels=False)
    assert fast._k is not None and ref._k is None
    n_live = n_est = 0
    for ids, age, x, y in _random_frames(seed, 400):
        fast.add(ids, age, x, y)
        ref.add(ids, age, x, y)
        assert list(fast._votes) == list(ref._votes)
        lf, wf = fast.live_votes_weighted()
        lr, wr = ref.live_votes_weighted()
        assert np.array_equal(lf, lr) and np.array_equal(wf, wr)
        ef, er = fast.estimate_rad(), ref.estimate_rad()
        assert _same_float(ef, er) and _same_float(fast.stderr_rad, ref.stderr_rad)
        n_live += lf.size
        n_est += ef is not None
    assert fast.n_votes > 0 and n_live > 100 and n_est > 100  # votes of ended and of running tracks were compared
    assert fast._live.shape[0] >= 200  # the table grew for the large ids


def _traffic_inputs(n_frames: int):
    """The traffic layer's inputs (tracks, time, motion model's x, body extents) of a seeded highway4-traffic run."""
    from tests.edge import lane_golden as g

    pipe, frames = g.build("highway4-traffic", 1, 5.0)
    rec = []
    orig = pipe.traffic.update

    def tap(tracks, t_ns, yaw_x_m=None, extent_m=None):
        rec.append((tracks, t_ns, None if yaw_x_m is None else np.array(yaw_x_m),
                    None if extent_m is None else np.array(extent_m)))
        return orig(tracks, t_ns, yaw_x_m, extent_m)

    pipe.traffic.update = tap
    timer = StageTimer(16)
    for f in frames(n_frames):
        pipe.process(f, timer)
    return rec, pipe.traffic.config


def test_traffic_monitor_with_the_kernel_publishes_what_the_reference_does(monkeypatch):
    """Recorded inputs: the monitor with the kernel and with RADAR_EDGE_KERNELS=0 publish the same tracks (lanes,
    lengths, classes), presence, lane statistics, events and yaw, frame for frame."""
    require_kernel("_traffic")
    rec, cfg = _traffic_inputs(160)
    fast = TrafficMonitor(cfg)
    monkeypatch.setenv("RADAR_EDGE_KERNELS", "0")
    ref = TrafficMonitor(cfg)
    monkeypatch.delenv("RADAR_EDGE_KERNELS")
    assert fast.yaw_estimator._k is not None and ref.yaw_estimator._k is None
    n_lane = n_stats = 0
    for tracks, t_ns, mx, ext in rec:
        a, b = fast.update(tracks, t_ns, mx, ext), ref.update(tracks, t_ns, mx, ext)
        assert a.tracks == b.tracks, t_ns
        assert a.presence == b.presence and a.events == b.events, t_ns
        assert repr(a.lane_stats) == repr(b.lane_stats), t_ns  # (repr: NaN fields compare equal)
        assert fast.yaw_rad == ref.yaw_rad and fast.yaw_sigma_rad == ref.yaw_sigma_rad, t_ns
        n_lane += sum(t.lane is not None for t in a.tracks)
        n_stats += len(a.lane_stats)
    assert n_lane > 1000 and n_stats >= 4


def _random_scene(seed: int, n_frames: int):
    """Seeded frames of tracks for the monitor: vehicles in and between the default lanes at +-5-35 m/s (some
    against their lane, some stopping), ids recycled, tracks not confirmed, coasting (hits not growing), body
    extents (some NaN), a classifier's class and the tracker's length on some; 10 frames per second."""
    rng = np.random.default_rng(seed)
    live: dict[int, list] = {}  # id -> [x, y, vx, vy, age, hits, cls, stop_at]
    for f in range(n_frames):
        for tid in list(live):
            v = live[tid]
            if rng.random() < 0.02 or not -20.0 < v[1] < 260.0:
                del live[tid]
            elif rng.random() < 0.005:
                v[4] = v[5] = 0  # recycled
        while len(live) < 12 and rng.random() < 0.5:
            tid = int(rng.integers(1, 60))
            vy = rng.choice([-1.0, 1.0]) * rng.uniform(5.0, 35.0)
            live.setdefault(tid, [rng.choice([-5.25, -1.75, 1.75, 5.25, 7.5]) + rng.normal(0, 0.6),
                                  rng.uniform(10.0, 200.0), rng.normal(0, 0.2), vy, 0, 0,
                                  rng.choice([None, None, "car"]), f + int(rng.integers(5, 400))])
        tracks, ext = [], []
        for tid, v in live.items():
            if f >= v[7]:
                v[2] = v[3] = 0.0  # stopped
            v[0] += 0.1 * v[2]
            v[1] += 0.1 * v[3]
            v[4] += 1
            v[5] += rng.random() < 0.9
            r = math.hypot(v[0], v[1])
            tracks.append(TrackState(tid, v[0], v[1], v[2], v[3], r, (v[0] * v[2] + v[1] * v[3]) / r,
                                     math.atan2(v[0], v[1]), v[4], v[5], v[4] > 2 or rng.random() < 0.3, cls=v[6],
                                     length_m=None if rng.random() < 0.7 else 1.0))
            ext.append(float("nan") if rng.random() < 0.3 else rng.uniform(0.0, 20.0))
        tracks.append(TrackState(0, 1.0, 30.0, 0.0, 1.0, 30.0, 1.0, 0.03, 1, 1, True))  # id 0: never followed
        yield tuple(tracks), f * 100_000_000, np.array(ext + [np.nan])


@pytest.mark.parametrize("seed, estimate_yaw", [(1, False), (2, True), (3, True)])
def test_traffic_monitor_kernel_equals_the_reference_on_random_scenes(monkeypatch, seed, estimate_yaw):
    """Random inputs: counts, late counts, lengths and classes, presence, wrong-way and stopped-vehicle events
    of the monitor with the kernel and with RADAR_EDGE_KERNELS=0 agree frame for frame."""
    require_kernel("_traffic")
    cfg = TrafficConfig(estimate_yaw=estimate_yaw, interval_s=5.0, wrong_way_min_frames=5, stopped_min_s=3.0,
                        length_min_frames=3, yaw_min_tracks=4)
    fast = TrafficMonitor(cfg)
    monkeypatch.setenv("RADAR_EDGE_KERNELS", "0")
    ref = TrafficMonitor(cfg)
    monkeypatch.delenv("RADAR_EDGE_KERNELS")
    assert fast._kernel is not None and ref._kernel is None
    kinds: dict[str, int] = {}
    volume = n_len = 0
    for tracks, t_ns, ext in _random_scene(seed, 900):
        a, b = fast.update(tracks, t_ns, extent_m=ext), ref.update(tracks, t_ns, extent_m=ext)
        assert a.tracks == b.tracks, t_ns
        assert a.presence == b.presence and a.events == b.events, t_ns
        assert repr(a.lane_stats) == repr(b.lane_stats), t_ns
        assert fast.yaw_rad == ref.yaw_rad, t_ns
        for e in a.events:
            kinds[e.kind] = kinds.get(e.kind, 0) + 1
        volume += sum(st.volume for st in a.lane_stats)
        n_len += sum(t.length_m is not None and t.lane is not None for t in a.tracks)
    assert kinds.get("wrong_way", 0) > 0 and kinds.get("stopped_vehicle", 0) > 0, kinds
    assert volume > 20 and n_len > 100


def test_start_up_weighted_median_and_its_error_equal_the_reference_bit_for_bit(monkeypatch):
    """The kernel's weighted median and standard error (numpy's pairwise summation) against the reference's plain
    Python / numpy path, on random votes and weights, ties included; beyond 64 votes the kernel declines."""
    k = require_kernel("_traffic")
    rng = np.random.default_rng(7)
    for trial in range(400):
        nv, nl = int(rng.integers(0, 20)), int(rng.integers(1, 45))
        votes = rng.normal(0.02, 0.01, nv).tolist()
        live = rng.normal(0.02, 0.02, nl)
        if trial % 4 == 0:
            live = np.round(live, 2)  # ties between values
        w = rng.uniform(0.1, 10.0, nl) ** 3
        ref = YawEstimator(TrafficConfig(yaw_min_tracks=nv + 1, yaw_window_tracks=64), kernels=False)
        ref._votes.extend(votes)
        monkeypatch.setattr(ref, "live_votes_weighted", lambda live=live, w=w: (live, w))
        want = ref.estimate_rad()
        got = k.weighted_median(ref._votes, np.ascontiguousarray(live), w)
        assert got is not None and got[0] == want and _same_float(got[1], ref.stderr_rad), trial
    assert k.weighted_median([0.0] * 40, np.zeros(25), np.ones(25)) is None  # 65 votes: the numpy path


def test_lane_pipeline_with_and_without_the_traffic_kernel_publishes_the_same(monkeypatch):
    """End to end, only the traffic layer switched: the lane pipeline on highway4-traffic (seed 1, 120 frames, lane
    statistics every 2 s)
    with the traffic kernel and with the traffic reference (all other kernels as built) gives identical
    detections, published tracks (lanes, lengths, classes included), presence, lane statistics and events."""
    require_kernel("_traffic")
    from tests.edge import lane_golden as g

    fast, frames = g.build("highway4-traffic", 1, 2.0)  # (lane statistics every 2 s)
    slow, _ = g.build("highway4-traffic", 1, 2.0)
    monkeypatch.setenv("RADAR_EDGE_KERNELS", "0")
    slow.traffic = TrafficMonitor(slow.traffic.config)
    monkeypatch.delenv("RADAR_EDGE_KERNELS")
    assert fast.traffic._kernel is not None and slow.traffic._kernel is None
    ta, tb = StageTimer(16), StageTimer(16)
    n_lane = n_stats = 0
    for f in frames(120):
        a, b = fast.process(f, ta), slow.process(f, tb)
        np.testing.assert_array_equal(a.detections.range_m, b.detections.range_m, err_msg=f"frame {f.seq}")
        assert a.tracks == b.tracks, f.seq
        assert a.presence == b.presence and a.events == b.events, f.seq
        assert repr(a.lane_stats) == repr(b.lane_stats), f.seq
        n_lane += sum(t.lane is not None for t in a.tracks)
        n_stats += len(a.lane_stats)
    assert n_lane > 500 and n_stats >= 4  # (one interval closed, four lanes)
