"""End-to-end figures of the lane pipeline on fixed seeds stay within bands (on any machine).

Whole runs diverge across machines in detail (a peak at the CFAR threshold comes or goes with the last bit of a
BLAS kernel), so they are checked on what matters, with margins: detection probability, false tracks, lane
accuracy, position RMSE, speed MAE, counts per lane and the wrong-way scene's alarm. The simulator is pinned to the
v1 instrument (scenario patch ``{"physics": {"preset": "v1"}}``) so that the hw_sim changes of issue 28 do not move
these figures; the corpus (``radar-edge evaluate --corpus``) reports the physical defaults.

Measured on the development machine (OpenBLAS Haswell kernel, numpy AVX2/AVX-512 targets) and with OpenBLAS held
to Sandybridge and numpy to its baseline SIMD (``OPENBLAS_CORETYPE=Sandybridge NPY_DISABLE_CPU_FEATURES="AVX2 FMA3
X86_V3 X86_V4"``), the figures are in :data:`MEASURED`. Each band keeps a margin of about a third of the distance to
what a real regression does (a vehicle lost for a second in 450 frames moves detection probability by 0.01; one
false track in 15 s is 4 per minute; one miscounted vehicle is a count error of 1), and wide enough for a few
frames' difference across machines.
"""

from __future__ import annotations

import functools

import pytest

V1 = {"physics": {"preset": "v1"}}

#: (scenario, seed, frames)
RUNS = [("highway4", 3, 400), ("highway4-traffic", 5, 300), ("wrong-way", 6, None)]

KEYS = ("detection_probability", "false_tracks", "false_tracks_per_min", "lane_accuracy", "position_rmse_m_mean",
        "position_rmse_m_max", "speed_mae_kmh", "count_error_per_lane", "volume_true_per_lane", "id_switches")


@functools.lru_cache(maxsize=None)
def summary(scenario: str, seed: int, frames: int | None) -> dict:
    from threadpoolctl import threadpool_limits

    from edge.config import load_config
    from edge.evaluation.lane import evaluate
    from hw_sim.scenario import load_scenario_for_eval

    with threadpool_limits(limits=1):  # as on the device (OPENBLAS_NUM_THREADS=1 in the service unit)
        return evaluate(load_scenario_for_eval(scenario, patch=V1), seed=seed, frames=frames,
                        config=load_config(env={}))["summary"]


#: measured (both machine kinds of the module docstring agreed to 1e-5 m and 1e-5 km/h; the discrete figures equal)
MEASURED = {
    "highway4": dict(detection_probability=0.9735, false_tracks=0, lane_accuracy=1.0, position_rmse_m_mean=0.0612,
                     position_rmse_m_max=0.0930, speed_mae_kmh=0.0802, count_error_per_lane=[0, 0, 0, 0],
                     id_switches=0),
    "highway4-traffic": dict(detection_probability=0.9290, false_tracks=0, lane_accuracy=1.0,
                             position_rmse_m_mean=0.1970, position_rmse_m_max=0.3755, speed_mae_kmh=0.2336,
                             count_error_per_lane=[0, 0, 0, 0], id_switches=1),
    "wrong-way": dict(detection_probability=0.9602, false_tracks=0, lane_accuracy=1.0, position_rmse_m_mean=0.1354,
                      position_rmse_m_max=0.1488, speed_mae_kmh=0.1291, count_error_per_lane=[0, 0, 0, 0],
                      id_switches=0, wrong_way_delay_s=7.359),
}

#: bands: (min detection probability, max false tracks, min lane accuracy, max mean / worst vehicle's position
#: RMSE (m), max speed MAE (km/h), max summed |count error|, max id switches). The OS-CFAR without its cap (decision
#: 0049) costs `v1`'s dense traffic 0.03 of detection probability (its trucks' evenly spaced scatterers fill the
#: reference window), the wrong-way scene 0.02; their bands moved with those measurements.
BANDS = {
    "highway4": (0.95, 0, 0.99, 0.09, 0.14, 0.13, 0, 1),
    "highway4-traffic": (0.91, 2, 0.94, 0.30, 0.80, 0.30, 1, 4),
    "wrong-way": (0.945, 0, 0.99, 0.20, 0.22, 0.17, 0, 1),
}


@pytest.mark.parametrize("run", RUNS, ids=[r[0] for r in RUNS])
def test_lane_figures_stay_in_their_bands(run):
    s = summary(*run)
    pd, false_max, lane_min, rmse_mean, rmse_max, speed_mae, count_max, switches = BANDS[run[0]]
    got = {k: s[k] for k in KEYS if k in s}
    assert s["detection_probability"] >= pd, got
    assert s["false_tracks"] <= false_max, got
    assert s["lane_accuracy"] >= lane_min, got
    assert s["position_rmse_m_mean"] <= rmse_mean and s["position_rmse_m_max"] <= rmse_max, got
    assert s["speed_mae_kmh"] <= speed_mae, got
    assert sum(abs(e) for e in s["count_error_per_lane"]) <= count_max, got
    assert s["id_switches"] <= switches, got
    assert sum(s["volume_true_per_lane"]) >= 2  # vehicles crossed the detection line in every run (2 to 11)


def test_the_wrong_way_driver_is_alarmed_in_time():
    ww = summary(*RUNS[2])["wrong_way"]
    assert (ww["drivers"], ww["correct"], ww["false"], ww["missed"]) == (1, 1, 0, 0), ww
    # 7.36 s measured: the alarm needs the track confirmed against its lane for traffic.wrong_way_* frames; half a
    # second (15 frames) later is a regression
    assert ww["delay_s"][0] <= MEASURED["wrong-way"]["wrong_way_delay_s"] + 0.5, ww


def test_no_false_alarm_on_the_highway_runs():
    for run in RUNS[:2]:
        ww = summary(*run)["wrong_way"]
        assert ww["alarms"] == 0 and ww["false"] == 0, (run, ww)


def test_the_bands_hold_what_was_measured():
    """Each band admits its measurement with margin (a band tighter than the figure it guards would fail on the
    first run; one without a margin on the first machine that rounds differently)."""
    for name, (pd, false_max, lane_min, rmse_mean, rmse_max, speed_mae, count_max, switches) in BANDS.items():
        m = MEASURED[name]
        assert m["detection_probability"] - pd >= 0.015 and m["false_tracks"] <= false_max
        assert m["lane_accuracy"] >= lane_min and m["id_switches"] <= switches
        assert rmse_mean >= 1.2 * m["position_rmse_m_mean"] and rmse_max >= 1.2 * m["position_rmse_m_max"]
        assert speed_mae >= 1.2 * m["speed_mae_kmh"] and sum(m["count_error_per_lane"]) <= count_max
