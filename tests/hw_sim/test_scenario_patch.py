"""Scenario patches (the corpus's variants) and the [physics] table."""

import pytest

from hw_sim.physics import PRESETS, Physics, parse_physics, PhysicsError
from hw_sim.scenario import ScenarioError, apply_patch, load_scenario, patch_from_assignments


def test_apply_patch_merges_tables_sets_every_array_element_and_appends_arrays():
    raw = {"radar": {"height_m": 7.0, "tilt_deg": 1.5}, "traffic": [{"flow_veh_h": 900.0}, {"flow_veh_h": 300.0}],
           "clutter": [{"x_m": 1.0}]}
    out = apply_patch(raw, {"radar": {"height_m": 10.0}, "traffic": {"weave_sdlp_m": 0.2},
                            "clutter": [{"x_m": 2.0}], "physics": {"preset": "v1"}})
    assert out["radar"] == {"height_m": 10.0, "tilt_deg": 1.5}
    assert out["traffic"] == [{"flow_veh_h": 900.0, "weave_sdlp_m": 0.2}, {"flow_veh_h": 300.0, "weave_sdlp_m": 0.2}]
    assert out["clutter"] == [{"x_m": 1.0}, {"x_m": 2.0}]
    assert out["physics"] == {"preset": "v1"}
    assert raw["radar"]["height_m"] == 7.0 and len(raw["clutter"]) == 1  # the original is untouched


def test_assignments_become_a_patch_with_toml_values():
    p = patch_from_assignments(["radar.height_m=10", "physics.preset=v1", "radar.yaw_deg=-2.5", "x.flag=true"])
    assert p == {"radar": {"height_m": 10, "yaw_deg": -2.5}, "physics": {"preset": "v1"}, "x": {"flag": True}}
    with pytest.raises(ScenarioError, match="KEY=VALUE"):
        patch_from_assignments(["radar.height_m"])


def test_patched_scenario_changes_the_pose_and_keeps_the_rest():
    base = load_scenario("highway4-traffic")
    sc = load_scenario("highway4-traffic", {"radar": {"height_m": 10.0, "yaw_deg": 3.0}})
    assert (sc.pose.height_m, sc.pose.yaw_deg) == (10.0, 3.0)
    assert sc.pose.tilt_deg == base.pose.tilt_deg and sc.lanes == base.lanes


def test_physics_table_is_checked_by_name():
    assert parse_physics(None) == Physics()
    assert parse_physics({"preset": "v1"}).preset == "v1"
    with pytest.raises(PhysicsError, match="no_such_knob"):
        parse_physics({"no_such_knob": 1})
    with pytest.raises(PhysicsError, match="preset"):
        parse_physics({"preset": "v0"})
    with pytest.raises(ScenarioError, match="no_such_knob"):
        load_scenario("highway4", {"physics": {"no_such_knob": 1}})
    assert set(PRESETS) >= {"v1"}


def test_v1_preset_sets_every_field_it_names():
    v1 = parse_physics({"preset": "v1"})
    for key, val in PRESETS["v1"].items():
        assert getattr(v1, key) == (tuple(val) if isinstance(val, list) else val)
