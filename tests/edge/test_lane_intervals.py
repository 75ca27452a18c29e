"""Per-lane interval truth (hand-made vehicles) and its scoring against the traffic layer's interval records."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.commands.evaluate import console_summary
from edge.evaluation.lane_intervals import LaneIntervalTruth, score_intervals, score_vehicles
from edge.types import LaneStats

NAMES = ("motorcycle", "car", "truck")
EDGES = (3.05, 5.79)


def _truth(vehicles, frames=201, dt=0.05, interval_s=5.0, lane_dir=(1,)):
    """Vehicles ``(id, lane, speed m/s, time its near face crosses 50 m, length m)`` moving along lane ``lane``
    (away from the radar: the near face is the rear, the centre L/2 farther)."""
    t = LaneIntervalTruth(len(lane_dir), 50.0, 5.0, interval_s, lane_dir, EDGES, NAMES)
    for n in range(frames):
        ts = n * dt
        ids, lanes, sn, sc, ln, sp = [], [], [], [], [], []
        for vid, lane, v, tc, length in vehicles:
            d = lane_dir[lane]
            s_near = 50.0 + d * v * (ts - tc)
            ids.append(vid), lanes.append(lane), sn.append(s_near), sc.append(s_near + 0.5 * length)
            ln.append(length), sp.append(v)
        t.add_frame(ts, ids, lanes, sn, sc, ln, sp)
    return t


def test_interval_truth_against_hand_computed_values():
    # lane 0, away: a car (4 m, 20 m/s) crossing at 1.0 s, a truck (12 m, 10 m/s) at 3.0 s, a car at 7.0 s
    t = _truth([(1, 0, 20.0, 1.0, 4.0), (2, 0, 10.0, 3.0, 12.0), (3, 0, 25.0, 7.0, 4.5)])
    iv = t.intervals()
    assert set(iv) == {(0, 0), (0, 1)}  # 201 frames of 50 ms: 10 s, two 5 s intervals
    a, b = iv[(0, 0)], iv[(0, 1)]
    assert a["volume"] == 2 and b["volume"] == 1
    assert a["mean_speed_kmh"] == pytest.approx(54.0)
    assert a["speed_p85_kmh"] == pytest.approx(36 + 0.85 * 36)
    assert a["headway_s"] == pytest.approx(2.0)
    assert a["gap_s"] == pytest.approx(2.0 - 4.0 / 20.0)  # the car's rear to the truck's front
    assert b["headway_s"] == pytest.approx(4.0) and b["gap_s"] == pytest.approx(4.0 - 12.0 / 10.0)
    assert a["class_counts"] == {"motorcycle": 0, "car": 1, "truck": 1}
    assert a["mean_length_m"] == pytest.approx(8.0)
    # occupancy: a vehicle occupies the 47.5-52.5 m zone while (rear) s_near <= 52.5 and s_near + L >= 47.5:
    # the car (5 + 4) m / 20 m/s = 0.45 s, the truck 17 m / 10 m/s = 1.7 s -> 2.15 s of 5 s; frames of 50 ms
    assert a["occupancy_pct"] == pytest.approx(100 * 2.15 / 5.0, abs=100 * 0.05 / 5.0 + 1e-9)
    assert b["occupancy_pct"] == pytest.approx(100 * 9.5 / 25.0 / 5.0, abs=1.0 + 1e-9)


def test_only_crossings_in_the_lane_direction_count_and_empty_intervals_are_nan():
    # lane 0 runs toward the radar: a vehicle driving it toward the radar counts, one driving it the wrong way
    # (an event, not volume) does not
    t = _truth([(1, 0, 20.0, 1.0, 4.0)], lane_dir=(-1,), frames=100)
    t2 = LaneIntervalTruth(1, 50.0, 5.0, 5.0, (-1,), EDGES, NAMES)
    for n in range(100):
        ts = n * 0.05
        s = 50.0 + 20.0 * (ts - 1.0)  # moving away in a toward lane
        t2.add_frame(ts, [1], [0], [s], [s + 2.0], [4.0], [20.0])
    iv = t2.intervals()[(0, 0)]
    assert iv["volume"] == 0 and math.isnan(iv["mean_speed_kmh"]) and math.isnan(iv["gap_s"])
    assert iv["occupancy_pct"] > 0  # it still occupies the zone
    assert t.intervals()[(0, 0)]["volume"] == 1


def _stats(lane, start_s, **kw):
    base = dict(lane=lane, interval_start_ns=int(start_s * 1e9), interval_s=5.0, sequence=0, volume=2,
                occupancy_pct=45.0, mean_speed_kmh=54.5, speed_p85_kmh=66.0, headway_s=2.0, gap_s=1.62,
                class_counts={"motorcycle": 0, "car": 2, "truck": 0}, mean_length_m=8.5)
    base.update(kw)
    return LaneStats(**base)


def test_scoring_pairs_each_record_with_its_lane_and_interval():
    t = _truth([(1, 0, 20.0, 1.0, 4.0), (2, 0, 10.0, 3.0, 12.0), (3, 0, 25.0, 7.0, 4.5)])
    truth = t.intervals()
    rec = [_stats(0, 0.0), _stats(0, 5.0, volume=1, gap_s=float("nan"), headway_s=4.1, mean_speed_kmh=float("nan"),
                                  class_counts={"motorcycle": 0, "car": 0, "truck": 0, "unknown": 1})]
    sc = score_intervals(rec, truth, 0.0, 5.0, NAMES)
    a = sc["all_lanes"]
    assert a["intervals"] == 2 and [r["interval"] for r in sc["records"]] == [0, 1]
    assert a["volume_error"]["mean"] == pytest.approx(0.0)
    # interval 0: the measured mean speed 54.5 against 54.0 (0.5 km/h, within 1); interval 1 has none measured
    assert a["mean_speed_error_kmh"]["n"] == 1 and a["mean_speed_error_kmh"]["mean"] == pytest.approx(0.5)
    assert a["mean_speed_error_kmh"]["within_tolerance"] == 1.0
    assert a["occupancy_error_pp"]["n"] == 2
    assert a["occupancy_error_pp"]["mean"] == pytest.approx(
        np.mean([45.0 - truth[(0, 0)]["occupancy_pct"], 45.0 - truth[(0, 1)]["occupancy_pct"]]))
    # gap: 1.62 s against 1.8 s = -10 %; interval 1's gap is n/a though the truth has one
    assert a["gap_error_pct"]["mean"] == pytest.approx(-10.0) and a["gap_intervals_na"] == 1
    assert a["class_count_error"]["car"]["mean"] == pytest.approx(((2 - 1) + (0 - 1)) / 2)
    assert a["class_count_error"]["truck"]["mean"] == pytest.approx(-0.5)
    assert a["class_count_error"]["unknown"]["mean"] == pytest.approx(0.5)
    assert set(sc["per_lane"]) == {"0"}


def test_vehicle_scores_by_kind_and_class():
    vs = [dict(kind="car", **{"class": "car"}, length_m_true=4.0, length_m_est=4.2, length_class_true="car",
               length_class_est="car"),
          dict(kind="van", **{"class": "car"}, length_m_true=5.9, length_m_est=5.9, length_class_true="truck",
               length_class_est="truck"),
          dict(kind="car", **{"class": "car"}, length_m_true=4.5, length_m_est=None, length_class_true="car",
               length_class_est=None)]
    sc = score_vehicles(vs, NAMES)
    car = sc["by_class"]["car"]
    assert car["vehicles"] == 3 and car["length_measured_fraction"] == pytest.approx(2 / 3)
    assert car["length_error_m"]["mean"] == pytest.approx(0.1)
    assert car["length_class_accuracy"] == pytest.approx(2 / 3)  # the n/a one is wrong
    assert car["body_class_accuracy"] == pytest.approx(1 / 3)  # the 5.9 m van is a truck by length
    assert sc["by_kind"]["van"]["vehicles"] == 1


def test_console_summary_is_rounded_and_tabulated():
    rep = {"scenario": "x", "seed": 1, "frames": 3,
           "summary": {"speed_mae_kmh": 0.123456789, "detection_probability": 0.98765432, "false_tracks": 2,
                       "confusion_matrix": None}}
    text = console_summary(rep)
    assert "0.123" in text and "0.123456789" not in text and "n/a" in text
    assert all(len(line) < 120 for line in text.splitlines())


def test_short_highway4_traffic_run_reports_intervals_and_vehicle_lengths():
    """8 s of highway4-traffic with 4 s intervals: every closed interval record is paired with the truth of its lane
    and interval, the vehicles scored are those that crossed the line, with their true lengths."""
    from edge.config import load_config
    from edge.evaluation.lane import evaluate
    from hw_sim.scenario import load_scenario

    sc = load_scenario("highway4-traffic")
    rep = evaluate(sc, seed=5, frames=240, config=load_config(env={}, overrides={"traffic.interval_s": 4.0}))
    s = rep["summary"]
    iv = s["intervals"]
    recs = iv["records"]
    assert {(r["lane"], r["interval"]) for r in recs} == {(k, 0) for k in range(4)}  # one closed interval per lane
    assert iv["all_lanes"]["intervals"] == 4 and set(iv["per_lane"]) == {"0", "1", "2", "3"}
    for key in ("volume_error", "occupancy_error_pp", "mean_speed_error_kmh", "speed_p85_error_kmh", "headway_error_s",
                "gap_error_pct", "mean_length_error_m", "class_count_error"):
        assert key in iv["all_lanes"]
    # the truth's volumes are crossings of the whole run's true count; the measured ones the traffic layer's
    assert 0 < sum(r["volume"][1] for r in recs) <= sum(s["volume_true_per_lane"])
    assert sum(r["volume"][0] for r in recs) <= sum(s["volume_measured_per_lane"])
    for r in recs:
        assert sum(v[1] for v in r["class_counts"].values()) == r["volume"][1]
        assert sum(v[0] for v in r["class_counts"].values()) == r["volume"][0]
        assert 0.0 <= r["occupancy_pct"][1] <= 100.0
    # the vehicles that crossed, each with its simulator length and that length's class
    scene = sc.build_scene(5)
    true_len = {t.id: t.length_m for t in scene.targets if hasattr(t, "length_m")}
    crossed = [t for t in rep["targets"] if t["length_m_true"] is not None]
    assert all(t["length_m_true"] == pytest.approx(true_len[t["id"]]) for t in crossed)
    vl = s["vehicle_lengths"]
    assert vl["all"]["vehicles"] == sum(s["volume_true_per_lane"])
    cars = [t for t in crossed if t["kind"] == "car" and t["length_m_est"] is not None]
    assert cars and min(abs(t["length_m_est"] - t["length_m_true"]) for t in cars) < 1.0
