"""Modbus RTU (RS-485) and Modbus TCP servers over one register image (pymodbus 3.16).

The frame loop calls :meth:`ModbusSink.publish`, which builds a complete new image
(:class:`~edge.outputs.registers.ImageBuilder`): that is the only writer. The image goes as one
message over a non-blocking local socket to the server process, which runs both servers in one
asyncio loop and swaps its image reference when a message arrives; a pymodbus ``SimDevice`` action
copies the requested registers out of the current image for every read, so RTU and TCP always
show the same, untorn data. A separate process (not a thread) because pymodbus does all its work
in Python: in a thread, every request would hold the interpreter lock the frame loop needs (with a
client polling the whole map at 20 Hz the frame-time p99 rose by 13 % that way; see
``python -m edge.outputs.pollbench``). The frame loop never waits on a Modbus client.

Only the configuration block (2000-2099) is writable. FC6/FC16 are not served (exception 01) unless
``outputs.modbus.config_writes`` is on; then every register is validated (exception 03 out of
range, 02 for reserved/read-only ones) and staged, and the command register 2090 applies (0xA5A5)
or discards (0x5A5A) the staged values. RTU stays silent for unit ids other than its own (a shared
RS-485 line); TCP answers every unit id.

Conformance (Modbus Application Protocol v1.1b3): the servers decode requests with
:func:`request_problem` first, so every function code other than 3, 4, 6 and 16 gets exception 01
with its own function code + 0x80 (pymodbus would answer FC8, FC17 and FC43 itself), quantities out
of range get 03 and truncated requests 01.

The server process watches its input too: when no image came from the frame loop for
``outputs.modbus.stale_image_s`` (the loop frozen by SIGSTOP, hung or crashed: the parent's watchdog
thread stops with it), it serves the fault itself (:func:`~edge.outputs.registers.no_image_fault`)
until the next image.

pymodbus facts this relies on (3.16.1, see the project's outputs reference): ``SimDevice(id=0)``
answers every unit id; ``trace_pdu`` returning ``None`` for a request drops it without a reply;
the action is called for every read and write after pymodbus's own address/read-only checks.
"""

from __future__ import annotations

import array
import asyncio
import logging
import multiprocessing
import os
import pickle
import select
import socket
import threading
import time
from typing import TYPE_CHECKING, Any, Callable

from edge.ops.affinity import AffinityError, pin
from edge.ops.affinity import check as check_cpus
from edge.outputs.config import BAUD_CODES, CAN_BITRATE_CODES, PARITY_CODES, FailsafeConfig, ModbusConfig
from edge.outputs.registers import (
    CMD_APPLY, CMD_RESTART_COMMS, CMD_STATUS_ADDR, CONFIG, CONFIG_BASE, CONFIG_SIZE, GENERATION_ADDR,
    GEOMETRY_OFFSETS, MAX_LANES, READ_RANGES, STATUS, ImageBuilder, Links, config_values, default_config_words,
    lane_geometry, lane_geometry_values, no_image_fault,
)
from edge.outputs.state import OutputState

if TYPE_CHECKING:  # keep the server process free of numpy
    from edge.types import FrameResult, LoopHealth

log = logging.getLogger(__name__)

try:
    from termios import error as _TermiosError
except ImportError:  # pragma: no cover - not on POSIX
    _TermiosError = OSError

READ_FCS = (3, 4)
WRITE_FCS = (6, 16)
#: the only function codes served; every other one gets exception 01
SERVED_FCS = READ_FCS + WRITE_FCS
_CFG_REG = {r.offset: r for r in CONFIG.regs}
#: configuration registers that take effect without a restart
LIVE_KEYS = frozenset({"unit_id", "can_enable", "can_sensor_id", "can_output_mask", "command", "generation",
                       "command_status"})

_GEOMETRY_KEYS = frozenset(_CFG_REG[o].name for o in GEOMETRY_OFFSETS)


class OutputError(RuntimeError):
    """An output could not be started (port in use, no such serial port...)."""


_START_ERRORS = (OSError, RuntimeError, ValueError, _TermiosError)  # pymodbus: RuntimeError "Could not start listen"


class ConfigBlock:
    """Staged and applied configuration words (owned by the Modbus thread)."""

    def __init__(self, words: list[int], on_apply: Callable[[dict[str, Any], dict[str, Any]], None] | None = None,
                 geometry_lanes: int | None = None):
        self.applied = list(words)
        self.staged = list(words)
        self.initial = list(words)
        self.on_apply = on_apply
        #: lanes the geometry registers must keep in use; None: geometry not writable (learned or no lanes)
        self.geometry_lanes = geometry_lanes

    def write(self, offset: int, values: list[int]) -> int | None:
        """Validate and stage ``values`` from ``offset``; returns an exception code or None."""
        for i, raw in enumerate(values):
            off = offset + i
            reg = _CFG_REG.get(off)
            if reg is None or not reg.writable or (off in GEOMETRY_OFFSETS and self.geometry_lanes is None):
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
            problem = validate_config(config_values(self.staged), self.geometry_lanes)
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
        live = LIVE_KEYS if self.geometry_lanes is None else LIVE_KEYS | _GEOMETRY_KEYS  # applied to the traffic layer
        return any(now[k] != first[k] for k in now if k not in live)


def validate_config(v: dict[str, Any], geometry_lanes: int | None = None) -> str | None:
    """Cross-register checks made when the command register applies a configuration; with
    ``geometry_lanes``, the enabled lanes must be exactly lanes 1..geometry_lanes (the lanes in use)."""
    for k in range(1, MAX_LANES + 1):
        if v.get(f"lane{k}_enabled") and v[f"lane{k}_x_min"] >= v[f"lane{k}_x_max"]:
            return f"lane {k}: x_min {v[f'lane{k}_x_min']:.1f} m must be below x_max {v[f'lane{k}_x_max']:.1f} m"
    if v.get("lanes") and sum(bool(v.get(f"lane{k}_enabled")) for k in range(1, MAX_LANES + 1)) > v["lanes"]:
        return "more lanes enabled than configured"
    if geometry_lanes is not None:
        enabled = [k for k in range(1, MAX_LANES + 1) if v.get(f"lane{k}_enabled")]
        if enabled != list(range(1, geometry_lanes + 1)):
            return f"lanes {enabled} enabled: the traffic layer uses lanes 1..{geometry_lanes} (changing the count " \
                   "needs the configuration file and a restart)"
    return None


def request_problem(fc: int, data: bytes, writes_enabled: bool) -> int | None:
    """Exception code for a request PDU (function code ``fc``, then ``data``) this device does not serve, or None
    (Modbus Application Protocol v1.1b3 section 7: 01 function not served, or a PDU too short to hold its fields;
    03 quantity or byte count out of range)."""
    if fc not in SERVED_FCS or (fc in WRITE_FCS and not writes_enabled):
        return 1
    if len(data) < (5 if fc == 16 else 4):
        return 1
    qty = int.from_bytes(data[2:4], "big")
    if fc in READ_FCS and not 1 <= qty <= 125:
        return 3
    if fc == 16 and (not 1 <= qty <= 123 or data[4] != 2 * qty or len(data) < 5 + data[4]):
        return 3
    return None


def _decoder(writes_enabled: bool) -> Any:
    """A pymodbus request decoder that refuses what :func:`request_problem` refuses (server process only)."""
    from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU

    class Refused(ModbusPDU):
        """A request answered with exception ``code`` under its own function code."""

        def __init__(self, fc: int, code: int) -> None:
            super().__init__()
            self.function_code = fc
            self.code = code

        async def datastore_update(self, context: Any, device_id: int) -> Any:
            return ExceptionResponse(self.function_code & 0x7F, self.code, device_id=device_id)

    class Decoder(DecodePDU):
        def decode(self, frame: bytes) -> Any:
            if not frame:
                return None
            fc = int(frame[0])
            code = request_problem(fc, bytes(frame[1:]), writes_enabled)
            if code is None:
                pdu = super().decode(frame)
                if pdu is not None:
                    return pdu
                code = 3
            return Refused(fc, code)

    return Decoder(True)


def initial_config_words(cfg: ModbusConfig, n_lanes: int, can: Any = None, interval_s: float = 60.0,
                         lanes: Any = ()) -> list[int]:
    """The configuration block of the running configuration: ``interval_s`` the traffic layer's interval,
    ``lanes`` its configured lanes (``center_m``, ``width_m``, ``direction``; none: geometry reads 0)."""
    words = default_config_words({
        "unit_id": cfg.unit_id, "baud_code": BAUD_CODES.index(cfg.rtu_baudrate),
        "parity_code": PARITY_CODES.index(cfg.rtu_parity), "stop_bits": cfg.rtu_stopbits,
        "interval_s": max(1, int(round(interval_s))), "lanes": n_lanes, **lane_geometry_values(lanes),
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


class _Server:
    """The server process's side: current image, staged configuration, the pymodbus action."""

    def __init__(self, cfg: ModbusConfig, image: array.array, config_words: list[int], conn: socket.socket,
                 geometry_lanes: int | None = None, presence: str = "on",
                 clock_s: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self.image = image
        self.conn = conn
        self.unit_id = cfg.unit_id
        self.config = ConfigBlock(config_words, self._applied, geometry_lanes)
        self.presence = presence
        self.clock_s = clock_s
        self.image_s = clock_s()  # when the current image arrived
        #: the silence watch starts with the first image the frame loop built (update counter > 0)
        self.armed = bool(image[STATUS.base + _UPDATE_COUNTER])
        self._fault: tuple[Any, int, list[int]] | None = None  # (image, since tenths, its fault view)
        self.counters = {"reads": 0, "writes": 0, "exceptions": 0, "ignored_unit_id": 0,
                         "rtu_open": 0, "rtu_open_failures": 0, "no_image_faults": 0}

    def served(self) -> Any:
        """The image to serve now: the latest one, or its fault view when the frame loop went silent."""
        silent = self.clock_s() - self.image_s
        if not self.armed or silent <= self.cfg.stale_image_s:
            return self.image
        tenths = int(silent * 10)
        fault = self._fault
        if fault is None or fault[0] is not self.image or fault[1] != tenths:
            if fault is None or fault[0] is not self.image:
                self.counters["no_image_faults"] += 1
                log.error("no image from the frame loop for %.1f s: serving the fault", silent)
            self._fault = fault = (self.image, tenths, no_image_fault(self.image, silent, self.presence))
        return fault[2]

    def take_image(self, img: array.array) -> None:
        if self._fault is not None:
            log.warning("images from the frame loop again: fault cleared")
            self._fault = None
        self.image = img  # one reference swap: reads see the old or the new image, never a mix
        self.image_s = self.clock_s()
        self.armed = self.armed or bool(img[STATUS.base + _UPDATE_COUNTER])



    def _applied(self, before: dict[str, Any], after: dict[str, Any]) -> None:
        self.unit_id = int(after["unit_id"])
        _send(self.conn, ("applied", before, after, self.config.pending_restart(), list(self.config.applied)))

    async def action(self, fc: int, start: int, address: int, count: int, regs: list[int],
                     values: list[int] | list[bool] | None) -> Any:
        from pymodbus.constants import ExcCodes

        if values is None:
            if fc in WRITE_FCS:
                return None  # pymodbus reads back after a write: the written values are in regs already
            if fc not in READ_FCS:
                return ExcCodes.ILLEGAL_FUNCTION
            self.counters["reads"] += 1
            if address >= CONFIG_BASE:
                regs[address - start: address - start + count] = self.config.staged[address - CONFIG_BASE:][:count]
            else:
                regs[address - start: address - start + count] = self.served()[address: address + count]
            return None
        if fc not in WRITE_FCS or not self.cfg.config_writes:
            return ExcCodes.ILLEGAL_FUNCTION
        if not CONFIG_BASE <= address < CONFIG_BASE + CONFIG_SIZE:
            return ExcCodes.ILLEGAL_ADDRESS
        code = self.config.write(address - CONFIG_BASE, [int(v) for v in values])
        if code is not None:
            return {1: ExcCodes.ILLEGAL_FUNCTION, 2: ExcCodes.ILLEGAL_ADDRESS, 3: ExcCodes.ILLEGAL_VALUE}[code]
        self.counters["writes"] += 1
        return None

    def trace(self, sending: bool, pdu: Any) -> Any:
        """Counts the exception responses sent (pymodbus's trace_pdu hook, TCP)."""
        if sending and pdu.function_code & 0x80:
            self.counters["exceptions"] += 1
        return pdu

    def rtu_filter(self, sending: bool, pdu: Any) -> Any:
        if sending:
            return self.trace(sending, pdu)
        if pdu.dev_id != self.unit_id:
            self.counters["ignored_unit_id"] += 1
            return None  # another device on the shared line: stay silent
        return pdu

    def device(self) -> Any:
        from pymodbus.simulator import DataType, SimData, SimDevice

        blocks = [SimData(a, count=b - a, datatype=DataType.REGISTERS, readonly=a < CONFIG_BASE) for a, b in READ_RANGES]
        return SimDevice(id=0, simdata=blocks, action=self.action)

    def on_readable(self, stop: asyncio.Event) -> None:
        """New images from the frame loop (one message each; the latest wins)."""
        while True:
            try:
                data = self.conn.recv(_MAX_MSG)
            except BlockingIOError:
                return
            except OSError:
                data = b""
            if not data:  # the parent closed its end (or died): stop serving
                stop.set()
                return
            if data[:1] == _IMG:
                img = array.array("H")
                img.frombytes(data[1:])
                self.take_image(img)
            elif data[:1] == _CTL:
                msg = pickle.loads(data[1:])
                if msg[0] == "stop":
                    stop.set()
                    return
                if msg[0] == "counters":
                    _send(self.conn, ("counters", dict(self.counters)))
                if msg[0] == "ping":
                    _send(self.conn, ("pong", msg[1]))

    def _rtu_server(self) -> Any:
        from pymodbus.framer import FramerType
        from pymodbus.server import ModbusSerialServer

        server = ModbusSerialServer(
            self.device(), framer=FramerType.RTU, port=self.cfg.rtu_port, baudrate=self.cfg.rtu_baudrate,
            parity=self.cfg.rtu_parity, bytesize=8, stopbits=self.cfg.rtu_stopbits, trace_pdu=self.rtu_filter,
        )
        server.decoder = _decoder(self.cfg.config_writes)
        return server

    async def _open_rtu(self, servers: list[Any]) -> str | None:
        """Open the RTU server; None when it serves, else the reason (the caller retries)."""
        try:
            if not os.path.exists(self.cfg.rtu_port):  # pymodbus would only say "Could not start listen"
                raise FileNotFoundError("no such serial port")
            rtu = self._rtu_server()
            await rtu.serve_forever(background=True)
        except _START_ERRORS as exc:  # adapter unplugged, settings the tty refuses
            self.counters["rtu_open_failures"] += 1
            return f"{self.cfg.rtu_port}: {exc}"
        servers.append(rtu)
        self.counters["rtu_open"] = 1
        return None

    async def _retry_rtu(self, servers: list[Any], stop: asyncio.Event) -> None:
        """Retry opening the serial port every ``rtu_retry_s`` until it opens (TCP keeps serving)."""
        while not stop.is_set():
            try:
                await asyncio.wait_for(stop.wait(), self.cfg.rtu_retry_s)
                return
            except asyncio.TimeoutError:
                pass
            err = await self._open_rtu(servers)
            if err is None:
                log.warning("Modbus RTU: %s opened after %d failed attempt(s); unit %d serving", self.cfg.rtu_port,
                            self.counters["rtu_open_failures"], self.unit_id)
                _send(self.conn, ("rtu", None))
                return
            if self.counters["rtu_open_failures"] in (2, 10) or self.counters["rtu_open_failures"] % 100 == 0:
                log.error("Modbus RTU: still cannot open %s (%d attempts): %s", self.cfg.rtu_port,
                          self.counters["rtu_open_failures"], err)

    async def serve(self) -> None:
        from pymodbus.server import ModbusTcpServer

        stop = asyncio.Event()
        servers: list[Any] = []
        retry: asyncio.Task | None = None
        try:
            tcp_address = None
            if self.cfg.tcp_enabled:
                tcp = ModbusTcpServer(self.device(), address=(self.cfg.tcp_host, self.cfg.tcp_port), trace_pdu=self.trace)
                tcp.decoder = _decoder(self.cfg.config_writes)  # each connection's framer takes it from here
                await tcp.serve_forever(background=True)
                servers.append(tcp)
                tcp_address = tuple(tcp.transport.sockets[0].getsockname()[:2])
            rtu_error = await self._open_rtu(servers) if self.cfg.rtu_port else None
        except _START_ERRORS as exc:  # TCP port in use, address not on this machine
            _send(self.conn, ("error", f"{type(exc).__name__}: {exc}"))
        else:
            _send(self.conn, ("ready", tcp_address, rtu_error))
            self.conn.setblocking(False)
            asyncio.get_running_loop().add_reader(self.conn.fileno(), self.on_readable, stop)
            if rtu_error is not None:
                retry = asyncio.create_task(self._retry_rtu(servers, stop))
            await stop.wait()
        finally:
            if retry is not None:
                retry.cancel()
            for s in servers:
                try:
                    await s.shutdown()
                except (OSError, RuntimeError, AttributeError) as exc:
                    log.debug("Modbus server shutdown: %s", exc)


def _server_main(cfg: ModbusConfig, image: bytes, config_words: list[int], conn: socket.socket, log_level: int,
                 geometry_lanes: int | None = None, presence: str = "on") -> None:
    """Entry point of the Modbus server process."""
    logging.basicConfig(level=log_level, format="%(asctime)s %(levelname)s %(name)s[modbus]: %(message)s")
    try:
        pin(cfg.cpus, "Modbus server")
    except AffinityError as exc:  # the parent checked the CPUs exist; a cpuset may still refuse them
        log.error("%s; running unpinned", exc)
    img = array.array("H")
    img.frombytes(image)
    srv = _Server(cfg, img, config_words, conn, geometry_lanes, presence)
    try:
        asyncio.run(srv.serve())
    except KeyboardInterrupt:  # Ctrl-C reaches the whole process group; the parent decides
        pass
    finally:
        conn.close()


_IMG, _CTL = b"I", b"C"
_UPDATE_COUNTER = next(r.offset for r in STATUS.regs if r.name == "update_counter")
_MAX_MSG = 1 << 16


def _send(conn: socket.socket, msg: Any) -> None:
    try:
        conn.send(_CTL + pickle.dumps(msg))
    except (BlockingIOError, InterruptedError):  # the other side is not reading: drop, never block
        log.warning("Modbus control message %r dropped: socket full", msg[0])


class ModbusSink:
    """Output sink: Modbus TCP and/or RTU servers in a child process, fed one image per publish.

    The frame loop's ``publish`` builds the image (the single writer) and hands it to the server
    process as one message on a non-blocking local socket, so Modbus clients never hold the loop's
    interpreter lock and the loop never waits for them (a full socket buffer drops the image and
    counts it; the next frame sends a newer one). A watchdog thread faults the image when the loop
    goes silent and restarts a dead server process (back-off 1-30 s); the server process faults it too
    when no image arrives (``stale_image_s``), which also covers a frozen or dead frame-loop process. Without :meth:`start` nothing
    is served and :meth:`image` is the only view (used by unit tests).
    """

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
        lanes: Callable[[], Any] | None = None,
        geometry_lanes: int | None = None,
    ) -> None:
        """``lanes``: the traffic layer's lanes in use (their directions are published); ``geometry_lanes``: how
        many configured lanes the geometry registers may re-apply (None: geometry writes refused)."""
        self.cfg = cfg
        self.n_lanes = n_lanes
        self.links = links or Links()
        self.links.writes_enabled = cfg.config_writes
        self.failsafe = failsafe or FailsafeConfig()
        self.geometry_lanes = geometry_lanes
        self.state = OutputState(n_lanes, failsafe, lanes)
        self.builder = ImageBuilder(n_lanes, serial_number=cfg.serial_number, links=self.links, wall_clock=wall_clock)
        self.config_words = list(config_words or initial_config_words(cfg, n_lanes))
        self.on_apply = on_apply
        self.unit_id = cfg.unit_id
        self._clock_ns = clock_ns
        self._watchdog_period_s = watchdog_period_s
        self._lock = threading.Lock()
        self._image: list[int] = self.builder.initial_image()
        self._watchdog_fired = False
        self._conn: socket.socket | None = None
        self._proc: Any = None
        self._stop = threading.Event()
        self._watchdog_thread: threading.Thread | None = None
        self.tcp_address: tuple[str, int] | None = None
        #: why the RTU serial port is not open (None: open, or RTU off); the server process retries it
        self.rtu_error: str | None = None
        self.counters = {"images_sent": 0, "images_dropped": 0, "watchdog": 0, "applied": 0, "server_restarts": 0,
                         "rtu_open_failures": 0}
        self._restart_backoff_s = 0.5
        self._next_restart_s = 0.0
        self.server_counters: dict[str, int] = {}
        self._ping = 0

    # --- the frame loop's side (single writer) ----------------------------------------------
    def publish(self, result: FrameResult | None, health: LoopHealth) -> None:
        snap = self.state.update(result, health)
        with self._lock:
            self._image = self.builder.build(snap)
            self._watchdog_fired = False
            self._ship(self._image)
        self._poll_messages()

    def image(self) -> list[int]:
        """The latest image (what the servers serve once they got it)."""
        return self._image

    def watchdog(self, now_ns: int | None = None) -> bool:
        """Fault the image when the frame loop went silent (nothing published for stale_after_s).

        Runs in a small thread every ``watchdog_period_s`` once started; tests call it with a fake clock.
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
            self._ship(self._image)
        finally:
            self._lock.release()
        log.warning("no results or heartbeats from the frame loop: Modbus status shows the fault")
        return True

    def _ship(self, img: list[int]) -> None:
        conn = self._conn
        if conn is None:
            return
        try:
            conn.send(_IMG + array.array("H", img).tobytes())
            self.counters["images_sent"] += 1
        except (BlockingIOError, InterruptedError):
            self.counters["images_dropped"] += 1
        except OSError as exc:  # the server process is gone
            self.counters["images_dropped"] += 1
            if self.counters["images_dropped"] == 1:
                log.error("Modbus server process not reachable: %s", exc)

    def _poll_messages(self) -> None:
        conn = self._conn
        if conn is None:
            return
        while True:
            try:
                data = conn.recv(_MAX_MSG)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            if not data:
                return
            self._handle(pickle.loads(data[1:]))

    def _handle(self, msg: tuple) -> None:
        if msg[0] == "applied":
            _, before, after, pending, words = msg
            self.config_words = words  # a restarted server process starts from the applied configuration
            self.unit_id = int(after["unit_id"])
            self.links.config_pending_restart = bool(pending)
            self.counters["applied"] += 1
            if self.on_apply is not None:
                self.on_apply(before, after)
        elif msg[0] == "counters":
            self.server_counters = msg[1]
        elif msg[0] == "rtu":
            self.rtu_error = msg[1]

    def sync(self, timeout_s: float = 5.0) -> bool:
        """Wait until the server process has taken everything sent so far (tests, tools; never the loop).

        Also processes the server's messages (applied configurations, counters). False on timeout.
        """
        conn = self._conn
        if conn is None:
            return True
        self._ping += 1
        token = self._ping
        _send(conn, ("ping", token))
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not select.select([conn], [], [], remaining)[0]:
                return False
            try:
                data = conn.recv(_MAX_MSG)
            except (BlockingIOError, InterruptedError):
                continue
            if not data:
                return False
            msg = pickle.loads(data[1:])
            if msg[0] == "pong" and msg[1] == token:
                return True
            self._handle(msg)

    def request_counters(self) -> None:
        """Ask the server process for its request counters (arrive with a later publish)."""
        if self._conn is not None:
            try:
                _send(self._conn, ("counters",))
            except OSError:
                pass

    # --- lifecycle --------------------------------------------------------------------------
    def start(self) -> "ModbusSink":
        if not (self.cfg.tcp_enabled or self.cfg.rtu_port):
            return self
        self._spawn()
        self._watchdog_thread = threading.Thread(target=self._watch, name="modbus-watchdog", daemon=True)
        self._watchdog_thread.start()
        return self

    def _spawn(self) -> None:
        try:
            check_cpus(self.cfg.cpus, "outputs.modbus.cpus")
        except AffinityError as exc:
            raise OutputError(str(exc)) from None
        ctx = multiprocessing.get_context("spawn")  # never fork a multi-threaded process
        parent, child = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        for s in (parent, child):
            s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 18)
        img = array.array("H", self._image).tobytes()
        self._proc = ctx.Process(target=_server_main, name="radar-edge-modbus", daemon=True,
                                 args=(self.cfg, img, self.config_words, child, logging.getLogger().level,
                                       self.geometry_lanes, self.failsafe.presence))
        self._proc.start()
        child.close()
        parent.settimeout(self.cfg.start_timeout_s)
        try:
            data = parent.recv(_MAX_MSG)
        except (socket.timeout, OSError) as exc:
            self._kill()
            raise OutputError(f"Modbus server process did not start: {exc}") from None
        msg = pickle.loads(data[1:]) if data else ("error", "server process exited")
        if msg[0] != "ready":
            self._proc.join(self.cfg.start_timeout_s)
            self._proc = None
            parent.close()
            raise OutputError(f"Modbus: {msg[1]}")
        self.tcp_address = msg[1]
        self.rtu_error = msg[2]
        if self.tcp_address:
            log.info("Modbus TCP listening on %s:%d", *self.tcp_address)
        if self.cfg.rtu_port and self.rtu_error is None:
            log.info("Modbus RTU unit %d on %s %d 8%s%d", self.unit_id, self.cfg.rtu_port, self.cfg.rtu_baudrate,
                     self.cfg.rtu_parity, self.cfg.rtu_stopbits)
        elif self.cfg.rtu_port:
            self.counters["rtu_open_failures"] += 1
            log.error("Modbus RTU: cannot open %s (%s); retrying every %g s%s", self.cfg.rtu_port, self.rtu_error,
                      self.cfg.rtu_retry_s, ", Modbus TCP serving meanwhile" if self.tcp_address else "")
        parent.setblocking(False)
        self._conn = parent
        self._ship(self._image)

    def check_server(self, now_s: float | None = None) -> bool:
        """Restart the server process if it died (with back-off); True when it was restarted.

        Called by the watchdog thread. The restarted servers get the last applied configuration and
        listen on the configured port (an OS-chosen port 0 may change).
        """
        proc = self._proc
        if proc is None or proc.is_alive() or self._stop.is_set():
            return False
        now = time.monotonic() if now_s is None else now_s
        if now < self._next_restart_s:
            return False
        log.error("Modbus server process exited (code %s); restarting it", proc.exitcode)
        self.counters["server_restarts"] += 1
        self._restart_backoff_s = min(30.0, max(1.0, 2 * self._restart_backoff_s))
        self._next_restart_s = now + self._restart_backoff_s
        conn, self._conn, self._proc = self._conn, None, None
        if conn is not None:
            conn.close()
        try:
            self._spawn()
        except OutputError as exc:
            log.error("Modbus server restart failed: %s (next try in %.0f s)", exc, self._restart_backoff_s)
            return False
        return True

    def _watch(self) -> None:
        while not self._stop.wait(self._watchdog_period_s):
            self.watchdog()
            self.check_server()

    def _kill(self) -> None:
        if self._proc is not None:
            self._proc.terminate()
            self._proc.join(5)
            self._proc = None

    def close(self) -> None:
        self._stop.set()
        if self._watchdog_thread is not None:
            self._watchdog_thread.join(5)
            self._watchdog_thread = None
        conn, self._conn = self._conn, None
        if conn is not None:
            try:
                conn.setblocking(True)
                conn.settimeout(1.0)
                _send(conn, ("stop",))
            except OSError:
                pass
            conn.close()
        if self._proc is not None:
            self._proc.join(10)
            if self._proc.is_alive():
                log.error("Modbus server process did not stop; terminating it")
                self._kill()
            self._proc = None
