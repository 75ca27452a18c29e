"""The command line, end to end, in-process (console script entry point ``edge.cli:main``)."""

import json
import re

import pytest

from edge.cli import COMMANDS, build_parser, main


def test_every_command_has_help_with_examples(capsys):
    parser = build_parser()
    for mod in COMMANDS:
        name = mod.rsplit(".", 1)[1].replace("_", "-")
        with pytest.raises(SystemExit) as e:
            parser.parse_args([name, "--help"])
        assert e.value.code == 0
        out = capsys.readouterr().out
        assert "usage: radar-edge" in out and len(out) > 300, name
        assert "example" in out, f"{name} --help has no examples"


def test_info_prints_lim_table_2(capsys):
    assert main(["info", "--source", "sim://simo"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"range resolution c/\(2B\)\s+0\.749 m", out)
    assert "±250.16 km/h" in out and "±19.5°" in out and "±15.0°" in out and "33.0 ms" in out


def test_info_json_d2g(capsys):
    assert main(["info", "--source", "sim://d2g", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["characteristics"]["max_unambiguous_range_m"] == pytest.approx(24.0, abs=0.05)
    assert d["frontend"]["waveform"]["segments"][0]["n_chirps"] == 21


def test_simulate_then_replay(tmp_path, capsys):
    out = tmp_path / "hw.npz"
    assert main(["simulate", "--scenario", "single-car", "--frames", "5", "--out", str(out)]) == 0
    assert out.is_file()
    assert main(["replay", str(out), "--speed", "0", "--no-outputs", "--status-every", "0"]) == 0
    text = capsys.readouterr().out
    assert re.search(r"frames 5, dropped 0 \(loop\) \+ 0 \(source\)", text)
    assert "end of source" in text


def test_run_on_the_simulator_offline(capsys):
    rc = main(["run", "--source", "sim://d2g?realtime=0&frames=4", "--no-outputs", "--status-every", "0",
               "--set", "loop.error_policy=stop"])
    assert rc == 0
    out = capsys.readouterr().out
    assert re.search(r"frames 4, dropped 0", out) and "frame " in out


def test_errors_are_one_line_with_exit_code_2(capsys):
    assert main(["info", "--source", "nope://x"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("radar-edge info: error: unknown source scheme")
    assert main(["run", "--set", "loop.error_policy=panic", "--no-outputs"]) == 2
    assert "choose one of skip, reconnect, stop" in capsys.readouterr().err
    assert main(["simulate", "--scenario", "nope", "--out", "x.npz"]) == 2
    assert "unknown scenario 'nope'" in capsys.readouterr().err


def test_simulate_list(capsys):
    assert main(["simulate", "--list"]) == 0
    out = capsys.readouterr().out
    assert "highway4" in out and "tavanti-test1" in out


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_run_stops_cleanly_on_signal_with_a_summary(sig):
    import os
    import signal
    import subprocess
    import sys

    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.Popen(
        [sys.executable, "-m", "edge", "run", "--source", "sim://d2g?loop=1", "--no-outputs", "--status-every", "0.01"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    try:
        # synchronise on the program's own output: wait for the first status line
        for line in p.stdout:
            if line.startswith("seq "):
                break
        p.send_signal(getattr(signal, sig))
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert "stage" in out and "p99/budget" in out and "(stopped)" in out


def test_output_into_a_closed_pipe_ends_quietly():
    """``radar-edge registers | head -1``: the reader goes away; the command stops with 141 (128 + SIGPIPE) and no
    traceback, as Unix tools do. The pipe's read end is closed before the command starts, so its first write fails."""
    import os
    import subprocess
    import sys

    r, w = os.pipe()
    os.close(r)
    try:
        proc = subprocess.run([sys.executable, "-m", "edge", "registers"], stdout=w, stderr=subprocess.PIPE,
                              timeout=120)
    finally:
        os.close(w)
    assert proc.returncode == 141
    assert b"Traceback" not in proc.stderr


def test_version_is_the_package_version_the_outputs_report(capsys):
    from importlib.metadata import version

    from edge.outputs.registers import firmware_version

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    out = capsys.readouterr().out.strip()
    assert out == f"radar-edge {version('radar-edge')}"
    assert out.split()[1].split(".")[:3] == [str(v) for v in firmware_version()]
