"""Closed-form inverses, determinants and quadratic forms of stacks of tiny matrices (2x2, 3x3).

The tracker's matrices are a few per track; ``np.linalg.inv``/``det``/``solve`` on a stack of a few tens
of 3x3 matrices spend most of their time in the wrapper and the per-matrix LAPACK calls (50-90 us for
the 3 x 20 innovation covariances of a busy frame), while the cofactor formulas are a dozen elementwise
numpy operations over the whole stack. They agree with LAPACK to rounding (a few ulps for the
well-conditioned covariances here: LU pivoting and the cofactor expansion round differently).

Everything works on any leading dimensions: ``a`` is ``(..., n, n)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["inv_det", "inv_quad2"]


def _adjugate_index() -> np.ndarray:
    # adj[i, j] = C[j, i] = a[j+1, i+1] a[j+2, i+2] - a[j+1, i+2] a[j+2, i+1] (indices mod 3): the four factor
    # planes of the 3 x 3 adjugate as flat indices into the row-major 3 x 3 matrix
    idx = [3 * ((j + ro) % 3) + (i + co) % 3
           for ro, co in ((1, 1), (2, 2), (1, 2), (2, 1)) for i in range(3) for j in range(3)]
    return np.array(idx)


_ADJ3 = _adjugate_index()
_SIGN2 = np.array([[1.0, -1.0], [-1.0, 1.0]])


def inv_det(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(inv(a), det(a))`` of a stack ``a`` (..., n, n), n = 2 or 3 (other sizes use ``np.linalg``).
    A singular matrix gives inf/nan entries instead of raising."""
    n = a.shape[-1]
    lead = a.shape[:-2]
    if n == 3:
        a9 = a.reshape(-1, 9).T  # (9, N): one contiguous row per matrix element
        g = a9[_ADJ3].reshape(4, 9, -1)
        adj = g[0] * g[1]
        adj -= g[2] * g[3]
        det = a9[0] * adj[0] + a9[1] * adj[3] + a9[2] * adj[6]  # first row of a times first column of adj
        return (adj / det).T.reshape(a.shape), det.reshape(lead)
    if n == 2:
        det = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
        inv = a[..., ::-1, ::-1].swapaxes(-1, -2) * _SIGN2 / det[..., None, None]
        return inv, det
    return np.linalg.inv(a), np.linalg.det(a)


def inv_quad2(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``v' a^-1 v`` for a stack of 2x2 matrices ``a`` (..., 2, 2) and vectors ``v`` (..., 2)."""
    v0, v1 = v[..., 0], v[..., 1]
    num = a[..., 1, 1] * v0 * v0 - (a[..., 0, 1] + a[..., 1, 0]) * v0 * v1 + a[..., 0, 0] * v1 * v1
    return num / (a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0])
