"""Start-up: outputs that cannot start and configuration errors are refused at start, in one line
naming the port or key; a serial adapter or CAN interface that is merely absent is retried."""

from __future__ import annotations

import socket

import pytest

from edge.cli import main
from edge.config import ConfigError, load_config
from edge.outputs import build_sinks
from edge.outputs.modbus import OutputError

RUN = ["run", "--source", "sim://simo?realtime=0", "--frames", "3", "--status-every", "0"]


@pytest.fixture
def occupied_port():
    """A TCP port on loopback that this test holds (listening), chosen by the OS."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


def test_modbus_tcp_port_in_use_stops_the_start_naming_the_port(occupied_port, capsys):
    rc = main([*RUN, "--modbus-tcp", f"127.0.0.1:{occupied_port}"])
    out, err = capsys.readouterr()
    assert rc == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"radar-edge run: error: Modbus TCP 127.0.0.1:{occupied_port} cannot be served: ")
    assert "in use" in err
    assert "frames" not in out  # the loop never ran without the output it was configured with


def test_build_sinks_refuses_a_busy_port_and_closes_what_it_started(occupied_port, request):
    channel = f"busy-{request.node.name}"
    cfg = load_config(env={}, overrides={"outputs.modbus.tcp_port": occupied_port,
                                         "outputs.can.interface": "virtual", "outputs.can.channel": channel})
    with pytest.raises(OutputError, match=f"127.0.0.1:{occupied_port}"):
        build_sinks(cfg, 1)
    sinks = build_sinks(cfg, 1, strict=False)  # strict=False: logged, the other outputs run
    try:
        assert [type(s).__name__ for s in sinks] == ["CanSink"]
    finally:
        for s in sinks:
            s.close()


@pytest.mark.parametrize("args,words", [
    (["--can", "nosuchiface:x"], "outputs.can.interface = 'nosuchiface' is not a python-can interface"),
    (["--set", "outputs.can.interface=nosuchiface"], "outputs.can.interface = 'nosuchiface'"),
    (["--can", "socketcan:can0/1"], "outputs.can.channel = 'can0/1' is not a network interface name"),
    (["--can", "socketcan"], "--can expects INTERFACE:CHANNEL"),
    (["--modbus-rtu", "ttyAMA0"], "outputs.modbus.rtu_port = 'ttyAMA0' is not a device path"),
    (["--modbus-rtu", "/"], "outputs.modbus.rtu_port = '/' is not a serial device"),
    (["--modbus-tcp", "127.0.0.1:70000"], "outputs.modbus.tcp_port = 70000 is out of range"),
    (["--modbus-tcp", "127.0.0.1:50x"], "--modbus-tcp expects HOST:PORT"),
    (["--modbus-tcp", "256.1.1.1:5020"], "Modbus TCP 256.1.1.1:5020 cannot be served: address '256.1.1.1' does not resolve"),
])
def test_configuration_errors_are_refused_at_start_naming_the_key(args, words, capsys):
    rc = main([*RUN, "--modbus-tcp", "127.0.0.1:0", *args] if "--modbus-tcp" not in args else [*RUN, *args])
    out, err = capsys.readouterr()
    assert rc == 2, out
    assert err.count("\n") == 1 and words in err
    assert "frames" not in out


def test_an_absent_serial_adapter_or_can_interface_is_not_a_configuration_error(tmp_path):
    from edge.outputs import check_output_config

    cfg = load_config(env={}, overrides={"outputs.modbus.rtu_port": str(tmp_path / "ttyUSB-not-plugged"),
                                         "outputs.can.interface": "socketcan", "outputs.can.channel": "can7"})
    check_output_config(cfg)  # absent now, retried by the outputs
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match="outputs.modbus.rtu_port"):
        check_output_config(load_config(env={}, overrides={"outputs.modbus.rtu_port": str(tmp_path / "file")}))
