"""The detection-stage kernel (edge/native/_detect.pyx) against its numpy reference (DetectionStage.reference with
every filter's numpy form): the same detections, every column and extra column bit for bit, on random angles over
random lane layouts (vehicles with bodies, values on the gates' edges, NaN) under several configurations,
and on seeded hw_sim runs through the lane pipeline."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge.lane.detections import DetectionStage
from edge.lane.records import Angles, Feedback
from edge.lane.road import RoadFrame
from edge.pipelines.lane import LaneConfig
from edge.traffic.lanes import Lane
from edge.types import Detections
from tests.native.conftest import require_kernel

CONFIGS = [{}, {"cluster_length_m": 0.0}, {"unalias_by_lane": False}, {"cluster_speed_mps": 0.3},
           {"mounting_height_m": 0.0, "cluster_lateral_m": 3.0},
           {"mounting_height_m": 7.3, "target_height_m": 0.45, "cluster_speed_mps": 0.7}]


def _frontend():
    from hw_sim.scenario import load_scenario_for_eval

    return load_scenario_for_eval("highway4-traffic").sim_board().frontend


def _numpy_stage(stage: DetectionStage) -> DetectionStage:
    """``stage`` with every filter on its numpy form (the reference of the per-filter kernels too)."""
    import copy

    ref = copy.deepcopy(stage)
    ref.kernel = None
    for f in ref.direction_filters + ref.filters:
        f.kernel = None
    return ref


def _bits(a: np.ndarray) -> np.ndarray:
    return a.view(np.uint8) if a.dtype == bool else a.view(f"u{a.dtype.itemsize}")


def assert_same_detections(a: Detections, b: Detections) -> None:
    for name in ("range_m", "radial_speed_mps", "az_rad", "snr_db", "x_m", "y_m"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(_bits(x), _bits(y), err_msg=name)
    assert list(a.extra) == list(b.extra)
    for name in a.extra:
        x, y = a.extra[name], b.extra[name]
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(_bits(x), _bits(y), err_msg=name)


def _random(rng, n: int, cfg, lanes) -> tuple[Angles, Feedback]:
    """Vehicles of up to four scatterers along their length, others a lane or two across, some against their lane's
    direction (grating-lobe aliases), some gates' edges exactly; NaN angles and ranges now and then."""
    centres = [ln.center_m for ln in lanes] or [0.0]
    n_veh = max(1, n // 3)
    veh = rng.integers(0, n_veh, n)
    r = (rng.uniform(3.0, 150.0, n_veh)[veh]
         + rng.choice([0.0, 1.0, 2.5, np.float32(cfg.cluster_length_m), 20.0], n)).astype(np.float32)
    v = (rng.choice([-25.0, -10.0, 0.0, 20.0], n_veh)[veh]
         + rng.choice([0.0, 0.3, cfg.cluster_speed_mps, 1.0], n)).astype(np.float32)
    u = (rng.choice(centres, n_veh)[veh] + rng.choice([0.0, 0.4, cfg.cluster_lateral_m, 3.5, -3.5, 7.0], n))
    az = np.arcsin(np.clip(u / np.maximum(r, 1.0), -1.0, 1.0)).astype(np.float32)
    if n > 3 and rng.random() < 0.5:
        az[rng.integers(0, n)] = np.nan
    if n > 3 and rng.random() < 0.2:
        r[rng.integers(0, n)] = np.nan
    pair = np.full(n, -1, np.int32)
    pair[: n // 4] = np.arange(n // 4, dtype=np.int32) // 2
    unresolved = (rng.random(n) < 0.2) if rng.random() < 0.7 else None
    a = Angles(r, v, rng.uniform(0.0, 3.0, n).astype(np.float32), az, rng.uniform(5.0, 40.0, n).astype(np.float32),
               pair, unresolved, np.zeros((n, 3), np.float32))
    fb = dataclasses.replace(Feedback.none(), lanes=lanes, yaw_rad=float(rng.normal(0.0, 0.03)))
    return a, fb


@pytest.mark.parametrize("seed", range(30))
def test_kernel_equals_reference_on_random_detections(seed):
    require_kernel("_detect")
    rng = np.random.default_rng(seed)
    cfg = dataclasses.replace(LaneConfig(), **CONFIGS[seed % len(CONFIGS)])
    stage = DetectionStage(_frontend(), cfg, RoadFrame())
    assert stage.kernel is not None
    ref = _numpy_stage(stage)
    n_drop = n_all = 0
    for n in (0, 1, 2, 3, 7, 20, 60, 60):
        n_l = int(rng.integers(0, 7))
        c0 = float(rng.uniform(-3.0, 3.0))
        lanes = tuple(Lane(c0 + (k - (n_l - 1) / 2) * 3.5, 3.5, 1 if k >= n_l / 2 else -1) for k in range(n_l))
        a, fb = _random(rng, n, cfg, lanes)
        want = ref(a, fb)
        assert_same_detections(stage(a, fb), want)
        assert_same_detections(stage.reference(a, fb), want)  # (the per-filter kernels)
        n_drop += n - len(want)
        n_all += n
    if cfg.cluster_length_m > 0:
        assert 0 < n_drop < n_all


def test_kernel_refuses_other_dtypes_and_the_stage_falls_back():
    k = require_kernel("_detect")
    n = 4
    f = np.ones(n, np.float32)
    args = (f, f, f, f, f, f, f, np.zeros(n, np.int32), None, np.float32(6.5), True, np.float32(17), np.float32(0.6),
            np.float32(1.5), np.float32(42.25))
    assert len(k.finish(*args)) == 10
    for i, bad in [(0, f.astype(np.float64)), (1, f[::-1]), (2, f.byteswap().view(f.dtype.newbyteorder())),
                   (7, np.zeros(n, np.int64)), (8, np.zeros(n, np.uint8)), (3, f[:3])]:
        with pytest.raises((ValueError, TypeError)):
            k.finish(*args[:i], bad, *args[i + 1:])
    stage = DetectionStage(_frontend(), LaneConfig(), RoadFrame())
    rng = np.random.default_rng(3)
    a, fb = _random(rng, 20, stage.config, (Lane(-1.75, 3.5, -1), Lane(1.75, 3.5, 1)))
    want = _numpy_stage(stage)(a, fb)
    a64 = dataclasses.replace(a, snr_db=a.snr_db.astype(np.float64))
    got = stage(a64, fb)  # float64 SNR: the reference path
    assert got.snr_db.dtype == np.float64
    np.testing.assert_array_equal(got.snr_db, want.snr_db)


@pytest.mark.parametrize("scenario", ["highway4-traffic", "wrong-way-traffic"])
def test_kernel_equals_reference_on_a_pipeline_run(monkeypatch, scenario):
    require_kernel("_detect")
    from edge.pipeline import StageTimer
    from tests.edge import lane_golden as g

    pipe, frames = g.build(scenario, 1, 5.0)
    stage = pipe.detections
    assert stage.kernel is not None
    ref = _numpy_stage(stage)
    seen = {"calls": 0, "dets": 0, "dropped": 0}
    real = stage.__call__

    def both(a, fb):
        out = real(a, fb)
        want = ref(a, fb)
        assert_same_detections(out, want)
        seen["calls"] += 1
        seen["dets"] += a.range_m.size
        seen["dropped"] += a.range_m.size - len(out)
        return out

    monkeypatch.setattr(stage, "__call__", both)
    monkeypatch.setattr(pipe, "detections", both)
    t = StageTimer(16)
    for f in frames(160):
        pipe.process(f, t)
    assert seen["calls"] > 100 and seen["dets"] > 300 and seen["dropped"] > 10, seen
