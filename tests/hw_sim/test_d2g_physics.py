"""Surveillance-site physics variants ([physics] gait, vehicle_lobes, wheels, site_clutter): each changes the
scatterers as documented, and the v1 preset keeps the old instrument."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from hw_sim.events import (
    FOLIAGE_BETA_S_PER_M,
    Foliage,
    SiteVehicle,
    make_target,
    panel_mean_gain,
    plate_lobe,
)
from hw_sim.pedestrian import BoulicPedestrian, Pedestrian
from hw_sim.physics import Physics, PhysicsError, parse_physics
from hw_sim.scenario import load_scenario_for_eval
from hw_sim.scene import LinearTrajectory

V1 = parse_physics({"preset": "v1"})


def _walker(v: float, height: float = 1.75, radar=(0.0, 0.0, 1.0)) -> BoulicPedestrian:
    return BoulicPedestrian.make(1, LinearTrajectory((1.0, 12.0, 0.0), (0.0, -v, 0.0)), total_rcs_m2=0.5,
                                 speed_mps=v, height_m=height, radar_m=radar)


@pytest.mark.parametrize("v", [1.0, 1.3, 1.7])
def test_boulic_micro_doppler_spread(v):
    """Torso at the walking speed, shank centres up to 2-3x and swing feet to 3-4.5x it, the cycle at
    Boulic's stride frequency (one period of every limb's speed)."""
    p = _walker(v)
    ts = np.arange(0.0, 4.0, 0.004)
    fwd = np.array([p.scatterers(t)[1][:, 1] for t in ts]) + v  # world speed along the walk (walking +y)
    assert fwd[:, 0].mean() == pytest.approx(v, rel=0.03)
    assert np.ptp(fwd[:, 0]) < 0.5 * v
    assert 2.0 * v <= fwd[:, 8:10].max() <= 3.0 * v  # shanks
    assert 3.0 * v <= fwd[:, 10:12].max() <= 4.5 * v  # feet
    assert fwd[:, 10:12].min() < 0.2 * v  # a foot stands (nearly) still in stance
    # the foot's speed repeats at the stride frequency: autocorrelation peak at one cycle, within 10 %
    x = fwd[:, 11] - fwd[:, 11].mean()
    ac = np.correlate(x, x, "full")[x.size - 1:]
    lag0 = int(0.5 / p.cycle_hz / 0.004)
    peak = (lag0 + int(np.argmax(ac[lag0: 3 * lag0]))) * 0.004
    assert 1.0 / peak == pytest.approx(p.cycle_hz, rel=0.1)
    # Boulic's cycle: 0.8-1.1 Hz at walking speeds
    assert 0.75 <= p.cycle_hz <= 1.1


def test_boulic_velocity_is_derivative_and_rcs_flashes():
    p = _walker(1.3)
    for t in (0.13, 0.61):
        o1, v = p.scatterers(t)
        o2, _ = p.scatterers(t + 1e-5)
        np.testing.assert_allclose((o2 - o1) / 1e-5, v, atol=2e-3)
    rcs = np.array([p.scatterers(t) and p.rcs_m2.copy() for t in np.arange(0, 2, 0.01)])
    assert rcs.sum(axis=1).max() <= 0.5 + 1e-9  # at most the standing person's frontal RCS
    legs = rcs[:, 6:10].sum(axis=1)
    assert legs.max() > 3.0 * legs.min()  # limbs flash as they swing through broadside


def test_gait_choice_in_make_target():
    traj = LinearTrajectory((1.0, 10.0, 0.0), (0.0, -1.3, 0.0))
    a = make_target("pedestrian", 1, traj, np.random.default_rng(1), t_start_s=0, t_end_s=9)
    b = make_target("pedestrian", 1, traj, np.random.default_rng(1), t_start_s=0, t_end_s=9, physics=V1)
    assert isinstance(a, BoulicPedestrian) and type(b) is Pedestrian
    # the stride frequency drawn as for v1 sets the walker's height, so its cycle is that stride (if adult)
    assert a.cycle_hz == pytest.approx(b.stride_hz, rel=0.1)


def _car(physics: Physics, radar=(0.0, 0.0, 1.0), v=(0.0, -8.0, 0.0), y0=12.0) -> SiteVehicle:
    t = make_target("car", 7, LinearTrajectory((3.0, y0, 0.0), v), np.random.default_rng(2), t_start_s=-1e9,
                    t_end_s=1e9, total_rcs_m2=10.0, physics=physics, radar_m=radar)
    assert isinstance(t, SiteVehicle)
    return t


def test_plate_lobe_shape():
    assert plate_lobe(np.array([1.0]), np.array([0.2]))[0] == pytest.approx(1.0)
    off = plate_lobe(np.cos(np.radians([5.0, 20.0, 60.0])), np.full(3, 0.2))
    assert np.all(off <= 0.06) and np.all(off >= 0.05 - 1e-12)  # the floor off specular
    assert plate_lobe(np.array([-0.5]), np.array([0.2]))[0] < 0.01  # facing away: hidden


def test_lobes_change_vehicle_rcs_with_aspect():
    """A car's front panels flash head-on and fall to the floor off-axis; broadside its doors flash."""
    phys = Physics(wheels=False)
    head_on = _car(phys, radar=(0.0, 0.0, 0.5), y0=20.0)  # radar straight ahead of the car's nose
    head_on.trajectory = LinearTrajectory((0.0, 20.0, 0.0), (0.0, -8.0, 0.0))
    head_on.scatterers(0.0)
    r_head = head_on.rcs_m2.sum()
    oblique = _car(phys, radar=(0.0, 0.0, 0.5))
    oblique.trajectory = LinearTrajectory((6.0, 12.0, 0.0), (0.0, -8.0, 0.0))  # ~27° off the nose
    oblique.scatterers(0.0)
    r_obl = oblique.rcs_m2.sum()
    side = _car(phys, radar=(0.0, 0.0, 0.6))
    side.trajectory = LinearTrajectory((3.0, 0.0, 0.0), (0.0, -8.0, 0.0))  # radar abeam the doors
    side.scatterers(0.0)
    doors = side.rcs_m2[np.abs(side.normals[:, 0]) > 0]
    base_doors = side._base_rcs[np.abs(side.normals[:, 0]) > 0]
    nose = 0  # the bumper's centre, a front panel
    assert head_on.rcs_m2[nose] == pytest.approx(head_on._base_rcs[nose], rel=1e-3)  # at its lobe's peak
    assert oblique.rcs_m2[nose] == pytest.approx(0.05 * oblique._base_rcs[nose])  # on the floor, 13 dB down
    assert r_head > r_obl
    # scatterers without a panel (wheel arches, mirrors, roof) keep their RCS at every aspect
    pts = ~np.any(oblique.normals != 0, axis=1)
    np.testing.assert_allclose(oblique.rcs_m2[pts], oblique._base_rcs[pts])
    assert doors.max() == pytest.approx(base_doors[np.argmax(doors)], rel=0.1)  # the near door at its peak
    iso = make_target("car", 7, LinearTrajectory((3.0, 12.0, 0.0), (0.0, -8.0, 0.0)), np.random.default_rng(2),
                      t_start_s=0, t_end_s=9, total_rcs_m2=10.0, physics=V1)
    assert type(iso).__name__ == "Target" and iso.rcs_m2.sum() == pytest.approx(10.0)  # v1: isotropic points


def test_panel_mean_gain_is_the_lobes_mean_over_incidence():
    for L in (0.08, 0.25):
        th = np.radians(np.linspace(0.0, 90.0, 100001))
        assert panel_mean_gain(np.array([L]))[0] == pytest.approx(plate_lobe(np.cos(th), np.full(th.size, L)).mean(),
                                                                  rel=1e-3)
    # the floor dominates: the panels' few-degree lobes add a little over it
    g = panel_mean_gain(np.array([0.08, 0.25]))
    assert np.all((g > 0.05) & (g < 0.08)) and g[0] > g[1]


@pytest.mark.parametrize("cls", ["car", "truck"])
def test_a_vehicles_rcs_is_its_mean_over_aspect(cls):
    """The class RCS is the target's mean over aspect: each panel's specular peak is its share over the lobe's mean
    gain, so the lobes redistribute the echo over aspect instead of removing it (a car kept 0.39 of its RCS on
    average and a truck 0.13 when the share was the peak)."""
    def make(physics):
        return make_target(cls, 7, LinearTrajectory((3.0, 12.0, 0.0), (0.0, -8.0, 0.0)), np.random.default_rng(4),
                           t_start_s=-1e9, t_end_s=1e9, total_rcs_m2=10.0, physics=physics)

    t = make(Physics(wheels=False))
    share = make(Physics(wheels=False, vehicle_lobes=False)).rcs_m2  # the same body without lobes
    panel = np.any(t.normals != 0.0, axis=1)
    assert panel.sum() >= 4
    base = t._base_rcs
    np.testing.assert_allclose(base[~panel], share[~panel])
    gain = panel_mean_gain(t.panel_m[panel])
    np.testing.assert_allclose(base[panel] * gain, share[panel])  # the peak, 11-13 dB over the share
    assert base[~panel].sum() + (base[panel] * gain).sum() == pytest.approx(10.0)


def test_wheels_span_zero_to_twice_the_speed():
    v = 8.0
    car = _car(Physics(vehicle_lobes=False), v=(0.0, -v, 0.0))
    nb = car._n_body
    speeds = []
    for t in np.arange(0.0, 0.5, 0.002):
        _, vel = car.scatterers(t)
        speeds.append(np.linalg.norm(vel[nb:] + np.array([0.0, -v, 0.0]), axis=1))
    s = np.array(speeds)
    assert s.min() < 0.05 * v and s.max() > 1.95 * v and s.max() <= 2.0 * v + 1e-9
    assert np.all(np.linalg.norm(car.scatterers(0.0)[1][:nb], axis=1) == 0.0)  # the body is rigid
    # the wheels take half the arch points' RCS: the total is kept
    assert car.rcs_m2.sum() == pytest.approx(10.0)


def _urban_scene(seed=3):
    sc = load_scenario_for_eval("single-random", events=4)
    return sc.build_scene(seed)


def test_swaying_foliage_has_doppler_spread_static_clutter_none():
    scene = _urban_scene()
    leaves = [t for t in scene.targets if isinstance(t, Foliage)]
    assert len(leaves) >= 3
    v = np.concatenate([np.concatenate([f.scatterers(t)[1] for f in leaves]) for t in np.arange(0, 20, 0.2)])
    speed = np.linalg.norm(v, axis=1)
    rms = math.sqrt(float(np.mean(speed**2)))
    assert 0.5 * math.sqrt(2) / FOLIAGE_BETA_S_PER_M <= rms <= 2.0 * math.sqrt(2) / FOLIAGE_BETA_S_PER_M
    assert 0.1 <= np.percentile(speed, 95) <= 0.6
    # poles, posts, the wall and parked cars are static clutter: no velocity in the scatterer set
    sc = scene.scatterers(1.0)
    stat = sc.target_index == -1
    assert stat.sum() > 50 and np.all(sc.velocity_mps[stat] == 0.0)
    # deterministic per seed, different across seeds
    again = _urban_scene()
    np.testing.assert_array_equal(again.scatterers(2.0).position_m, scene.scatterers(2.0).position_m)
    other = _urban_scene(4)
    assert not np.array_equal(other.clutter.position_m, scene.clutter.position_m)


def test_site_clutter_v1_adds_nothing_and_keeps_events():
    phys = {"physics": {"site_clutter": "v1"}}
    v1 = load_scenario_for_eval("single-random", events=4, patch=phys).build_scene(3)
    urban = _urban_scene()
    assert v1.clutter.rcs_m2.size == 7 and urban.clutter.rcs_m2.size > 50
    ev = [(t.id, t.trajectory.p0, t.t_start_s) for t in urban.targets if t.cls != "clutter"]
    assert ev == [(t.id, t.trajectory.p0, t.t_start_s) for t in v1.targets]


def _scatterer_digest(physics_patch) -> str:
    h = hashlib.sha256()
    for name, ev in (("single-random", 4), ("multi-random", 2), ("tavanti-test1", None)):
        sc = load_scenario_for_eval(name, events=ev, patch=physics_patch)
        scene = sc.build_scene(3)
        for t in np.arange(0.0, min(sc.duration_s, 40.0), 0.6):
            s = scene.scatterers(float(t), np.random.default_rng([3, int(t * 10)]))
            for a in (s.position_m, s.velocity_mps, s.rcs_m2, s.phase_cycles):
                h.update(np.round(a, 9).tobytes())
    return h.hexdigest()


def test_v1_preset_reproduces_the_old_scatterers():
    """Digest of the v1 scatterers (positions, velocities, RCS, phases, to 1e-9) of the D2G site scenarios,
    recorded on main before the surveillance physics variants; the I/Q frames were checked bit-exact too."""
    assert _scatterer_digest({"physics": {"preset": "v1"}}) == V1_DIGEST
    assert _scatterer_digest(None) != V1_DIGEST


def test_physics_choices_validated():
    with pytest.raises(PhysicsError):
        parse_physics({"gait": "moonwalk"})
    with pytest.raises(PhysicsError):
        parse_physics({"site_clutter": "forest"})
    assert V1.gait == "sinusoid" and not V1.vehicle_lobes and not V1.wheels and V1.site_clutter == "v1"
    d = Physics()
    assert d.gait == "boulic" and d.vehicle_lobes and d.wheels and d.site_clutter == "urban"


V1_DIGEST = "907f7e9704663d9ff3e212e704aa641a54a271e74d58c71a120163d2c6621745"
