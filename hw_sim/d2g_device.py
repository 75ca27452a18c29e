"""Distance2Go firmware emulator speaking ComLib on a pseudo-terminal (hardware-in-the-loop tests).

``python -m hw_sim.d2g_device --scenario tavanti-test1 --seed 1`` prints the port path (a stable
symlink to the current pty, like ``/dev/serial/by-id/...``) and serves until interrupted; point the
product at it with ``--source d2g://PATH``. In tests use it in-process::

    with D2GEmulator("tavanti-test1", seed=1) as emu:
        with open_radar(f"d2g://{emu.port}?period_ms=50") as src: ...

What it emulates (``reference/d2g-comlib.md``; the UNCONFIRMED D2G details follow the sibling
Position2Go firmware, as the reference suggests):

* endpoints RBAS, RADX, RFMC, RDPL, RIND, RCAL, RTDC numbered 1..7 (order configurable, so that
  tests prove the host discovers them); firmware info on endpoint 0;
* device-side framing checks with the endpoint-0 status codes (bad start, no such endpoint, empty
  or oversized payload, bad end marker, incomplete message after the quiet time); after a framing
  error the device ignores input until the line has been quiet;
* RBAS: frame format (refused while the trigger runs; announcements 0x41/0x35/0x37, RADX 0x01 and
  RFMC 0x02 after every SET_FRAME_FORMAT), device info, temperature (also pushed after a frame when it
  changed), TX power, chirp duration, minimum interval, automatic trigger (the frame counter restarts;
  below the minimum interval -> 0x0005), GET_FRAME_DATA (wait=1 blocks for a new frame, wait=0 gives
  0x0004 when there is none, only the newest frame is kept so a slow host sees gaps);
* RFMC configuration (alternating directions need an even number of chirps), RADX, RIND, RDPL.

Frames come from :class:`hw_sim.simulator.FrameSimulator` on :data:`hw_sim.boards.D2G_BOARD` with the
scenario's scene, indexed by the number of acquisitions since the emulator started: in a session that
starts the trigger once, frame number ``n`` is bit-identical to frame ``n`` of
``sim://d2g?scenario=..&seed=..&realtime=0``. The scene advances one simulated frame period (200 ms)
per acquisition whatever interval the host sets, so a short test interval replays the scene faster.

Faults: :meth:`D2GEmulator.inject_garbage`, :meth:`~D2GEmulator.truncate_next_frame`,
:meth:`~D2GEmulator.corrupt_next_frame`,
:meth:`~D2GEmulator.stall` / :meth:`~D2GEmulator.recover`, :meth:`~D2GEmulator.disconnect` /
:meth:`~D2GEmulator.reconnect` (the pty disappears and comes back behind the same path, with the
firmware in its power-on state).
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import select
import shutil
import signal
import struct
import tempfile
import threading
import time
import tty
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from hal import comlib as cl
from hal.comlib import Ep0, Radx, Rbas, Rfmc
from hw_sim.boards import D2G_MAX_TX_POWER, with_tx_power

log = logging.getLogger(__name__)

DEFAULT_ENDPOINTS = ("RBAS", "RADX", "RFMC", "RDPL", "RIND", "RCAL", "RTDC")
ALLOWED_SAMPLES = (32, 64, 128, 256)
MAX_CHIRPS = 64
#: frame buffer of the emulated firmware, in samples (I and Q counted separately)
MAX_FRAME_SAMPLES = 16384
RAMP_DOWN_S = 200e-6
SETTLE_S = 400e-6
DUTY_CYCLE_OVERHEAD_S = 3e-3


class SteppedClock:
    """Firmware time (seconds) that moves only when a test calls :meth:`advance`.

    With it the automatic trigger is deterministic: frame ``k`` is ready once the clock passed
    ``(k + 1)`` intervals after the trigger started, and GET_FRAME_DATA wait=1 blocks until then.
    """

    def __init__(self, start_s: float = 0.0) -> None:
        self._t = start_s
        self.cond = threading.Condition()

    def now(self) -> float:
        return self._t

    def advance(self, dt_s: float) -> None:
        with self.cond:
            self._t += dt_s
            self.cond.notify_all()


@dataclass
class Counters:
    """What the emulator has seen and done (tests wait on these through ``wait_for``)."""

    requests: int = 0
    frames_served: int = 0
    trigger_starts: int = 0
    framing_errors: int = 0
    swallowed: int = 0
    connects: int = 0
    statuses: dict[int, int] = field(default_factory=dict)


class D2GFirmware:
    """The device's protocol behaviour, without I/O: one host payload in, reply messages out.

    ``clock`` gives seconds (monotonic); ``wait(t)`` blocks until time ``t`` or an interruption and
    returns False when interrupted.
    """

    def __init__(
        self,
        frame_source: Callable[[int, cl.FrameFormat], tuple[np.ndarray, np.ndarray]],
        *,
        endpoints: tuple[str, ...] = DEFAULT_ENDPOINTS,
        clock: Callable[[], float] = time.monotonic,
        wait: Callable[[float], bool] | None = None,
        power_on_direction: int = 2,
    ) -> None:
        from hal.waveform import d2g_frontend

        self._frame_source = frame_source
        self.endpoints = tuple(endpoints)
        self.ep = {tag: k + 1 for k, tag in enumerate(self.endpoints)}
        self._clock = clock
        self._wait = wait or self._sleep_until
        fe = d2g_frontend()
        seg = fe.waveform.segments[0]
        self.chirp_s = seg.ramp_s
        self.sample_rate_hz = seg.sample_rate_hz
        self.bandwidth_hz = seg.bandwidth_hz
        self._power_on_fmcw = cl.FmcwConfig(
            int(round(seg.f_start_hz / 1e3)),
            int(round((seg.f_start_hz + seg.bandwidth_hz) / 1e3)),
            power_on_direction,
            D2G_MAX_TX_POWER,
        )
        self.device_info = cl.DeviceInfo(
            min_rf_khz=23_900_000,
            max_rf_khz=24_300_000,
            n_tx=1,
            n_rx=1,
            max_tx_power=D2G_MAX_TX_POWER,
            n_temp_sensors=1,
            hw_major=1,
            hw_minor=1,
            interleaved_rx=0,
            data_format=1,
            description="Distance2Go (BGT24MTR11) emulator",
        )
        self.firmware = cl.FirmwareInfo(1, 2, 0, "radar-edge hw_sim Distance2Go firmware emulator")
        self.counters = Counters()
        self.power_on()

    # --- state -------------------------------------------------------------------------------
    def power_on(self) -> None:
        """Reset to the power-on state (after a replug or FIRMWARE_RESET)."""
        if getattr(self, "trigger_us", 0):
            self._stop_trigger()
        self.fmt = cl.FrameFormat(64, 16, 1, 2)
        self.fmcw = self._power_on_fmcw
        self.trigger_us = 0
        self.test_mode = False
        self.duty_cycling = True
        self.lna = True
        self._t0 = 0.0
        self._last_delivered = -1
        self._scene_base = getattr(self, "_scene_next", 0)
        self._scene_next = self._scene_base
        self._reported_temp: int | None = None

    @property
    def min_interval_us(self) -> int:
        per_chirp = self.chirp_s + RAMP_DOWN_S + SETTLE_S
        overhead = DUTY_CYCLE_OVERHEAD_S if self.duty_cycling else 1e-3
        return int(round((self.fmt.chirps_per_frame * per_chirp + overhead) * 1e6))

    def temperature_mc(self, scene_index: int) -> int:
        """Board temperature in m°C: a slow deterministic drift (changes every 25 frames)."""
        return 38_000 + 125 * ((scene_index // 25) % 6)

    def _newest(self, now: float) -> int:
        """Frame number of the newest complete frame of the running trigger (-1: none yet)."""
        return int((now - self._t0) // (self.trigger_us * 1e-6)) - 1

    def _stop_trigger(self) -> None:
        if self.trigger_us:
            self._scene_next = self._scene_base + max(0, self._newest(self._clock()) + 1)
        self.trigger_us = 0

    @staticmethod
    def _sleep_until(t: float) -> bool:
        dt = t - time.monotonic()
        if dt > 0:
            time.sleep(dt)
        return True

    # --- dispatch ------------------------------------------------------------------------------
    def handle(self, msg: cl.Payload) -> list[bytes] | None:
        """Replies (encoded messages, the status last) to one host payload; None if interrupted."""
        self.counters.requests += 1
        if msg.endpoint == 0:
            out = self._endpoint0(msg.data)
        else:
            tag = self.endpoints[msg.endpoint - 1]
            handler = {"RBAS": self._rbas, "RFMC": self._rfmc, "RADX": self._radx, "RIND": self._rind}.get(tag)
            out = handler(msg.data) if handler else ([], 0xFFFF)
        if out is None:
            return None
        payloads, code = out
        self.counters.statuses[code] = self.counters.statuses.get(code, 0) + 1
        return [*payloads, cl.encode_status(msg.endpoint, code)]

    def _endpoint0(self, d: bytes):
        if d == bytes((Ep0.QUERY_ENDPOINT_INFO,)):
            return [cl.encode_payload(0, cl.encode_endpoint_list([(t, 1) for t in self.endpoints]))], 0
        if d == bytes((Ep0.QUERY_FW_INFO,)):
            return [cl.encode_payload(0, self.firmware.encode())], 0
        if d == bytes((Ep0.FIRMWARE_RESET,)):
            self.power_on()
            return [], 0
        return [], 0xFFFF

    def _p(self, tag: str, data: bytes) -> bytes:
        return cl.encode_payload(self.ep[tag], data)

    def _announce_format(self) -> list[bytes]:
        out = [
            self._p("RBAS", self.fmt.encode()),
            self._p("RBAS", cl.encode_u32_reply(Rbas.CHIRP_DURATION, int(round(self.chirp_s * 1e9)))),
            self._p("RBAS", cl.encode_u32_reply(Rbas.MIN_INTERVAL, self.min_interval_us)),
        ]
        if "RADX" in self.ep:
            out.append(self._p("RADX", struct.pack("<BIBB", Radx.CONFIGURATION, int(round(self.sample_rate_hz)), 12, 0)))
        if "RFMC" in self.ep:
            out.append(self._p("RFMC", cl.encode_u32_reply(Rfmc.BW_PER_SECOND, self._bw_per_s())))
        return out

    def _bw_per_s(self) -> int:
        return int(round((self.fmcw.upper_khz - self.fmcw.lower_khz) / 1e3 / self.chirp_s))

    def _rbas(self, d: bytes):
        t = d[0]
        busy = self.trigger_us != 0 or self.test_mode
        if t == Rbas.GET_FRAME_DATA and len(d) == 2:
            return self._get_frame(d[1])
        if t == Rbas.SET_AUTOMATIC_TRIGGER and len(d) == 5:
            (interval,) = struct.unpack_from("<I", d, 1)
            if interval == 0:
                self._stop_trigger()
                return [], 0
            if self.test_mode:
                return [], 0x0002
            if interval < self.min_interval_us:
                return [], 0x0005
            self._stop_trigger()
            self.trigger_us = interval
            self._t0 = self._clock()
            self._last_delivered = -1
            self._scene_base = self._scene_next
            self.counters.trigger_starts += 1
            return [], 0
        if t == Rbas.ENABLE_TEST_MODE and len(d) == 8:
            if self.trigger_us:
                return [], 0x0002
            self.test_mode = not (d[1] == 0 and d[2] == 0)
            return [], 0
        if t == Rbas.GET_DRIVER_VERSION and len(d) == 1:
            return [self._p("RBAS", bytes((Rbas.DRIVER_VERSION, 1, 0, 0)))], 0
        if t == Rbas.GET_DEVICE_INFO and len(d) == 1:
            return [self._p("RBAS", self.device_info.encode())], 0
        if t == Rbas.GET_TEMPERATURE and len(d) == 2:
            if d[1] != 0:
                return [], 0x0007
            return [self._p("RBAS", cl.encode_sensor_reply(Rbas.TEMPERATURE, 0, self.temperature_mc(self._scene_next)))], 0
        if t == Rbas.GET_TX_POWER and len(d) == 2:
            if d[1] != 0:
                return [], 0x0006
            return [self._p("RBAS", cl.encode_sensor_reply(Rbas.TX_POWER, 0, 1000 * self.fmcw.tx_power - 2000))], 0
        if t == Rbas.GET_CHIRP_DURATION and len(d) == 1:
            return [self._p("RBAS", cl.encode_u32_reply(Rbas.CHIRP_DURATION, int(round(self.chirp_s * 1e9))))], 0
        if t == Rbas.GET_MIN_INTERVAL and len(d) == 1:
            return [self._p("RBAS", cl.encode_u32_reply(Rbas.MIN_INTERVAL, self.min_interval_us))], 0
        if t == Rbas.GET_FRAME_FORMAT and len(d) == 1:
            return [self._p("RBAS", self.fmt.encode())], 0
        if t == Rbas.FRAME_FORMAT and len(d) == 11:
            code = self._set_format(cl.FrameFormat.parse(d), busy)
            return self._announce_format(), code
        return [], 0xFFFF

    def _set_format(self, f: cl.FrameFormat, busy: bool) -> int:
        if busy:
            return 0x0002
        if f.samples_per_chirp not in ALLOWED_SAMPLES:
            return 0x0050
        if not 1 <= f.chirps_per_frame <= MAX_CHIRPS:
            return 0x0008
        if f.rx_mask != 0x01:
            return 0x0006
        if f.signal_part != 2:
            return 0x000B
        if 2 * f.samples_per_chirp * f.chirps_per_frame > MAX_FRAME_SAMPLES:
            return 0x0008
        if self.fmcw.direction in (2, 3) and f.chirps_per_frame % 2:
            return 0x0020
        self.fmt = f
        return 0

    def _get_frame(self, wait: int):
        if self.test_mode:
            return [], 0x0003
        if not self.trigger_us:  # one acquisition, wait ignored; the counter reads 0
            scene = self._scene_next
            self._scene_next += 1
            return self._frame_messages(0, scene), 0
        now = self._clock()
        newest = self._newest(now)
        if newest <= self._last_delivered:
            if not wait:
                return [], 0x0004
            ready_at = self._t0 + (self._last_delivered + 2) * self.trigger_us * 1e-6
            if not self._wait(ready_at):
                return None
            newest = max(self._last_delivered + 1, self._newest(self._clock()))
        self._last_delivered = newest
        return self._frame_messages(newest, self._scene_base + newest), 0

    def _frame_messages(self, number: int, scene: int) -> list[bytes]:
        i, q = self._frame_source(scene, self.fmt)
        out = [self._p("RBAS", cl.encode_frame(number & 0xFFFFFFFF, i, q))]
        self.counters.frames_served += 1
        temp = self.temperature_mc(scene)
        if temp != self._reported_temp:
            self._reported_temp = temp
            out.append(self._p("RBAS", cl.encode_sensor_reply(Rbas.TEMPERATURE, 0, temp)))
        return out

    def _rfmc(self, d: bytes):
        t = d[0]
        if t == Rfmc.GET_CONFIGURATION and len(d) == 1:
            return [self._p("RFMC", self.fmcw.encode())], 0
        if t == Rfmc.BW_PER_SECOND and len(d) == 1:
            return [self._p("RFMC", cl.encode_u32_reply(Rfmc.BW_PER_SECOND, self._bw_per_s()))], 0
        if t == Rfmc.CONFIGURATION and len(d) == 11:
            c = cl.FmcwConfig.parse(d)
            if self.trigger_us or self.test_mode:
                return [], 0x0002
            di = self.device_info
            if not di.min_rf_khz <= c.lower_khz < c.upper_khz <= di.max_rf_khz:
                return [], 0x0009
            if c.tx_power > di.max_tx_power:
                return [], 0x000A
            if c.direction > 3 or (c.direction in (2, 3) and self.fmt.chirps_per_frame % 2):
                return [], 0x0020
            self.fmcw = c
            return [
                self._p("RFMC", c.encode()),
                self._p("RFMC", cl.encode_u32_reply(Rfmc.BW_PER_SECOND, self._bw_per_s())),
                self._p("RBAS", cl.encode_sensor_reply(Rbas.TX_POWER, 0, 1000 * c.tx_power - 2000)),
            ], 0
        return [], 0xFFFF

    def _radx(self, d: bytes):
        if d == bytes((Radx.GET_CONFIGURATION,)):
            return [self._p("RADX", struct.pack("<BIBB", Radx.CONFIGURATION, int(round(self.sample_rate_hz)), 12, 0))], 0
        if d[0] == Radx.CONFIGURATION and len(d) == 7:
            if self.trigger_us:
                return [], 0x0002
            return [], (0 if d[5] == 12 else 0x0051)
        return [], 0xFFFF

    def _rind(self, d: bytes):
        if len(d) != 1 or d[0] > 5:
            return [], 0xFFFF
        t = d[0]
        if t in (0, 1):
            if self.trigger_us:
                return [], 0x0002
            self.duty_cycling = bool(t)
        elif t in (3, 4):
            self.lna = t == 4
        elif t == 2:
            return [self._p("RIND", bytes((2, int(self.duty_cycling))))], 0
        elif t == 5:
            return [self._p("RIND", bytes((5, int(self.lna))))], 0
        return [], 0


class DeviceFramer:
    """The firmware's receive side: frames host messages and reports framing errors once."""

    def __init__(self, n_endpoints: int) -> None:
        self.n_endpoints = n_endpoints
        self.buf = bytearray()
        self.ignoring = False

    def feed(self, data: bytes) -> tuple[list[cl.Payload], int | None]:
        """Complete host messages, and a framing status code if one was detected (then ignore)."""
        if self.ignoring:
            return [], None
        self.buf += data
        out: list[cl.Payload] = []
        while self.buf:
            b = self.buf
            if b[0] != cl.PAYLOAD_START:
                return out, self._error(0x0002)
            if len(b) < cl.HEADER_LEN:
                break
            ep = b[1]
            length = b[2] | (b[3] << 8)
            if ep > self.n_endpoints:
                return out, self._error(0x0003)
            if length == 0:
                return out, self._error(0x0005)
            if length + cl.HEADER_LEN + cl.TAIL_LEN > cl.DEVICE_RX_BUFFER:
                return out, self._error(0x0006)
            end = cl.HEADER_LEN + length
            if len(b) < end + cl.TAIL_LEN:
                break
            if bytes(b[end : end + cl.TAIL_LEN]) != cl.END_MARKER:
                return out, self._error(0x0007)
            out.append(cl.Payload(ep, bytes(b[cl.HEADER_LEN : end])))
            del b[: end + cl.TAIL_LEN]
        return out, None

    def quiet(self) -> int | None:
        """The line has been quiet for the device timeout: reset; 0x0001 if a message was left incomplete."""
        code = 0x0001 if (self.buf and not self.ignoring) else None
        self.buf.clear()
        self.ignoring = False
        return code

    def _error(self, code: int) -> int:
        self.buf.clear()
        self.ignoring = True
        return code


class D2GEmulator:
    """The firmware above on a pseudo-terminal, served by a background thread.

    ``port`` is a stable symlink to the current pty slave. Fault injection methods are thread-safe
    and may be called while a host is connected. ``quiet_s`` is the device's input timeout (quiet
    line after a framing error or an incomplete message): 10 s on the sibling firmware, 0.5 s here
    so that tests stay fast. ``clock`` (a :class:`SteppedClock`) makes the automatic trigger advance
    only when a test says so; by default it runs on the host's monotonic time.
    """

    def __init__(
        self,
        scenario: str = "tavanti-test1",
        seed: int | None = None,
        *,
        link: str | None = None,
        endpoints: tuple[str, ...] = DEFAULT_ENDPOINTS,
        quiet_s: float = 0.5,
        power_on_direction: int = 2,
        clock: SteppedClock | None = None,
    ) -> None:
        from hw_sim.scenario import load_scenario
        from hw_sim.simulator import FrameSimulator

        sc = load_scenario(scenario)
        if sc.board != "d2g":
            raise ValueError(f"scenario {sc.name!r} is for board {sc.board!r}, not the Distance2Go")
        self.scenario = sc
        self.seed = sc.seed if seed is None else seed
        # the firmware's TX power level (RFMC configuration) sets the board's, frame by frame
        board = self._board = sc.sim_board()
        self._sim = FrameSimulator(board, sc.build_scene(self.seed), self.seed)
        self._sim_shape = board.frontend.frame_shape
        self.quiet_s = quiet_s
        self._tmpdir = None if link else tempfile.mkdtemp(prefix="radar-edge-d2g-")
        self.port = link or os.path.join(self._tmpdir, "ttyD2G")
        self._interrupt = threading.Event()
        self._cond = threading.Condition()
        self._stepped = clock
        self.fw = D2GFirmware(
            self._frame,
            endpoints=endpoints,
            clock=clock.now if clock is not None else time.monotonic,
            wait=self._wait_until,
            power_on_direction=power_on_direction,
        )
        self.counters = self.fw.counters
        self._framer = DeviceFramer(len(endpoints))
        self._master: int | None = None
        self._slave: int | None = None
        self._want_connected = True
        self._stalled = False
        self._garbage = b""
        self._truncate: int | None = None
        self._corrupt = False
        self._running = False
        self._thread: threading.Thread | None = None
        self._wake_r, self._wake_w = -1, -1
        self.faults_injected: list[str] = []

    # --- frames ----------------------------------------------------------------------------------
    def _frame(self, scene_index: int, fmt: cl.FrameFormat) -> tuple[np.ndarray, np.ndarray]:
        if (1, fmt.chirps_per_frame, fmt.samples_per_chirp) == self._sim_shape:
            self._sim.board = with_tx_power(self._board, self.fw.fmcw.tx_power)
            f = self._sim.frame(scene_index)
            return f.i, f.q
        # another format than the board model: receiver noise only
        rng = np.random.default_rng([self.seed, scene_index, 0xD26])
        shape = (1, fmt.chirps_per_frame, fmt.samples_per_chirp)
        return (rng.normal(0, 4, shape).round().astype(np.int16), rng.normal(0, 4, shape).round().astype(np.int16))

    # --- lifecycle -----------------------------------------------------------------------------
    def start(self) -> str:
        if self._running:
            return self.port
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._running = True
        self._connect()
        self._thread = threading.Thread(target=self._serve, name="d2g-emulator", daemon=True)
        self._thread.start()
        log.info("Distance2Go emulator on %s (scenario %s, seed %d)", self.port, self.scenario.name, self.seed)
        return self.port

    def stop(self) -> None:
        if not self._running:
            return
        self._running = False
        self._interrupt.set()
        self._poke()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._disconnect_pty()
        os.close(self._wake_r)
        os.close(self._wake_w)
        if self._tmpdir:
            shutil.rmtree(self._tmpdir, ignore_errors=True)

    def __enter__(self) -> "D2GEmulator":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- fault injection -----------------------------------------------------------------------
    def inject_garbage(self, data: bytes | int = 64, seed: int = 0) -> None:
        """Send these bytes (or this many seeded random bytes) before the next reply."""
        if isinstance(data, int):
            data = np.random.default_rng(seed).integers(0, 256, data, dtype=np.uint8).tobytes()
        with self._cond:
            self._garbage += data
            self.faults_injected.append("garbage")

    def truncate_next_frame(self, keep: int | None = None) -> None:
        """Cut the next frame message after ``keep`` bytes (default: half); its status still follows."""
        with self._cond:
            self._truncate = -1 if keep is None else keep
            self.faults_injected.append("truncate")

    def corrupt_next_frame(self) -> None:
        """Damage the header of the next frame (chirp count) inside an intact message: framing stays valid."""
        with self._cond:
            self._corrupt = True
            self.faults_injected.append("corrupt")

    def stall(self) -> None:
        """Stop answering: requests are read and dropped until :meth:`recover`."""
        with self._cond:
            self._stalled = True
            self.faults_injected.append("stall")
        self._interrupt.set()
        self._poke()

    def recover(self) -> None:
        with self._cond:
            self._stalled = False
            self._framer.quiet()
        self._poke()

    def disconnect(self) -> None:
        """Unplug: the pty and its path disappear; blocks until done."""
        with self._cond:
            self._want_connected = False
            self.faults_injected.append("disconnect")
        self._interrupt.set()
        self._poke()
        self.wait_for(lambda: self._master is None, 5.0)

    def reconnect(self) -> None:
        """Plug back in: a fresh pty behind the same path, the firmware in its power-on state."""
        with self._cond:
            self._want_connected = True
        self._poke()
        self.wait_for(lambda: self._master is not None, 5.0)

    def wait_for(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Block until ``predicate()`` holds (re-checked whenever the emulator's state changes)."""
        with self._cond:
            return self._cond.wait_for(predicate, timeout)

    @property
    def connected(self) -> bool:
        return self._master is not None

    # --- internals -----------------------------------------------------------------------------
    def _poke(self) -> None:
        if self._wake_w >= 0:
            try:
                os.write(self._wake_w, b"x")
            except OSError:
                pass

    def _wait_until(self, t: float) -> bool:
        """Block until firmware time ``t``; False if a fault or a stop interrupted the wait."""
        with self._cond:
            self._cond.notify_all()  # a request is waiting: let tests see it
        if self._stepped is not None:
            clk = self._stepped
            while not self._interrupt.is_set():
                with clk.cond:
                    if clk.cond.wait_for(lambda: clk.now() >= t, 0.05):
                        return True
            return False
        while True:
            dt = t - time.monotonic()
            if dt <= 0:
                return True
            if self._interrupt.wait(dt):
                return False

    def _connect(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        name = os.ttyname(slave)
        tmp = self.port + ".new"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(name, tmp)
        os.replace(tmp, self.port)
        with self._cond:
            self._master, self._slave = master, slave
            self._framer = DeviceFramer(len(self.fw.endpoints))
            self.fw.power_on()
            self.counters.connects += 1
            self._cond.notify_all()

    def _disconnect_pty(self) -> None:
        with self._cond:
            for fd in (self._master, self._slave):
                if fd is not None:
                    os.close(fd)
            self._master = self._slave = None
            if os.path.lexists(self.port):
                os.unlink(self.port)
            self._cond.notify_all()

    def _serve(self) -> None:
        last_rx = time.monotonic()
        while self._running:
            with self._cond:
                want = self._want_connected
            if not want and self._master is not None:
                self._disconnect_pty()
                continue
            if want and self._master is None:
                self._interrupt.clear()
                self._connect()
                continue
            fds = [self._wake_r] + ([self._master] if self._master is not None else [])
            pending = bool(self._framer.buf) or self._framer.ignoring
            timeout = self.quiet_s if pending else None
            r, _, _ = select.select(fds, [], [], timeout)
            if self._wake_r in r:
                try:
                    os.read(self._wake_r, 4096)
                except BlockingIOError:
                    pass
            if self._master is None:
                continue
            if self._master not in r:
                if pending and time.monotonic() - last_rx >= self.quiet_s:
                    code = self._framer.quiet()
                    if code is not None:
                        self._send([cl.encode_status(0, code)])
                continue
            try:
                data = os.read(self._master, 65536)
            except BlockingIOError:
                continue
            except OSError as exc:
                if exc.errno == errno.EIO:
                    continue
                raise
            last_rx = time.monotonic()
            with self._cond:
                stalled = self._stalled
            if stalled:
                self.counters.swallowed += 1
                continue
            msgs, err = self._framer.feed(data)
            for m in msgs:
                if self._running:
                    self._interrupt.clear()
                replies = self.fw.handle(m)
                with self._cond:
                    self._cond.notify_all()
                    if replies is None or self._stalled or not self._want_connected:
                        continue
                self._send(replies)
            if err is not None:
                self.counters.framing_errors += 1
                self._send([cl.encode_status(0, err)])

    def _send(self, replies: list[bytes]) -> None:
        with self._cond:
            garbage, self._garbage = self._garbage, b""
            trunc = self._truncate
            out = bytearray(garbage)
            for r in replies:
                is_frame = len(r) > 64 and r[0] == cl.PAYLOAD_START and r[4] == Rbas.FRAME_DATA
                if self._corrupt and is_frame:
                    r = r[:9] + bytes([r[9] ^ 0x01]) + r[10:]  # payload offset 5: num_chirps
                    self._corrupt = False
                if trunc is not None and len(r) > 64 and r[4] == Rbas.FRAME_DATA and r[0] == cl.PAYLOAD_START:
                    r = r[: (len(r) // 2 if trunc < 0 else trunc)]
                    trunc = None
                    self._truncate = None
                out += r
        self._write(bytes(out))
        with self._cond:
            self._cond.notify_all()

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + 2.0
        while view and self._master is not None:
            try:
                n = os.write(self._master, view)
                view = view[n:]
            except BlockingIOError:
                if time.monotonic() > deadline:
                    log.warning("host is not reading: %d reply bytes dropped", len(view))
                    return
                select.select([], [self._master], [], 0.05)
            except OSError as exc:
                log.warning("pty write failed: %s", exc)
                return


# --- command line ---------------------------------------------------------------------------------


def _fault_spec(text: str) -> tuple[str, int, float]:
    """``KIND@FRAME[:SECONDS]``, e.g. ``stall@100:3``."""
    kinds = ("garbage", "truncate", "corrupt", "stall", "disconnect")
    kind, _, rest = text.partition("@")
    at, _, dur = rest.partition(":")
    if kind not in kinds or not at.isdigit():
        raise argparse.ArgumentTypeError(f"expected KIND@FRAME[:SECONDS] with KIND in {', '.join(kinds)}, got {text!r}")
    return kind, int(at), float(dur or 2.0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m hw_sim.d2g_device",
        description=(
            "Emulate a Distance2Go board (Infineon ComLib firmware) on a pseudo-terminal. Prints the port "
            "path; frames come from the scenario's scene, bit-identical to sim://d2g for the same scenario "
            "and seed. Faults can be scheduled at a count of served frames."
        ),
        epilog=(
            "examples:\n"
            "  python -m hw_sim.d2g_device --scenario tavanti-test1 --seed 1\n"
            "  radar-edge run --source d2g://$PORT\n"
            "  python -m hw_sim.d2g_device --scenario tavanti-test1 --fault garbage@20 --fault stall@40:3 "
            "--fault disconnect@80:2"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--scenario", default="tavanti-test1", help="built-in scenario name or .toml path (board d2g)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.add_argument("--link", default=None, help="path of the port symlink (default: a new temporary directory)")
    p.add_argument(
        "--fault",
        type=_fault_spec,
        action="append",
        default=[],
        help="KIND@FRAME[:SECONDS]: inject garbage/truncate/corrupt/stall/disconnect after FRAME served frames; "
        "stall and disconnect last SECONDS (default 2)",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log every fault and connection")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(asctime)s %(message)s")
    emu = D2GEmulator(args.scenario, args.seed, link=args.link)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with emu:
        print(emu.port, flush=True)
        try:
            for kind, at, dur in sorted(args.fault, key=lambda f: f[1]):
                while not stop.is_set() and not emu.wait_for(lambda: emu.counters.frames_served >= at, 0.5):
                    pass
                if stop.is_set():
                    break
                log.warning("injecting %s at frame %d", kind, emu.counters.frames_served)
                if kind == "garbage":
                    emu.inject_garbage(256, seed=at)
                elif kind == "truncate":
                    emu.truncate_next_frame()
                elif kind == "corrupt":
                    emu.corrupt_next_frame()
                elif kind == "stall":
                    emu.stall()
                    stop.wait(dur)
                    emu.recover()
                else:
                    emu.disconnect()
                    stop.wait(dur)
                    emu.reconnect()
            stop.wait()
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
