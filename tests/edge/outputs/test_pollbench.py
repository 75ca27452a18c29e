"""Smoke test of the Modbus polling benchmark (the real figure needs a quiet machine and minutes)."""

from __future__ import annotations

from edge.outputs.pollbench import measure


def test_pollbench_smoke():
    r = measure(duration_s=3.0, block_s=0.5, rate_hz=20.0, source="sim://simo?scenario=highway4&loop=1")
    assert r["full_map_polls"] > 0
    assert r["with_poller"]["frames"] > 0 and r["without_poller"]["frames"] > 0
    assert r["p99_ratio"] > 0


def test_pollbench_flood_smoke():
    """Several clients polling as fast as they can (the issue-9 flood acceptance form)."""
    r = measure(duration_s=3.0, block_s=0.5, rate_hz=0.0, source="sim://simo?scenario=highway4&loop=1", clients=3)
    assert r["clients"] == 3 and r["full_map_polls"] > 0
    assert r["with_poller"]["frames"] > 0 and r["without_poller"]["frames"] > 0
    assert r["with_poller"]["dropped_frames"] >= 0 and r["without_poller"]["dropped_frames"] >= 0
