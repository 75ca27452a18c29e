"""Road-traffic realism of hw_sim: vehicles, trajectories, random traffic, clutter, fast synthesis."""

from __future__ import annotations

import dataclasses
import tomllib

import numpy as np
import pytest

from hw_sim import SIMO_BOARD, FrameSimulator, RadarPose
from hw_sim.physics import parse_physics
from hw_sim.scenario import ScenarioError, builtin_names, load_scenario, parse_scenario
from hw_sim.scene import CLASSES, ScattererSet
from hw_sim.synth import synthesize_if
from hw_sim.vehicles import BODY_TYPES, RoadTrajectory, Vehicle, make_vehicle

LANES = """
[[lane]]
center_x_m = -5.25
[[lane]]
center_x_m = -1.75
[[lane]]
center_x_m = 1.75
direction = "away"
"""


def _scenario(body: str, duration_s: float = 10.0):
    text = f'[scenario]\nname = "t"\nboard = "simo"\nduration_s = {duration_s}\nseed = 2\n' + LANES + body
    return parse_scenario(tomllib.loads(text), "test")


def test_fast_synthesis_matches_the_reference_synthesis():
    rng = np.random.default_rng(0)
    k = 40
    scat = ScattererSet(
        np.c_[rng.uniform(-8, 8, k), rng.uniform(5, 300, k), rng.uniform(0, 2, k)],
        np.c_[rng.uniform(-2, 2, k), rng.uniform(-40, 40, k), np.zeros(k)],
        rng.uniform(0.5, 20, k), rng.random(k), np.zeros(k, int))
    pose = RadarPose(height_m=7.0, tilt_deg=1.5, yaw_deg=2.0)
    board = dataclasses.replace(SIMO_BOARD, channel_gain=(1.0, 0.9j, 1.1, -1.0))
    fast = synthesize_if(board, pose, scat, 0.4, np.random.default_rng(1), noise=False)
    ref = synthesize_if(dataclasses.replace(board, fast_synthesis=False), pose, scat, 0.4, np.random.default_rng(1), noise=False)
    assert SIMO_BOARD.fast_synthesis
    assert np.max(np.abs(fast - ref)) < 2e-3 * np.max(np.abs(ref))


def test_vehicle_scatterers_put_most_rcs_on_the_face_towards_the_radar():
    rng = np.random.default_rng(1)
    v1 = parse_physics({"preset": "v1"})  # figure measured on the v1 instrument; the corpus reports the physical defaults
    for kind, body in BODY_TYPES.items():
        for d in (-1, 1):
            v = make_vehicle(1, kind, RoadTrajectory(0.0, 100.0, d, (0.0,), (20.0,)), lane=0, rng=rng, physics=v1)
            assert v.cls in CLASSES
            assert body.length_m[0] <= v.length_m <= body.length_m[1]
            assert v.rcs_m2.sum() == pytest.approx(body.rcs_m2)
            near = np.isclose(v.offsets_m[:, 1], v.near_face_offset_m)
            assert v.rcs_m2[near].sum() >= 0.69 * body.rcs_m2
            # the near face is the vehicle's nearest point to a radar at y = 0
            ys = 100.0 + (v.offsets_m @ v.heading_rotation(0.0).T)[:, 1]
            assert np.argmin(ys) in np.flatnonzero(near)


def test_road_trajectory_stop_and_go_and_lane_change():
    sc = _scenario("""
[[vehicle]]
id = 1
lane = 0
y_m = 100.0
speed_kmh = 72.0
stop_at_s = 1.0
decel_mps2 = 4.0
stop_s = 2.0
accel_mps2 = 2.0
lane_change_to = 1
lane_change_at_s = 12.0
lane_change_duration_s = 2.0
""")
    scene = sc.build_scene()
    v: Vehicle = scene.targets[0]
    t = np.array([0.0, 1.0, 6.0, 7.5, 20.0])
    vel = v.trajectory.velocity(t)
    assert vel[0, 1] == pytest.approx(-20.0) and vel[1, 1] == pytest.approx(-20.0)
    assert np.allclose(v.trajectory.velocity(np.array([6.1, 7.9])), 0.0)  # standing 6..8 s (1 + 20/4 = 6)
    assert vel[4, 1] == pytest.approx(-20.0)
    p = v.trajectory.position(np.array([0.0, 1.0, 6.0, 8.0]))
    assert p[0, 1] == pytest.approx(100.0)
    assert p[1, 1] == pytest.approx(80.0)
    assert p[2, 1] == pytest.approx(80.0 - 20.0**2 / (2 * 4.0))  # braking distance
    assert p[3, 1] == pytest.approx(p[2, 1])
    # lane change 12..14 s, from lane 0 to lane 1; the truth lane switches at the midpoint
    x = v.trajectory.position(np.array([11.9, 13.0, 14.1]))[:, 0]
    assert x[0] == pytest.approx(-5.25) and x[1] == pytest.approx(-3.5) and x[2] == pytest.approx(-1.75)
    assert scene.truth(12.9).lane[0] == 0 and scene.truth(13.1).lane[0] == 1
    # numerical derivative of the position is the velocity
    tt = np.linspace(0, 12, 400)
    num = np.gradient(v.trajectory.position(tt), tt, axis=0)
    assert np.max(np.abs(num[1:-1] - v.trajectory.velocity(tt)[1:-1])) < 0.3


def test_random_traffic_flow_speeds_no_overtaking_and_determinism():
    # the v1 traffic model (platoons without overtaking); the IDM's test is in test_vehicle_physics.py
    sc = _scenario("""
[physics]
preset = "v1"
[[traffic]]
flow_veh_h = 1200.0
speed_kmh_mean = 100.0
speed_kmh_sd = 15.0
min_headway_s = 1.5
range_m = 320.0
""", duration_s=1800.0)
    scene = sc.build_scene()
    again = sc.build_scene()
    assert [t.id for t in scene.targets] == [t.id for t in again.targets]
    assert all(a.length_m == b.length_m for a, b in zip(scene.targets, again.targets))
    for lane in range(3):
        veh = [t for t in scene.targets if t.lane == lane and t.t_start_s >= 0.0]
        assert len(veh) == pytest.approx(1200 * 0.5, rel=0.1)  # half an hour at 1200 veh/h
        speeds = np.array([abs(t.trajectory.speed_mps[0]) for t in veh]) * 3.6
        # followers that would catch up take their leader's speed: platoons behind slow vehicles (no
        # overtaking in this model), so the mean lies between the minimum and the configured mean
        assert 40.0 <= speeds.min() and speeds.mean() < 100.0 and speeds.max() > 110.0
        starts = np.array([t.t_start_s for t in veh])
        assert np.all(np.diff(starts) >= 1.5 - 1e-9)
        # no overtaking: order along the road is the entry order at any time
        for tq in (300.0, 900.0, 1500.0):
            act = [t for t in veh if t.active(tq)]
            y = np.array([t.trajectory.position(tq)[1] for t in act])
            d = -1 if sc.lanes[lane].direction == "toward" else 1
            assert np.all(np.diff(y) * d < 0)
    kinds = {t.kind for t in scene.targets}
    assert {"car", "truck"} <= kinds


def test_guardrail_and_multipath_ghosts():
    sc = _scenario("""
[[vehicle]]
id = 1
lane = 0
y_m = 100.0
[[guardrail]]
x_m = -7.5
y_from_m = 10.0
y_to_m = 50.0
spacing_m = 10.0
[[multipath]]
plane_x_m = -7.5
loss_db = 10.0
""")
    scene = sc.build_scene()
    assert scene.clutter.rcs_m2.size == 5
    ghost = [t for t in scene.targets if t.cls == "clutter"]
    assert len(ghost) == 1 and ghost[0].lane is None
    assert ghost[0].trajectory.position(0.0)[0] == pytest.approx(-9.75)
    assert ghost[0].rcs_m2.sum() == pytest.approx(0.1 * scene.targets[0].rcs_m2.sum())


def test_schema_errors_name_the_key():
    with pytest.raises(ScenarioError, match="lane"):
        _scenario("[[vehicle]]\nid = 1\nlane = 9\ny_m = 10.0\n")
    with pytest.raises(ScenarioError, match="kind"):
        _scenario("[[vehicle]]\nid = 1\nlane = 0\nkind = \"tank\"\ny_m = 10.0\n")
    with pytest.raises(ScenarioError, match="mix"):
        _scenario("[[traffic]]\nmix = { tank = 1.0 }\n")


@pytest.mark.parametrize("name", ["highway4-traffic", "crossing", "side-by-side", "stop-and-go"])
def test_builtin_lane_scenarios_load_and_synthesize(name):
    assert name in builtin_names()
    sc = load_scenario(name)
    sim = FrameSimulator(SIMO_BOARD, sc.build_scene(), sc.seed)
    f = sim.frame(3)
    assert f.i.dtype == np.int16 and f.i.shape == SIMO_BOARD.frontend.frame_shape
    assert len(f.truth) >= 1
    assert set(f.truth.cls) <= set(CLASSES)


def test_simo_antennas_have_a_front_to_back_ratio():
    """A vehicle behind the overpass must not come back through the sidelobe floor: 30 dB down behind,
    the sidelobe floor to the sides, unchanged in front."""
    from hw_sim.radio import SIMO_RADIO

    for ant in (SIMO_RADIO.tx, SIMO_RADIO.rx):
        g = 10 * np.log10(ant.gain_linear(np.radians([0.0, 60.0, 170.0]), np.zeros(3))) - ant.gain_dbi
        assert g[0] == pytest.approx(0.0)
        assert g[1] == pytest.approx(-ant.sidelobe_db)
        assert g[2] == pytest.approx(-30.0)


def test_overpass_deck_hides_what_is_behind_the_radar():
    """occluded_behind: scatterers behind the vertical plane of the radar's face are not seen (a truck that has
    passed under the bridge came back through the 30 dB backlobe as a receding vehicle in front of the radar,
    a false track driving the wrong way once the leakage no longer masked near-zero beats); truth keeps them."""
    import numpy as _np

    from hw_sim.scenario import load_scenario
    from hw_sim.scene import LinearTrajectory, RadarPose, Scene, Target

    assert load_scenario("highway4").pose.occluded_behind
    for yaw in (0.0, 3.0):
        for occluded in (False, True):
            sc = Scene(RadarPose(height_m=7.0, tilt_deg=1.5, yaw_deg=yaw, occluded_behind=occluded), seed=1)
            for tid, y in ((1, -12.0), (2, 40.0)):
                sc.add_target(Target(tid, "truck", LinearTrajectory((-1.75, y, 1.0), (0.0, -22.0, 0.0)),
                                     _np.zeros((1, 3)), _np.array([40.0])))
            scat = sc.scatterers(0.0)
            seen = sorted(sc.targets[k].id for k in scat.target_index)
            assert seen == ([2] if occluded else [1, 2]), (yaw, occluded, seen)
            assert len(sc.truth(0.0)) == 2


def test_wrong_way_traffic_places_its_six_drivers_as_described():
    """wrong-way-traffic: one wrong-way driver every 40 s from 60 s on, those of the receding lanes (2, 3) coming
    towards the radar from 380 m out, those of the approaching lanes (0, 1) driving away from under the bridge;
    the random traffic's ids do not collide with theirs."""
    sc = load_scenario("wrong-way-traffic")
    scene = sc.build_scene(1)
    ids = [t.id for t in scene.targets]
    assert len(ids) == len(set(ids))
    by = {t.id: t for t in scene.targets}
    for n, vid in enumerate(range(9001, 9007)):
        v = by[vid]
        t = 60.0 + 40.0 * n + 0.5
        lane = v.lane_at(t)
        vy = v.trajectory.velocity(t)[1]
        y = v.near_face_point(t)[1] - sc.pose.y_m
        direction = sc.lanes[lane].direction
        assert (vy > 0) != (direction == "away")  # against its lane
        assert (345.0 < y < 380.0) if direction == "away" else (0.0 < y < 20.0)
        assert v.t_start_s == pytest.approx(t - 0.5) and v.t_end_s > t + 10.0


def test_a_standing_vehicle_keeps_its_scattering_phases():
    """Moving, a vehicle's glint decorrelates from frame to frame (new scattering phases); standing still (a
    breakdown, engine off) its phases stay fixed: a static echo. The other targets' draws do not change with it."""
    sc = load_scenario("stop-and-go")
    scene = sc.build_scene()
    car = next(t for t in scene.targets if t.id == 1)
    k = scene.targets.index(car)

    def phases(t):
        s = scene.scatterers(t)
        return s.phase_cycles[s.target_index == k], s.phase_cycles[s.target_index != k]

    assert np.linalg.norm(car.trajectory.velocity(7.0)) < 0.05 and np.linalg.norm(car.trajectory.velocity(0.5)) > 10
    standing_a, others_a = phases(7.0)
    standing_b, others_b = phases(7.033)
    assert np.array_equal(standing_a, standing_b)
    moving_a, _ = phases(0.5)
    moving_b, _ = phases(0.533)
    assert not np.array_equal(moving_a, moving_b)
    assert not np.array_equal(others_a, others_b)  # the truck moves on


def test_drivers_keep_their_own_offset_and_weave_inside_the_lane():
    """lateral_offset_sd_m and weave_sdlp_m: the same vehicles (ids, kinds, lengths, entry times, speeds) as without
    them, each off its lane centre by its own offset (spread as configured) and wandering around it with the
    configured SDLP; the velocity is the position's derivative; bad values are refused by name."""
    # figure measured on the v1 instrument; the corpus reports the physical defaults
    v1 = '[physics]\npreset = "v1"\n'
    plain = _scenario(v1 + "[[traffic]]\nflow_veh_h = 1200.0\n", duration_s=600.0).build_scene()
    sc = _scenario(v1 + "[[traffic]]\nflow_veh_h = 1200.0\nlateral_offset_sd_m = 0.2\nweave_sdlp_m = 0.18\n",
                   duration_s=600.0)
    scene = sc.build_scene()
    assert [(t.id, t.kind, t.length_m, t.t_start_s, t.trajectory.speed_mps) for t in scene.targets] == \
        [(t.id, t.kind, t.length_m, t.t_start_s, t.trajectory.speed_mps) for t in plain.targets]
    offsets, sdlp = [], []
    for veh in scene.targets:
        centre = sc.lanes[veh.lane].center_x_m
        t = np.linspace(veh.t_start_s, veh.t_end_s, 400)
        x = veh.trajectory.position(t)[:, 0] - centre
        assert np.abs(x).max() < 0.2 * 2.5 + 0.18 * 2**0.5 + 1e-9  # inside its lane (3.5 m wide)
        offsets.append(veh.trajectory.x0_m - centre)
        sdlp.append(x.std())
        vx = veh.trajectory.velocity(t)[:, 0]
        mid = 0.5 * (t[1:] + t[:-1])
        assert np.interp(mid, t, vx) == pytest.approx(np.diff(x) / np.diff(t), abs=2e-3)
    assert len(offsets) > 500
    assert np.std(offsets) == pytest.approx(0.2, rel=0.1)
    # a vehicle in view for 12-20 s sees one or two of its 8-20 s periods: its own sd scatters around the SDLP
    assert np.median(sdlp) == pytest.approx(0.18, rel=0.15)
    assert all(t.trajectory.x0_m == sc.lanes[t.lane].center_x_m for t in plain.targets)
    with pytest.raises(ScenarioError, match="weave_period_s"):
        _scenario("[[traffic]]\nweave_sdlp_m = 0.2\nweave_period_s = [5.0]\n")
    with pytest.raises(ScenarioError, match="lateral_offset_sd_m"):
        _scenario("[[traffic]]\nlateral_offset_sd_m = -1.0\n")
