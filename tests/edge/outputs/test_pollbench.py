"""Smoke test of the Modbus polling benchmark (the real figure needs a quiet machine and minutes)."""

from __future__ import annotations

import json
import os

import pytest

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
    assert r["with_poller"]["p99_ms"] > 0 and r["without_poller"]["p99_ms"] > 0


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs CPU affinity and two CPUs")
def test_pollbench_flood_with_the_loop_on_its_own_core():
    """The deployed set-up (loop.cpus / outputs.modbus.cpus) runs under a flood. Whether the flood costs
    frames is the benchmark's figure on a quiet machine (a unit test here would measure CI's neighbours)."""
    cpus = sorted(os.sched_getaffinity(0))
    loop_cpu, other = cpus[0], cpus[1]
    r = measure(duration_s=3.0, block_s=0.5, rate_hz=0.0, source="sim://simo?scenario=highway4&loop=1", clients=2,
                loop_cpus=(loop_cpu,), server_cpus=(other,), client_cpus=(other,))
    assert r["loop_cpus"] == [loop_cpu] and r["server_cpus"] == [other]
    assert r["full_map_polls"] > 0 and r["with_poller"]["frames"] > 0 and r["without_poller"]["frames"] > 0


def test_pollbench_command_writes_its_report_and_rejects_bad_arguments(tmp_path, capsys):
    from edge.cli import main

    out = tmp_path / "flood.json"
    rc = main(["pollbench", "--duration", "1.5", "--block", "0.5", "--clients", "1", "--rate", "0",
               "--source", "sim://simo?scenario=highway4&loop=1", "--json", str(out)])
    assert rc == 0
    rep = json.loads(out.read_text())
    assert rep["clients"] == 1 and rep["rate_hz"] == 0.0 and rep["full_map_polls"] > 0
    assert "full-map polls served" in capsys.readouterr().out
    assert main(["pollbench", "--clients", "0"]) == 2
    assert "--clients >= 1" in capsys.readouterr().err
