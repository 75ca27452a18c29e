"""Road vehicles as extended targets: body types, scatterer layouts, road trajectories.

A vehicle is a :class:`hw_sim.scene.Target` whose scatterers spread over its footprint:

* the face turned towards the radar (the front of an approaching vehicle, the rear of a receding one)
  carries most of the echo: three scatterers across the width at bumper height;
* both sides carry weaker scatterers along the length (wheel houses, mirrors, pillars);
* the far face is largely shadowed: one weak scatterer.

Shares of the class RCS: near face 70 %, sides 25 %, far face 5 %. Class-typical total RCS at 24 GHz
(front/rear aspect, literature values rounded): motorcycle 2 m^2, car 10 m^2 (Lim's design target),
van 20 m^2, truck/bus 50 m^2.

Fluctuation: a vehicle's scatterers get new random scattering phases every frame (millimetres of
vibration and pitch decorrelate the glint between 33 ms frames at lambda = 12 mm), so the three
near-face scatterers add up differently each frame: the echo fluctuates like a Swerling III/I target
and produces the occasional missed detection of a real sensor (the face is below a fifth of its mean
power in about 10 % of frames). Keeping the phases fixed instead would freeze a vehicle in a deep
glint null for seconds. ``swerling = 1`` adds a whole-body exponential factor on top (default 0).

Reference point (ground truth, DESIGN §3): the centre of the footprint at road level. Because a radar
measures the face it sees, :attr:`Vehicle.near_face_offset_m` gives the body-frame ``y`` of the
near-face centre; the lane evaluation scores positions against that point (``ref + heading *
near_face_offset_m``).

:class:`RoadTrajectory` drives a vehicle along the road (world ``y``) with a piecewise-linear speed
profile (stop-and-go: decelerate to standstill, wait, accelerate) and optional lane changes (a
half-cosine lateral move), analytic in position and velocity and vectorised over time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hw_sim.scene import Target


@dataclass(frozen=True)
class BodyType:
    """Geometry and radar signature of a vehicle body type."""

    cls: str  # ground-truth class (hw_sim.scene.CLASSES)
    length_m: tuple[float, float]  # uniform range
    width_m: float
    rcs_m2: float  # mean total RCS
    n_side: int  # scatterers per side along the length
    height_m: float  # height of the scatterers above the road


BODY_TYPES: dict[str, BodyType] = {
    "car": BodyType("car", (4.0, 4.9), 1.8, 10.0, 2, 0.5),
    "van": BodyType("car", (5.0, 6.0), 2.0, 20.0, 2, 0.7),
    "truck": BodyType("truck", (10.0, 16.5), 2.5, 50.0, 4, 1.0),
    "bus": BodyType("truck", (11.0, 13.5), 2.55, 50.0, 4, 1.0),
    "motorcycle": BodyType("motorcycle", (2.0, 2.3), 0.8, 2.0, 1, 0.6),
}

NEAR_SHARE, SIDE_SHARE, FAR_SHARE = 0.70, 0.25, 0.05


def body_scatterers(body: BodyType, length_m: float, approaching: bool) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame offsets ``(K, 3)`` and RCS ``(K,)`` of a vehicle (see module docstring)."""
    half_l, half_w, h = length_m / 2.0, body.width_m / 2.0, body.height_m
    near_y = half_l if approaching else -half_l
    near_x = np.array([-0.35, 0.0, 0.35]) * body.width_m * (0.0 if body.width_m < 1.0 else 1.0)
    near = np.stack([near_x, np.full(3, near_y), np.full(3, h)], axis=1)
    ys = np.linspace(-half_l, half_l, body.n_side + 2)[1:-1]
    sides = np.concatenate([np.stack([np.full(ys.size, s * half_w), ys, np.full(ys.size, h)], axis=1) for s in (-1, 1)])
    far = np.array([[0.0, -near_y, h]])
    off = np.concatenate([near, sides, far])
    rcs = np.concatenate([
        np.full(3, body.rcs_m2 * NEAR_SHARE / 3),
        np.full(sides.shape[0], body.rcs_m2 * SIDE_SHARE / sides.shape[0]),
        [body.rcs_m2 * FAR_SHARE],
    ])
    return off, rcs


@dataclass(frozen=True)
class RoadTrajectory:
    """Vehicle motion along the road.

    ``y(t) = y0 + direction * s(t)`` with ``s`` the integral of the speed profile (knots ``speed_t_s``,
    ``speed_mps``, linear between, constant outside); ``x(t) = x0 + sum dx_i * (1 - cos(pi u_i)) / 2``,
    ``u_i = clip((t - t_i) / T_i, 0, 1)`` for each lane change ``(t_i, T_i, dx_i)``, plus ``A sin(2 pi t / P + phi)``
    for a weave ``(A, P, phi)``: a driver's slow wander inside the lane (its standard deviation of lateral position,
    SDLP, is ``A / sqrt 2``).
    """

    x0_m: float
    y0_m: float
    direction: int  # +1 away from the radar (+y), -1 towards it
    speed_t_s: tuple[float, ...]
    speed_mps: tuple[float, ...]
    lane_changes: tuple[tuple[float, float, float], ...] = ()  # (t_start_s, duration_s, dx_m)
    weave: tuple[float, float, float] | None = None  # (amplitude_m, period_s, phase_rad)

    def __post_init__(self) -> None:
        if len(self.speed_t_s) != len(self.speed_mps) or not self.speed_t_s:
            raise ValueError("RoadTrajectory needs matching, non-empty speed knots")
        if any(b < a for a, b in zip(self.speed_t_s, self.speed_t_s[1:])):
            raise ValueError("RoadTrajectory speed knots must be sorted in time")

    def _s(self, t: np.ndarray) -> np.ndarray:
        tk = np.asarray(self.speed_t_s, dtype=np.float64)
        vk = np.asarray(self.speed_mps, dtype=np.float64)
        # distance at the knots (trapezoids), relative to the first knot
        sk = np.concatenate([[0.0], np.cumsum(0.5 * (vk[1:] + vk[:-1]) * np.diff(tk))])
        j = np.clip(np.searchsorted(tk, t, side="right") - 1, 0, tk.size - 1)
        dt = t - tk[j]
        v_t = np.interp(t, tk, vk)
        # inside a segment: trapezoid between the knot speed and the speed at t; before/after: constant
        before = t < tk[0]
        s = sk[j] + 0.5 * (vk[j] + v_t) * dt
        return np.where(before, (t - tk[0]) * vk[0], s)

    def _x(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.full(t.shape, self.x0_m)
        vx = np.zeros(t.shape)
        for t0, dur, dx in self.lane_changes:
            u = np.clip((t - t0) / dur, 0.0, 1.0)
            x = x + dx * (1.0 - np.cos(math.pi * u)) / 2.0
            inside = (t > t0) & (t < t0 + dur)
            vx = vx + np.where(inside, dx * math.pi / (2.0 * dur) * np.sin(math.pi * u), 0.0)
        if self.weave is not None:
            amp, period, phase = self.weave
            w = 2.0 * math.pi / period
            x = x + amp * np.sin(w * t + phase)
            vx = vx + amp * w * np.cos(w * t + phase)
        return x, vx

    def position(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)
        x, _ = self._x(t)
        y = self.y0_m + self.direction * self._s(t)
        return np.stack([x, y, np.zeros(t.shape)], axis=-1)

    def velocity(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)
        _, vx = self._x(t)
        vy = self.direction * np.interp(t, np.asarray(self.speed_t_s), np.asarray(self.speed_mps))
        return np.stack([vx, vy, np.zeros(t.shape)], axis=-1)


@dataclass
class Vehicle(Target):
    """An extended road vehicle; ``lane_switch`` lists ``(t_s, new_lane)`` (the lane changes at the
    midpoint of a lane change, when the reference point crosses the lane boundary)."""

    kind: str = "car"
    length_m: float = 4.5
    width_m: float = 1.8
    near_face_offset_m: float = 0.0
    lane_switch: tuple[tuple[float, int], ...] = field(default_factory=tuple)
    heading_sign: int = -1  # direction of travel along world y, fixes the heading while standing
    glint_decorrelates: bool = True  # new scattering phases every frame (see module docstring)

    def lane_at(self, t_s: float) -> int | None:
        lane = self.lane
        for t_sw, new in self.lane_switch:
            if t_s >= t_sw:
                lane = new
        return lane

    def heading_rotation(self, t_s: float) -> np.ndarray:
        v = np.asarray(self.trajectory.velocity(t_s), dtype=np.float64)
        speed = math.hypot(v[0], v[1])
        if speed < 0.1:  # standing (stop-and-go): keep facing along the lane
            fy = np.array([0.0, float(self.heading_sign), 0.0])
        else:
            fy = np.array([v[0] / speed, v[1] / speed, 0.0])
        fx = np.array([fy[1], -fy[0], 0.0])
        return np.stack([fx, fy, [0.0, 0.0, 1.0]], axis=1)

    def near_face_point(self, t_s: float) -> np.ndarray:
        """World position of the centre of the face the radar sees, at road level."""
        rot = self.heading_rotation(t_s)
        return np.asarray(self.trajectory.position(t_s)) + rot[:, 1] * self.near_face_offset_m


def make_vehicle(
    vid: int,
    kind: str,
    trajectory: RoadTrajectory,
    *,
    lane: int | None,
    rng: np.random.Generator,
    t_start_s: float = -math.inf,
    t_end_s: float = math.inf,
    length_m: float | None = None,
    rcs_m2: float | None = None,
    swerling: int = 0,
    lane_switch: tuple[tuple[float, int], ...] = (),
) -> Vehicle:
    """Build a :class:`Vehicle` of body type ``kind`` (length drawn from the type's range)."""
    try:
        body = BODY_TYPES[kind]
    except KeyError:
        raise ValueError(f"unknown vehicle kind {kind!r}; expected one of {', '.join(BODY_TYPES)}") from None
    if rcs_m2 is not None:
        body = BodyType(body.cls, body.length_m, body.width_m, rcs_m2, body.n_side, body.height_m)
    length = float(rng.uniform(*body.length_m)) if length_m is None else float(length_m)
    approaching = trajectory.direction < 0  # the radar looks along +y from y = 0
    off, rcs = body_scatterers(body, length, approaching)
    return Vehicle(
        id=vid,
        cls=body.cls,
        trajectory=trajectory,
        offsets_m=off,
        rcs_m2=rcs,
        swerling=swerling,
        lane=lane,
        t_start_s=t_start_s,
        t_end_s=t_end_s,
        kind=kind,
        length_m=length,
        width_m=body.width_m,
        near_face_offset_m=length / 2.0 if approaching else -length / 2.0,
        lane_switch=tuple(lane_switch),
        heading_sign=trajectory.direction,
    )
