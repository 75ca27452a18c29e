"""The grating-lobe unaliasing kernel (edge/native/_unalias.pyx) against its numpy reference
(UnaliasByLane.reference): the same angles bit for bit, on random near detections over random lane layouts (values
on the lane edges, both directions of travel, NaN) and on seeded hw_sim runs through the lane pipeline."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge.lane.detections import UnaliasByLane
from edge.lane.records import Feedback
from edge.lane.road import RoadFrame
from edge.pipelines.lane import LaneConfig
from edge.traffic.lanes import Lane
from tests.native.conftest import require_kernel


def _feedback(lanes, yaw: float) -> Feedback:
    fb = Feedback.none()
    return dataclasses.replace(fb, lanes=lanes, yaw_rad=yaw)


def _random_road(rng, offset_m: float, against_p: float, yaw_sd: float):
    """A road: lanes toward the radar on one side, away on the other, its middle up to ``offset_m`` off the radar's
    axis, a lane against its side's direction with probability ``against_p``; and its feedback, yaw ~ N(0, yaw_sd)."""
    n_l = int(rng.integers(1, 7))
    width = float(rng.choice([3.5, 3.75]))
    c0 = float(rng.uniform(-offset_m, offset_m))
    centres = [c0 + (k - (n_l - 1) / 2) * width for k in range(n_l)]
    lanes = tuple(Lane(c, width, (1 if c > c0 else -1) * (-1 if rng.random() < against_p else 1)) for c in centres)
    return lanes, _feedback(lanes, float(rng.normal(0.0, yaw_sd)))


def _stage(cfg):
    from hw_sim.scenario import load_scenario_for_eval

    fe = load_scenario_for_eval("highway4-traffic").sim_board().frontend
    return UnaliasByLane(fe, cfg, RoadFrame())


def _assert_same(a: np.ndarray, b: np.ndarray) -> None:
    assert a.dtype == b.dtype == np.float32
    np.testing.assert_array_equal(a.view(np.int32), b.view(np.int32))


@pytest.mark.parametrize("seed", range(20))
def test_kernel_equals_reference_on_random_detections(seed):
    require_kernel("_unalias")
    rng = np.random.default_rng(seed)
    cfg = dataclasses.replace(LaneConfig(), mounting_height_m=float(rng.choice([1.0, 6.0, 8.0])))
    stage = _stage(cfg)
    assert stage.kernel is not None
    moved = 0
    for n in (1, 3, 10, 40, 80, 80, 80):
        lanes, fb = _random_road(rng, 3.0, 0.1, 0.05)
        r = rng.uniform(0.5, 30.0, n).astype(np.float32)
        v = rng.choice([-20.0, -0.5, 0.0, 0.5, 15.0, np.float32(cfg.unalias_min_speed_mps)], n).astype(np.float32)
        az = rng.uniform(-1.2, 1.2, n).astype(np.float32)
        # half of them aliases of a vehicle in a lane of its direction (sin az off by one grating-lobe period)
        for i in range(0, n, 2):
            own = [ln for ln in lanes if ln.direction == np.sign(v[i])]
            if own:
                ln = own[int(rng.integers(0, len(own)))]
                u = ln.center_m + rng.uniform(-0.5, 0.5) * ln.width_m
                s = np.clip(u / max(float(r[i]), 1.0), -1.0, 1.0) + rng.choice([1.0, -1.0]) * stage.period
                if abs(s) <= 1.0:
                    az[i] = np.float32(np.arcsin(s))
        if n > 3:
            az[rng.integers(0, n)] = np.nan
            r[rng.integers(0, n)] = np.float32(cfg.mounting_height_m)  # no ground solution: y = 0
        ref = stage.reference(r, v, az, fb)
        out = stage.unalias(r, v, az, fb)
        _assert_same(out, ref)
        moved += int((out.view(np.int32) != az.view(np.int32)).sum())
    assert moved > 0


@pytest.mark.parametrize("scenario", ["highway4-traffic", "wrong-way-traffic"])
def test_kernel_equals_reference_on_a_pipeline_run(monkeypatch, scenario):
    require_kernel("_unalias")
    from edge.pipeline import StageTimer
    from tests.edge import lane_golden as g

    pipe, frames = g.build(scenario, 1, 5.0)
    un = [f for f in pipe.detections.direction_filters if isinstance(f, UnaliasByLane)][0]
    assert un.kernel is not None
    seen = {"calls": 0, "dets": 0, "moved": 0}
    real = un.unalias

    def both(range_m, v_mps, az, fb):
        out = real(range_m, v_mps, az, fb)
        ref = un.reference(range_m, v_mps, az, fb)
        _assert_same(out, ref)
        seen["calls"] += 1
        seen["dets"] += range_m.size
        seen["moved"] += int((out.view(np.int32) != az.view(np.int32)).sum())
        return out

    monkeypatch.setattr(un, "unalias", both)
    t = StageTimer(16)
    for f in frames(160):
        pipe.process(f, t)
    assert seen["calls"] > 50 and seen["dets"] > 300, seen


def test_kernel_equals_reference_within_a_metre_of_the_largest_range():
    """Detections just inside the kernel's range limit (span / period + mounting height), on roads turned by the
    yaw, where some aliases still land in a lane of their direction and move."""
    require_kernel("_unalias")
    rng = np.random.default_rng(0)
    stages = {h: _stage(dataclasses.replace(LaneConfig(), mounting_height_m=h)) for h in (1.0, 6.0, 8.0)}
    moved = 0
    for trial in range(300):
        stage = stages[float(rng.choice([1.0, 6.0, 8.0]))]
        cfg = stage.config
        lanes, fb = _random_road(rng, 6.0, 0.3, 0.3)
        span, _ = stage.road.lane_arrays(lanes)
        limit = np.float32(span / stage.period + cfg.mounting_height_m)
        r = (limit - rng.uniform(0.0, 1.0, 64)).astype(np.float32)
        r[0] = limit
        v = rng.choice([-20.0, 15.0], r.size).astype(np.float32)
        az = np.arcsin(rng.uniform(-1.0, 1.0, r.size)).astype(np.float32)
        ref = stage.reference(r, v, az, fb)
        _assert_same(stage.unalias(r, v, az, fb), ref)
        moved += int((ref.view(np.int32) != az.view(np.int32)).sum())
    assert moved > 0
