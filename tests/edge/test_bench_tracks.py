"""``radar-edge bench --tracks``: scenes that hold N cars, the frame cost against the confirmed tracks held."""

import json

import pytest

from edge.bench.tracks import run_tracks, scene_toml
from edge.cli import main
from edge.config import load_config


@pytest.mark.parametrize("n", [5, 64])
def test_scene_holds_n_cars_in_view_for_the_whole_run(tmp_path, n):
    """The bench's scene keeps all n cars between 25 and 290 m at every frame of the run (the truth of each frame
    time; the frames' signals are not needed for it)."""
    from hw_sim.boards import SIMO_BOARD
    from hw_sim.scenario import load_scenario

    duration_s = 6.0
    path = tmp_path / "t.toml"
    path.write_text(scene_toml(n, duration_s))
    scene = load_scenario(str(path)).build_scene(1)
    period = SIMO_BOARD.frontend.waveform.frame_period_s
    for k in range(int(duration_s / period) - 1):
        truth = scene.truth(k * period)
        assert len(truth) == n
        y = truth.position_m[:, 1]
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
