"""Surveillance-site targets and random events for the Distance2Go (Tavanti et al. §III).

The site (Tavanti Fig. 8): the radar stands 1 m high by a straight urban road, looking along it and
turned :data:`SITE_YAW_DEG` towards it so that the road lies in the 42° main beam; static metallic
objects (poles, a fence, a parked car, a gate) are in view. Targets move along the road lanes
(x 2-3.5 m approaching and 5-6.5 m receding, keep-right two-way road, vehicles in one lane at least
:data:`MIN_HEADWAY_S` apart) or the sidewalks (x 0.3-1.5 m, three pedestrians in four; 7.5-9 m), approaching
or receding, heading jittered by up to 2° (vehicles) or 4° (pedestrians) so aspects vary, or, for some
pedestrians in multi-target events, across the road, entering and leaving the beam sideways.

Bodies (body frame ``x`` right, ``y`` forward, ``z`` up; reference point = footprint centre):

* pedestrian: :class:`hw_sim.pedestrian.Pedestrian` (torso, head, swinging arms and legs), total RCS
  about -3 dBsm (lognormal, sigma 2 dB), Swerling I, walking 1.0-1.7 m/s or (one in four) jogging
  2.2-3.3 m/s;
* car: 17 scatterers on bumpers, wheel arches, mirrors, doors, roof; 3.8-5.0 m long; about 10 dBsm;
* motorcycle with rider: 10 scatterers (wheels, fork, engine, tail, rider's torso, helmet, knees);
  about 5 dBsm;
* truck/bus: 30-50 scatterers on the front face, both sides at two heights, axles and rear doors;
  7-12 m long; about 18 dBsm.

The event generators' ``population`` (:data:`VEHICLE_POPULATIONS`) chooses these lengths: ``"site"`` (default,
the evaluation corpus) as above; ``"wide"`` (for reference sets) draws cars 3.5-5.2 m, one car in
:data:`VAN_PROBABILITY` a van (:func:`van_body`, labelled car) and trucks/buses 6-18 m.

Under the default ``[physics]`` (:mod:`hw_sim.physics`) the pedestrian is the Boulic et al. 1990 walker
(:class:`hw_sim.pedestrian.BoulicPedestrian`, ``gait``), vehicle panels (bumpers, doors, tailgate) have a flat
plate's aspect lobe over a diffuse floor, its specular peak set so that the panel's mean over aspect is its share of
the target's RCS (``vehicle_lobes``), wheels turn (``wheels``: rim and tread points, 0
to 2v), and the site adds parked cars, a denser fence, a wall and swaying trees (``site_clutter = "urban"``,
the ``[[d2g_site]]`` table); ``preset = "v1"`` restores the rigid isotropic bodies and the seven objects.

Scatterer RCS shares are random per target (gamma-distributed), total RCS lognormal around the class
mean (sigma 3 dB for vehicles), Swerling III for most vehicles (I for some), speeds uniform in the
class range. Ground-truth identities: target ``id = 100 * (event + 1) + k``.

Event generators (registered in :data:`hw_sim.scenario.EVENT_SCENARIOS`, ``events=N``):

* ``single-random``: one target per event, classes balanced (each block of four events holds one of
  each class in random order);
* ``multi-random``: two to four targets per event, random classes, staggered starts inside the
  event's slot so they overlap, cross each other and enter/leave the beam at different times.

Each event owns a slot of :data:`SLOT_S` seconds and every target is out of view at least
:data:`QUIET_S` seconds before the slot ends, so events are separated by an empty scene.
TOML scenarios can place these bodies explicitly with ``[[d2g_target]]`` tables (see
:func:`_d2g_target_table`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hw_sim.pedestrian import BoulicPedestrian, Pedestrian, height_for_cycle
from hw_sim.physics import Physics
from hw_sim.scene import Clutter, GroundTruth, LinearTrajectory, RadarPose, Scene, Target

#: the four classes of the surveillance profile (Tavanti), in the order of its confusion matrices
SURVEILLANCE_CLASSES: tuple[str, ...] = ("car", "pedestrian", "truck", "motorcycle")
SITE_YAW_DEG = 10.0
SITE_HEIGHT_M = 1.0
SLOT_S = 24.0
QUIET_S = 3.0
#: visibility for ground truth: the D2G's unambiguous range and half its 42° azimuth beamwidth
VISIBLE_RANGE_M = 24.0
VISIBLE_HALF_BEAM_DEG = 21.0
#: sector in which a target can still be seen through the pattern's skirts at short range (two-way
#: gain down ~30 dB at 45°): tracks there are not false, but truth statistics use the beam above
SEEN_HALF_SECTOR_DEG = 45.0

#: static metallic objects of the site (x, y, z, rcs): lamp pole, parked car, fence posts, gate
SITE_CLUTTER: tuple[tuple[float, float, float, float], ...] = (
    (-1.5, 4.0, 2.0, 10.0),
    (4.5, 9.0, 0.8, 20.0),
    (-2.0, 6.0, 1.0, 3.0),
    (-2.0, 10.0, 1.0, 3.0),
    (-2.0, 14.0, 1.0, 3.0),
    (-2.0, 18.0, 1.0, 3.0),
    (9.0, 20.0, 1.5, 30.0),
)

#: class -> (mean total RCS m^2, lognormal sigma dB, speed range m/s)
CLASS_RCS_SPEED: dict[str, tuple[float, float, tuple[float, float]]] = {
    "pedestrian": (0.5, 2.0, (1.0, 1.7)),
    "car": (10.0, 3.0, (15 / 3.6, 40 / 3.6)),
    "motorcycle": (3.0, 3.0, (15 / 3.6, 45 / 3.6)),
    "truck": (60.0, 3.0, (10 / 3.6, 30 / 3.6)),
}
JOG_SPEED_MPS = (2.2, 3.3)
#: pedestrians use the radar's own sidewalk (x 0.3-1.5 m) or, less often, the far one (x 7.5-9 m,
#: never closer than ~15 m inside the beam: beyond a pedestrian's detection range, as in the paper)
NEAR_SIDEWALK_PROBABILITY = 0.75
#: vehicles entering one lane during an event are at least this far apart in time
MIN_HEADWAY_S = 2.0
JOG_PROBABILITY = 0.25


def _shares(rng: np.random.Generator, n: int, total: float, weight: np.ndarray | None = None) -> np.ndarray:
    s = rng.gamma(2.0, 1.0, n) * (1.0 if weight is None else weight)
    return total * s / s.sum()


#: vehicle populations of the event generators (module doc): "site" (the evaluation corpus) and "wide"
VEHICLE_POPULATIONS: tuple[str, ...] = ("site", "wide")
#: body lengths (m) of the populations
CAR_LENGTH_M = {"site": (3.8, 5.0), "wide": (3.5, 5.2)}
TRUCK_LENGTH_M = {"site": (7.0, 12.0), "wide": (6.0, 18.0)}
#: "wide": share of the cars that are vans (light commercial vehicles) and their body (length, width, height, m)
VAN_PROBABILITY = 0.25
VAN_LENGTH_M = (4.7, 6.0)
VAN_WIDTH_M = (1.9, 2.1)
VAN_HEIGHT_M = (1.9, 2.6)


def car_body(rng: np.random.Generator, total_rcs_m2: float, length_m: tuple[float, float] = (3.8, 5.0),
             width_m: tuple[float, float] = (1.7, 1.9), height_m: tuple[float, float] = (1.4, 1.6)
             ) -> tuple[np.ndarray, np.ndarray]:
    length = rng.uniform(*length_m)
    width = rng.uniform(*width_m)
    height = rng.uniform(*height_m)
    l2, w2 = length / 2, width / 2
    pts = [
        (0.0, l2, 0.5), (-0.8 * w2, l2 - 0.1, 0.5), (0.8 * w2, l2 - 0.1, 0.5), (0.0, l2 - 0.3, 0.8),
        (0.0, 0.15 * length, 0.75 * height),
        (-w2, 0.3 * length, 0.35), (w2, 0.3 * length, 0.35), (-w2, -0.3 * length, 0.35), (w2, -0.3 * length, 0.35),
        (-w2 - 0.08, 0.2 * length, 1.0), (w2 + 0.08, 0.2 * length, 1.0),
        (-w2, 0.0, 0.6), (w2, 0.0, 0.6),
        (0.0, -0.2 * length, height),
        (0.0, -l2, 0.6), (-0.8 * w2, -l2 + 0.1, 0.8), (0.8 * w2, -l2 + 0.1, 0.8),
    ]
    off = np.array(pts)
    # bumpers and the front/rear faces dominate a car seen nearly head-on or tail-on
    weight = np.where(np.abs(off[:, 1]) > 0.45 * length, 2.0, 1.0)
    return off, _shares(rng, len(pts), total_rcs_m2, weight)


def motorcycle_body(rng: np.random.Generator, total_rcs_m2: float) -> tuple[np.ndarray, np.ndarray]:
    length = rng.uniform(1.9, 2.3)
    l2 = length / 2
    pts = [
        (0.0, l2 - 0.15, 0.4), (0.0, l2 - 0.3, 0.9), (0.0, 0.1, 0.5), (0.25, -0.1, 0.45),
        (0.0, -l2 + 0.2, 0.4), (0.0, -l2 + 0.1, 0.8),
        (0.0, -0.15, 1.25), (0.0, 0.05, 1.6), (-0.2, 0.2, 0.7), (0.2, 0.2, 0.7),  # rider
    ]
    return np.array(pts), _shares(rng, len(pts), total_rcs_m2)


def van_body(rng: np.random.Generator, total_rcs_m2: float) -> tuple[np.ndarray, np.ndarray]:
    """A van: the car's scatterer layout on a longer, wider and taller body (:data:`VAN_LENGTH_M`)."""
    return car_body(rng, total_rcs_m2, VAN_LENGTH_M, VAN_WIDTH_M, VAN_HEIGHT_M)


def truck_body(rng: np.random.Generator, total_rcs_m2: float, length_m: tuple[float, float] = (7.0, 12.0)
               ) -> tuple[np.ndarray, np.ndarray]:
    length = rng.uniform(*length_m)
    width = rng.uniform(2.3, 2.55)
    height = rng.uniform(3.0, 3.8)
    l2, w2 = length / 2, width / 2
    pts = [(x, l2, z) for x in (-0.8 * w2, 0.0, 0.8 * w2) for z in (0.6, 1.5, 2.4)]  # cab front
    for y in np.linspace(-l2 + 0.5, l2 - 0.5, max(3, int(length / 1.2))):  # side panels
        for z in (1.0, 0.65 * height):
            pts += [(-w2, float(y), z), (w2, float(y), z)]
    axles = [l2 - 1.2, -l2 + 1.5] + ([-l2 + 2.8] if length > 9.0 else [])
    pts += [(s * w2, y, 0.5) for y in axles for s in (-1.0, 1.0)]
    pts += [(x, -l2, z) for x in (-0.6 * w2, 0.6 * w2) for z in (1.0, 0.7 * height)]  # rear doors
    off = np.array(pts)
    weight = np.where(np.abs(off[:, 1]) > l2 - 0.05, 3.0, 1.0)
    return off, _shares(rng, len(pts), total_rcs_m2, weight)


BODIES = {"car": car_body, "motorcycle": motorcycle_body, "truck": truck_body}

# --- aspect lobes and rotating wheels (Physics.vehicle_lobes, Physics.wheels) ----------------------------

#: wavelength of the Distance2Go (m), for the panels' lobes
WAVELENGTH_M = 299_792_458.0 / 24.125e9
#: a panel's diffuse floor relative to its specular peak: edges, seams and curvature keep an off-specular
#: panel visible some 13 dB down (the spread of measured car RCS over aspect away from the broadside and
#: head-on flashes; Schuler, Becker & Wiesbeck, IEEE Trans. Antennas Propag. 56(11), 2008)
LOBE_FLOOR = 0.05
#: effective flat length (m) of a panel across the plane of incidence: a curved body panel reflects
#: coherently only over about a Fresnel zone sqrt(lambda R / 2) of its curvature radius R (0.5-5 m), so its
#: lobe is a few degrees wide, not the sub-degree lobe of a 1.7 m flat plate
PANEL_LENGTH_M = (0.08, 0.25)
#: wheel radius (m) by class; rim scatterers at RIM_FRACTION of it, tread scatterers on the tyre
WHEEL_RADIUS_M = {"car": 0.31, "motorcycle": 0.32, "truck": 0.5}
RIM_FRACTION = 0.6
#: scatterers per wheel (alternately tread and rim, evenly spaced in angle) and the share of the static
#: wheel-arch point's RCS they take over (the arch edge keeps the rest)
WHEEL_POINTS = 6
WHEEL_SHARE = 0.5


def panel_normals(cls: str, off: np.ndarray) -> np.ndarray:
    """(K, 3) outward unit normals of the body's flat panels (zero for point-like scatterers: wheel arches,
    mirrors, roof, windscreen, rider, axles), from where each scatterer sits on the body's outline."""
    n = np.zeros_like(off)
    if cls == "motorcycle":
        return n  # fork, engine, rider: curved, no flat panel
    y = off[:, 1]
    l2 = float(np.max(np.abs(y)))
    front, rear = y > l2 - 0.35, y < -l2 + 0.35
    n[front, 1] = 1.0
    n[rear, 1] = -1.0
    # doors and side panels: on the side outline above the wheels (car mirrors, higher and outside it, excluded)
    ax = np.abs(off[:, 0])
    w2 = float(np.max(ax[off[:, 2] < 0.9])) if cls == "car" else float(np.max(ax))
    side = (np.abs(ax - w2) < 0.02) & ~front & ~rear & (off[:, 2] > 0.55)
    if cls == "car":
        side &= off[:, 2] < 0.9
    n[side, 0] = np.sign(off[side, 0])
    return n


def wheel_centres(cls: str, off: np.ndarray) -> np.ndarray:
    """Indices of the body scatterers that mark a wheel (car wheel arches, truck axles, motorcycle wheels)."""
    if cls == "car":
        return np.array([5, 6, 7, 8])
    if cls == "motorcycle":
        return np.array([0, 4])
    return np.flatnonzero(np.isclose(off[:, 2], 0.5) & (np.abs(off[:, 0]) > 0.5))


def plate_lobe(cos_inc: np.ndarray, length_m: np.ndarray) -> np.ndarray:
    """Power gain of a flat panel seen at incidence angle theta (``cos_inc`` = cos theta; <= 0: facing away):
    cos^2 theta sinc^2(2 L sin theta / lambda) (the flat plate's physical-optics pattern, Knott et al. 2004
    eq. 6.21, peak 1) above the diffuse floor :data:`LOBE_FLOOR`; a panel facing away is hidden by the body
    and keeps a tenth of the floor (edge diffraction)."""
    c = np.clip(cos_inc, -1.0, 1.0)
    s = np.sqrt(1.0 - c * c)
    g = c * c * np.sinc(2.0 * length_m * s / WAVELENGTH_M) ** 2
    return np.where(c > 0.0, np.maximum(g, LOBE_FLOOR), 0.1 * LOBE_FLOOR)


#: incidence angles (rad) over which a panel's aspect-mean gain is taken: 0-90 deg in 0.01 deg steps
_MEAN_INCIDENCE_RAD = np.radians(np.linspace(0.0, 90.0, 9001))


def panel_mean_gain(length_m: np.ndarray) -> np.ndarray:
    """Mean of :func:`plate_lobe` over incidence angles 0-90 deg (uniform in angle) for panels of effective flat
    length ``length_m``: the share of its specular peak that a panel returns on average over the aspects it
    faces the radar from."""
    L = np.asarray(length_m, dtype=float).reshape(-1, 1)
    c = np.cos(_MEAN_INCIDENCE_RAD)[None, :]
    return plate_lobe(c, L).mean(axis=1)


@dataclass
class SiteVehicle(Target):
    """A surveillance-site vehicle body with aspect lobes on its panels and/or rotating wheels.

    ``normals`` (K, 3) are the panels' outward normals (zero: isotropic point), ``panel_m`` their effective
    flat lengths; the wheels add ``WHEEL_POINTS`` scatterers per wheel after the K body points, turning at
    ``omega = v / R`` so a tread point moves at 0 (on the road) to 2v (on top) along the heading. ``rcs_m2``
    holds the RCS at the instant of the last :meth:`scatterers` call (the scene reads it right after);
    ``radar_m`` is the radar's world position, for the aspect.
    """

    normals: np.ndarray | None = None
    panel_m: np.ndarray | None = None
    radar_m: tuple[float, float, float] = (0.0, 0.0, 1.0)
    wheel_hub_m: np.ndarray | None = None  # (W, 3) body frame
    wheel_radius_m: float = 0.3
    wheel_phase0: np.ndarray | None = None  # (W,) rad

    def __post_init__(self) -> None:
        super().__post_init__()
        self._base_off = self.offsets_m.copy()
        self._base_rcs = self.rcs_m2.copy()
        nw = 0 if self.wheel_hub_m is None else len(self.wheel_hub_m)
        k = np.arange(WHEEL_POINTS)
        self._wheel_rho = np.where(k % 2 == 0, 1.0, RIM_FRACTION) * self.wheel_radius_m
        self._wheel_ang = 2 * np.pi * k / WHEEL_POINTS
        self._n_body = self._base_off.shape[0] - nw * WHEEL_POINTS

    def _speed(self, t_s: float) -> float:
        v = np.asarray(self.trajectory.velocity(t_s), dtype=float)
        return float(math.hypot(v[0], v[1]))

    def scatterers(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        off = self._base_off.copy()
        vel = np.zeros_like(off)
        nb = self._n_body
        if self.wheel_hub_m is not None and len(self.wheel_hub_m):
            w = self._speed(t_s) / self.wheel_radius_m
            # psi measured from the forward direction in the body's y-z plane, turning so the top moves forward
            psi = self.wheel_phase0[:, None] + self._wheel_ang[None, :] - w * t_s  # (W, P)
            rho = self._wheel_rho[None, :]
            hub = self.wheel_hub_m[:, None, :]
            pts = hub + np.stack([np.zeros_like(psi), rho * np.cos(psi), rho * np.sin(psi)], -1)
            vp = np.stack([np.zeros_like(psi), rho * w * np.sin(psi), -rho * w * np.cos(psi)], -1)
            off[nb:] = pts.reshape(-1, 3)
            vel[nb:] = vp.reshape(-1, 3)
        if self.normals is not None:
            rot = self.heading_rotation(t_s)
            p = np.asarray(self.trajectory.position(t_s), dtype=float) + off[:nb] @ rot.T
            los = np.asarray(self.radar_m) - p
            los = (los / np.linalg.norm(los, axis=1, keepdims=True)) @ rot  # body frame, towards the radar
            normals = self.normals[:nb]
            cos_inc = np.einsum("kj,kj->k", los, normals)
            panel = np.any(normals != 0.0, axis=1)
            g = np.where(panel, plate_lobe(cos_inc, self.panel_m[:nb]), 1.0)
            rcs = self._base_rcs.copy()
            rcs[:nb] = self._base_rcs[:nb] * g
            self.rcs_m2 = rcs
        return off, vel


def site_vehicle(cls: str, off: np.ndarray, rcs: np.ndarray, aux: np.random.Generator, physics: Physics,
                 radar_m) -> dict:
    """Keyword arguments of a :class:`SiteVehicle` for a body (``off``, ``rcs``) under ``physics``; random
    choices (panel lengths, wheel angles) from ``aux``, never from the event generator."""
    kw: dict = {"radar_m": tuple(float(v) for v in radar_m)}
    off = np.asarray(off, dtype=float)
    rcs = np.asarray(rcs, dtype=float).copy()
    if physics.wheels:
        idx = wheel_centres(cls, off)
        r = WHEEL_RADIUS_M[cls]
        hubs = off[idx].copy()
        hubs[:, 2] = r
        moved = rcs[idx] * WHEEL_SHARE
        rcs[idx] -= moved
        wheel_rcs = np.repeat(moved / WHEEL_POINTS, WHEEL_POINTS)
        kw.update(wheel_hub_m=hubs, wheel_radius_m=r, wheel_phase0=aux.uniform(0.0, 2 * np.pi, len(idx)))
        body_n = off.shape[0]
        off = np.concatenate([off, np.zeros((len(idx) * WHEEL_POINTS, 3))])
        rcs = np.concatenate([rcs, wheel_rcs])
    else:
        body_n = off.shape[0]
    if physics.vehicle_lobes:
        normals = np.zeros((off.shape[0], 3))
        normals[:body_n] = panel_normals(cls, off[:body_n])
        panel_m = aux.uniform(*PANEL_LENGTH_M, off.shape[0])
        # a target's RCS is its mean over aspect, as measured RCS figures are: a panel's share is its aspect-mean,
        # so its specular peak is that share over the lobe's mean gain (the lobe redistributes the echo over
        # aspect instead of removing it)
        panel = np.any(normals != 0.0, axis=1)
        rcs[panel] /= panel_mean_gain(panel_m[panel])
        kw.update(normals=normals, panel_m=panel_m)
    kw.update(offsets_m=off, rcs_m2=rcs)
    return kw


def random_rcs(cls: str, rng: np.random.Generator) -> float:
    mean, sigma_db, _ = CLASS_RCS_SPEED[cls]
    return float(mean * 10.0 ** (rng.normal(0.0, sigma_db) / 10.0))


def random_speed(cls: str, rng: np.random.Generator) -> tuple[float, bool]:
    """Speed (m/s) for a class; for pedestrians also whether they jog."""
    if cls == "pedestrian" and rng.random() < JOG_PROBABILITY:
        return float(rng.uniform(*JOG_SPEED_MPS)), True
    lo, hi = CLASS_RCS_SPEED[cls][2]
    return float(rng.uniform(lo, hi)), False


def make_target(
    cls: str,
    target_id: int,
    trajectory: LinearTrajectory,
    rng: np.random.Generator,
    *,
    t_start_s: float,
    t_end_s: float,
    total_rcs_m2: float | None = None,
    stride_hz: float | None = None,
    physics: Physics | None = None,
    radar_m=(0.0, 0.0, SITE_HEIGHT_M),
    seed: int = 0,
    population: str = "site",
) -> Target:
    """A randomised body of class ``cls`` on ``trajectory`` (speed taken from the trajectory).

    ``physics`` (default: the defaults) chooses the pedestrian model and the vehicles' lobes and wheels;
    their extra random choices come from a generator of (``seed``, ``target_id``), so ``rng`` is drawn
    exactly as under the v1 instrument and the events stay the same. ``radar_m``: the radar's world position.
    ``population`` (:data:`VEHICLE_POPULATIONS`) sets the vehicles' body lengths.
    """
    if population not in VEHICLE_POPULATIONS:
        raise ValueError(f"population must be one of {VEHICLE_POPULATIONS}, got {population!r}")
    physics = Physics() if physics is None else physics
    aux = np.random.default_rng([seed, target_id & 0x7FFFFFFF, 0xA5EC])
    rcs = random_rcs(cls, rng) if total_rcs_m2 is None else total_rcs_m2
    v = np.asarray(trajectory.v, dtype=float)
    speed = float(math.hypot(v[0], v[1]))
    if cls == "pedestrian":
        if stride_hz is None:
            # stride frequency grows with speed: ~0.9 Hz walking at 1.3 m/s, ~1.4 Hz jogging at 2.8 m/s
            stride_hz = float(np.clip(0.55 + 0.3 * speed, 0.75, 1.6) * rng.uniform(0.93, 1.07))
        if physics.gait == "boulic":
            # the body height whose Boulic cycle is this stride frequency, kept within adult heights (the
            # cycle then follows Boulic's law for that height)
            height = float(np.clip(height_for_cycle(max(speed, 0.1), stride_hz), 1.5, 1.95))
            return BoulicPedestrian.make(
                target_id, trajectory, total_rcs_m2=rcs, speed_mps=max(speed, 0.1), height_m=height,
                gait_phase_rad=float(rng.uniform(0, 2 * math.pi)), radar_m=radar_m, swerling=1,
                t_start_s=t_start_s, t_end_s=t_end_s,
            )
        return Pedestrian.make(
            target_id, trajectory, total_rcs_m2=rcs, speed_mps=max(speed, 0.1), stride_hz=stride_hz,
            gait_phase_rad=float(rng.uniform(0, 2 * math.pi)), swerling=1, t_start_s=t_start_s, t_end_s=t_end_s,
        )
    if cls not in BODIES:
        raise ValueError(f"no surveillance body for class {cls!r}; expected one of {SURVEILLANCE_CLASSES}")
    if population == "site":
        off, rcs_k = BODIES[cls](rng, rcs)
    elif cls == "car":
        van = rng.random() < VAN_PROBABILITY
        off, rcs_k = van_body(rng, rcs) if van else car_body(rng, rcs, CAR_LENGTH_M[population])
    elif cls == "truck":
        off, rcs_k = truck_body(rng, rcs, TRUCK_LENGTH_M[population])
    else:
        off, rcs_k = BODIES[cls](rng, rcs)
    swerling = 3 if rng.random() < 0.7 else 1
    if physics.vehicle_lobes or physics.wheels:
        kw = site_vehicle(cls, off, rcs_k, aux, physics, radar_m)
        return SiteVehicle(id=target_id, cls=cls, trajectory=trajectory, swerling=swerling, t_start_s=t_start_s,
                           t_end_s=t_end_s, **kw)
    return Target(
        id=target_id, cls=cls, trajectory=trajectory, offsets_m=off, rcs_m2=rcs_k,
        swerling=swerling, t_start_s=t_start_s, t_end_s=t_end_s,
    )


# --- random events -------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Path:
    p0: tuple[float, float, float]
    v: tuple[float, float, float]
    duration_s: float
    lane: int = -1  # vehicles: 0 = near lane (approaching), 1 = far lane (receding); -1 = sidewalk/crossing


def _along_road_path(
    cls: str, speed: float, rng: np.random.Generator, max_duration_s: float, lane: int | None = None,
    keep_right: bool = True,
) -> _Path:
    """Approaching or receding along the road/sidewalk, heading jittered a little (aspect varies).

    Vehicles keep right on the two-way road: the near lane (x 2-3.5 m) carries approaching traffic,
    the far lane (x 5-6.5 m) receding traffic. With ``keep_right=False`` (reference sets only) a
    vehicle's direction is drawn independently of its lane, so both directions pass at both distances.
    """
    if cls == "pedestrian":
        near = rng.random() < NEAR_SIDEWALK_PROBABILITY
        x = float(rng.uniform(0.3, 1.5) if near else rng.uniform(7.5, 9.0))
        jitter = 4.0
        approaching = bool(rng.random() < 0.5)
    else:
        lane = int(rng.integers(0, 2)) if lane is None else lane
        x = float(rng.uniform(2.0, 3.5) if lane == 0 else rng.uniform(5.0, 6.5))
        jitter = 2.0
        approaching = lane == 0 if keep_right else bool(rng.random() < 0.5)
    y_far, y_near = 27.0, -2.0
    head = math.radians(rng.uniform(-jitter, jitter))
    length = min(y_far - y_near, speed * max_duration_s)  # slow walkers start nearer
    vy = speed * math.cos(head) * (-1.0 if approaching else 1.0)
    vx = speed * math.sin(head)
    dur = length / speed
    if approaching:
        y0 = y_near + length * math.cos(head)
    else:
        y0 = y_near
    x0 = x - vx * dur / 2.0  # the lateral drift is centred on the lane
    return _Path((x0, y0, 0.0), (vx, vy, 0.0), dur, -1 if cls == "pedestrian" else int(lane))


def _crossing_path(speed: float, rng: np.random.Generator) -> _Path:
    """A pedestrian crossing the road in front of the radar, in and out of the beam sideways."""
    y = float(rng.uniform(5.0, 14.0))
    left_to_right = bool(rng.random() < 0.5)
    x0, x1 = (-4.0, 11.0) if left_to_right else (11.0, -4.0)
    vx = speed if left_to_right else -speed
    return _Path((x0, y, 0.0), (vx, float(rng.uniform(-0.2, 0.2)), 0.0), abs(x1 - x0) / speed)


def add_event(
    scene: Scene, event: int, classes: list[str], t0_s: float, slot_s: float, rng: np.random.Generator,
    *, crossing_probability: float = 0.0, stagger_s: float = 0.0, keep_right: bool = True,
    population: str = "site",
) -> None:
    """Add the targets of one event (ids ``100 * (event + 1) + k``) inside ``[t0, t0 + slot)``; ``population``:
    the vehicles' bodies (:func:`make_target`)."""
    usable = slot_s - QUIET_S - 0.5
    lane_starts: dict[int, list[float]] = {0: [], 1: []}
    for k, cls in enumerate(classes):
        speed, _jog = random_speed(cls, rng)
        if cls == "pedestrian" and rng.random() < crossing_probability:
            path = _crossing_path(speed, rng)
        else:
            path = _along_road_path(cls, speed, rng, usable - stagger_s, keep_right=keep_right)
        latest = max(0.0, usable - path.duration_s)
        start = t0_s + 0.5 + float(rng.uniform(0.0, min(stagger_s, latest)))
        if path.lane >= 0:
            # vehicles in one lane keep a time headway (they cannot overlap); else take the other lane
            for lane in (path.lane, 1 - path.lane):
                if lane != path.lane:
                    path = _along_road_path(cls, speed, rng, usable - stagger_s, lane=lane, keep_right=keep_right)
                    latest = max(0.0, usable - path.duration_s)
                for _ in range(8):
                    if all(abs(start - t) >= MIN_HEADWAY_S for t in lane_starts[lane]):
                        break
                    start = t0_s + 0.5 + float(rng.uniform(0.0, min(stagger_s, latest)))
                if all(abs(start - t) >= MIN_HEADWAY_S for t in lane_starts[lane]):
                    break
            lane_starts[path.lane].append(start)
        traj = LinearTrajectory(path.p0, path.v, t0_s=start)
        scene.add_target(
            make_target(cls, 100 * (event + 1) + k, traj, rng, t_start_s=start, t_end_s=start + path.duration_s,
                        physics=scene.physics, radar_m=scene.pose.position, seed=scene.seed, population=population)
        )


def _d2g_events_table(scene: Scene, scenario: Any, spec: dict, rng: np.random.Generator) -> None:
    """``[[d2g_events]]``: ``mode`` (single|multi), ``events``, ``slot_s``, ``first_event``, ``keep_right``
    (default true: approaching vehicles in the near lane, receding ones in the far lane; false draws the
    direction independently of the lane, for reference sets that cover both geometries), ``population``
    (:data:`VEHICLE_POPULATIONS`, default "site")."""
    from hw_sim.scenario import ScenarioError

    mode = spec.get("mode", "single")
    n = spec.get("events", 10)
    slot = float(spec.get("slot_s", SLOT_S))
    first = int(spec.get("first_event", 0))
    keep_right = spec.get("keep_right", True)
    population = spec.get("population", "site")
    if (mode not in ("single", "multi") or not isinstance(n, int) or n < 1 or slot < 8.0
            or not isinstance(keep_right, bool) or population not in VEHICLE_POPULATIONS):
        raise ScenarioError(f"d2g_events: need mode single|multi, events >= 1, slot_s >= 8, keep_right a boolean, "
                            f"population one of {VEHICLE_POPULATIONS}; got {spec!r}")
    order: list[str] = []
    for e in range(n):
        if mode == "single":
            if e % len(SURVEILLANCE_CLASSES) == 0:
                order = list(rng.permutation(SURVEILLANCE_CLASSES))
            classes = [order[e % len(SURVEILLANCE_CLASSES)]]
            add_event(scene, first + e, classes, e * slot, slot, rng, keep_right=keep_right, population=population)
        else:
            m = int(rng.integers(2, 5))
            # pedestrians and motorcycles dominate Tavanti's multi-target events (45/26/20/3)
            classes = list(rng.choice(SURVEILLANCE_CLASSES, size=m, p=[0.25, 0.4, 0.07, 0.28]))
            add_event(scene, first + e, classes, e * slot, slot, rng, crossing_probability=0.3, stagger_s=6.0,
                      keep_right=keep_right, population=population)


def _d2g_target_table(scene: Scene, scenario: Any, spec: dict, rng: np.random.Generator) -> None:
    """``[[d2g_target]]``: one realistic body: ``id``, ``class``, ``x_m``, ``y_m``, ``vx_mps``,
    ``vy_mps``, ``start_s``, ``end_s``, optional ``rcs_m2`` (total) and ``stride_hz``."""
    from hw_sim.scenario import ScenarioError, _num

    where = f"{scenario.source}: d2g_target."
    tid = spec.get("id")
    if not isinstance(tid, int) or tid <= 0:
        raise ScenarioError(f"{where}id must be a positive integer, got {tid!r}")
    cls = spec.get("class")
    if cls not in SURVEILLANCE_CLASSES:
        raise ScenarioError(f"{where}class must be one of {SURVEILLANCE_CLASSES}, got {cls!r}")
    start = _num(spec, "start_s", 0.0, where)
    traj = LinearTrajectory(
        (_num(spec, "x_m", where=where), _num(spec, "y_m", where=where), 0.0),
        (_num(spec, "vx_mps", 0.0, where), _num(spec, "vy_mps", 0.0, where), 0.0),
        t0_s=start,
    )
    rcs = spec.get("rcs_m2")
    stride = spec.get("stride_hz")
    scene.add_target(
        make_target(
            cls, tid, traj, np.random.default_rng([scene.seed, tid, 0xB0D7]), t_start_s=start,
            t_end_s=_num(spec, "end_s", 1e9, where), total_rcs_m2=None if rcs is None else float(rcs),
            stride_hz=None if stride is None else float(stride), physics=scene.physics,
            radar_m=scene.pose.position, seed=scene.seed,
        )
    )


# --- static surroundings (Physics.site_clutter) ---------------------------------------------------------

#: Billingsley's exponential Doppler spectrum of wind-blown foliage, P(v) ~ exp(-beta |v|): beta (s/m) for a
#: breeze of 7-15 mph (Billingsley, Low-Angle Radar Land Clutter, 2002, Table 6.3); rms leaf speed sqrt(2)/beta
FOLIAGE_BETA_S_PER_M = 8.0
#: sinusoids per leaf scatterer (frequencies of branches and leaves, Hz)
FOLIAGE_MODES = 4
FOLIAGE_HZ = (0.5, 3.0)
#: first id of the site's swaying objects (far above any event's 100 * (event + 1) + k)
FOLIAGE_ID0 = 900_000
#: "urban" additions, world frame (radar at the origin, road along +y): parked cars (centre x, y, total RCS),
#: the fence's intermediate posts (the v1 posts are every 4 m), the wall of a building behind the fence, and
#: trees (trunk x, y; crown height) and a bush on the far sidewalk and beside the radar
URBAN_PARKED_CARS = ((10.3, 11.0, 10.0), (10.3, 16.5, 10.0))
URBAN_FENCE_POSTS = tuple((-2.0, y, 1.0, 3.0) for y in (8.0, 12.0, 16.0, 20.0))
URBAN_WALL_X_M = -3.5
URBAN_TREES = ((9.3, 9.0, 4.0), (9.3, 22.0, 4.0))
URBAN_BUSHES = ((-1.2, 8.0, 0.7),)


@dataclass
class Foliage(Target):
    """Leaves of a tree crown or bush: scatterers about fixed points, each displaced along its own random
    direction by a sum of :data:`FOLIAGE_MODES` sinusoids, so its speed is a zero-mean random process with
    rms ``sqrt(2) / beta`` (Billingsley's exponential spectrum's width) and its phase wanders over several
    wavelengths; deterministic in time (any frame in any order). Class "clutter": not a target of the truth.
    """

    direction: np.ndarray | None = None  # (K, 3) unit
    amp_m: np.ndarray | None = None  # (K, M)
    freq_hz: np.ndarray | None = None  # (K, M)
    phase0: np.ndarray | None = None  # (K, M)

    def scatterers(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        arg = 2 * np.pi * self.freq_hz * t_s + self.phase0
        d = np.sum(self.amp_m * np.sin(arg), axis=1)
        v = np.sum(self.amp_m * 2 * np.pi * self.freq_hz * np.cos(arg), axis=1)
        return self.offsets_m + d[:, None] * self.direction, v[:, None] * self.direction


def foliage(target_id: int, centre, radius_m: float, n: int, total_rcs_m2: float, rng: np.random.Generator,
            beta_s_per_m: float = FOLIAGE_BETA_S_PER_M) -> Foliage:
    """A crown/bush of ``n`` leaf scatterers in a sphere of ``radius_m`` about ``centre`` (world, m)."""
    u = rng.normal(size=(n, 3))
    off = u / np.linalg.norm(u, axis=1, keepdims=True) * radius_m * rng.random((n, 1)) ** (1 / 3)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    f = rng.uniform(*FOLIAGE_HZ, (n, FOLIAGE_MODES))
    v_rms = math.sqrt(2.0) / beta_s_per_m * rng.uniform(0.5, 1.5, (n, 1))  # sheltered and exposed leaves
    amp = v_rms * math.sqrt(2.0 / FOLIAGE_MODES) / (2 * np.pi * f)  # each mode's speed amplitude
    return Foliage(
        id=target_id, cls="clutter", trajectory=LinearTrajectory(tuple(float(c) for c in centre), (0.0, 0.0, 0.0)),
        offsets_m=off, rcs_m2=_shares(rng, n, total_rcs_m2), swerling=0, direction=dirs, amp_m=amp, freq_hz=f,
        phase0=rng.uniform(0, 2 * np.pi, (n, FOLIAGE_MODES)),
    )


def urban_static(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Static points (K, 3) and RCS (K,) the "urban" site adds: parked cars (a :func:`car_body` each, parked
    along the road), the fence's intermediate posts (every 2 m with the v1 posts), tree trunks, and a
    building wall (at grazing incidence a wall returns from its discontinuities -- window frames, pipes,
    joints -- not specularly: points every metre at two heights, 0.3 m^2 each)."""
    pts, rcs = [], []
    for x, y, total in URBAN_PARKED_CARS:
        off, r = car_body(rng, total)
        pts.append(off + np.array([x, y, 0.0]))
        rcs.append(r)
    pts.append(np.array([p[:3] for p in URBAN_FENCE_POSTS]))
    rcs.append(np.array([p[3] for p in URBAN_FENCE_POSTS]))
    pts.append(np.array([[x, y, 1.5] for x, y, _ in URBAN_TREES]))
    rcs.append(np.full(len(URBAN_TREES), 1.0))
    wy = np.arange(2.0, 25.0, 1.0)
    pts.append(np.array([[URBAN_WALL_X_M, y, z] for y in wy for z in (1.0, 2.5)]))
    rcs.append(np.full(2 * wy.size, 0.3))
    return np.concatenate(pts), np.concatenate(rcs)


def _d2g_site_table(scene: Scene, scenario: Any, spec: dict, rng: np.random.Generator) -> None:
    """``[[d2g_site]]`` (no keys): the scene is the surveillance site; add the surroundings of
    ``[physics] site_clutter`` beyond the ``[[clutter]]`` points (v1: nothing). Seeded by the scene's seed
    alone, after the events, so the events and their draws are those of v1."""
    from hw_sim.scenario import ScenarioError

    if spec:
        raise ScenarioError(f"d2g_site takes no keys, got {sorted(spec)}")
    if scene.physics.site_clutter == "v1":
        return
    aux = np.random.default_rng([scene.seed, 0x517E])
    pts, rcs = urban_static(aux)
    if scene.clutter is None:
        scene.clutter = Clutter(position_m=pts, rcs_m2=rcs)
    else:
        scene.clutter = Clutter(np.concatenate([scene.clutter.position_m, pts]),
                                np.concatenate([scene.clutter.rcs_m2, rcs]))
    k = 0
    for x, y, h in URBAN_TREES:  # crown: 12 leaf clusters, 2 m^2 in all
        scene.add_target(foliage(FOLIAGE_ID0 + k, (x, y, h), 1.5, 12, 2.0, aux))
        k += 1
    for x, y, h in URBAN_BUSHES:  # 6 clusters, 0.5 m^2
        scene.add_target(foliage(FOLIAGE_ID0 + k, (x, y, h), 0.5, 6, 0.5, aux))
        k += 1


def site_raw(name: str, description: str, duration_s: float) -> dict[str, Any]:
    """The raw scenario dict of the surveillance site (radar pose and clutter), no targets yet."""
    return {
        "scenario": {"name": name, "board": "d2g", "description": description, "duration_s": duration_s, "seed": 1},
        "radar": {"height_m": SITE_HEIGHT_M, "yaw_deg": SITE_YAW_DEG},
        "clutter": [{"x_m": x, "y_m": y, "z_m": z, "rcs_m2": r} for x, y, z, r in SITE_CLUTTER],
        "d2g_site": [{}],
    }


def _event_scenario(mode: str, events: int | None, keep_right: bool = True, population: str = "site"):
    from hw_sim.scenario import parse_scenario

    n = 10 if events is None else int(events)
    if n < 1:
        raise ValueError("events must be >= 1")
    name = f"{mode}-random"
    what = "one target per event, classes balanced" if mode == "single" else "two to four targets per event"
    raw = site_raw(name, f"{n} random Distance2Go events ({what}), {SLOT_S:.0f} s each", n * SLOT_S)
    raw["d2g_events"] = [{"mode": mode, "events": n, "slot_s": SLOT_S, "keep_right": keep_right}]
    if population != "site":
        raw["d2g_events"][0]["population"] = population
    return parse_scenario(raw, f"generator:{name}")


def single_random(events: int | None = None, keep_right: bool = True, population: str = "site"):
    return _event_scenario("single", events, keep_right, population)


def multi_random(events: int | None = None):
    return _event_scenario("multi", events)


# --- ground truth per event ----------------------------------------------------------------------


def visible(truth: GroundTruth, pose: RadarPose) -> np.ndarray:
    """(n,) bool: reference points inside the D2G's range and half-power azimuth beam at this frame."""
    if len(truth) == 0:
        return np.zeros(0, dtype=bool)
    return (truth.range_m <= VISIBLE_RANGE_M) & (np.abs(np.degrees(truth.az_rad)) <= VISIBLE_HALF_BEAM_DEG)


@dataclass(frozen=True)
class FrameView:
    """Targets with at least one scatterer in view (range <= 24 m, |az| <= 21°) at one instant.

    A 12 m truck whose footprint centre is at 27 m already shows its front face at 21 m, so what the
    radar can see is judged on the scatterers, not on the reference point. Rows are the targets with
    scatterers within 24 m and :data:`SEEN_HALF_SECTOR_DEG`; ``in_beam`` marks those with scatterers
    inside the half-power beam (:data:`VISIBLE_HALF_BEAM_DEG`), which define the truth statistics.
    ``range_m`` is the range of the target's scatterers in the sector weighted by their echo power (radar
    equation with the antenna patterns, IF high-pass, road bounce; where its cluster's centroid should be),
    ``range_min_m``/``range_max_m`` their extent, and ``radial_speed_mps`` the radial speed of those scatterers at the
    target's velocity, weighted alike (where its cluster's Doppler should be).
    """

    id: np.ndarray  # (n,) int
    cls: tuple[str, ...]
    range_m: np.ndarray
    range_min_m: np.ndarray
    range_max_m: np.ndarray
    radial_speed_mps: np.ndarray
    in_beam: np.ndarray  # (n,) bool

    def __len__(self) -> int:
        return int(self.id.size)


def frame_view(scene: Scene, t_s: float, half_sector_deg: float = SEEN_HALF_SECTOR_DEG, board: Any = None) -> FrameView:
    """What of the scene is in the Distance2Go's view at ``t_s`` (see :class:`FrameView`); rows are the
    targets with scatterers within 24 m and ``half_sector_deg`` of boresight (180 = all round: the
    board's sidelobe floor sees a target passing beside it, or just behind it, at a few metres). ``board`` (a
    :class:`hw_sim.synth.SimBoard`; default :data:`hw_sim.boards.D2G_BOARD`) weights the scatterers by their echo
    power (:func:`hw_sim.synth.echo_power_w`)."""
    sc = scene.scatterers(t_s, np.random.default_rng(0))
    tix = sc.target_index
    site = np.array([tg.cls == "clutter" for tg in scene.targets] + [True])  # [-1]: static clutter
    mov = ~site[tix]
    if not mov.any():
        z = np.zeros(0)
        return FrameView(np.zeros(0, dtype=int), (), z, z, z, z, np.zeros(0, dtype=bool))
    rel = scene.pose.to_radar(sc.position_m[mov])
    rng = np.linalg.norm(rel, axis=1)
    az = np.abs(np.degrees(np.arctan2(rel[:, 0], rel[:, 1])))
    inv = (rng <= VISIBLE_RANGE_M) & (az <= half_sector_deg)
    k = tix[mov][inv]
    if k.size == 0:
        z = np.zeros(0)
        return FrameView(np.zeros(0, dtype=int), (), z, z, z, z, np.zeros(0, dtype=bool))
    if board is None:
        from hw_sim.boards import D2G_BOARD as board
    from hw_sim.synth import echo_power_w

    r = rng[inv]
    w = echo_power_w(board, scene.pose, sc.position_m[mov][inv], sc.rcs_m2[mov][inv])
    u = np.unique(k)
    idx = np.searchsorted(u, k)
    wsum = np.bincount(idx, w)
    wr = np.bincount(idx, w * r) / wsum
    rmin = np.full(u.size, np.inf)
    rmax = np.full(u.size, -np.inf)
    np.minimum.at(rmin, idx, r)
    np.maximum.at(rmax, idx, r)
    beam = np.bincount(idx, az[inv] <= VISIBLE_HALF_BEAM_DEG, minlength=u.size) > 0
    tr = scene.truth(t_s)
    by_id = {int(i): v for i, v in zip(tr.id, tr.velocity_mps)}
    ids = np.array([scene.targets[j].id for j in u], dtype=int)
    # each scatterer's radial speed at its target's velocity (the body's motion, not a wheel's spin), weighted as the
    # range: a long body whose reference point has passed the radar still shows its approaching rear
    vel = np.array([by_id[int(i)] for i in ids]).reshape(-1, 3)[idx]
    rel_w = sc.position_m[mov][inv] - scene.pose.position
    vr = np.einsum("ij,ij->i", rel_w, vel) / np.maximum(r, 1e-9)
    wv = np.bincount(idx, w * vr) / wsum
    return FrameView(ids, tuple(scene.targets[j].cls for j in u), wr, rmin, rmax, wv, beam)


@dataclass(frozen=True)
class TargetTruth:
    """What a passage of one target should produce (Tavanti Tables VIII-X)."""

    id: int
    event: int
    cls: str
    direction: str  # "approaching" | "receding"
    mean_radial_speed_kmh: float
    visible_frames: int
    first_frame: int
    last_frame: int


def event_truth(scene: Scene, period_s: float, n_frames: int, views: list[FrameView] | None = None) -> list[TargetTruth]:
    """Per-target truth over frames ``0..n_frames-1``: class, direction and mean radial speed while in view."""
    ids: dict[int, list[tuple[int, float]]] = {}
    cls: dict[int, str] = {}
    for n in range(n_frames):
        fv = views[n] if views is not None else frame_view(scene, n * period_s)
        for j in np.flatnonzero(fv.in_beam):
            tid = int(fv.id[j])
            ids.setdefault(tid, []).append((n, float(fv.radial_speed_mps[j])))
            cls[tid] = fv.cls[j]
    out = []
    for tid, rows in sorted(ids.items()):
        frames = np.array([r[0] for r in rows])
        v = float(np.mean([r[1] for r in rows])) * 3.6
        out.append(
            TargetTruth(
                id=tid, event=max(0, tid // 100 - 1), cls=cls[tid], direction="receding" if v > 0 else "approaching",
                mean_radial_speed_kmh=v, visible_frames=int(frames.size), first_frame=int(frames.min()),
                last_frame=int(frames.max()),
            )
        )
    return out


def register() -> None:
    """Register the table generators and event scenarios (idempotent)."""
    from hw_sim.scenario import EVENT_SCENARIOS, GENERATORS

    GENERATORS.setdefault("d2g_events", _d2g_events_table)
    GENERATORS.setdefault("d2g_target", _d2g_target_table)
    GENERATORS.setdefault("d2g_site", _d2g_site_table)  # after the events: its targets come last
    EVENT_SCENARIOS.setdefault("single-random", single_random)
    EVENT_SCENARIOS.setdefault("multi-random", multi_random)


register()
