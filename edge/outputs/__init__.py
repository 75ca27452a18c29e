"""Outputs: Modbus register image and servers (RTU on RS-485, TCP), CAN object list.

The frame loop (:mod:`edge.loop`) gets its sinks from :func:`build_sinks`; every sink has
``publish(result: FrameResult | None, health: LoopHealth)`` (never blocks) and ``close()``.
"""

from __future__ import annotations

import logging
import os
import re
import stat
from typing import Any

from edge.config import ConfigError

log = logging.getLogger(__name__)

__all__ = ["build_sinks", "check_output_config"]

#: a Linux network interface name (what SocketCAN channels are): 1-15 characters, no '/' or blanks
_IFNAME = re.compile(r"[^/\s:]{1,15}")


def check_output_config(config: Any) -> None:
    """Refuse, naming the key, what no retry can fix: an unknown python-can interface, a SocketCAN
    channel that cannot be an interface name, an RTU port that is not a device path or names
    something that is not a character device. A serial adapter or CAN interface that is merely
    absent is not refused: the outputs retry it."""
    mb, cn = config.section("outputs.modbus"), config.section("outputs.can")
    if cn.interface:
        import can

        valid = sorted(can.interfaces.VALID_INTERFACES)
        if cn.interface not in valid:
            raise ConfigError(f"outputs.can.interface = {cn.interface!r} is not a python-can interface; "
                              f"one of: {', '.join(valid)}")
        if not cn.channel:
            raise ConfigError("outputs.can.channel is empty (e.g. can0)")
        if cn.interface == "socketcan" and not _IFNAME.fullmatch(cn.channel):
            raise ConfigError(f"outputs.can.channel = {cn.channel!r} is not a network interface name (e.g. can0)")
    if mb.rtu_port:
        if not os.path.isabs(mb.rtu_port):
            raise ConfigError(f"outputs.modbus.rtu_port = {mb.rtu_port!r} is not a device path (e.g. /dev/ttyAMA0)")
        try:
            st = os.stat(mb.rtu_port)
        except OSError:
            st = None  # not plugged in yet: the Modbus server retries it
        if st is not None and not stat.S_ISCHR(st.st_mode):
            raise ConfigError(f"outputs.modbus.rtu_port = {mb.rtu_port!r} is not a serial device")


def tcp_bind_error(host: str, port: int) -> str | None:
    """Why ``host:port`` cannot be listened on now (None if it can), binding as the server does."""
    import socket

    try:
        infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        return f"address {host!r} does not resolve: {exc.strerror or exc}"
    for fam, typ, proto, _, addr in infos:
        with socket.socket(fam, typ, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's create_server on Unix
            try:
                s.bind(addr)
            except OSError as exc:
                return (exc.strerror or str(exc)).lower()
    return None


def build_sinks(config: Any, n_lanes: int, *, strict: bool = True, traffic: Any = None) -> list:
    """Create and start the outputs enabled in ``config`` (sections ``outputs.modbus``, ``outputs.can``,
    ``outputs.failsafe``; ``traffic.interval_s`` for the configuration block) after :func:`check_output_config`.
    ``traffic``: the pipeline's :class:`~edge.traffic.TrafficMonitor` (or None): its lanes in use are published,
    and with configured lanes a Modbus lane geometry apply replaces them
    (:meth:`~edge.traffic.TrafficMonitor.set_lanes`). A Modbus server that cannot start (TCP port in use,
    address not on this machine) raises :class:`~edge.outputs.modbus.OutputError` naming the address;
    ``strict=False`` logs it and leaves Modbus out instead. A serial port or CAN interface that is absent is a
    counted fault the output retries (the loop keeps running)."""
    from edge.outputs.can_out import CanSink
    from edge.outputs.modbus import ModbusSink, OutputError, initial_config_words
    from edge.outputs.registers import MAX_LANES, Links, lane_geometry

    check_output_config(config)
    mb, cn, fs = config.section("outputs.modbus"), config.section("outputs.can"), config.section("outputs.failsafe")
    n = min(max(int(n_lanes), 0), MAX_LANES)
    if n_lanes > MAX_LANES:
        log.warning("%d lanes configured; outputs report the first %d", n_lanes, MAX_LANES)
    links = Links()
    sinks: list = []
    can_sink = None
    if cn.interface:
        can_sink = CanSink(cn, n, failsafe=fs, links=links).start()
        sinks.append(can_sink)
    if mb.tcp_enabled or mb.rtu_port:
        configured = traffic is not None and traffic.config.lane_mode == "configured" and 0 < len(traffic.lanes) <= n

        def on_apply(before: dict, after: dict) -> None:
            if can_sink is not None:
                can_sink.set_runtime(bool(after["can_enable"]), int(after["can_sensor_id"]), int(after["can_output_mask"]))
            if configured and lane_geometry(after) != lane_geometry(before):
                traffic.set_lanes([((lo + hi) / 2, hi - lo, d) for lo, hi, d in lane_geometry(after)])

        if mb.stale_image_s <= config.section("loop").health_period_s:
            log.warning("outputs.modbus.stale_image_s %.2f s is not above loop.health_period_s %.2f s: Modbus will show "
                        "a stalled source as 'not responding'", mb.stale_image_s, config.section("loop").health_period_s)
        interval_s = config.section("traffic").interval_s
        words = initial_config_words(mb, n, cn, interval_s, traffic.lanes if configured else ())
        lanes = (lambda: traffic.lanes) if traffic is not None else None
        busy = tcp_bind_error(mb.tcp_host, mb.tcp_port) if strict and mb.tcp_enabled and mb.tcp_port else None
        try:
            if busy:
                hint = f" (which program holds it: ss -ltnp 'sport = :{mb.tcp_port}')" if "in use" in busy else ""
                raise OutputError(f"Modbus TCP {mb.tcp_host}:{mb.tcp_port} cannot be served: {busy}{hint}")
            sinks.insert(0, ModbusSink(mb, n, failsafe=fs, links=links, config_words=words, on_apply=on_apply,
                                       lanes=lanes, geometry_lanes=len(traffic.lanes) if configured else None).start())
        except OutputError as exc:
            where = ", ".join([f"TCP {mb.tcp_host}:{mb.tcp_port}"] * mb.tcp_enabled + [f"RTU {mb.rtu_port}"] * bool(mb.rtu_port))
            if strict:
                for s in sinks:
                    s.close()
                if busy:
                    raise
                raise OutputError(f"Modbus ({where}) cannot start: {str(exc).removeprefix('Modbus: ')}") from exc
            log.error("Modbus output (%s) not started: %s", where, exc)
    return sinks
