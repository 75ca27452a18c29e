"""Probabilistic data association (Lim et al. §III-B, eqs. 17-19), batched over tracks.

For ``T`` tracks and ``M`` detections of one frame, all in numpy (no per-detection objects):

1. validation (eq. 17): squared Mahalanobis distance ``d2[t, m] = v^T S_t^-1 v`` of every
   innovation ``v = z_m - z_hat_t``; a detection is validated for track ``t`` when ``d2 <= gamma``,
   ``gamma = chi2.ppf(P_G, n)`` (the gate threshold that holds the true measurement with probability
   ``P_G``).
2. non-parametric clutter density: ``lambda_t = M_t / V_t`` with ``M_t`` the number of validated
   detections and ``V_t = c_n gamma^(n/2) |S_t|^(1/2)`` the gate volume (``c_2 = pi``,
   ``c_3 = 4 pi / 3``), so every validated point is equally likely clutter.
3. association probabilities (eqs. 18-19): ``L = P_D N(v; 0, S) / lambda``,
   ``beta_m = L_m / (1 - P_G P_D + sum L)``, ``beta_0 = (1 - P_G P_D) / (1 - P_G P_D + sum L)``.
   Eq. 19 of the paper writes the 2-D normal density; the ``n``-dimensional one is used here so a
   radial-speed row can join the measurement.
4. combined update: ``x = x^- + K sum(beta_m v_m)``,
   ``P = beta_0 P^- + (1 - beta_0)(P^- - K S K^T) + K (sum beta_m v_m v_m^T - v v^T) K^T``.

``association = "jpda"`` replaces step 3 by Fitzgerald's "cheap JPDA" approximation: a detection
that lies in several gates has its weight shared, ``beta[t, m] = L[t, m] / (S_t + S_m - L[t, m] + B)``
with ``S_t``, ``S_m`` the row and column sums of ``L`` and ``B = 1 - P_G P_D``; for a detection in one
gate only it is exactly the PDAF weight, so it changes nothing for isolated vehicles and stops two
close tracks from pulling on the same points (track coalescence, id swaps when vehicles cross).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from edge.track.smallmat import inv_det

__all__ = ["gate_threshold", "unit_ball_volume", "Innovations", "innovations", "association_weights", "combined_update"]


def gate_threshold(prob_gate: float, n: int) -> float:
    """``gamma`` of eq. 17: the chi-square quantile of ``P_G`` with ``n`` degrees of freedom."""
    return float(chi2.ppf(prob_gate, n))


def unit_ball_volume(n: int) -> float:
    """``c_n`` = volume of the unit ball in ``n`` dimensions (pi for 2, 4 pi / 3 for 3)."""
    return math.pi ** (n / 2.0) / math.gamma(n / 2.0 + 1.0)


@dataclass
class Innovations:
    """Innovations of ``T`` tracks against ``M`` detections of dimension ``n``."""

    v: np.ndarray  # (T, M, n) z_m - z_hat_t
    d2: np.ndarray  # (T, M) squared Mahalanobis distance
    s: np.ndarray  # (T, n, n) innovation covariance
    s_inv: np.ndarray  # (T, n, n)
    det_s: np.ndarray  # (T,)


def _quad_terms(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ij = [(i, j) for i in range(n) for j in range(i, n)]
    return (np.array([i for i, _ in ij]), np.array([j for _, j in ij]),
            np.array([1.0 if i == j else 2.0 for i, j in ij]))


_QUAD_TERMS = {n: _quad_terms(n) for n in (1, 2, 3)}


def innovations(z: np.ndarray, z_hat: np.ndarray, h: np.ndarray, p: np.ndarray, r: np.ndarray) -> Innovations:
    """``z`` (M, n), ``z_hat`` (T, n), ``h`` (T, n, 4), ``p`` (T, 4, 4), ``r`` (T, n, n)."""
    s = h @ p @ h.transpose(0, 2, 1) + r
    s = 0.5 * (s + s.transpose(0, 2, 1))
    s_inv, det_s = inv_det(s)
    n = z.shape[1]
    v = z[None, :, :] - z_hat[:, None, :]  # (T, M, n)
    # d2 = v' S^-1 v expanded over the symmetric n x n terms (cheaper than tiny batched matmuls), all terms
    # S^-1_ij v_i v_j (doubled off the diagonal) in one product, summed in the order i <= j
    ii, jj, twice = _QUAD_TERMS[n]
    terms = (s_inv[:, ii, jj] * twice)[:, None, :] * v[:, :, ii] * v[:, :, jj]  # (T, M, n (n + 1) / 2)
    d2 = np.add.reduce(terms, axis=2)  # fewer than 8 terms: summed one after the other (no pairwise blocks)
    return Innovations(v, d2, s, s_inv, det_s)


def association_weights(
    inn: Innovations,
    gamma: float,
    prob_detect: float,
    prob_gate: float,
    method: str = "pdaf",
    allowed: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Association probabilities: ``beta`` (T, M), ``beta0`` (T,), ``gated`` (T, M) bool.

    Rows of ``beta`` plus ``beta0`` sum to 1. ``method`` is ``"pdaf"`` (eq. 18) or ``"jpda"``.
    ``allowed`` (T, M) bool, optional, removes pairs before validation (e.g. tentative tracks may not
    use detections a confirmed track validated).
    """
    t, m = inn.d2.shape
    n = inn.v.shape[2]
    gated = inn.d2 <= gamma
    if allowed is not None:
        gated &= allowed
    m_t = gated.sum(axis=1)
    b = 1.0 - prob_gate * prob_detect
    if m == 0 or t == 0:
        return np.zeros((t, m)), np.ones(t), gated
    vol = unit_ball_volume(n) * gamma ** (n / 2.0) * np.sqrt(inn.det_s)  # (T,)
    norm = (2.0 * math.pi) ** (n / 2.0) * np.sqrt(inn.det_s)  # (T,)
    # L = P_D N(v; 0, S) V / M  (eq. 19 with lambda = M / V), zero outside the gate
    scale = prob_detect * vol / (norm * np.maximum(m_t, 1))  # (T,)
    lik = np.where(gated, np.exp(-0.5 * np.minimum(inn.d2, gamma)) * scale[:, None], 0.0)
    s_t = lik.sum(axis=1)  # (T,)
    if method == "pdaf":
        beta = lik / (b + s_t)[:, None]
        beta0 = b / (b + s_t)
    elif method == "jpda":
        s_m = lik.sum(axis=0)  # (M,)
        beta = lik / (s_t[:, None] + s_m[None, :] - lik + b)
        beta0 = 1.0 - beta.sum(axis=1)
    else:
        raise ValueError(f"unknown association method {method!r}: choose pdaf or jpda")
    return beta, beta0, gated


def combined_update(
    xp: np.ndarray, pp: np.ndarray, h: np.ndarray, inn: Innovations, beta: np.ndarray, beta0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """PDAF state estimation: ``xp`` (T, 4), ``pp`` (T, 4, 4) -> posterior (x, P).

    ``P = beta0 P^- + (1 - beta0)(P^- - K S K') + K spread K'`` is evaluated as
    ``P^- + K (spread - (1 - beta0) S) K'`` (two small matrix products fewer). Leading dimensions broadcast:
    the IMM updates both modes at once with ``xp`` (T, 2, 4), ``inn`` of shapes (T, 2, ...) and the common
    weights ``beta`` (T, 1, M), ``beta0`` (T, 1)."""
    k = pp @ h.swapaxes(-1, -2) @ inn.s_inv  # (..., 4, n)
    v = inn.v  # (..., M, n)
    vbar = beta[..., None, :] @ v  # (..., 1, n)
    kt = k.swapaxes(-1, -2)
    x = xp + (vbar @ kt)[..., 0, :]
    spread = (v * beta[..., :, None]).swapaxes(-1, -2) @ v - vbar.swapaxes(-1, -2) * vbar
    spread -= (1.0 - beta0)[..., None, None] * inn.s
    p = pp + k @ spread @ kt
    p = 0.5 * (p + p.swapaxes(-1, -2))
    return x, p
