"""Output shorthands for `radar-edge run`, the `registers` and `dbc` commands, build_sinks from config."""

from __future__ import annotations

import argparse

import pytest

from edge.config import load_config
from edge.outputs import build_sinks
from edge.outputs.cli_options import add_output_arguments, output_overrides
from edge.outputs.can_out import CanSink
from edge.outputs.modbus import ModbusSink


def _parse(argv):
    p = argparse.ArgumentParser()
    add_output_arguments(p)
    return output_overrides(p.parse_args(argv))


def test_shorthands_become_config_overrides():
    o = _parse(["--modbus-tcp", "0.0.0.0:502", "--modbus-rtu", "/dev/ttyAMA0", "--can", "socketcan:can0"])
    cfg = load_config(env={}, overrides=o)
    assert (cfg["outputs.modbus"].tcp_host, cfg["outputs.modbus"].tcp_port) == ("0.0.0.0", 502)
    assert cfg["outputs.modbus"].rtu_port == "/dev/ttyAMA0"
    assert (cfg["outputs.can"].interface, cfg["outputs.can"].channel) == ("socketcan", "can0")
    assert _parse(["--modbus-tcp", "off"]) == {"outputs.modbus.tcp_enabled": False}
    assert _parse([]) == {}
    for bad in (["--modbus-tcp", "5020"], ["--modbus-tcp", "host:abc"], ["--can", "can0"]):
        with pytest.raises(ValueError):
            _parse(bad)


def test_defaults_tcp_on_loopback_rtu_and_can_off():
    cfg = load_config(env={})
    mb, cn = cfg["outputs.modbus"], cfg["outputs.can"]
    assert mb.tcp_enabled and (mb.tcp_host, mb.tcp_port) == ("127.0.0.1", 5020)
    assert (mb.rtu_baudrate, mb.rtu_parity, mb.rtu_stopbits, mb.unit_id) == (19200, "E", 1, 1)
    assert mb.rtu_port == "" and cn.interface == "" and not mb.config_writes
    assert cfg["outputs.failsafe"].presence == "on"


def test_build_sinks_starts_what_is_configured(request):
    cfg = load_config(env={}, overrides={"outputs.modbus.tcp_port": 0, "outputs.can.interface": "virtual",
                                         "outputs.can.channel": f"bs-{request.node.name}"})
    sinks = build_sinks(cfg, 3)
    try:
        assert [type(s) for s in sinks] == [ModbusSink, CanSink]
        assert sinks[0].tcp_address[1] > 0 and sinks[0].n_lanes == 3
    finally:
        for s in sinks:
            s.close()
    none = build_sinks(load_config(env={}, overrides={"outputs.modbus.tcp_enabled": False}), 2)
    assert none == []


def test_registers_and_dbc_commands(tmp_path, capsys):
    from edge.cli import main
    from edge.outputs.can_db import dbc_text
    from edge.outputs.registers import markdown

    assert main(["registers"]) == 0
    assert capsys.readouterr().out == markdown() + "\n"
    out = tmp_path / "r.dbc"
    assert main(["dbc", "--out", str(out), "--sensor-id", "3"]) == 0
    assert out.read_text(encoding="utf-8") == dbc_text(3)
    assert "BO_ 1595 Obj_1_General" in out.read_text(encoding="utf-8")  # 0x60B + 0x30
    for cmd in ("registers", "dbc"):
        with pytest.raises(SystemExit):
            main([cmd, "--help"])
        assert "examples:" in capsys.readouterr().out


def test_modbus_configuration_apply_reaches_the_can_output(request):
    import can
    from pymodbus.client import ModbusTcpClient

    from edge.outputs import registers as R
    from tests.edge.outputs.helpers import health, make_result

    channel = f"apply-{request.node.name}"
    rx = can.Bus(interface="virtual", channel=channel)
    cfg = load_config(env={}, overrides={"outputs.modbus.tcp_port": 0, "outputs.modbus.config_writes": True,
                                         "outputs.can.interface": "virtual", "outputs.can.channel": channel})
    sinks = build_sinks(cfg, 1)
    mb, cs = sinks
    c = ModbusTcpClient(*mb.tcp_address[:1], port=mb.tcp_address[1], timeout=2, retries=0)
    try:
        assert c.connect()
        assert c.read_holding_registers(R.CONFIG_BASE + 6, count=4, device_id=1).registers == [1, 2, 0, 0b11101]
        assert not c.write_register(R.CONFIG_BASE + 8, 2, device_id=1).isError()  # sensor id 2
        assert not c.write_register(R.CMD_ADDR, R.CMD_APPLY, device_id=1).isError()
        assert mb.sync()  # the applied configuration reached this side (publish would also pick it up)
        t = 5_000_000_000
        for s in sinks:
            s.publish(make_result(1, t, presence=(True,)), health(t, t))
        ids = set()
        while 0x62A not in ids:  # the sender thread delivers; recv waits for it (no sleeps)
            m = rx.recv(timeout=10)
            assert m is not None, sorted(ids)
            ids.add(m.arbitration_id)
        assert 0x60A not in ids and not mb.links.config_pending_restart  # live setting, no restart needed
    finally:
        c.close()
        for s in sinks:
            s.close()
        rx.shutdown()
