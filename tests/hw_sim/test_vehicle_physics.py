"""Vehicle physics variants of hw_sim (issue 28): correlated glint, distributed RCS, shadowing, car-following
traffic, and the v1 preset reproducing the old instrument."""

from __future__ import annotations

import numpy as np
import pytest

from hw_sim.physics import PhysicsError, parse_physics
from hw_sim.scenario import load_scenario
from hw_sim.scene import GLINT_WAVELENGTH_M, RadarPose, Scene
from hw_sim.vehicles import BODY_TYPES, RoadTrajectory, make_vehicle

POSE = RadarPose(height_m=7.0, tilt_deg=1.5)


def _echo(glint: str, kind: str, n_frames: int = 120) -> np.ndarray:
    """Complex echo of one vehicle per 33 ms frame (sum over its scatterers, the bulk range phase of its reference
    point removed), approaching from 200 m in the outer lane at 100 km/h."""
    ph = parse_physics({"glint": glint})
    scene = Scene(POSE, seed=3, physics=ph)
    veh = make_vehicle(1, kind, RoadTrajectory(-5.25, 200.0, -1, (0.0,), (28.0,)), lane=0,
                       rng=np.random.default_rng(1), physics=ph)
    scene.add_target(veh)
    out = []
    for n in range(n_frames):
        t = n * 0.033
        s = scene.scatterers(t)
        r = np.linalg.norm(s.position_m - POSE.position, axis=1)
        r0 = np.linalg.norm(veh.trajectory.position(t) - POSE.position)
        cycles = s.phase_cycles + 2.0 * (r - r0) / GLINT_WAVELENGTH_M
        out.append(np.sum(np.sqrt(s.rcs_m2) * np.exp(2j * np.pi * cycles)))
    return np.asarray(out)


def _lag1(e: np.ndarray) -> tuple[float, float]:
    """Lag-1 correlation coefficient of the complex echo and of its power."""
    c = abs(np.vdot(e[:-1], e[1:])) / np.sqrt(np.vdot(e[:-1], e[:-1]).real * np.vdot(e[1:], e[1:]).real)
    p = np.abs(e) ** 2
    return float(c), float(np.corrcoef(p[:-1], p[1:])[0, 1])


@pytest.mark.parametrize("kind", ["car", "truck", "motorcycle"])
def test_aspect_glint_is_correlated_frame_to_frame_and_white_glint_is_not(kind):
    c_aspect, p_aspect = _lag1(_echo("aspect", kind))
    c_white, p_white = _lag1(_echo("white", kind))
    assert c_aspect > 0.7 and p_aspect > 0.5, (c_aspect, p_aspect)
    assert c_white < 0.25 and abs(p_white) < 0.25, (c_white, p_white)


def test_aspect_glint_keeps_the_mean_power_and_freezes_a_standing_vehicle():
    ph = parse_physics({})
    powers = np.abs(_echo("aspect", "car", 300)) ** 2
    assert 0.5 * 10.0 < powers.mean() < 2.0 * 10.0  # the class RCS on average (a few correlation widths)
    scene = Scene(POSE, seed=3, physics=ph)
    scene.add_target(make_vehicle(1, "car", RoadTrajectory(1.75, 80.0, 1, (0.0,), (0.0,)), lane=2,
                                  rng=np.random.default_rng(2), physics=ph))
    a, b = scene.scatterers(0.0), scene.scatterers(5.0)
    np.testing.assert_array_equal(a.phase_cycles, b.phase_cycles)
    np.testing.assert_array_equal(a.rcs_m2, b.rcs_m2)


@pytest.mark.parametrize("kind", list(BODY_TYPES))
@pytest.mark.parametrize("direction", [-1, 1])
def test_distributed_rcs_puts_the_echo_centre_behind_the_near_face(kind, direction):
    ph = parse_physics({})
    body = BODY_TYPES[kind]
    for length in body.length_m:
        v = make_vehicle(1, kind, RoadTrajectory(0.0, 100.0, direction, (0.0,), (20.0,)), lane=0,
                         rng=np.random.default_rng(0), length_m=length, physics=ph)
        assert v.rcs_m2.sum() == pytest.approx(body.rcs_m2)
        assert v.near_face_offset_m == pytest.approx(length / 2.0 * -direction)  # truth: the geometric near face
        behind = (v.near_face_offset_m - v.offsets_m[:, 1]) * np.sign(v.near_face_offset_m)
        assert behind.min() == pytest.approx(0.0, abs=1e-12)  # nothing in front of the near face
        w = v.rcs_m2 / v.rcs_m2.sum()
        assert 0.05 <= float(w @ behind) <= 0.3
        assert w[np.isclose(behind, 0.0)].sum() < 0.5
        assert np.unique(np.round(v.offsets_m[:, 2], 2)).size >= 3  # several heights
        assert v.centre_size_m is not None and v.centre_size_m.shape == v.rcs_m2.shape


def _truck_and_car_scene(shadowing: bool, car_x: float) -> Scene:
    """A 14 m truck 150 m out in the lane at x = -1.75 m and a car 25 m beyond it at ``car_x``, both at 25 m/s."""
    ph = parse_physics({"shadowing": shadowing})
    scene = Scene(POSE, seed=4, physics=ph)
    rng = np.random.default_rng(5)
    scene.add_target(make_vehicle(1, "truck", RoadTrajectory(-1.75, 150.0, -1, (0.0,), (25.0,)), lane=1, rng=rng,
                                  length_m=14.0, physics=ph))
    scene.add_target(make_vehicle(2, "car", RoadTrajectory(car_x, 175.0, -1, (0.0,), (25.0,)), lane=1, rng=rng,
                                  length_m=4.5, physics=ph))
    return scene


def _truck_and_car(shadowing: bool, car_x: float):
    s = _truck_and_car_scene(shadowing, car_x).scatterers(0.0)
    return s.rcs_m2[s.target_index == 0].sum(), s.rcs_m2[s.target_index == 1].sum()


def test_shadowing_attenuates_a_car_behind_a_truck():
    truck_on, car_on = _truck_and_car(True, -1.75)
    truck_off, car_off = _truck_and_car(False, -1.75)
    assert truck_on == pytest.approx(truck_off)  # the truck's own echo is not shadowed by the car
    assert 10.0 * np.log10(car_off / car_on) > 15.0  # the car, 11 m behind the truck's rear, lies in its shadow
    # a car beside the truck's lane, well clear of its shadow, keeps its echo
    _, car_beside_on = _truck_and_car(True, 5.25)
    _, car_beside_off = _truck_and_car(False, 5.25)
    assert car_beside_on == pytest.approx(car_beside_off)


def _truth_shadowed(shadowing: bool, car_x: float, make_scatterers: bool = True):
    scene = _truck_and_car_scene(shadowing, car_x)
    if make_scatterers:
        scene.scatterers(0.0)
    return scene.truth(0.0).shadowed_fraction


def test_truth_reports_the_shadowed_share_of_each_echo():
    """The truth of a frame carries the share of each target's echo that another body shadows (what the lane
    evaluation's detection_probability_visible leaves out): the car behind the truck nearly all, the truck none,
    a car beside the truck's lane none; zeros without shadowing; unknown when the frame's scatterers were not made."""
    sh = _truth_shadowed(True, -1.75)
    assert sh[0] == 0.0 and sh[1] > 0.9
    assert np.array_equal(_truth_shadowed(True, 5.25), [0.0, 0.0])
    assert np.array_equal(_truth_shadowed(False, -1.75), [0.0, 0.0])
    assert _truth_shadowed(True, -1.75, make_scatterers=False) is None


def test_physics_choices_are_checked():
    with pytest.raises(PhysicsError, match="glint"):
        parse_physics({"glint": "pink"})
    with pytest.raises(PhysicsError, match="traffic_model"):
        parse_physics({"traffic_model": "nagel"})
    with pytest.raises(PhysicsError, match="glint_vibration_s"):
        parse_physics({"glint_vibration_s": 0.0})
    v1 = parse_physics({"preset": "v1"})
    assert (v1.glint, v1.body, v1.shadowing, v1.traffic_model, v1.weave_sdlp_m, v1.lateral_offset_sd_m) == \
        ("white", "near-face", False, "v1", 0.0, 0.0)


#: scatterers of highway4-traffic (seed 7) at three instants, measured with the simulator before issue 28:
#: (t_s, count, sum of positions, rcs weighted by index, phase weighted by index, y velocity weighted by index)
V1_FINGERPRINT = (
    (0.0, 190, 30628.62053627396, 18639.5, 9027.577495747664, 72501.41979130375),
    (3.3, 207, 31960.008141110306, 24715.0, 10960.640416854998, 58627.391389240845),
    (17.016, 223, 35686.53219157155, 30156.5, 12344.160888379014, 69656.82285472998),
)


def test_v1_preset_reproduces_the_old_scatterers_exactly():
    scene = load_scenario("highway4-traffic", {"physics": {"preset": "v1"}}).build_scene()
    for t, n, pos, rcs, phase, vy in V1_FINGERPRINT:
        s = scene.scatterers(t)
        w = np.arange(1, s.rcs_m2.size + 1)
        assert s.rcs_m2.size == n
        assert float(s.position_m.sum()) == pytest.approx(pos, rel=1e-12)
        assert float((s.rcs_m2 * w).sum()) == pytest.approx(rcs, rel=1e-12)
        assert float((s.phase_cycles * w).sum()) == pytest.approx(phase, rel=1e-12)
        assert float((s.velocity_mps[:, 1] * w).sum()) == pytest.approx(vy, rel=1e-12)


FOUR_LANES = """
[scenario]
name = "t"
board = "simo"
duration_s = 300.0
seed = 11
[[lane]]
center_x_m = -5.25
[[lane]]
center_x_m = -1.75
[[lane]]
center_x_m = 1.75
direction = "away"
[[lane]]
center_x_m = 5.25
direction = "away"
[[traffic]]
flow_veh_h = 1200.0
speed_kmh_mean = 100.0
speed_kmh_sd = 15.0
min_headway_s = 1.5
range_m = 320.0
"""


def _four_lanes(extra: str = ""):
    import tomllib

    from hw_sim.scenario import parse_scenario

    return parse_scenario(tomllib.loads(FOUR_LANES + extra), "test")


def test_idm_traffic_keeps_safe_gaps_changes_lanes_and_keeps_truth_lanes():
    from hw_sim.vehicles import Vehicle

    sc = _four_lanes()
    scene = sc.build_scene()
    vehicles = [t for t in scene.targets if isinstance(t, Vehicle)]
    centres = np.array([ln.center_x_m for ln in sc.lanes])
    same_side = {0: {0, 1}, 1: {0, 1}, 2: {2, 3}, 3: {2, 3}}
    n_changes = sum(len(v.lane_switch) for v in vehicles)
    assert n_changes >= 10  # overtaking happens on both carriageways
    for v in vehicles:
        lanes = [v.lane] + [ln for _, ln in v.lane_switch]
        assert all(b in same_side[a] and abs(centres[b] - centres[a]) < 4.0 for a, b in zip(lanes, lanes[1:]))
    min_headway, min_gap, overtakes = np.inf, np.inf, 0
    order: dict[int, list[int]] = {}
    for t in np.arange(0.0, 300.0, 0.5):
        act = [v for v in vehicles if v.active(t)]
        pos = np.array([v.trajectory.position(t) for v in act])
        vel = np.array([v.trajectory.velocity(t) for v in act])
        lane = np.array([v.lane_at(t) for v in act])
        switching = np.array([any(abs(t - ts) < 0.05 for ts, _ in v.lane_switch) for v in act])
        nearest = np.argmin(np.abs(pos[:, :1] - centres[None, :]), axis=1)
        assert np.all((nearest == lane) | switching), t  # the truth lane is the lane the vehicle is in
        for ln in range(4):
            idx = np.flatnonzero(lane == ln)
            d = act[idx[0]].heading_sign if idx.size else 1
            o = idx[np.argsort(pos[idx, 1] * d)]
            for f, lead in zip(o[:-1], o[1:]):
                gap = (pos[lead, 1] - pos[f, 1]) * d - 0.5 * (act[lead].length_m + act[f].length_m)
                min_gap = min(min_gap, gap)
                if abs(vel[f, 1]) > 5.0:
                    min_headway = min(min_headway, gap / abs(vel[f, 1]))
        for side, lanes in ((1, (2, 3)), (-1, (0, 1))):
            ids = [act[i].id for i in np.argsort(pos[:, 1] * side) if lane[i] in lanes]
            prev = [i for i in order.get(side, []) if i in ids]
            overtakes += int([i for i in ids if i in prev] != prev)
            order[side] = ids
    assert min_gap > 0.0  # no collisions
    assert min_headway > 0.5, min_headway
    assert overtakes > 0  # the order along a carriageway changes (v1 traffic never overtakes)


def test_idm_traffic_is_deterministic_in_any_frame_order_and_weaves_by_default():
    sc = _four_lanes()
    a, b = sc.build_scene(), sc.build_scene()
    times = [0.0, 123.456, 17.0, 299.0]
    for ta, tb in zip(a.targets, b.targets):
        assert ta.id == tb.id and ta.lane_switch == tb.lane_switch
        fwd = [tuple(ta.trajectory.position(t)) + tuple(ta.trajectory.velocity(t)) for t in times]
        rev = [tuple(tb.trajectory.position(t)) + tuple(tb.trajectory.velocity(t)) for t in reversed(times)]
        assert fwd == rev[::-1]
        t = np.array(times)  # the vectorised and the one-instant evaluations agree
        assert np.allclose(ta.trajectory.position(t), [ta.trajectory.position(x) for x in times], atol=1e-9)
    # the physical defaults: every driver has an own offset and weaves (SDLP 0.2 m); a [[traffic]] key overrides
    defaults = parse_physics({})
    weaves = [t.trajectory.weave for t in a.targets]
    assert all(w is not None and w[0] == pytest.approx(defaults.weave_sdlp_m * 2 ** 0.5) for w in weaves)
    offsets = np.array([t.trajectory.x0_m - sc.lanes[t.lane].center_x_m for t in a.targets])
    assert np.std(offsets) == pytest.approx(defaults.lateral_offset_sd_m, rel=0.25)
    plain = _four_lanes("weave_sdlp_m = 0.0\nlateral_offset_sd_m = 0.0\n").build_scene()
    assert all(t.trajectory.weave is None and t.trajectory.x0_m == sc.lanes[t.lane].center_x_m for t in plain.targets)
