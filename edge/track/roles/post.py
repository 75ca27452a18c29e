"""Post-step roles, run after the update and the hit counters: the straight-line lateral filter that gives the
published lateral position, and re-anchoring a track on its vehicle's near face. A post-step changes only its own
columns and the tracks' common state; it returns the rows whose state it moved so that the roles that keep their own
per-track state restart them (``restart``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge import native
from edge.track import kalman
from edge.track.config import LateralSmootherConfig, ReanchorConfig
from edge.track.pdaf import gate_threshold
from edge.track.roles.associate import Hypotheses
from edge.track.roles.box import SameVehicleBox
from edge.track.roles.delete import carrying_detection
from edge.track.roles.measure import MeasurementModel, MeasurementPrediction, Prediction
from edge.track.table import Measurements, TrackTable

__all__ = ["Frame", "LateralSmoother", "Reanchor"]

_NO_R = np.zeros((0, 1, 1))  # no per-detection noise (lateral_frame's placeholder)
_NO_KEEP = (np.zeros(0), np.zeros((0, 4)), np.zeros((0, 4, 4)))  # no manoeuvre hold (placeholders)
_NO_FLAGS = np.zeros(0, dtype=bool)


@dataclass
class Frame:
    """What the post-steps may read of this frame: the measurements, the time step, the prediction, the measurement
    prediction, the association, the tracks hit (T,) and the detections claimed (M,; a post-step may claim more)."""

    meas: Measurements
    dt_s: float
    pred: Prediction
    mp: MeasurementPrediction
    hyp: Hypotheses
    hit: np.ndarray
    used: np.ndarray


class LateralSmoother(native.KernelUser):
    """A straight-line filter per track across the boresight (``tracks.lat``: ``[x, vx]``), outside the IMM's mixing,
    updated with the association's weights and each detection's own lateral noise (:mod:`edge.track.kalman`). It
    restarts from the motion model's estimate when a Hausman test or a CUSUM of the likelihood ratio says the vehicle
    left the line, and is held there while the predictor's manoeuvring mode is likely or while the detection that
    carries the track is an unresolved pair."""

    def __init__(self, cfg: LateralSmootherConfig, predictor) -> None:
        self.cfg = cfg
        self.predictor = predictor  # its manoeuvre probability, if it has modes (``manoeuvring``)
        self._gamma = gate_threshold(cfg.lateral_smoother_reset_prob, 1)
        #: the compiled line filter (``edge.native._track``), or None: numpy
        self.kernel = native.load("_track")

    def run(self, tracks: TrackTable, frame: Frame) -> np.ndarray | None:
        cfg = self.cfg
        tr = tracks
        if self.kernel is not None:  # the whole frame below in one pass (equal to rounding)
            self._run_kernel(tr, frame)
            return None
        meas, beta = frame.meas, frame.hyp.beta
        new = tr.age == 2  # seeded last frame: its lateral speed is the road direction's, give or take a little
        if np.count_nonzero(new):
            tr.lat_p[new, 1, 1] = np.minimum(tr.lat_p[new, 1, 1], cfg.lateral_smoother_init_speed_sigma_mps**2)
            tr.lat_p[new, 0, 1] = tr.lat_p[new, 1, 0] = 0.0
        ref, ref_p = tr.x[:, 0::2], tr.p[:, 0::2, 0::2]
        lat, lat_p, cusum, off, any_pair = self._line(tr, frame, ref, ref_p)
        hold = keep = None
        if cfg.lateral_smoother_hold_manoeuvre_prob < 1.0:
            keep = self.predictor.manoeuvring(tr)
            if keep is not None:
                hold = keep[0] > cfg.lateral_smoother_hold_manoeuvre_prob  # the IMM says: manoeuvring
                off |= hold
        if cfg.lateral_smoother_hold_unresolved and meas.unresolved is not None and any_pair:
            # a detection of two vehicles too close in angle to split (its angle lies between them) carries the track:
            # no straight line through it, the motion model's position until the pair splits
            best, strong = carrying_detection(beta)
            off |= meas.unresolved[best] & strong  # (with the motion model's own lateral speed: it may be crossing)
        if np.count_nonzero(off):
            lat[off], lat_p[off] = ref[off], ref_p[off]
            cusum = np.where(off, 0.0, cusum)
            if hold is not None and np.count_nonzero(hold):
                # held during a manoeuvre: the lateral speed of the lane-keeping mode (decaying to the road's), so a
                # line that starts again as the manoeuvre ends does not keep the manoeuvre's speed across
                _, xk, pk = keep
                lat[hold, 1] = xk[hold, 2]
                lat_p[hold, 1, 1] = pk[hold, 2, 2]
                lat_p[hold, 0, 1] = lat_p[hold, 1, 0] = pk[hold, 0, 2]
        tr.lat, tr.lat_p, tr.lat_cusum = lat, lat_p, cusum
        return None

    def _run_kernel(self, tr: TrackTable, frame: Frame) -> None:
        """:meth:`run` in one ``lateral_frame`` call: the seeded lines, the line step and the restarts."""
        cfg, mp, pred = self.cfg, frame.mp, frame.pred
        keep = self.predictor.manoeuvring(tr) if cfg.lateral_smoother_hold_manoeuvre_prob < 1.0 else None
        unresolved = frame.meas.unresolved if cfg.lateral_smoother_hold_unresolved else None
        tr.lat, tr.lat_p, tr.lat_cusum = self.kernel.lateral_frame(
            tr.age, cfg.lateral_smoother_init_speed_sigma_mps**2, tr.lat, tr.lat_p, frame.dt_s,
            cfg.lateral_smoother_q_m2ps3, frame.hyp.beta, frame.meas.z, mp.r, _NO_R if mp.rm is None else mp.rm,
            mp.rm is not None, pred.x, pred.p, tr.lat_cusum, tr.x, tr.p, self._gamma,
            cfg.lateral_smoother_min_var_fraction, cfg.lateral_smoother_cusum_nats, keep is not None,
            *(_NO_KEEP if keep is None else keep), cfg.lateral_smoother_hold_manoeuvre_prob, unresolved is not None,
            _NO_FLAGS if unresolved is None else unresolved)

    def _line(self, tr: TrackTable, frame: Frame, ref: np.ndarray, ref_p: np.ndarray):
        """The numpy reference of one frame of the lines: predicted, tested against the detections (CUSUM of the
        likelihood ratio), updated and tested against the motion model -> (lat, lat_p, cusum, off, any pair)."""
        cfg = self.cfg
        meas, beta, r, rm = frame.meas, frame.hyp.beta, frame.mp.r, frame.mp.rm
        xp, pp = frame.pred.x, frame.pred.p
        lat, lat_p = kalman.lateral_predict(tr.lat, tr.lat_p, frame.dt_s, cfg.lateral_smoother_q_m2ps3)
        ti, mi = np.nonzero(beta > 0)
        cusum = tr.lat_cusum
        if ti.size:
            var = r[ti, 0, 0] if rm is None else r[ti, 0, 0] + rm[mi, 0, 0]
            z, w = meas.z[mi, 0], beta[ti, mi]
            llr = kalman.lateral_log_likelihood_ratio(len(tr), ti, w, z, var, lat[:, 0], lat_p[:, 0, 0], xp[:, 0],
                                                      pp[:, 0, 0])
            cusum = np.maximum(cusum + llr, 0.0)
            lat, lat_p = kalman.lateral_pda_update(lat, lat_p, z, var, ti, w)
        off = kalman.lateral_inconsistent(lat, lat_p, ref, ref_p, self._gamma, cfg.lateral_smoother_min_var_fraction)
        off |= cusum > cfg.lateral_smoother_cusum_nats
        return lat, lat_p, cusum, off, bool(ti.size)

    def restart(self, tracks: TrackTable, rows: np.ndarray) -> None:
        """The line restarts from the rows' (moved) state."""
        tracks.lat[rows] = tracks.x[rows, 0::2]
        tracks.lat_p[rows] = tracks.p[rows, 0::2, 0::2]
        tracks.lat_cusum[rows] = 0.0


class Reanchor(native.KernelUser):
    """A confirmed track that missed moves to the nearest unclaimed detection between ``reanchor_min_m`` and
    ``reanchor_m`` nearer, in line with it (``merge_lateral_m``) and at its radial speed: the near face of the
    vehicle whose body the track sat on. The detection is claimed (no seed). The speed test widens, as the confirm
    block's does, by the ground radial-speed error of scatterers two height sd off the assumed height at the track
    and at the detection (:meth:`speed_widening`): above it a scatterer reads faster, below it slower, but no lower
    than the road (the measurement model's ``target_height_m``). The detection lies where tracks live
    (``min_range_m`` on): under the mounting its ground radial speed means nothing."""

    def __init__(self, cfg: ReanchorConfig, box: SameVehicleBox, measurement_model: MeasurementModel | None,
                 height_2sd_m: float = 0.0, min_range_m: float = 0.0) -> None:
        self.cfg, self.box = cfg, box
        self.measurement_model = measurement_model
        #: twice the sd of a scatterer's height (m; ``scatterer_height_sigma_m``)
        self.height_2sd_m = float(height_2sd_m)
        #: the field of view's ground range where tracks begin to live (m)
        self.min_range_m = float(min_range_m)
        #: the compiled matching (``edge.native._track``), or None: numpy (:meth:`matches`)
        self.kernel = native.load("_track")

    def run(self, tracks: TrackTable, frame: Frame) -> np.ndarray | None:
        meas, used = frame.meas, frame.used
        if not (meas.z.shape[0] and meas.with_radial_speed):
            return None
        tr = tracks
        if self.kernel is not None:  # the same tests in one pass (identical)
            c = self.cfg
            k_fast, k_slow = self.height_speed_k
            i, j = self.kernel.reanchor_match(tr.x, tr.confirmed, frame.hit, frame.hyp.gated, meas.z,
                                              c.reanchor_speed_mps, c.reanchor_receding_only, c.reanchor_min_m,
                                              c.reanchor_m, self.box.cfg.merge_lateral_m, k_fast,
                                              self.min_range_m, k_slow)
            if i.size == 0:
                return None
        else:
            found = self.matches(tr, frame)
            if found is None:
                return None
            i, j = found
        tr.x[i, :2] = meas.z[j, :2]
        _, _, r = self.measurement_model.at(tr.x[i], False)  # a jump: the constant model's (wider) noise
        tr.p[i, :2, :2] = r
        tr.p[i, :2, 2:] = 0.0
        tr.p[i, 2:, :2] = 0.0
        tr.hits[i] += 1
        tr.misses[i] = 0
        tr.history[i] |= np.uint32(1)
        used[j] = True
        return i

    @property
    def height_speed_k(self) -> tuple[float, float]:
        """``dz dh`` (m^2) for a detection faster and slower than its track: the radar's height above the assumed
        scatterers (the measurement model's) times twice their height sd, and times the lesser of that and the
        assumed height itself (no scatterer lies below the road; the model's ``target_height_m``, None: no bound);
        zeros without a measurement model."""
        mm = self.measurement_model
        if mm is None:
            return 0.0, 0.0
        below = mm.target_height_m
        dh_slow = self.height_2sd_m if below is None else min(self.height_2sd_m, max(float(below), 0.0))
        return mm.height_above_target_m * self.height_2sd_m, mm.height_above_target_m * dh_slow

    @staticmethod
    def speed_widening(k: float, vr_t: np.ndarray, rho_t: np.ndarray, rho_z: np.ndarray,
                       k_track: float | None = None) -> np.ndarray:
        """(k, f) the speed test's widening (m/s) for tracks of ground radial speed ``vr_t`` and range ``rho_t``
        (k,) and detections at ranges ``rho_z`` (f,): ``hypot`` of ``k |v_r| / rho^2`` at each (``k_track`` at the
        track, default ``k``; ``rho`` at least 1 m, :func:`edge.track.roles.measure.height_cov`'s speed term for
        the track's speed)."""
        av = np.abs(vr_t)
        kv, kt = k * av, (k if k_track is None else k_track) * av
        rt, rz = np.maximum(rho_t, 1.0), np.maximum(rho_z, 1.0)
        ht, hz = kt / (rt * rt), kv[:, None] / (rz * rz)[None, :]
        return np.sqrt(ht[:, None] * ht[:, None] + hz * hz)

    def matches(self, tracks: TrackTable, frame: Frame) -> tuple[np.ndarray, np.ndarray] | None:
        """The numpy reference of the matching: rows ``(i, j)`` of the tracks that move and their detections, or
        None."""
        c = self.cfg
        meas, gated, hit = frame.meas, frame.hyp.gated, frame.hit
        tr = tracks
        miss = (tr.confirmed & ~hit).nonzero()[0]
        if miss.size == 0:
            return None
        free = (~gated.any(axis=0)).nonzero()[0]
        if free.size == 0:
            return None
        st, z = tr.x.take(miss, axis=0), meas.z.take(free, axis=0)
        rho_t = np.maximum(np.hypot(st[:, 0], st[:, 1]), 1e-3)
        vr_t = (st[:, 0] * st[:, 2] + st[:, 1] * st[:, 3]) / rho_t
        rho_z = np.hypot(z[:, 0], z[:, 1])
        k_fast, k_slow = self.height_speed_k
        faster = np.where(vr_t < 0.0, -1.0, 1.0)[:, None] * (z[None, :, 2] - vr_t[:, None])  # (k, f) m/s
        ok = ((faster < c.reanchor_speed_mps + self.speed_widening(k_fast, vr_t, rho_t, rho_z))
              & (-faster < c.reanchor_speed_mps + self.speed_widening(k_slow, vr_t, rho_t, rho_z, k_fast)))
        ok &= (rho_z >= self.min_range_m)[None, :]
        if c.reanchor_receding_only:  # an approaching track is on its near face from afar
            ok &= (vr_t > 0.0)[:, None]
        if not ok.any():  # the usual frame: no unclaimed detection at a missed track's radial speed
            return None
        nearer = rho_t[:, None] - rho_z[None, :]  # (k, f) > 0: the detection is nearer
        ok &= ((nearer > c.reanchor_min_m) & (nearer <= c.reanchor_m)
               & (np.abs(st[:, 0, None] - z[None, :, 0]) < self.box.cfg.merge_lateral_m))
        has = ok.any(axis=1)
        if not has.any():
            return None
        i = miss[has]
        j = free[np.argmax(np.where(ok, nearer, -np.inf), axis=1)[has]]  # the nearest: the near face
        return i, j
