"""Predictor and updater roles. :class:`CvPredictor` with :class:`PdaUpdater`: Lim's constant-velocity Kalman
filter. :class:`ImmPredictor` with :class:`ImmPdaUpdater`: an IMM of lane keeping (velocity across the road decaying
to zero, along ``road_yaw_rad``) and the constant-velocity model for manoeuvres (:mod:`edge.track.imm`); both modes
are updated with the association weights of the combined prediction and weighed by their PDAF likelihoods."""

from __future__ import annotations

import math

import numpy as np

from edge import native
from edge.track import imm, kalman
from edge.track.config import AssociationConfig, MotionConfig
from edge.track.roles.associate import Hypotheses
from edge.track.roles.measure import MeasurementModel, MeasurementPrediction, Prediction
from edge.track.table import Measurements, TrackTable

__all__ = ["CvPredictor", "ImmPredictor", "PdaUpdater", "ImmPdaUpdater"]


class CvPredictor:
    """Constant-velocity prediction of every track to the frame time."""

    modes = False

    def __init__(self, cfg: MotionConfig) -> None:
        self.cfg = cfg
        self._cached: tuple[float, np.ndarray, np.ndarray] | None = None  # (dt, F, Q) of the last frame

    def predict(self, tracks: TrackTable, dt_s: float, yaw_rad: float = 0.0) -> Prediction:
        if self._cached is None or self._cached[0] != dt_s:  # frames come at a fixed period
            self._cached = (dt_s, kalman.cv_transition(dt_s),
                            kalman.cv_process_noise(dt_s, self.cfg.q_lateral_m2ps3, self.cfg.q_along_m2ps3))
        _, f, q = self._cached
        return Prediction(*kalman.predict(tracks.x, tracks.p, f, q))

    def seeded(self, tracks: TrackTable, k: int, road_yaw_rad: float, speed_var: np.ndarray | float | None) -> None:
        """The last ``k`` rows of ``tracks`` are new seeds (nothing kept per model)."""

    def restart(self, tracks: TrackTable, rows: np.ndarray) -> None:
        """Rows whose state the tracker moved (re-anchoring): nothing kept per model."""

    def manoeuvring(self, tracks: TrackTable):
        """None: one model, no manoeuvre probability."""
        return None


class ImmPredictor(native.KernelUser):
    """IMM mixing and mode-matched prediction: lane keeping along the road at ``road_yaw_rad`` and the
    constant-velocity model for manoeuvres. Per track: ``tracks.xm``, ``tracks.pm``, ``tracks.mu``."""

    modes = True

    def __init__(self, cfg: MotionConfig) -> None:
        self.cfg = cfg
        self.pi = imm.switch_matrix(cfg.imm_p_keep_to_manoeuvre, cfg.imm_p_manoeuvre_to_keep)
        self._pi1 = np.ascontiguousarray(self.pi[None])  # (1, 2, 2): the kernel's form
        #: the compiled IMM cycle (``edge.native._track``), or None: numpy
        self.kernel = native.load("_track")
        self._cached: tuple[float, float, np.ndarray, np.ndarray] | None = None  # (dt, yaw, F (2,4,4), Q (2,4,4))

    def _far_switch(self, rho: np.ndarray) -> np.ndarray:
        """(T, 2, 2) switching matrices: ``imm_p_keep_to_manoeuvre`` up to ``imm_far_from_m``, then falling
        log-linearly to ``imm_far_p_keep_to_manoeuvre`` at ``imm_far_to_m`` and beyond."""
        c = self.cfg
        u = np.minimum(np.maximum((rho - c.imm_far_from_m) / max(c.imm_far_to_m - c.imm_far_from_m, 1e-9), 0.0), 1.0)
        p = np.exp((1.0 - u) * math.log(c.imm_p_keep_to_manoeuvre) + u * math.log(c.imm_far_p_keep_to_manoeuvre))
        pi = np.empty((rho.size, 2, 2))
        pi[:, 0, 0], pi[:, 0, 1] = 1.0 - p, p
        pi[:, 1] = self.pi[1]
        return pi

    def predict(self, tracks: TrackTable, dt_s: float, yaw_rad: float = 0.0) -> Prediction:
        """The combined prediction (moment-matched), per mode, and the predicted mode probabilities."""
        c = self.cfg
        if self._cached is None or self._cached[0] != dt_s:
            fm = kalman.cv_transition(dt_s)
            qm = kalman.cv_process_noise(dt_s, c.imm_manoeuvre_q_lateral_m2ps3, c.q_along_m2ps3)
            self._cached = (dt_s, None, np.stack([fm, fm]), np.stack([qm, qm]))
        _, cached_yaw, f, q = self._cached
        if cached_yaw != yaw_rad:  # the yaw estimate moves nearly every frame: only the keep mode is rebuilt
            if self.kernel is not None:  # keep_model's numbers written into f[0], q[0] (the same operations)
                self.kernel.keep_model_into(f, q, dt_s, yaw_rad, c.imm_keep_tau_s, c.imm_keep_q_across_m2ps3,
                                            c.q_along_m2ps3, dt_s**3 / 3.0, dt_s**2 / 2.0)
            else:
                f[0], q[0] = imm.keep_model(dt_s, yaw_rad, c.imm_keep_tau_s, c.imm_keep_q_across_m2ps3,
                                            c.q_along_m2ps3)
            self._cached = (dt_s, yaw_rad, f, q)
        pi = self.pi
        far = c.imm_far_p_keep_to_manoeuvre < c.imm_p_keep_to_manoeuvre and tracks.x.shape[0]
        if self.kernel is not None:  # switching, mixing, prediction and moment matching in one pass (to rounding)
            if far:  # the switching matrices of _far_switch, built in the kernel
                xp, pp, xpm, ppm, cj = self.kernel.imm_predict(
                    tracks.xm, tracks.pm, tracks.mu, self._pi1, f, q, tracks.x, c.imm_far_from_m,
                    max(c.imm_far_to_m - c.imm_far_from_m, 1e-9), math.log(c.imm_p_keep_to_manoeuvre),
                    math.log(c.imm_far_p_keep_to_manoeuvre))
            else:
                xp, pp, xpm, ppm, cj = self.kernel.imm_predict(tracks.xm, tracks.pm, tracks.mu, self._pi1, f, q)
            return Prediction(xp, pp, xpm, ppm, cj)
        if far:
            pi = self._far_switch(np.hypot(tracks.x[:, 0], tracks.x[:, 1]))
        x0, p0, cj = imm.mix(tracks.xm, tracks.pm, tracks.mu, pi)
        xpm, ppm = imm.predict_modes(x0, p0, f, q)
        xp, pp = imm.moment_match(xpm, ppm, cj)
        return Prediction(xp, pp, xpm, ppm, cj)

    def seeded(self, tracks: TrackTable, k: int, road_yaw_rad: float, speed_var: np.ndarray | float | None) -> None:
        """The last ``k`` rows are new seeds (both modes at the seed's state): the lane-keeping mode gets
        ``imm_init_keep_prob`` and, with a measured radial speed (``speed_var``: the seeds' speed variance along the
        road), little speed across the road (``imm_keep_init_lateral_speed_sigma_mps``)."""
        c = self.cfg
        w = c.imm_init_keep_prob
        with_speed = speed_var is not None and c.imm_keep_init_lateral_speed_sigma_mps > 0
        if self.kernel is not None:  # the same operations in place, in one call
            per_seed = isinstance(speed_var, np.ndarray)
            self.kernel.imm_seeded(tracks.mu, tracks.pm, tracks.p, k, w, with_speed, math.cos(road_yaw_rad),
                                   math.sin(road_yaw_rad), c.imm_keep_init_lateral_speed_sigma_mps**2,
                                   0.0 if per_seed or not with_speed else speed_var, speed_var if per_seed else None)
            return
        tracks.mu[-k:, 0], tracks.mu[-k:, 1] = w, 1.0 - w
        if not with_speed:
            return
        cy, sy = math.cos(road_yaw_rad), math.sin(road_yaw_rad)
        p0 = tracks.p[-k:]
        pk = p0.copy()
        var_k = c.imm_keep_init_lateral_speed_sigma_mps**2
        pk[:, 2, 2] = cy * cy * var_k + sy * sy * speed_var
        pk[:, 3, 3] = sy * sy * var_k + cy * cy * speed_var
        pk[:, 2, 3] = pk[:, 3, 2] = cy * sy * (var_k - speed_var)
        tracks.pm[-k:, 0] = pk
        tracks.p[-k:] = w * pk + (1.0 - w) * p0  # the modes share the mean: no spread term

    def restart(self, tracks: TrackTable, rows: np.ndarray) -> None:
        """Both modes restart from the rows' (moved) state."""
        tracks.xm[rows] = tracks.x[rows, None, :]
        tracks.pm[rows] = tracks.p[rows, None, :, :]

    def manoeuvring(self, tracks: TrackTable) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per track the manoeuvring mode's probability and the lane-keeping mode's state and covariance."""
        return tracks.mu[:, 1], tracks.xm[:, 0], tracks.pm[:, 0]


class PdaUpdater:
    """The PDAF posterior of one model (:class:`CvPredictor`)."""

    def __init__(self, measurement_model: MeasurementModel) -> None:
        self.measurement_model = measurement_model

    def update(self, tracks: TrackTable, pred: Prediction, mp: MeasurementPrediction, hyp: Hypotheses,
               meas: Measurements) -> None:
        tracks.x, tracks.p = self.measurement_model.state_update(pred.x, pred.p, mp, hyp.beta, hyp.beta0)


class ImmPdaUpdater(native.KernelUser):
    """Both modes' PDAF posteriors with the combined prediction's weights, mode probabilities from each mode's
    likelihood of the validated detections, the moment-matched state (:class:`ImmPredictor`)."""

    def __init__(self, assoc: AssociationConfig, motion: MotionConfig, measurement_model: MeasurementModel,
                 gamma) -> None:
        self.assoc, self.motion = assoc, motion
        self.measurement_model = measurement_model
        self.gamma = gamma  # gamma(n): the validation gate threshold
        #: the compiled moment matching (``edge.native._track``), or None: numpy
        self.kernel = native.load("_track")

    def update(self, tracks: TrackTable, pred: Prediction, mp: MeasurementPrediction, hyp: Hypotheses,
               meas: Measurements) -> None:
        xm, pm, lik = self.measurement_model.mode_update(pred, mp, meas, hyp.beta, hyp.beta0, hyp.gated,
                                                         self.gamma(meas.z.shape[1]), self.assoc.prob_detect,
                                                         self.assoc.prob_gate)
        tracks.xm, tracks.pm = xm, pm
        if self.kernel is not None:  # mode probabilities (bit-identical) and moment matching (equal to rounding)
            c = np.ascontiguousarray
            tracks.mu, tracks.x, tracks.p = self.kernel.mode_probabilities_match(
                c(pred.c), c(lik), self.motion.imm_min_mode_prob, c(xm), c(pm))
        else:
            tracks.mu = imm.update_mode_probabilities(pred.c, lik, self.motion.imm_min_mode_prob)
            tracks.x, tracks.p = imm.moment_match(xm, pm, tracks.mu)
