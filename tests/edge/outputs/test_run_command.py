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


def _start(extra=()):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-m", "edge", "-v", "run", "--duration", "60", "--status-every", "0",
         "--set", "outputs.modbus.tcp_port=0", *extra],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)


def _stop(proc):
    proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(20)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait(5)


@pytest.fixture
def running_instance():
    proc = _start()
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
        _stop(proc)


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


def _pty_pair(tmp_path, name):
    socat = shutil.which("socat")
    if socat is None:
        pytest.skip("socat not installed (apt-get install socat): needed for pty pairs")
    a, b = tmp_path / f"{name}0", tmp_path / f"{name}1"
    proc = subprocess.Popen([socat, "-d", "-d", f"pty,raw,echo=0,ignoreeof,link={a}",
                             f"pty,raw,echo=0,ignoreeof,link={b}"], stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if "starting data transfer loop" in line:
            return proc, str(a), str(b)
    pytest.fail("socat did not start")


def test_running_instance_rtu_and_can_across_processes(tmp_path):
    """RTU on a pty (pymodbus client and mbpoll, unit-id silence) and CAN over slcan on a pty."""
    import can

    from edge.outputs.can_db import load_shipped
    from pymodbus.client import ModbusSerialClient
    from pymodbus.exceptions import ModbusIOException

    rtu_socat, rtu_srv, rtu_cli = _pty_pair(tmp_path, "ttyV")
    can_socat, can_tx, can_rx = _pty_pair(tmp_path, "ttyC")
    rx = can.Bus(interface="slcan", channel=can_rx, bitrate=500000)
    proc = _start(["--set", f"outputs.modbus.rtu_port={rtu_srv}", "--set", "outputs.modbus.rtu_parity=N",
                   "--set", "outputs.modbus.unit_id=7", "--set", "outputs.can.interface=slcan",
                   "--set", f"outputs.can.channel={can_tx}"])
    try:
        for line in proc.stderr:
            if "Modbus RTU unit 7" in line:
                break
        else:
            pytest.fail(f"no RTU server (exit {proc.poll()})")
        c = ModbusSerialClient(rtu_cli, baudrate=19200, parity="N", bytesize=8, stopbits=1, timeout=1, retries=0)
        assert c.connect()
        try:
            assert c.read_input_registers(0, count=4, device_id=7).registers == [R.MAP_MAGIC, R.MAP_VERSION, 0x1234, 0x5678]
            with pytest.raises(ModbusIOException):
                c.read_input_registers(0, count=1, device_id=8)
            st = R.decode_block(R.STATUS, c.read_input_registers(R.STATUS.base, count=R.STATUS.size, device_id=7).registers)
            assert st["loop_state"] in (0, 1) and st["alarm"] == 0
        finally:
            c.close()
        exe = shutil.which("mbpoll")
        if exe is not None:
            p = subprocess.run([exe, "-m", "rtu", "-a", "7", "-b", "19200", "-P", "none", "-t", "3:hex", "-0", "-r", "2",
                                "-c", "2", "-1", rtu_cli], capture_output=True, text=True, timeout=20)
            assert p.returncode == 0 and "0x1234" in p.stdout and "0x5678" in p.stdout, p.stdout + p.stderr
            p = subprocess.run([exe, "-1", "-o", "0.5", "-m", "rtu", "-a", "9", "-b", "19200", "-P", "none", "-t", "4",
                                "-r", "1", rtu_cli], capture_output=True, text=True, timeout=20)
            assert p.returncode != 0 and "timed out" in p.stderr.lower()
        db = load_shipped()
        seen = {}
        while not {0x201, 0x60A, 0x700} <= set(seen):  # slcan init lines from the peer are ignored by recv
            m = rx.recv(timeout=10)
            assert m is not None, f"no CAN frames; seen {sorted(seen)}"
            if m.arbitration_id in (0x201, 0x60A, 0x700):
                seen[m.arbitration_id] = db.decode_message(m.arbitration_id, m.data)
        assert seen[0x60A]["Obj_InterfaceVersion"] == 1 and seen[0x201]["RadarState_OutputTypeCfg"] == "send_objects"
        assert seen[0x201]["RadarState_Temporary_Error"] == 0 and seen[0x201]["RadarState_Persistent_Error"] == 0
    finally:
        _stop(proc)
        rx.shutdown()
        for s in (rtu_socat, can_socat):
            s.terminate()
            s.wait(5)


def _status_after_frames(extra, n_frames=3):
    """Start `radar-edge run` with ``extra`` arguments; the status block once ``n_frames`` frames were served."""
    proc = _start(extra)
    try:
        port = None
        for line in proc.stderr:
            m = re.search(r"Modbus TCP listening on 127\.0\.0\.1:(\d+)", line)
            if m:
                port = int(m.group(1))
                break
        assert port is not None, f"radar-edge run did not start Modbus TCP (exit {proc.wait(10)})"
        c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        assert c.connect()
        try:
            while True:  # each request waits for the server: no sleeps
                st = R.decode_block(R.STATUS, c.read_input_registers(R.STATUS.base, count=R.STATUS.size,
                                                                     device_id=1).registers)
                if st["loop_state"] == 1 and st["frame_counter"] >= n_frames:
                    return st
                assert proc.poll() is None
        finally:
            c.close()
    finally:
        _stop(proc)


def test_a_board_clipping_on_its_leakage_reads_degraded_until_its_tx_power_is_lowered(tmp_path):
    from importlib import resources

    text = resources.files("hw_sim").joinpath("scenarios", "empty-d2g.toml").read_text(encoding="utf-8")
    hot = tmp_path / "empty-d2g-hot6.toml"
    hot.write_text(text + "\n[physics]\ngain_offset_db = 6.0\n", encoding="utf-8")
    st = _status_after_frames(["--source", f"sim://d2g?scenario={hot}&realtime=0&loop=1"])
    assert st["status_bits"] & (1 << R.ST_DEGRADED) and st["status_bits"] & (1 << R.ST_RADAR_OK)
    assert st["alarm"] == 0  # degraded, not a fault
    st = _status_after_frames(["--source", f"sim://d2g?scenario={hot}&realtime=0&loop=1&tx_power=2"])
    assert not st["status_bits"] & (1 << R.ST_DEGRADED) and st["status_bits"] & (1 << R.ST_RADAR_OK)
