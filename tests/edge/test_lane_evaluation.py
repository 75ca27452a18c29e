"""Seeded end-to-end smoke test of ``radar-edge evaluate`` for the lane profile (a short highway4 run)."""

from __future__ import annotations

import json

import pytest
from pathlib import Path

from edge.cli import main
from edge.config import load_config
from edge.evaluation.lane import NEAR_M, _TargetAcc, _near_count, _rmse_within, _vehicle_rmse_tallies, evaluate
from hw_sim.scenario import load_scenario

V1 = {"physics": {"preset": "v1"}}  # the v1 instrument (hw_sim.physics.PRESETS)


def test_highway4_short_run_meets_accuracy_floor():
    """150 frames (5 s) of highway4: six point vehicles 20-260 m, Swerling I.

    Thresholds: Lim Table 3 reports 0.08-0.14 m RMSE; our mean over 10 s on seeds 1-3 is 0.12-0.13 m
    with the far cars dominating, so 0.25 m leaves room for the shorter run but catches a biased range
    or angle (a tenth of a degree of bias at 200 m is 0.35 m). Speed error of a good pairing is below
    0.2 km/h; 1 km/h is the issue's acceptance figure. Swerling I fading of these point targets and the
    tracker's 5-of-7 confirmation limit the tracked fraction (0.94-0.97 over 10 s); 0.85 catches a
    broken detection chain or tracker hand-over.
    """
    # figure measured on the v1 instrument; the corpus reports the physical defaults
    rep = evaluate(load_scenario("highway4", V1), seed=11, frames=150, config=load_config(env={}))
    s = rep["summary"]
    assert rep["profile"] == "lane" and rep["frames"] == 150 and len(rep["targets"]) == 6
    assert s["detection_probability"] >= 0.85
    assert s["position_rmse_m_mean"] <= 0.25
    assert s["speed_mae_kmh"] <= 1.0
    assert s["id_switches"] == 0
    assert s["lane_accuracy"] >= 0.98
    assert s["false_tracks"] == 0
    for key in ("p50", "p99", "budget"):
        assert rep["frame_time_ms"][key] > 0
    for t in rep["targets"]:
        assert t["direction_true"] == t["direction_est"]
    # per vehicle over its assigned frames: their mean weighted by those frames is the overall lane accuracy
    n = [round(t["frames_in_view"] * t["tracked_fraction"]) for t in rep["targets"]]
    assert sum(k * t["lane_accuracy"] for k, t in zip(n, rep["targets"])) / sum(n) == pytest.approx(s["lane_accuracy"])
    # per class and range: the same assigned frames regrouped, so the overall value lies between the classes'
    by_cls = s["detection_probability_by_class"]
    assert set(by_cls) == {t["class"] for t in rep["targets"]}
    assert min(by_cls.values()) <= s["detection_probability"] <= max(by_cls.values())
    for c, bins in s["detection_probability_by_class_and_range"].items():
        assert set(bins) <= set(s["detection_probability_by_range"]) and c in by_cls
    assert s["false_track_episodes"] == []
    # the untracked frames split by phase: the three add up to the untracked frames, and the vehicles entering
    # the view during the run (all six start inside it) need a few frames to confirm, so some are before_first
    by_phase = {c: [0, 0, 0] for c in by_cls}
    for t in rep["targets"]:
        u = t["untracked_frames"]
        assert min(u.values()) >= 0
        assert sum(u.values()) == round(t["frames_in_view"] * (1 - t["tracked_fraction"]))
        by_phase[t["class"]] = [a + b for a, b in zip(by_phase[t["class"]], u.values())]
    assert {c: list(v.values()) for c, v in s["untracked_frames_by_class"].items()} == by_phase
    assert sum(v[0] for v in by_phase.values()) > 0
    # per vehicle within each 50 m of range: the last step holds all its assigned frames, so it is its whole-time
    # figure; the summary's per-step figure is the worst vehicle's
    worst: dict[str, float] = {}
    for t in rep["targets"]:
        w = t["position_rmse_m_within"]
        assert w[max(w, key=float)] == pytest.approx(t["position_rmse_m"])
        for k, v in w.items():
            worst[k] = max(worst.get(k, 0.0), v)
    assert s["position_rmse_m_max_within"] == pytest.approx(worst)


def test_vehicle_rmse_tallies_weigh_each_vehicle_once():
    """Each vehicle's own RMSE within 200 m, summed with their number: 12 frames of error 1 m (and 3 beyond 200 m,
    left out) and 10 frames of 2 m count; a vehicle with 5 frames within 200 m does not."""
    a, b, c = _TargetAcc("car"), _TargetAcc("motorcycle"), _TargetAcc("truck")
    a.sq_err, a.err_rng = [1.0] * 12 + [100.0] * 3, [150.0] * 12 + [250.0] * 3
    b.sq_err, b.err_rng = [4.0] * 10, [190.0] * 10
    c.sq_err, c.err_rng = [9.0] * 5, [50.0] * 5
    t = _vehicle_rmse_tallies({1: a, 2: b, 3: c})
    assert t == {"position_vehicle_rmse_sum_m": pytest.approx(3.0), "position_vehicles": 2}


def test_rmse_within_range_steps_is_cumulative():
    """Squared errors 1, 4, 9 at 10, 60 and 260 m: within 50 m the first alone, from 100 m to 250 m the first two,
    within 300 m all three."""
    w = _rmse_within([1.0, 4.0, 9.0], [10.0, 60.0, 260.0])
    assert list(w) == ["50", "100", "150", "200", "250", "300"]
    assert w["50"] == pytest.approx(1.0)
    assert w["100"] == w["150"] == w["200"] == w["250"] == pytest.approx((2.5) ** 0.5)
    assert w["300"] == pytest.approx((14.0 / 3.0) ** 0.5)
    assert _rmse_within([], []) == {}


def test_evaluate_command_writes_design_keys(tmp_path, capsys):
    out = tmp_path / "r.json"
    rc = main(["evaluate", "--scenario", "single-car", "--frames", "30", "--json", str(out), "--no-progress"])
    assert rc == 0
    d = json.loads(out.read_text())
    for k in ("scenario", "profile", "seed", "frames", "targets", "summary", "frame_time_ms"):
        assert k in d
    for k in ("position_rmse_m_mean", "speed_mae_kmh", "detection_probability", "false_tracks_per_min",
              "id_switches", "lane_accuracy", "count_error_per_lane", "classification_accuracy", "confusion_matrix"):
        assert k in d["summary"]
    assert d["summary"]["classification_accuracy"] is None


def test_side_by_side_is_resolved_into_two_tracks_by_angle():
    """Two cars at equal range and speed in adjacent lanes, 90 frames (3 s, 120 -> 45 m). One peak per
    segment holds both; the per-cell covariance over frames resolves them (edge.lane.resolve). Measured on
    seeds 3, 8, 21: tracked fractions 0.67-0.82 (the first ~15 frames are needed to resolve them), lane
    accuracy 1.0; without the resolver one car is tracked in 0.27-0.32 of the frames, with a track
    between the lanes (RMSE 1.3-1.7 m)."""
    # figure measured on the v1 instrument; the corpus reports the physical defaults
    rep = evaluate(load_scenario("side-by-side", V1), seed=8, frames=90, config=load_config(env={}))
    fr = sorted(t["tracked_fraction"] for t in rep["targets"])
    assert len(fr) == 2 and fr[0] >= 0.6
    assert rep["summary"]["lane_accuracy"] >= 0.95
    assert {t["lane"] for t in rep["targets"]} == {0, 1}
    assert all(t["position_rmse_m"] < 1.2 for t in rep["targets"])
    # the evaluator's overlap diagnosis sees the pair as one range-Doppler cell in one beam throughout
    assert rep["summary"]["detection_probability_by_overlap"]["car"]["overlapping_fraction"] == 1.0


def test_wrong_way_alarms_are_scored_against_the_truth():
    """``wrong-way``: one car drives against lane 2 among normal traffic; the alarm must follow it (and
    no other vehicle). ``highway4-misaimed`` (radar 3 deg off, yaw 0 configured): no vehicle drives the
    wrong way, and while the yaw self-calibrates a far car can sit in the neighbouring, opposite lane --
    which raised false alarms (seed 1: frames 18, 23, 30) before the wrong-way gate."""
    s = evaluate(load_scenario("wrong-way"), config=load_config(env={}))["summary"]
    ww = s["wrong_way"]
    assert {k: ww[k] for k in ("drivers", "alarms", "correct", "false", "missed")} == {
        "drivers": 1, "alarms": 1, "correct": 1, "false": 0, "missed": 0}
    # the car is in view from 200 m; the yaw self-calibrates first (8 s of traffic): the alarm comes late and near
    assert len(ww["delay_s"]) == len(ww["alarm_range_m"]) == 1
    assert 0.5 < ww["delay_s"][0] < 8.0 and 10.0 < ww["alarm_range_m"][0] < 200.0
    # crossing the detection line against lane 2, the driver is an event and not part of the lane's volume
    assert s["count_error_per_lane"][2] == 0
    assert all(m["vehicle_id"] != 1 for m in s["count_mismatches"]["missed"])
    s = evaluate(load_scenario("highway4-misaimed"), seed=1, frames=120, config=load_config(env={}))["summary"]
    assert s["wrong_way"] == {"drivers": 0, "alarms": 0, "correct": 0, "false": 0, "missed": 0, "delay_s": [],
                              "alarm_range_m": []}


def test_count_mismatches_pair_crossings_by_time_per_lane():
    from edge.evaluation.counting import count_mismatches as _count_mismatches

    true = [(0, 10.0, 1, "car"), (0, 20.0, 2, "truck"), (1, 30.0, 3, "car"), (1, 40.0, 4, "car")]
    meas = [(0, 10.3, 90.0), (0, 20.1, 80.0), (0, 20.2, 70.0), (1, 30.5, 95.0), (2, 40.0, 99.0)]
    got = _count_mismatches(true, meas, 3)
    # lane 0: the 20.2 s crossing is the second of one vehicle; lane 1: vehicle 4 missed; lane 2: one extra
    assert got["missed"] == [{"lane": 1, "t_s": 40.0, "vehicle_id": 4, "class": "car"}]
    assert got["extra"] == [{"lane": 0, "t_s": 20.2, "speed_kmh": 70.0}, {"lane": 2, "t_s": 40.0, "speed_kmh": 99.0}]
    assert _count_mismatches([(0, 10.0, 1, "car")], [(0, 12.5, 90.0)], 1) == {
        "missed": [{"lane": 0, "t_s": 10.0, "vehicle_id": 1, "class": "car"}],
        "extra": [{"lane": 0, "t_s": 12.5, "speed_kmh": 90.0}], "straddling": []}  # more than COUNT_MATCH_S apart
    assert got["straddling"] == []  # no crossing names a lane it straddles into


def test_a_straddling_vehicle_counted_in_the_lane_it_straddles_into_is_not_an_error_either_way():
    """A vehicle whose body reaches into the neighbouring lane at the line may be counted there: the pair of
    a miss in its lane and an extra in that one, close in time, becomes ``straddling``; an extra in a third lane,
    one too late, or a vehicle that straddles nothing stay errors."""
    from edge.evaluation.counting import CountTally, count_mismatches
    from edge.evaluation.lane import _straddled_lane
    from hw_sim.scenario import Lane

    lanes = [Lane(-5.25), Lane(-1.75), Lane(1.75), Lane(5.25, direction="away")]
    # a 1.8 m wide car: inside its lane up to 0.85 m from the centre, into the neighbour beyond 0.85 m
    assert _straddled_lane(-1.75, 1.8, 1, lanes) == -1
    assert _straddled_lane(-1.75 + 0.84, 1.8, 1, lanes) == -1
    assert _straddled_lane(-1.75 + 0.86, 1.8, 1, lanes) == 2
    assert _straddled_lane(-1.75 - 0.86, 1.8, 1, lanes) == 0
    assert _straddled_lane(1.75 + 0.9, 1.8, 2, lanes) == -1  # the lane beside runs the other way
    assert _straddled_lane(0.0, 1.8, 7, lanes) == -1  # not a lane of the scenario

    true = [(1, 10.0, 1, "truck", 2), (1, 20.0, 2, "car", 2), (0, 30.0, 3, "car", 1), (0, 40.0, 4, "car", -1)]
    meas = [(2, 10.1, 80.0), (3, 20.0, 90.0), (1, 33.0, 90.0), (1, 40.0, 90.0)]
    got = count_mismatches(true, meas, 4)
    assert got["straddling"] == [{"lane": 1, "t_s": 10.0, "vehicle_id": 1, "class": "truck", "counted_lane": 2,
                                  "counted_t_s": 10.1}]
    assert [m["vehicle_id"] for m in got["missed"]] == [3, 4, 2]  # lane by lane
    assert [(e["lane"], e["t_s"]) for e in got["extra"]] == [(1, 33.0), (1, 40.0), (3, 20.0)]

    tally = CountTally(4)
    tally.measured[:] = [0, 2, 1, 1]
    tally.counted = meas
    s = tally.summary(true)
    assert s["volume_true_per_lane"] == [2, 2, 0, 0]
    assert s["volume_measured_per_lane"] == [0, 2, 1, 1]
    assert s["volume_measured_either_per_lane"] == [0, 3, 0, 1]  # the truck given back to lane 1


def test_true_crossings_are_those_of_the_reference_point_the_tracks_follow(tmp_path):
    """The truth counts a vehicle at the detection line when its reference point (the near face, which its track
    follows) crosses it, not its centre: a run that ends after a car's front crossed the line and before its
    centre did (2.25 m, 3 frames later at 90 km/h) has one true crossing, and the traffic layer's count matches it
    (with the centre the truth had none and the count was an "extra": highway4-traffic seed 7002, lanes 0 and 1,
    in the run's last 0.1 s)."""
    from hw_sim.boards import SIMO_BOARD
    from hw_sim.scenario import load_scenario as load

    toml = (Path(__file__).parent.parent.parent / "hw_sim" / "scenarios" / "side-by-side.toml").read_text()
    head = toml.split("[[vehicle]]")[0].replace('name = "side-by-side"', 'name = "one-at-the-line"')
    path = tmp_path / "one.toml"
    path.write_text(head + '[[vehicle]]\nid = 1\nkind = "car"\nlane = 1\ny_m = 100.0\nspeed_kmh = 90.0\nlength_m = 4.5\n')
    sc = load(str(path))
    car = sc.build_scene(1).targets[0]
    period = SIMO_BOARD.frontend.waveform.frame_period_s
    line = load_config(env={}).section("traffic").detection_line_m
    y0 = sc.build_scene(1).pose.y_m
    front = next(n for n in range(400) if car.near_face_point(n * period)[1] - y0 < line)
    centre = next(n for n in range(400) if car.trajectory.position(n * period)[1] - y0 < line)
    assert centre - front >= 2
    rep = evaluate(sc, seed=1, frames=centre, config=load_config(env={}))  # its last frame: the centre short of it
    s = rep["summary"]
    assert s["volume_true_per_lane"][1] == 1
    assert s["count_error_per_lane"] == [0, 0, 0, 0]
    assert s["count_mismatches"] == {"missed": [], "extra": [], "straddling": []}
    assert s["volume_measured_either_per_lane"] == s["volume_measured_per_lane"]


def test_overlap_diagnosis_marks_vehicles_the_waveform_and_array_cannot_separate():
    """The evaluator's ``detection_probability_by_overlap``: which vehicles share another's range-Doppler
    cell and beam. Built from the SIMO waveform's own beat model (edge.dsp.pairing.PairingModel)."""
    import math

    import numpy as np

    from edge.dsp.pairing import PairingModel
    from edge.evaluation.lane import _overlapping
    from hal.waveform import simo_frontend

    fe = simo_frontend()
    model = PairingModel.from_waveform(fe.waveform)
    bin_hz = np.array([sg.sample_rate_hz / sg.n_samples for sg in fe.waveform.segments])
    bw = fe.waveform.wavelength_m / (fe.n_rx * fe.rx_spacing_m)
    assert math.degrees(bw) == pytest.approx(9.55, abs=0.01)

    def ov(r, length, v, az_deg):
        return _overlapping(model, bin_hz, np.array(r, float), np.array(length, float), np.array(v, float),
                            np.radians(az_deg), bw).tolist()

    # two cars side by side at 150 m, 0.3 m/s apart, 1.3 deg apart: one cell, one beam
    assert ov([150.0, 150.0], [4.5, 4.5], [-19.0, -19.3], [-0.7, -2.0]) == [True, True]
    # the same 10 m apart in range, or 20 deg apart in azimuth (at short range), or 5 m/s apart: separate
    assert ov([150.0, 160.0], [4.5, 4.5], [-19.0, -19.3], [-0.7, -2.0]) == [False, False]
    assert ov([15.0, 15.0], [4.5, 4.5], [-19.0, -19.3], [-10.0, 10.0]) == [False, False]
    assert ov([150.0, 150.0], [4.5, 4.5], [-19.0, -24.0], [-0.7, -2.0]) == [False, False]
    # a motorcycle beside the middle of a 12 m truck 4 m/s faster: inside the truck body's beats; the truck's
    # own near face, 6 m nearer, is outside the motorcycle's (short) span
    assert ov([56.0, 50.0], [2.0, 12.0], [-20.0, -24.0], [-5.0, -2.0]) == [True, False]
    # one vehicle alone, and none
    assert ov([100.0], [4.5], [-20.0], [0.0]) == [False]
    assert ov([], [], [], []) == []


def test_stopped_vehicle_alarms_are_scored_against_the_truth():
    """``stopped-vehicle``, first 20 s: the car of lane 1 stands 120 m out from 12.2 s; it is a stopped vehicle once
    it has stood 5 s, and the alarm (traffic.stopped_min_s = 5 s) must follow it, about 5 s after it stopped.
    ``stop-and-go``'s car stands 4 s: no stopped vehicle, no alarm."""
    s = evaluate(load_scenario("stopped-vehicle"), seed=1, frames=600, config=load_config(env={}))["summary"]
    sv = s["stopped_vehicle"]
    assert {k: sv[k] for k in ("vehicles", "alarms", "correct", "false", "missed")} == {
        "vehicles": 1, "alarms": 1, "correct": 1, "false": 0, "missed": 0}
    # (the monitor calls slower than 1 m/s standing, the truth slower than 0.5 m/s: 0.2 s of braking apart)
    assert 4.5 <= sv["delay_s"][0] < 6.0 and abs(sv["alarm_range_m"][0] - 118.0) < 3.0
    s = evaluate(load_scenario("stop-and-go"), config=load_config(env={}))["summary"]
    assert s["stopped_vehicle"]["vehicles"] == 0 and s["stopped_vehicle"]["alarms"] == 0


def test_lane_accuracy_is_split_into_lane_keeping_and_lane_changing_frames():
    """``crossing``: two cars change lanes across each other from 2 to 5 s of a 6 s run. The frames inside
    those 3 s count as lane changing, the others as lane keeping; together they are the lane accuracy's frames."""
    from edge.evaluation.lane import _changing_lanes
    from hw_sim.vehicles import RoadTrajectory

    traj = RoadTrajectory(0.0, 50.0, -1, (0.0,), (25.0,), lane_changes=((2.0, 3.0, 3.5),))
    veh = type("V", (), {"trajectory": traj})()
    assert [_changing_lanes(veh, t) for t in (1.99, 2.0, 3.5, 5.0, 5.01)] == [False, True, True, True, False]
    assert not _changing_lanes(object(), 3.0)  # no road trajectory: never changing lanes

    rep = evaluate(load_scenario("crossing", V1), seed=3, config=load_config(env={}))
    s, tl = rep["summary"], rep["summary"]["tallies"]
    assert 0 < tl["lane_keeping_assigned"] < tl["lane_assigned"]
    n_change = tl["lane_assigned"] - tl["lane_keeping_assigned"]
    assert s["lane_accuracy_keeping"] == pytest.approx(tl["lane_keeping_correct"] / tl["lane_keeping_assigned"])
    assert s["lane_accuracy_changing"] * n_change + tl["lane_keeping_correct"] == pytest.approx(tl["lane_correct"])
    # both cars are assigned through their lane changes (3 s of 33 ms frames each, less the evaluated gaps)
    assert n_change >= 150
    # a scene without lane changes: every assigned frame is a lane-keeping one
    rep = evaluate(load_scenario("highway4", V1), seed=11, frames=60, config=load_config(env={}))
    tl = rep["summary"]["tallies"]
    assert tl["lane_keeping_assigned"] == tl["lane_assigned"] > 0
    assert rep["summary"]["lane_accuracy_changing"] is None


def test_road_frame_error_cancels_a_turn_the_yaw_estimate_took_up():
    """A board whose boresight is turned by b puts every track turned by b; the traffic layer's yaw estimate reads
    mounting yaw + b. In the road frame the turn cancels; with the yaw the truth has, the error is the plain one."""
    import math

    import numpy as np

    from edge.evaluation.lane import _road_sq_error

    yaw, b = math.radians(3.0), math.radians(0.2)
    truth = np.array([4.0, 150.0])
    turned = np.array([[math.cos(b), math.sin(b)], [-math.sin(b), math.cos(b)]]).T @ truth  # truth turned by b
    # the traffic layer's convention: across = x cos + y sin; a point turned by b reads across = ... of yaw + b
    assert _road_sq_error(turned, truth, yaw + b, yaw) == pytest.approx(0.0, abs=1e-18)
    plain = float(np.sum((turned - truth) ** 2))
    assert plain > 0.25  # 0.2 deg at 150 m: 0.52 m
    assert _road_sq_error(turned, truth, yaw, yaw) == pytest.approx(plain)
    assert _road_sq_error(truth + [0.3, -0.4], truth, yaw, yaw) == pytest.approx(0.25)


def test_false_tracks_near_the_radar_are_those_begun_within_near_m():
    """``false_tracks_near`` counts the false-track episodes by the ground range where they began (x, y), not
    where they ended or their frame."""
    ep = lambda x, y, first=0: [first, first + 10, 11, 0, 1, x, y]  # noqa: E731
    assert NEAR_M == 25.0
    eps = [ep(0.6, 16.0), ep(-3.0, 24.8, first=900), ep(18.0, 18.0), ep(0.0, 25.0), ep(1.0, 140.0)]
    assert _near_count(eps) == 2  # 16.0 m and 24.98 m; 25.46 m, 25.0 m and 140 m are not near
    assert _near_count([]) == 0
