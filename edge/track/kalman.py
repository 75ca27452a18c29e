"""Constant-velocity Kalman filter maths, batched over tracks (state ``[x, y, vx, vy]``).

Stateless numpy functions with shapes in the docstrings (Stone Soup ``predictor/kalman.py`` and
``models/transition/linear.py`` in spirit, not in code). The filter runs in float64: it is
O(tracks), not O(samples), so the cost is negligible, and the covariance recursion is the one place
where float32 rounding would accumulate (a 4x4 covariance with position variances of 1e-2 m^2 next to
range-squared terms of 1e5 m^2). Detections arrive as float32 and are promoted once per frame.

Measurement models:

- position only: ``z = [x, y]`` (Lim eq. 16, the converted polar measurement), ``H`` linear;
- position and radial speed: ``z = [x, y, v_r]`` with ``v_r = (x vx + y vy) / sqrt(x^2 + y^2)``
  (positive receding), linearised at the prediction (extended Kalman filter).

The measurement noise of a converted polar measurement depends on where the target is
(``R = J diag(sigma_r^2, sigma_az^2) J^T`` at the predicted range and azimuth), so ``R`` is computed
per track at its prediction, one ``S`` per track, which keeps the PDAF gate an ellipse per track
(``measurement_noise = "constant"``). With ``measurement_noise = "snr"`` the sensor part of ``R`` is computed per
detection at its own position from its SNR (:func:`snr_polar_noise`), and ``S`` is per (track, detection)
(:mod:`edge.track.pdaf`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "cv_transition",
    "cv_process_noise",
    "predict",
    "polar_position_noise",
    "measurement_prediction",
    "snr_polar_noise",
    "lateral_predict",
    "lateral_pda_update",
    "lateral_inconsistent",
    "lateral_log_likelihood_ratio",
    "lateral_blend",
]


def cv_transition(dt_s: float) -> np.ndarray:
    """(4, 4) constant-velocity transition matrix for a time step ``dt_s``."""
    f = np.eye(4)
    f[0, 2] = f[1, 3] = dt_s
    return f


def cv_process_noise(dt_s: float, q_x_m2ps3: float, q_y_m2ps3: float) -> np.ndarray:
    """(4, 4) process noise of continuous white-noise acceleration with spectral densities ``q``.

    Per axis ``q * [[dt^3/3, dt^2/2], [dt^2/2, dt]]`` (the same model as Stone Soup's
    ``ConstantVelocity(noise_diff_coeff=q)``).
    """
    d3, d2, d1 = dt_s**3 / 3.0, dt_s**2 / 2.0, dt_s
    q = np.zeros((4, 4))
    for pos, vel, qa in ((0, 2, q_x_m2ps3), (1, 3, q_y_m2ps3)):
        q[pos, pos] = qa * d3
        q[pos, vel] = q[vel, pos] = qa * d2
        q[vel, vel] = qa * d1
    return q


def predict(x: np.ndarray, p: np.ndarray, f: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalman prediction of ``T`` tracks: ``x`` (T, 4), ``p`` (T, 4, 4) -> predicted (x, p)."""
    xp = x @ f.T
    pp = f @ p @ f.T + q
    return xp, pp


def polar_position_noise(xy: np.ndarray, range_sigma_m: float, az_sigma_rad: float, floor_sigma_m: float) -> np.ndarray:
    """(T, 2, 2) covariance of a converted polar position measurement at ground points ``xy`` (T, 2).

    ``x = r sin(az)``, ``y = r cos(az)`` (Lim eq. 16); ``J = [[sin az, r cos az], [cos az, -r sin az]]``.
    ``floor_sigma_m`` adds an isotropic variance (where on an extended vehicle the peak lands). The product
    ``J diag(d) J'`` is summed without BLAS, in the kernels' order: ``(jd_i0 j_k0) + (jd_i1 j_k1)``, ``jd = J diag(d)``.
    """
    r = np.hypot(xy[:, 0], xy[:, 1])
    r_safe = np.maximum(r, 1e-6)
    s, c = xy[:, 0] / r_safe, xy[:, 1] / r_safe
    j = np.empty((xy.shape[0], 2, 2))
    j[:, 0, 0], j[:, 0, 1] = s, r * c
    j[:, 1, 0], j[:, 1, 1] = c, -r * s
    d = np.array([range_sigma_m**2, az_sigma_rad**2])
    jd = j * d[None, None, :]
    rr = jd[:, :, None, 0] * j[:, None, :, 0] + jd[:, :, None, 1] * j[:, None, :, 1]
    rr[:, 0, 0] += floor_sigma_m**2
    rr[:, 1, 1] += floor_sigma_m**2
    return rr


def measurement_prediction(xp: np.ndarray, with_radial_speed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Predicted measurement ``z_hat`` (T, n) and Jacobian ``H`` (T, n, 4), n = 2 or 3.

    The radial-speed row is the ground-plane radial speed ``(x vx + y vy) / rho``,
    ``rho = sqrt(x^2 + y^2)``, differentiated at the prediction.
    """
    t = xp.shape[0]
    n = 3 if with_radial_speed else 2
    h = np.zeros((t, n, 4))
    h[:, 0, 0] = 1.0
    h[:, 1, 1] = 1.0
    zh = np.empty((t, n))
    zh[:, :2] = xp[:, :2]
    if with_radial_speed:
        x, y, vx, vy = xp[:, 0], xp[:, 1], xp[:, 2], xp[:, 3]
        rho = np.maximum(np.hypot(x, y), 1e-3)
        vr = (x * vx + y * vy) / rho
        zh[:, 2] = vr
        h[:, 2, 0] = (vx - vr * x / rho) / rho
        h[:, 2, 1] = (vy - vr * y / rho) / rho
        h[:, 2, 2] = x / rho
        h[:, 2, 3] = y / rho
    return zh, h


def snr_polar_noise(xy: np.ndarray, snr_db: np.ndarray, range_sigma0_m: float, range_floor_m: float,
                    az_sigma0_rad: float, az_floor_rad: float, floor_sigma_m: float,
                    snr_clip_db: tuple[float, float] = (0.0, 60.0)) -> np.ndarray:
    """(M, 2, 2) covariance of each converted polar detection at its own ground point ``xy`` (M, 2) from its
    SNR ``snr_db`` (M,): the Cramer-Rao form ``sigma^2 = sigma0^2 / snr + floor^2`` (``snr`` linear, clipped to
    ``snr_clip_db``) for the azimuth (``sigma0`` = the sd at 0 dB) and for the range, converted like
    :func:`polar_position_noise` (``J diag(sigma_r^2, sigma_az^2) J'`` plus ``floor_sigma_m^2`` isotropic).
    """
    # np.clip, without its wrapper
    snr = 10.0 ** (np.minimum(np.maximum(snr_db, snr_clip_db[0]), snr_clip_db[1]) / 10.0)
    var_r = range_sigma0_m**2 / snr + range_floor_m**2
    var_az = az_sigma0_rad**2 / snr + az_floor_rad**2
    r = np.hypot(xy[:, 0], xy[:, 1])
    r_safe = np.maximum(r, 1e-6)
    s, c = xy[:, 0] / r_safe, xy[:, 1] / r_safe
    rr2 = r * r * var_az
    out = np.empty((xy.shape[0], 2, 2))
    out[:, 0, 0] = s * s * var_r + c * c * rr2 + floor_sigma_m**2
    out[:, 1, 1] = c * c * var_r + s * s * rr2 + floor_sigma_m**2
    out[:, 0, 1] = out[:, 1, 0] = s * c * (var_r - rr2)
    return out


# --- the lane-keeping lateral estimate: a non-interacting straight-line filter across the boresight ---------------
#
# A vehicle that keeps its lane drives a straight line: its coordinate across the boresight is ``x(t) = x0 + vx t``
# (``vx`` = its speed along the road times the sine of the road's angle to the boresight, constant while it keeps
# its lane and speed). Its lateral position can then be averaged over every detection since it last manoeuvred.
# The IMM's lane-keeping mode cannot do that: each frame it is mixed with the manoeuvring mode, whose state follows
# the noise, and at the switching prior of a far vehicle (p = 0.002 per frame) that mixing injects ~20x the mode's
# own lateral process noise (highway4 motorcycle at 250 m: lateral speed sd 0.1-0.3 m/s in the keep mode against
# the 0.03 m/s of its q and tau; the same RMSE to three decimals with q_keep 0.002 and 1e-4). The straight-line
# filter below runs beside the IMM, outside its interaction: state ``[x, vx]`` per track, tiny process noise, the
# PDAF weights of the tracker's association, one gain per validated detection. It is reset to the IMM's estimate
# when the two disagree beyond their statistics (:func:`lateral_inconsistent`), or when the detections have been
# explained better by the IMM's predictions than by its own for a while (:func:`lateral_log_likelihood_ratio`, a
# CUSUM): a lane change.


def lateral_predict(xs: np.ndarray, ps: np.ndarray, dt_s: float, q_m2ps3: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity prediction of the straight-line state ``xs`` (T, 2) = ``[x, vx]``, ``ps`` (T, 2, 2) with
    white-noise acceleration density ``q_m2ps3`` (the 1-D blocks of :func:`cv_transition` and
    :func:`cv_process_noise`)."""
    x = np.empty_like(xs)
    x[:, 0] = xs[:, 0] + dt_s * xs[:, 1]
    x[:, 1] = xs[:, 1]
    p00, p01, p11 = ps[:, 0, 0], ps[:, 0, 1], ps[:, 1, 1]
    p = np.empty_like(ps)
    p[:, 0, 0] = p00 + 2.0 * dt_s * p01 + dt_s * dt_s * p11 + q_m2ps3 * dt_s**3 / 3.0
    p[:, 0, 1] = p[:, 1, 0] = p01 + dt_s * p11 + q_m2ps3 * dt_s**2 / 2.0
    p[:, 1, 1] = p11 + q_m2ps3 * dt_s
    return x, p


def lateral_pda_update(xs: np.ndarray, ps: np.ndarray, z: np.ndarray, r: np.ndarray, t: np.ndarray,
                       w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PDAF update of the straight-line state with a gain per hypothesis (the per-detection form of
    :mod:`edge.track.pdaf`, ``H = [1, 0]``): pairs ``(t[k], z[k])`` of track row and measured ``x`` with variance
    ``r[k]`` and association weight ``w[k]`` (``beta``; ``beta_0`` is implied). Per pair ``K = P[:, 0] / (P00 + r)``,
    ``dx = K (z - x)``; ``x += sum w dx``, ``P -= sum w K P[0, :] - (sum w dx dx' - dx_bar dx_bar')``."""
    n_t = xs.shape[0]
    if t.size == 0:
        return xs.copy(), ps.copy()
    pt = ps.take(t, axis=0)  # (P, 2, 2)
    k = pt[:, :, 0] / (pt[:, 0, 0] + r)[:, None]  # (P, 2)
    dx = k * (z - xs[t, 0])[:, None]
    wdx = dx * w[:, None]
    g = np.empty((t.size, 8))
    g[:, :2] = wdx
    g[:, 2:4] = k * w[:, None]
    g[:, 4:] = (wdx[:, :, None] * dx[:, None, :]).reshape(-1, 4)
    member = np.zeros((n_t, t.size))
    member[t, np.arange(t.size)] = 1.0
    sums = member @ g  # the per-row sums over its pairs
    dxbar = sums[:, :2]
    kbar = sums[:, 2:4]
    x = xs + dxbar
    p = ps - kbar[:, :, None] * ps[:, 0, None, :] + sums[:, 4:].reshape(n_t, 2, 2) - dxbar[:, :, None] * dxbar[:, None, :]
    p = 0.5 * (p + p.transpose(0, 2, 1))
    return x, p


def lateral_inconsistent(xs: np.ndarray, ps: np.ndarray, x_ref: np.ndarray, p_ref: np.ndarray, gamma: float,
                         min_fraction: float) -> np.ndarray:
    """(T,) bool: the straight-line estimate ``xs`` (T, 2) disagrees with the IMM's ``x_ref`` (T, 2) = ``[x, vx]``
    (covariance ``p_ref`` (T, 2, 2)) in position or in velocity. A Hausman test per component: the straight-line
    filter is efficient while the vehicle keeps its lane and the IMM consistent either way, so the variance of their
    difference is ``var_ref - var_s`` (kept at least ``min_fraction`` of ``var_ref``: both are model variances);
    ``d^2 / var > gamma`` (a chi-square quantile, 1 dof) in either component means the vehicle left the line."""
    d = xs - x_ref
    d *= d
    v_ref = p_ref.reshape(-1, 4)[:, 0::3]  # the diagonals (T, 2): one strided view
    var = np.maximum(v_ref - ps.reshape(-1, 4)[:, 0::3], min_fraction * v_ref)
    out = d[:, 0] > gamma * np.maximum(var[:, 0], 1e-12)
    out |= d[:, 1] > gamma * np.maximum(var[:, 1], 1e-12)
    return out


def lateral_log_likelihood_ratio(n_tracks: int, t: np.ndarray, w: np.ndarray, z: np.ndarray, r: np.ndarray,
                                 x_s: np.ndarray, var_s: np.ndarray, x_ref: np.ndarray,
                                 var_ref: np.ndarray) -> np.ndarray:
    """(T,) log-likelihood ratio of this frame's detections across the boresight under a reference prediction
    (the IMM's, ``x_ref``, ``var_ref`` (T,)) against the straight line's (``x_s``, ``var_s`` (T,)): per pair ``(t[k],
    z[k])`` with noise variance ``r[k]`` and association weight ``w[k]``, ``log N(z; x_ref, var_ref + r) -
    log N(z; x_s, var_s + r)``, summed over each track's pairs with the weights. Page's CUSUM of it,
    ``max(0, c + llr)``, grows while the vehicle leaves the straight line (and stays near 0 while it keeps it,
    where the straight line predicts better)."""
    if t.size == 0:
        return np.zeros(n_tracks)
    s_s = var_s.take(t) + r
    s_r = var_ref.take(t) + r
    v_s = z - x_s.take(t)
    v_r = z - x_ref.take(t)
    llr = 0.5 * (np.log(s_s / s_r) + v_s * v_s / s_s - v_r * v_r / s_r)
    return np.bincount(t, w * llr, minlength=n_tracks)


def lateral_blend(x_s: np.ndarray, x_ref: np.ndarray, cusum: np.ndarray, threshold: float) -> np.ndarray:
    """The published lateral position: the straight line's ``x_s``, moved towards the motion model's ``x_ref`` by
    the probability that the vehicle has left the line, ``p(c) = 1 / (1 + exp(threshold - c))`` for the CUSUM ``c``
    of :func:`lateral_log_likelihood_ratio` (log-odds against prior odds ``exp(-threshold)``; at the threshold the
    filter restarts from ``x_ref``), less its value without evidence: ``w = (p(c) - p(0)) / (1 - p(0))``, 0 while
    the CUSUM is 0. The change is followed while the evidence for it accumulates."""
    p0 = 1.0 / (1.0 + math.exp(min(threshold, 700.0)))
    p = 1.0 / (1.0 + np.exp(np.minimum(threshold - cusum, 700.0)))
    w = (p - p0) / (1.0 - p0)
    return x_s + w * (x_ref - x_s)
