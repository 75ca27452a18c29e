"""Modbus RTU (RS-485) and Modbus TCP servers over one register image (pymodbus 3.16).

The frame loop calls :meth:`ModbusSink.publish`, which builds a complete new image
(:class:`~edge.outputs.registers.ImageBuilder`) and swaps one reference: that is the only write.
The servers run in their own thread with their own asyncio loop; a pymodbus ``SimDevice`` action
copies the requested registers out of the current image for every read, so RTU and TCP always show
the same, untorn data and the frame loop never waits on a Modbus client.

Only the configuration block (2000-2099) is writable. Writes are refused with exception 01 unless
``outputs.modbus.config_writes`` is on; then every register is validated (exception 03 out of
range, 02 for reserved/read-only ones) and staged, and the command register 2090 applies (0xA5A5)
or discards (0x5A5A) the staged values. RTU stays silent for unit ids other than its own (a shared
RS-485 line); TCP answers every unit id.

pymodbus facts this relies on (3.16.1, see the project's outputs reference): ``SimDevice(id=0)``
answers every unit id; ``trace_pdu`` returning ``None`` for a request drops it without a reply;
the action is called for every read and write after pymodbus's own address/read-only checks.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from typing import Any, Callable

from edge.outputs.config import BAUD_CODES, CAN_BITRATE_CODES, PARITY_CODES, FailsafeConfig, ModbusConfig
from edge.outputs.registers import (
    CMD_ADDR, CMD_APPLY, CMD_RESTART_COMMS, CMD_STATUS_ADDR, CONFIG, CONFIG_BASE, CONFIG_SIZE, GENERATION_ADDR,
    MAX_LANES, READ_RANGES, ImageBuilder, Links, config_values, default_config_words,
)
from edge.outputs.state import OutputState
from edge.types import FrameResult, LoopHealth

log = logging.getLogger(__name__)

try:
    from termios import error as _TermiosError
except ImportError:  # pragma: no cover - not on POSIX
    _TermiosError = OSError

READ_FCS = (3, 4)
WRITE_FCS = (6, 16)
_CFG_REG = {r.offset: r for r in CONFIG.regs}
#: configuration registers that take effect without a restart
LIVE_KEYS = frozenset({"unit_id", "can_enable", "can_sensor_id", "can_output_mask", "command", "generation",
                       "command_status"})


class OutputError(RuntimeError):
    """An output could not be started (port in use, no such serial port...)."""


_START_ERRORS = (OSError, RuntimeError, ValueError, _TermiosError)  # pymodbus: RuntimeError "Could not start listen"


class ConfigBlock:
    """Staged and applied configuration words (owned by the Modbus thread)."""

    def __init__(self, words: list[int], on_apply: Callable[[dict[str, Any], dict[str, Any]], None] | None = None):
        self.applied = list(words)
        self.staged = list(words)
        self.initial = list(words)
        self.on_apply = on_apply

    def write(self, offset: int, values: list[int]) -> int | None:
        """Validate and stage ``values`` from ``offset``; returns an exception code or None."""
        for i, raw in enumerate(values):
            off = offset + i
            reg = _CFG_REG.get(off)
            if reg is None or not reg.writable:
                return 2
            v = raw - 0x10000 if reg.kind == "s16" and raw & 0x8000 else raw
            if not reg.lo <= v <= reg.hi:
                return 3
            if reg.name == "command":
                code = self._command(raw)
                if code is not None:
                    return code
            else:
                self.staged[off] = raw & 0xFFFF
        return None

    def _command(self, raw: int) -> int | None:
        st = CMD_STATUS_ADDR - CONFIG_BASE
        if raw == CMD_APPLY:
            problem = validate_config(config_values(self.staged))
            if problem:
                log.warning("configuration apply rejected: %s", problem)
                self.staged[st] = 2
                return 3
            before = config_values(self.applied)
            gen = GENERATION_ADDR - CONFIG_BASE
            self.staged[gen] = (self.staged[gen] + 1) & 0xFFFF
            self.staged[st] = 1
            self.applied = list(self.staged)
            after = config_values(self.applied)
            log.info("configuration generation %d applied: %s", self.staged[gen],
                     {k: v for k, v in after.items() if before.get(k) != v})
            if self.on_apply is not None:
                self.on_apply(before, after)
            return None
        if raw == CMD_RESTART_COMMS:
            self.staged = list(self.applied)
            self.staged[st] = 3
            return None
        return 3  # unknown command, or reboot (refused)

    def pending_restart(self) -> bool:
        now, first = config_values(self.applied), config_values(self.initial)
        return any(now[k] != first[k] for k in now if k not in LIVE_KEYS)


def validate_config(v: dict[str, Any]) -> str | None:
    """Cross-register checks made when the command register applies a configuration."""
    for k in range(1, MAX_LANES + 1):
        if v.get(f"lane{k}_enabled") and v[f"lane{k}_x_min"] >= v[f"lane{k}_x_max"]:
            return f"lane {k}: x_min {v[f'lane{k}_x_min']:.1f} m must be below x_max {v[f'lane{k}_x_max']:.1f} m"
    if v.get("lanes") and sum(bool(v.get(f"lane{k}_enabled")) for k in range(1, MAX_LANES + 1)) > v["lanes"]:
        return "more lanes enabled than configured"
    return None


def initial_config_words(cfg: ModbusConfig, n_lanes: int, can: Any = None, interval_s: float = 60.0) -> list[int]:
    words = default_config_words({
        "unit_id": cfg.unit_id, "baud_code": BAUD_CODES.index(cfg.rtu_baudrate),
        "parity_code": PARITY_CODES.index(cfg.rtu_parity), "stop_bits": cfg.rtu_stopbits,
        "interval_s": int(interval_s), "lanes": max(1, n_lanes),
        "can_enable": int(bool(can is not None and can.interface)),
        "can_bitrate_code": CAN_BITRATE_CODES.index(can.bitrate) if can is not None else 2,
        "can_sensor_id": can.sensor_id if can is not None else 0,
        "can_output_mask": can_output_mask(can),
    })
    return words


def can_output_mask(can: Any) -> int:
    if can is None:
        return 0b11101
    return (1 | (can.send_quality << 1) | (can.send_extended << 2) | (can.send_lane_stats << 3)
            | (can.send_presence << 4))


class ModbusSink:
    """Output sink: Modbus TCP and/or RTU servers in their own thread, fed one image per publish."""

    def __init__(
        self,
        cfg: ModbusConfig,
        n_lanes: int,
        *,
        failsafe: FailsafeConfig | None = None,
        links: Links | None = None,
        config_words: list[int] | None = None,
        on_apply: Callable[[dict[str, Any], dict[str, Any]], None] | None = None,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        wall_clock: Callable[[], float] = time.time,
        watchdog_period_s: float = 0.25,
    ) -> None:
        self.cfg = cfg
        self.n_lanes = n_lanes
        self.links = links or Links()
        self.links.writes_enabled = cfg.config_writes
        self.state = OutputState(n_lanes, failsafe)
        self.builder = ImageBuilder(n_lanes, serial_number=cfg.serial_number, links=self.links, wall_clock=wall_clock)
        self.config = ConfigBlock(config_words or initial_config_words(cfg, n_lanes), self._applied)
        self._user_on_apply = on_apply
        self.unit_id = cfg.unit_id  # live: changed by an applied configuration
        self._clock_ns = clock_ns
        self._watchdog_period_s = watchdog_period_s
        self._lock = threading.Lock()
        self._image: list[int] = self.builder.initial_image()
        self._watchdog_fired = False
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._servers: list[Any] = []
        self.tcp_address: tuple[str, int] | None = None
        self.counters = {"reads": 0, "writes": 0, "exceptions": 0, "ignored_unit_id": 0, "watchdog": 0}

    # --- the frame loop's side (single writer) ----------------------------------------------
    def publish(self, result: FrameResult | None, health: LoopHealth) -> None:
        snap = self.state.update(result, health)
        with self._lock:
            self._image = self.builder.build(snap)
            self._watchdog_fired = False

    def image(self) -> list[int]:
        """The current image (a reference to an immutable-by-convention list)."""
        return self._image

    def watchdog(self, now_ns: int | None = None) -> bool:
        """Fault the image when the frame loop went silent (nothing published for stale_after_s).

        Runs in the server thread every ``watchdog_period_s``; tests call it with a fake clock.
        """
        snap = self.state.check(self._clock_ns() if now_ns is None else now_ns)
        if snap is None or self._watchdog_fired:
            return False
        if not self._lock.acquire(blocking=False):
            return False
        try:
            self._image = self.builder.build(snap)
            self._watchdog_fired = True
            self.counters["watchdog"] += 1
        finally:
            self._lock.release()
        log.warning("no results or heartbeats from the frame loop: Modbus status shows the fault")
        return True

    def _applied(self, before: dict[str, Any], after: dict[str, Any]) -> None:
        self.unit_id = int(after["unit_id"])
        self.links.config_pending_restart = self.config.pending_restart()
        if self._user_on_apply is not None:
            self._user_on_apply(before, after)

    # --- pymodbus side ----------------------------------------------------------------------
    async def _action(self, fc: int, start: int, address: int, count: int, regs: list[int],
                      values: list[int] | list[bool] | None) -> Any:
        from pymodbus.constants import ExcCodes

        if values is None:
            if fc in WRITE_FCS:
                return None  # pymodbus reads back after a write: the written values are in regs already
            if fc not in READ_FCS:
                self.counters["exceptions"] += 1
                return ExcCodes.ILLEGAL_FUNCTION
            self.counters["reads"] += 1
            src = self.config.staged if address >= CONFIG_BASE else self._image
            off = CONFIG_BASE if address >= CONFIG_BASE else 0
            regs[address - start: address - start + count] = src[address - off: address - off + count]
            return None
        if fc not in WRITE_FCS:
            self.counters["exceptions"] += 1
            return ExcCodes.ILLEGAL_FUNCTION
        if not self.cfg.config_writes:
            self.counters["exceptions"] += 1
            return ExcCodes.ILLEGAL_FUNCTION
        if not CONFIG_BASE <= address < CONFIG_BASE + CONFIG_SIZE:
            self.counters["exceptions"] += 1
            return ExcCodes.ILLEGAL_ADDRESS
        code = self.config.write(address - CONFIG_BASE, [int(v) for v in values])
        if code is not None:
            self.counters["exceptions"] += 1
            return {1: ExcCodes.ILLEGAL_FUNCTION, 2: ExcCodes.ILLEGAL_ADDRESS, 3: ExcCodes.ILLEGAL_VALUE}[code]
        self.counters["writes"] += 1
        return None

    def _rtu_filter(self, sending: bool, pdu: Any) -> Any:
        if not sending and pdu.dev_id != self.unit_id:
            self.counters["ignored_unit_id"] += 1
            return None  # another device on the line: stay silent
        return pdu

    def _device(self) -> Any:
        from pymodbus.simulator import DataType, SimData, SimDevice

        blocks = []
        for a, b in READ_RANGES:
            blocks.append(SimData(a, count=b - a, datatype=DataType.REGISTERS, readonly=a < CONFIG_BASE))
        return SimDevice(id=0, simdata=blocks, action=self._action)

    async def _serve(self, ready: threading.Event, errors: list[BaseException]) -> None:
        from pymodbus.framer import FramerType
        from pymodbus.server import ModbusSerialServer, ModbusTcpServer

        self._stop = asyncio.Event()
        try:
            if self.cfg.tcp_enabled:
                tcp = ModbusTcpServer(self._device(), address=(self.cfg.tcp_host, self.cfg.tcp_port))
                await tcp.serve_forever(background=True)
                if tcp.transport is None:
                    raise OutputError(f"Modbus TCP: cannot listen on {self.cfg.tcp_host}:{self.cfg.tcp_port}")
                self._servers.append(tcp)
                self.tcp_address = tcp.transport.sockets[0].getsockname()[:2]
                log.info("Modbus TCP listening on %s:%d", *self.tcp_address)
            if self.cfg.rtu_port:
                rtu = ModbusSerialServer(
                    self._device(), framer=FramerType.RTU, port=self.cfg.rtu_port, baudrate=self.cfg.rtu_baudrate,
                    parity=self.cfg.rtu_parity, bytesize=8, stopbits=self.cfg.rtu_stopbits, trace_pdu=self._rtu_filter,
                )
                await rtu.serve_forever(background=True)
                if rtu.transport is None:
                    raise OutputError(f"Modbus RTU: cannot open serial port {self.cfg.rtu_port}")
                self._servers.append(rtu)
                log.info("Modbus RTU unit %d on %s %d %d%s%d", self.unit_id, self.cfg.rtu_port,
                         self.cfg.rtu_baudrate, 8, self.cfg.rtu_parity, self.cfg.rtu_stopbits)
        except _START_ERRORS as exc:  # port in use, no such serial port, settings the tty refuses
            errors.append(exc)
        finally:
            ready.set()
        try:
            if not errors:
                while not self._stop.is_set():
                    try:
                        await asyncio.wait_for(self._stop.wait(), self._watchdog_period_s)
                    except asyncio.TimeoutError:
                        self.watchdog()
        finally:
            for s in self._servers:
                try:
                    await s.shutdown()
                except (OSError, RuntimeError, AttributeError) as exc:
                    log.debug("Modbus server shutdown: %s", exc)
            self._servers.clear()

    def start(self) -> "ModbusSink":
        ready = threading.Event()
        errors: list[BaseException] = []

        def main() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            try:
                loop.run_until_complete(self._serve(ready, errors))
            finally:
                loop.close()

        self._thread = threading.Thread(target=main, name="modbus", daemon=True)
        self._thread.start()
        if not ready.wait(self.cfg.start_timeout_s):
            self.close()
            raise OutputError("Modbus servers did not start in time")
        if errors:
            self._thread.join(self.cfg.start_timeout_s)
            raise OutputError(str(errors[0])) from errors[0]
        return self

    def close(self) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:  # loop already closed
                pass
        if self._thread is not None:
            self._thread.join(5.0)
            if self._thread.is_alive():
                log.error("Modbus server thread did not stop")
            self._thread = None
