"""The alpha-beta kernels (edge/native/_alphabeta.pyx) against their numpy references (the same objects with
``kernel = None``): the cylinder projections, the filter's predict and update and the associator's gated cost matrix
and greedy pairs, bit for bit, on random states and centroids (hypothesis, seeded; gate ties, NaN, empty sets)."""

from __future__ import annotations

import copy
import pickle

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.track.alphabeta import BenedictBordnerFilter, GreedyAssociator
from edge.track.cylinder import Cylinder
from tests.native.conftest import require_kernel

CYL = Cylinder(5.35)


def _plain(obj):
    ref = copy.copy(obj)
    ref.kernel = None
    return ref


def _same(a, b) -> None:
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    np.testing.assert_array_equal(a, b, strict=True)


def _states(rng: np.random.Generator, n: int) -> np.ndarray:
    s = rng.normal(0.0, 2.0, (n, 6))
    s[:, 4] = rng.uniform(0.0, 25.0, n)
    s[rng.random(n) < 0.1, 0:4:2] = 0.0  # on the axis: angle 0
    return s


@settings(max_examples=80, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.integers(0, 6), st.floats(0.05, 1.0))
def test_projections_predict_update_equal_reference(seed, n, alpha):
    require_kernel("_alphabeta")
    rng = np.random.default_rng(seed)
    s = _states(rng, n)
    m = s[:, [0, 2, 4]] + rng.normal(0.0, 0.5, (n, 3))
    _same(CYL.project_states(s), _plain(CYL).project_states(s))
    _same(CYL.project_points(m), _plain(CYL).project_points(m))
    f = BenedictBordnerFilter(alpha, CYL)
    ref = _plain(f)
    ref.cylinder = _plain(CYL)
    _same(f.predict(s), ref.predict(s))
    _same(f.update(s, m), ref.update(s, m))
    _same(f.initiate(m), ref.initiate(m))


@settings(max_examples=120, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.integers(0, 5), st.integers(0, 5), st.sampled_from(["last_measurement",
                                                                                          "prediction"]),
       st.booleans(), st.booleans())
def test_associate_equals_reference(seed, n, m, reference, range_gate, ties):
    require_kernel("_alphabeta")
    rng = np.random.default_rng(seed)
    if ties:  # a few distinct positions: equal costs, the first in row-major order wins
        grid = np.array([[1.0, 0.0, 5.0], [0.0, 1.0, 5.0], [1.0, 0.0, 6.0]])
        pred, last, cen = grid[rng.integers(0, 3, n)], grid[rng.integers(0, 3, n)], grid[rng.integers(0, 3, m)]
    else:
        pred = rng.normal(0.0, 2.0, (n, 3))
        last = pred + rng.normal(0.0, 1.0, (n, 3))
        cen = rng.normal(0.0, 2.0, (m, 3))
    if n and rng.random() < 0.2:
        pred[rng.integers(0, n), 1] = np.nan
    gate = rng.uniform(0.5, 6.0, n) if range_gate else None
    if gate is not None and n:
        gate[rng.random(n) < 0.3] = np.inf
    a = GreedyAssociator(3.0, reference)
    assert a.kernel is not None
    got, want = a.associate(pred, last, cen, gate), _plain(a).associate(pred, last, cen, gate)
    for x, y in zip(got, want):
        _same(x, y)


def test_kernel_users_copy_and_pickle():
    require_kernel("_alphabeta")
    for obj in (CYL, BenedictBordnerFilter(0.19, CYL), GreedyAssociator(3.0)):
        for other in (copy.deepcopy(obj), pickle.loads(pickle.dumps(obj))):
            assert other.kernel is obj.kernel
