"""A Distance2Go missing at start: the service stays up, serves the fault over Modbus and CAN, retries
the board with back-off and runs normally once it appears (before, ``run`` exited 2 and systemd gave
up after its start limit). Synchronised by polling with deadlines, never by sleeping."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest
from pymodbus.client import ModbusTcpClient

from edge.config import load_config
from edge.loop import FrameLoop
from edge.outputs import build_sinks
from edge.outputs import registers as R
from edge.outputs.can_db import build_database
from edge.outputs.state import ALARM_PIPELINE, LOOP_STATES
from hal import open_radar
from hw_sim.d2g_device import D2GEmulator

ROOT = Path(__file__).resolve().parents[2]
FAST = "period_ms=50&timeout_s=0.3&gap_s=0.02&backoff_s=0.02&backoff_max_s=0.1"
FAULT, RUNNING = LOOP_STATES.index("fault"), LOOP_STATES.index("running")


def _status(client: ModbusTcpClient) -> dict:
    rr = client.read_input_registers(R.STATUS.base, count=R.STATUS.size, device_id=1)
    assert not rr.isError(), rr
    return R.decode_block(R.STATUS, rr.registers)


def _poll(client, pred, deadline_s=20.0, wait=lambda: None):
    """Read the status block until ``pred`` holds; ``wait`` blocks on an event between reads."""
    t_end = time.monotonic() + deadline_s
    st = None
    while time.monotonic() < t_end:
        st = _status(client)
        if pred(st):
            return st
        wait()
    raise AssertionError(f"condition not reached within {deadline_s} s; last status {st}")


def _radar_state(rx: can.BusABC, db, pred, deadline_s=20.0) -> dict:
    t_end = time.monotonic() + deadline_s
    last = None
    while time.monotonic() < t_end:
        m = rx.recv(timeout=1.0)
        if m is not None and m.arbitration_id == 0x201:
            last = db.decode_message(0x201, m.data)
            if pred(last):
                return last
    raise AssertionError(f"RadarState condition not reached; last {last}")


def test_missing_board_is_served_as_a_fault_over_modbus_and_can_until_it_appears(tmp_path, request):
    from edge.pipelines.minimal import MinimalConfig, MinimalPipeline

    link = tmp_path / "ttyD2G"  # the board's port: not there yet
    channel = f"missing-board-{request.node.name}"
    rx = can.Bus(interface="virtual", channel=channel)
    cfg = load_config(env={}, overrides={
        "source.url": f"d2g://{link}?{FAST}", "loop.reconnect_backoff_s": 0.05, "loop.health_period_s": 0.1,
        "outputs.modbus.tcp_port": 0, "outputs.can.interface": "virtual", "outputs.can.channel": channel})
    src = open_radar(cfg["source"].url)
    sinks = build_sinks(cfg, 0)
    loop = FrameLoop(src, MinimalPipeline(src.frontend, MinimalConfig()), cfg["loop"], sinks=sinks,
                     read_timeout_s=0.5)
    out: dict = {}
    th = threading.Thread(target=lambda: out.update(summary=loop.run()), daemon=True)
    emu = D2GEmulator("tavanti-test1", seed=1, link=str(link))
    client = ModbusTcpClient("127.0.0.1", port=sinks[0].tcp_address[1], timeout=2, retries=0)
    db = build_database(0)
    th.start()
    try:
        assert client.connect()
        st = _poll(client, lambda s: s["loop_state"] == FAULT and s["errors"] >= 2,
                   wait=lambda: rx.recv(timeout=0.2))
        assert st["alarm"] == ALARM_PIPELINE and st["status_bits"] & (1 << R.ST_ANY_FAULT)
        assert not st["status_bits"] & (1 << R.ST_RADAR_OK)
        rs = _radar_state(rx, db, lambda d: d["RadarState_Persistent_Error"] == 1)
        assert th.is_alive()  # still up, retrying
        emu.start()  # the board is plugged in
        st = _poll(client, lambda s: s["loop_state"] == RUNNING and s["frame_counter"] >= 3,
                   wait=lambda: rx.recv(timeout=0.2))
        assert st["alarm"] == 0 and st["status_bits"] & (1 << R.ST_RADAR_OK)
        rs = _radar_state(rx, db, lambda d: d["RadarState_Persistent_Error"] == 0)
        assert rs["RadarState_Temporary_Error"] == 0
    finally:
        client.close()
        loop.stop()
        th.join(20)
        emu.stop()
        rx.shutdown()
    s = out["summary"]
    assert s.frames >= 3 and s.stop_reason == "stopped"
    assert s.errors >= 2  # the failed opens are counted


def test_radar_edge_run_stays_up_without_the_board_and_runs_once_it_appears(tmp_path):
    link = tmp_path / "ttyD2G"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "edge", "-v", "run", "--source", f"d2g://{link}?{FAST}", "--status-every", "0",
         "--modbus-tcp", "127.0.0.1:0", "--set", "loop.reconnect_backoff_s=0.05",
         "--set", "loop.health_period_s=0.1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    emu = D2GEmulator("tavanti-test1", seed=1, link=str(link))
    lines: list[str] = []
    try:
        port = None
        for line in proc.stderr:  # the server logs the port the OS gave it
            lines.append(line)
            m = re.search(r"Modbus TCP listening on 127\.0\.0\.1:(\d+)", line)
            if m:
                port = int(m.group(1))
                break
        assert port is not None, f"exit {proc.wait(10)}: {''.join(lines)}"
        threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True).start()
        c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        assert c.connect()
        try:
            st = _poll(c, lambda s: s["loop_state"] == FAULT and s["errors"] >= 3)
            assert proc.poll() is None and st["alarm"] == ALARM_PIPELINE
            emu.start()
            first = _poll(c, lambda s: s["loop_state"] == RUNNING)
            _poll(c, lambda s: s["frame_counter"] >= first["frame_counter"] + 3)
        finally:
            c.close()
        proc.send_signal(signal.SIGINT)
        stdout, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        emu.stop()
    assert proc.returncode == 0, "".join(lines)
    log = "".join(lines)
    assert "cannot open the source (attempt 1)" in log and "source opened after" in log
    m = re.search(r"frames (\d+), .* errors (\d+),", stdout)
    assert m and int(m.group(1)) >= 3 and int(m.group(2)) >= 3, stdout
