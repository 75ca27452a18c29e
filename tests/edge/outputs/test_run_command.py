"""`radar-edge run` (simulated source) serving Modbus TCP on an OS-chosen port, read by pymodbus and mbpoll."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

from edge.outputs import registers as R

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture
def running_instance():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "edge", "-v", "run", "--duration", "60", "--status-every", "0",
         "--set", "outputs.modbus.tcp_port=0"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        port = None
        for line in proc.stderr:  # the server logs the port the OS gave it
            m = re.search(r"Modbus TCP listening on 127\.0\.0\.1:(\d+)", line)
            if m:
                port = int(m.group(1))
                break
        if port is None:
            pytest.fail(f"radar-edge run did not start Modbus TCP (exit {proc.wait(10)})")
        yield proc, port
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def test_running_instance_serves_live_status(running_instance):
    proc, port = running_instance
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    assert c.connect()
    try:
        ident = R.decode_block(R.IDENT, c.read_input_registers(0, count=16, device_id=1).registers)
        assert ident["magic"] == R.MAP_MAGIC and ident["word_order_test"] == 0x12345678
        counters = []
        while len(set(counters)) < 3:  # frames keep arriving (each request waits for the server, no sleeps)
            st = R.decode_block(R.STATUS, c.read_input_registers(R.STATUS.base, count=R.STATUS.size, device_id=1).registers)
            if st["loop_state"] == 1:
                assert st["alarm"] == 0 and st["status_bits"] & (1 << R.ST_RADAR_OK)
                counters.append(st["frame_counter"])
            assert proc.poll() is None
        assert counters == sorted(counters)
        hdr = R.decode_block(R.TRACK_HDR, c.read_input_registers(R.TRACK_HEADER, count=8, device_id=1).registers)
        assert hdr["valid_records"] <= R.TRACK_SLOTS
    finally:
        c.close()
    exe = shutil.which("mbpoll")
    if exe is None:
        pytest.skip("mbpoll not installed (apt-get install mbpoll): pymodbus part passed")
    p = subprocess.run([exe, "-m", "tcp", "-p", str(port), "-a", "1", "-t", "3:hex", "-0", "-r", "0", "-c", "4", "-1",
                        "127.0.0.1"], capture_output=True, text=True, timeout=20)
    assert p.returncode == 0, p.stderr
    assert re.findall(r"^\[(\d+)\]:\s+(\w+)", p.stdout, re.M) == [("0", "0x5452"), ("1", "0x0100"), ("2", "0x1234"),
                                                                  ("3", "0x5678")]
