"""``d2g://`` backend: an Infineon Distance2Go board over its USB virtual serial port (ComLib).

``d2g:///dev/serial/by-id/usb-Infineon_IFX_CDC-if00`` (or the emulator's pty from
``python -m hw_sim.d2g_device``), or ``d2g://auto`` to find the board by its USB id 058B:0058 and its
endpoint list. Options: ``period_ms`` (automatic trigger period, default Tavanti's 200 ms; the
front end's ``frame_period_s`` follows it),
``timeout_s`` (reply timeout), ``gap_s``, ``backoff_s``, ``backoff_max_s``, ``quiet_s``, ``baud``.

Session (``reference/d2g-comlib.md``, "Minimal host session"): discover the endpoints, read the
firmware and device info, stop any running trigger, set the FMCW direction to up-only if it was
alternating (21 chirps is odd), set the frame format (64 samples x 21 chirps, RX 1, I and Q), read the
minimum frame interval and the chirp duration, start the automatic trigger at ``period_ms``, then ask
for each frame with GET_FRAME_DATA wait=1. The request stays outstanding across ``read_frame`` calls,
so a short read timeout never desynchronises the exchange.

Frame numbers become ``RawFrame.seq`` (the base class counts the gaps as dropped frames). They stay
monotonic across an internal reconnect: the board restarts its counter, the backend continues from
the last sequence number plus the frame periods that elapsed. Temperature messages are kept as
telemetry (:attr:`D2GSource.telemetry`), announcements of other settings are logged and skipped.

Faults: an unplugged port, a read or write error, a reply that does not come within the frame period
plus ``timeout_s``, or an error status are counted in ``stats.faults``; frames that arrive corrupted or
truncated in ``stats.malformed_frames``, runs of garbage the decoder skipped in ``stats.resyncs`` (all
three reach the frame loop's ``errors``); the port is closed and reopened
with exponential back-off (``backoff_s`` doubling up to ``backoff_max_s``, on the injectable clock),
the session is configured again and frames resume (``stats.reconnects``). After a framing error from
endpoint 0 the board ignores input until its line has been quiet for its timeout (10 s on the sibling
firmware), so the host then stays silent for ``quiet_s`` before it tries again. While that happens
``read_frame`` times out like any source without a frame; it never raises a transient fault into the
frame loop. A board that refuses the configuration (wrong format, interval below its minimum, no radar
base endpoint) raises :class:`D2GConfigError`.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any

from hal import comlib as cl
from hal.base import RadarSource, RawRead
from hal.clock import MonotonicClock
from hal.comlib import Ep0, Rbas, Rfmc
from hal.errors import DeviceError, ProtocolError, SourceUrlError
from hal.registry import Option, SourceUrl, resolve_options
from hal.waveform import FrontendInfo, d2g_frontend

log = logging.getLogger(__name__)

USB_VID = 0x058B
USB_PID = 0x0058
RBAS_TAG = "RBAS"
RFMC_TAG = "RFMC"
#: the frame format Tavanti et al. use (Table I): 64 samples x 21 chirps, RX antenna 1, I and Q
SIGNAL_PART_IQ = 2
RX_MASK = 0x01


class D2GConfigError(DeviceError):
    """The board refused or cannot hold the configuration the product needs (not transient)."""


class LinkStallError(DeviceError):
    """The board did not answer within the allowed time."""


class LinkLostError(DeviceError):
    """The serial port failed (unplugged, I/O error)."""


def _positive(text: str) -> float:
    v = float(text)
    if not v > 0:
        raise ValueError("must be > 0")
    return v


class _Link:
    """One open serial port and the stream decoder on it."""

    def __init__(self, port: Any, decoder: cl.Decoder) -> None:
        self.port = port
        self.decoder = decoder
        self.last_rx = time.monotonic()

    def send(self, data: bytes) -> None:
        try:
            self.port.write(data)
        except OSError as exc:  # pyserial's SerialException (and its timeout) derive from OSError
            raise LinkLostError(f"write to {self.port.port} failed: {exc}") from exc

    def read(self, max_wait_s: float) -> list[cl.Message]:
        """Messages completed by the bytes that arrive within ``max_wait_s`` (at least one byte ends the wait)."""
        try:
            self.port.timeout = max(0.0, max_wait_s)
            data = self.port.read(1)
            if data:
                n = self.port.in_waiting
                if n:
                    data += self.port.read(n)
        except OSError as exc:  # see send()
            raise LinkLostError(f"read from {self.port.port} failed: {exc}") from exc
        if not data:
            return []
        self.last_rx = time.monotonic()
        return self.decoder.feed(data)

    def close(self) -> None:
        try:
            self.port.close()
        except OSError as exc:  # closing a vanished port may fail; nothing to recover
            log.debug("closing %s: %s", getattr(self.port, "port", "?"), exc)


def find_boards() -> list[str]:
    """Serial ports with the Distance2Go's USB id (other XMC boards share it: check the endpoints)."""
    from serial.tools import list_ports

    return sorted(p.device for p in list_ports.comports() if p.vid == USB_VID and p.pid == USB_PID)


class D2GSource(RadarSource):
    scheme = "d2g"
    options = {
        "period_ms": Option(_positive, 200.0, "automatic trigger period in ms (Tavanti: 200)"),
        "timeout_s": Option(
            _positive, 1.0, "reply timeout in s beyond the frame period before the board counts as stalled"
        ),
        "gap_s": Option(_positive, 0.05, "silence in s after which a partly received message is abandoned"),
        "backoff_s": Option(_positive, 0.1, "first reconnect back-off in s (doubles per failed attempt)"),
        "backoff_max_s": Option(_positive, 0.5, "longest reconnect back-off in s"),
        "quiet_s": Option(
            _positive, 10.5, "silence in s after the board reported a framing error (its input timeout is 10 s)"
        ),
        "baud": Option(int, 115200, "serial baud rate (no effect on the USB virtual port)"),
        "tx_power": Option(int, None, "TX power level 0..max_tx_power (7 on the Distance2Go = full power); default: "
                                      "leave the board's (radar-edge calibrate --headroom picks it)"),
    }

    def __init__(
        self,
        target: str,
        *,
        period_ms: float = 200.0,
        timeout_s: float = 1.0,
        gap_s: float = 0.05,
        backoff_s: float = 0.1,
        backoff_max_s: float = 0.5,
        quiet_s: float = 10.5,
        baud: int = 115200,
        tx_power: int | None = None,
        clock: Any = None,
    ) -> None:
        self._clock = clock or MonotonicClock()
        if tx_power is not None and tx_power < 0:
            raise SourceUrlError(f"tx_power={tx_power} must be 0 or more")
        self.tx_power = tx_power
        super().__init__(clock_ns=self._clock.now_ns)
        if not target:
            raise SourceUrlError("d2g:// needs a port path or 'auto', e.g. d2g:///dev/ttyACM0 or d2g://auto")
        self.target = target
        self.period_s = period_ms / 1e3
        self.timeout_s = timeout_s
        self.gap_s = gap_s
        self.backoff_s = backoff_s
        self.backoff_max_s = max(backoff_max_s, backoff_s)
        self.quiet_s = quiet_s
        self.baud = baud
        base = d2g_frontend()
        wf = base.waveform
        if abs(wf.frame_period_s - self.period_s) > 1e-12:
            try:
                wf = dataclasses.replace(wf, frame_period_s=self.period_s)
            except ValueError as exc:
                cpi_ms = wf.segments[0].duration_s * 1e3
                raise SourceUrlError(
                    f"period_ms={period_ms:g} is shorter than the {cpi_ms:.1f} ms chirp burst: {exc}"
                ) from None
        self._frontend = dataclasses.replace(base, waveform=wf) if wf is not base.waveform else base
        _, n_ch, n_s = self._frontend.frame_shape
        self.frame_format = cl.FrameFormat(n_s, n_ch, RX_MASK, SIGNAL_PART_IQ)
        self._frame_len = cl.frame_payload_len(n_ch, n_s)
        self._link: _Link | None = None
        self.port_path: str | None = None
        self.endpoints: dict[str, int] = {}
        self.telemetry: dict[str, Any] = {}
        self._resyncs_done = 0  # decoder resyncs on links already closed
        self.failed_attempts = 0  # reconnect attempts that failed, over the source's life
        self.last_fault: str | None = None
        self._last_host_seq: int | None = None
        self._reset_session_state()

    @classmethod
    def from_url(cls, url: SourceUrl, overrides: dict[str, Any]) -> "D2GSource":
        clock = overrides.pop("clock", None)
        opts = resolve_options(url, cls.options, overrides)
        return cls(url.target, clock=clock, **opts)

    @property
    def frontend(self) -> FrontendInfo:
        return self._frontend

    @property
    def max_tx_power(self) -> int | None:
        """The highest TX power level of the ``tx_power`` option, as the board's device info reports it (None before
        the session is configured or when the board did not report it)."""
        info = self.telemetry.get("device")
        return None if info is None else int(info.max_tx_power)

    @property
    def corrupted_frames(self) -> int:
        """Frame requests that ended without a valid frame (``stats.malformed_frames``)."""
        return self.stats.malformed_frames

    @property
    def connected(self) -> bool:
        return self._link is not None

    # --- hooks ---------------------------------------------------------------------------------
    def _open(self) -> None:
        self._reset_session_state()
        self._last_host_seq = None
        try:
            self._connect()
        except (DeviceError, OSError) as exc:
            self._drop_link()
            if isinstance(exc, DeviceError):
                raise
            raise DeviceError(f"cannot open Distance2Go at {self.target}: {exc}") from exc

    def _close(self) -> None:
        link = self._link
        if link is not None and self.endpoints.get(RBAS_TAG):
            try:  # leave the board idle; best effort, the port may already be gone
                self._drain_pending()
                self._exchange(self.endpoints[RBAS_TAG], self._trigger_request(0), "stop trigger", self.gap_s + 0.2)
            except DeviceError as exc:
                log.debug("stopping the trigger at close: %s", exc)
        self._drop_link()
        self._down = False

    def _read_raw(self, timeout_s: float | None) -> RawRead | None:
        try:
            return self._read_raw_link(timeout_s)
        finally:
            link = self._link
            self.stats.resyncs = self._resyncs_done + (link.decoder.resyncs if link is not None else 0)

    def _read_raw_link(self, timeout_s: float | None) -> RawRead | None:
        t_end = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            if self._down:
                if not self._reconnect_step(t_end) and t_end is not None:
                    return None  # still reconnecting: the caller sees a timeout, never the fault
                continue
            try:
                raw = self._poll_frame(t_end)
            except (DeviceError, OSError) as exc:
                self._fault(exc)
                continue
            return raw

    # --- session -------------------------------------------------------------------------------
    def _reset_session_state(self) -> None:
        self._pending = False
        self._pending_since = 0.0
        self._frame: tuple[cl.FrameHeader, Any, Any] | None = None
        self._seq_offset: int | None = None
        self._last_frame_ns: int | None = None
        self._down = False
        self._attempt = 0
        self._next_attempt_ns = 0

    def _open_port(self, path: str) -> _Link:
        import serial  # lazy: only this backend needs pyserial

        try:
            port = serial.Serial(path, baudrate=self.baud, timeout=0, write_timeout=self.timeout_s, exclusive=True)
        except (OSError, ValueError) as exc:
            raise LinkLostError(f"cannot open {path}: {exc}") from exc
        try:
            port.reset_input_buffer()  # stale replies of an earlier session
        except OSError as exc:  # pyserial's SerialException is an OSError
            port.close()
            raise LinkLostError(f"cannot flush {path}: {exc}") from exc
        return _Link(port, cl.Decoder(max_payload=max(self._frame_len, cl.DEVICE_RX_BUFFER)))

    def _connect(self) -> None:
        """Open the port (finding the board for ``auto``) and configure the session."""
        if self.target == "auto":
            candidates = find_boards()
            if not candidates:
                raise LinkLostError(f"no USB serial port with id {USB_VID:04X}:{USB_PID:04X} (Distance2Go)")
        else:
            candidates = [self.target]
        last: Exception | None = None
        for path in candidates:
            self._link = self._open_port(path)
            try:
                self._drain_quiet()  # stale bytes of an earlier session
                self._discover()
            except D2GConfigError as exc:  # another XMC board: try the next one
                last = exc
                self._drop_link()
                continue
            except DeviceError:
                self._drop_link()
                raise
            self.port_path = path
            break
        else:
            raise D2GConfigError(f"no Distance2Go among {', '.join(candidates)}: {last}")
        try:
            self._configure()
        except DeviceError:
            self._drop_link()
            raise

    def _discover(self) -> None:
        for attempt in range(2):  # a stale status left on the line by an earlier session can end the first try
            if attempt:
                self._drain_quiet()
            payloads, _ = self._exchange(0, cl.request(0, Ep0.QUERY_ENDPOINT_INFO), "query endpoints")
            lists = [p for p in payloads if p.endpoint == 0 and p.msg_type == Ep0.QUERY_ENDPOINT_INFO]
            if lists:
                break
        else:
            raise LinkStallError("the endpoint query got a status but no endpoint list")
        records = cl.parse_endpoint_list(lists[-1].data)
        self.endpoints = {r.tag: r.number for r in records}
        self._link.decoder.max_endpoint = len(records)
        for tag in (RBAS_TAG, RFMC_TAG):
            r = next((r for r in records if r.tag == tag), None)
            if r is not None and r.version != cl.SUPPORTED_ENDPOINT_VERSION:
                raise D2GConfigError(f"endpoint {tag} has version {r.version}, only version 1 is supported")
        if RBAS_TAG not in self.endpoints:
            raise D2GConfigError(f"no radar base endpoint (RBAS) among {[r.tag for r in records]}: not a Distance2Go")
        self.telemetry["endpoints"] = {r.tag: r.number for r in records}

    def _configure(self) -> None:
        try:
            self._configure_session()
        except (cl.BusyError, cl.FramingStatusError, cl.UnknownStatusError):
            raise  # transient: a trigger we could not stop yet, a garbled request
        except cl.StatusError as exc:
            raise D2GConfigError(f"the board refused the configuration: {exc}") from exc

    def _optional(self, what: str, step: Any) -> Any:
        """Run an informational step; a board that does not know the request only costs a warning."""
        try:
            return step()
        except (cl.InvalidPayloadError, cl.UnknownCommandError, cl.MalformedMessageError) as exc:
            log.warning("%s not available: %s", what, exc)
            return None

    def _configure_session(self) -> None:
        ep = self.endpoints[RBAS_TAG]

        def firmware() -> cl.FirmwareInfo:
            payloads, _ = self._exchange(0, cl.request(0, Ep0.QUERY_FW_INFO), "firmware info")
            return self._reply(payloads, 0, Ep0.QUERY_FW_INFO, cl.FirmwareInfo.parse, "firmware info")

        def device() -> cl.DeviceInfo:
            payloads, _ = self._exchange(ep, cl.request(ep, Rbas.GET_DEVICE_INFO), "device info")
            return self._reply(payloads, ep, Rbas.DEVICE_INFO, cl.DeviceInfo.parse, "device info")

        def frame_format() -> cl.FrameFormat:
            payloads, _ = self._exchange(ep, cl.request(ep, Rbas.GET_FRAME_FORMAT), "frame format")
            return self._reply(payloads, ep, Rbas.FRAME_FORMAT, cl.FrameFormat.parse, "frame format")

        fw = self._optional("firmware info", firmware)
        self.telemetry["firmware"] = fw
        self._exchange(ep, self._trigger_request(0), "stop trigger")
        info = self._optional("device info", device)
        self.telemetry["device"] = info
        if info is not None and info.n_rx < 1:
            raise D2GConfigError(f"the board reports {info.n_rx} receive antennas")
        before = self._optional("frame format", frame_format)
        fm = self.endpoints.get(RFMC_TAG)
        if fm is not None:
            payloads, _ = self._exchange(fm, cl.request(fm, Rfmc.GET_CONFIGURATION), "FMCW configuration")
            ramp = self._reply(payloads, fm, Rfmc.CONFIGURATION, cl.FmcwConfig.parse, "FMCW configuration")
            wanted = ramp
            if ramp.direction != 0:  # 21 chirps is odd: alternating ramps are impossible, use up-chirps
                wanted = dataclasses.replace(wanted, direction=0)
            if self.tx_power is not None and ramp.tx_power != self.tx_power:
                if info is not None and self.tx_power > info.max_tx_power:
                    raise D2GConfigError(f"tx_power={self.tx_power}: the board's levels are 0..{info.max_tx_power}")
                wanted = dataclasses.replace(wanted, tx_power=self.tx_power)
            if wanted != ramp:
                ramp = wanted
                self._exchange(fm, cl.encode_payload(fm, ramp.encode()), "set FMCW direction and TX power")
            self.telemetry["fmcw"] = ramp
            self._check_ramp(ramp)
        elif self.tx_power is not None:
            raise D2GConfigError("tx_power is set, but the board has no FMCW endpoint (RFMC) to set it on")
        self.telemetry.pop("min_interval_us", None)
        self._exchange(ep, cl.encode_payload(ep, self.frame_format.encode()), "set frame format")
        announced = self.telemetry.get("min_interval_us")  # from the announcements after SET_FRAME_FORMAT
        min_us = self._optional(
            "minimum interval", lambda: self._get_u32(ep, Rbas.GET_MIN_INTERVAL, Rbas.MIN_INTERVAL, "minimum interval")
        )
        min_us = announced if min_us is None else min_us
        chirp_ns = self._optional(
            "chirp duration", lambda: self._get_u32(ep, Rbas.GET_CHIRP_DURATION, Rbas.CHIRP_DURATION, "chirp duration")
        )
        self.telemetry.update(min_interval_us=min_us, chirp_duration_ns=chirp_ns, frame_format=self.frame_format)
        seg = self._frontend.waveform.segments[0]
        if chirp_ns is not None and abs(chirp_ns * 1e-9 - seg.ramp_s) > 1e-6:
            log.warning(
                "board chirp duration %.3f ms differs from the front end's %.3f ms", chirp_ns / 1e6, seg.ramp_s * 1e3
            )
        period_us = int(round(self.period_s * 1e6))
        if min_us is not None and min_us > period_us:
            raise D2GConfigError(
                f"the board needs at least {min_us / 1e3:.1f} ms per frame; "
                f"period_ms={self.period_s * 1e3:g} is too short"
            )
        try:
            self._exchange(ep, self._trigger_request(period_us), "start trigger")
        except cl.FrameIntervalError as exc:
            raise D2GConfigError(f"period_ms={self.period_s * 1e3:g} is below the board's minimum: {exc}") from exc
        log.info(
            "Distance2Go on %s: firmware %s, %s; format %s (was %s); min interval %s ms, chirp %s ms; "
            "trigger every %.1f ms",
            self.port_path or self.target,
            f"{fw.major}.{fw.minor}.{fw.build} {fw.description!r}" if fw else "?",
            (info.description or "no description") if info else "no device info",
            self.frame_format,
            before,
            "?" if min_us is None else f"{min_us / 1e3:.1f}",
            "?" if chirp_ns is None else f"{chirp_ns / 1e6:.3f}",
            self.period_s * 1e3,
        )
        self._pending = False
        self._seq_offset = None

    def _check_ramp(self, ramp: cl.FmcwConfig) -> None:
        seg = self._frontend.waveform.segments[0]
        lo_khz = seg.f_start_hz / 1e3
        bw_khz = seg.bandwidth_hz / 1e3
        if abs(ramp.lower_khz - lo_khz) > 1 or abs(ramp.upper_khz - ramp.lower_khz - bw_khz) > 1:
            log.warning(
                "board ramp %d-%d kHz differs from the front end's %.0f-%.0f kHz",
                ramp.lower_khz, ramp.upper_khz, lo_khz, lo_khz + bw_khz,
            )

    def _get_u32(self, ep: int, request_type: int, reply_type: int, what: str) -> int:
        payloads, _ = self._exchange(ep, cl.request(ep, request_type), what)
        return self._reply(payloads, ep, reply_type, lambda d: cl.parse_u32_reply(d, reply_type, what), what)

    def _trigger_request(self, interval_us: int) -> bytes:
        ep = self.endpoints[RBAS_TAG]
        return cl.request(ep, Rbas.SET_AUTOMATIC_TRIGGER, interval_us.to_bytes(4, "little"))

    @staticmethod
    def _reply(payloads: list[cl.Payload], ep: int, msg_type: int, parse: Any, what: str) -> Any:
        for p in reversed(payloads):
            if p.endpoint == ep and p.msg_type == msg_type:
                return parse(p.data)
        raise cl.MalformedMessageError(f"{what}: the status came without a 0x{msg_type:02X} reply")

    def _exchange(
        self, ep: int, data: bytes, what: str, timeout_s: float | None = None
    ) -> tuple[list[cl.Payload], cl.Status]:
        """Send one request and collect payloads up to its status; raise on an error status or no answer."""
        link = self._link
        if link is None:
            raise LinkLostError("not connected")
        link.send(data)
        limit = self.timeout_s if timeout_s is None else timeout_s
        t0 = time.monotonic()
        payloads: list[cl.Payload] = []
        while True:
            now = time.monotonic()
            quiet = now - link.last_rx
            if now - t0 > limit and quiet > min(limit, self.gap_s):
                msgs = link.decoder.flush()
                if not any(isinstance(m, cl.Status) for m in msgs):
                    raise LinkStallError(f"{what}: no answer within {limit:g} s")
            else:
                msgs = link.read(min(self.gap_s, max(0.0, limit - (now - t0)) + 1e-3))
            for m in msgs:
                if isinstance(m, cl.Payload):
                    payloads.append(m)
                    self._note(m)
                elif m.endpoint in (ep, 0):
                    if m.code:
                        raise m.error(what)
                    return payloads, m
                else:
                    log.debug("%s: ignoring a status from endpoint %d", what, m.endpoint)

    def _drain_quiet(self) -> None:
        """Discard input until the line has been quiet for ``gap_s`` (at most ``timeout_s``)."""
        link = self._link
        resyncs = link.decoder.resyncs  # stale bytes of an earlier session are expected, not a link error
        t_end = time.monotonic() + self.timeout_s
        while time.monotonic() < t_end:
            msgs = link.read(self.gap_s)
            if not msgs and time.monotonic() - link.last_rx >= self.gap_s:
                break
        link.decoder.reset()
        link.decoder.resyncs = resyncs

    def _drain_pending(self) -> None:
        """Let an outstanding frame request finish, so that its status is not taken for the next one."""
        link = self._link
        ep = self.endpoints[RBAS_TAG]
        t_end = time.monotonic() + self.period_s + self.gap_s
        while self._pending and time.monotonic() < t_end:
            for m in link.read(min(self.gap_s, max(0.0, t_end - time.monotonic()))):
                if isinstance(m, cl.Status) and m.endpoint in (ep, 0):
                    self._pending = False
        self._pending = False

    def _note(self, p: cl.Payload) -> None:
        """Keep telemetry from announcements; everything else is skipped."""
        if p.endpoint == self.endpoints.get(RBAS_TAG):
            try:
                if p.msg_type == Rbas.TEMPERATURE:
                    _, mc = cl.parse_sensor_reply(p.data, Rbas.TEMPERATURE, "temperature")
                    self.telemetry["temperature_c"] = mc / 1000.0
                elif p.msg_type == Rbas.MIN_INTERVAL:
                    us = cl.parse_u32_reply(p.data, Rbas.MIN_INTERVAL, "minimum interval")
                    self.telemetry["min_interval_us"] = us
            except ProtocolError as exc:
                log.debug("skipping a malformed announcement: %s", exc)
                return
        log.debug("announcement from endpoint %d, type 0x%02X (%d bytes)", p.endpoint, p.msg_type, len(p.data))

    # --- frames --------------------------------------------------------------------------------
    def _poll_frame(self, t_end: float | None) -> RawRead | None:
        link = self._link
        ep = self.endpoints[RBAS_TAG]
        stall_s = self.period_s + self.timeout_s
        while True:
            if not self._pending:
                link.send(cl.request(ep, Rbas.GET_FRAME_DATA, b"\x01"))
                self._pending = True
                self._pending_since = time.monotonic()
                self._frame = None
            now = time.monotonic()
            if t_end is not None and now >= t_end:
                return None
            msgs: list[cl.Message]
            if link.decoder.buffered and now - link.last_rx > self.gap_s:
                msgs = link.decoder.flush()  # a truncated message will not complete
            elif now - self._pending_since > stall_s and now - link.last_rx > self.timeout_s:
                msgs = link.decoder.flush()
                if not msgs:
                    raise LinkStallError(f"no frame and no status for {now - self._pending_since:.1f} s")
            else:
                wait = self.gap_s if link.decoder.buffered else stall_s
                if t_end is not None:
                    wait = min(wait, t_end - now)
                msgs = link.read(max(0.0, wait))
            for m in msgs:
                if isinstance(m, cl.Payload):
                    if m.endpoint == ep and m.msg_type == Rbas.FRAME_DATA:
                        self._take_frame(m.data)
                    else:
                        self._note(m)
                    continue
                if m.endpoint not in (ep, 0):
                    log.debug("ignoring a status from endpoint %d", m.endpoint)
                    continue
                self._pending = False
                frame, self._frame = self._frame, None
                if m.code:
                    err = m.error("frame request")
                    if isinstance(err, cl.NoFrameReadyError):
                        continue
                    raise err
                if frame is None:
                    self.stats.malformed_frames += 1
                    log.info("frame request ended without a valid frame (corrupted or truncated)")
                    continue
                return self._raw(frame)

    def _take_frame(self, data: bytes) -> None:
        try:
            h, i, q = cl.parse_frame(data)
            if (h.n_rx, h.n_chirps, h.n_samples) != self._frontend.frame_shape:
                raise cl.MalformedMessageError(
                    f"frame of {h.n_rx}x{h.n_chirps}x{h.n_samples}, configured {self._frontend.frame_shape}"
                )
        except ProtocolError as exc:  # counted when its status arrives without a valid frame
            log.warning("dropping a malformed frame: %s", exc)
            return
        self._frame = (h, i, q)

    def _raw(self, frame: tuple[cl.FrameHeader, Any, Any]) -> RawRead:
        h, i, q = frame
        now_ns = self._clock.now_ns()
        if self._seq_offset is None:  # first frame since the trigger (re)started
            if self._last_host_seq is None or self._last_frame_ns is None:
                first = h.frame_number
            else:
                periods = round((now_ns - self._last_frame_ns) / (self.period_s * 1e9))
                first = self._last_host_seq + max(1, periods)
            self._seq_offset = first - h.frame_number
        seq = self._seq_offset + h.frame_number
        self._last_host_seq = seq
        self._last_frame_ns = now_ns
        meta = {"frame_number": h.frame_number}
        if "temperature_c" in self.telemetry:
            meta["temperature_c"] = self.telemetry["temperature_c"]
        return RawRead(seq=seq, i=i, q=q, t_ns=now_ns, meta=meta)

    # --- faults and reconnection ------------------------------------------------------------------
    def _fault(self, exc: Exception) -> None:
        self.stats.faults += 1
        self.last_fault = f"{type(exc).__name__}: {exc}"
        log.warning("Distance2Go fault (%s); reconnecting", self.last_fault)
        self._drop_link()
        self._down = True
        self._attempt = 0
        self._next_attempt_ns = self._clock.now_ns() + int(self._delay_after(exc) * 1e9)

    def _delay_after(self, exc: Exception) -> float:
        """Back-off before the next attempt; after a framing error the board must see a quiet line."""
        if isinstance(exc, cl.FramingStatusError):
            return self.quiet_s
        return min(self.backoff_max_s, self.backoff_s * 2.0 ** self._attempt)

    def _reconnect_step(self, t_end: float | None) -> bool:
        """Wait for the next attempt (within the caller's time) and try once; True once reconnected.

        A board that answers but refuses the configuration raises :class:`D2GConfigError`.
        """
        now_ns = self._clock.now_ns()
        if now_ns < self._next_attempt_ns:
            if t_end is None:
                self._clock.sleep_until_ns(self._next_attempt_ns)
            else:
                left_ns = int(max(0.0, t_end - time.monotonic()) * 1e9)
                self._clock.sleep_until_ns(min(self._next_attempt_ns, now_ns + left_ns))
            if self._clock.now_ns() < self._next_attempt_ns:
                return False
        try:
            self._connect()
        except D2GConfigError:
            self._drop_link()
            raise
        except (DeviceError, OSError) as exc:
            self._drop_link()
            self._attempt += 1
            self.failed_attempts += 1
            delay = self._delay_after(exc)
            log.info("reconnect attempt %d failed (%s); next in %.2f s", self._attempt, exc, delay)
            self._next_attempt_ns = self._clock.now_ns() + int(delay * 1e9)
            return False
        self._down = False
        self.stats.reconnects += 1
        log.warning("Distance2Go reconnected on %s after %d failed attempt(s)", self.port_path, self._attempt)
        return True

    def _drop_link(self) -> None:
        if self._link is not None:
            self._resyncs_done += self._link.decoder.resyncs
            self._link.close()
            self._link = None
        self._pending = False
