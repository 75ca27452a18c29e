"""Articulated pedestrians: two micro-Doppler models, chosen by ``[physics] gait``.

``"boulic"`` (default, :class:`BoulicPedestrian`): the joint trajectories of Boulic, Magnenat-Thalmann &
Thalmann 1990 (fitted to measured gait) on twelve ellipsoid segments whose RCS follows the aspect, the model
of Chen's micro-Doppler book; swing feet reach 3-4.5x the walking speed, shank centres 2-3x, the torso
oscillates about the walking speed. ``"sinusoid"`` (v1, :class:`Pedestrian`) is described below.

A walking or jogging person is modelled, after the usual kinematic simplifications of gait models
(Boulic et al.), as nine point scatterers in the body frame (``x`` right, ``y`` forward, ``z`` up)
around the reference point (the feet's mid-point on the ground):

===========  =================  ==========================================================
scatterer    share of the RCS   motion relative to the body
===========  =================  ==========================================================
torso        ~55 %              vertical bob at twice the stride frequency (2-3 cm)
head         ~5 %               follows the torso
hands (2)    ~5 % each          fore-aft swing in anti-phase with the leg of the same side
knees (2)    ~7.5 % each        fore-aft swing, half the foot excursion
feet (2)     ~7.5 % each        fore-aft swing with amplitude ``v / (2 pi f)``
===========  =================  ==========================================================

A foot swinging with amplitude ``A = v / (2 pi f)`` at the stride frequency ``f`` moves, in the world
frame, between standstill (stance) and twice the walking speed (swing), as real feet do, and one
stride covers ``v / f`` metres. Walking: ``f`` about 0.8-1.0 Hz at 1.0-1.7 m/s; jogging: 1.3-1.5 Hz at
2.2-3.5 m/s. The total RCS of an adult at 24 GHz is about -5 to 0 dBsm.

The limb velocities are the analytic derivatives of the offsets, so the synthesiser's intra-frame
motion and Doppler are consistent with the positions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hw_sim.scene import Target

#: body-frame rest positions (m) and RCS shares of the nine scatterers
_REST = np.array(
    [
        [0.0, 0.0, 1.25],  # torso
        [0.0, 0.0, 1.65],  # head
        [-0.25, 0.0, 0.95],  # left hand
        [0.25, 0.0, 0.95],  # right hand
        [-0.10, 0.0, 0.50],  # left knee
        [0.10, 0.0, 0.50],  # right knee
        [-0.10, 0.0, 0.10],  # left foot
        [0.10, 0.0, 0.10],  # right foot
    ]
)
_SHARE = np.array([0.55, 0.05, 0.05, 0.05, 0.075, 0.075, 0.075, 0.075])
_SHARE = _SHARE / _SHARE.sum()
#: fore-aft swing amplitude of each scatterer relative to the foot amplitude, signed by phase
#: (left foot +1, right foot -1, each hand in anti-phase with its own side's foot)
_SWING = np.array([0.0, 0.0, -0.45, 0.45, 0.5, -0.5, 1.0, -1.0])


@dataclass
class Pedestrian(Target):
    """A walking/jogging person; ``rcs_m2`` is split over the limbs by :data:`_SHARE`."""

    stride_hz: float = 0.9
    speed_mps: float = 1.3
    gait_phase_rad: float = 0.0
    bob_m: float = 0.025

    @classmethod
    def make(
        cls,
        target_id: int,
        trajectory,
        *,
        total_rcs_m2: float,
        speed_mps: float,
        stride_hz: float,
        gait_phase_rad: float = 0.0,
        swerling: int = 1,
        t_start_s: float = -math.inf,
        t_end_s: float = math.inf,
    ) -> "Pedestrian":
        return cls(
            id=target_id,
            cls="pedestrian",
            trajectory=trajectory,
            offsets_m=_REST.copy(),
            rcs_m2=_SHARE * total_rcs_m2,
            swerling=swerling,
            t_start_s=t_start_s,
            t_end_s=t_end_s,
            stride_hz=stride_hz,
            speed_mps=speed_mps,
            gait_phase_rad=gait_phase_rad,
        )

    @property
    def foot_amplitude_m(self) -> float:
        return self.speed_mps / (2.0 * math.pi * self.stride_hz)

    def scatterers(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        w = 2.0 * math.pi * self.stride_hz
        ph = w * t_s + self.gait_phase_rad
        a = self.foot_amplitude_m * _SWING
        off = self.offsets_m.copy()
        vel = np.zeros_like(off)
        off[:, 1] += a * math.sin(ph)
        vel[:, 1] = a * w * math.cos(ph)
        # torso and head bob twice per stride
        off[:2, 2] += self.bob_m * math.sin(2.0 * ph)
        vel[:2, 2] = self.bob_m * 2.0 * w * math.cos(2.0 * ph)
        return off, vel


# --- Boulic walking model -------------------------------------------------------------------------

#: segment lengths as fractions of the body height (Boulic et al. 1990 after Winter's anthropometry; the
#: values of Chen, The Micro-Doppler Effect in Radar, 2011, §5.2)
_LEN = {
    "head": 0.130, "shoulder": 0.259 / 2, "torso": 0.288, "hip": 0.191 / 2, "thigh": 0.245, "shank": 0.246,
    "foot": 0.143, "upper_arm": 0.188, "forearm": 0.152, "ankle_height": 0.039,
}
#: ellipsoid segments: name, semi-axis across the body (x), along the walk (y), along the segment (half length,
#: fraction of the segment length); radii in metres for a 1.75 m adult
_SEGMENTS = (
    ("torso", 0.17, 0.10), ("head", 0.09, 0.10),
    ("upper_arm_l", 0.045, 0.045), ("upper_arm_r", 0.045, 0.045), ("forearm_l", 0.035, 0.035),
    ("forearm_r", 0.035, 0.035), ("thigh_l", 0.07, 0.07), ("thigh_r", 0.07, 0.07), ("shank_l", 0.05, 0.05),
    ("shank_r", 0.05, 0.05), ("foot_l", 0.045, 0.045), ("foot_r", 0.045, 0.045),
)
#: relative velocity RV = v / Ht above which Boulic's joint amplitudes are extrapolated no further (his data
#: end at RV = 3, a fast walk; a jogger's cycle duration still follows his law)
BOULIC_RV_MAX = 3.0


def _periodic_pchip(xs: list[float], ys: list[float]):
    """A 1-periodic shape-preserving cubic through control points (phase in cycles, value in degrees)."""
    from scipy.interpolate import PchipInterpolator

    x = np.asarray(xs, dtype=float)
    y = np.asarray(ys, dtype=float)
    o = np.argsort(x)
    x, y = x[o], y[o]
    return PchipInterpolator(np.concatenate([x - 1.0, x, x + 1.0]), np.tile(y, 3))


def boulic_joint_curves(rv: float) -> dict:
    """Boulic's normalised gait trajectories at relative velocity ``rv`` (v / Ht), phase t in cycles.

    Returns callables of the phase of the right leg (t = 0: right heel strike): translations of the spine
    origin in metres (``vert``, ``lat``, ``fwd``), pelvis torsion (deg, right side forward positive), and
    flexion angles in degrees (positive forward) of hip, knee (positive = shank behind the thigh), ankle,
    shoulder, elbow and the thorax torsion. Constants from Boulic et al. 1990, appendices A-D, for the three
    gait ranges a (RV < 0.5), b (0.5-1.3), c (1.3-3).
    """
    rv = float(min(max(rv, 0.05), BOULIC_RV_MAX))
    gait = "a" if rv < 0.5 else "b" if rv < 1.3 else "c"
    u = (rv - 1.3) / 1.7  # position within range c
    dc = 1.346 / math.sqrt(rv)  # relative cycle duration
    ds = (0.752 * dc - 0.143) / dc  # relative duration of support
    av = 0.015 * rv
    al = -0.128 * rv * rv + 0.128 * rv if gait == "a" else -0.032
    aa = -0.084 * rv * rv + 0.084 * rv if gait == "a" else -0.021
    phia = 0.625 - ds
    a3 = 4.0 * rv
    if gait == "a":
        hip = ([-0.1, 0.5], [50 * rv, -30 * rv])
        knee = ([0.17, 0.4, 0.75, 1.0], [3, 3, 140 * rv, 3])
        ankle = ([0.0, 0.08, 0.5, ds, 0.85], [-3, -30 * rv - 3, 22 * rv - 3, -34 * rv - 3, -3])
        elbow = ([0.05, 0.5, 0.9], [6 * rv + 3, 34 * rv + 3, 10 * rv + 3])
    elif gait == "b":
        hip = ([-0.1, 0.5], [25.0, -15.0])
        knee = ([0.17, 0.4, 0.75, 1.0], [3, 3, 70, 3])
        ankle = ([0.0, 0.08, 0.5, ds, 0.85], [-3, -18, 8, -20, -3])
        w = (rv - 0.5) / 0.8
        elbow = ([0.05, 0.01 * w + 0.5, 0.9], [8 * w + 6, 24 * w + 20, 9 * w + 8])
    else:
        hip = ([0.2 * u - 0.1, 0.5, 0.9], [5 * u + 25, -15.0, 6 * u + 25])
        knee = ([-0.05 * u + 0.17, 0.4, -0.05 * u + 0.75, -0.03 * u + 1.0], [22 * u + 3, 3, -5 * u + 70, 3 * u + 3])
        ankle = ([0.0, 0.08, -0.1 * u + 0.5, ds, 0.85], [5 * u - 3, 4 * u - 18, -3 * u + 8, -8 * u - 20, 5 * u - 3])
        elbow = ([0.05, 0.04 * u + 0.51, -0.1 * u + 0.9], [-6 * u + 14, 26 * u + 44, -6 * u + 17])
    # a control point at x and one at x + 1 are the same point of the cycle: keep one (x in [0, 1))
    def pts(c):
        seen: dict[float, float] = {}
        for x, y in zip(*c):
            seen.setdefault(round(x % 1.0, 9), y)
        return list(seen), list(seen.values())

    ash = 9.88 * rv
    return {
        "vert": lambda t: -av + av * np.sin(2 * np.pi * (2 * t - 0.35)),
        "lat": lambda t: -al * np.sin(2 * np.pi * (t - 0.1)),  # metres to the right (towards the stance leg)
        "fwd": lambda t: aa * np.sin(2 * np.pi * (2 * t + 2 * phia)),
        "pelvis": lambda t: a3 * np.cos(2 * np.pi * t),
        "hip": _periodic_pchip(*pts(hip)),
        "knee": _periodic_pchip(*pts(knee)),
        "ankle": _periodic_pchip(*pts(ankle)),
        "thorax": _periodic_pchip([0.1, 0.4, 0.6, 0.9], [-(4 / 3) * rv, (4.5 / 3) * rv, (4 / 3) * rv, -(4.5 / 3) * rv]),
        "shoulder": lambda t: 3.0 - ash / 2 - ash * np.cos(2 * np.pi * (t + 0.5)),
        "elbow": _periodic_pchip(*pts(elbow)),
    }


def boulic_cycle_hz(speed_mps: float, height_m: float) -> float:
    """Boulic's gait cycle frequency (one stride: two steps) at ``speed_mps`` for a person ``height_m`` tall:
    the relative cycle length 1.346 sqrt(RV) leg lengths, RV = v / Ht, Ht = 0.491 height."""
    ht = (_LEN["thigh"] + _LEN["shank"]) * height_m
    rv = max(speed_mps, 0.05) / ht
    return speed_mps / (1.346 * math.sqrt(rv) * ht)


def height_for_cycle(speed_mps: float, cycle_hz: float) -> float:
    """The body height whose Boulic cycle frequency at ``speed_mps`` is ``cycle_hz`` (inverse of boulic_cycle_hz)."""
    ht = speed_mps / (1.346**2 * cycle_hz**2)
    return ht / (_LEN["thigh"] + _LEN["shank"])


def _rot_z(a: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations about z by ``a`` radians (counter-clockwise seen from above)."""
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def boulic_pose(curves: dict, height_m: float, phase: np.ndarray) -> np.ndarray:
    """Segment centres (n, 12, 3) in the body frame at right-leg phases ``phase`` (cycles), in the order of
    :data:`_SEGMENTS`: torso, head, upper arms l/r, forearms l/r, thighs l/r, shanks l/r, feet l/r.

    Sagittal-plane forward kinematics of Boulic's joint angles: the spine origin (hips' mid-point) at leg
    height plus ankle height, translated by the vertical, lateral and fore-aft oscillations; hips turned by the
    pelvis torsion, shoulders by the thorax torsion; each leg chains hip -> knee -> ankle -> foot, each arm
    shoulder -> elbow -> hand, the left limbs half a cycle after the right. Pelvis list and the back's
    forward tilt (both under 4°, a few centimetres at the head) are left out.
    """
    t = np.atleast_1d(np.asarray(phase, dtype=float)) % 1.0
    L = {k: v * height_m for k, v in _LEN.items()}
    n = t.size
    origin = np.stack([curves["lat"](t), curves["fwd"](t),
                       L["thigh"] + L["shank"] + L["ankle_height"] + curves["vert"](t)], -1)
    rp = _rot_z(np.radians(curves["pelvis"](t)))
    rt = _rot_z(np.radians(curves["thorax"](t)))
    out = np.zeros((n, 12, 3))
    up = np.array([0.0, 0.0, 1.0])
    out[:, 0] = origin + np.einsum("nij,j->ni", rt, up * L["torso"] / 2)
    out[:, 1] = origin + np.einsum("nij,j->ni", rt, up * (L["torso"] + L["head"] / 2))

    def limb(angle_deg):  # unit vector pointing down, turned forward by the angle
        a = np.radians(angle_deg)
        return np.stack([np.zeros_like(a), np.sin(a), -np.cos(a)], -1)

    for side, sx, lag in (("l", -1.0, 0.5), ("r", 1.0, 0.0)):
        ts = (t + lag) % 1.0
        # leg
        hip = origin + np.einsum("nij,j->ni", rp, np.array([sx * L["hip"], 0.0, 0.0]))
        th = curves["hip"](ts)
        sh = th - curves["knee"](ts)
        knee = hip + L["thigh"] * limb(th)
        ankle = knee + L["shank"] * limb(sh)
        fa = np.radians(sh + curves["ankle"](ts))
        toe = ankle + L["foot"] * np.stack([np.zeros_like(fa), np.cos(fa), np.sin(fa)], -1)
        k = 6 if side == "l" else 7
        out[:, k] = (hip + knee) / 2
        out[:, k + 2] = (knee + ankle) / 2
        out[:, k + 4] = (ankle + toe) / 2
        # arm: swings in anti-phase with the same side's leg
        shoulder = origin + np.einsum("nij,j->ni", rt, np.array([sx * L["shoulder"], 0.0, L["torso"]]))
        sa = curves["shoulder"](ts)
        elbow = shoulder + L["upper_arm"] * limb(sa)
        hand = elbow + L["forearm"] * limb(sa + curves["elbow"](ts))
        k = 2 if side == "l" else 3
        out[:, k] = (shoulder + elbow) / 2
        out[:, k + 2] = (elbow + hand) / 2
    return out


def _segment_axes(pose: np.ndarray, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Half lengths (12,) and unit long axes (n, 12, 3) of the segments at ``pose`` (torso and head upright)."""
    half = np.array([_LEN["torso"], _LEN["head"], _LEN["upper_arm"], _LEN["upper_arm"], _LEN["forearm"],
                     _LEN["forearm"], _LEN["thigh"], _LEN["thigh"], _LEN["shank"], _LEN["shank"], _LEN["foot"],
                     _LEN["foot"]]) * height_m / 2
    return half, np.broadcast_to(np.array([0.0, 0.0, 1.0]), pose.shape).copy()


def ellipsoid_rcs(a: np.ndarray, b: np.ndarray, c: np.ndarray, los: np.ndarray) -> np.ndarray:
    """Physical-optics RCS (m^2) of ellipsoids with semi-axes a (x), b (y), c (z) seen along unit ``los``
    (..., 3) in each ellipsoid's own frame: pi a^2 b^2 c^2 / (a^2 l_x^2 + b^2 l_y^2 + c^2 l_z^2)^2
    (Ruck et al., Radar Cross Section Handbook, 1970; Chen 2011 eq. 5.4)."""
    d = a * a * los[..., 0] ** 2 + b * b * los[..., 1] ** 2 + c * c * los[..., 2] ** 2
    return np.pi * (a * b * c) ** 2 / np.maximum(d, 1e-12) ** 2


@dataclass
class BoulicPedestrian(Target):
    """A walker after Boulic et al. 1990: twelve ellipsoid segments on the limb kinematics of
    :func:`boulic_pose`, the RCS of each from its ellipsoid seen from the radar (so limbs flash as they pass
    broadside), scaled so that the person standing, seen from the front, has ``total_rcs_m2``.

    ``radar_m`` is the radar's world position (for the aspect); ``rcs_m2`` holds the segments' RCS at the
    instant of the last :meth:`scatterers` call (the scene reads it right after). Velocities are central
    differences of the pose over 1 ms.
    """

    height_m: float = 1.75
    speed_mps: float = 1.3
    gait_phase_rad: float = 0.0
    radar_m: tuple[float, float, float] | None = None
    total_rcs_m2: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        ht = (_LEN["thigh"] + _LEN["shank"]) * self.height_m
        self.curves = boulic_joint_curves(self.speed_mps / ht)
        self.cycle_hz = boulic_cycle_hz(self.speed_mps, self.height_m)
        s = self.height_m / 1.75
        half, _ = _segment_axes(np.zeros((1, 12, 3)), self.height_m)
        self._abc = (np.array([r[1] for r in _SEGMENTS]) * s, np.array([r[2] for r in _SEGMENTS]) * s, half)
        front = ellipsoid_rcs(*self._abc, np.broadcast_to(np.array([0.0, 1.0, 0.0]), (12, 3)))
        self._scale = self.total_rcs_m2 / float(front.sum())
        self._rest_rcs = front * self._scale

    @classmethod
    def make(cls, target_id: int, trajectory, *, total_rcs_m2: float, speed_mps: float, height_m: float,
             gait_phase_rad: float = 0.0, radar_m=None, swerling: int = 1, t_start_s: float = -math.inf,
             t_end_s: float = math.inf) -> "BoulicPedestrian":
        ped = cls(id=target_id, cls="pedestrian", trajectory=trajectory, offsets_m=np.zeros((12, 3)),
                  rcs_m2=np.ones(12), swerling=swerling, t_start_s=t_start_s, t_end_s=t_end_s,
                  height_m=height_m, speed_mps=speed_mps, gait_phase_rad=gait_phase_rad,
                  radar_m=None if radar_m is None else tuple(float(v) for v in radar_m), total_rcs_m2=total_rcs_m2)
        ped.offsets_m = ped.pose(0.0)
        ped.rcs_m2 = ped._rest_rcs.copy()
        return ped

    def phase(self, t_s: np.ndarray | float) -> np.ndarray:
        """Right-leg gait phase (cycles) at ``t_s``."""
        return np.asarray(t_s, dtype=float) * self.cycle_hz + self.gait_phase_rad / (2 * math.pi)

    def pose(self, t_s: float) -> np.ndarray:
        return boulic_pose(self.curves, self.height_m, self.phase(t_s))[0]

    def scatterers(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        h = 5e-4
        three = boulic_pose(self.curves, self.height_m, self.phase(np.array([t_s - h, t_s, t_s + h])))
        off = three[1]
        vel = (three[2] - three[0]) / (2 * h)
        if self.radar_m is not None:
            rot = self.heading_rotation(t_s)
            p = np.asarray(self.trajectory.position(t_s), dtype=float) + off @ rot.T
            los = np.asarray(self.radar_m) - p
            los = (los / np.linalg.norm(los, axis=1, keepdims=True)) @ rot  # body frame
            # the limbs' long axes tilt with their flexion in the sagittal plane: turn the line of sight
            # into each segment's frame (rotation about x by the segment's angle from vertical)
            ax = self._limb_axes(t_s)
            ang = np.arctan2(ax[:, 1], -ax[:, 2])  # forward tilt of the segment's long axis from down
            c, s = np.cos(ang), np.sin(ang)
            los_seg = np.stack([los[:, 0], c * los[:, 1] + s * los[:, 2], -s * los[:, 1] + c * los[:, 2]], -1)
            self.rcs_m2 = ellipsoid_rcs(*self._abc, los_seg) * self._scale
        return off, vel

    def _limb_axes(self, t_s: float) -> np.ndarray:
        """(12, 3) unit vectors along each segment, pointing down its length (torso and head: straight down)."""
        t = float(self.phase(t_s)) % 1.0
        out = np.tile(np.array([0.0, 0.0, -1.0]), (12, 1))
        for k, lag in ((0, 0.5), (1, 0.0)):  # left, right
            ts = (t + lag) % 1.0
            sa = float(self.curves["shoulder"](ts))
            fa = sa + float(self.curves["elbow"](ts))
            th = float(self.curves["hip"](ts))
            sh = th - float(self.curves["knee"](ts))
            foot = math.radians(sh + float(self.curves["ankle"](ts)))
            for j, a in ((2 + k, sa), (4 + k, fa), (6 + k, th), (8 + k, sh)):
                out[j] = [0.0, math.sin(math.radians(a)), -math.cos(math.radians(a))]
            out[10 + k] = [0.0, math.cos(foot), math.sin(foot)]
        return out
