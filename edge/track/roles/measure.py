"""Measurement-model role: predicted measurement, Jacobian and noise ``R`` per track, the innovations of every
track x detection pair and the per-mode update that depends on their form. Two implementations:
:class:`ConstantNoiseModel` (one ``R`` per track at its prediction, Lim) and :class:`SnrNoiseModel` (one sensor
``R`` per detection from its SNR, the Cramer-Rao form ``sigma^2 = sigma0^2 / SNR + floor^2``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from edge import native
from edge.track import kalman
from edge.track.config import MeasurementConfig
from edge.track.pdaf import (Innovations, PairBuffers, PairInnovations, combined_update, combined_update_pairs,
                             gate_volume_each, innovations, innovations_each, mahalanobis_d2, pair_innovations,
                             unit_ball_volume)
from edge.track import imm
from edge.track.table import Measurements

__all__ = ["MeasurementModel", "ConstantNoiseModel", "SnrNoiseModel", "MeasurementPrediction", "Prediction",
           "heading", "extent_cov", "height_cov"]


@dataclass
class Prediction:
    """The predictor's output: the (combined) state ``x`` (T, 4), ``p`` (T, 4, 4); with an IMM also the per-mode
    states ``xm`` (T, 2, 4), ``pm`` (T, 2, 4, 4) and predicted mode probabilities ``c`` (T, 2)."""

    x: np.ndarray
    p: np.ndarray
    xm: np.ndarray | None = None
    pm: np.ndarray | None = None
    c: np.ndarray | None = None


@dataclass
class MeasurementPrediction:
    """``zh`` (T, n), ``h`` (T, n, 4), ``r`` (T, n, n) the track's part of ``R``, ``rm`` (M, n, n) each detection's part
    (or None), ``inn`` the innovations of the combined prediction; per mode (rows (track, mode)) ``zhm``, ``hm`` and,
    with the constant model, ``inn_m``."""

    zh: np.ndarray
    h: np.ndarray
    r: np.ndarray
    rm: np.ndarray | None
    inn: Innovations
    zhm: np.ndarray | None = None
    hm: np.ndarray | None = None
    inn_m: Innovations | None = None


def heading(xp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit heading (T, 2) and weight (T,) in [0, 1] (0 when standing, 1 from 1 m/s)."""
    sp = np.hypot(xp[:, 2], xp[:, 3])
    u = xp[:, 2:4] / np.maximum(sp, 1e-9)[:, None]
    return u, np.minimum(np.maximum(sp, 0.0), 1.0)  # np.clip, without its wrapper


_EYE2 = np.eye(2)[None]  # (1, 2, 2)


def extent_cov(xp: np.ndarray, ext_var: np.ndarray, head: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(T, 2, 2) spread of an extended vehicle's detections: ``ext_var`` along the heading (isotropic while the
    heading is unknown). ``head``: ``heading(xp)`` if already computed."""
    u, w = heading(xp) if head is None else head
    uu = u[:, :, None] * u[:, None, :]
    iso = _EYE2 * (1.0 - w)[:, None, None]
    return ext_var[:, None, None] * (w[:, None, None] * uu + iso)


def height_cov(r: np.ndarray, xy: np.ndarray, vr: np.ndarray | None, dz_m: float, var_m2: float) -> None:
    """Add to ``r`` (K, n, n), in place, the rank-one noise of a scatterer's unknown height at the ground points ``xy``
    (K, >= 2) with ground radial speeds ``vr`` (K,; None: n = 2). A scatterer ``dh`` above the assumed height
    (``dz_m`` below the radar) appears ``dz_m dh / rho`` nearer and its radial speed ``vr dz_m dh / rho^2`` faster:
    ``r += var_m2 g g'``, ``g = dz_m / rho^2 (-x, -y[, vr])``, ``rho`` at least 1 m. The kernels repeat these
    operations."""
    x, y = xy[:, 0], xy[:, 1]
    rho = np.maximum(np.hypot(x, y), 1.0)
    k = dz_m / (rho * rho)
    g0, g1 = -x * k, -y * k
    s0, s1 = var_m2 * g0, var_m2 * g1
    c01 = s0 * g1
    r[:, 0, 0] += s0 * g0
    r[:, 0, 1] += c01
    r[:, 1, 0] += c01
    r[:, 1, 1] += s1 * g1
    if vr is not None and r.shape[1] == 3:
        g2 = vr * k
        c02, c12 = s0 * g2, s1 * g2
        r[:, 0, 2] += c02
        r[:, 2, 0] += c02
        r[:, 1, 2] += c12
        r[:, 2, 1] += c12
        r[:, 2, 2] += (var_m2 * g2) * g2


class MeasurementModel(native.KernelUser):
    """What both noise models share: ``z_hat``, ``H`` and the track's part of ``R`` at its prediction (the extent of
    an extended vehicle: ``extent_sigma_m`` across, the learned ``ext_var`` along its heading, isotropic below 1 m/s;
    the radial-speed noise), and the learning of ``ext_var``."""

    per_detection = False

    def __init__(self, cfg: MeasurementConfig) -> None:
        self.cfg = cfg
        self._az_sigma_rad = math.radians(cfg.azimuth_sigma_deg)
        self._head: tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None = None  # (xp, heading(xp))
        #: the compiled association/update core (``edge.native._track``), or None: the numpy reference runs
        self.kernel = native.load("_track")
        #: storage the kernel reuses frame to frame for the pairs' innovations (``v``, ``S``, ``S^-1``)
        self._pair_buffers = PairBuffers()
        #: the radar's height above the assumed scatterer height (m; the lane pipeline sets it from the mounting):
        #: it sizes the seed-exclusion noise's :func:`height_cov`; 0: no height term
        self.height_above_target_m = 0.0
        #: the assumed scatterer height above the road (m; the lane pipeline sets it; None: unknown): no scatterer
        #: lies lower, which bounds how much slower than its vehicle a detection near the radar reads
        self.target_height_m: float | None = None

    @property
    def use_radial_speed(self) -> bool:
        return self.cfg.use_radial_speed

    @property
    def initial_extent_var(self) -> float:
        """A new track's along-heading spread of its detections (m^2)."""
        return self.cfg.extent_along_sigma_m ** 2

    def detection_noise(self, meas: Measurements) -> np.ndarray | None:
        """(M, n, n) sensor noise per detection, or None when the sensor noise is the track's (constant model)."""
        return None

    def of_detections(self, meas: Measurements, n: int | None = None, rows: np.ndarray | None = None) -> np.ndarray:
        """(M, n, n) sensor noise of each detection from its SNR; the radial-speed row stays in the track's part
        (:meth:`at`). ``rows``: only those detections (the noise of a detection depends on its own row alone)."""
        c = self.cfg
        n = meas.z.shape[1] if n is None else n
        z, snr_db = (meas.z, meas.snr_db) if rows is None else (meas.z.take(rows, axis=0), meas.snr_db.take(rows))
        if self.kernel is not None:  # bit-identical
            return self.kernel.snr_noise(z, snr_db, c.snr_min_db, c.snr_max_db, c.snr_range_sigma_m**2,
                                         c.snr_range_floor_m**2, math.radians(c.snr_azimuth_sigma_deg)**2,
                                         math.radians(c.snr_azimuth_floor_deg)**2, c.snr_extent_sigma_m**2, n)
        rp = kalman.snr_polar_noise(z[:, :2], snr_db, c.snr_range_sigma_m, c.snr_range_floor_m,
                                    math.radians(c.snr_azimuth_sigma_deg), math.radians(c.snr_azimuth_floor_deg),
                                    c.snr_extent_sigma_m, (c.snr_min_db, c.snr_max_db))
        if n == 2:
            return rp
        r = np.zeros((rp.shape[0], n, n))
        r[:, :2, :2] = rp
        return r

    def at(self, xp: np.ndarray, with_radial_speed: bool, ext_var: np.ndarray | None = None, sensor: bool = True,
           pred: tuple[np.ndarray, np.ndarray] | None = None):
        """``z_hat`` (T, n), ``H`` (T, n, 4), ``R`` (T, n, n) at the predictions ``xp``. ``sensor=False``: without the
        converted polar noise (it comes per detection). ``pred``: ``kalman.measurement_prediction(xp, ...)`` if
        already computed."""
        c = self.cfg
        zh, h = kalman.measurement_prediction(xp, with_radial_speed) if pred is None else pred
        if sensor:
            rp = kalman.polar_position_noise(xp[:, :2], c.range_sigma_m, self._az_sigma_rad, c.extent_sigma_m)
        else:
            rp = np.zeros((xp.shape[0], 2, 2))
        if ext_var is not None:
            self._head = (xp, heading(xp))  # update_extent reuses it for the same prediction
            rp += extent_cov(xp, ext_var, self._head[1])
        n = zh.shape[1]
        r = np.zeros((xp.shape[0], n, n))
        r[:, :2, :2] = rp
        if n == 3:
            r[:, 2, 2] = c.radial_speed_sigma_mps**2
        return zh, h, r

    def with_sensor(self, xp: np.ndarray, r: np.ndarray, height_var_m2: float = 0.0) -> np.ndarray:
        """``r`` of :meth:`at` with ``sensor=False`` plus the constant converted polar noise and, with
        ``height_var_m2`` > 0 and the radar above the assumed scatterers, the scatterer height's term
        (:func:`height_cov` at the states ``xp``)."""
        c = self.cfg
        out = r.copy()
        out[:, :2, :2] += kalman.polar_position_noise(xp[:, :2], c.range_sigma_m, self._az_sigma_rad, c.extent_sigma_m)
        if height_var_m2 > 0.0 and self.height_above_target_m > 0.0:
            vr = kalman.measurement_prediction(xp, True)[0][:, 2] if out.shape[1] == 3 else None
            height_cov(out, xp, vr, self.height_above_target_m, height_var_m2)
        return out

    def predict(self, pred: Prediction, meas: Measurements, ext_var: np.ndarray,
                prune_gamma: float | None = None) -> MeasurementPrediction:
        """The measurement prediction of every state row of ``pred`` (combined and, with modes, per mode, in one
        call) and the innovations of every track x detection pair (``prune_gamma``: pairs that surely lie outside a
        gate of that chi-square threshold need not be computed exactly, :func:`edge.track.pdaf.innovations_each`)."""
        t = pred.x.shape[0]
        rm = self.detection_noise(meas)
        if self.kernel is not None and rm is not None:  # the track's part only: one kernel call (bit-identical)
            mp = self._predict_kernel(pred, meas, ext_var, rm)
            self._innovations(meas, pred, mp, prune_gamma)
            return mp
        both = zhm = hm = None
        if pred.xm is not None:
            zh_all, h_all = kalman.measurement_prediction(np.concatenate([pred.x, pred.xm.reshape(2 * t, 4)]),
                                                          meas.with_radial_speed)
            both, zhm, hm = (zh_all[:t], h_all[:t]), zh_all[t:], h_all[t:]
        zh, h, r = self.at(pred.x, meas.with_radial_speed, ext_var, sensor=rm is None, pred=both)
        mp = MeasurementPrediction(zh, h, r, rm, None, zhm, hm)
        self._innovations(meas, pred, mp, prune_gamma)
        return mp

    def _predict_kernel(self, pred: Prediction, meas: Measurements, ext_var: np.ndarray,
                        rm: np.ndarray) -> MeasurementPrediction:
        """:meth:`predict`'s measurement prediction without the sensor noise (it comes per detection, ``rm``) from
        the ``measure_predict`` kernel: ``z_hat``, ``H`` of every state row, the heading and ``R`` of the tracks."""
        c, t = self.cfg, pred.x.shape[0]
        xp = pred.x if pred.xm is None else np.concatenate([pred.x, pred.xm.reshape(2 * t, 4)])
        zh, h, r, u, w = self.kernel.measure_predict(xp, t, meas.with_radial_speed, ext_var, c.radial_speed_sigma_mps**2)
        self._head = (pred.x, (u, w))  # update_extent reuses it for the same prediction
        if pred.xm is None:
            return MeasurementPrediction(zh, h, r, rm, None, None, None)
        return MeasurementPrediction(zh[:t], h[:t], r, rm, None, zh[t:], h[t:])

    def _innovations(self, meas: Measurements, pred: Prediction, mp: MeasurementPrediction,
                     prune_gamma: float | None) -> None:
        """Set ``mp.inn`` (and ``mp.inn_m`` where the noise model computes the modes' with it)."""
        raise NotImplementedError("a noise model: ConstantNoiseModel or SnrNoiseModel")

    def seed_exclusion_d2(self, mp: MeasurementPrediction, xp: np.ndarray, constant: bool,
                          height_var_m2: float = 0.0) -> np.ndarray:
        """(T, M) squared distances of the seed-exclusion gate: the association's, or (``constant``) those under the
        constant noise model (the same innovations, ``S`` = the track's part plus the constant sensor noise and the
        scatterer height's term of variance ``height_var_m2``, :meth:`with_sensor`)."""
        return mp.inn.d2

    def seed_exclusion_claimed(self, mp: MeasurementPrediction, xp: np.ndarray, constant: bool,
                               gamma: float, height_var_m2: float = 0.0) -> np.ndarray:
        """(M,) detections with a squared distance of :meth:`seed_exclusion_d2` at most ``gamma`` to some track."""
        return (self.seed_exclusion_d2(mp, xp, constant, height_var_m2) <= gamma).any(axis=0)

    def update_extent(self, xp, ext_var, inn: Innovations, beta: np.ndarray) -> np.ndarray:
        """Learn the along-heading spread from the weighted along-heading innovations of this frame:
        ``E[a^2] - u' (H P H' + R_sensor) u``, ``R_sensor`` = ``S`` without the extent term."""
        c = self.cfg
        u, w = self._head[1] if self._head is not None and self._head[0] is xp else heading(xp)
        if self.kernel is not None and inn.v.shape[2] >= 2:  # the same arithmetic and summation order
            per_pair = inn.s.ndim == 4
            s2_track = _NO_S2 if per_pair else np.ascontiguousarray(inn.s[:, :2, :2]).reshape(-1, 4)
            return self.kernel.update_extent(np.ascontiguousarray(inn.v), s2_track,
                                             np.ascontiguousarray(inn.s) if per_pair else _NO_S_PAIR, per_pair,
                                             np.ascontiguousarray(beta, dtype=np.float64), np.ascontiguousarray(u),
                                             np.ascontiguousarray(w), np.ascontiguousarray(ext_var), c.extent_alpha,
                                             c.extent_max_sigma_m**2)
        a = inn.v[:, :, 0] * u[:, None, 0] + inn.v[:, :, 1] * u[:, None, 1]  # (T, M) along-heading innovation
        wsum = beta.sum(axis=1)
        ok = (wsum > 0.5) & (w >= 1.0)
        m2 = (beta * a * a).sum(axis=1) / np.maximum(wsum, 1e-12)
        s2 = inn.s[..., :2, :2]
        if s2.ndim == 4:  # one S per (track, detection): its weighted mean over this frame's detections
            s2 = (s2 * beta[:, :, None, None]).sum(axis=1) / np.maximum(wsum, 1e-12)[:, None, None]
        along_s = u[:, 0] * (s2[:, 0, 0] * u[:, 0] + s2[:, 0, 1] * u[:, 1]) + u[:, 1] * (
            s2[:, 1, 0] * u[:, 0] + s2[:, 1, 1] * u[:, 1])
        other = along_s - ext_var  # for moving tracks (w = 1) the extent adds exactly ext_var along u
        sample = np.minimum(np.maximum(m2 - other, 0.0), c.extent_max_sigma_m**2)
        return np.where(ok, (1.0 - c.extent_alpha) * ext_var + c.extent_alpha * sample, ext_var)

    def learn(self, tracks, xp: np.ndarray, mp: MeasurementPrediction, beta: np.ndarray, n_det: int) -> None:
        """Update every track's along-heading spread ``tracks.ext_var`` (``extent_alpha`` > 0)."""
        if self.cfg.extent_alpha > 0 and n_det:
            tracks.ext_var = self.update_extent(xp, tracks.ext_var, mp.inn, beta)


class ConstantNoiseModel(MeasurementModel):
    """One ``R`` per track from ``range_sigma_m``, ``azimuth_sigma_deg`` and ``extent_sigma_m`` at its prediction
    (Lim): one ``S`` per track, one gain per track."""

    def _innovations(self, meas, pred, mp, prune_gamma) -> None:
        if mp.hm is None:
            mp.inn = innovations(meas.z, mp.zh, mp.h, pred.p, mp.r, self.kernel)
            return
        t = pred.x.shape[0]  # the combined prediction and both modes in one computation
        inn_all = innovations(meas.z, np.concatenate([mp.zh, mp.zhm]), np.concatenate([mp.h, mp.hm]),
                              np.concatenate([pred.p, pred.pm.reshape(2 * t, 4, 4)]),
                              np.concatenate([mp.r, mp.r.repeat(2, axis=0)]), self.kernel)
        mp.inn, mp.inn_m = _rows(inn_all, slice(0, t)), _rows(inn_all, slice(t, None))

    def state_update(self, xp, pp, mp: MeasurementPrediction, beta, beta0):
        """The PDAF posterior with one gain per track (Lim)."""
        return combined_update(xp, pp, mp.h, mp.inn, beta, beta0)

    def mode_update(self, pred: Prediction, mp: MeasurementPrediction, meas, beta, beta0, gated, gamma: float,
                    prob_detect: float, prob_gate: float):
        """Both modes' PDAF posteriors with the common weights and each mode's likelihood -> (xm, pm, lik (T, 2))."""
        t = pred.x.shape[0]
        n = meas.z.shape[1]
        inn_m = mp.inn_m
        m = inn_m.d2.shape[1]
        # (track, mode) axes: the common weights, gate and gate volume broadcast over the modes
        by_mode = Innovations(inn_m.v.reshape(t, 2, m, n), inn_m.d2.reshape(t, 2, m), inn_m.s.reshape(t, 2, n, n),
                              inn_m.s_inv.reshape(t, 2, n, n), inn_m.det_s.reshape(t, 2))
        xm, pm = combined_update(pred.xm, pred.pm, mp.hm.reshape(t, 2, n, 4), by_mode, beta[:, None, :],
                                 beta0[:, None])
        vol = unit_ball_volume(n) * gamma ** (n / 2.0) * np.sqrt(mp.inn.det_s)
        lik = imm.mode_likelihood(by_mode, gated[:, None, :], vol[:, None], prob_detect, prob_gate)
        return xm, pm, lik


class SnrNoiseModel(MeasurementModel):
    """One sensor ``R`` per detection from its SNR (``snr_*``); the track keeps the extent and radial-speed parts.
    ``S`` is per (track, detection) and the PDAF posterior is the mixture of one Kalman update per hypothesis."""

    per_detection = True

    def detection_noise(self, meas: Measurements) -> np.ndarray:
        return self.of_detections(meas)

    def _innovations(self, meas, pred, mp, prune_gamma) -> None:
        mp.inn = innovations_each(meas.z, mp.zh, mp.h, pred.p, mp.r, mp.rm, prune_gamma, self.kernel,
                                  self._pair_buffers)

    def seed_exclusion_d2(self, mp: MeasurementPrediction, xp: np.ndarray, constant: bool,
                          height_var_m2: float = 0.0) -> np.ndarray:
        if not constant:
            return mp.inn.d2
        return mahalanobis_d2(mp.inn.v, self.with_sensor(xp, mp.inn.s_track, height_var_m2), self.kernel)

    def seed_exclusion_claimed(self, mp: MeasurementPrediction, xp: np.ndarray, constant: bool,
                               gamma: float, height_var_m2: float = 0.0) -> np.ndarray:
        if self.kernel is None or not constant or mp.inn.v.shape[2] not in (2, 3):
            return super().seed_exclusion_claimed(mp, xp, constant, gamma, height_var_m2)
        # the converted polar noise (and the height term), the inverses, distances and the test in one kernel call,
        # S as with_sensor's (bit-identical: kalman.polar_position_noise's and height_cov's operations)
        c = self.cfg
        dz = self.height_above_target_m if height_var_m2 > 0.0 else 0.0
        return self.kernel.claimed_any_polar(np.ascontiguousarray(mp.inn.v), np.ascontiguousarray(mp.inn.s_track), xp,
                                             c.range_sigma_m**2, self._az_sigma_rad**2, c.extent_sigma_m**2,
                                             gamma, dz, height_var_m2).view(bool)

    def state_update(self, xp, pp, mp: MeasurementPrediction, beta, beta0):
        """The PDAF posterior with one gain per hypothesis (:func:`edge.track.pdaf.combined_update`)."""
        if self.kernel is not None:  # equal to rounding
            t, m = np.nonzero(beta > 0)
            c = np.ascontiguousarray
            return self.kernel.update_pairs(c(xp), c(pp), c(mp.h), c(t), mp.inn.v[t, m], mp.inn.s_inv[t, m],
                                            beta[t, m])
        return combined_update(xp, pp, mp.h, mp.inn, beta, beta0)

    def mode_update(self, pred: Prediction, mp: MeasurementPrediction, meas, beta, beta0, gated, gamma: float,
                    prob_detect: float, prob_gate: float):
        """Both modes' posteriors over the validated pairs only, each pair with its own gain; a detection nearer than
        the mode's prediction counts ``extent_near_side_factor`` of the extent (the track is on the near face)."""
        t = pred.x.shape[0]
        xs, ps = pred.xm.reshape(2 * t, 4), pred.pm.reshape(2 * t, 4, 4)  # rows (track, mode)
        if self.kernel is not None:  # pairs, updates and likelihoods in one call (equal to rounding)
            inn = mp.inn
            vol = inn.gate_volume if inn.gate_volume is not None else gate_volume_each(inn, gated, gamma)
            c = np.ascontiguousarray
            xu, pu, lik = self.kernel.imm_mode_update(
                c(xs), c(ps), c(mp.hm), c(mp.zhm), c(mp.r), c(meas.z), c(mp.rm), c(gated), c(beta),
                self.cfg.extent_near_side_factor, self.cfg.extent_near_side_factor != 1.0, c(vol), prob_detect,
                prob_gate)
            return xu.reshape(t, 2, 4), pu.reshape(t, 2, 4, 4), lik
        ti, mi = np.nonzero(gated)
        rows = np.concatenate([2 * ti, 2 * ti + 1])
        cols = np.concatenate([mi, mi])
        scale = None
        if self.cfg.extent_near_side_factor != 1.0:
            zp = mp.zhm[rows, :2]
            nearer = ((meas.z[cols, :2] - zp) * zp).sum(axis=1) < 0.0
            scale = np.where(nearer, self.cfg.extent_near_side_factor, 1.0)
        wg = beta[ti, mi]
        w = np.concatenate([wg, wg])
        pin, xu, pu = self._pair_update(xs, ps, mp, meas, rows, cols, scale, wg, w)
        inn = mp.inn
        vol = inn.gate_volume if inn.gate_volume is not None else gate_volume_each(inn, gated, gamma)
        lik = imm.mode_likelihood_pairs(pin, 2 * t, np.repeat(vol, 2), np.repeat(gated.sum(axis=1), 2),
                                        prob_detect, prob_gate).reshape(t, 2)
        return xu.reshape(t, 2, 4), pu.reshape(t, 2, 4, 4), lik

    @staticmethod
    def _pair_update(xs, ps, mp: MeasurementPrediction, meas, rows, cols, scale, wg, w):
        """The numpy reference of the mode rows' pair innovations and per-hypothesis update -> (pin, x, P)."""
        pin = pair_innovations(meas.z, mp.zhm, mp.hm, ps, np.repeat(mp.r, 2, axis=0), mp.rm, rows, cols, scale)
        if (wg > 0).all():  # the usual case (a validated pair has a positive weight unless it underflows)
            xu, pu = combined_update_pairs(xs, ps, mp.hm, pin, w)
        else:
            pos = w > 0
            xu, pu = combined_update_pairs(xs, ps, mp.hm, PairInnovations(rows[pos], cols[pos], pin.v[pos],
                                                                          pin.d2[pos], pin.s_inv[pos],
                                                                          pin.det_s[pos]), w[pos])
        return pin, xu, pu


_NO_SCALE = np.zeros(0)
_NO_S2 = np.zeros((0, 4))
_NO_S_PAIR = np.zeros((0, 0, 0, 0))


def _rows(inn: Innovations, rows: slice) -> Innovations:
    return Innovations(inn.v[rows], inn.d2[rows], inn.s[rows], inn.s_inv[rows], inn.det_s[rows])
