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


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("n_tracks,n_det", [(0, 5), (4, 0), (1, 1), (12, 14), (30, 60)])
def test_track_extents_are_identical(seed, n_tracks, n_det):
    """The lane pipeline's per-track body extent (``LanePipeline.track_extents``) with the ``track_extents`` kernel
    against its numpy form: tracks on a detection's gates' edges, ties in range, NaN extents; bit for bit."""
    from types import SimpleNamespace

    from edge.pipelines.lane import LanePipeline, _TRACK_DET_RANGE_M, _TRACK_DET_SPEED_MPS
    from edge.types import Detections

    k = require_kernel("_faces")
    rng = np.random.default_rng(seed)
    d_rng = rng.choice([20.0, 20.5, 35.0, 80.25], n_det).astype(np.float32) + rng.choice([0.0, 0.5], n_det).astype(
        np.float32)
    d_v = rng.choice([-20.0, -10.0, 15.0], n_det).astype(np.float32)
    body = rng.uniform(0.0, 12.0, n_det).astype(np.float32)
    body[rng.random(n_det) < 0.2] = np.nan
    det = Detections(d_rng, d_v, np.zeros(n_det, np.float32), np.zeros(n_det, np.float32),
                     np.zeros(n_det, np.float32), d_rng.copy(), {"body_extent_m": body})
    tracks = tuple(SimpleNamespace(range_m=float(rng.choice([20.0, 21.5, 21.75, 36.0, 80.0, 150.0])
                                                 + rng.choice([0.0, _TRACK_DET_RANGE_M, 0.3])),
                                   radial_speed_mps=float(rng.choice([-20.0, -9.0, 15.0])
                                                          + rng.choice([0.0, _TRACK_DET_SPEED_MPS, -0.6])))
                   for _ in range(n_tracks))
    if n_tracks and n_det:  # the first track right on the first detection, which has an extent
        body[0] = 4.5
        tracks = (SimpleNamespace(range_m=float(d_rng[0]), radial_speed_mps=float(d_v[0])),) + tracks[1:]
    pipe = SimpleNamespace(_k_faces=None)
    want = LanePipeline.track_extents(pipe, tracks, det)
    pipe._k_faces = k
    got = LanePipeline.track_extents(pipe, tracks, det)
    assert got.dtype == want.dtype == np.float64 and got.shape == want.shape == (n_tracks,)
    np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))  # bits (NaN)
    if n_tracks and n_det:
        assert np.isfinite(got[0])  # (a detection no farther than the first in range: a finite extent)


def test_a_failing_track_extents_kernel_is_not_hidden():
    """``LanePipeline.track_extents`` picks the kernel by the columns' dtype and layout, not by catching its errors."""
    from types import SimpleNamespace

    from edge.pipelines.lane import LanePipeline
    from edge.types import Detections

    def boom(*_):
        raise TypeError("kernel failure")

    col = np.array([20.0, 40.0], np.float32)
    det = Detections(col, col, col, col, col, col, {"body_extent_m": np.array([4.0, 5.0], np.float32)})
    tracks = (SimpleNamespace(range_m=20.0, radial_speed_mps=20.0),)
    pipe = SimpleNamespace(_k_faces=SimpleNamespace(track_extents=boom))
    with pytest.raises(TypeError, match="kernel failure"):
        LanePipeline.track_extents(pipe, tracks, det)
    det.extra["body_extent_m"] = np.array([4.0, 5.0])  # float64: the numpy form, no call
    assert LanePipeline.track_extents(pipe, tracks, det).tolist() == [4.0]


def test_arrays_are_checked():
    """The kernels read their arrays through the numpy C API (edge/native/_views.pxi): float64, strided or non-array
    columns are refused, as the typed memoryviews did."""
    k = require_kernel("_faces")
    f = np.arange(8, dtype=np.float32)
    keep = np.ones(8, np.uint8)
    k.near_faces(f, f, f, keep, 5.0, 1.0, 1.0, 1.0)
    for bad in (f.astype(np.float64), np.arange(16, dtype=np.float32)[::2], f.tolist()):
        with pytest.raises((ValueError, TypeError)):
            k.near_faces(bad, f, f, keep, 5.0, 1.0, 1.0, 1.0)
