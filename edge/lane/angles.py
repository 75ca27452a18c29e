"""Stage 4, angles (Lim §III-A): Bartlett beamforming over the four channels (calibration divided out), the four
segments as looks, each normalised; a segment that disagrees with the others, or whose peak another pairing of
another speed uses, is left out (edge.dsp.angle). Then the side-by-side resolver (:mod:`edge.lane.resolve`): a
pairing whose range-speed cell holds two vehicles becomes two detections, one per fitted angle, unless the split
is a vehicle's body or does not straddle two lanes of the cell's direction."""

from __future__ import annotations

import math

import numpy as np

from edge import native
from edge.dsp.angle import bartlett_consensus, beamform, steering_matrix
from edge.dsp.geometry import polar_to_ground
from edge.lane.records import Angles, Feedback, PairList, Spectra
from edge.lane.resolve import CellResolver, ResolverConfig
from edge.lane.road import RoadFrame
from edge.npc import count_nonzero
from edge.types import FrontendInfo


class AngleStage(native.KernelUser):
    """Bartlett consensus over the segments of every pairing."""

    def __init__(self, frontend: FrontendInfo, config, want_looks: bool) -> None:
        cfg = self.config = config
        wf = frontend.waveform
        self.n_rx = frontend.n_rx
        self._outlier_rad = np.float32(math.radians(cfg.angle_outlier_deg))
        half = math.radians(cfg.angle_max_deg)
        self.grid = np.arange(-half, half + 1e-12, math.radians(cfg.angle_step_deg)).astype(np.float32)
        self.steer = steering_matrix(frontend.n_rx, frontend.rx_spacing_m, wf.wavelength_m, self.grid)
        cal = np.asarray(cfg.calibration_gain) * np.exp(1j * np.radians(cfg.calibration_phase_deg))
        self._inv_cal = (1.0 / cal).astype(np.complex64)
        self._seg_bin0 = np.arange(len(wf.segments)) * wf.n_samples  # first bin of each segment, (rx, seg*bin) view
        self._want_looks = want_looks  # the resolver's input
        #: the compiled consensus (edge/native/_angles.pyx), None: the numpy reference (bartlett_consensus) runs
        self.kernel = native.load("_angles")
        #: the compiled output (SNR, kept pairings, looks: edge/native/_anglesout.pyx), None: numpy (below)
        self._k_out = native.load("_anglesout")

    def consensus(self, snaps: np.ndarray, outlier, pk: np.ndarray, p_vel: np.ndarray,
                  p_rng: np.ndarray | None = None) -> tuple:
        """Bartlett consensus of ``snaps`` (n, seg, rx): the compiled kernel after numpy's beamforming product
        when built, else :meth:`reference`. ``outlier``: the outlier window (rad, a scalar or (n,)); with ``p_rng``
        (the pairings' ranges) a scalar window is widened near the radar (:meth:`outlier_window`, in the kernel
        for float32 ranges). Returns ``(az, spectrum, kept, used)`` as bartlett_consensus."""
        cfg = self.config
        if p_rng is not None and not (self.kernel is not None and cfg.angle_outlier_lateral_m > 0
                                      and np.ndim(outlier) == 0 and p_rng.dtype == np.float32):
            outlier, p_rng = self.outlier_window(outlier, p_rng), None
        if self.kernel is None:
            return self.reference(snaps, outlier, pk, p_vel)
        n = snaps.shape[0]
        y = beamform(snaps, self.steer)
        q = y.view(y.real.dtype)
        bins = pk if cfg.angle_skip_shared_looks else None
        if p_rng is None:  # (the kernel takes the window's array as np.ascontiguousarray(outlier, np.float32))
            outl = outlier if np.ndim(outlier) else np.full(n, outlier, np.float32)
            az, spec, kept, used = self.kernel.consensus(q, self.grid, outl, bins, cfg.angle_shared_bins,
                                                         cfg.angle_min_agreeing, 2, p_vel,
                                                         np.float32(cfg.angle_shared_speed_mps))
        else:
            az, spec, kept, used = self.kernel.consensus(q, self.grid, np.float32(outlier), bins,
                                                         cfg.angle_shared_bins, cfg.angle_min_agreeing, 2, p_vel,
                                                         np.float32(cfg.angle_shared_speed_mps), p_rng,
                                                         np.float32(cfg.angle_outlier_lateral_m))
        return az, spec, kept.view(bool), used.view(bool)

    def outlier_window(self, outlier, p_rng: np.ndarray):
        """The outlier window per pairing: ``outlier`` (rad), wider near the radar, where a vehicle spans degrees:
        at least ``angle_outlier_lateral_m`` across at the pairing's range ``p_rng`` (float32, as numpy rounds)."""
        cfg = self.config
        if cfg.angle_outlier_lateral_m > 0:
            return np.maximum(outlier, np.float32(cfg.angle_outlier_lateral_m) / np.maximum(p_rng, np.float32(1.0)))
        return outlier

    def reference(self, snaps: np.ndarray, outlier, pk: np.ndarray, p_vel: np.ndarray) -> tuple:
        """The numpy consensus (edge.dsp.angle.bartlett_consensus: the kernel's reference and fallback)."""
        cfg = self.config
        return bartlett_consensus(snaps, self.steer, self.grid, outlier, pk if cfg.angle_skip_shared_looks else None,
                                  cfg.angle_shared_bins, cfg.angle_min_agreeing, speeds=p_vel,
                                  min_speed_diff=cfg.angle_shared_speed_mps)

    def __call__(self, spectra: Spectra, noise: np.ndarray, floor: np.ndarray, pairs: PairList) -> Angles:
        """Angles of ``pairs`` from the spectra; the SNR against the CFAR ``noise`` (seg, bin) or the segment's
        ``floor`` where a track-aided pairing reads a bin that is no local maximum."""
        cfg = self.config
        spec, power = spectra.spec, spectra.power
        pk, p_rng, p_vel = pairs.bins, pairs.range_m, pairs.radial_speed_mps
        n_det = p_rng.size
        if n_det:
            snaps = spec.reshape(spec.shape[0], -1).take(pk + self._seg_bin0, axis=1)  # (rx, n, seg)
            snaps = snaps.transpose(1, 2, 0) * self._inv_cal  # (n, seg, rx)
            az, aspec, kept, used = self.consensus(snaps, self._outlier_rad, pk, p_vel, p_rng)
            f32 = np.float32
            if (self._k_out is not None and pk.dtype == np.int64 and p_rng.dtype == f32 and p_vel.dtype == f32
                    and pairs.residual_hz.dtype == f32 and az.dtype == f32 and noise.dtype == f32
                    and floor.dtype == f32):
                # (the kernel reads the arrays as np.ascontiguousarray gives them)
                rng_k, vel_k, res_k, az_k, snr_k, looks_k, pair_k = self._k_out.finish(
                    spectra.power_padded, spectra.pad, noise, floor[0], pk, p_rng, p_vel, pairs.residual_hz, az, kept,
                    used, snaps, cfg.angle_min_agreeing, self._want_looks)
                return Angles(rng_k, vel_k, res_k, az_k, snr_k, pair_k, None, aspec, looks_k)
            p0 = power[0, pk[:, 0]]
            n0 = noise[0, pk[:, 0]]
            n0 = np.where(np.isfinite(n0), n0, floor[0])  # a track-aided pair may read a non-peak bin
            # the logarithm in float64, rounded to float32 once: the same value as the kernel's libm log10 on any
            # machine (numpy's float32 log10 is its own SIMD code on AVX-512 and differs in the last bits)
            snr_db = (10.0 * np.log10((p0 / np.maximum(n0, np.float32(1e-30))).astype(np.float64))).astype(np.float32)
        else:
            az = snr_db = np.zeros(0, np.float32)
            aspec = np.zeros((0, self.grid.size), np.float32)
            kept = used = np.zeros((0, 4), bool)
        keep = ((np.add.reduce(kept, axis=1) >= cfg.angle_min_agreeing).nonzero()[0] if n_det
                else np.zeros(0, np.int64))
        looks = None
        if self._want_looks:
            # only the looks that agreed on the angle and hold no other pairing's peak (another vehicle may
            # share one segment's bin)
            looks = snaps[keep] * used[keep][:, :, None] if n_det else np.zeros((0, 4, self.n_rx), np.complex64)
        return Angles(p_rng[keep], p_vel[keep], pairs.residual_hz[keep], az[keep], snr_db[keep],
                      np.full(keep.size, -1, np.int32), None, aspec, looks)


class SplitStraddlesLanes:
    """Keeps a split whose two directions lie in adjacent lanes with their midpoint within
    ``resolve_boundary_fraction`` of the lane spacing from the boundary between them (two vehicles side by side;
    a truck's two sides straddle the centre of one lane). Only with lanes."""

    def __init__(self, config, road: RoadFrame) -> None:
        self.config = config
        self.road = road

    def __call__(self, split: np.ndarray, range_m: np.ndarray, v_mps: np.ndarray, az: np.ndarray, ang: np.ndarray,
                 feedback: Feedback) -> np.ndarray:
        if not feedback.lanes:
            return split
        return split & self.straddles(range_m, ang, feedback)

    def straddles(self, range_m: np.ndarray, ang: np.ndarray, feedback: Feedback) -> np.ndarray:
        """(n,) bool: the two directions ``ang`` (n, 2) of each cell lie in adjacent lanes about their boundary."""
        cfg = self.config
        lanes = feedback.lanes
        centres = self.road.lane_centres(lanes)
        # both directions at once: the ground position and the road frame's lateral offset (to_road's operations)
        x, y = polar_to_ground(range_m[:, None], np.nan_to_num(ang), cfg.mounting_height_m, cfg.target_height_m)
        u = self.road.across_road(x, y, feedback.yaw_rad)  # (n, 2)
        lane = np.argmin(np.abs(u[:, :, None] - centres[None, None, :]), axis=2)  # (n, 2) nearest lane
        lo, hi = np.minimum(lane[:, 0], lane[:, 1]), np.maximum(lane[:, 0], lane[:, 1])
        ok = (hi - lo) == 1
        boundary = 0.5 * (centres[lo] + centres[hi])
        spacing = np.abs(centres[hi] - centres[lo])
        mid = (u[:, 0] + u[:, 1]) / 2  # u.mean(axis=1): the sum of the two, halved
        ok &= np.abs(mid - boundary) <= cfg.resolve_boundary_fraction * spacing
        return ok


class ResolveStage:
    """The side-by-side resolver (:class:`edge.lane.resolve.CellResolver`, memory across frames) and the road-geometry
    checks of its splits; a split detection becomes two, one per angle, half the power each."""

    def __init__(self, frontend: FrontendInfo, config, steer: np.ndarray, grid: np.ndarray, road: RoadFrame) -> None:
        cfg = self.config = config
        wf = frontend.waveform
        self.resolver = CellResolver(
            ResolverConfig(memory_frames=cfg.resolve_memory_frames, min_frames=cfg.resolve_min_frames,
                           min_split_frames=cfg.resolve_min_split_frames,
                           min_eig_ratio=cfg.resolve_min_eig_ratio, min_noise_ratio=cfg.resolve_min_noise_ratio,
                           pair_hint_eig_ratio=cfg.resolve_pair_hint_eig_ratio,
                           min_lateral_m=cfg.resolve_min_lateral_m, min_power_ratio=cfg.resolve_min_power_ratio,
                           follow_direction=cfg.resolve_follow_direction),
            steer, grid, wf.frame_period_s, frontend.rx_spacing_m / wf.wavelength_m, kernel=native.load("_resolve"))
        # checks of a split, in order (each narrows the split mask)
        self.split_filters: tuple = (SplitStraddlesLanes(cfg, road),)

    def __call__(self, a: Angles, feedback: Feedback) -> Angles:
        rng, vel, res, az, snr_db, pair_of = (a.range_m, a.radial_speed_mps, a.residual_hz, a.az_rad, a.snr_db,
                                              a.resolved_pair)
        split, ang = self.resolver.step(rng, vel, a.looks, az)
        unresolved = self.resolver.two_sources
        for f in self.split_filters:
            if not count_nonzero(split):  # (rare: asked once when nothing is split)
                break
            split = f(split, rng, vel, az, ang, feedback)
        if count_nonzero(split):  # each split detection becomes two, one per angle, half the power each
            s_idx = split.nonzero()[0]
            az, snr_db, pair_of = az.copy(), snr_db.copy(), pair_of.copy()  # (the input record stays as it was)
            az[s_idx] = ang[s_idx, 0]
            pair_of[s_idx] = s_idx
            rng, vel, res = (np.concatenate([x, x[s_idx]]) for x in (rng, vel, res))
            az = np.concatenate([az, ang[s_idx, 1]])
            snr_db[s_idx] -= np.float32(3.0)
            snr_db = np.concatenate([snr_db, snr_db[s_idx]])
            pair_of = np.concatenate([pair_of, s_idx.astype(np.int32)])
            unresolved = np.concatenate([unresolved & ~split, np.zeros(s_idx.size, bool)])
        return Angles(rng, vel, res, az, snr_db, pair_of, unresolved, a.spectrum, None)
