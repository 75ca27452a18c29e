"""Confirmer role: when a tentative track becomes a published vehicle (M of N hits, or the sequential track score of
:mod:`edge.track.score`; surely moving; not on a confirmed track's body), and when it can no longer."""

from __future__ import annotations

import logging

import numpy as np

from edge import native
from edge.track import kalman, score
from edge.track.config import AssociationConfig, ConfirmerConfig
from edge.track.pdaf import Innovations, gate_threshold
from edge.track.roles.box import SameVehicleBox
from edge.track.roles.measure import heading
from edge.track.smallmat import inv_quad2
from edge.track.table import IdPool, TrackTable

log = logging.getLogger(__name__)

__all__ = ["Confirmer"]


class Confirmer(native.KernelUser):
    """Confirmation by ``confirmation`` (m_of_n, score, either), once the track surely moves, unless a confirmed track
    moving alike lies on it (``confirm_block_*``); tentative tracks that can no longer confirm expire."""

    def __init__(self, cfg: ConfirmerConfig, assoc: AssociationConfig, box: SameVehicleBox) -> None:
        self.cfg, self.box = cfg, box
        self._prob_gate = assoc.prob_gate
        self._mask_n = np.uint32((1 << cfg.confirm_n) - 1)
        self.uses_score = cfg.confirmation in ("score", "either")
        self._score_confirm = score.confirm_threshold(cfg.score_false_confirm_prob, cfg.score_true_reject_prob)
        self._score_drop = -score.confirm_threshold(cfg.score_true_reject_prob, cfg.score_false_confirm_prob)
        self._density = {n: score.false_density(cfg.score_false_density_m2, cfg.score_speed_span_mps, n) for n in (2, 3)}
        self._moving_gamma = gate_threshold(cfg.moving_prob, 2)
        #: twice the sd of a scatterer's height (m): near the radar the block's speed test widens by its effect
        self._height_2sd_m = 2.0 * assoc.scatterer_height_sigma_m
        #: the radar's height above the assumed scatterers (m; the tracker sets it; 0: no height term)
        self.height_above_target_m = 0.0
        #: the compiled ``edge.native._track`` for :meth:`moving_and_expired` (None: the numpy reference)
        self.kernel = native.load("_track")

    @property
    def confirmed_log_odds(self) -> float:
        """Wald's confirmation threshold: the evidence (log-odds) a confirmation stands for."""
        return self._score_confirm

    def score(self, tracks: TrackTable, inn: Innovations, gated: np.ndarray, n: int) -> None:
        """Add this frame's log-likelihood ratio to every track's score (:func:`edge.track.score.score_increment`)."""
        if self.uses_score:
            c = self.cfg
            tracks.score += score.score_increment(inn.d2, inn.det_s, gated, n, c.score_prob_detect, self._prob_gate,
                                                  self._density[n])

    def update_moving(self, tracks: TrackTable) -> None:
        """Moving for sure: the velocity is significantly non-zero (``v' P_v^-1 v``) and fast enough."""
        v = tracks.x[:, 2:4]
        d2v = inv_quad2(tracks.p[:, 2:4, 2:4], v)
        tracks.moved |= (d2v > self._moving_gamma) & (np.hypot(v[:, 0], v[:, 1]) >= self.cfg.confirm_min_speed_mps)

    def _ready(self, tracks: TrackTable) -> np.ndarray:
        """Tentative tracks that pass the confirmation test (``confirmation``), before the moving and block rules."""
        c = self.cfg
        out = ~tracks.confirmed
        if c.confirmation == "score":
            return out & (tracks.score >= self._score_confirm)
        mofn = np.bitwise_count(tracks.history & self._mask_n) >= c.confirm_m
        if c.confirmation == "either":
            mofn |= tracks.score >= self._score_confirm
        return out & mofn

    def confirm(self, tracks: TrackTable, ids: IdPool) -> None:
        for i in self.confirming(tracks):
            tid = ids.acquire()
            if tid is None:
                log.warning("no free track id (max %d): track stays tentative", self.cfg.max_track_id)
                break
            tracks.track_id[i] = tid
            tracks.confirmed[i] = True

    def confirming(self, tracks: TrackTable):
        """The rows that confirm this frame, in row order: ready (:meth:`_ready`), moved, and not blocked by a confirmed
        track. One ``confirm_ready`` kernel call when it is built (the same rows as :meth:`confirming_numpy`)."""
        if self.kernel is None:
            return self.confirming_numpy(tracks)
        c, box = self.cfg, self.box.cfg
        mode = 1 if c.confirmation == "score" else 2 if c.confirmation == "either" else 0
        return self.kernel.confirm_ready(tracks.x, tracks.history, tracks.confirmed.view(np.uint8),
                                         tracks.moved.view(np.uint8), tracks.score, mode, self._score_confirm,
                                         self._mask_n, c.confirm_m, c.confirm_block_along_m, box.merge_lateral_m,
                                         box.merge_speed_mps, c.confirm_block_lateral_m, c.confirm_block_behind_m,
                                         c.confirm_block_speed_mps, self.height_speed_k)

    def confirming_numpy(self, tracks: TrackTable) -> np.ndarray:
        """:meth:`confirming` in numpy (the reference)."""
        c = self.cfg
        merge_lateral_m, merge_speed_mps = self.box.cfg.merge_lateral_m, self.box.cfg.merge_speed_mps
        ready = self._ready(tracks) & tracks.moved
        if c.confirm_block_along_m > 0 and np.count_nonzero(ready) and np.count_nonzero(tracks.confirmed):
            # a second track on a long vehicle (its front and its rear half) waits for the duplicate check
            r, k = np.flatnonzero(ready), np.flatnonzero(tracks.confirmed)
            xk = tracks.x.take(k, axis=0)
            d = tracks.x.take(r, axis=0)[:, None, :] - xk[None, :, :]
            u, _ = heading(xk)  # speed compared along the confirmed track's heading (a young track's
            dv = d[..., 2] * u[None, :, 0] + d[..., 3] * u[None, :, 1]  # lateral speed is still noise)
            along = np.abs(d[..., 1]) < c.confirm_block_along_m
            # the speed tests widen by the two tracks' radial-speed errors from scatterers 2 sd off the assumed
            # height: two scatterers of one truck near the radar read speeds metres per second apart
            hr = self.height_speed_sd(tracks.x.take(r, axis=0))
            hk = self.height_speed_sd(xk)
            wide = np.sqrt(hr[:, None] * hr[:, None] + hk[None, :] * hk[None, :])
            adv = np.abs(dv)
            blocked = (along & (((np.abs(d[..., 0]) < merge_lateral_m) & (adv < merge_speed_mps + wide))
                                | ((np.abs(d[..., 0]) < c.confirm_block_lateral_m) & (d[..., 1] > c.confirm_block_behind_m)
                                   & (adv < c.confirm_block_speed_mps + wide)))).any(axis=1)
            ready[r[blocked]] = False
        return ready.nonzero()[0]

    @property
    def height_speed_k(self) -> float:
        """``2 sigma_h dz`` (m^2): the radar's height above the assumed scatterers times twice their height sd."""
        return self.height_above_target_m * self._height_2sd_m

    def height_speed_sd(self, x: np.ndarray) -> np.ndarray:
        """(n,) the ground radial-speed error (m/s) of states ``x`` (n, 4) from a scatterer twice the height sd off
        the assumed height: ``2 sigma_h dz |v_r| / rho^2`` (:func:`edge.track.roles.measure.height_cov`'s speed
        term: ``v_r`` the predicted measurement's, ``rho`` at least 1 m)."""
        vr = kalman.measurement_prediction(x, True)[0][:, 2]
        rho = np.maximum(np.hypot(x[:, 0], x[:, 1]), 1.0)
        return self.height_speed_k * np.abs(vr) / (rho * rho)

    def moving_and_expired(self, tracks: TrackTable) -> np.ndarray:
        """:meth:`update_moving`, then :meth:`tentative_expired`'s mask: one kernel call when it is built."""
        if self.kernel is None:
            self.update_moving(tracks)
            return self.tentative_expired(tracks)
        c = self.cfg
        moved = tracks.moved.view(np.uint8)
        if not moved.flags.writeable:
            tracks.moved = tracks.moved.copy()
            moved = tracks.moved.view(np.uint8)
        out = self.kernel.moving_expired(tracks.x, tracks.p, tracks.history, tracks.age, tracks.misses,
                                         tracks.confirmed.view(np.uint8), moved, tracks.score, self._moving_gamma,
                                         c.confirm_min_speed_mps, c.confirmation == "score", self._mask_n, c.confirm_m,
                                         c.confirm_n, self._score_drop, c.tentative_keep_from_m,
                                         c.tentative_keep_min_hits)
        return out.view(bool)

    def tentative_expired(self, tracks: TrackTable) -> np.ndarray:
        """Tentative tracks that can no longer reach M hits in their last N frames (or Wald's lower threshold)."""
        c = self.cfg
        if c.confirmation == "score":
            return ~tracks.confirmed & (tracks.score <= self._score_drop)
        recent = tracks.history & self._mask_n
        counts = np.bitwise_count(recent)
        out = ~tracks.confirmed & (tracks.age >= c.confirm_n) & (counts < c.confirm_m) & (tracks.misses > 0)
        if c.tentative_keep_from_m > 0 and np.count_nonzero(out):  # far tracks: only once hardly anything hits any more
            far = np.hypot(tracks.x[:, 0], tracks.x[:, 1]) > c.tentative_keep_from_m
            out &= ~far | (counts < c.tentative_keep_min_hits)
        return out
