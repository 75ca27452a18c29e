"""``radar-edge calibrate``: th_RD from empty-scene frames (mean of per-frame maxima + margin)."""

from __future__ import annotations

import argparse
import itertools
import json

import numpy as np
import pytest

from edge.commands import calibrate
from edge.dsp.dbscan import CylinderDbscan
from edge.dsp.range_doppler import RangeDopplerProcessor
from hal import open_radar


def _frames(n: int, seed: int = 1, scenario: str = "empty-d2g", tx_power: int | None = None):
    extra = "" if tx_power is None else f"&tx_power={tx_power}"
    src = open_radar(f"sim://d2g?scenario={scenario}&realtime=0&seed={seed}{extra}")
    src.open()
    try:
        return list(itertools.islice(iter(src), n)), src.frontend
    finally:
        src.close()


def _site_file(tmp_path, scenario: str, name: str, physics: str) -> str:
    """The built-in ``scenario`` with a ``[physics]`` table of ``physics`` lines, as the scenario file ``name``."""
    from importlib import resources

    text = resources.files("hw_sim").joinpath("scenarios", f"{scenario}.toml").read_text(encoding="utf-8")
    path = tmp_path / f"{name}.toml"
    path.write_text(text + f"\n[physics]\n{physics}\n", encoding="utf-8")
    return str(path)


def _v1_empty_site(tmp_path) -> str:
    """empty-d2g on the v1 instrument (seven point objects, no swaying foliage), as a scenario file."""
    return _site_file(tmp_path, "empty-d2g", "empty-d2g-v1", 'preset = "v1"')


def test_threshold_is_mean_of_maxima_plus_margin_and_empty_scene_gives_no_cluster(tmp_path):
    # figure measured on the v1 instrument; the corpus reports the physical defaults
    site = _v1_empty_site(tmp_path)
    frames, fe = _frames(30, scenario=site)
    rdp = RangeDopplerProcessor(fe)
    res = calibrate.calibrate_threshold(frames, rdp, margin_std=3.0)
    maxima = np.array([rdp.process(f.iq()).amplitude.max() for f in frames])
    assert res["mean_of_maxima"] == pytest.approx(maxima.mean(), rel=1e-6)
    assert res["th_rd"] == pytest.approx(maxima.mean() + 3.0 * maxima.std(ddof=1), rel=1e-6)
    # on the simulated site the calibrated value lands near Table III's th_RD = 2
    assert 1.5 < res["th_rd"] < 3.0
    # the residue is leakage jitter at the first range bins
    assert res["median_range_of_maximum_m"] < 1.0
    # fresh empty frames (another seed) at that threshold: no DBSCAN cluster in any frame
    db = CylinderDbscan(rdp.n_range, rdp.n_doppler_fft, rdp.range_bin_m, rdp.cylinder_radius_kmh, 1.9, 80)
    others, _ = _frames(30, seed=7, scenario=site)
    assert all(db.fit(rdp.process(f.iq()).amplitude >= res["th_rd"]).n_clusters == 0 for f in others)


def test_calibrate_command_writes_json(tmp_path, capsys):
    p = argparse.ArgumentParser()
    calibrate.add_arguments(p)
    out = tmp_path / "th.json"
    args = p.parse_args(["--frames", "12", "--margin-std", "2", "--json", str(out)])
    assert calibrate.run(args) == 0
    res = json.loads(out.read_text())
    assert res["frames"] == 12 and res["margin_std"] == 2.0
    assert res["th_rd"] > res["mean_of_maxima"]
    assert "pipeline.surveillance.th_rd=" in capsys.readouterr().out


def test_calibrate_needs_two_frames():
    frames, fe = _frames(1)
    with pytest.raises(ValueError):
        calibrate.calibrate_threshold(frames, RangeDopplerProcessor(fe))


# --- --rcs: the RCS calibration constant C from a corner reflector (issue 31) -------------------------------------


def _reflector_frames(gain_offset_db: float, tmp_path, n: int = 12, tx_power: int | None = None):
    """Frames of the simulated reflector site (hw_sim reflector-d2g) on a board ``gain_offset_db`` off (at TX power
    level ``tx_power``; None: full power)."""
    name = f"reflector-{'m' if gain_offset_db < 0 else 'p'}{abs(gain_offset_db):g}"
    path = _site_file(tmp_path, "reflector-d2g", name, f"gain_offset_db = {gain_offset_db}")
    return _frames(n, scenario=path, tx_power=tx_power)


def test_trihedral_rcs_is_4_pi_a4_over_3_lambda2():
    from edge.classify.calibration import trihedral_rcs_m2

    lam = 299_792_458.0 / 24.0e9
    assert trihedral_rcs_m2(0.1, lam) == pytest.approx(4 * np.pi * 1e-4 / (3 * lam**2))
    assert trihedral_rcs_m2(0.2, lam) == pytest.approx(16 * trihedral_rcs_m2(0.1, lam))  # a^4
    with pytest.raises(ValueError):
        trihedral_rcs_m2(0.0, lam)


def test_measured_c_follows_the_board_gain_and_a_clipping_board_is_refused(tmp_path):
    from edge.classify.calibration import DATASHEET_C_DB, measure_reflector, trihedral_rcs_m2

    got = {}
    for off in (-6.0, -3.0, 0.0, 3.0):
        frames, fe = _reflector_frames(off, tmp_path)
        sigma = trihedral_rcs_m2(0.10, fe.waveform.wavelength_m)
        res = measure_reflector(frames, fe, rcs_m2=sigma, range_m=5.0)
        got[off] = res["c_db"]
        assert res["clipped_fraction"] == 0.0
        assert abs(res["measured_peak_range_m"] - 5.0) < 0.3
        # the uncertainty: the frames' spread is tiny on a static reflector; the 5 cm of range dominates
        assert res["c_sd_range_db"] == pytest.approx(40 / np.log(10) * 0.05 / 5.0)
        assert res["c_sd_db"] >= res["c_sd_range_db"]
    # the nominal (datasheet) board reads the datasheet constant; the others follow their offsets
    assert got[0.0] == pytest.approx(DATASHEET_C_DB, abs=0.1)
    for off, c in got.items():
        assert c - got[0.0] == pytest.approx(off, abs=0.5)
    # +6 dB: the TX->RX leakage alone drives the simulated ADC to full scale; a clipped measurement is refused
    frames, fe = _reflector_frames(6.0, tmp_path)
    with pytest.raises(ValueError, match="clips"):
        measure_reflector(frames, fe, rcs_m2=2.69, range_m=5.0)


def test_calibrate_rcs_command_prints_and_writes_the_settings(tmp_path, capsys):
    from edge.classify.calibration import DATASHEET_C_DB
    from edge.config import load_config, parse_set_option

    p = argparse.ArgumentParser()
    calibrate.add_arguments(p)
    out = tmp_path / "c.json"
    assert calibrate.run(p.parse_args(["--rcs", "--frames", "6", "--json", str(out)])) == 0
    res = json.loads(out.read_text())
    assert res["frames"] == 6 and res["rcs_m2"] == pytest.approx(2.69, abs=0.01)
    assert res["c_db"] == pytest.approx(DATASHEET_C_DB, abs=0.1)
    assert "classify.features.rcs_calibration_db=" in capsys.readouterr().out
    # the printed settings load as the configuration's calibration
    fc = load_config(overrides=dict(parse_set_option(s) for s in res["set"]), env={}).section("classify.features")
    assert fc.rcs_calibration_source == "measured"
    assert fc.rcs_calibration_db == pytest.approx(res["c_db"], abs=0.01)


def test_calibration_constant_refers_eq17_to_the_reference_board():
    from edge.classify.calibration import DATASHEET_C_DB
    from edge.classify.features import FeatureConfig, MapPoints, SignatureExtractor

    frames, fe = _frames(1)
    pts = MapPoints(label=np.array([0, 0, 0, 1]), range_m=np.array([5.0, 5.2, 5.4, 9.0]),
                    amplitude=np.array([3.0, 6.0, 4.0, 2.5]), range_bin=np.array([106, 110, 115, 192]),
                    doppler_bin=np.array([40, 40, 40, 80]), doppler_kmh=np.array([-3.0, -3.0, -3.0, 1.0]))
    nominal = SignatureExtractor(FeatureConfig(), fe)
    weak = SignatureExtractor(FeatureConfig(rcs_calibration_db=DATASHEET_C_DB - 6.0), fe)
    assert nominal.rcs_factor == 1.0
    a, b = nominal(pts), weak(pts)
    # a board measured 6 dB weak has its eq. 17 power raised by 6 dB; nothing else changes
    np.testing.assert_allclose(b.rcs, a.rcs * 10**0.6, rtol=1e-12)
    assert np.all(np.isfinite(a.rcs)) and np.all(a.rcs > 0)
    np.testing.assert_array_equal(b.extent_m, a.extent_m)
    np.testing.assert_array_equal(b.circular_variance, a.circular_variance)


# --- TX power headroom (calibrate --headroom) ------------------------------------------------------------


def _hot_empty_site(tmp_path, offset_db: float) -> str:
    """empty-d2g on a board ``offset_db`` hotter, as a scenario file."""
    return _site_file(tmp_path, "empty-d2g", f"empty-d2g-hot{int(offset_db)}", f"gain_offset_db = {offset_db}")


def test_with_tx_power_sets_or_replaces_the_url_option():
    assert calibrate.with_tx_power("d2g:///dev/ttyACM0", 3) == "d2g:///dev/ttyACM0?tx_power=3"
    assert (calibrate.with_tx_power("sim://d2g?scenario=/tmp/a.toml&tx_power=7&realtime=0", 2)
            == "sim://d2g?scenario=/tmp/a.toml&realtime=0&tx_power=2")


def test_pick_tx_power_takes_the_highest_level_off_the_rails():
    peaks = {7: (1.0, 0.4), 6: (1.0, 0.01), 5: (0.93, 0.0), 4: (0.79, 0.0), 3: (0.7, 0.0)}
    seen = []

    def measure(level):
        seen.append(level)
        frac, clipped = peaks[level]
        return {"peak_fraction": frac, "clipped_fraction": clipped}

    res = calibrate.pick_tx_power(measure, 7, 0.8)
    assert res["level"] == 4 and seen == [7, 6, 5, 4]
    assert [h["level"] for h in res["levels"]] == [7, 6, 5, 4]
    res = calibrate.pick_tx_power(lambda level: {"peak_fraction": 1.0, "clipped_fraction": 0.1}, 2, 0.8)
    assert res["level"] is None and len(res["levels"]) == 3


def test_headroom_keeps_a_nominal_board_at_full_power_and_backs_a_hot_one_off(tmp_path, capsys):
    from edge.classify.calibration import DATASHEET_C_DB, measure_reflector

    p = argparse.ArgumentParser()
    calibrate.add_arguments(p)
    out = tmp_path / "h.json"
    assert calibrate.run(p.parse_args(["--headroom", "--frames", "3", "--json", str(out)])) == 0
    res = json.loads(out.read_text())
    assert res["level"] == 7 and len(res["levels"]) == 1
    assert 0.5 < res["levels"][0]["peak_fraction"] <= 0.8  # the nominal board's leakage: about two thirds
    # a board 6 dB hot clips at full power; the level picked keeps it off the rails, 1 dB a level
    src = f"sim://d2g?scenario={_hot_empty_site(tmp_path, 6.0)}&realtime=0"
    assert calibrate.run(p.parse_args(["--headroom", "--frames", "3", "--source", src, "--json", str(out)])) == 0
    res = json.loads(out.read_text())
    assert res["levels"][0]["clipped_fraction"] > 0.2
    assert res["level"] == 2 and res["url"].endswith("tx_power=2")
    assert res["levels"][-1]["clipped_fraction"] == 0.0 and res["levels"][-1]["peak_fraction"] <= 0.8
    assert "install TX power level 2 of 7" in capsys.readouterr().out
    # C measured on the reflector at that level: no clipping, and it reads the board's +6 dB less the 5 dB back-off
    frames, fe = _reflector_frames(6.0, tmp_path, tx_power=2)
    c = measure_reflector(frames, fe, rcs_m2=2.69, range_m=5.0)
    assert c["clipped_fraction"] == 0.0
    assert c["c_db"] - DATASHEET_C_DB == pytest.approx(6.0 - 5.0, abs=0.2)


def test_headroom_over_d2g_reads_the_levels_from_the_board(tmp_path, capsys):
    from tests.hal.d2g_emulator import emulated_d2g_url

    p = argparse.ArgumentParser()
    calibrate.add_arguments(p)
    with emulated_d2g_url("empty-d2g", 1) as url:
        assert calibrate.run(p.parse_args(["--headroom", "--frames", "2", "--source", url])) == 0
    assert "install TX power level 7 of 7" in capsys.readouterr().out


def test_headroom_needs_a_board_with_a_tx_power_setting(capsys):
    p = argparse.ArgumentParser()
    calibrate.add_arguments(p)
    assert calibrate.run(p.parse_args(["--headroom", "--frames", "2", "--source",
                                       "sim://simo?scenario=highway4&realtime=0"])) == 2
    assert "no TX power setting" in capsys.readouterr().err
    with pytest.raises(ValueError, match="two steps"):
        calibrate.run(p.parse_args(["--headroom", "--rcs"]))
