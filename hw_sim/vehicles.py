"""Road vehicles as extended targets: body types, scatterer layouts, road trajectories.

A vehicle is a :class:`hw_sim.scene.Target` whose scatterers spread over its body. Two layouts
(``Physics.body``):

* ``"centres"`` (default): scattering centres at several heights per body type, from the face turned
  towards the radar backwards (:data:`CENTRES`): a car's bumper, licence plate, lights, wheel houses,
  mirrors, A-pillars/windscreen and roof edge; a truck's or bus's cab or rear doors, bumper or underrun
  bar, mirrors, wheel houses along the length and box edges; a motorcycle's wheels, fork, engine and the
  rider's legs, torso and helmet. Scattering-centre models of this kind describe measured vehicle
  signatures at 24-77 GHz (Buhren & Yang, "Simulation of automotive radar target lists using a novel
  approach of object representation", IEEE IV 2006; Schuler et al., "Extraction of virtual scattering
  centers of vehicles by ray-tracing simulations", IEEE TAP 56, 2008). Seen nose- or tail-on (within a
  few degrees at 50-300 m) the surfaces near the facing end carry most of the power, the sides are seen
  at grazing incidence: the geometric near face carries under half of the RCS and the power-weighted
  echo centre sits 0.05-0.3 m behind it.
* ``"near-face"`` (the v1 instrument): three scatterers across the width at the near face carry 70 %,
  both sides 25 % (wheel houses, mirrors, pillars), the far face 5 %, all at one height.

Class-typical total RCS at 24 GHz (front/rear aspect, literature values rounded): motorcycle 2 m^2, car
10 m^2 (Lim's design target), van 20 m^2, truck/bus 50 m^2; both layouts keep these totals.

Fluctuation (``Physics.glint``, see :meth:`hw_sim.scene.Scene.scatterers`): ``"aspect"`` gives each
centre a scattering phase and amplitude that vary smoothly with the aspect angle (correlation width
lambda / (2 d) for a centre of size ``d``, :attr:`Vehicle.centre_size_m`) plus a slow body vibration, so
a vehicle's glint is correlated over many 33 ms frames at 100-200 m; ``"white"`` (v1) draws new random
scattering phases every frame while the vehicle moves. ``swerling = 1`` adds a whole-body exponential
factor on top (default 0).

Reference point (ground truth, DESIGN §3): the centre of the footprint at road level. Because a radar
measures the face it sees, :attr:`Vehicle.near_face_offset_m` gives the body-frame ``y`` of the
geometric near face; the lane evaluation scores positions against that point (``ref + heading *
near_face_offset_m``).

:class:`RoadTrajectory` drives a vehicle along the road (world ``y``) with a piecewise-linear speed
profile (stop-and-go: decelerate to standstill, wait, accelerate) and optional lane changes (a
half-cosine lateral move), analytic in position and velocity and vectorised over time.
:class:`SampledTrajectory` interpolates a precomputed path (the car-following traffic of
:mod:`hw_sim.traffic`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from hw_sim.physics import Physics
from hw_sim.scene import Target


@dataclass(frozen=True)
class BodyType:
    """Geometry and radar signature of a vehicle body type."""

    cls: str  # ground-truth class (hw_sim.scene.CLASSES)
    length_m: tuple[float, float]  # uniform range
    width_m: float
    rcs_m2: float  # mean total RCS
    n_side: int  # scatterers per side along the length ("near-face" layout)
    height_m: float  # height of the scatterers above the road ("near-face" layout)
    body_height_m: float = 1.5  # height of the body (m): its shadow (Physics.shadowing) and the roof edge
    layout: str = "car"  # key of CENTRES ("centres" layout)


BODY_TYPES: dict[str, BodyType] = {
    "car": BodyType("car", (4.0, 4.9), 1.8, 10.0, 2, 0.5, 1.5, "car"),
    "van": BodyType("car", (5.0, 6.0), 2.0, 20.0, 2, 0.7, 2.4, "car"),
    "truck": BodyType("truck", (10.0, 16.5), 2.5, 50.0, 4, 1.0, 4.0, "truck"),
    "bus": BodyType("truck", (11.0, 13.5), 2.55, 50.0, 4, 1.0, 3.2, "truck"),
    "motorcycle": BodyType("motorcycle", (2.0, 2.3), 0.8, 2.0, 1, 0.6, 1.6, "motorcycle"),
}

#: scattering centres per layout and face seen (``front`` when approaching, ``rear`` when receding):
#: rows ``(name, behind_m, behind_of_length, x_of_half_width, x_extra_m, z_of_body_height, z_m, weight,
#: size_m)``; a row with a lateral offset stands for a mirrored pair (one centre on each side, the weight
#: each). Distance behind the near face = ``behind_m + behind_of_length * L``; ``x = +-(x_of_half_width * W/2
#: + x_extra_m)``; ``z = z_of_body_height * H + z_m``. ``weight``: relative share of the class RCS at
#: nose/tail-on aspect (flat surfaces normal to the line of sight and dihedral corners dominate; side features
#: are seen at grazing incidence). ``size_m``: extent of the centre, which sets how fast its scattering changes
#: with aspect (``Physics.glint``).
CENTRES: dict[str, dict[str, tuple[tuple, ...]]] = {
    "car": {
        "front": (
            ("licence plate, bumper centre", 0.0, 0.0, 0.0, 0.0, 0.0, 0.45, 30.0, 0.5),
            ("bumper corner", 0.12, 0.0, 0.8, 0.0, 0.0, 0.45, 10.0, 0.3),
            ("headlight, grille", 0.10, 0.0, 0.6, 0.0, 0.0, 0.70, 9.0, 0.25),
            ("front wheel house", 0.85, 0.0, 1.0, 0.0, 0.0, 0.35, 2.5, 0.6),
            ("mirror", 0.0, 0.42, 1.0, 0.1, 0.0, 0.95, 0.8, 0.2),
            ("A-pillar, windscreen base", 0.0, 0.33, 0.8, 0.0, 0.7, 0.0, 0.8, 0.5),
            ("roof edge", 0.0, 0.48, 0.0, 0.0, 1.0, -0.05, 0.6, 1.0),
            ("rear wheel house", -0.8, 1.0, 1.0, 0.0, 0.0, 0.35, 0.3, 0.6),
            ("far face", 0.0, 1.0, 0.0, 0.0, 0.0, 0.6, 0.3, 1.0),
        ),
        "rear": (
            ("licence plate, bumper centre", 0.0, 0.0, 0.0, 0.0, 0.0, 0.50, 30.0, 0.5),
            ("bumper corner", 0.12, 0.0, 0.8, 0.0, 0.0, 0.50, 10.0, 0.3),
            ("tail light", 0.08, 0.0, 0.7, 0.0, 0.0, 0.85, 8.0, 0.2),
            ("rear window, hatch edge", 0.25, 0.0, 0.0, 0.0, 0.72, 0.0, 4.0, 0.8),
            ("rear wheel house", 0.8, 0.0, 1.0, 0.0, 0.0, 0.35, 3.0, 0.6),
            ("roof edge", 0.0, 0.2, 0.0, 0.0, 1.0, -0.05, 1.5, 1.0),
            ("mirror", 0.0, 0.58, 1.0, 0.1, 0.0, 0.95, 0.4, 0.2),
            ("front wheel house", -0.85, 1.0, 1.0, 0.0, 0.0, 0.35, 0.3, 0.6),
            ("far face", 0.0, 1.0, 0.0, 0.0, 0.0, 0.6, 0.3, 1.0),
        ),
    },
    "truck": {
        "front": (
            ("cab front", 0.0, 0.0, 0.0, 0.0, 0.4, 0.0, 30.0, 1.2),
            ("bumper corner", 0.08, 0.0, 0.85, 0.0, 0.0, 0.55, 9.0, 0.4),
            ("headlight", 0.05, 0.0, 0.7, 0.0, 0.0, 0.85, 5.0, 0.3),
            ("windscreen frame corner", 0.15, 0.0, 0.9, 0.0, 0.68, 0.0, 6.0, 0.5),
            ("mirror", 0.35, 0.0, 1.0, 0.25, 0.6, 0.0, 3.0, 0.3),
            ("front wheel house", 1.4, 0.0, 1.0, 0.0, 0.0, 0.5, 1.2, 0.9),
            ("cab roof edge", 0.3, 0.0, 0.0, 0.0, 0.95, 0.0, 2.0, 1.5),
            ("box front top edge", 2.3, 0.0, 0.9, 0.0, 1.0, 0.0, 0.4, 1.5),
            ("middle wheel house", 0.0, 0.6, 1.0, 0.0, 0.0, 0.5, 0.1, 0.9),
            ("rear wheel house", -1.2, 1.0, 1.0, 0.0, 0.0, 0.5, 0.1, 0.9),
            ("rear box edge", 0.0, 1.0, 0.9, 0.0, 1.0, 0.0, 0.05, 1.5),
        ),
        "rear": (
            ("rear doors", 0.0, 0.0, 0.0, 0.0, 0.55, 0.0, 30.0, 1.5),
            ("underrun bar", 0.12, 0.0, 0.5, 0.0, 0.0, 0.5, 8.0, 0.8),
            ("tail light", 0.10, 0.0, 0.8, 0.0, 0.0, 0.9, 4.0, 0.2),
            ("door edge, box corner", 0.05, 0.0, 1.0, 0.0, 0.3, 0.0, 5.0, 0.5),
            ("box top edge", 0.05, 0.0, 0.6, 0.0, 1.0, 0.0, 4.0, 1.0),
            ("rear wheel house", 1.2, 0.0, 1.0, 0.0, 0.0, 0.5, 1.2, 0.9),
            ("middle wheel house", 0.0, 0.4, 1.0, 0.0, 0.0, 0.5, 0.1, 0.9),
            ("mirror", -0.35, 1.0, 1.0, 0.25, 0.6, 0.0, 0.05, 0.3),
            ("front wheel house", -1.4, 1.0, 1.0, 0.0, 0.0, 0.5, 0.05, 0.9),
        ),
    },
    "motorcycle": {
        "front": (
            ("front wheel, mudguard", 0.0, 0.0, 0.0, 0.0, 0.0, 0.35, 25.0, 0.6),
            ("fork, headlight", 0.12, 0.0, 0.0, 0.0, 0.0, 0.85, 20.0, 0.3),
            ("rider's knees", 0.0, 0.30, 1.0, 0.0, 0.0, 0.65, 3.0, 0.3),
            ("engine", 0.0, 0.33, 0.0, 0.0, 0.0, 0.45, 6.0, 0.4),
            ("rider's torso", 0.0, 0.42, 0.0, 0.0, 0.0, 1.15, 4.0, 0.4),
            ("rider's helmet", 0.0, 0.38, 0.0, 0.0, 0.0, 1.55, 2.0, 0.3),
            ("rear wheel", -0.3, 1.0, 0.0, 0.0, 0.0, 0.35, 0.5, 0.6),
        ),
        "rear": (
            ("licence plate, tail light, rear wheel", 0.0, 0.0, 0.0, 0.0, 0.0, 0.55, 25.0, 0.5),
            ("exhaust", 0.15, 0.0, 0.5, 0.0, 0.0, 0.35, 8.0, 0.3),
            ("rider's back", 0.0, 0.28, 0.0, 0.0, 0.0, 1.15, 8.0, 0.4),
            ("rider's helmet", 0.0, 0.32, 0.0, 0.0, 0.0, 1.55, 3.0, 0.3),
            ("rider's legs", 0.0, 0.26, 1.0, 0.0, 0.0, 0.6, 4.0, 0.3),
            ("engine", 0.0, 0.55, 0.0, 0.0, 0.0, 0.45, 1.0, 0.4),
            ("front wheel", 0.0, 1.0, 0.0, 0.0, 0.0, 0.35, 0.5, 0.6),
        ),
    },
}

NEAR_SHARE, SIDE_SHARE, FAR_SHARE = 0.70, 0.25, 0.05


def body_centres(body: BodyType, length_m: float, approaching: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body-frame offsets ``(K, 3)``, RCS ``(K,)`` and sizes ``(K,)`` of a vehicle's scattering centres
    (:data:`CENTRES`; the RCS adds up to the body type's)."""
    near_y = length_m / 2.0 if approaching else -length_m / 2.0
    back = -1.0 if approaching else 1.0  # body-frame y direction from the near face into the body
    half_w, h = body.width_m / 2.0, body.body_height_m
    off, w, size = [], [], []
    for _name, b_m, b_l, x_w, x_m, z_h, z_m, weight, d in CENTRES[body.layout]["front" if approaching else "rear"]:
        y = near_y + back * min(b_m + b_l * length_m, length_m)
        x = x_w * half_w + x_m
        z = z_h * h + z_m
        for sx in ((-1.0, 1.0) if x != 0.0 else (0.0,)):
            off.append((sx * x, y, z))
            w.append(weight)
            size.append(d)
    w_arr = np.asarray(w)
    return np.asarray(off), body.rcs_m2 * w_arr / w_arr.sum(), np.asarray(size)


def body_scatterers(body: BodyType, length_m: float, approaching: bool) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame offsets ``(K, 3)`` and RCS ``(K,)`` of the v1 "near-face" layout (see module docstring)."""
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


@dataclass(frozen=True, eq=False)
class SampledTrajectory(RoadTrajectory):
    """A :class:`RoadTrajectory` whose along-road motion is precomputed: distance travelled ``s_m`` and speed
    ``v_mps`` on the grid ``t0_s + i * dt_s``, cubic Hermite interpolation between samples (position and its
    derivative, the velocity, stay consistent), constant speed outside the grid. The lateral motion (lane
    changes, weave, offset) is :class:`RoadTrajectory`'s. Any instant can be evaluated in any order."""

    t0_s: float = 0.0
    dt_s: float = 0.1
    s_m: np.ndarray = field(default_factory=lambda: np.zeros(1))
    v_mps: np.ndarray = field(default_factory=lambda: np.zeros(1))

    def _hermite(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = self.s_m.size
        if t.ndim == 0 and n >= 2:  # one instant (a frame): the same formula without array overhead
            tf = float(t)
            u = (tf - self.t0_s) / self.dt_s
            if u < 0.0:
                return np.float64(self.s_m[0] + self.v_mps[0] * (tf - self.t0_s)), np.float64(self.v_mps[0])
            if u > n - 1:
                te = self.t0_s + (n - 1) * self.dt_s
                return np.float64(self.s_m[-1] + self.v_mps[-1] * (tf - te)), np.float64(self.v_mps[-1])
            i = min(int(u), n - 2)
            x = u - i
            s0, s1 = float(self.s_m[i]), float(self.s_m[i + 1])
            m0, m1 = float(self.v_mps[i]) * self.dt_s, float(self.v_mps[i + 1]) * self.dt_s
            x2, x3 = x * x, x * x * x
            sv = (2 * x3 - 3 * x2 + 1) * s0 + (x3 - 2 * x2 + x) * m0 + (-2 * x3 + 3 * x2) * s1 + (x3 - x2) * m1
            vv = ((6 * x2 - 6 * x) * s0 + (3 * x2 - 4 * x + 1) * m0
                  + (-6 * x2 + 6 * x) * s1 + (3 * x2 - 2 * x) * m1) / self.dt_s
            return np.float64(sv), np.float64(vv)
        u = (t - self.t0_s) / self.dt_s
        i = np.clip(np.floor(u).astype(np.int64), 0, max(n - 2, 0))
        if n < 2:
            return self.s_m[0] + self.v_mps[0] * (t - self.t0_s), np.full(t.shape, self.v_mps[0])
        x = u - i
        inside = (u >= 0.0) & (u <= n - 1)
        s0, s1 = self.s_m[i], self.s_m[i + 1]
        m0, m1 = self.v_mps[i] * self.dt_s, self.v_mps[i + 1] * self.dt_s
        x2, x3 = x * x, x * x * x
        s = (2 * x3 - 3 * x2 + 1) * s0 + (x3 - 2 * x2 + x) * m0 + (-2 * x3 + 3 * x2) * s1 + (x3 - x2) * m1
        v = ((6 * x2 - 6 * x) * s0 + (3 * x2 - 4 * x + 1) * m0
             + (-6 * x2 + 6 * x) * s1 + (3 * x2 - 2 * x) * m1) / self.dt_s
        t_end = self.t0_s + (n - 1) * self.dt_s
        s_out = np.where(u < 0.0, self.s_m[0] + self.v_mps[0] * (t - self.t0_s),
                         self.s_m[-1] + self.v_mps[-1] * (t - t_end))
        v_out = np.where(u < 0.0, self.v_mps[0], self.v_mps[-1])
        return np.where(inside, s, s_out), np.where(inside, v, v_out)

    def _s(self, t: np.ndarray) -> np.ndarray:
        return self._hermite(t)[0]

    def _x(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if t.ndim:
            return super()._x(t)
        tf = float(t)  # one instant: RoadTrajectory's lateral motion without array overhead
        x, vx = self.x0_m, 0.0
        for t0, dur, dx in self.lane_changes:
            u = min(max((tf - t0) / dur, 0.0), 1.0)
            x += dx * (1.0 - math.cos(math.pi * u)) / 2.0
            if t0 < tf < t0 + dur:
                vx += dx * math.pi / (2.0 * dur) * math.sin(math.pi * u)
        if self.weave is not None:
            amp, period, phase = self.weave
            w = 2.0 * math.pi / period
            x += amp * math.sin(w * tf + phase)
            vx += amp * w * math.cos(w * tf + phase)
        return np.float64(x), np.float64(vx)

    def velocity(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)
        _, vx = self._x(t)
        vy = self.direction * self._hermite(t)[1]
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
    glint_decorrelates: bool = True  # moving: its glint fluctuates (Physics.glint, see module docstring)
    #: extent (m) of each scattering centre, sets its aspect correlation width (None: 0.5 m each)
    centre_size_m: np.ndarray | None = None
    body_height_m: float = 1.5  # height of the body box that shadows other vehicles (Physics.shadowing)

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
    physics: Physics | None = None,
) -> Vehicle:
    """Build a :class:`Vehicle` of body type ``kind`` (length drawn from the type's range), with the
    scatterer layout ``physics.body`` (default: the :class:`Physics` defaults)."""
    try:
        body = BODY_TYPES[kind]
    except KeyError:
        raise ValueError(f"unknown vehicle kind {kind!r}; expected one of {', '.join(BODY_TYPES)}") from None
    if rcs_m2 is not None:
        body = dataclasses.replace(body, rcs_m2=float(rcs_m2))
    length = float(rng.uniform(*body.length_m)) if length_m is None else float(length_m)
    approaching = trajectory.direction < 0  # the radar looks along +y from y = 0
    if (physics or Physics()).body == "centres":
        off, rcs, size = body_centres(body, length, approaching)
    else:
        off, rcs = body_scatterers(body, length, approaching)
        size = None
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
        centre_size_m=size,
        body_height_m=body.body_height_m,
    )
