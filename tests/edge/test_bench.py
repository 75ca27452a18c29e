"""Smoke test of ``radar-edge bench``: the report has the DESIGN §6 keys and consistent numbers."""

import json

from edge.bench import run_bench
from edge.cli import main
from edge.config import load_config


def test_bench_report_keys_and_consistency():
    rep = run_bench("minimal", load_config(env={}), frames=12, seed=2, startup=False)
    assert {"profile", "frames", "stages", "frame", "peak_rss_mb", "startup_s", "peer", "fft_bound"} <= set(rep)
    fr = rep["frame"]
    assert fr["budget_ms"] == 33.0
    assert 0 < fr["p50_ms"] <= fr["p99_ms"]
    assert abs(fr["p99_budget_fraction"] - fr["p99_ms"] / 33.0) < 1e-12
    assert set(rep["stages"]) >= {"to_complex", "range_fft", "peaks"}
    assert rep["fft_bound"]["p99_ms"] > 0 and rep["fft_bound"]["ratio"] > 0
    assert rep["peer"]["p99_ms"] > 0 and rep["peer"]["frames"] == 12
    assert rep["peak_rss_mb"] > 10


def test_bench_cli_writes_json(tmp_path, capsys):
    out = tmp_path / "b.json"
    assert main(["bench", "--profile", "minimal", "--frames", "10", "--no-peer", "--json", str(out)]) == 0
    rep = json.loads(out.read_text())
    assert rep["startup_s"] > 0 and rep["peer"] is None
    assert "p99/budget" in capsys.readouterr().out
    assert main(["bench", "--profile", "nope"]) == 2
