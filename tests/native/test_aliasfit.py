"""The alias fit's candidate kernel (edge/native/_aliasfit.pyx) against its numpy reference
(features.fit_candidates_reference): the same best candidate, rivals' verdict and frames on the path, on random
range histories (bin-quantised edges with exact ties, clutter outliers, frames at zero Doppler, gaps, 2-48 frames),
through RadialSpeedEstimator.fit_alias with and without the kernel, and on a seeded surveillance run."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge import native
from edge.classify import features
from edge.classify.features import RadialSpeedEstimator, fit_candidates_reference
from tests.native.conftest import require_kernel

VMAX = 5.35  # km/h: the Distance2Go's unambiguous radial speed
BIN = 0.75  # m: its range bin


def _history(rng: np.random.Generator, n: int) -> RadialSpeedEstimator:
    est = RadialSpeedEstimator(VMAX)
    v = float(rng.choice([rng.uniform(-110, 110), rng.uniform(-8, 8), 0.0]))
    r0 = float(rng.uniform(3.0, 40.0))
    length = float(rng.choice([0.5, 2.0, 4.5, 12.0]))
    t = 0.0
    for _ in range(n):
        t += 0.2 * float(rng.choice([1, 1, 1, 2, 3]))  # missed frames
        r = r0 + v / 3.6 * t + float(rng.normal(0.0, 0.2))
        vw = (v + float(rng.normal(0.0, 0.3)) + VMAX) % (2 * VMAX) - VMAX
        if rng.random() < 0.15:  # a frame that held static clutter
            r, vw = float(rng.uniform(2.0, 30.0)), float(rng.normal(0.0, 0.2))
        lo = BIN * math.floor(r / BIN)
        hi = lo + BIN * max(1, round(length * float(rng.uniform(0.3, 1.0)) / BIN))
        if rng.random() < 0.2:
            lo = hi = math.nan
        est.add(t, r if rng.random() < 0.5 else lo + 0.5 * (hi - lo) if math.isfinite(lo) else r, vw, lo, hi)
    return est


@pytest.mark.parametrize("seed", range(12))
def test_kernel_equals_reference_on_random_candidates(seed):
    kernel = require_kernel("_aliasfit")
    rng = np.random.default_rng(seed)
    ties = 0
    for _ in range(150):
        n = int(rng.integers(1, 49))
        t = np.cumsum(0.2 * rng.choice([1, 1, 2], n))
        vw = rng.uniform(-VMAX, VMAX, n)
        vw[rng.random(n) < 0.2] = 0.0
        obs = [np.round(rng.normal(10.0, 3.0, n) / BIN) * BIN for _ in range(int(rng.choice([1, 3])))]
        for x in obs:
            x[rng.random(n) < 0.2] = np.nan
        refs = float(rng.uniform(-VMAX, VMAX)) + 2 * VMAX / 4 * np.arange(int(rng.integers(1, 40)))
        period, tol2, margin2 = 2 * VMAX, 0.75 ** 2, 0.75 ** 2 * float(rng.choice([0.0, 1.0, 2.5]))
        lower = np.zeros((len(obs), n), dtype=np.uint8)
        lower[0] = rng.random(n) < float(rng.choice([0.0, 0.3]))  # frames where the centroid is a lower bound
        want = fit_candidates_reference(t, vw, refs, obs, period, 1.5, tol2, VMAX, margin2, lower.view(bool))
        on = np.empty(n, dtype=np.uint8)
        best, clear = kernel.fit_candidates(t, vw, refs, np.array(obs), lower, period, 1.5, tol2, VMAX, margin2, on)
        assert (best, clear) == want[:2]
        np.testing.assert_array_equal(on.view(bool), want[2])
        ties += int(np.count_nonzero(np.isin(obs[0], obs[0][~np.isnan(obs[0])][:1])) > 1)
    assert ties > 20  # quantised observables: equal residuals and tied costs were exercised


@pytest.mark.parametrize("seed", range(8))
def test_fit_alias_with_and_without_the_kernel(seed, monkeypatch):
    require_kernel("_aliasfit")
    rng = np.random.default_rng(100 + seed)
    histories = [_history(rng, int(rng.integers(2, 60))) for _ in range(60)]
    calls = [dict(last_frames=0), dict(last_frames=25), dict(last_frames=25, around_kmh=float(rng.uniform(-60, 60))),
             dict(edge_m=0.0, margin_frames=2.0), dict(edge_limit_m=21.0), dict(last_frames=25, edge_limit_m=21.0)]
    fast = [[h.fit_alias(**c) for c in calls] for h in histories]
    real_load = native.load
    monkeypatch.setattr(features.native, "load", lambda name: None if name == "_aliasfit" else real_load(name))
    slow = [[h.fit_alias(**c) for c in calls] for h in histories]
    certain = 0
    for fh, sh in zip(fast, slow):
        for (v1, r1, c1, p1), (v2, r2, c2, p2) in zip(fh, sh):
            np.testing.assert_array_equal(v1, v2)
            assert (r1 == r2 or (math.isnan(r1) and math.isnan(r2))) and c1 == c2
            np.testing.assert_array_equal(p1, p2)
            certain += c1
    assert certain > 20  # both verdicts occur


def test_refuses_more_frames_than_the_offsets_cover():
    kernel = require_kernel("_aliasfit")
    n = 49
    with pytest.raises(ValueError):
        kernel.fit_candidates(np.arange(n, dtype=float), np.zeros(n), np.zeros(3), np.zeros((1, n)),
                              np.zeros((1, n), dtype=np.uint8), 10.7, 1.5, 0.5625, VMAX, 0.5625,
                              np.empty(n, dtype=np.uint8))
