"""Scenes: a radar pose, moving targets made of point scatterers, static clutter, ground truth.

World frame: metres, ``x`` lateral (right +), ``y`` along the road away from the radar's foot,
``z`` up; the road surface is ``z = 0``. The radar's own frame has ``y`` along boresight, ``x`` to the
right, ``z`` up; :class:`RadarPose` maps between the two (yaw about ``z``, then a downward tilt).

A target's *reference point* is its trajectory point: the centre of the vehicle's footprint at road
level (``z = 0``), or a pedestrian's feet. Ground truth reports that point, its velocity, the range,
radial speed and azimuth seen from the radar, the class and the lane.

Targets are sets of scatterers given in the body frame (``x`` right of the heading, ``y`` forward,
``z`` up) and rotated with the heading; later issues add extended vehicles, pedestrians with swinging
limbs (time-varying offsets through :meth:`Target.scatterers`) and random traffic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from hw_sim.physics import Physics

#: a decorrelating target slower than this stands still and keeps its scattering phases (Scene.scatterers)
STANDING_MPS = 0.05

#: wavelength (m) the aspect glint model scales with: the 24 GHz ISM band of both boards (24.0-24.25 GHz)
GLINT_WAVELENGTH_M = 299_792_458.0 / 24.125e9
#: random sinusoids per Gaussian process of the aspect glint model (spectral representation, Shinozuka &
#: Deodatis, Appl. Mech. Rev. 44, 1991: a sum of M cosines with Gaussian random frequencies has the Gaussian
#: correlation function; 8 make the process close to Gaussian)
GLINT_TERMS = 8
#: rms of a centre's scattering phase over aspect (cycles): the phase of a small extended centre wraps over a
#: full cycle within a few correlation widths
GLINT_PHASE_SD_CYCLES = 0.5
#: rms of a centre's log-amplitude over aspect (neper; 0.35 Np = 3 dB rms in power, the scintillation of a
#: single vehicle part at 24-77 GHz is a few dB)
GLINT_LOGAMP_SD_NP = 0.35
#: speed (m/s) above which road-induced body vibration has its full amplitude (Physics.glint_vibration_mm)
VIBRATION_FULL_MPS = 10.0

#: class names used in ground truth and by the classifier, in a fixed order
CLASSES: tuple[str, ...] = ("pedestrian", "car", "motorcycle", "truck", "bicycle", "clutter")


@dataclass(frozen=True)
class RadarPose:
    """Where the radar is and where it looks."""

    x_m: float = 0.0
    y_m: float = 0.0
    height_m: float = 6.0
    yaw_deg: float = 0.0
    tilt_deg: float = 0.0
    #: the radar hangs on the face of an overpass: the deck hides everything behind the vertical plane of
    #: its face (under and beyond the bridge), whatever the antennas' front-to-back ratio
    occluded_behind: bool = False

    @property
    def position(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.height_m])

    def rotation(self) -> np.ndarray:
        """3x3 matrix whose rows are the radar's x, y (boresight), z axes in world coordinates."""
        yaw = math.radians(self.yaw_deg)
        tilt = math.radians(self.tilt_deg)
        # boresight: heading yaw (clockwise from +y towards +x), tilted down by tilt
        by = np.array([math.sin(yaw) * math.cos(tilt), math.cos(yaw) * math.cos(tilt), -math.sin(tilt)])
        bx = np.array([math.cos(yaw), -math.sin(yaw), 0.0])
        bz = np.cross(bx, by)
        return np.stack([bx, by, bz])

    def to_radar(self, p_world: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> radar frame (..., 3)."""
        return (p_world - self.position) @ self.rotation().T


class Trajectory(Protocol):
    def position(self, t_s: np.ndarray | float) -> np.ndarray: ...
    def velocity(self, t_s: np.ndarray | float) -> np.ndarray: ...


@dataclass(frozen=True)
class LinearTrajectory:
    """Constant velocity: ``p(t) = p0 + v (t - t0)``."""

    p0: tuple[float, float, float]
    v: tuple[float, float, float]
    t0_s: float = 0.0

    def position(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)
        return np.asarray(self.p0) + np.multiply.outer(t - self.t0_s, np.asarray(self.v))

    def velocity(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)
        return np.broadcast_to(np.asarray(self.v, dtype=np.float64), t.shape + (3,)).copy()


@dataclass
class Target:
    """A moving object made of point scatterers.

    ``offsets_m`` (K, 3) in the body frame, ``rcs_m2`` (K,). ``swerling`` 0 keeps the RCS fixed; 1
    draws a new exponential RCS factor per frame for the whole target (Swerling I); 3 uses a
    chi-square with 4 degrees of freedom (Swerling III).
    """

    id: int
    cls: str
    trajectory: Trajectory
    offsets_m: np.ndarray
    rcs_m2: np.ndarray
    swerling: int = 0
    lane: int | None = None
    t_start_s: float = -math.inf
    t_end_s: float = math.inf

    def __post_init__(self) -> None:
        self.offsets_m = np.atleast_2d(np.asarray(self.offsets_m, dtype=np.float64))
        self.rcs_m2 = np.atleast_1d(np.asarray(self.rcs_m2, dtype=np.float64))
        if self.offsets_m.shape != (self.rcs_m2.size, 3):
            raise ValueError(f"target {self.id}: offsets_m must be (K, 3) matching rcs_m2 (K,)")
        if self.swerling not in (0, 1, 3):
            raise ValueError(f"target {self.id}: swerling must be 0, 1 or 3")

    def active(self, t_s: float) -> bool:
        return self.t_start_s <= t_s <= self.t_end_s

    def lane_at(self, t_s: float) -> int | None:
        """Lane at ``t_s`` (vehicles that change lanes override this)."""
        return self.lane

    def scatterers(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Body-frame offsets and velocities relative to the reference point at ``t_s``.

        Rigid targets return their fixed offsets and zero relative velocity; articulated targets
        (pedestrian limbs, wheels) override this.
        """
        return self.offsets_m, np.zeros_like(self.offsets_m)

    def heading_rotation(self, t_s: float) -> np.ndarray:
        """3x3 body -> world rotation from the direction of travel (identity when standing)."""
        v = np.asarray(self.trajectory.velocity(t_s), dtype=np.float64)
        speed = math.hypot(v[0], v[1])
        if speed < 1e-6:
            fy = np.array([0.0, 1.0, 0.0])
        else:
            fy = np.array([v[0] / speed, v[1] / speed, 0.0])
        fx = np.array([fy[1], -fy[0], 0.0])
        return np.stack([fx, fy, [0.0, 0.0, 1.0]], axis=1)


@dataclass(frozen=True)
class ScattererSet:
    """All scatterers of a scene at one instant, flat arrays (K scatterers)."""

    position_m: np.ndarray  # (K, 3) world
    velocity_mps: np.ndarray  # (K, 3) world
    rcs_m2: np.ndarray  # (K,)
    phase_cycles: np.ndarray  # (K,) scattering phase in [0, 1)
    target_index: np.ndarray  # (K,) index into Scene.targets, -1 for clutter


@dataclass(frozen=True)
class GroundTruth:
    """Truth for one frame: one row per target in view of the scene (flat arrays)."""

    t_s: float
    id: np.ndarray  # (n,) int32
    cls: tuple[str, ...]
    lane: np.ndarray  # (n,) int16, -1 when not on a lane
    position_m: np.ndarray  # (n, 3) world, reference point
    velocity_mps: np.ndarray  # (n, 3) world
    range_m: np.ndarray  # (n,) radar to reference point
    radial_speed_mps: np.ndarray  # (n,) positive receding
    az_rad: np.ndarray  # (n,) azimuth in the radar frame, positive to the right
    #: (n,) share of each target's echo (its scatterers' RCS at this frame) that another vehicle's body shadows
    #: (``Physics.shadowing``; 0 without it); None where not known (truth not made with the frame's scatterers)
    shadowed_fraction: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.id.size)


@dataclass
class Clutter:
    """Static point scatterers (guard rail posts, poles, sign gantries, metal fences)."""

    position_m: np.ndarray
    rcs_m2: np.ndarray

    def __post_init__(self) -> None:
        self.position_m = np.asarray(self.position_m, dtype=np.float64).reshape(-1, 3)
        self.rcs_m2 = np.asarray(self.rcs_m2, dtype=np.float64).reshape(-1)


@dataclass
class Scene:
    """Radar pose, targets and clutter; deterministic for a given seed."""

    pose: RadarPose
    targets: list[Target] = field(default_factory=list)
    clutter: Clutter | None = None
    seed: int = 0
    physics: Physics = field(default_factory=Physics)

    def __post_init__(self) -> None:
        self._phase: dict[int, np.ndarray] = {}
        self._glint: dict[int, tuple[np.ndarray, ...]] = {}
        #: (t_s, {target id: shadowed share of its RCS}) of the last :meth:`scatterers` call, for :meth:`truth`
        self._shadowed: tuple[float, dict[int, float]] | None = None

    def add_target(self, target: Target) -> None:
        if any(t.id == target.id for t in self.targets):
            raise ValueError(f"duplicate target id {target.id}")
        self.targets.append(target)

    def _scatter_phase(self, tid: int, n: int) -> np.ndarray:
        """Fixed random scattering phase per scatterer (cycles), seeded by (scene seed, target id)."""
        ph = self._phase.get(tid)
        if ph is None or ph.size != n:
            ph = np.random.default_rng([self.seed, tid & 0x7FFFFFFF, 0xFA5E]).random(n)
            self._phase[tid] = ph
        return ph

    def _glint_params(self, tid: int, size_m: np.ndarray) -> tuple[np.ndarray, ...]:
        """Random draws of the aspect glint model for one target's centres, seeded by (scene seed, target id)."""
        g = self._glint.get(tid)
        if g is None or g[0].shape[0] != size_m.size:
            r = np.random.default_rng([self.seed, tid & 0x7FFFFFFF, 0x611E7])
            k, m = size_m.size, GLINT_TERMS
            # correlation width in aspect of a centre of extent d: lambda / (2 d) rad (the two-way path difference
            # across it changes by one wavelength); Gaussian random frequencies of sd 1 / width
            inv_w = (2.0 * size_m / GLINT_WAVELENGTH_M)[:, None, None]
            freq = r.normal(0.0, 1.0, (k, 2, m, 2)) * inv_w[..., None]  # (K, phase|amp, M, az|el), rad/rad
            arg0 = r.uniform(0.0, 2.0 * np.pi, (k, 2, m))
            vib_w = r.normal(0.0, 1.0, (k, m)) / self.physics.glint_vibration_s  # rad/s
            vib0 = r.uniform(0.0, 2.0 * np.pi, (k, m))
            base = r.random(k)
            g = (freq, arg0, vib_w, vib0, base)
            self._glint[tid] = g
        return g

    def _aspect_glint(self, tg: Target, t_s: float, p_ref: np.ndarray, v_ref: np.ndarray,
                      rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scattering phase (cycles) and power factor of a moving target's centres (``Physics.glint = "aspect"``).

        Each centre's extra phase and log-amplitude are smooth Gaussian random functions of the aspect angle
        (azimuth and elevation of the radar seen from the body) with correlation width lambda / (2 d)
        (:attr:`Vehicle.centre_size_m` = d, 0.5 m by default); its path length to the radar is in the geometry
        already. On top, each centre vibrates along the line of sight by a Gaussian process of rms
        ``Physics.glint_vibration_mm`` and correlation time ``glint_vibration_s``, scaled with speed up to
        :data:`VIBRATION_FULL_MPS`. Both are functions of time, so any frame can be made in any order. The
        power factor has mean 1. Basis: glint of a target of several scattering centres (Delano, Proc. IRE 41,
        1778, 1953; Skolnik (ed.), Radar Handbook 3rd ed. 2008, on RCS fluctuation).
        """
        n = tg.rcs_m2.size
        size = getattr(tg, "centre_size_m", None)
        size = np.full(n, 0.5) if size is None else np.asarray(size, dtype=np.float64)
        freq, arg0, vib_w, vib0, base = self._glint_params(tg.id, size)
        los = rot.T @ (self.pose.position - p_ref)  # radar seen from the body (body frame)
        asp = np.array([math.atan2(los[0], los[1]), math.atan2(los[2], math.hypot(los[0], los[1]))])
        scale = math.sqrt(2.0 / GLINT_TERMS)
        proc = scale * np.cos(freq @ asp + arg0).sum(axis=2)  # (K, 2) unit-variance processes
        speed = math.hypot(float(v_ref[0]), float(v_ref[1]))
        vib_mm = self.physics.glint_vibration_mm * min(1.0, speed / VIBRATION_FULL_MPS)
        vib = vib_mm * 1e-3 * scale * np.cos(vib_w * t_s + vib0).sum(axis=1)  # (K,) m along the line of sight
        phase = base + GLINT_PHASE_SD_CYCLES * proc[:, 0] + 2.0 * vib / GLINT_WAVELENGTH_M
        power = np.exp(2.0 * GLINT_LOGAMP_SD_NP * proc[:, 1] - 2.0 * GLINT_LOGAMP_SD_NP ** 2)
        return np.mod(phase, 1.0), power

    def _shadow(self, out: ScattererSet, t_s: float, frames: dict[int, tuple[np.ndarray, np.ndarray]]) -> ScattererSet:
        """Attenuate by ``Physics.shadow_loss_db`` every scatterer whose line of sight to the radar passes
        through another vehicle's body box (footprint length x width, road to ``body_height_m``); ``frames``: target
        index -> (body rotation, reference point) of the active targets."""
        radar = self.pose.position
        hit = np.zeros(out.rcs_m2.size, dtype=bool)
        for k, tg in enumerate(self.targets):
            h = getattr(tg, "body_height_m", None)
            if h is None or k not in frames:
                continue
            rot, ctr = frames[k]
            r0 = rot.T @ (radar - ctr)  # radar in the box frame
            d = (out.position_m - ctr) @ rot - r0  # (K, 3) segment radar -> scatterer, box frame
            lo = np.array([-tg.width_m / 2.0, -tg.length_m / 2.0, 0.0])
            hi = np.array([tg.width_m / 2.0, tg.length_m / 2.0, h])
            with np.errstate(divide="ignore", invalid="ignore"):
                t1 = (lo - r0) / d
                t2 = (hi - r0) / d
            t_in = np.nanmax(np.minimum(t1, t2), axis=1)
            t_out = np.nanmin(np.maximum(t1, t2), axis=1)
            hit |= (t_in < t_out) & (t_in < 1.0 - 1e-9) & (t_out > 0.0) & (out.target_index != k)
        if not hit.any():
            self._shadowed = (t_s, {})
            return out
        tot = np.bincount(out.target_index[out.target_index >= 0], weights=out.rcs_m2[out.target_index >= 0],
                          minlength=len(self.targets))
        veh_hit = hit & (out.target_index >= 0)
        hid = np.bincount(out.target_index[veh_hit], weights=out.rcs_m2[veh_hit], minlength=len(self.targets))
        self._shadowed = (t_s, {self.targets[k].id: float(hid[k] / tot[k]) for k in np.nonzero(hid)[0]})
        rcs = np.where(hit, out.rcs_m2 * 10.0 ** (-self.physics.shadow_loss_db / 10.0), out.rcs_m2)
        return ScattererSet(out.position_m, out.velocity_mps, rcs, out.phase_cycles, out.target_index)

    def scatterers(self, t_s: float, rng: np.random.Generator | None = None) -> ScattererSet:
        """Every scatterer at time ``t_s``.

        Swerling factors are drawn from ``rng`` (one draw per target per call, i.e. per frame); by
        default from a generator seeded with the scene seed and the time, so a frame is the same
        whatever frames were synthesised before it. The scattering phases and amplitudes of moving vehicles
        follow ``Physics.glint``, shadowing by vehicle bodies ``Physics.shadowing``.
        """
        if rng is None:
            rng = np.random.default_rng([self.seed, int(round(t_s * 1e6)), 0x5C])
        pos, vel, rcs, ph, idx = [], [], [], [], []
        frames: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for k, tg in enumerate(self.targets):
            if not tg.active(t_s):
                continue
            rot = tg.heading_rotation(t_s)
            off, off_v = tg.scatterers(t_s)
            p_ref = np.asarray(tg.trajectory.position(t_s), dtype=np.float64)
            frames[k] = (rot, p_ref)
            v_ref = np.asarray(tg.trajectory.velocity(t_s), dtype=np.float64)
            pos.append(p_ref + off @ rot.T)
            vel.append(v_ref + off_v @ rot.T)
            r = tg.rcs_m2
            if tg.swerling == 1:
                r = r * rng.exponential(1.0)
            elif tg.swerling == 3:
                r = r * rng.gamma(2.0, 0.5)
            rcs.append(r)
            if getattr(tg, "glint_decorrelates", False) and self.physics.glint == "aspect":
                # a vehicle standing still keeps its aspect and does not vibrate: fixed phases, a static echo
                glint_ph, glint_pow = self._aspect_glint(tg, t_s, p_ref, v_ref, rot)
                rcs[-1] = r * glint_pow
                ph.append(glint_ph)
                idx.append(np.full(r.size, k, dtype=np.int32))
                continue
            # "white" (v1): a target whose micro-motion (vibration, pitch: millimetres at lambda = 12 mm)
            # decorrelates its glint from frame to frame draws new scattering phases every frame -- while it
            # moves: a vehicle standing still (a breakdown, engine off) keeps fixed phases, a static echo the
            # clutter map can learn (the draw is made either way, so the other targets' draws stay those of the
            # moving case)
            fresh = rng.random(r.size) if getattr(tg, "glint_decorrelates", False) else None
            moving = fresh is not None and v_ref[0] * v_ref[0] + v_ref[1] * v_ref[1] >= STANDING_MPS * STANDING_MPS
            ph.append(fresh if moving else self._scatter_phase(tg.id, r.size))
            idx.append(np.full(r.size, k, dtype=np.int32))
        if self.clutter is not None and self.clutter.rcs_m2.size:
            pos.append(self.clutter.position_m)
            vel.append(np.zeros_like(self.clutter.position_m))
            rcs.append(self.clutter.rcs_m2)
            ph.append(self._scatter_phase(-1, self.clutter.rcs_m2.size))
            idx.append(np.full(self.clutter.rcs_m2.size, -1, dtype=np.int32))
        if not pos:
            z = np.zeros((0, 3))
            return ScattererSet(z, z.copy(), np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.int32))
        out = ScattererSet(
            np.concatenate(pos), np.concatenate(vel), np.concatenate(rcs), np.concatenate(ph), np.concatenate(idx)
        )
        if self.physics.shadowing:
            out = self._shadow(out, t_s, frames)
        if self.pose.occluded_behind:  # the overpass deck: nothing behind the plane of its face is seen
            yaw = math.radians(self.pose.yaw_deg)
            d = out.position_m[:, :2] - np.array([self.pose.x_m, self.pose.y_m])
            front = d[:, 0] * math.sin(yaw) + d[:, 1] * math.cos(yaw) > 0.0
            if not front.all():
                out = ScattererSet(out.position_m[front], out.velocity_mps[front], out.rcs_m2[front],
                                   out.phase_cycles[front], out.target_index[front])
        return out

    def truth(self, t_s: float) -> GroundTruth:
        act = [tg for tg in self.targets if tg.active(t_s)]
        n = len(act)
        pos = np.array([tg.trajectory.position(t_s) for tg in act], dtype=np.float64).reshape(n, 3)
        vel = np.array([tg.trajectory.velocity(t_s) for tg in act], dtype=np.float64).reshape(n, 3)
        rel = self.pose.to_radar(pos)
        rng = np.linalg.norm(pos - self.pose.position, axis=1)
        los = (pos - self.pose.position) / np.maximum(rng, 1e-9)[:, None]
        if not self.physics.shadowing:
            shadowed = np.zeros(n)
        elif self._shadowed is not None and self._shadowed[0] == t_s:  # the scatterers of this frame were made
            shadowed = np.array([self._shadowed[1].get(tg.id, 0.0) for tg in act], dtype=np.float64)
        else:
            shadowed = None
        return GroundTruth(
            t_s=t_s,
            id=np.array([tg.id for tg in act], dtype=np.int32),
            cls=tuple(tg.cls for tg in act),
            lane=np.array([-1 if (ln := tg.lane_at(t_s)) is None else ln for tg in act], dtype=np.int16),
            position_m=pos,
            velocity_mps=vel,
            range_m=rng,
            radial_speed_mps=np.einsum("ij,ij->i", los, vel),
            az_rad=np.arctan2(rel[:, 0], rel[:, 1]),
            shadowed_fraction=shadowed,
        )
