"""Command-line shortcuts for the outputs, for ``radar-edge run``.

``--modbus-tcp HOST:PORT``, ``--modbus-rtu PORT`` and ``--can INTERFACE:CHANNEL`` are shorthands
for ``--set outputs.modbus.*`` / ``--set outputs.can.*``; :func:`output_overrides` turns them into
configuration overrides (command-line precedence). A malformed value is refused here; what the
values name is checked at start (:func:`edge.outputs.check_output_config`, the TCP port bound).
"""

from __future__ import annotations

import argparse
from typing import Any


def add_output_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("outputs (shorthands for --set outputs.*)")
    g.add_argument("--modbus-tcp", metavar="HOST:PORT",
                   help="serve Modbus TCP here (default 127.0.0.1:5020; 0.0.0.0:502 on a deployed box; 'off')")
    g.add_argument("--modbus-rtu", metavar="PORT",
                   help="serve Modbus RTU on this serial port, e.g. /dev/ttyAMA0 (19200 8E1, unit id 1 unless "
                        "--set outputs.modbus.rtu_baudrate/rtu_parity/rtu_stopbits/unit_id)")
    g.add_argument("--can", metavar="INTERFACE:CHANNEL",
                   help="send the CAN object list, e.g. socketcan:can0 (bring the bus up with `ip link` first; an "
                        "unknown python-can interface is refused at start, an absent can0 is retried)")


def output_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Configuration overrides from the shorthands; a malformed value is a ValueError naming it."""
    out: dict[str, Any] = {}
    tcp = getattr(args, "modbus_tcp", None)
    if tcp:
        if tcp.lower() == "off":
            out["outputs.modbus.tcp_enabled"] = False
        else:
            host, sep, port = tcp.rpartition(":")
            if not sep or not host or not port.isdigit():
                raise ValueError(f"--modbus-tcp expects HOST:PORT (e.g. 127.0.0.1:5020) or off, got {tcp!r}")
            out.update({"outputs.modbus.tcp_enabled": True, "outputs.modbus.tcp_host": host.strip("[]"),
                        "outputs.modbus.tcp_port": int(port)})
    rtu = getattr(args, "modbus_rtu", None)
    if rtu:
        out["outputs.modbus.rtu_port"] = rtu
    can_opt = getattr(args, "can", None)
    if can_opt:
        iface, sep, channel = can_opt.partition(":")
        if not sep or not iface or not channel:
            raise ValueError(f"--can expects INTERFACE:CHANNEL (e.g. socketcan:can0), got {can_opt!r}")
        out.update({"outputs.can.interface": iface, "outputs.can.channel": channel})
    return out
