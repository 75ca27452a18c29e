"""The lane profile's multi-target tracker: a thin orchestrator over role objects (after Stone Soup
``tracker/simple.py``): predict, associate (gate + weights), update, delete, initiate.

Public API (stable; used by ``edge.pipelines.lane``)::

    from edge.track import PdafConfig, PdafTracker
    tracker = PdafTracker(PdafConfig())            # or cfg.section("track.pdaf")
    tracks = tracker.step(detections, t_ns)        # tuple[TrackState, ...], confirmed tracks
    tracker.intermediates                          # arrays of the last step, for plots
    tracker.reset()

``detections`` is an :class:`edge.types.Detections` (ground-plane ``x_m``, ``y_m``; ``range_m`` and
``radial_speed_mps`` as measured), ``t_ns`` the frame time (monotonic). Published tracks carry a small
recycled integer ``track_id`` in ``1..max_track_id`` given at confirmation; ``lane`` and ``cls`` are
left ``None`` for later stages (:mod:`edge.traffic` fills ``lane``). ``range_m`` of a track is the
ground range ``hypot(x, y)`` and ``radial_speed_mps`` the ground-plane radial speed.

The measured radial speed is slant (the radar is above the road); it is projected to the ground
plane with the detection's own range: ``v_ground = v_r * range_m / hypot(x_m, y_m)``. Frames whose
radial speeds are not all finite fall back to position-only updates.

Tracks are held as a struct of arrays (:class:`TrackTable`): the per-frame work is a handful of
batched numpy operations over tracks x detections; there is no Python object per detection.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from edge.track import kalman
from edge.track.config import PdafConfig
from edge.track.pdaf import Innovations, association_weights, combined_update, gate_threshold, innovations
from edge.types import Detections, TrackState

log = logging.getLogger(__name__)

__all__ = ["PdafTracker", "TrackTable", "IdPool"]


class IdPool:
    """Small integer ids ``1..max_id``, handed out lowest-first at start, then oldest-released first
    (a released id waits as long as possible before it is reused, so consumers do not confuse vehicles)."""

    def __init__(self, max_id: int) -> None:
        self._free: deque[int] = deque(range(1, max_id + 1))
        self._used: set[int] = set()

    def acquire(self) -> int | None:
        if not self._free:
            return None
        i = self._free.popleft()
        self._used.add(i)
        return i

    def release(self, track_id: int) -> None:
        if track_id in self._used:
            self._used.remove(track_id)
            self._free.append(track_id)

    @property
    def in_use(self) -> int:
        return len(self._used)


@dataclass
class TrackTable:
    """All tracks as columns (row = track). ``track_id`` is 0 until a track is confirmed."""

    x: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    p: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    track_id: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    age: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    hits: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    misses: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    history: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint32))  # bit 0 = this frame hit
    confirmed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    moved: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # was ever surely moving

    _COLUMNS = ("x", "p", "track_id", "age", "hits", "misses", "history", "confirmed", "moved")

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def keep(self, mask: np.ndarray) -> None:
        for c in self._COLUMNS:
            setattr(self, c, getattr(self, c)[mask])

    def append(self, x: np.ndarray, p: np.ndarray) -> None:
        k = x.shape[0]
        self.x = np.concatenate([self.x, x])
        self.p = np.concatenate([self.p, p])
        self.track_id = np.concatenate([self.track_id, np.zeros(k, dtype=np.int32)])
        self.age = np.concatenate([self.age, np.ones(k, dtype=np.int32)])
        self.hits = np.concatenate([self.hits, np.ones(k, dtype=np.int32)])
        self.misses = np.concatenate([self.misses, np.zeros(k, dtype=np.int32)])
        self.history = np.concatenate([self.history, np.ones(k, dtype=np.uint32)])
        self.confirmed = np.concatenate([self.confirmed, np.zeros(k, dtype=bool)])
        self.moved = np.concatenate([self.moved, np.zeros(k, dtype=bool)])


@dataclass
class Measurements:
    """One frame's detections as the filter sees them (float64, ground plane)."""

    z: np.ndarray  # (M, n): x, y[, ground radial speed]
    snr_db: np.ndarray  # (M,)
    with_radial_speed: bool

    @classmethod
    def from_detections(cls, det: Detections, use_radial_speed: bool) -> "Measurements":
        x = det.x_m.astype(np.float64)
        y = det.y_m.astype(np.float64)
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok], y[ok]
        snr = det.snr_db.astype(np.float64)[ok]
        vr = det.radial_speed_mps.astype(np.float64)[ok]
        rng = det.range_m.astype(np.float64)[ok]
        use = use_radial_speed and bool(np.all(np.isfinite(vr)) and np.all(np.isfinite(rng)))
        if use:
            rho = np.hypot(x, y)
            ratio = np.divide(rng, rho, out=np.ones_like(rho), where=rho > 1e-6)
            z = np.stack([x, y, vr * ratio], axis=1)
        else:
            z = np.stack([x, y], axis=1)
        return cls(z, np.nan_to_num(snr, nan=0.0), use)


class CvPredictor:
    """Constant-velocity prediction of every track to the frame time."""

    def __init__(self, cfg: PdafConfig) -> None:
        self.cfg = cfg

    def predict(self, tracks: TrackTable, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        f = kalman.cv_transition(dt_s)
        q = kalman.cv_process_noise(dt_s, self.cfg.q_lateral_m2ps3, self.cfg.q_along_m2ps3)
        return kalman.predict(tracks.x, tracks.p, f, q)


class MeasurementModel:
    """``z_hat``, ``H`` and ``R`` per track at its prediction."""

    def __init__(self, cfg: PdafConfig) -> None:
        self.cfg = cfg
        self._az_sigma_rad = math.radians(cfg.azimuth_sigma_deg)

    def at(self, xp: np.ndarray, with_radial_speed: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = self.cfg
        zh, h = kalman.measurement_prediction(xp, with_radial_speed)
        rp = kalman.polar_position_noise(xp[:, :2], c.range_sigma_m, self._az_sigma_rad, c.extent_sigma_m)
        n = zh.shape[1]
        r = np.zeros((xp.shape[0], n, n))
        r[:, :2, :2] = rp
        if n == 3:
            r[:, 2, 2] = c.radial_speed_sigma_mps**2
        return zh, h, r


class PdaAssociator:
    """Gate (eq. 17) and association probabilities (eqs. 18-19, or cheap JPDA)."""

    def __init__(self, cfg: PdafConfig) -> None:
        self.cfg = cfg
        self._gamma = {n: gate_threshold(cfg.prob_gate, n) for n in (2, 3)}
        self.exclusion_gamma = {n: gate_threshold(max(cfg.init_exclusion_prob, cfg.prob_gate), n) for n in (2, 3)}

    def associate(self, meas: Measurements, zh, h, pp, r, confirmed: np.ndarray):
        """Confirmed tracks validate first; tentative tracks only see detections no confirmed track
        validated (a tentative track born from clutter next to a vehicle must not live off its points)."""
        inn = innovations(meas.z, zh, h, pp, r)
        n = meas.z.shape[1]
        gamma = self._gamma[n]
        taken = ((inn.d2 <= gamma) & confirmed[:, None]).any(axis=0)
        allowed = confirmed[:, None] | ~taken[None, :]
        beta, beta0, gated = association_weights(
            inn, gamma, self.cfg.prob_detect, self.cfg.prob_gate, self.cfg.association, allowed
        )
        return inn, beta, beta0, gated


class PdaUpdater:
    def update(self, xp, pp, h, inn: Innovations, beta, beta0):
        return combined_update(xp, pp, h, inn, beta, beta0)


def _box_close(a_xy: np.ndarray, b_xy: np.ndarray, lat_m: float, along_m: float) -> np.ndarray:
    """(A, B) bool: points closer than the box half-sizes in x and y."""
    d = a_xy[:, None, :] - b_xy[None, :, :]
    return (np.abs(d[..., 0]) < lat_m) & (np.abs(d[..., 1]) < along_m)


class MofNInitiator:
    """Tentative tracks from detections no track explains; confirmation after M hits in N frames."""

    def __init__(self, cfg: PdafConfig, meas_model: MeasurementModel) -> None:
        self.cfg = cfg
        self.meas_model = meas_model
        self._mask_n = np.uint32((1 << cfg.confirm_n) - 1)

    def initiate(self, tracks: TrackTable, meas: Measurements, used: np.ndarray) -> int:
        c = self.cfg
        z = meas.z
        rho = np.hypot(z[:, 0], z[:, 1])
        cand = ~used & (rho >= c.min_range_m) & (rho <= c.max_range_m)
        if len(tracks):
            near = _box_close(tracks.x[:, :2], z[:, :2], c.merge_lateral_m, c.merge_along_m).any(axis=0)
            cand &= ~near
        idx = np.flatnonzero(cand)
        if idx.size == 0:
            return 0
        # one seed per vehicle: drop a candidate when a stronger one lies in its merge box
        zc, snr = z[idx], meas.snr_db[idx]
        close = _box_close(zc[:, :2], zc[:, :2], c.merge_lateral_m, c.merge_along_m)
        order = np.arange(idx.size)
        stronger = (snr[None, :] > snr[:, None]) | ((snr[None, :] == snr[:, None]) & (order[None, :] < order[:, None]))
        seeds = zc[~(close & stronger).any(axis=1)]
        room = c.max_tracks - len(tracks)
        if room <= 0:
            log.debug("track table full (%d): %d seeds dropped", c.max_tracks, seeds.shape[0])
            return 0
        seeds = seeds[:room]
        k = seeds.shape[0]
        x0 = np.zeros((k, 4))
        x0[:, :2] = seeds[:, :2]
        p0 = np.zeros((k, 4, 4))
        _, _, r = self.meas_model.at(x0, False)
        p0[:, :2, :2] = r
        if meas.with_radial_speed:
            y = seeds[:, 1]
            rho_s = np.hypot(seeds[:, 0], y)
            ok = np.abs(y) > 1.0
            x0[:, 3] = np.where(ok, seeds[:, 2] * rho_s / np.where(ok, y, 1.0), 0.0)
            p0[:, 2, 2] = c.init_lateral_speed_sigma_mps**2
            p0[:, 3, 3] = np.where(ok, c.init_along_speed_sigma_mps**2, c.init_speed_sigma_mps**2)
        else:
            p0[:, 2, 2] = p0[:, 3, 3] = c.init_speed_sigma_mps**2
        tracks.append(x0, p0)
        return k

    def confirm(self, tracks: TrackTable, ids: IdPool) -> None:
        c = self.cfg
        recent = tracks.history & self._mask_n
        counts = np.array([int(v).bit_count() for v in recent], dtype=np.int32) if len(tracks) else recent
        ready = ~tracks.confirmed & (counts >= c.confirm_m) & tracks.moved
        for i in np.flatnonzero(ready):
            tid = ids.acquire()
            if tid is None:
                log.warning("no free track id (max %d): track stays tentative", c.max_track_id)
                break
            tracks.track_id[i] = tid
            tracks.confirmed[i] = True

    def tentative_expired(self, tracks: TrackTable) -> np.ndarray:
        """Tentative tracks that can no longer reach M hits in their last N frames."""
        c = self.cfg
        recent = tracks.history & self._mask_n
        counts = np.array([int(v).bit_count() for v in recent], dtype=np.int32) if len(tracks) else recent
        return ~tracks.confirmed & (tracks.age >= c.confirm_n) & (counts < c.confirm_m) & (tracks.misses > 0)


class TrackDeleter:
    """Deletion: misses in a row, diverged covariance, out of the field, duplicates of an older track."""

    def __init__(self, cfg: PdafConfig) -> None:
        self.cfg = cfg

    def delete(self, tracks: TrackTable) -> np.ndarray:
        c = self.cfg
        rho = np.hypot(tracks.x[:, 0], tracks.x[:, 1])
        sig = np.sqrt(np.maximum(tracks.p[:, 0, 0], tracks.p[:, 1, 1]))
        dead = (tracks.misses >= c.delete_after_misses) | (sig > c.max_position_sigma_m)
        dead |= (rho < c.min_range_m) | (rho > c.max_range_m)
        return dead | self.duplicates(tracks)

    def duplicates(self, tracks: TrackTable) -> np.ndarray:
        """Of two tracks on one vehicle, drop the junior (unconfirmed first, then fewer hits, then younger)."""
        c = self.cfg
        t = len(tracks)
        out = np.zeros(t, dtype=bool)
        if t < 2:
            return out
        close = _box_close(tracks.x[:, :2], tracks.x[:, :2], c.merge_lateral_m, c.merge_along_m)
        dv = np.hypot(tracks.x[:, None, 2] - tracks.x[None, :, 2], tracks.x[:, None, 3] - tracks.x[None, :, 3])
        pair = close & (dv < c.merge_speed_mps)
        np.fill_diagonal(pair, False)
        if not pair.any():
            return out
        rank = tracks.confirmed.astype(np.int64) * (1 << 40) + tracks.hits.astype(np.int64) * (1 << 20) + tracks.age
        junior = rank[:, None] < rank[None, :]
        tie = (rank[:, None] == rank[None, :]) & (np.arange(t)[:, None] > np.arange(t)[None, :])
        out = (pair & (junior | tie)).any(axis=1)
        return out


class PdafTracker:
    """Multi-target PDAF (or cheap JPDA) tracker with a constant-velocity Kalman filter.

    One :meth:`step` per frame::

        predict -> associate (gate, beta) -> update -> confirm -> delete -> initiate -> publish
    """

    def __init__(self, config: PdafConfig | None = None) -> None:
        self.config = config or PdafConfig()
        self.predictor = CvPredictor(self.config)
        self.measurement_model = MeasurementModel(self.config)
        self.associator = PdaAssociator(self.config)
        self.updater = PdaUpdater()
        self.initiator = MofNInitiator(self.config, self.measurement_model)
        self.deleter = TrackDeleter(self.config)
        self.reset()

    def reset(self) -> None:
        self.tracks = TrackTable()
        self.ids = IdPool(self.config.max_track_id)
        self.last_t_ns: int | None = None
        self.intermediates: dict[str, np.ndarray] = {}

    def step(self, detections: Detections, t_ns: int) -> tuple[TrackState, ...]:
        """Advance all tracks to ``t_ns`` with this frame's detections; return the published tracks."""
        cfg = self.config
        meas = Measurements.from_detections(detections, cfg.use_radial_speed)
        dt_s = 0.0 if self.last_t_ns is None else max((t_ns - self.last_t_ns) * 1e-9, 0.0)
        self.last_t_ns = t_ns
        tr = self.tracks
        m = meas.z.shape[0]
        used = np.zeros(m, dtype=bool)
        if len(tr):
            xp, pp = self.predictor.predict(tr, dt_s)
            zh, h, r = self.measurement_model.at(xp, meas.with_radial_speed)
            inn, beta, beta0, gated = self.associator.associate(meas, zh, h, pp, r, tr.confirmed)
            tr.x, tr.p = self.updater.update(xp, pp, h, inn, beta, beta0)
            hit = gated.any(axis=1)
            used = (inn.d2 <= self.associator.exclusion_gamma[meas.z.shape[1]]).any(axis=0)
            tr.age += 1
            tr.hits += hit
            tr.misses = np.where(hit, 0, tr.misses + 1).astype(np.int32)
            tr.history = ((tr.history << np.uint32(1)) | hit.astype(np.uint32)).astype(np.uint32)
            # moving for sure: speed minus two standard deviations of its estimate above the minimum
            sd_v = np.sqrt(0.5 * (tr.p[:, 2, 2] + tr.p[:, 3, 3]))
            tr.moved |= np.hypot(tr.x[:, 2], tr.x[:, 3]) - 2.0 * sd_v >= cfg.confirm_min_speed_mps
            self.initiator.confirm(tr, self.ids)
            dead = self.deleter.delete(tr) | self.initiator.tentative_expired(tr)
            for tid in tr.track_id[dead & tr.confirmed]:
                self.ids.release(int(tid))
            tr.keep(~dead)
            self.intermediates = {"gated": gated, "beta0": beta0, "d2": inn.d2}
        else:
            self.intermediates = {}
        self.initiator.initiate(tr, meas, used)
        self.intermediates["used"] = used
        return self.published()

    def published(self) -> tuple[TrackState, ...]:
        tr = self.tracks
        sel = np.ones(len(tr), dtype=bool) if self.config.publish_tentative else tr.confirmed
        out = []
        for i in np.flatnonzero(sel):
            x, y, vx, vy = (float(v) for v in tr.x[i])
            rho = math.hypot(x, y)
            out.append(
                TrackState(
                    track_id=int(tr.track_id[i]),
                    x_m=x,
                    y_m=y,
                    vx_mps=vx,
                    vy_mps=vy,
                    range_m=rho,
                    radial_speed_mps=(x * vx + y * vy) / rho if rho > 0 else 0.0,
                    az_rad=math.atan2(x, y),
                    age_frames=int(tr.age[i]),
                    hits=int(tr.hits[i]),
                    confirmed=bool(tr.confirmed[i]),
                )
            )
        return tuple(out)
