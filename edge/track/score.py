"""Score-based track confirmation: the sequential log-likelihood-ratio track score (Blackman & Popoli 1999,
§6.2; the PDA form of Musicki et al.'s IPDA), next to the M-of-N rule of :class:`edge.track.roles.confirm.Confirmer`.

A tentative track is either a vehicle (H1) or a run of false detections (H0). Per frame its score ``L`` (the log
of the likelihood ratio of H1 to H0 over its life) grows by the log of this frame's ratio

    LR = 1 - P_D P_G + P_D sum_m N(v_m; 0, S_m) / lambda

over the detections ``m`` in its gate (the PDAF's own innovations ``v_m`` and covariances ``S_m``; a tentative
track's gate holds only the detections no more senior track validated), ``lambda`` the density of false detections
in the measurement space (x, y and, when measured, the radial speed). A frame without a validated detection
adds ``ln(1 - P_D P_G)`` (-2.2 with P_D = 0.9, P_G = 0.99); a detection where the track expected it adds
``ln(P_D N / lambda)``, large when the innovation covariance is small (a strong, near detection) and the
false-detection density low. Wald's sequential test confirms at

    L >= ln((1 - beta) / alpha)

with ``alpha`` the probability that a false track confirms and ``beta`` that a true one is dropped: a consistent
near car confirms in two or three frames, a far one whose detections are weak and whose gate is metres wide
only after many frames (the M-of-N rule stays beside it: the scores do not slow anything down).

The score starts at 0 on the seed frame (prior odds of one: a seed is as likely a vehicle as not). All work is
elementwise over the tracks x detections arrays the association already computed: about ten numpy calls per
frame, whatever the number of tracks.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["confirm_threshold", "false_density", "score_increment"]


def confirm_threshold(false_confirm_prob: float, true_reject_prob: float) -> float:
    """Wald's upper threshold ``ln((1 - beta) / alpha)``."""
    return math.log((1.0 - true_reject_prob) / false_confirm_prob)


def false_density(density_m2: float, speed_span_mps: float, n: int) -> float:
    """``lambda`` in the measurement space of dimension ``n``: per m^2 (position) and, for ``n = 3``, spread
    uniformly over ``speed_span_mps`` of radial speed."""
    return density_m2 / speed_span_mps if n == 3 else density_m2


def score_increment(d2: np.ndarray, det_s: np.ndarray, gated: np.ndarray, n: int, prob_detect: float,
                    prob_gate: float, density: float) -> np.ndarray:
    """(T,) ``ln LR`` of each track for this frame.

    ``d2`` (T, M) squared Mahalanobis distances, ``det_s`` (T,) or (T, M) ``|S|`` (one innovation covariance per
    track, or per track and detection), ``gated`` (T, M) the validated pairs, ``n`` the measurement dimension and
    ``density`` ``lambda`` of :func:`false_density` for it."""
    miss = 1.0 - prob_detect * prob_gate
    if d2.shape[1] == 0:
        return np.full(d2.shape[0], math.log(miss))
    root = np.sqrt(det_s)
    if root.ndim == 1:
        root = root[:, None]
    g = np.exp(-0.5 * np.where(gated, d2, np.inf)) / root  # N(v; 0, S) (2 pi)^(n/2), zero outside the gate
    s = np.add.reduce(g, axis=1)
    return np.log(miss + (prob_detect / (density * (2.0 * math.pi) ** (n / 2.0))) * s)
