"""Initiator role: tentative tracks from detections no track explains, one seed per vehicle."""

from __future__ import annotations

import logging
import math

import numpy as np

from edge import native
from edge.track.config import FieldOfViewConfig, InitiatorConfig
from edge.track.roles.box import SameVehicleBox, box_close
from edge.track.roles.measure import MeasurementModel, MeasurementPrediction
from edge.track.table import Measurements, TrackTable

log = logging.getLogger(__name__)

__all__ = ["SeedInitiator"]

_SEED_MERGE_PLAIN_MAX = 8  # seed candidates up to which SeedInitiator merges them in plain Python
_NO_PAIR = np.zeros(0, dtype=np.int64)  # no resolved pairs (seed_candidates' placeholder)


class SeedInitiator(native.KernelUser):
    """Seeds from the detections outside every track's exclusion gate and same-vehicle box, moving, in the field of
    view; of one frame's candidates within one merge box the strongest seeds. With a radial speed the seed moves
    along the road (``road_yaw_rad`` off the boresight): its speed along the road from the radial speed (sd
    ``init_along_speed_sigma_mps``), ``init_lateral_speed_sigma_mps`` across it. ``height_sigma_m``: the sd of a
    scatterer's height; with the radar above the assumed height (the measurement model's ``height_above_target_m``)
    a detection too near the radar for its speed to be known does not seed (:meth:`_speed_known`)."""

    def __init__(self, cfg: InitiatorConfig, fov: FieldOfViewConfig, box: SameVehicleBox,
                 measurement_model: MeasurementModel, predictor=None, height_sigma_m: float = 0.0) -> None:
        self.cfg, self.fov, self.box = cfg, fov, box
        self.meas_model = measurement_model
        self.height_sigma_m = max(float(height_sigma_m), 0.0)
        self.predictor = predictor  # told of new rows (its per-model state), if any
        #: the compiled seed block (``edge.native._track``), or None: numpy
        self.kernel = native.load("_track")

    def initiate(self, tracks: TrackTable, meas: Measurements, used: np.ndarray, road_yaw_rad: float = 0.0,
                 mp: MeasurementPrediction | None = None) -> int:
        """Seed tentative tracks; ``used`` (M,) the detections tracks claimed. Returns the number of seeds."""
        c, box = self.cfg, self.box
        z = meas.z
        idx, resolved = self.candidates(tracks, meas, used)
        if idx.size == 0:
            return 0
        zc = z.take(idx, axis=0)
        known = self._speed_known(zc) if meas.with_radial_speed else None
        if known is not None and not known.all():
            idx, zc = idx.compress(known), zc.compress(known, axis=0)
            if idx.size == 0:
                return 0
        # one seed per vehicle: drop a candidate when a stronger one lies in its merge box
        if idx.size == 1:  # one candidate: nothing to merge
            seed_idx = idx
        elif idx.size <= _SEED_MERGE_PLAIN_MAX:  # a handful: the same comparisons on Python floats, pair by pair
            seed_idx = self._merge_seeds_plain(idx, zc, meas.snr_db.take(idx), resolved.take(idx),
                                               meas.with_radial_speed)
        else:
            snr = meas.snr_db[idx]
            lat_c = np.where(resolved[idx][None, :] & resolved[idx][:, None], box.cfg.merge_lateral_m,
                             box.lateral_m(zc[:, :2])[:, None])
            close = box_close(zc[:, :2], zc[:, :2], lat_c, c.init_merge_along_m)
            if meas.with_radial_speed:  # detections of one vehicle share its radial speed
                close &= np.abs(zc[:, None, 2] - zc[None, :, 2]) < c.seed_merge_speed_mps
            order = np.arange(idx.size)
            stronger = (snr[None, :] > snr[:, None]) | ((snr[None, :] == snr[:, None]) & (order[None, :] < order[:, None]))
            seed_idx = idx.compress(~(close & stronger).any(axis=1))
        seeds = z.take(seed_idx, axis=0)
        room = c.max_tracks - len(tracks)
        if room <= 0:
            log.debug("track table full (%d): %d seeds dropped", c.max_tracks, seeds.shape[0])
            return 0
        seeds, seed_idx = seeds[:room], seed_idx[:room]
        k = seeds.shape[0]
        if self.meas_model.per_detection:  # the seed's own noise (its SNR)
            # computed for the seeds only, or taken from this frame's (the same values)
            r = (self.meas_model.of_detections(meas, 2, rows=seed_idx) if mp is None or mp.rm is None
                 else mp.rm.take(seed_idx, axis=0)[:, :2, :2])
        else:
            x0 = np.zeros((k, 4))
            x0[:, :2] = seeds[:, :2]
            _, _, r = self.meas_model.at(x0, False)
        x0, p0, var_s = self.seed_states(seeds, r, road_yaw_rad, meas.with_radial_speed)
        tracks.append(x0, p0, self.meas_model.initial_extent_var, kernel=self.kernel)
        if self.predictor is not None:
            self.predictor.seeded(tracks, k, road_yaw_rad, var_s)
        return k

    def _speed_known(self, zc: np.ndarray) -> np.ndarray | None:
        """(K,) which candidates ``zc`` (K, 3) have a speed the scatterer height leaves within two sds of a seed's
        (None: no height term): a scatterer one sd (``height_sigma_m``) above the assumed height reads
        ``|vr| dz / rho^2`` faster (``dz`` the radar's height above the assumed scatterers), so near the radar a
        detection seeds only when that is at most twice ``init_along_speed_sigma_mps``."""
        dz = self.meas_model.height_above_target_m
        if dz <= 0.0 or self.height_sigma_m <= 0.0:
            return None
        rho2 = zc[:, 0] * zc[:, 0] + zc[:, 1] * zc[:, 1]
        return dz * self.height_sigma_m * np.abs(zc[:, 2]) <= 2.0 * self.cfg.init_along_speed_sigma_mps * rho2

    def seed_states(self, seeds: np.ndarray, r: np.ndarray, road_yaw_rad: float, with_radial_speed: bool):
        """New tracks at the seeds (k, n) with position noise ``r`` (k, 2, 2): ``(x0, p0, var_s)``, ``var_s`` the seeds'
        speed variance along the road for the predictor (None without a radial speed). The ``seed_states`` kernel when
        built (the same values as :meth:`seed_states_numpy`)."""
        if self.kernel is None:
            return self.seed_states_numpy(seeds, r, road_yaw_rad, with_radial_speed)
        c = self.cfg
        x0, p0, var_s, all_along = self.kernel.seed_states(
            seeds, r, with_radial_speed, math.cos(road_yaw_rad), math.sin(road_yaw_rad),
            c.init_lateral_speed_sigma_mps**2, c.init_along_speed_sigma_mps**2, c.init_speed_sigma_mps**2)
        if not with_radial_speed:
            return x0, p0, None
        return x0, p0, (c.init_along_speed_sigma_mps**2 if all_along else var_s)

    def seed_states_numpy(self, seeds: np.ndarray, r: np.ndarray, road_yaw_rad: float, with_radial_speed: bool):
        """:meth:`seed_states` in numpy (the reference)."""
        c = self.cfg
        k = seeds.shape[0]
        x0 = np.zeros((k, 4))
        x0[:, :2] = seeds[:, :2]
        p0 = np.zeros((k, 4, 4))
        p0[:, :2, :2] = r
        var_s = None
        if with_radial_speed:
            # road direction e_s = (-sin yaw, cos yaw), across it e_u = (cos yaw, sin yaw): v = v_s e_s with
            # v_r = v_s (e_s . p) / |p|
            cy, sy = math.cos(road_yaw_rad), math.sin(road_yaw_rad)
            proj = cy * seeds[:, 1] - sy * seeds[:, 0]  # e_s . p
            rho_s = np.hypot(seeds[:, 0], seeds[:, 1])
            ok = np.abs(proj) > 1.0
            if ok.all():  # the usual case: no seed right beside the radar across the road
                v_s = seeds[:, 2] * rho_s / proj
                var_s = c.init_along_speed_sigma_mps**2  # one value for all seeds: the covariances below once
            else:
                v_s = np.where(ok, seeds[:, 2] * rho_s / np.where(ok, proj, 1.0), 0.0)
                var_s = np.where(ok, c.init_along_speed_sigma_mps**2, c.init_speed_sigma_mps**2)
            x0[:, 2], x0[:, 3] = -sy * v_s, cy * v_s
            var_u = c.init_lateral_speed_sigma_mps**2
            p0[:, 2, 2] = cy * cy * var_u + sy * sy * var_s
            p0[:, 3, 3] = sy * sy * var_u + cy * cy * var_s
            p0[:, 2, 3] = p0[:, 3, 2] = cy * sy * (var_u - var_s)
        else:
            p0[:, 2, 2] = p0[:, 3, 3] = c.init_speed_sigma_mps**2
        return x0, p0, var_s

    def candidates(self, tracks: TrackTable, meas: Measurements, used: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The detections that may seed (rows, ascending) and the resolved ones (M,) bool: not claimed by a track
        (``used``) unless split from a merged detection, in the field's range, moving, and in no track's
        same-vehicle box at its speed. The compiled ``seed_candidates`` when built (identical)."""
        c, box, z = self.cfg, self.box, meas.z
        if self.kernel is not None:
            bc = box.cfg
            return self.kernel.seed_candidates(
                z, used, _NO_PAIR if meas.pair is None else meas.pair, meas.pair is not None, tracks.x,
                tracks.ext_var, self.fov.min_range_m, self.fov.max_range_m, meas.with_radial_speed,
                c.seed_min_radial_speed_mps, bc.merge_lateral_sigmas, math.radians(box.azimuth_sigma_deg),
                bc.merge_lateral_m, max(bc.merge_lateral_m, bc.merge_lateral_max_m), bc.merge_along_m,
                bc.merge_headway_s, bc.merge_extent_factor, c.seed_merge_speed_mps)
        rho = np.hypot(z[:, 0], z[:, 1])
        # a detection split from a merged one (two vehicles side by side) lies inside the gate of the track
        # that followed the merged detection: it may seed unless a track sits right on it
        resolved = meas.pair >= 0 if meas.pair is not None else np.zeros(z.shape[0], bool)
        cand = (~used | resolved) & (rho >= self.fov.min_range_m) & (rho <= self.fov.max_range_m)
        if meas.with_radial_speed:
            cand &= np.abs(z[:, 2]) >= c.seed_min_radial_speed_mps
        if tracks.x.shape[0] and np.count_nonzero(cand):
            cand &= ~self._near(tracks, meas, resolved)
        return cand.nonzero()[0], resolved

    def _near(self, tracks: TrackTable, meas: Measurements, resolved: np.ndarray) -> np.ndarray:
        """(M,) detections in some track's same-vehicle box (a resolved one: ``merge_lateral_m`` across) and, with
        a radial speed, moving like it: they do not seed."""
        xt, z, box = tracks.x, meas.z, self.box
        lat = box.lateral_m(xt[:, :2])[:, None]
        if meas.pair is not None:
            lat = np.where(resolved[None, :], box.cfg.merge_lateral_m, lat)
        d = xt[:, None, :2] - z[None, :, :2]  # (T, M, 2)
        near = (np.abs(d[..., 0]) < lat) & (np.abs(d[..., 1]) < box.along_m(tracks)[:, None])
        if meas.with_radial_speed:  # ... and moving like the track
            rho_t = np.maximum(np.hypot(xt[:, 0], xt[:, 1]), 1e-3)
            vr_t = (xt[:, 0] * xt[:, 2] + xt[:, 1] * xt[:, 3]) / rho_t
            near &= np.abs(vr_t[:, None] - z[None, :, 2]) < self.cfg.seed_merge_speed_mps
        return near.any(axis=0)

    def _near_kernel(self, tracks: TrackTable, meas: Measurements, resolved: np.ndarray) -> np.ndarray:
        """:meth:`_near` in the compiled kernel (the same arithmetic)."""
        xt, z, box = tracks.x, meas.z, self.box
        if meas.with_radial_speed:
            rho_t = np.maximum(np.hypot(xt[:, 0], xt[:, 1]), 1e-3)
            vr_t = (xt[:, 0] * xt[:, 2] + xt[:, 1] * xt[:, 3]) / rho_t
        else:
            vr_t = np.zeros(xt.shape[0])
        return self.kernel.near_tracks(np.ascontiguousarray(xt), np.ascontiguousarray(z),
                                       np.ascontiguousarray(box.lateral_m(xt[:, :2]), dtype=np.float64),
                                       np.ascontiguousarray(box.along_m(tracks), dtype=np.float64),
                                       np.ascontiguousarray(resolved, dtype=bool), box.cfg.merge_lateral_m, vr_t,
                                       meas.with_radial_speed, self.cfg.seed_merge_speed_mps)

    def _merge_seeds_plain(self, idx: np.ndarray, zc: np.ndarray, snr: np.ndarray, resolved: np.ndarray,
                           with_radial_speed: bool) -> np.ndarray:
        """The merge of :meth:`initiate`'s candidates (a candidate goes when a stronger one, or an equally strong
        earlier one, lies in its merge box at its radial speed) for a handful of them, in plain Python: the same
        float64 differences and comparisons as the (A, A) array form, a few calls fewer."""
        c = self.cfg
        rows = zc.tolist()
        sl = snr.tolist()
        res = resolved.tolist()
        lat_i = self.box.lateral_m(zc[:, :2]).tolist()
        lat_pair, along, dv = self.box.cfg.merge_lateral_m, c.init_merge_along_m, c.seed_merge_speed_mps
        keep = []
        for i, zi in enumerate(rows):
            si, ri, li = sl[i], res[i], lat_i[i]
            for j, zj in enumerate(rows):
                sj = sl[j]
                if not (sj > si or (sj == si and j < i)):  # j is not stronger (never itself)
                    continue
                if (abs(zi[0] - zj[0]) < (lat_pair if ri and res[j] else li) and abs(zi[1] - zj[1]) < along
                        and (not with_radial_speed or abs(zi[2] - zj[2]) < dv)):
                    break
            else:
                keep.append(i)
        return idx.take(np.array(keep, dtype=np.intp))
