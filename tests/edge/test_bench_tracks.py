"""``radar-edge bench --tracks``: scenes that hold N cars, the frame cost against the confirmed tracks held."""

import json

import pytest

from edge.bench import synth_frames
from edge.bench.tracks import run_tracks, scene_toml
from edge.cli import main
from edge.config import load_config


@pytest.mark.parametrize("n", [5, 64])
def test_scene_holds_n_cars_in_view_for_the_whole_run(tmp_path, n):
    duration_s = 6.0
    path = tmp_path / "t.toml"
    path.write_text(scene_toml(n, duration_s))
    frames = synth_frames("simo", str(path), 1, int(duration_s / 0.034) - 2)
    for f in (frames[0], frames[-1]):
        assert len(f.truth) == n
        y = f.truth.position_m[:, 1]
        assert y.min() >= 25.0 - 1.0 and y.max() <= 290.0 + 1.0


def test_run_tracks_holds_every_car_with_truth_detections():
    rep = run_tracks(load_config(env={}), (3, 12), frames=12, warmup_frames=30)
    assert rep["detections"] == "truth" and set(rep["by_count"]) == {"3", "12"}
    for n, r in ((3, rep["by_count"]["3"]), (12, rep["by_count"]["12"])):
        assert r["confirmed_min"] == r["confirmed_max"] == n
        assert 0 < r["p50_ms"] <= r["p99_ms"] and 0 < r["cpu_p50_ms"] <= r["cpu_p99_ms"]
        assert r["p99_budget_fraction"] == pytest.approx(r["p99_ms"] / 33.0)


def test_bench_cli_tracks_section(tmp_path, capsys):
    out = tmp_path / "b.json"
    assert main(["bench", "--profile", "lane", "--frames", "10", "--no-peer", "--no-startup", "--tracks", "4",
                 "--tracks-frames", "10", "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["tracks"]["by_count"]["4"]["vehicles"] == 4
    assert "cost against confirmed tracks" in capsys.readouterr().out
    assert main(["bench", "--profile", "lane", "--tracks", "5,x"]) == 2
    assert main(["bench", "--profile", "minimal", "--tracks", "5"]) == 2
