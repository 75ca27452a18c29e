"""Closed-form small-matrix inverses and quadratic forms agree with numpy.linalg (edge.track.smallmat)."""

import numpy as np
import pytest

from edge.track.smallmat import inv_det, inv_quad2


def _spd(rng, shape, n):
    a = rng.normal(size=shape + (n, n))
    return a @ a.swapaxes(-1, -2) + 0.1 * np.eye(n)


@pytest.mark.parametrize("n", [2, 3, 4])
@pytest.mark.parametrize("shape", [(1,), (37,), (5, 7), ()])
def test_inv_det_matches_linalg(n, shape):
    rng = np.random.default_rng(n * 100 + len(shape))
    a = _spd(rng, shape, n)
    inv, det = inv_det(a)
    assert inv.shape == a.shape and det.shape == shape
    np.testing.assert_allclose(inv, np.linalg.inv(a), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(det, np.linalg.det(a), rtol=1e-12)


def test_inv_det_of_a_general_matrix_and_a_strided_stack():
    rng = np.random.default_rng(3)
    big = rng.normal(size=(6, 4, 4))
    a = big[:, 1:, :3]  # not contiguous, not symmetric
    inv, det = inv_det(a)
    np.testing.assert_allclose(inv, np.linalg.inv(a), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(det, np.linalg.det(a), rtol=1e-10, atol=1e-12)
    inv2, det2 = inv_det(big[:, :2, 1:3])
    np.testing.assert_allclose(inv2, np.linalg.inv(big[:, :2, 1:3]), rtol=1e-9, atol=1e-9)


def test_inv_quad2_matches_solve():
    rng = np.random.default_rng(4)
    a = _spd(rng, (3, 11), 2)
    v = rng.normal(size=(3, 11, 2))
    ref = (v[..., None, :] @ np.linalg.solve(a, v[..., None]))[..., 0, 0]
    np.testing.assert_allclose(inv_quad2(a, v), ref, rtol=1e-12)
