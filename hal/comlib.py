"""Infineon host protocol ("ComLib") of the Distance2Go, as a sans-IO codec.

Nothing here touches a port (pymodbus ``FramerBase`` style): :class:`Decoder` turns bytes, in any
chunking, into :class:`Payload` and :class:`Status` messages and resynchronises on the next start
byte after garbage; the ``encode_*``/``*_request`` helpers build the bytes of requests and replies;
the ``parse_*`` helpers read the payloads of the messages the D2G backend and its emulator exchange.

Wire format (all numbers little-endian):

* payload message: ``5A ep L(u16) payload[L] DB E0``; byte 0 of the payload is the message type;
* status message (device to host only): ``5B ep code(u16)``; it ends every exchange.

Every non-zero status code maps to a named :class:`StatusError` subclass (:func:`status_error`).
The decoder itself never raises on input: garbage is skipped and counted in ``Decoder.discarded``
(bytes) and ``Decoder.resyncs`` (runs of garbage).
The payload parsers raise :class:`MalformedMessageError`, the request builders
:class:`RequestError`; all are :class:`hal.errors.ProtocolError`.

12-bit samples are packed LSB first, two samples in three bytes (``b0 b1 b2``: first =
``b0 + 256 (b1 & 0x0F)``, second = ``(b1 >> 4) + 16 b2``), as unsigned ADC counts; the frame
parser returns them centred (minus 2048) as int16 I and Q shaped ``(n_rx, n_chirps, n_samples)``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import Union

import numpy as np

from hal.errors import ProtocolError

PAYLOAD_START = 0x5A
STATUS_START = 0x5B
END_MARKER = b"\xdb\xe0"
HEADER_LEN = 4
STATUS_LEN = 4
TAIL_LEN = 2
MAX_PAYLOAD = 0xFFFF
#: the device's receive buffer for host messages (firmware Protocol.c)
DEVICE_RX_BUFFER = 512
#: only protocol version the host library accepts for every endpoint type
SUPPORTED_ENDPOINT_VERSION = 1


class Ep0(IntEnum):
    """Message types of endpoint 0 (the protocol itself)."""

    QUERY_ENDPOINT_INFO = 0x00
    QUERY_FW_INFO = 0x01
    FIRMWARE_RESET = 0x02


class Rbas(IntEnum):
    """Message types of the radar base endpoint (RBAS)."""

    FRAME_DATA = 0x00
    GET_FRAME_DATA = 0x01
    SET_AUTOMATIC_TRIGGER = 0x02
    ENABLE_TEST_MODE = 0x03
    GET_DRIVER_VERSION = 0x20
    DRIVER_VERSION = 0x21
    GET_DEVICE_INFO = 0x22
    DEVICE_INFO = 0x23
    GET_TEMPERATURE = 0x30
    TEMPERATURE = 0x31
    GET_TX_POWER = 0x32
    TX_POWER = 0x33
    GET_CHIRP_DURATION = 0x34
    CHIRP_DURATION = 0x35
    GET_MIN_INTERVAL = 0x36
    MIN_INTERVAL = 0x37
    GET_FRAME_FORMAT = 0x40
    FRAME_FORMAT = 0x41  # also SET_FRAME_FORMAT


class Rfmc(IntEnum):
    """Message types of the FMCW endpoint (RFMC)."""

    GET_CONFIGURATION = 0x00
    CONFIGURATION = 0x01  # also SET_CONFIGURATION
    BW_PER_SECOND = 0x02  # request and reply


class Radx(IntEnum):
    """Message types of the XMC ADC endpoint (RADX)."""

    GET_CONFIGURATION = 0x00
    CONFIGURATION = 0x01


def tag_code(tag: str) -> int:
    """u32 type constant of an endpoint tag (``'RBAS'`` -> 0x52424153)."""
    return int.from_bytes(tag.encode("ascii"), "big")


def code_tag(code: int) -> str:
    return code.to_bytes(4, "big").decode("ascii", errors="replace")


# --- errors -------------------------------------------------------------------------------------


class RequestError(ProtocolError, ValueError):
    """A request cannot be encoded (endpoint or field out of range, empty payload)."""


class MalformedMessageError(ProtocolError):
    """A payload does not have the layout its message type requires."""


class StatusError(ProtocolError):
    """The device answered with a non-zero status. Subclasses name each code."""

    #: meaning shown in the message; the subclass's code (``None`` for ranges / unknown codes)
    meaning = "status"
    status_code: int | None = None

    def __init__(self, endpoint: int, code: int, context: str = "") -> None:
        self.endpoint = endpoint
        self.code = code
        where = f"{context}: " if context else ""
        super().__init__(f"{where}endpoint {endpoint} answered status 0x{code:04X} ({self.meaning})")


class FramingStatusError(StatusError):
    """A status from endpoint 0: the device could not frame the host's message."""

    meaning = "protocol error"


class IncompleteMessageError(FramingStatusError):
    status_code, meaning = 0x0001, "message incomplete (device timeout)"


class BadStartByteError(FramingStatusError):
    status_code, meaning = 0x0002, "bad start byte"


class NoSuchEndpointError(FramingStatusError):
    status_code, meaning = 0x0003, "endpoint does not exist"


class EmptyPayloadError(FramingStatusError):
    status_code, meaning = 0x0005, "empty payload"


class PayloadTooLargeError(FramingStatusError):
    status_code, meaning = 0x0006, "payload larger than the device buffer"


class BadEndMarkerError(FramingStatusError):
    status_code, meaning = 0x0007, "bad end marker"


class UnknownCommandError(FramingStatusError):
    status_code, meaning = 0xFFFF, "unknown command"


class EndpointStatusError(StatusError):
    """A status from a radar endpoint (RBAS, RFMC, RDPL, RADX, ...)."""

    meaning = "endpoint error"


class BusyError(EndpointStatusError):
    status_code, meaning = 0x0002, "busy: trigger or test mode active"


class IncompatibleModeError(EndpointStatusError):
    status_code, meaning = 0x0003, "incompatible mode"


class NoFrameReadyError(EndpointStatusError):
    status_code, meaning = 0x0004, "no new frame ready"


class FrameIntervalError(EndpointStatusError):
    status_code, meaning = 0x0005, "frame interval unsupported or below the minimum"


class NoSuchAntennaError(EndpointStatusError):
    status_code, meaning = 0x0006, "antenna does not exist"


class NoSuchSensorError(EndpointStatusError):
    status_code, meaning = 0x0007, "temperature sensor does not exist"


class UnsupportedFrameFormatError(EndpointStatusError):
    status_code, meaning = 0x0008, "frame format unsupported"


class FrequencyRangeError(EndpointStatusError):
    status_code, meaning = 0x0009, "frequency out of range"


class TxPowerRangeError(EndpointStatusError):
    status_code, meaning = 0x000A, "TX power out of range"


class SignalPartError(EndpointStatusError):
    status_code, meaning = 0x000B, "signal part unavailable"


class FmcwDirectionError(EndpointStatusError):
    status_code, meaning = 0x0020, "FMCW direction unsupported"


class SampleRateError(EndpointStatusError):
    status_code, meaning = 0x0050, "sample rate or samples per chirp out of range"


class AdcResolutionError(EndpointStatusError):
    status_code, meaning = 0x0051, "ADC resolution unsupported"


class InvalidPayloadError(EndpointStatusError):
    status_code, meaning = 0xFFFF, "invalid payload (unknown type or wrong length)"


class ChipError(EndpointStatusError):
    """0x0100-0x0135: PLL, shape-sequence and FIFO errors of other Infineon radar chips."""

    meaning = "radar chip error (PLL, shape sequence or FIFO)"


class UnknownStatusError(StatusError):
    meaning = "unknown status code"


FRAMING_STATUS: dict[int, type[StatusError]] = {
    c.status_code: c
    for c in (
        IncompleteMessageError,
        BadStartByteError,
        NoSuchEndpointError,
        EmptyPayloadError,
        PayloadTooLargeError,
        BadEndMarkerError,
        UnknownCommandError,
    )
}
ENDPOINT_STATUS: dict[int, type[StatusError]] = {
    c.status_code: c
    for c in (
        BusyError,
        IncompatibleModeError,
        NoFrameReadyError,
        FrameIntervalError,
        NoSuchAntennaError,
        NoSuchSensorError,
        UnsupportedFrameFormatError,
        FrequencyRangeError,
        TxPowerRangeError,
        SignalPartError,
        FmcwDirectionError,
        SampleRateError,
        AdcResolutionError,
        InvalidPayloadError,
    )
}
CHIP_STATUS_RANGE = range(0x0100, 0x0136)


def status_error_class(endpoint: int, code: int) -> type[StatusError] | None:
    """The named error class of a status code (``None`` for 0 = OK)."""
    if code == 0:
        return None
    if endpoint == 0:
        return FRAMING_STATUS.get(code, UnknownStatusError)
    if code in CHIP_STATUS_RANGE:
        return ChipError
    return ENDPOINT_STATUS.get(code, UnknownStatusError)


def status_error(endpoint: int, code: int, context: str = "") -> StatusError | None:
    cls = status_error_class(endpoint, code)
    return None if cls is None else cls(endpoint, code, context)


# --- messages and the stream decoder ------------------------------------------------------------


@dataclass(frozen=True)
class Payload:
    """A payload message: ``data[0]`` is the endpoint's message type."""

    endpoint: int
    data: bytes

    @property
    def msg_type(self) -> int:
        return self.data[0]

    def encode(self) -> bytes:
        return encode_payload(self.endpoint, self.data)


@dataclass(frozen=True)
class Status:
    """A status message: the end of one exchange."""

    endpoint: int
    code: int

    @property
    def ok(self) -> bool:
        return self.code == 0

    def error(self, context: str = "") -> StatusError | None:
        return status_error(self.endpoint, self.code, context)

    def encode(self) -> bytes:
        return encode_status(self.endpoint, self.code)


Message = Union[Payload, Status]


def encode_payload(endpoint: int, data: bytes) -> bytes:
    if not 0 <= endpoint <= 0xFF:
        raise RequestError(f"endpoint {endpoint} outside 0..255")
    if not 1 <= len(data) <= MAX_PAYLOAD:
        raise RequestError(f"payload length {len(data)} outside 1..{MAX_PAYLOAD}")
    return bytes((PAYLOAD_START, endpoint)) + struct.pack("<H", len(data)) + bytes(data) + END_MARKER


def encode_status(endpoint: int, code: int) -> bytes:
    if not 0 <= endpoint <= 0xFF or not 0 <= code <= 0xFFFF:
        raise RequestError(f"status endpoint {endpoint} / code {code} out of range")
    return struct.pack("<BBH", STATUS_START, endpoint, code)


class Decoder:
    """Bytes in, messages out, from any chunking of the stream.

    ``feed(data)`` returns the messages completed by ``data``. A byte that does not start a
    plausible message (wrong start byte, zero or over-long length, endpoint above ``max_endpoint``,
    missing end marker) is skipped and the search restarts at the next start byte; skipped bytes are
    counted in :attr:`discarded`. A false start byte followed by a long length keeps the decoder
    waiting for bytes that will never come: when the line has been quiet for the protocol timeout,
    call :meth:`flush`, which drops that start byte and parses the rest (ComLib discards input until
    a read times out).

    ``accept_status=False`` is the device's view: the host sends payload messages only.
    """

    def __init__(
        self, *, max_payload: int = MAX_PAYLOAD, max_endpoint: int = 0xFF, accept_status: bool = True
    ) -> None:
        self.max_payload = max_payload
        self.max_endpoint = max_endpoint
        self.accept_status = accept_status
        self._buf = bytearray()
        self.discarded = 0
        self.decoded = 0
        #: times the decoder lost the message boundaries and skipped bytes to find them again (one per
        #: run of garbage between two good messages, however it was chunked)
        self.resyncs = 0
        self._lost = False

    @property
    def buffered(self) -> int:
        """Bytes held back waiting for the rest of a message."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Message]:
        self._buf += data
        return self._parse()

    def flush(self) -> list[Message]:
        """The line went quiet: give up on the incomplete message at the head and resynchronise."""
        out: list[Message] = []
        while self._buf:
            n = self._next_start(0)
            if n and not self._lost:
                self._lost = True
                self.resyncs += 1
            self._drop(n)
            out += self._parse()
        return out

    def reset(self) -> None:
        """Forget everything buffered (after reopening the port)."""
        self.discarded += len(self._buf)
        self._buf.clear()
        self._lost = False

    def _drop(self, n: int) -> None:
        self.discarded += n
        del self._buf[:n]

    def _next_start(self, pos: int) -> int:
        """Index of the first start byte after ``pos`` (``len`` if none)."""
        buf = self._buf
        n = len(buf)
        a = buf.find(PAYLOAD_START, pos + 1)
        best = n if a < 0 else a
        if self.accept_status:
            b = buf.find(STATUS_START, pos + 1, best)
            if b >= 0:
                best = b
        return best

    def _parse(self) -> list[Message]:
        out: list[Message] = []
        buf = self._buf
        n = len(buf)
        pos = 0
        skipped = 0
        lost = self._lost
        while pos < n:
            start = buf[pos]
            if start == PAYLOAD_START:
                if n - pos < HEADER_LEN:
                    break
                ep = buf[pos + 1]
                length = buf[pos + 2] | (buf[pos + 3] << 8)
                if length == 0 or length > self.max_payload or ep > self.max_endpoint:
                    nxt = self._next_start(pos)
                    skipped += nxt - pos
                    pos = nxt
                    if not lost:
                        lost = True
                        self.resyncs += 1
                    continue
                end = pos + HEADER_LEN + length
                if n < end + TAIL_LEN:
                    break
                if buf[end] != END_MARKER[0] or buf[end + 1] != END_MARKER[1]:
                    nxt = self._next_start(pos)
                    skipped += nxt - pos
                    pos = nxt
                    if not lost:
                        lost = True
                        self.resyncs += 1
                    continue
                out.append(Payload(ep, bytes(buf[pos + HEADER_LEN : end])))
                pos = end + TAIL_LEN
                lost = False
            elif start == STATUS_START and self.accept_status:
                if n - pos < STATUS_LEN:
                    break
                ep = buf[pos + 1]
                if ep > self.max_endpoint:
                    nxt = self._next_start(pos)
                    skipped += nxt - pos
                    pos = nxt
                    if not lost:
                        lost = True
                        self.resyncs += 1
                    continue
                out.append(Status(ep, buf[pos + 2] | (buf[pos + 3] << 8)))
                pos += STATUS_LEN
                lost = False
            else:
                nxt = self._next_start(pos)
                skipped += nxt - pos
                pos = nxt
                if not lost:
                    lost = True
                    self.resyncs += 1
        del buf[:pos]
        self._lost = lost
        self.discarded += skipped
        self.decoded += len(out)
        return out


# --- 12-bit packing -----------------------------------------------------------------------------

ADC_BITS = 12
ADC_OFFSET = 1 << (ADC_BITS - 1)


def packed_len_12(count: int) -> int:
    return (count * 12 + 7) // 8


def unpack12(buf: bytes | memoryview | np.ndarray, count: int) -> np.ndarray:
    """``count`` unsigned 12-bit samples (uint16) from an LSB-first packed stream."""
    b = np.frombuffer(buf, dtype=np.uint8) if not isinstance(buf, np.ndarray) else buf.astype(np.uint8, copy=False)
    need = packed_len_12(count)
    if b.size < need:
        raise MalformedMessageError(f"{b.size} packed bytes hold fewer than {count} 12-bit samples")
    groups = (count + 1) // 2
    g = b[:need]
    if groups * 3 != need:  # odd count: the last group has only two bytes
        g = np.concatenate([g, np.zeros(groups * 3 - need, dtype=np.uint8)])
    g = g.reshape(groups, 3).astype(np.uint16)
    out = np.empty(groups * 2, dtype=np.uint16)
    out[0::2] = g[:, 0] | ((g[:, 1] & 0x0F) << 8)
    out[1::2] = (g[:, 1] >> 4) | (g[:, 2] << 4)
    return out[:count]


def pack12(values: np.ndarray) -> bytes:
    """Pack unsigned 12-bit samples (0..4095) LSB first; inverse of :func:`unpack12`."""
    v = np.asarray(values).ravel()
    if v.size and (int(v.min()) < 0 or int(v.max()) > 0xFFF):
        raise RequestError("12-bit samples must lie in 0..4095")
    count = v.size
    v = v.astype(np.uint16)
    if count % 2:
        v = np.concatenate([v, np.zeros(1, dtype=np.uint16)])
    a, b = v[0::2], v[1::2]
    g = np.empty((a.size, 3), dtype=np.uint8)
    g[:, 0] = a & 0xFF
    g[:, 1] = (a >> 8) | ((b & 0x0F) << 4)
    g[:, 2] = b >> 4
    return g.tobytes()[: packed_len_12(count)]


# --- payloads -----------------------------------------------------------------------------------


def _need(data: bytes, n: int, what: str, exact: bool = False) -> None:
    if len(data) < n or (exact and len(data) != n):
        raise MalformedMessageError(f"{what}: payload of {len(data)} bytes, expected {'' if exact else 'at least '}{n}")


def _cstring(data: bytes) -> str:
    return data.split(b"\x00", 1)[0].decode("ascii", errors="replace")


def request(endpoint: int, msg_type: int, body: bytes = b"") -> bytes:
    """The bytes of a host request: a payload message whose first byte is ``msg_type``."""
    if not 0 <= msg_type <= 0xFF:
        raise RequestError(f"message type {msg_type} outside 0..255")
    return encode_payload(endpoint, bytes((msg_type,)) + body)


@dataclass(frozen=True)
class EndpointRecord:
    number: int
    tag: str
    version: int


def encode_endpoint_list(tags: list[tuple[str, int]]) -> bytes:
    body = bytes((Ep0.QUERY_ENDPOINT_INFO, len(tags)))
    return body + b"".join(struct.pack("<IH", tag_code(t), v) for t, v in tags)


def parse_endpoint_list(data: bytes) -> tuple[EndpointRecord, ...]:
    _need(data, 2, "endpoint list")
    if data[0] != Ep0.QUERY_ENDPOINT_INFO:
        raise MalformedMessageError(f"endpoint list: type 0x{data[0]:02X}")
    n = data[1]
    _need(data, 2 + 6 * n, "endpoint list", exact=True)
    out = []
    for k in range(n):
        code, ver = struct.unpack_from("<IH", data, 2 + 6 * k)
        out.append(EndpointRecord(k + 1, code_tag(code), ver))
    return tuple(out)


@dataclass(frozen=True)
class FirmwareInfo:
    major: int
    minor: int
    build: int
    description: str = ""

    def encode(self) -> bytes:
        return struct.pack("<BHHH", Ep0.QUERY_FW_INFO, self.major, self.minor, self.build) + (
            self.description.encode("ascii") + b"\x00" if self.description else b""
        )

    @classmethod
    def parse(cls, data: bytes) -> "FirmwareInfo":
        _need(data, 7, "firmware info")
        if data[0] != Ep0.QUERY_FW_INFO:
            raise MalformedMessageError(f"firmware info: type 0x{data[0]:02X}")
        major, minor, build = struct.unpack_from("<HHH", data, 1)
        return cls(major, minor, build, _cstring(data[7:]))


@dataclass(frozen=True)
class DeviceInfo:
    min_rf_khz: int
    max_rf_khz: int
    n_tx: int
    n_rx: int
    max_tx_power: int
    n_temp_sensors: int
    hw_major: int
    hw_minor: int
    interleaved_rx: int
    data_format: int
    description: str = ""

    _FMT = "<BIIBBBBBBBB"

    def encode(self) -> bytes:
        return struct.pack(
            self._FMT,
            Rbas.DEVICE_INFO,
            self.min_rf_khz,
            self.max_rf_khz,
            self.n_tx,
            self.n_rx,
            self.max_tx_power,
            self.n_temp_sensors,
            self.hw_major,
            self.hw_minor,
            self.interleaved_rx,
            self.data_format,
        ) + self.description.encode("ascii") + b"\x00"

    @classmethod
    def parse(cls, data: bytes) -> "DeviceInfo":
        _need(data, 17, "device info")
        if data[0] != Rbas.DEVICE_INFO:
            raise MalformedMessageError(f"device info: type 0x{data[0]:02X}")
        f = struct.unpack_from(cls._FMT, data, 0)
        return cls(*f[1:], description=_cstring(data[17:]))


@dataclass(frozen=True)
class FrameFormat:
    samples_per_chirp: int
    chirps_per_frame: int
    rx_mask: int
    signal_part: int  # 0 = I only, 1 = Q only, 2 = I and Q

    def encode(self) -> bytes:
        return struct.pack(
            "<BIIBB", Rbas.FRAME_FORMAT, self.samples_per_chirp, self.chirps_per_frame, self.rx_mask, self.signal_part
        )

    @classmethod
    def parse(cls, data: bytes) -> "FrameFormat":
        _need(data, 11, "frame format", exact=True)
        if data[0] != Rbas.FRAME_FORMAT:
            raise MalformedMessageError(f"frame format: type 0x{data[0]:02X}")
        return cls(*struct.unpack_from("<IIBB", data, 1))


@dataclass(frozen=True)
class FmcwConfig:
    lower_khz: int
    upper_khz: int
    direction: int  # 0 up, 1 down, 2 alternating up first, 3 alternating down first
    tx_power: int

    def encode(self) -> bytes:
        return struct.pack("<BIIBB", Rfmc.CONFIGURATION, self.lower_khz, self.upper_khz, self.direction, self.tx_power)

    @classmethod
    def parse(cls, data: bytes) -> "FmcwConfig":
        _need(data, 11, "FMCW configuration", exact=True)
        if data[0] != Rfmc.CONFIGURATION:
            raise MalformedMessageError(f"FMCW configuration: type 0x{data[0]:02X}")
        return cls(*struct.unpack_from("<IIBB", data, 1))


def encode_u32_reply(msg_type: int, value: int) -> bytes:
    return struct.pack("<BI", msg_type, value)


def parse_u32_reply(data: bytes, msg_type: int, what: str) -> int:
    _need(data, 5, what, exact=True)
    if data[0] != msg_type:
        raise MalformedMessageError(f"{what}: type 0x{data[0]:02X}, expected 0x{msg_type:02X}")
    return struct.unpack_from("<I", data, 1)[0]


def encode_sensor_reply(msg_type: int, index: int, value: int) -> bytes:
    """Temperature (0x31, m°C) and TX power (0x33, m dBm) replies: u8 index, i32 value."""
    return struct.pack("<BBi", msg_type, index, value)


def parse_sensor_reply(data: bytes, msg_type: int, what: str) -> tuple[int, int]:
    _need(data, 6, what, exact=True)
    if data[0] != msg_type:
        raise MalformedMessageError(f"{what}: type 0x{data[0]:02X}, expected 0x{msg_type:02X}")
    idx, value = struct.unpack_from("<Bi", data, 1)
    return idx, value


# --- frames -------------------------------------------------------------------------------------

FRAME_HEADER = struct.Struct("<BIIBIBBBB")  # 18 bytes


@dataclass(frozen=True)
class FrameHeader:
    frame_number: int
    n_chirps: int
    n_rx: int
    n_samples: int
    rx_mask: int
    data_format: int  # 0 real, 1 complex in separate I and Q blocks, 2 complex interleaved
    adc_bits: int
    interleaved_rx: int

    @property
    def n_values(self) -> int:
        return self.n_chirps * self.n_samples * self.n_rx * (1 if self.data_format == 0 else 2)

    @property
    def payload_len(self) -> int:
        return FRAME_HEADER.size + (self.n_values * self.adc_bits + 7) // 8


def frame_payload_len(n_chirps: int, n_samples: int, n_rx: int = 1, complex_iq: bool = True) -> int:
    return FRAME_HEADER.size + packed_len_12(n_chirps * n_samples * n_rx * (2 if complex_iq else 1))


def encode_frame(
    frame_number: int, i: np.ndarray, q: np.ndarray, *, rx_mask: int = 1, data_format: int = 1
) -> bytes:
    """FRAME_DATA payload of centred int16 ``i``/``q`` shaped (n_rx, n_chirps, n_samples)."""
    if i.shape != q.shape or i.ndim != 3:
        raise RequestError(f"I and Q must share a (n_rx, n_chirps, n_samples) shape, got {i.shape} / {q.shape}")
    n_rx, n_ch, n_s = i.shape
    iu = i.astype(np.int32) + ADC_OFFSET
    qu = q.astype(np.int32) + ADC_OFFSET
    if data_format == 1:  # per chirp, per antenna: N I samples then N Q samples
        x = np.stack([iu, qu], axis=2).transpose(1, 0, 2, 3)  # (n_ch, n_rx, 2, n_s)
    elif data_format == 2:  # per chirp, per antenna, per sample: I, Q
        x = np.stack([iu, qu], axis=3).transpose(1, 0, 2, 3)  # (n_ch, n_rx, n_s, 2)
    else:
        raise RequestError(f"data_format {data_format} cannot carry I and Q")
    head = FRAME_HEADER.pack(Rbas.FRAME_DATA, frame_number, n_ch, n_rx, n_s, rx_mask, data_format, ADC_BITS, 0)
    return head + pack12(x)


def parse_frame_header(data: bytes) -> FrameHeader:
    _need(data, FRAME_HEADER.size, "frame")
    f = FRAME_HEADER.unpack_from(data, 0)
    if f[0] != Rbas.FRAME_DATA:
        raise MalformedMessageError(f"frame: type 0x{f[0]:02X}")
    return FrameHeader(*f[1:])


def parse_frame(data: bytes) -> tuple[FrameHeader, np.ndarray, np.ndarray]:
    """Header and centred int16 I, Q shaped (n_rx, n_chirps, n_samples) of a FRAME_DATA payload."""
    h = parse_frame_header(data)
    if h.adc_bits != ADC_BITS:
        raise MalformedMessageError(f"frame: {h.adc_bits}-bit samples, only 12-bit data is supported")
    if h.data_format not in (1, 2):
        raise MalformedMessageError(f"frame: data_format {h.data_format} has no I/Q pair (need 1 or 2)")
    if h.interleaved_rx not in (0, 1) or (h.interleaved_rx == 1 and h.n_rx > 1):
        raise MalformedMessageError("frame: antenna-interleaved data from several antennas is not supported")
    if min(h.n_chirps, h.n_rx, h.n_samples) == 0:
        raise MalformedMessageError("frame: empty dimensions")
    if len(data) != h.payload_len:
        raise MalformedMessageError(f"frame: payload of {len(data)} bytes, header implies {h.payload_len}")
    x = unpack12(np.frombuffer(data, dtype=np.uint8, offset=FRAME_HEADER.size), h.n_values)
    xs = x.astype(np.int16) - np.int16(ADC_OFFSET)
    if h.data_format == 1:
        x4 = xs.reshape(h.n_chirps, h.n_rx, 2, h.n_samples)
        i, q = x4[:, :, 0, :], x4[:, :, 1, :]
    else:
        x4 = xs.reshape(h.n_chirps, h.n_rx, h.n_samples, 2)
        i, q = x4[..., 0], x4[..., 1]
    return h, np.ascontiguousarray(i.transpose(1, 0, 2)), np.ascontiguousarray(q.transpose(1, 0, 2))
