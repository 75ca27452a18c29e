"""The surveillance back end's cheaper code paths compute what the numpy forms compute, bit for bit (issue 30).

The pipeline's outputs are pinned end to end by tests/native/test_surv_identity.py and the surveillance tests;
these tests pin the pieces on random inputs (hypothesis, seeded): numpy's pairwise float64 sum in plain Python,
and the radial speed estimator's current speed and mean |speed| against their numpy forms.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.classify.features import RadialSpeedEstimator, _np_sum


def _bits(x: float) -> str:
    return float(x).hex()


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.sampled_from([0, 1, 2, 7, 8, 9, 15, 16, 17, 127, 128, 129, 130, 255, 300, 1000]))
def test_np_sum_is_numpys_pairwise_sum(seed, n):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=n) * 10.0 ** rng.integers(-8, 17, size=n)
    x[rng.random(n) < 0.1] = 0.0
    x[rng.random(n) < 0.1] = -0.0
    assert _bits(_np_sum(x.tolist())) == _bits(np.add.reduce(x))
    z = np.where(rng.random(n) < 0.5, -0.0, 0.0)  # signed zeros only
    assert _bits(_np_sum(z.tolist())) == _bits(np.add.reduce(z))


def _estimator(rng: np.random.Generator, n: int, t0: float) -> RadialSpeedEstimator:
    e = RadialSpeedEstimator(5.35)
    t = t0
    for _ in range(n):
        t += 0.2 * int(rng.integers(1, 4))  # dropped frames too
        e.add(t, float(rng.uniform(0.0, 25.0)), float(rng.uniform(-5.35, 5.35)), 1.0, 2.0)
    return e


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.integers(1, 200), st.sampled_from([0.0, 37.4, 1e5, 3e8]))
def test_radial_speed_estimator_plain_paths_equal_numpy(seed, n, t0):
    rng = np.random.default_rng(seed)
    e = _estimator(rng, n, t0)
    a, b = e._current_radial_speed_kmh(), e._current_radial_speed_kmh_numpy()
    assert _bits(a) == _bits(b)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the mean of no speeds (one frame)
        ref = float(np.mean(np.abs(e.speeds_kmh()))) if len(e) >= 2 else math.nan
    assert _bits(e.mean_abs_speed_kmh()) == _bits(ref)


def test_current_speed_after_prepend_and_merge_equals_numpy():
    rng = np.random.default_rng(5)
    a, b, c = _estimator(rng, 30, 0.0), _estimator(rng, 20, 100.0), _estimator(rng, 25, 2.1)
    b.prepend(a)
    b.merge(c)
    assert _bits(b._current_radial_speed_kmh()) == _bits(b._current_radial_speed_kmh_numpy())
    assert _bits(b.mean_abs_speed_kmh()) == _bits(float(np.mean(np.abs(b.speeds_kmh()))))


def test_dealias_rounds_half_to_even_and_keeps_signed_zero():
    e = RadialSpeedEstimator(5.0)  # period 10 km/h
    # (rho - v) / period exactly -0.5, 0.5, 1.5, and a small negative quotient (np.rint gives -0.0)
    for t_v in ((0.0, 5.0), (0.0, -5.0), (0.0, -15.0), (0.0, 1.0), (0.0, -0.0)):
        e._v.clear()
        e._t.clear()
        e._r.clear()
        for k in range(4):
            e._t.append(0.2 * k)
            e._r.append(10.0 + t_v[0] * k)
            e._v.append(t_v[1])
        e._current = None
        assert _bits(e._current_radial_speed_kmh()) == _bits(e._current_radial_speed_kmh_numpy())
