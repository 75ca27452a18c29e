"""The SNR noise-law fit (edge.evaluation.lane_noise, radar-edge fit-noise)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.evaluation.lane_noise import detection_errors, fit_azimuth_law, fit_range_law


def _synthetic(seed: int, sigma0_deg: float, floor_deg: float, extent_m: float, n: int = 20000):
    rng = np.random.default_rng(seed)
    r = rng.uniform(20.0, 300.0, n)
    snr = rng.uniform(4.0, 40.0, n)
    lin = 10 ** (snr / 10)
    sd_x = np.sqrt(r**2 * (math.radians(sigma0_deg) ** 2 / lin + math.radians(floor_deg) ** 2) + extent_m**2)
    sd_y = np.sqrt(0.15**2 / lin + 0.02**2)
    return {"range_m": r, "snr_db": snr, "err_x_m": rng.normal(0, sd_x), "err_y_m": rng.normal(0, sd_y),
            "length_m": np.full(n, 4.5)}


def test_fit_recovers_a_known_law():
    e = _synthetic(1, 0.9, 0.05, 0.3)
    az = fit_azimuth_law(e)
    assert az["sigma0_deg"] == pytest.approx(0.9, rel=0.06)
    assert az["floor_deg"] == pytest.approx(0.05, rel=0.25)
    assert az["extent_m"] == pytest.approx(0.3, rel=0.15)
    rg = fit_range_law(e)
    assert rg["sigma0_m"] == pytest.approx(0.15, rel=0.08) and rg["floor_m"] == pytest.approx(0.02, rel=0.2)
    # the angle law held fixed: only the extent is fitted
    held = fit_azimuth_law(e, sigma0_deg=0.9, floor_deg=0.05)
    assert held["sigma0_deg"] == 0.9 and held["extent_m"] == pytest.approx(0.3, rel=0.1)


def test_fit_refuses_too_little_data():
    e = {k: v[:50] for k, v in _synthetic(2, 0.9, 0.05, 0.3).items()}
    with pytest.raises(ValueError, match="too few cells"):
        fit_azimuth_law(e)


def test_detections_of_the_simulated_board_follow_an_snr_law():
    """Smoke test on 90 frames of highway4 (seed 1, not a tuning seed): detections are matched to vehicles and the
    fitted azimuth sd at 0 dB is of the order of the board's (0.85-0.88 deg on five seeds)."""
    from hw_sim.scenario import load_scenario_for_eval

    e = detection_errors(load_scenario_for_eval("highway4"), seed=1, frames=90)
    assert e["range_m"].size > 300
    assert np.median(np.abs(e["err_x_m"])) < 0.5 and np.median(np.abs(e["err_y_m"])) < 0.2
    # error grows as the SNR falls
    lo, hi = e["snr_db"] < 15, e["snr_db"] > 25
    assert np.std(e["err_x_m"][lo] / e["range_m"][lo]) > 2 * np.std(e["err_x_m"][hi] / e["range_m"][hi])
