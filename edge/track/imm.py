"""Interacting multiple model (IMM) maths for the lane tracker, batched over tracks (two modes).

A vehicle on a road keeps its lane almost all the time and changes lanes now and then. One constant-
velocity model must carry enough lateral process noise for the lane change, and that noise lets the
lateral position of a far vehicle, whose azimuth noise is a metre or more per frame, wander. The IMM
(Blom & Bar-Shalom 1988; with PDA: Houles & Bar-Shalom 1989, "IMM-PDAF") runs two models side by side
and weighs them by how well each explains the detections:

- mode 0, *lane keeping*: the velocity across the road decays to zero with time constant ``tau``
  (a vehicle moves along the road) and the white-noise acceleration across the road is tiny
  (``q_keep``); along the road it is the tracker's ``q_along``. The road direction is the radar's
  mounting yaw (``road_yaw_rad``; the traffic layer estimates it);
- mode 1, *manoeuvring*: the tracker's constant-velocity model with its lateral and along process
  noise (unchanged from the single-model tracker).

One cycle, for ``T`` tracks with mode states ``xm`` (T, 2, 4), covariances ``pm`` (T, 2, 4, 4) and
mode probabilities ``mu`` (T, 2), Markov switching matrix ``pi`` (2, 2) (``pi[i, j]`` = P(j | i)):

1. mixing: ``c_j = sum_i pi_ij mu_i``, ``w_ij = pi_ij mu_i / c_j``, mixed initial conditions
   ``x0_j = sum_i w_ij x_i``, ``P0_j = sum_i w_ij (P_i + (x_i - x0_j)(x_i - x0_j)')``;
2. mode-matched prediction ``x_j = F_j x0_j``, ``P_j = F_j P0_j F_j' + Q_j``;
3. data association once, on the moment-matched prediction (the tracker's PDAF/JPDA as before: gate,
   clutter density, ``beta``), then a PDAF update of every mode with those weights;
4. mode likelihood: the PDAF likelihood of the validated detections under the mode's own innovation
   covariance, ``L_j = (1 - P_D P_G) + sum_m P_D N(v_jm; 0, S_j) V / m`` (the common factor
   ``V^-m`` cancels), ``mu_j = L_j c_j / sum``;
5. output: the moment-matched mixture ``x = sum_j mu_j x_j``, ``P = sum_j mu_j (P_j + d d')``.

Everything is numpy over ``(T, 2, ...)``; no per-track Python loop.
"""

from __future__ import annotations

import math

import numpy as np

from edge.track.pdaf import Innovations

__all__ = [
    "switch_matrix",
    "keep_model",
    "mix",
    "predict_modes",
    "moment_match",
    "mode_likelihood",
    "mode_likelihood_each",
    "mode_likelihood_pairs",
    "update_mode_probabilities",
]


def switch_matrix(p_keep_to_manoeuvre: float, p_manoeuvre_to_keep: float) -> np.ndarray:
    """(2, 2) Markov mode transition matrix per frame, rows sum to 1 (mode 0 keep, mode 1 manoeuvre)."""
    return np.array([[1.0 - p_keep_to_manoeuvre, p_keep_to_manoeuvre],
                     [p_manoeuvre_to_keep, 1.0 - p_manoeuvre_to_keep]])


def keep_model(dt_s: float, yaw_rad: float, tau_s: float, q_across_m2ps3: float,
               q_along_m2ps3: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of the lane-keeping mode: across-road velocity decays as ``exp(-dt / tau)``, white-noise
    acceleration ``q_across`` across and ``q_along`` along the road (direction ``yaw_rad`` off the boresight,
    the convention of :func:`edge.traffic.lanes.to_road`: across ``(cos, sin)``, along ``(-sin, cos)``)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    decay = math.exp(-dt_s / tau_s) if tau_s > 0 else 1.0
    # rot diag(u, v) rot' with rot = [[c, -s], [s, c]] (columns: road across, road along) in closed form, with
    # Python floats: the road direction follows the traffic layer's yaw estimate, so this runs nearly every
    # frame, and a dozen tiny numpy calls cost more than the 4 x 4 matrices (issue 9)
    cc, ss, cs = c * c, s * s, c * s
    p00, p01, p11 = cc * decay + ss, cs * (decay - 1.0), ss * decay + cc  # phi = rot diag(decay, 1) rot'
    a00 = cc * q_across_m2ps3 + ss * q_along_m2ps3
    a01 = cs * (q_across_m2ps3 - q_along_m2ps3)
    a11 = ss * q_across_m2ps3 + cc * q_along_m2ps3
    f = np.array([[1.0, 0.0, dt_s, 0.0], [0.0, 1.0, 0.0, dt_s], [0.0, 0.0, p00, p01], [0.0, 0.0, p01, p11]])
    d3, d2, d1 = dt_s**3 / 3.0, dt_s**2 / 2.0, dt_s
    q = np.array([[d3 * a00, d3 * a01, d2 * a00, d2 * a01], [d3 * a01, d3 * a11, d2 * a01, d2 * a11],
                  [d2 * a00, d2 * a01, d1 * a00, d1 * a01], [d2 * a01, d2 * a11, d1 * a01, d1 * a11]])
    return f, q


def mix(xm: np.ndarray, pm: np.ndarray, mu: np.ndarray, pi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 1: ``xm`` (T, 2, 4), ``pm`` (T, 2, 4, 4), ``mu`` (T, 2) -> mixed ``x0``, ``p0`` and the predicted
    mode probabilities ``c`` (T, 2).

    With two modes ``x_i - x0_j`` is ``w_1j D`` or ``-w_0j D`` (``D = x_0 - x_1``), so the spread term
    ``sum_i w_ij d d'`` is ``w_0j w_1j D D'``: no (T, 2, 2, 4, 4) intermediate."""
    t = xm.shape[0]
    joint = mu[:, :, None] * (pi if pi.ndim == 3 else pi[None, :, :])  # (T, i, j) = pi_ij mu_i (pi: (2, 2) or per track)
    c = joint[:, 0] + joint[:, 1]  # (T, j): the sum over the two i
    w = joint / np.maximum(c, 1e-300)[:, None, :]  # (T, i, j)
    wt = w.swapaxes(1, 2)  # (T, j, i)
    x0 = wt @ xm  # (T, j, 4)
    d = xm[:, 0] - xm[:, 1]
    dd = (d[:, :, None] * d[:, None, :]).reshape(t, 1, 16)
    # sum_i w_ij P_i as one small matrix product over the flattened covariances (fewer broadcasting operations)
    p0 = wt @ pm.reshape(t, 2, 16)  # (T, j, 16)
    p0 += (w[:, 0] * w[:, 1])[:, :, None] * dd
    return x0, p0.reshape(t, 2, 4, 4), c


def predict_modes(x0: np.ndarray, p0: np.ndarray, f: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Step 2: ``f``, ``q`` (2, 4, 4) per mode -> predicted (T, 2, 4), (T, 2, 4, 4)."""
    xp = (x0[:, :, None, :] @ f.transpose(0, 2, 1)[None])[:, :, 0, :]
    pp = f[None] @ p0 @ f.transpose(0, 2, 1)[None] + q[None]
    return xp, pp


def moment_match(xm: np.ndarray, pm: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian with the mean and covariance of the mixture ``sum_j w_j N(xm_j, pm_j)`` of two modes:
    (T, 4), (T, 4, 4); the spread term is ``w_0 w_1 D D'``, ``D = x_0 - x_1``."""
    t = xm.shape[0]
    wr = w[:, None, :]  # (T, 1, 2)
    x = (wr @ xm)[:, 0]  # sum_j w_j x_j as small matrix products (fewer broadcasting operations)
    d = xm[:, 0] - xm[:, 1]
    d *= np.sqrt(w[:, 0] * w[:, 1])[:, None]
    p = (wr @ pm.reshape(t, 2, 16)).reshape(t, 4, 4)
    p += d[:, :, None] * d[:, None, :]  # every element is summed alike: symmetric inputs give a symmetric sum
    return x, p


def mode_likelihood(inn: Innovations, gated: np.ndarray, gate_volume: np.ndarray, prob_detect: float,
                    prob_gate: float) -> np.ndarray:
    """Step 4 for one mode: ``inn`` of the mode's prediction (T, M), ``gated`` (T, M) the detections the
    common gate validated, ``gate_volume`` (T,) that gate's volume -> (T,) likelihood up to a factor
    common to all modes of a track.

    Leading dimensions broadcast: all modes at once with ``inn`` of shapes (T, 2, M[, n]), ``gated``
    (T, 1, M) and ``gate_volume`` (T, 1) give (T, 2)."""
    n = inn.v.shape[-1]
    m_t = np.maximum(gated.sum(axis=-1), 1)
    norm = (2.0 * math.pi) ** (n / 2.0) * np.sqrt(inn.det_s)
    dens = np.where(gated, np.exp(-0.5 * np.minimum(inn.d2, 700.0)), 0.0).sum(axis=-1) / norm
    return (1.0 - prob_gate * prob_detect) + prob_detect * gate_volume / m_t * dens


def update_mode_probabilities(c: np.ndarray, lik: np.ndarray, floor: float) -> np.ndarray:
    """Step 4: ``mu_j = L_j c_j / sum`` (T, 2), kept at least ``floor`` so a mode can always come back."""
    mu = c * lik
    mu /= np.maximum(mu[:, 0:1] + mu[:, 1:2], 1e-300)  # the sum over the two modes
    mu = np.maximum(mu, floor)
    return mu / (mu[:, 0:1] + mu[:, 1:2])


def mode_likelihood_each(inn: Innovations, gated: np.ndarray, gate_volume: np.ndarray, prob_detect: float,
                         prob_gate: float) -> np.ndarray:
    """:func:`mode_likelihood` with one innovation covariance per (track, detection) (``inn.det_s`` (T, M),
    :func:`edge.track.pdaf.innovations_each`): ``N(v_jm; 0, S_jm)`` per detection."""
    n = inn.v.shape[2]
    m_t = np.maximum(gated.sum(axis=1), 1)
    norm = (2.0 * math.pi) ** (n / 2.0) * np.sqrt(inn.det_s)  # (T, M)
    dens = (np.where(gated, np.exp(-0.5 * np.minimum(inn.d2, 700.0)), 0.0) / norm).sum(axis=1)
    return (1.0 - prob_gate * prob_detect) + prob_detect * gate_volume / m_t * dens


def mode_likelihood_pairs(pin, n_rows: int, gate_volume: np.ndarray, n_gated: np.ndarray, prob_detect: float,
                          prob_gate: float) -> np.ndarray:
    """:func:`mode_likelihood_each` from the validated pairs only (``pin``: :class:`edge.track.pdaf.PairInnovations`
    of the mode rows): ``gate_volume`` and ``n_gated`` (number of validated detections) per row -> (n_rows,)."""
    n = pin.v.shape[1]
    dens = np.bincount(pin.t, np.exp(-0.5 * np.minimum(pin.d2, 700.0)) / ((2.0 * math.pi) ** (n / 2.0)
                                                                         * np.sqrt(pin.det_s)), minlength=n_rows)
    return (1.0 - prob_gate * prob_detect) + prob_detect * gate_volume / np.maximum(n_gated, 1) * dens
