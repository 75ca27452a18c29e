"""Outputs: Modbus register image and servers (RTU on RS-485, TCP), CAN object list.

The frame loop (:mod:`edge.loop`) gets its sinks from :func:`build_sinks`; every sink has
``publish(result: FrameResult | None, health: LoopHealth)`` (never blocks) and ``close()``.
"""

from __future__ import annotations

import logging
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["build_sinks"]


def build_sinks(config: Any, n_lanes: int, *, strict: bool = False, traffic: Any = None) -> list:
    """Create and start the outputs enabled in ``config`` (sections ``outputs.modbus``, ``outputs.can``,
    ``outputs.failsafe``; ``traffic.interval_s`` for the configuration block). ``traffic``: the pipeline's
    :class:`~edge.traffic.TrafficMonitor` (or None): its lanes in use are published, and with configured lanes
    a Modbus lane geometry apply replaces them (:meth:`~edge.traffic.TrafficMonitor.set_lanes`). A Modbus server that cannot start (port in use, no serial port) is logged as
    an error and left out, so the radar keeps serving its other outputs; ``strict=True`` raises
    :class:`~edge.outputs.modbus.OutputError` instead. A missing CAN interface is a counted fault that
    the CAN sink retries (the loop keeps running)."""
    from edge.outputs.can_out import CanSink
    from edge.outputs.modbus import ModbusSink, OutputError, initial_config_words
    from edge.outputs.registers import MAX_LANES, Links, lane_geometry

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
        try:
            sinks.insert(0, ModbusSink(mb, n, failsafe=fs, links=links, config_words=words, on_apply=on_apply,
                                       lanes=lanes, geometry_lanes=len(traffic.lanes) if configured else None).start())
        except OutputError as exc:
            if strict:
                for s in sinks:
                    s.close()
                raise
            log.error("Modbus output not started: %s", exc)
    return sinks
