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
