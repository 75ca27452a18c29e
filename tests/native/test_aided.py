"""The track-aided prediction kernel (edge/native/_aided.pyx) against its reference (PairStage.reference_predictions,
its plain-Python and array paths): the same tracks kept and the same ranges, speeds and beats bit for bit, on random
tracks (pairings on and just outside the gates, out of range, slow) and on a seeded hw_sim run through the lane
pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from edge.dsp.pairing import Pairs
from hw_sim import SIMO_BOARD
from tests.native.conftest import require_kernel


def _assert_same(a, b) -> None:
    assert (a is None) == (b is None)
    if a is not None:
        for x, y in zip(a, b):
            assert x.dtype == y.dtype == np.float64 and x.shape == y.shape
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("small", [10_000, -1])
def test_kernel_equals_reference_on_random_tracks(monkeypatch, small):
    require_kernel("_aided")
    from edge.lane import pairs as lane
    from edge.pipelines.lane import LaneConfig, LanePipeline

    monkeypatch.setattr(lane, "_AIDED_SMALL", small)  # the reference's plain-Python or its array path
    stage = LanePipeline(SIMO_BOARD.frontend, LaneConfig()).pairs
    assert stage._k_aided_pred is not None
    rng = np.random.default_rng(4)
    n_kept = 0
    for t in range(80):
        n = int(rng.integers(0, 25))
        x = np.stack([rng.uniform(-8.0, 8.0, n), rng.uniform(-20.0, 380.0, n), rng.normal(0.0, 0.5, n),
                      rng.choice([-30.0, -0.5, 25.0], n)], axis=1)
        dt = float(rng.choice([0.0, 0.033, 0.066]))
        xp, yp = x[:, 0] + x[:, 2] * dt, x[:, 1] + x[:, 3] * dt
        r = np.sqrt(xp * xp + yp * yp + 6.5 ** 2)
        v = (xp * x[:, 2] + yp * x[:, 3]) / np.maximum(r, 1e-9)
        k = rng.random(n) < 0.4  # some tracks already paired (within the gates), some just outside
        pr = (r[k] + rng.choice([0.0, 2.4, 2.6, -2.6], k.sum())).astype(np.float32)
        pv = (v[k] + rng.choice([0.0, 1.4, 1.6], k.sum())).astype(np.float32)
        if pr.size and t % 7 == 0:
            pr[0] = np.nan
        pairs = Pairs(np.zeros((pr.size, 4), np.int64), pr, pv, np.zeros(pr.size, np.float32), 0, 0)
        sel = np.flatnonzero(rng.random(n) < 0.8)
        ref = stage.reference_predictions(x, sel, dt, pairs)
        _assert_same(stage.aided_predictions(x, sel, dt, pairs), ref)
        n_kept += 0 if ref is None else ref[0].size
    assert n_kept > 100


def test_kernel_equals_reference_on_a_pipeline_run(monkeypatch):
    require_kernel("_aided")
    from edge.pipeline import StageTimer
    from tests.edge import lane_golden as g

    pipe, frames = g.build("highway4-traffic", 1, 5.0)
    stage = pipe.pairs
    real = stage.aided_predictions
    seen = {"calls": 0, "kept": 0}

    def both(track_state, sel, dt, pairs):
        out = real(track_state, sel, dt, pairs)
        _assert_same(out, stage.reference_predictions(track_state, sel, dt, pairs))
        seen["calls"] += 1
        seen["kept"] += 0 if out is None else out[0].size
        return out

    monkeypatch.setattr(stage, "aided_predictions", both)
    # (the fused selection and predictions declined: the stage predicts through aided_predictions, as it does for
    # arrays of other types; tests/native/test_aided_fit.py compares the fused kernel)
    monkeypatch.setattr(stage._k_aided_pred, "select_predictions", lambda *args: None)
    t = StageTimer(16)
    for f in frames(120):
        pipe.process(f, t)
    assert seen["calls"] > 50 and seen["kept"] > 20, seen


def test_arrays_are_checked():
    """The kernel reads its arrays through the numpy C API (edge/native/_views.pxi): another dtype or a strided
    column where a contiguous one is needed is refused, as the typed memoryviews did."""
    k = require_kernel("_aided")
    state = np.zeros((3, 4))
    sel = np.arange(3, dtype=np.int64)
    r = np.ones(2, np.float32)
    coef = np.ones(8)
    k.predictions(state, sel, 0.03, r, r, 1.0, 0.0, 100.0, 1.0, 1.0, coef)
    for i, bad in [(0, state.astype(np.float32)), (1, sel.astype(np.int32)), (3, np.ones(4, np.float32)[::2]),
                   (10, np.ones(16)[::2])]:
        args = [state, sel, 0.03, r, r, 1.0, 0.0, 100.0, 1.0, 1.0, coef]
        args[i] = bad
        with pytest.raises(ValueError):
            k.predictions(*args)
