"""The lane profile's multi-target tracker, after Stone Soup's ``MultiTargetTracker``: a thin loop over role
objects that :func:`edge.track.roles.build_roles` builds from the per-role sections of ``track.pdaf``.

One :meth:`PdafTracker.step` per frame (Lim et al. §III-B, with a PDAF or cheap-JPDA association):

1. predict every track to the frame time (predictor: constant velocity, or an IMM of lane keeping and manoeuvring);
2. predict the measurements and the innovations of every track x detection pair (measurement model: one ``R`` per
   track, or one sensor ``R`` per detection from its SNR), skipping pairs an exact pre-gate rules out;
3. gate and associate (PDAF/JPDA weights; tentative tracks only use detections no senior track validated);
4. update (one Kalman gain per track or per hypothesis; both IMM modes with the common weights) and learn the
   vehicles' extent; score the tracks;
5. count hits and misses, then the post-steps (the straight-line lateral filter; re-anchoring on the near face);
6. delete (misses, divergence, field of view, duplicates of a senior track), confirm, initiate from the
   detections no track claimed.

Tracks are a struct of arrays (:class:`edge.track.table.TrackTable`); there is no Python object per track or
detection on the hot path. Published tracks carry a recycled ``track_id`` in ``1..max_track_id``.
"""

from __future__ import annotations

import logging

import numpy as np

from edge import native
from edge.npc import count_nonzero
from edge.track import kalman
from edge.track.config import PdafConfig
from edge.track.roles import Frame, build_roles, resolved_pairs
from edge.track.roles.delete import TrackDeleter
from edge.track.roles.initiate import SeedInitiator
from edge.track.roles.measure import MeasurementModel, extent_cov, heading
from edge.track.roles.predict import CvPredictor, ImmPredictor
from edge.track.table import IdPool, Measurements, TrackTable
from edge.types import TRACK_STATE_PLAIN as _TRACK_STATE_PLAIN
from edge.types import Detections, TrackState

log = logging.getLogger(__name__)

__all__ = ["PdafTracker", "TrackTable", "IdPool", "Measurements", "CvPredictor", "ImmPredictor", "MeasurementModel",
           "SeedInitiator", "TrackDeleter", "heading", "extent_cov"]


class PdafTracker(native.KernelUser):
    """Multi-target PDAF (or cheap JPDA) tracker of the lane profile; see the module docstring for the algorithm.

    ``road_yaw_rad`` (the road direction off the boresight, set by the lane pipeline from the traffic layer) is the
    input besides the detections. ``height_above_target_m``: the radar's height above the scatterer height the
    detections were projected to the ground with (the scatterer-height terms of the measurement model, the
    initiator, the confirmer and re-anchoring; 0: none); ``target_height_m``: that scatterer height above the road
    (None: unknown)."""

    def __init__(self, config: PdafConfig | None = None, height_above_target_m: float = 0.0,
                 target_height_m: float | None = None) -> None:
        self.config = config or PdafConfig()
        roles = build_roles(self.config)
        self.predictor = roles.predictor
        self.measurement_model = roles.measurement_model
        self.measurement_model.height_above_target_m = max(float(height_above_target_m), 0.0)
        self.measurement_model.target_height_m = None if target_height_m is None else max(float(target_height_m), 0.0)
        self.associator = roles.associator
        self.updater = roles.updater
        self.initiator = roles.initiator
        self.confirmer = roles.confirmer
        self.confirmer.height_above_target_m = self.measurement_model.height_above_target_m
        self.deleter = roles.deleter
        self.post_steps = roles.post_steps
        self._stateful = roles.stateful
        #: the compiled ``edge.native._track`` for :meth:`published` (None: the numpy reference)
        self.kernel = native.load("_track")
        self.road_yaw_rad = 0.0  # direction of the road off the boresight (the lane pipeline sets its estimate)
        # lateral_smoother: the motion model's x_m of the last published tracks (the published x_m is the line's)
        self.published_motion_x_m: np.ndarray | None = None
        self.reset()

    def reset(self) -> None:
        self.tracks = TrackTable()
        self.ids = IdPool(self.config.max_track_id)
        self.last_t_ns: int | None = None
        self.intermediates: dict[str, np.ndarray] = {}
        self.published_motion_x_m = None

    def step(self, detections: Detections, t_ns: int) -> tuple[TrackState, ...]:
        """Advance all tracks to ``t_ns`` with this frame's detections; return the published tracks."""
        meas = Measurements.from_detections(detections, self.measurement_model.use_radial_speed, self.kernel)
        dt_s = 0.0 if self.last_t_ns is None else max((t_ns - self.last_t_ns) * 1e-9, 0.0)
        self.last_t_ns = t_ns
        tr, n = self.tracks, meas.z.shape[1]
        used, mp, self.intermediates = np.zeros(meas.z.shape[0], dtype=bool), None, {}
        if tr.x.shape[0]:  # (len(tr) without its Python-level __len__)
            pred = self.predictor.predict(tr, dt_s, self.road_yaw_rad)
            mp = self.measurement_model.predict(pred, meas, tr.ext_var, self.associator.prune_gamma(n))
            hyp = self.associator.associate(meas, mp.inn, tr.confirmed, tr.hits)
            self.updater.update(tr, pred, mp, hyp, meas)
            self.measurement_model.learn(tr, pred.x, mp, hyp.beta, meas.z.shape[0])
            self.confirmer.score(tr, mp.inn, hyp.gated, n)
            used = self.associator.claimed(mp, pred.x, self.measurement_model)  # inside an exclusion gate: no seed
            if self.kernel is not None:  # hit = gated.any(axis=1) and tr.count(hit) in one pass (identical)
                hit, tr.misses, tr.history = self.kernel.count_hits(hyp.gated, tr.age, tr.hits, tr.misses, tr.history)
            else:
                hit = hyp.gated.any(axis=1)
                tr.count(hit)
            frame = Frame(meas, dt_s, pred, mp, hyp, hit, used)
            for post in self.post_steps:
                moved = post.run(tr, frame)
                if moved is not None:
                    for role in self._stateful:
                        role.restart(tr, moved)
            expired = self.confirmer.moving_and_expired(tr)  # (the deleter reads neither moved nor these columns)
            dead = self.deleter.delete(tr, resolved_pairs(meas.pair, hyp.beta, self.kernel)) | expired
            for tid in tr.track_id[dead & tr.confirmed]:
                self.ids.release(int(tid))
            if count_nonzero(dead):
                tr.keep(~dead, self.kernel)
            self.confirmer.confirm(tr, self.ids)  # after duplicates are gone: no id is spent on one
            self.intermediates = {"gated": hyp.gated, "beta0": hyp.beta0, "d2": mp.inn.d2}
        self.initiator.initiate(tr, meas, used, self.road_yaw_rad, mp)
        self.intermediates["used"] = used
        return self.published()

    def published(self) -> tuple[TrackState, ...]:
        tr = self.tracks
        if self.kernel is not None and _TRACK_STATE_PLAIN:  # the rows, their numbers and TrackStates in one call
            cfg = self.config
            res = self.kernel.publish_table(TrackState, tr, cfg.publish_tentative, cfg.publish_max_misses,
                                            cfg.lateral_smoother, cfg.lateral_smoother_cusum_nats, cfg.publish_length,
                                            self.confirmer.confirmed_log_odds)
            if res is not None:
                if cfg.lateral_smoother:
                    self.published_motion_x_m = res[1]
                return res[0]
        if self.config.publish_tentative:
            sel = tr.misses <= self.config.publish_max_misses
        else:
            sel = tr.confirmed & (tr.misses <= self.config.publish_max_misses)
        idx = sel.nonzero()[0]
        if idx.size == 0:
            if self.config.lateral_smoother:
                self.published_motion_x_m = None
            return ()
        if self.kernel is not None:
            return self._published_kernel(idx)
        st = tr.x.take(idx, axis=0)
        if self.config.lateral_smoother:  # the lateral position of the straight-line filter ...
            self.published_motion_x_m = st[:, 0].copy()
            c = tr.lat_cusum.take(idx)
            lat = tr.lat[:, 0].take(idx)
            # ... moved towards the motion model's by the evidence that the vehicle left its line (none: itself)
            st[:, 0] = kalman.lateral_blend(lat, st[:, 0], c, self.config.lateral_smoother_cusum_nats) if c.any() else lat
        x, y, vx, vy = st[:, 0], st[:, 1], st[:, 2], st[:, 3]
        rho = np.hypot(x, y)
        num = x * vx + y * vy
        if (rho > 0).all():  # always, unless a track sits on the radar (min_range_m = 0)
            vr = num / rho
        else:
            vr = np.divide(num, rho, out=np.zeros_like(rho), where=rho > 0)
        az = np.arctan2(x, y)
        if self.config.publish_length:  # moving (the weight of heading() is 1 from 1 m/s): the length is known
            length = [v if ok else None
                      for v, ok in zip(np.sqrt(12.0 * tr.ext_var[idx]).tolist(), (np.hypot(vx, vy) >= 1.0).tolist())]
        else:
            length = [None] * idx.size
        rows = zip(tr.track_id[idx].tolist(), st.tolist(), rho.tolist(), vr.tolist(), az.tolist(),
                   tr.age[idx].tolist(), tr.hits[idx].tolist(), tr.confirmed[idx].tolist(), length)
        quality = self._published_quality(idx)
        if not _TRACK_STATE_PLAIN:
            return tuple(TrackState(tid, x, y, vx, vy, r, v, a, age, hits, conf, length_m=ln, x_sd_m=xs, y_sd_m=ys,
                                    vx_sd_mps=vxs, vy_sd_mps=vys, existence_probability=pe)
                         for (tid, (x, y, vx, vy), r, v, a, age, hits, conf, ln), (xs, ys, vxs, vys, pe)
                         in zip(rows, quality))
        # TrackState(...) without the frozen dataclass's per-field object.__setattr__ (tens of tracks per
        # frame on the hot path): the same __dict__
        new, set_dict, cls = _new_object, _set_dict, TrackState
        out = []
        for (tid, (x, y, vx, vy), r, v, a, age, hits, conf, ln), (xs, ys, vxs, vys, pe) in zip(rows, quality):
            o = new(cls)
            set_dict(o, "__dict__", {
                "track_id": tid, "x_m": x, "y_m": y, "vx_mps": vx, "vy_mps": vy, "range_m": r,
                "radial_speed_mps": v, "az_rad": a, "age_frames": age, "hits": hits, "confirmed": conf, "lane": None,
                "cls": None, "class_probability": None, "rcs_dbsm": None, "length_m": ln, "x_sd_m": xs, "y_sd_m": ys,
                "vx_sd_mps": vxs, "vy_sd_mps": vys, "existence_probability": pe})
            out.append(o)
        return tuple(out)

    def _published_kernel(self, idx: np.ndarray) -> tuple[TrackState, ...]:
        """:meth:`published` for the rows ``idx`` from one kernel call: ``publish_states`` makes the TrackStates as well,
        ``publish_rows`` only their numbers (bit-identical)."""
        tr, cfg = self.tracks, self.config
        args = (tr.x, tr.p, idx.astype(np.int64, copy=False), tr.lat, tr.lat_p, tr.lat_cusum, tr.ext_var, tr.score,
                tr.confirmed.view(np.uint8), cfg.lateral_smoother, cfg.lateral_smoother_cusum_nats, cfg.publish_length,
                self.confirmer.confirmed_log_odds)
        if _TRACK_STATE_PLAIN:  # the TrackStates made in the kernel too (the same __dict__)
            states, num = self.kernel.publish_states(TrackState, *args, tr.track_id, tr.age, tr.hits)
            if cfg.lateral_smoother:
                self.published_motion_x_m = num[:, 14].copy()
            return states
        num = self.kernel.publish_rows(*args)  # TrackState is not the plain dataclass: its own constructor
        if cfg.lateral_smoother:
            self.published_motion_x_m = num[:, 14].copy()
        rows = zip(tr.track_id[idx].tolist(), num.tolist(), tr.age[idx].tolist(), tr.hits[idx].tolist(),
                   tr.confirmed[idx].tolist())
        return tuple(TrackState(tid, x, y, vx, vy, r, v, a, age, hits, conf, length_m=ln if has_ln else None,
                                x_sd_m=xs, y_sd_m=ys, vx_sd_mps=vxs, vy_sd_mps=vys, existence_probability=pe)
                     for tid, (x, y, vx, vy, r, v, a, ln, has_ln, xs, ys, vxs, vys, pe, _), age, hits, conf in rows)

    def _published_quality(self, idx: np.ndarray) -> zip:
        """Per published track (rows ``idx``): the standard deviations of the published x, y, vx, vy and the
        existence probability, as TrackState's quality fields.

        The deviations are the roots of the state covariance's diagonal (the published frame is the state's);
        with the lateral smoother the lateral one is the straight-line filter's, or the larger of the two while
        the published position moves towards the motion model's. The existence probability is the posterior
        ``1 / (1 + exp(-L))`` of the track score ``L`` (:mod:`edge.track.score`, prior odds 1; ``L`` stays 0 when
        confirmation = m_of_n keeps no score), and a confirmed track's ``L`` counts as at least Wald's
        threshold ``ln((1 - score_true_reject_prob) / score_false_confirm_prob)``, the evidence a confirmation
        stands for (an M-of-N confirmation is taken as equally strong): 0.9999 with the defaults."""
        tr, cfg = self.tracks, self.config
        sd = np.sqrt(np.maximum(np.diagonal(tr.p.take(idx, axis=0), axis1=1, axis2=2), 0.0))  # (n, 4): x, y, vx, vy
        if cfg.lateral_smoother:
            lat_sd = np.sqrt(np.maximum(tr.lat_p[:, 0, 0].take(idx), 0.0))
            sd[:, 0] = np.where(tr.lat_cusum.take(idx) > 0.0, np.maximum(lat_sd, sd[:, 0]), lat_sd)
        log_odds = tr.score.take(idx)
        floor = self.confirmer.confirmed_log_odds
        log_odds = np.where(tr.confirmed.take(idx), np.maximum(log_odds, floor), log_odds)
        p_exist = 1.0 / (1.0 + np.exp(-np.clip(log_odds, -700.0, 700.0)))
        return zip(*sd.T.tolist(), p_exist.tolist())


_new_object = object.__new__
_set_dict = object.__setattr__
