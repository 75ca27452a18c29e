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


def _frames(n: int, seed: int = 1, scenario: str = "empty-d2g"):
    src = open_radar(f"sim://d2g?scenario={scenario}&realtime=0&seed={seed}")
    src.open()
    try:
        return list(itertools.islice(iter(src), n)), src.frontend
    finally:
        src.close()


def _v1_empty_site(tmp_path) -> str:
    """empty-d2g on the v1 instrument (seven point objects, no swaying foliage), as a scenario file."""
    from importlib import resources

    text = resources.files("hw_sim").joinpath("scenarios", "empty-d2g.toml").read_text(encoding="utf-8")
    path = tmp_path / "empty-d2g-v1.toml"
    path.write_text(text + '\n[physics]\npreset = "v1"\n', encoding="utf-8")
    return str(path)


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
