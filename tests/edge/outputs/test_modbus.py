"""Modbus servers end to end: a real pymodbus client (and mbpoll) over TCP on an OS-chosen port and
over RTU on a socat pty pair; exceptions, unit-id silence, configuration writes, tearing."""

from __future__ import annotations

import contextlib
import re
import shutil
import subprocess
import threading

import numpy as np
import pytest
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusIOException

from edge.outputs import registers as R
from edge.outputs.config import ModbusConfig
from edge.outputs.modbus import ModbusSink
from tests.edge.outputs.helpers import PERIOD_NS, health, make_lane_stats, make_result, make_tracks

T0 = 1_000_000_000
N_LANES = 4


def _publish(sink, seq, rng, lanes=False):
    t = T0 + seq * PERIOD_NS
    res = make_result(seq, t, make_tracks(rng, 20), (True, False, False, True),
                      make_lane_stats(rng, N_LANES, seq=seq % 256, t_ns=t) if lanes else ())
    sink.publish(res, health(t, t, frames=seq))
    assert sink.sync()  # the server process has the image (publish itself never waits)
    return res


@pytest.fixture
def tcp_sink(request):
    writes = getattr(request, "param", False)
    # the tests publish on a fake timeline starting at T0: the watchdog must use the same clock, or
    # it sees every published frame as ancient and faults the image while the tests read it
    sink = ModbusSink(ModbusConfig(tcp_host="127.0.0.1", tcp_port=0, config_writes=writes), N_LANES,
                      clock_ns=lambda: T0).start()
    yield sink
    sink.close()


@pytest.fixture
def client(tcp_sink):
    host, port = tcp_sink.tcp_address
    c = ModbusTcpClient(host, port=port, timeout=2, retries=0)
    assert c.connect()
    yield c
    c.close()


def test_tcp_reads_back_the_image(tcp_sink, client):
    rng = np.random.default_rng(11)
    _publish(tcp_sink, 77, rng, lanes=True)
    img = tcp_sink.image()
    for fc_read in (client.read_input_registers, client.read_holding_registers):
        for a, b in R.READ_RANGES:
            for start in range(a, b, 125):
                n = min(125, b - start)
                rr = fc_read(start, count=n, device_id=1)
                assert not rr.isError(), rr
                expect = img[start: start + n] if start < R.CONFIG_BASE else tcp_sink.config_words[start - R.CONFIG_BASE:][:n]
                assert rr.registers == expect
    rr = client.read_input_registers(2, count=2, device_id=1)
    assert client.convert_from_registers(rr.registers, client.DATATYPE.UINT32) == 0x12345678  # word_order="big"
    assert client.read_input_registers(R.STATUS.base + 4, count=1, device_id=1).registers == [77]
    # TCP answers any unit id (gateways address it as 0, 1 or 255)
    for uid in (0, 7, 255):
        assert client.read_input_registers(0, count=1, device_id=uid).registers == [R.MAP_MAGIC]


@pytest.mark.parametrize("address,count", [(R.LANE_BASE + R.MAX_LANES * R.LANE_STRIDE, 1), (500, 4), (990, 4),
                                           (1250, 10), (2095, 6), (3000, 1)])
def test_illegal_addresses_give_exception_02(client, address, count):
    rr = client.read_holding_registers(address, count=count, device_id=1)
    assert rr.isError() and rr.exception_code == 2


def test_writes_are_refused_when_config_writes_are_off(client):
    rr = client.write_register(R.CONFIG_BASE + 4, 30, device_id=1)
    assert rr.isError() and rr.exception_code == 1
    rr = client.write_register(R.STATUS.base, 1, device_id=1)  # telemetry is read-only
    assert rr.isError() and rr.exception_code == 2
    rr = client.read_coils(0, count=8, device_id=1)
    assert rr.isError() and rr.exception_code == 1


@pytest.mark.parametrize("tcp_sink", [True], indirect=True)
def test_config_writes_validated_staged_and_applied(tcp_sink, client):
    applied = []
    tcp_sink.on_apply = lambda before, after: applied.append(after)
    base = R.CONFIG_BASE
    gen0 = client.read_holding_registers(R.GENERATION_ADDR, count=1, device_id=1).registers[0]
    # telemetry stays read-only; reserved and read-only config registers are illegal addresses
    assert client.write_register(10, 1, device_id=1).exception_code == 2
    assert client.write_register(base + 50, 1, device_id=1).exception_code == 2
    assert client.write_register(R.GENERATION_ADDR, 9, device_id=1).exception_code == 2
    # out of range -> 03, nothing staged
    assert client.write_register(base + 4, 5, device_id=1).exception_code == 3
    assert client.write_registers(base + 6, [1, 9], device_id=1).exception_code == 3
    # staged: visible on read, not applied
    assert not client.write_registers(base + 4, [120, 2], device_id=1).isError()
    assert client.read_holding_registers(base + 4, count=2, device_id=1).registers == [120, 2]
    assert tcp_sink.sync() and not applied
    # inconsistent lane geometry (x_min >= x_max) is rejected by the apply command
    assert not client.write_registers(base + 10, [50, 0xFFF6, 0, 1], device_id=1).isError()  # 5.0 m .. -1.0 m
    rr = client.write_register(R.CMD_ADDR, R.CMD_APPLY, device_id=1)
    assert rr.isError() and rr.exception_code == 3
    assert client.read_holding_registers(R.CMD_STATUS_ADDR, count=1, device_id=1).registers == [2]
    assert not client.write_registers(base + 10, [0xFFE2, 0xFFFB], device_id=1).isError()  # -3.0 .. -0.5 m
    assert not client.write_register(base + 0, 17, device_id=1).isError()
    assert not client.write_register(R.CMD_ADDR, R.CMD_APPLY, device_id=1).isError()
    regs = client.read_holding_registers(R.CMD_ADDR, count=3, device_id=1).registers
    assert regs == [0, gen0 + 1, 1]
    assert tcp_sink.sync()  # the applied configuration reaches the frame loop's side
    assert applied and applied[-1]["interval_s"] == 120 and applied[-1]["lane1_x_min"] == pytest.approx(-3.0)
    assert tcp_sink.unit_id == 17 and tcp_sink.links.config_pending_restart  # interval needs a restart
    _publish(tcp_sink, 1, np.random.default_rng(0))
    st = client.read_input_registers(R.STATUS.base, count=1, device_id=1).registers[0]
    assert st & (1 << R.ST_CONFIG_PENDING) and st & (1 << R.ST_WRITES_ENABLED)
    # discard staged values
    assert not client.write_register(base + 4, 600, device_id=1).isError()
    assert not client.write_register(R.CMD_ADDR, R.CMD_RESTART_COMMS, device_id=1).isError()
    assert client.read_holding_registers(base + 4, count=1, device_id=1).registers == [120]
    # unknown commands and reboot are refused
    assert client.write_register(R.CMD_ADDR, R.CMD_REBOOT, device_id=1).exception_code == 3
    assert client.write_register(R.CMD_ADDR, 0x1234, device_id=1).exception_code == 3


def test_single_reads_never_tear_and_the_tear_byte_detects_split_reads(tcp_sink, client):
    stop = threading.Event()
    rng = np.random.default_rng(5)

    def writer():
        seq = 0
        while not stop.is_set():
            seq += 1
            t = T0 + seq * PERIOD_NS
            # every track's x encodes the frame: a record from another frame is recognisable
            tracks = [tr.__class__(**{**tr.__dict__, "x_m": (seq % 200) / 10.0, "range_m": 10.0 + i})
                      for i, tr in enumerate(make_tracks(rng, 14))]
            tcp_sink.publish(make_result(seq, t, tracks, (False,) * N_LANES), health(t, t, frames=seq))

    # publish frame 0 first: the writer thread may start after our first read
    tcp_sink.publish(make_result(0, T0, [tr.__class__(**{**tr.__dict__, "x_m": 0.0}) for tr in make_tracks(rng, 14)],
                                 (False,) * N_LANES), health(T0, T0))
    assert tcp_sink.sync()
    th = threading.Thread(target=writer)
    th.start()
    try:
        seen_frames, split_mismatch = set(), 0
        for _ in range(150):
            regs = client.read_input_registers(R.TRACK_HEADER, count=125, device_id=1).registers
            fc = regs[0]
            seen_frames.add(fc)
            for k in range(14):
                rec = regs[8 + k * 8: 16 + k * 8]
                assert rec[7] >> 8 == fc & 0xFF
                assert rec[2] == fc % 200  # x in 0.1 m
            # two requests: header then records; when the frame changed in between, the tear byte shows it
            hdr = client.read_input_registers(R.TRACK_HEADER, count=1, device_id=1).registers[0]
            rec = client.read_input_registers(R.TRACK_BASE, count=8, device_id=1).registers
            if rec[2] != hdr % 200:
                split_mismatch += 1
                if rec[7] >> 8 == hdr & 0xFF:
                    # an 8-bit tear byte cannot tell frames 256 apart (8.5 s at 30 Hz; this writer is
                    # unthrottled): a match is only allowed when the record's frame is hdr + 256 k
                    assert any((hdr + 256 * k) % 200 == rec[2] for k in range(1, 26)), (hdr, rec)
        assert len(seen_frames) > 1  # the writer really ran while we read
    finally:
        stop.set()
        th.join()


# --- RTU over a socat pty pair ----------------------------------------------------------------
@contextlib.contextmanager
def _socat_pair(a, b):
    socat = shutil.which("socat")
    if socat is None:
        pytest.skip("socat not installed (apt-get install socat): needed for the RTU pty pair")
    proc = subprocess.Popen([socat, "-d", "-d", f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
                            stderr=subprocess.PIPE, text=True)
    try:
        for line in proc.stderr:  # socat reports when both ends exist
            if "starting data transfer loop" in line:
                break
        else:
            pytest.fail("socat did not start")
        yield str(a), str(b)
    finally:
        proc.terminate()
        proc.wait(5)


@pytest.fixture
def pty_pair(tmp_path):
    with _socat_pair(tmp_path / "ttyV0", tmp_path / "ttyV1") as pair:
        yield pair


@pytest.fixture
def rtu_sink(pty_pair):
    # a pty refuses parity settings (EINVAL), so the pty test runs 8N1; the default 8E1 is for real UARTs
    cfg = ModbusConfig(tcp_enabled=False, rtu_port=pty_pair[0], unit_id=3, rtu_parity="N")
    sink = ModbusSink(cfg, N_LANES).start()
    yield sink, pty_pair[1]
    sink.close()


def test_rtu_reads_and_silence_for_other_unit_ids(rtu_sink):
    sink, port = rtu_sink
    _publish(sink, 321, np.random.default_rng(2), lanes=True)
    img = sink.image()
    c = ModbusSerialClient(port, baudrate=19200, parity="N", bytesize=8, stopbits=1, timeout=0.5, retries=0)
    assert c.connect()
    try:
        rr = c.read_input_registers(0, count=16, device_id=3)
        assert rr.registers == img[:16]
        rr = c.read_holding_registers(R.LANE_BASE, count=32, device_id=3)
        assert rr.registers == img[R.LANE_BASE: R.LANE_BASE + 32]
        rr = c.read_holding_registers(R.TRACK_HEADER, count=125, device_id=3)
        assert rr.registers == img[R.TRACK_HEADER: R.TRACK_HEADER + 125]
        assert c.write_register(0, 1, device_id=3).exception_code == 2
        assert c.read_holding_registers(400, count=1, device_id=3).exception_code == 2
        with pytest.raises(ModbusIOException):
            c.read_holding_registers(0, count=1, device_id=4)  # another device on the line: no reply
        sink.request_counters()
        assert sink.sync() and sink.server_counters["ignored_unit_id"] >= 1
        assert c.read_input_registers(0, count=1, device_id=3).registers == [R.MAP_MAGIC]  # line still in sync
    finally:
        c.close()


# --- mbpoll (Debian package), the tool field technicians use ----------------------------------
def _mbpoll():
    exe = shutil.which("mbpoll")
    if exe is None:
        pytest.skip("mbpoll not installed (apt-get install mbpoll)")
    return exe


def _mbpoll_values(out: str) -> dict[int, int]:
    return {int(a): int(v, 0) for a, v in re.findall(r"^\[(\d+)\]:\s+(-?\w+)", out, re.M)}


def test_mbpoll_tcp(tcp_sink):
    exe = _mbpoll()
    _publish(tcp_sink, 4660, np.random.default_rng(3))
    host, port = tcp_sink.tcp_address
    p = subprocess.run([exe, "-m", "tcp", "-p", str(port), "-a", "1", "-t", "3:hex", "-0", "-r", "0", "-c", "4", "-1",
                        host], capture_output=True, text=True, timeout=20)
    assert p.returncode == 0, p.stderr
    assert _mbpoll_values(p.stdout) == {0: 0x5452, 1: R.MAP_VERSION, 2: 0x1234, 3: 0x5678}
    p = subprocess.run([exe, "-m", "tcp", "-p", str(port), "-a", "1", "-t", "3:int", "-B", "-r", "3", "-c", "1", "-1",
                        host], capture_output=True, text=True, timeout=20)
    assert p.returncode == 0 and _mbpoll_values(p.stdout) == {3: 0x12345678}, p.stdout + p.stderr
    p = subprocess.run([exe, "-m", "tcp", "-p", str(port), "-a", "1", "-t", "4", "-r", "21", "-1", host],
                       capture_output=True, text=True, timeout=20)
    assert _mbpoll_values(p.stdout) == {21: 4660}, p.stdout  # register number 40021 = address 20: frame counter
    p = subprocess.run([exe, "-m", "tcp", "-p", str(port), "-a", "1", "-t", "4", "-r", "1", "-1", host, "9"],
                       capture_output=True, text=True, timeout=20)
    assert p.returncode != 0 and "Illegal data address" in p.stderr


def test_mbpoll_rtu_unit_id(rtu_sink):
    exe = _mbpoll()
    sink, port = rtu_sink
    _publish(sink, 99, np.random.default_rng(4))
    ok = subprocess.run([exe, "-m", "rtu", "-a", "3", "-b", "19200", "-P", "none", "-t", "3:hex", "-0", "-r", "0",
                         "-c", "2", "-1", port], capture_output=True, text=True, timeout=20)
    assert ok.returncode == 0, ok.stderr
    assert _mbpoll_values(ok.stdout) == {0: 0x5452, 1: R.MAP_VERSION}
    other = subprocess.run([exe, "-1", "-o", "0.5", "-m", "rtu", "-a", "5", "-b", "19200", "-P", "none", "-t", "4",
                            "-r", "1", port], capture_output=True, text=True, timeout=20)
    assert other.returncode != 0 and "timed out" in other.stderr.lower()


def test_start_fails_cleanly_for_a_busy_tcp_port(tcp_sink):
    from edge.outputs.modbus import OutputError

    host, port = tcp_sink.tcp_address
    with pytest.raises(OutputError, match="Modbus"):
        ModbusSink(ModbusConfig(tcp_host=host, tcp_port=port), 1).start()


@pytest.mark.parametrize("tcp_enabled", [True, False])
def test_a_missing_serial_port_is_retried_and_tcp_serves_meanwhile(tmp_path, tcp_enabled):
    """An RS-485 adapter unplugged at start: a counted fault, retried until it appears (before, a missing
    serial port stopped the whole Modbus server, TCP included)."""
    a, b = tmp_path / "ttyV0", tmp_path / "ttyV1"
    cfg = ModbusConfig(tcp_enabled=tcp_enabled, tcp_host="127.0.0.1", tcp_port=0, rtu_port=str(a), unit_id=3,
                       rtu_parity="N", rtu_retry_s=0.1)
    sink = ModbusSink(cfg, N_LANES, clock_ns=lambda: T0).start()
    try:
        assert sink.rtu_error is not None and str(a) in sink.rtu_error
        assert sink.counters["rtu_open_failures"] == 1
        _publish(sink, 5, np.random.default_rng(3))
        if tcp_enabled:
            host, port = sink.tcp_address
            c = ModbusTcpClient(host, port=port, timeout=2, retries=0)
            assert c.connect()
            assert c.read_input_registers(0, count=1, device_id=1).registers == [R.MAP_MAGIC]
            c.close()
        with _socat_pair(a, b):  # the adapter is plugged in
            rtu = ModbusSerialClient(str(b), baudrate=19200, parity="N", bytesize=8, stopbits=1, timeout=0.3,
                                     retries=0)
            assert rtu.connect()
            regs = None
            for _ in range(50):  # the server retries every 0.1 s; each failed read waits out its 0.3 s timeout
                try:
                    r = rtu.read_input_registers(0, count=1, device_id=3)
                except ModbusIOException:
                    continue
                if not r.isError():
                    regs = r.registers
                    break
            rtu.close()
            assert regs == [R.MAP_MAGIC]
            sink.request_counters()
            assert sink.sync()
            assert sink.server_counters["rtu_open"] == 1 and sink.server_counters["rtu_open_failures"] >= 1
            assert sink.rtu_error is None
    finally:
        sink.close()


def test_unit_id_applied_over_tcp_moves_the_rtu_device(pty_pair):
    cfg = ModbusConfig(tcp_port=0, rtu_port=pty_pair[0], unit_id=3, rtu_parity="N", config_writes=True)
    sink = ModbusSink(cfg, N_LANES).start()
    tcp = ModbusTcpClient(*sink.tcp_address[:1], port=sink.tcp_address[1], timeout=2, retries=0)
    rtu = ModbusSerialClient(pty_pair[1], baudrate=19200, parity="N", bytesize=8, stopbits=1, timeout=0.5, retries=0)
    try:
        assert tcp.connect() and rtu.connect()
        _publish(sink, 5, np.random.default_rng(9))
        assert rtu.read_input_registers(0, count=1, device_id=3).registers == [R.MAP_MAGIC]
        assert not tcp.write_register(R.CONFIG_BASE, 9, device_id=1).isError()
        assert rtu.read_input_registers(0, count=1, device_id=3).registers == [R.MAP_MAGIC]  # staged only
        assert not tcp.write_register(R.CMD_ADDR, R.CMD_APPLY, device_id=1).isError()
        assert rtu.read_input_registers(0, count=1, device_id=9).registers == [R.MAP_MAGIC]
        with pytest.raises(ModbusIOException):
            rtu.read_input_registers(0, count=1, device_id=3)  # the old id is now another device's
        assert sink.sync() and sink.unit_id == 9 and not sink.links.config_pending_restart
    finally:
        tcp.close()
        rtu.close()
        sink.close()


def test_a_dead_server_process_is_restarted_with_the_applied_configuration():
    # no watchdog thread racing with the explicit check_server calls below
    sink = ModbusSink(ModbusConfig(tcp_port=0, config_writes=True), N_LANES, watchdog_period_s=3600.0).start()
    try:
        host, port = sink.tcp_address
        c = ModbusTcpClient(host, port=port, timeout=2, retries=0)
        assert c.connect()
        assert not c.write_register(R.CONFIG_BASE + 4, 300, device_id=1).isError()
        assert not c.write_register(R.CMD_ADDR, R.CMD_APPLY, device_id=1).isError()
        c.close()
        assert sink.sync()
        assert not sink.check_server(now_s=1e9)  # alive: nothing to do
        sink._proc.kill()  # simulate a crash of the server process
        sink._proc.join(10)
        assert not sink.check_server(now_s=-1.0)  # inside the back-off window
        assert sink.check_server(now_s=1e9) and sink.counters["server_restarts"] == 1
        _publish(sink, 3, np.random.default_rng(1))
        host, port = sink.tcp_address  # port 0 in tests: the OS may give another one
        c = ModbusTcpClient(host, port=port, timeout=2, retries=0)
        assert c.connect()
        try:
            assert c.read_input_registers(R.STATUS.base + 4, count=1, device_id=1).registers == [3]
            assert c.read_holding_registers(R.CONFIG_BASE + 4, count=1, device_id=1).registers == [300]
            assert c.read_holding_registers(R.GENERATION_ADDR, count=1, device_id=1).registers == [1]
        finally:
            c.close()
    finally:
        sink.close()
