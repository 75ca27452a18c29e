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
import scipy.special

from edge.track.smallmat import inv_det

__all__ = ["gate_threshold", "unit_ball_volume", "Innovations", "innovations", "mahalanobis_d2", "association_weights",
           "combined_update", "InnovationsEach", "hph_product", "innovations_each", "PairBuffers",
           "gate_volume_each", "PairInnovations",
           "pair_innovations", "combined_update_pairs"]


def gate_threshold(prob_gate: float, n: int) -> float:
    """``gamma`` of eq. 17: the chi-square quantile of ``P_G`` with ``n`` degrees of freedom."""
    # chi2.ppf(P_G, n) = 2 P^-1(n / 2, P_G), P^-1 the inverse regularised lower incomplete gamma function (what
    # scipy.stats.chi2 evaluates; scipy.stats is not imported for it: slow to import)
    return float(2.0 * scipy.special.gammaincinv(n / 2.0, prob_gate))


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


def _quad_terms(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    ij = [(i, j) for i in range(n) for j in range(i, n)]
    return (np.array([i for i, _ in ij]), np.array([j for _, j in ij]),
            np.array([1.0 if i == j else 2.0 for i, j in ij]), np.array([n * i + j for i, j in ij]))


_QUAD_TERMS = {n: _quad_terms(n) for n in (1, 2, 3)}


def innovations(z: np.ndarray, z_hat: np.ndarray, h: np.ndarray, p: np.ndarray, r: np.ndarray,
                kernel=None) -> Innovations:
    """``z`` (M, n), ``z_hat`` (T, n), ``h`` (T, n, 4), ``p`` (T, 4, 4), ``r`` (T, n, n). ``kernel``: the compiled
    ``edge.native._track`` for the distances (bit-identical), or None for numpy."""
    s = h @ p @ h.transpose(0, 2, 1) + r
    s = 0.5 * (s + s.transpose(0, 2, 1))
    s_inv, det_s = inv_det(s)
    v = z[None, :, :] - z_hat[:, None, :]  # (T, M, n)
    if kernel is not None and v.shape[2] in (2, 3):
        return Innovations(v, kernel.quad_d2(v, np.ascontiguousarray(s_inv)), s, s_inv, det_s)
    return Innovations(v, _quad(v, s_inv), s, s_inv, det_s)


def _quad(v: np.ndarray, s_inv: np.ndarray) -> np.ndarray:
    """(T, M) ``v' S_t^-1 v`` of innovations ``v`` (T, M, n) with one symmetric ``S_t^-1`` (T, n, n) per track."""
    # expanded over the symmetric n x n terms (cheaper than tiny batched matmuls), all terms
    # S^-1_ij v_i v_j (doubled off the diagonal) in one product, summed in the order i <= j
    n = v.shape[2]
    ii, jj, twice, flat = _QUAD_TERMS[n]
    sij = s_inv.reshape(-1, n * n).take(flat, axis=1)  # (T, n (n + 1) / 2) distinct entries, one take
    terms = (sij * twice)[:, None, :] * v.take(ii, axis=2) * v.take(jj, axis=2)  # (T, M, n (n + 1) / 2)
    return np.add.reduce(terms, axis=2)  # fewer than 8 terms: summed one after the other (no pairwise blocks)


def mahalanobis_d2(v: np.ndarray, s: np.ndarray, kernel=None) -> np.ndarray:
    """(T, M) squared Mahalanobis distances of innovations ``v`` (T, M, n) under one covariance per track
    ``s`` (T, n, n): the ``d2`` of :func:`innovations` for innovations already computed. ``kernel``: the compiled
    ``edge.native._track`` (the same arithmetic), or None for numpy."""
    s_inv = inv_det(s)[0]
    if kernel is not None and v.shape[2] in (2, 3):
        return kernel.quad_d2(np.ascontiguousarray(v), np.ascontiguousarray(s_inv))
    return _quad(v, s_inv)


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
    use detections a confirmed track validated). ``inn`` with one ``S`` per track or, an
    :class:`InnovationsEach`, per (track, detection) (``L_tm = P_D N(v; 0, S_tm) V_t / M_t``).
    """
    if isinstance(inn, InnovationsEach):
        return _association_weights_each(inn, gamma, prob_detect, prob_gate, method, allowed)
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
    """PDAF state estimation: ``xp`` (T, 4), ``pp`` (T, 4, 4) -> posterior (x, P). An :class:`InnovationsEach`
    (one ``S`` per (track, detection)) takes the update with one gain per hypothesis (:func:`combined_update_pairs`).

    ``P = beta0 P^- + (1 - beta0)(P^- - K S K') + K spread K'`` is evaluated as
    ``P^- + K (spread - (1 - beta0) S) K'`` (two small matrix products fewer). Leading dimensions broadcast:
    the IMM updates both modes at once with ``xp`` (T, 2, 4), ``inn`` of shapes (T, 2, ...) and the common
    weights ``beta`` (T, 1, M), ``beta0`` (T, 1)."""
    if isinstance(inn, InnovationsEach):
        return _combined_update_each(xp, pp, h, inn, beta, beta0)
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


# --- measurement-dependent noise: one R per detection (its SNR), so one S per (track, detection) ----------------
#
# With ``R_m`` per detection the innovation covariance is ``S_tm = H_t P_t H_t' + R_t + R_m`` (``R_t``: the
# track's own part, the extent of its vehicle; ``R_m``: the sensor noise of detection ``m``). Each association
# hypothesis ``m`` then has its own gain ``K_tm = P_t H_t' S_tm^-1`` and the PDAF posterior is the moment-matched
# mixture of the per-hypothesis Kalman posteriors (Bar-Shalom, Daum & Huang 2009, eq. 39 with ``K`` inside the sum):
#
#     x = x^- + sum_m beta_m K_m v_m
#     P = P^- - (sum_m beta_m K_m) H P^- + sum_m beta_m dx_m dx_m' - dx dx',   dx_m = K_m v_m,  dx = sum_m beta_m dx_m
#
# (``beta_0`` keeps ``x^-, P^-``). With a common ``R`` this is exactly :func:`combined_update`. The gate of a
# detection is its own ellipse ``v' S_tm^-1 v <= gamma``; the likelihoods use ``N(v; 0, S_tm)``; the clutter density
# ``M_t / V_t`` uses the mean gate volume of the validated detections, ``V_t = c_n gamma^(n/2) mean_m |S_tm|^(1/2)``
# (with one validated detection ``L`` does not depend on ``S``, as with the common ``R``).

@dataclass
class InnovationsEach(Innovations):
    """:class:`Innovations` with one ``S`` per (track, detection): ``s``, ``s_inv`` (T, M, n, n),
    ``det_s`` (T, M); ``s_track`` (T, n, n) is ``H P H' + R_t`` without the detections' noise."""

    s_track: np.ndarray | None = None
    #: (T,) gate volume of the validated detections, set by :func:`association_weights` (the IMM update reuses it)
    gate_volume: np.ndarray | None = None


def _sym_inv_det(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and determinant of symmetric 2x2 or 3x3 matrices ``s`` (..., n, n) in closed form (batched over
    tracks x detections, where ``np.linalg.inv`` on thousands of tiny matrices costs more than the maths):
    :func:`edge.track.smallmat.inv_det`, whose cofactors of a symmetric matrix are those of the symmetric
    formulas bit for bit, in a third of the numpy calls."""
    return inv_det(s)


def _quad_each(v: np.ndarray, s_inv: np.ndarray) -> np.ndarray:
    """``v' S^-1 v`` with one ``S^-1`` per innovation: ``v`` (..., n), ``s_inv`` (..., n, n) symmetric -> (...).
    All terms ``S^-1_ij v_i v_j`` (doubled off the diagonal) in one product, summed in the order i <= j (as
    :func:`innovations` does per track)."""
    n = v.shape[-1]
    ii, jj, twice, flat = _QUAD_TERMS[n]
    # the distinct entries of S^-1 with one take (not 2-D fancy indexing)
    sij = s_inv.reshape(s_inv.shape[:-2] + (n * n,)).take(flat, axis=-1)
    return np.add.reduce(sij * twice * v.take(ii, axis=-1) * v.take(jj, axis=-1), axis=-1)


#: relative margin of the pre-gate's bound (rounding of the exact distance near the gate never crosses it)
_PREGATE_MARGIN = 1e-6
#: track x detection pairs from which the pre-gate pays (below, its bookkeeping costs more than the inverses it saves:
#: 20 x 16 pairs 124 -> 172 us, 30 x 30 235 -> 188 us, 90 x 140 3.9 -> 1.1 ms, thread CPU time)
_PREGATE_MIN_PAIRS = 512


class PairBuffers:
    """Reusable storage for the (track, detection) arrays of :func:`innovations_each`'s kernel path: ``v``, ``S`` and
    ``S^-1`` of every pair (with 64+ tracks about 0.7 MB each). Fresh arrays of that size come from the allocator as
    new pages each frame (glibc returns large blocks to the OS), and the page faults cost several times the
    arithmetic; one grown buffer is written in place instead. The arrays returned are views, valid until the next
    frame that uses the same buffers. Copies and pickles start empty."""

    def __init__(self) -> None:
        self._flat: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def flat(self, t: int, m: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The three float64 buffers, each at least ``t * m * n * n`` long (grown, by at least half, when too small):
        the kernel makes ``v``, ``s`` and ``s_inv`` of their starts. Their contents are undefined."""
        need = t * m * n * n
        if self._flat is None or self._flat[1].size < need:
            size = max(need, 0 if self._flat is None else self._flat[1].size * 3 // 2, 1024)
            self._flat = (np.empty(size), np.empty(size), np.empty(size))
        return self._flat

    def views(self, t: int, m: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """C-contiguous float64 views ``v`` (t, m, n), ``s`` and ``s_inv`` (t, m, n, n) of the buffers (:meth:`flat`);
        their contents are undefined."""
        fv, fs, fsi = self.flat(t, m, n)
        need = t * m * n * n
        return (fv[:t * m * n].reshape(t, m, n), fs[:need].reshape(t, m, n, n), fsi[:need].reshape(t, m, n, n))

    def __getstate__(self) -> dict:
        return {}

    def __setstate__(self, state: dict) -> None:
        self._flat = None

    def __deepcopy__(self, memo) -> "PairBuffers":
        return PairBuffers()


def hph_product(h: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``H P H'`` (T, n, n) of ``h`` (T, n, 4) and ``p`` (T, 4, 4) without BLAS, in one fixed order of float64
    operations that the kernels repeat: ``(HP)_ij = ((h_i0 p_0j + h_i1 p_1j) + h_i2 p_2j) + h_i3 p_3j``, then
    ``(HPH')_ij = (((HP)_i0 h_j0 + (HP)_i1 h_j1) + (HP)_i2 h_j2) + (HP)_i3 h_j3``."""
    hp = (h[:, :, 0, None] * p[:, None, 0, :] + h[:, :, 1, None] * p[:, None, 1, :]
          + h[:, :, 2, None] * p[:, None, 2, :] + h[:, :, 3, None] * p[:, None, 3, :])  # (T, n, 4)
    return (hp[:, :, None, 0] * h[:, None, :, 0] + hp[:, :, None, 1] * h[:, None, :, 1]
            + hp[:, :, None, 2] * h[:, None, :, 2] + hp[:, :, None, 3] * h[:, None, :, 3])


def innovations_each(z: np.ndarray, z_hat: np.ndarray, h: np.ndarray, p: np.ndarray, r_track: np.ndarray,
                     r_meas: np.ndarray, prune_gamma: float | None = None, kernel=None,
                     buffers: PairBuffers | None = None) -> InnovationsEach:
    """``z`` (M, n), ``z_hat`` (T, n), ``h`` (T, n, 4), ``p`` (T, 4, 4), ``r_track`` (T, n, n) the track's part of
    ``R``, ``r_meas`` (M, n, n) each detection's part: ``S_tm = H_t P_t H_t' + r_track_t + r_meas_m``
    (``H P H'`` of :func:`hph_product`).

    ``prune_gamma``: an exact pre-gate. A marginal Mahalanobis distance never exceeds the joint one,
    ``v' S^-1 v >= v_i^2 / S_ii`` for every component ``i``, so a pair with ``v_i^2 > gamma S_ii`` in any component
    lies outside every gate of threshold ``gamma`` or less; ``S`` is inverted only for the other pairs. A pruned pair
    gets ``d2 = inf``, ``S = S^-1 = 0`` and ``|S| = 1`` (outside the gate none of them is read). Applied from
    ``_PREGATE_MIN_PAIRS`` pairs on.

    ``kernel``: the compiled ``edge.native._track``, which computes the pairs (pre-gate, ``S``, its inverse and
    determinant, ``d2``) in one pass with the same arithmetic (bit-identical); None: numpy. ``buffers``: the kernel
    writes ``v``, ``S`` and ``S^-1`` into these (:class:`PairBuffers`; the result's arrays are then views, valid until
    their next use)."""
    if kernel is not None and z.shape[1] in (2, 3):
        prune = prune_gamma is not None and z_hat.shape[0] * z.shape[0] >= _PREGATE_MIN_PAIRS
        lim = prune_gamma * (1.0 + _PREGATE_MARGIN) if prune else 0.0
        flat = None if buffers is None else buffers.flat(z_hat.shape[0], z.shape[0], z.shape[1])
        v, d2, s, s_inv, det_s, st = kernel.innovations_each(z, z_hat, h, p, r_track, np.ascontiguousarray(r_meas),
                                                             lim, prune, flat)
        return InnovationsEach(v, d2, s, s_inv, det_s, st)
    st = hph_product(h, p) + r_track
    st = 0.5 * (st + st.transpose(0, 2, 1))
    v = z[None, :, :] - z_hat[:, None, :]  # (T, M, n)
    if prune_gamma is not None and v.shape[0] * v.shape[1] >= _PREGATE_MIN_PAIRS:
        n = v.shape[2]
        lim = prune_gamma * (1.0 + _PREGATE_MARGIN)
        dg_t = np.diagonal(st, axis1=1, axis2=2)  # (T, n)
        dg_m = np.diagonal(r_meas, axis1=1, axis2=2)  # (M, n)
        far = v[:, :, 0] * v[:, :, 0] > lim * (dg_t[:, None, 0] + dg_m[None, :, 0])
        for i in range(1, n):
            far |= v[:, :, i] * v[:, :, i] > lim * (dg_t[:, None, i] + dg_m[None, :, i])
        if far.any():
            ti, mi = np.nonzero(~far)
            t, m = far.shape
            s = np.zeros((t, m, n, n))
            s_inv = np.zeros((t, m, n, n))
            det_s = np.ones((t, m))
            d2 = np.full((t, m), np.inf)
            if ti.size:
                sp = st.take(ti, axis=0) + r_meas.take(mi, axis=0)  # the same sums as st[:, None] + r_meas[None]
                sp_inv, det_p = _sym_inv_det(sp)
                s[ti, mi], s_inv[ti, mi], det_s[ti, mi] = sp, sp_inv, det_p
                d2[ti, mi] = _quad_each(v[ti, mi], sp_inv)
            return InnovationsEach(v, d2, s, s_inv, det_s, st)
    s = st[:, None] + r_meas[None]  # (T, M, n, n)
    s_inv, det_s = _sym_inv_det(s)
    return InnovationsEach(v, _quad_each(v, s_inv), s, s_inv, det_s, st)


def gate_volume_each(inn: InnovationsEach, gated: np.ndarray, gamma: float, n_gated: np.ndarray | None = None,
                     root: np.ndarray | None = None) -> np.ndarray:
    """(T,) ``V_t = c_n gamma^(n/2) mean_m |S_tm|^(1/2)`` over the validated detections (over all when none).
    ``n_gated`` (``gated.sum(axis=1)``) and ``root`` (``sqrt(inn.det_s)``): if already computed."""
    n = inn.v.shape[2]
    root = np.sqrt(inn.det_s) if root is None else root
    k = np.add.reduce(gated, axis=1) if n_gated is None else n_gated  # ndarray.sum without its wrapper
    mean_root = np.add.reduce(root * gated, axis=1) / np.maximum(k, 1)
    if not k.all():  # a track without a validated detection: the mean over all (np.mean's sum / count)
        mean_root = np.where(k > 0, mean_root, np.add.reduce(root, axis=1) / root.shape[1] if root.shape[1] else 1.0)
    return unit_ball_volume(n) * gamma ** (n / 2.0) * mean_root


def _association_weights_each(
    inn: "InnovationsEach",
    gamma: float,
    prob_detect: float,
    prob_gate: float,
    method: str = "pdaf",
    allowed: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`association_weights` with one ``S`` per (track, detection)."""
    t, m = inn.d2.shape
    n = inn.v.shape[2]
    gated = inn.d2 <= gamma
    if allowed is not None:
        gated &= allowed
    b = 1.0 - prob_gate * prob_detect
    if m == 0 or t == 0:
        return np.zeros((t, m)), np.ones(t), gated
    m_t = np.add.reduce(gated, axis=1)  # the sums as ufunc reductions: ndarray.sum's value without its wrapper
    root = np.sqrt(inn.det_s)
    vol = inn.gate_volume = gate_volume_each(inn, gated, gamma, m_t, root)  # (T,)
    norm = (2.0 * math.pi) ** (n / 2.0) * root  # (T, M)
    scale = prob_detect * vol / np.maximum(m_t, 1)  # (T,)
    lik = np.where(gated, np.exp(-0.5 * np.minimum(inn.d2, gamma)) * scale[:, None] / norm, 0.0)
    s_t = np.add.reduce(lik, axis=1)
    if method == "pdaf":
        beta = lik / (b + s_t)[:, None]
        beta0 = b / (b + s_t)
    elif method == "jpda":
        s_m = np.add.reduce(lik, axis=0)
        beta = lik / (s_t[:, None] + s_m[None, :] - lik + b)
        beta0 = 1.0 - np.add.reduce(beta, axis=1)
    else:
        raise ValueError(f"unknown association method {method!r}: choose pdaf or jpda")
    return beta, beta0, gated


@dataclass
class PairInnovations:
    """Innovations of selected (track row, detection) pairs only (``P`` pairs, e.g. the validated ones): rows
    ``t`` (P,), detections ``m`` (P,), ``v`` (P, n), ``d2`` (P,), ``s_inv`` (P, n, n), ``det_s`` (P,)."""

    t: np.ndarray
    m: np.ndarray
    v: np.ndarray
    d2: np.ndarray
    s_inv: np.ndarray
    det_s: np.ndarray


def pair_innovations(z: np.ndarray, z_hat: np.ndarray, h: np.ndarray, p: np.ndarray, r_track: np.ndarray,
                     r_meas: np.ndarray, t: np.ndarray, m: np.ndarray,
                     position_scale: np.ndarray | None = None) -> PairInnovations:
    """:func:`innovations_each` for the pairs ``(t[k], m[k])`` only (the per-mode rows of the IMM need the validated
    pairs, not all tracks x detections). ``position_scale`` (P,): the position block of the track's part of ``R``
    scaled per pair (``extent_near_side_factor``)."""
    rt = r_track[t]  # a copy (fancy indexing): scaled in place
    if position_scale is not None:
        rt[:, :2, :2] *= position_scale[:, None, None]
    s = (h @ p @ h.transpose(0, 2, 1))[t] + rt
    s = 0.5 * (s + s.transpose(0, 2, 1)) + r_meas[m]
    s_inv, det_s = _sym_inv_det(s)
    v = z.take(m, axis=0) - z_hat.take(t, axis=0)
    return PairInnovations(t, m, v, _quad_each(v, s_inv), s_inv, det_s)


def combined_update_pairs(xp: np.ndarray, pp: np.ndarray, h: np.ndarray, pin: PairInnovations,
                          w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The per-hypothesis PDAF update (comment above :class:`InnovationsEach`) over pairs: ``w`` (P,) the weight
    ``beta`` of each pair (the pairs with ``beta > 0`` suffice; ``beta_0`` is implied)."""
    t = xp.shape[0]
    if pin.t.size == 0:
        return xp.copy(), pp.copy()
    n_p, n = pin.v.shape
    ph = pp @ h.transpose(0, 2, 1)  # (T, 4, n)
    k = ph.take(pin.t, axis=0) @ pin.s_inv  # (P, 4, n)
    dx = (k @ pin.v[:, :, None])[:, :, 0]  # (P, 4)
    wdx = dx * w[:, None]
    # the three weighted sums over each row's pairs (sum w dx, sum w K, sum w dx dx') in one product with the
    # (T, P) row-membership matrix (np.add.at three times costs three times as much; the sums are sequential over
    # the few pairs of a row, in pair order, either way)
    g = np.empty((n_p, 4 + 4 * n + 16))
    g[:, :4] = wdx
    np.multiply(k.reshape(n_p, 4 * n), w[:, None], out=g[:, 4:4 + 4 * n])
    g[:, 4 + 4 * n:] = (wdx[:, :, None] * dx[:, None, :]).reshape(n_p, 16)
    member = np.zeros((t, n_p))
    member[pin.t, np.arange(n_p)] = 1.0
    sums = member @ g
    dxbar = sums[:, :4]
    kbar = sums[:, 4:4 + 4 * n].reshape(t, 4, n)
    spread = sums[:, 4 + 4 * n:].reshape(t, 4, 4)
    x = xp + dxbar
    p = pp - kbar @ ph.transpose(0, 2, 1) + spread - dxbar[:, :, None] * dxbar[:, None, :]
    p = 0.5 * (p + p.transpose(0, 2, 1))
    return x, p


def _combined_update_each(
    xp: np.ndarray, pp: np.ndarray, h: np.ndarray, inn: InnovationsEach, beta: np.ndarray, beta0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """PDAF state estimation with a gain per hypothesis (see the comment above :class:`InnovationsEach`):
    ``xp`` (T, 4), ``pp`` (T, 4, 4) -> posterior (x, P). ``beta0`` is implied (``1 - sum beta``); only the pairs
    with ``beta > 0`` are computed (:func:`combined_update_pairs`)."""
    t, m = np.nonzero(beta > 0)
    pin = PairInnovations(t, m, inn.v[t, m], inn.d2[t, m], inn.s_inv[t, m], inn.det_s[t, m])
    return combined_update_pairs(xp, pp, h, pin, beta[t, m])
