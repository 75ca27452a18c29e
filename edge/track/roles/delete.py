"""Deleter role: tracks that missed too long, diverged, left the field of view, or duplicate an older track."""

from __future__ import annotations

import math

import numpy as np

from edge import native
from edge.track.config import DeleterConfig, FieldOfViewConfig
from edge.track.pdaf import gate_threshold
from edge.track.roles.box import SameVehicleBox
from edge.track.roles.measure import extent_cov
from edge.track.table import TrackTable

__all__ = ["TrackDeleter", "resolved_pairs"]

_NO_ROWS = np.zeros(0, dtype=np.int64)


def resolved_pairs(pair: np.ndarray | None, beta: np.ndarray, kernel=None) -> tuple[np.ndarray, np.ndarray] | None:
    """Per track the resolved pair (``Measurements.pair``, or -1) of the detection that carries it (largest weight,
    above 0.5) and that detection: tracks on the two members of one pair are two vehicles, not duplicates.
    ``kernel``: the compiled ``edge.native._track`` (``carrying_pairs``, the same values) for an int64 ``pair``."""
    if pair is None or beta.shape[1] == 0:
        return None
    if kernel is not None and pair.dtype == np.int64:
        return kernel.carrying_pairs(beta, pair)
    best, strong = carrying_detection(beta)
    return np.where(strong, pair[best], -1), best


def carrying_detection(beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per track, the detection of largest association weight and whether it carries the track (weight > 0.5)."""
    best = np.argmax(beta, axis=1)
    return best, beta[np.arange(beta.shape[0]), best] > 0.5


class TrackDeleter(native.KernelUser):
    """Deletion: misses in a row, diverged covariance, out of the field, duplicates of an older track."""

    def __init__(self, cfg: DeleterConfig, fov: FieldOfViewConfig, box: SameVehicleBox) -> None:
        self.cfg, self.fov, self.box = cfg, fov, box
        self._state_gamma = gate_threshold(cfg.merge_state_prob, 4)
        self._pairs: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # track count -> np.triu_indices(t, 1)
        self._pairs_all: tuple[np.ndarray, np.ndarray] = np.triu_indices(32, 1)  # for up to 32 tracks (grows)
        #: the compiled pair tests of :meth:`duplicates` (``edge.native._track``), or None: numpy
        self.kernel = native.load("_track")

    def pairs(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """``np.triu_indices(t, 1)`` (row-major pairs ``a < b``), cached per track count; a new count takes the
        pairs ``b < t`` of a larger table in their order (the same arrays, 3 calls instead of ~60 us)."""
        pairs = self._pairs.get(t)
        if pairs is None:
            ia, ib = self._pairs_all
            n_all = int(ib[-1]) + 1 if ib.size else 1
            if t > n_all:
                ia, ib = self._pairs_all = np.triu_indices(max(t, 2 * n_all), 1)
            m = ib < t
            pairs = self._pairs[t] = (ia.compress(m), ib.compress(m))
        return pairs

    def delete(self, tracks: TrackTable, resolved: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """``resolved``: per track the resolved pair (or -1) and the detection it followed this frame."""
        c = self.cfg
        if self.kernel is not None:  # the tests of every track and the duplicate test's inputs in one pass
            dead, pdx, pdy, along = self.kernel.delete_tests(
                tracks.x, tracks.p, tracks.misses, tracks.ext_var, c.delete_after_misses, c.max_position_sigma_m,
                self.fov.min_range_m, self.fov.max_range_m, math.radians(self.fov.max_azimuth_deg),
                self.box.cfg.merge_along_m, self.box.cfg.merge_headway_s, self.box.cfg.merge_extent_factor)
            return dead | self._duplicates_kernel(tracks, resolved, (pdx, pdy, along)) if tracks.x.shape[0] >= 2 else dead
        rho = np.hypot(tracks.x[:, 0], tracks.x[:, 1])
        sig = np.sqrt(np.maximum(tracks.p[:, 0, 0], tracks.p[:, 1, 1]))
        dead = (tracks.misses >= c.delete_after_misses) | (sig > c.max_position_sigma_m)
        dead |= (rho < self.fov.min_range_m) | (rho > self.fov.max_range_m)
        dead |= np.abs(np.arctan2(tracks.x[:, 0], tracks.x[:, 1])) > math.radians(self.fov.max_azimuth_deg)
        return dead | self.duplicates(tracks, resolved)

    def duplicates(self, tracks: TrackTable, resolved: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Of two tracks on one vehicle, drop the junior (unconfirmed first, then fewer hits, then younger).

        Two tracks are one vehicle when their velocities agree within ``merge_speed_mps`` along their common
        heading and ``merge_lateral_speed_mps`` across it (or they stayed in the same-vehicle box for
        ``merge_persist_frames``, whatever their lateral speeds) and either their
        positions are within the same-vehicle box or their states are statistically indistinguishable
        (position covariances widened by the vehicles' along-heading spread)."""
        c = self.cfg
        t = len(tracks)
        out = np.zeros(t, dtype=bool)
        if t < 2:
            return out
        x = tracks.x
        if self.kernel is not None:
            return self._duplicates_kernel(tracks, resolved)
        # speed difference along the pair's common heading, and across it: a duplicate born with a wrong
        # lateral velocity (a far, noisy seed) drifts onto its vehicle with metres per second across
        ia, ib = self.pairs(t)
        xa, xb = x.take(ia, axis=0), x.take(ib, axis=0)  # take: rows without the fancy-indexing machinery
        dx = xa - xb  # (pairs, 4): position and velocity differences
        vsum = xa[:, 2:4] + xb[:, 2:4]
        nrm = np.maximum(np.hypot(vsum[:, 0], vsum[:, 1]), 1e-9)
        ux, uy = vsum[:, 0] / nrm, vsum[:, 1] / nrm
        dvx, dvy = dx[:, 2], dx[:, 3]
        keep = np.abs(dvx * ux + dvy * uy) < self.box.cfg.merge_speed_mps
        if resolved is not None:  # tracks on the two members of a resolved pair are two vehicles
            pair, det = resolved
            keep &= ~((pair[ia] >= 0) & (pair[ia] == pair[ib]) & (det[ia] != det[ib]))
        sel = keep.nonzero()[0]
        if sel.size == 0:  # no two tracks move alike: nothing is boxed, no duplicate
            tracks.close_run = np.zeros(t, np.int32)
            return out
        ia, ib, dx, ux, uy = ia[sel], ib[sel], dx.take(sel, axis=0), ux[sel], uy[sel]
        dv_across = np.abs(dx[:, 2] * uy - dx[:, 3] * ux)
        reach = self.box.along_m(tracks)
        boxed = (np.abs(dx[:, 0]) < self.box.cfg.merge_lateral_m) & (np.abs(dx[:, 1]) < np.maximum(reach[ia], reach[ib]))
        # same place, same speed along, but moving apart or together across: two vehicles crossing each
        # other's path pass through the box within a second; a duplicate stays in it
        keep = dv_across < c.merge_lateral_speed_mps
        if np.count_nonzero(boxed):
            run = np.zeros(t, bool)
            run[ia[boxed]] = run[ib[boxed]] = True
            tracks.close_run = np.where(run, tracks.close_run + 1, 0).astype(np.int32, copy=False)
            keep |= boxed & (np.minimum(tracks.close_run[ia], tracks.close_run[ib]) >= c.merge_persist_frames)
        else:  # nothing boxed: every run ends, and no pair lasted (merge_persist_frames >= 1)
            tracks.close_run = np.zeros(t, np.int32)
        sel = keep.nonzero()[0]
        if sel.size == 0:
            return out
        ia, ib, close, dx = ia[sel], ib[sel], boxed[sel], dx.take(sel, axis=0)
        pdx, pdy = self._position_spread(tracks)
        # a marginal Mahalanobis distance never exceeds the joint one: prune before the 4x4 solves
        dxx, dxy = dx[:, 0], dx[:, 1]
        marg = dxx * dxx < self._state_gamma * (pdx[ia] + pdx[ib])
        marg &= dxy * dxy < self._state_gamma * (pdy[ia] + pdy[ib])
        rest = (marg & ~close).nonzero()[0]
        if rest.size:
            close[rest] = self._state_close(tracks, ia[rest], ib[rest], dx.take(rest, axis=0))
        return self._juniors(tracks, ia[close], ib[close], out)

    @staticmethod
    def _position_spread(tracks: TrackTable) -> tuple[np.ndarray, np.ndarray]:
        """(T,) x and y variances of each track's position plus the diagonal of ``extent_cov(x, ext_var)``, column
        by column (heading() without its two-column forms)."""
        x = tracks.x
        sp = np.hypot(x[:, 2], x[:, 3])
        nrm_t = np.maximum(sp, 1e-9)
        ux_t, uy_t = x[:, 2] / nrm_t, x[:, 3] / nrm_t
        w = np.minimum(np.maximum(sp, 0.0), 1.0)
        iso = 1.0 - w
        pdx = tracks.p[:, 0, 0] + tracks.ext_var * (w * (ux_t * ux_t) + iso)
        pdy = tracks.p[:, 1, 1] + tracks.ext_var * (w * (uy_t * uy_t) + iso)
        return pdx, pdy

    def _state_close(self, tracks: TrackTable, ja: np.ndarray, jb: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Pairs ``(ja, jb)`` with state differences ``d`` whose states are statistically indistinguishable (the
        position covariances widened by the vehicles' along-heading spread)."""
        ext = extent_cov(tracks.x, tracks.ext_var)
        psum = tracks.p.take(ja, axis=0) + tracks.p.take(jb, axis=0)
        psum[:, :2, :2] += ext.take(ja, axis=0) + ext.take(jb, axis=0)
        d2 = (d[:, None, :] @ np.linalg.solve(psum, d[:, :, None]))[:, 0, 0]
        return d2 < self._state_gamma

    @staticmethod
    def _juniors(tracks: TrackTable, ia: np.ndarray, ib: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out`` with the junior track of each duplicate pair ``(ia, ib)`` set."""
        if ia.size == 0:
            return out
        rank = tracks.confirmed.astype(np.int64) * (1 << 40) + tracks.hits.astype(np.int64) * (1 << 20) + tracks.age
        b_senior = (rank[ib] > rank[ia]) | ((rank[ib] == rank[ia]) & (ib < ia))
        out[np.where(b_senior, ia, ib)] = True
        return out

    def _duplicates_kernel(self, tracks: TrackTable, resolved, spread: tuple | None = None) -> np.ndarray:
        """:meth:`duplicates` with the pair tests and the same-vehicle runs in the compiled kernel (one pass over the
        pairs, the same arithmetic); the 4x4 state test and the choice of the junior stay here. ``spread``: the
        position spreads and box half-lengths ``(pdx, pdy, along)`` if already computed (``delete_tests``)."""
        c, box = self.cfg, self.box.cfg
        t = tracks.x.shape[0]
        if spread is None:
            pdx, pdy = self._position_spread(tracks)
            along = self.box.along_m(tracks)
        else:
            pdx, pdy, along = spread
        if resolved is None:
            pair = det = _NO_ROWS
        else:
            pair = np.ascontiguousarray(resolved[0], dtype=np.int64)
            det = np.ascontiguousarray(resolved[1], dtype=np.int64)
        tracks.close_run, ka, kb, ra, rb, rdx = self.kernel.duplicate_pairs(
            tracks.x, box.merge_speed_mps, box.merge_lateral_m, along, c.merge_lateral_speed_mps, pdx, pdy,
            self._state_gamma, pair, det, resolved is not None, tracks.close_run, c.merge_persist_frames)
        out = np.zeros(t, dtype=bool)
        out = self._juniors(tracks, ka, kb, out)
        if ra.size:
            close = self._state_close(tracks, ra, rb, rdx)
            out = self._juniors(tracks, ra[close], rb[close], out)
        return out
