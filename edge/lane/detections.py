"""Stage 5, detections (Lim §III-A; eq. 16 for a raised radar): ground-plane x/y of every detection, then the
road-geometry filters, each a small object switched by its ``pipeline.lane`` key:

* :class:`UnaliasByLane` (before the projection): a grating-lobe alias moved back into a lane of its direction;
* :class:`NearFaces`: a vehicle's body (detections behind its near face at its speed) dropped; the body's length
  measured.

A filter is called as ``filter(candidates, feedback) -> candidates`` (:class:`edge.lane.records.Candidates`)."""

from __future__ import annotations

import math

import numpy as np

from edge import native
from edge.dsp.geometry import polar_to_ground
from edge.dsp.pairing import nearest_of_clusters
from edge.lane.records import Angles, Candidates, Feedback
from edge.lane.road import RoadFrame
from edge.traffic.lanes import assign_lanes
from edge.types import Detections, FrontendInfo


def _lane_table(lanes) -> tuple:
    """The kernels' lane arrays (edge/native/_unalias.pyx): centres (m), half widths (m), directions (+-1), float64
    (the values edge.traffic.lanes.assign_lanes compares with)."""
    return (np.array([ln.center_m for ln in lanes], np.float64), 0.5 * np.array([ln.width_m for ln in lanes], np.float64),
            np.array([ln.direction for ln in lanes], np.float64))


class UnaliasByLane(native.KernelUser):
    """Grating lobes: with d = 1.5 lambda the array measures sin(az) only modulo lambda/d (+-19.5 deg). A vehicle
    close to the radar in an outer lane lies beyond that and shows up mirrored across the road. A moving detection
    (``unalias_min_speed_mps``) that lands in a lane of the other direction of travel is moved to its alias
    (sin(az) +- lambda/d) if that lies in a lane of its own direction (``unalias_by_lane``; only with lanes)."""

    def __init__(self, frontend: FrontendInfo, config, road: RoadFrame) -> None:
        self.config = config
        self.road = road
        self.period = frontend.waveform.wavelength_m / frontend.rx_spacing_m  # grating-lobe period in sin(az)
        self._offsets = np.array([0.0, self.period, -self.period])[:, None]  # (3, 1)
        dz = config.mounting_height_m - config.target_height_m
        self._dz2 = dz * dz  # (m^2, float64)
        #: the compiled pass (edge/native/_unalias.pyx), None: :meth:`reference` runs
        self.kernel = native.load("_unalias")
        #: (lanes, the kernel's arguments of them: (centre, half width, direction) float64 arrays, the float32 speed
        #: and range limits; the config they were made with)
        self._k_lanes: tuple = (None, None, None)

    def __call__(self, c: Candidates, feedback: Feedback) -> Candidates:
        if not (feedback.lanes and c.range_m.size):
            return c
        az = self.unalias(c.range_m, c.radial_speed_mps, c.az_rad, feedback)
        return c if az is c.az_rad else Candidates(c.range_m, c.radial_speed_mps, az, c.x_m, c.y_m, c.keep,
                                                   c.body_extent_m)

    def unalias(self, range_m: np.ndarray, v_mps: np.ndarray, az: np.ndarray, feedback: Feedback) -> np.ndarray:
        """``az`` with the aliases moved (``az`` itself when none is): the compiled kernel when built, else
        :meth:`reference` (the same angles)."""
        k = self.kernel
        f32 = np.float32
        if k is None or not (range_m.dtype == f32 and v_mps.dtype == f32 and az.dtype == f32):
            return self.reference(range_m, v_mps, az, feedback)
        cfg = self.config
        lanes = feedback.lanes
        kl = self._k_lanes
        if kl[0] is not lanes or kl[2] is not cfg:  # the lanes change rarely (see RoadFrame)
            span, _ = self.road.lane_arrays(lanes)
            kl = self._k_lanes = (lanes, _lane_table(lanes) + (
                np.float32(cfg.unalias_min_speed_mps), np.float32(span / self.period + cfg.mounting_height_m)), cfg)
        out = k.unalias(np.ascontiguousarray(range_m), np.ascontiguousarray(v_mps), np.ascontiguousarray(az),
                        *kl[1], self.period, self._dz2, math.cos(feedback.yaw_rad), math.sin(feedback.yaw_rad))
        return az if out is None else out

    def reference(self, range_m: np.ndarray, v_mps: np.ndarray, az: np.ndarray, feedback: Feedback) -> np.ndarray:
        """The numpy form of :meth:`unalias` (the kernel's reference and fallback)."""
        cfg = self.config
        lanes = feedback.lanes
        period = self.period
        # an alias is sin(az) +- period away, i.e. about period x range across: only near detections can have
        # both themselves and their alias on the road (the rest is left alone at the cost of one comparison)
        span, dirs = self.road.lane_arrays(lanes)
        near = np.abs(v_mps) >= np.float32(cfg.unalias_min_speed_mps)
        near &= range_m <= np.float32(span / period + cfg.mounting_height_m)
        idx = near.nonzero()[0]
        if idx.size == 0:
            return az
        # itself and the two neighbouring grating lobes, (3, n)
        cand = np.sin(az[idx].astype(np.float64)) + self._offsets
        # the lane direction of all three in one pass (the cost is per call, not per element): the ground position
        # (eq. 16, in float64 from sin az: x = r sin az, y^2 = r^2 cos^2 az - dz^2) and the road frame's lateral
        # offset as to_road computes it
        s = np.minimum(np.maximum(cand, -1.0), 1.0)
        r = range_m[idx].astype(np.float64)
        x = r * s
        y = np.sqrt(np.maximum((r * r) * (1.0 - s * s) - self._dz2, 0.0))
        u = self.road.across_road(x, y, feedback.yaw_rad)
        d = dirs[assign_lanes(u.reshape(-1), lanes)].reshape(3, -1)  # direction, 0 outside every lane (-1 -> 0)
        sign = np.sign(v_mps[idx])  # +1 receding: lanes "away"
        bad = d[0] == -sign
        if not np.count_nonzero(bad):
            return az
        az = az.copy()
        for j in (1, 2):
            alt = cand[j]
            ok = bad & (np.abs(alt) <= 1.0)
            ok &= d[j] == sign
            az[idx[ok]] = np.arcsin(alt[ok]).astype(np.float32)
            bad &= ~ok
        return az


class NearFaces(native.KernelUser):
    """A vehicle is reported by its nearest face (edge.dsp.pairing.nearest_of_clusters): detections up to
    ``cluster_length_m`` behind a nearer one within ``cluster_speed_mps`` and ``cluster_lateral_m`` are its body,
    and are dropped. The body's along-road length is kept per detection (``body_extent_m``)."""

    def __init__(self, config) -> None:
        self.config = config
        self._dz2 = np.float32((config.mounting_height_m - config.target_height_m) ** 2)
        #: the compiled pass (edge/native/_faces.pyx), None: the numpy reference (:meth:`reference`) runs
        self.kernel = native.load("_faces")
        self._k_args = (np.float32(config.cluster_length_m), np.float32(config.cluster_speed_mps),
                        np.float32(config.cluster_lateral_m), self._dz2)

    def __call__(self, c: Candidates, feedback: Feedback) -> Candidates:
        rng = c.range_m
        if rng.size <= 1:  # one detection or none: no body behind it
            return Candidates(rng, c.radial_speed_mps, c.az_rad, c.x_m, c.y_m, c.keep, np.zeros(rng.size, np.float32))
        if (self.kernel is None or rng.dtype != np.float32 or c.radial_speed_mps.dtype != np.float32
                or c.x_m.dtype != np.float32):
            return self.reference(c, feedback)
        keep, ext = self.kernel.near_faces(np.ascontiguousarray(rng), np.ascontiguousarray(c.radial_speed_mps),
                                           np.ascontiguousarray(c.x_m), np.ascontiguousarray(c.keep).view(np.uint8),
                                           *self._k_args)
        return Candidates(rng, c.radial_speed_mps, c.az_rad, c.x_m, c.y_m, keep.view(bool), ext)

    def reference(self, c: Candidates, feedback: Feedback) -> Candidates:
        """The numpy form of :meth:`__call__` (the kernel's reference and fallback)."""
        cfg = self.config
        rng = c.range_m
        if rng.size <= 1:  # one detection or none: no body behind it
            return Candidates(rng, c.radial_speed_mps, c.az_rad, c.x_m, c.y_m, c.keep, np.zeros(rng.size, np.float32))
        keep, ext = nearest_of_clusters(rng, c.radial_speed_mps, c.x_m, length_m=cfg.cluster_length_m,
                                        speed_mps=cfg.cluster_speed_mps, lateral_m=cfg.cluster_lateral_m,
                                        with_extent=True)
        keep &= c.keep
        return Candidates(rng, c.radial_speed_mps, c.az_rad, c.x_m, c.y_m, keep,
                          self.body_extent(rng, c.x_m, ext, keep))

    def body_extent(self, rng: np.ndarray, x: np.ndarray, ext: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """Per detection the along-road length of the body behind it (``ext``: its slant range extent, from
        ``nearest_of_clusters``), as ground distance along the road at its lateral offset; NaN for dropped ones."""
        ext = np.where(keep, ext, np.float32(np.nan))
        dz2 = self._dz2
        x2 = x * x
        near = np.sqrt(np.maximum(rng * rng - dz2 - x2, np.float32(0)))
        far_r = rng + ext
        far = np.sqrt(np.maximum(far_r * far_r - dz2 - x2, np.float32(0)))
        return far - near


class DetectionStage(native.KernelUser):
    """Ground-plane geometry and the road-geometry filters, as configured."""

    def __init__(self, frontend: FrontendInfo, config, road: RoadFrame) -> None:
        cfg = self.config = config
        #: filters of the direction, before the projection
        self.direction_filters: tuple = (UnaliasByLane(frontend, cfg, road),) if cfg.unalias_by_lane else ()
        #: filters of the projected detections, in order
        self.filters: tuple = ()
        if cfg.cluster_length_m > 0:
            self.filters += (NearFaces(cfg),)
        #: the compiled stage after the direction filters (edge/native/_detect.pyx), None: :meth:`reference`
        self.kernel = native.load("_detect")
        self._k_dz = np.float32(cfg.mounting_height_m - cfg.target_height_m)  # (polar_to_ground's)

    def __call__(self, a: Angles, feedback: Feedback) -> Detections:
        """The detections of ``a``: the direction filters, the ground projection and the filters of the projected
        detections. The compiled kernel after the direction filters when built and the columns are float32 (int32
        pairs), else :meth:`reference` (the same detections bit for bit)."""
        k = self.kernel
        nd, f32 = np.ndarray, np.float32
        rng, vel, az, snr, res = a.range_m, a.radial_speed_mps, a.az_rad, a.snr_db, a.residual_hz
        if (k is None or not (type(rng) is nd and rng.dtype == f32 and type(vel) is nd and vel.dtype == f32
                              and type(az) is nd and az.dtype == f32 and type(snr) is nd and snr.dtype == f32
                              and type(res) is nd and res.dtype == f32)
                or type(a.resolved_pair) is not np.ndarray or a.resolved_pair.dtype != np.int32
                or not (a.unresolved_pair is None or (type(a.unresolved_pair) is np.ndarray
                                                      and a.unresolved_pair.dtype == bool))):
            return self.reference(a, feedback)
        faces = None
        for f in self.filters:
            if type(f) is NearFaces and faces is None and f.kernel is not None:
                faces = f
            else:
                return self.reference(a, feedback)
        c = Candidates(a.range_m, a.radial_speed_mps, a.az_rad, None, None, None)
        for f in self.direction_filters:
            c = f(c, feedback)
        az = c.az_rad
        if type(az) is not np.ndarray or az.dtype != np.float32:
            return self._filtered(a, c, feedback)
        f_args = faces._k_args if faces is not None else (0.0, 0.0, 0.0, 0.0)  # (NearFaces' float32 arguments)
        rng, vel, az, snr, x, y, res, pair, body, unresolved = k.finish(
            c.range_m, c.radial_speed_mps, az, np.sin(az), np.cos(az), a.snr_db, a.residual_hz, a.resolved_pair,
            a.unresolved_pair, self._k_dz, faces is not None, *f_args)
        extra = {"pair_residual_hz": res, "resolved_pair": pair}
        if body is not None:
            extra["body_extent_m"] = body
        if unresolved is not None:
            extra["unresolved_pair"] = unresolved
        return Detections(rng, vel, az, snr, x, y, extra)

    def reference(self, a: Angles, feedback: Feedback) -> Detections:
        """The numpy form of :meth:`__call__` (each filter's own kernel when built): the kernel's reference and
        fallback."""
        c = Candidates(a.range_m, a.radial_speed_mps, a.az_rad, None, None, None)
        for f in self.direction_filters:
            c = f(c, feedback)
        return self._filtered(a, c, feedback)

    def _filtered(self, a: Angles, c: Candidates, feedback: Feedback) -> Detections:
        """:meth:`reference` after the direction filters."""
        cfg = self.config
        rng, vel, az = c.range_m, c.radial_speed_mps, c.az_rad
        x, y = polar_to_ground(rng, az, cfg.mounting_height_m, cfg.target_height_m)
        c = Candidates(rng, vel, az, x, y, np.ones(rng.size, bool))
        for f in self.filters:
            c = f(c, feedback)
        extra = {"pair_residual_hz": a.residual_hz, "resolved_pair": a.resolved_pair}
        if c.body_extent_m is not None:
            extra["body_extent_m"] = c.body_extent_m
        if a.unresolved_pair is not None:
            extra["unresolved_pair"] = a.unresolved_pair
        if c.keep.all():  # the arrays themselves (nothing reads or writes them after this)
            return Detections(rng, vel, az, a.snr_db, x, y, extra)
        sel = c.keep.nonzero()[0]
        return Detections(rng[sel], vel[sel], az[sel], a.snr_db[sel], x[sel], y[sel],
                          {k: v[sel] for k, v in extra.items()})
