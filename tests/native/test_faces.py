"""The near-face kernel (edge/native/_faces.pyx) against its numpy reference (NearFaces.reference: nearest_of_clusters
with its extent, then the body's along-road length): the same kept detections and body extents bit for bit, on random
detections (vehicles of several scatterers, values on the gates' edges, NaN) and on a seeded hw_sim run through the
lane pipeline."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge.lane.detections import NearFaces
from edge.lane.records import Candidates, Feedback
from edge.pipelines.lane import LaneConfig
from tests.native.conftest import require_kernel


def _assert_same(a: Candidates, b: Candidates) -> None:
    assert a.keep.dtype == b.keep.dtype == bool
    np.testing.assert_array_equal(a.keep, b.keep)
    assert a.body_extent_m.dtype == b.body_extent_m.dtype == np.float32
    np.testing.assert_array_equal(a.body_extent_m.view(np.int32), b.body_extent_m.view(np.int32))  # bits (NaN, -0)


def _random(rng, n: int, cfg) -> Candidates:
    """Vehicles of up to four scatterers along their length, some pairs exactly on the gates' edges."""
    n_veh = max(1, n // 3)
    r0 = rng.uniform(3.0, 200.0, n_veh).astype(np.float32)
    veh = rng.integers(0, n_veh, n)
    r = (r0[veh] + rng.choice([0.0, 1.0, 2.5, np.float32(cfg.cluster_length_m), 9.0], n)).astype(np.float32)
    v = (rng.choice([-25.0, -10.0, 0.0, 20.0], n_veh)[veh] + rng.choice([0.0, 0.5, cfg.cluster_speed_mps], n)
         ).astype(np.float32)
    x = (rng.uniform(-12.0, 12.0, n_veh)[veh] + rng.choice([0.0, 0.4, cfg.cluster_lateral_m, 3.0], n)
         ).astype(np.float32)
    if n > 3 and rng.random() < 0.3:
        x[rng.integers(0, n)] = np.nan
    keep = rng.random(n) < 0.9
    return Candidates(r, v, np.zeros(n, np.float32), x, np.zeros(n, np.float32), keep)


@pytest.mark.parametrize("seed", range(20))
def test_kernel_equals_reference_on_random_detections(seed):
    require_kernel("_faces")
    rng = np.random.default_rng(seed)
    cfg = dataclasses.replace(LaneConfig(), mounting_height_m=float(rng.choice([0.0, 6.0, 8.0])))
    stage = NearFaces(cfg)
    assert stage.kernel is not None
    n_drop = 0
    for n in (2, 3, 7, 20, 60):
        c = _random(rng, n, cfg)
        ref = stage.reference(c, Feedback.none())
        _assert_same(stage(c, Feedback.none()), ref)
        n_drop += int((~ref.keep).sum())
    assert n_drop > 5


def test_kernel_equals_reference_on_a_pipeline_run(monkeypatch):
    require_kernel("_faces")
    from edge.pipeline import StageTimer
    from tests.edge import lane_golden as g

    pipe, frames = g.build("highway4-traffic", 1, 5.0)
    faces = [f for f in pipe.detections.filters if isinstance(f, NearFaces)][0]
    assert faces.kernel is not None
    seen = {"frames": 0, "dets": 0, "dropped": 0}
    real = faces.__call__

    def both(c, fb):
        out = real(c, fb)
        _assert_same(out, faces.reference(c, fb))
        seen["frames"] += 1
        seen["dets"] += c.range_m.size
        seen["dropped"] += int((~out.keep).sum())
        return out

    monkeypatch.setattr(faces, "__call__", both)
    pipe.detections.filters = tuple(both if f is faces else f for f in pipe.detections.filters)
    t = StageTimer(16)
    for f in frames(120):
        pipe.process(f, t)
    assert seen["frames"] == 120 and seen["dets"] > 1000 and seen["dropped"] > 20, seen
