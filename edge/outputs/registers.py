"""The Modbus register map: one declarative table -> image builder, documentation and tests.

Conventions (stated in the generated documentation too):

* Addresses are 0-based PDU addresses. The 1-based "register numbers" a PLC shows are 30001 + address
  (input registers, FC4) and 40001 + address (holding registers, FC3); mbpoll takes the 1-based
  reference ``address + 1`` with ``-t 3`` (FC4) or ``-t 4`` (FC3). Both function codes read the same
  image; only the configuration block accepts writes (FC6/FC16).
* 16-bit values are big-endian (the Modbus rule). 32-bit values take two registers, **high word
  first**; registers 2-3 hold the word-order test value 0x12345678.
* Fixed point: ``physical = raw x scale``. "Not available" is 0xFFFF (u16), 0x8000 (s16),
  0xFFFFFFFF (u32), 0xFF in a packed byte. Values beyond the range saturate at the largest
  value that is not the n/a code.

:data:`BLOCKS` is the table. :class:`ImageBuilder` turns a :class:`~edge.outputs.state.Snapshot`
into a complete image (a list of ints, index = address); :func:`markdown` renders the table.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable

from edge.outputs.state import ALARM_NO_PUBLISH, ALARMS, LOOP_STATES, MAX_LANES, Snapshot, finite
from hal.frame import SATURATED_FRACTION

MAP_MAGIC = 0x5452  # "TR"
MAP_VERSION = 0x0100  # 1.0
WORD_ORDER_TEST = 0x12345678
DEVICE_TYPES = {"": 0, "minimal": 1, "lane": 2, "surveillance": 3}

LANE_BASE, LANE_STRIDE = 100, 32
TRACK_HEADER, TRACK_BASE, TRACK_RECORD, TRACK_SLOTS = 992, 1000, 8, 32
CONFIG_BASE, CONFIG_SIZE = 2000, 100
CMD_ADDR, GENERATION_ADDR, CMD_STATUS_ADDR = 2090, 2091, 2092
CMD_APPLY, CMD_RESTART_COMMS, CMD_REBOOT = 0xA5A5, 0x5A5A, 0xDEAD

#: ARS408 Obj_Class enum (shared with CAN)
ARS_CLASS = {"point": 0, "car": 1, "truck": 2, "bus": 2, "pedestrian": 3, "motorcycle": 4, "bicycle": 5, "wide": 6}
#: class-count registers of a lane block, in order, and the pipeline class names they count
CLASS_COUNT_GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("pedestrian", ("pedestrian",)),
    ("bicycle", ("bicycle",)),
    ("motorcycle", ("motorcycle",)),
    ("car", ("car",)),
    ("truck_bus", ("truck", "bus")),
    ("other", ()),  # everything else
)

NA_U16, NA_S16, NA_U32, NA_U8 = 0xFFFF, 0x8000, 0xFFFFFFFF, 0xFF

# status register 16 bits
ST_RADAR_OK, ST_TRACKING, ST_CAN_UP, ST_TIME_SYNCED, ST_DEGRADED = 0, 1, 2, 3, 4
ST_CONFIG_PENDING, ST_STATS_STALE, ST_FAILSAFE, ST_WRITES_ENABLED, ST_ANY_FAULT = 7, 8, 9, 10, 15
# lane live-word bits
LV_PRESENCE, LV_QUEUE, LV_WRONG_WAY, LV_STALE, LV_FAILSAFE, LV_NO_INTERVAL = 0, 1, 2, 8, 9, 10
NTCIP_OCC_WATCHDOG_FAULT = 216
#: loop_state value the Modbus server process itself serves when no image came from the frame loop
LOOP_STATE_NO_IMAGE = len(LOOP_STATES)
#: lane direction codes (lane_id high byte, configuration lane<k>_direction)
DIR_APPROACHING, DIR_RECEDING, DIR_BOTH = 0, 1, 2


@dataclass(frozen=True)
class Reg:
    """One value: ``offset`` within its block, ``kind`` u16 | s16 | u32 | bits | u8x2."""

    name: str
    offset: int
    kind: str
    doc: str
    unit: str = ""
    scale: float = 1.0  # physical = raw * scale
    na: bool = True  # has a "not available" code
    lo: int | None = None  # writable registers: allowed raw range
    hi: int | None = None
    writable: bool = False

    @property
    def size(self) -> int:
        return 2 if self.kind == "u32" else 1


@dataclass(frozen=True)
class Block:
    name: str
    base: int
    size: int  # registers reserved for one instance
    regs: tuple[Reg, ...]
    doc: str
    repeat: int = 1
    stride: int = 0
    writable: bool = False

    def address(self, reg: Reg, instance: int = 0) -> int:
        return self.base + instance * self.stride + reg.offset

    @property
    def end(self) -> int:
        """One past the last address of all instances."""
        return self.base + (self.repeat - 1) * self.stride + self.size


def _r(name, off, kind, doc, unit="", scale=1.0, na=True, **kw) -> Reg:
    return Reg(name, off, kind, doc, unit, scale, na, **kw)


IDENT = Block("identification", 0, 16, (
    _r("magic", 0, "u16", "map magic 0x5452 ('TR')", na=False),
    _r("map_version", 1, "u16", "register map version, major << 8 | minor", na=False),
    _r("word_order_test", 2, "u32", "0x12345678: reads 0x1234, 0x5678 when the word order is high word first", na=False),
    _r("device_type", 4, "u16", "profile: 0 none yet, 1 minimal, 2 lane (1x4 SIMO), 3 surveillance (Distance2Go)", na=False),
    _r("fw_major_minor", 5, "u16", "firmware version major << 8 | minor", na=False),
    _r("fw_patch", 6, "u16", "firmware version patch", na=False),
    _r("serial_number", 7, "u32", "serial number (outputs.modbus.serial_number)", na=False),
    _r("lanes", 9, "u16", f"lanes configured N (0..{MAX_LANES})", na=False),
    _r("lane_base", 10, "u16", f"address of lane 1's statistics block ({LANE_BASE})", na=False),
    _r("lane_stride", 11, "u16", f"registers per lane block ({LANE_STRIDE})", na=False),
    _r("track_base", 12, "u16", f"address of track record 0 ({TRACK_BASE})", na=False),
    _r("track_record_size", 13, "u16", f"registers per track record ({TRACK_RECORD})", na=False),
    _r("track_slots", 14, "u16", f"track records ({TRACK_SLOTS})", na=False),
    _r("config_base", 15, "u16", f"address of the configuration block ({CONFIG_BASE})", na=False),
), "Read-only. Constant while the firmware runs, except `device_type` and `lanes` (set at start).")

STATUS = Block("status", 16, 32, (
    _r("status_bits", 0, "bits", "bit0 radar OK (frames arrive), 1 tracking running, 2 CAN up, 3 time synced "
       "(not measured: 0), 4 degraded: the ADC saturates (over 0.01 % of the samples at full scale over the last 10 s; "
       "radar-edge calibrate --headroom), 7 configuration applied that needs a restart, "
       "8 lane statistics stale, 9 fail-safe presence active, 10 configuration writes enabled, 15 any fault", na=False),
    _r("alarm", 1, "u16", "active alarm: " + ", ".join(f"{k} {v}" for k, v in ALARMS.items()), na=False),
    _r("uptime_s", 2, "u32", "seconds since the outputs started", "s", na=False),
    _r("frame_counter", 4, "u16", "sequence number of the last frame, mod 65536 (= CAN Obj_MeasCounter)", na=False),
    _r("frame_rate", 5, "u16", "frame rate (0 while in fault)", "Hz", 0.1),
    _r("temperature", 6, "s16", "CPU temperature (n/a if not readable)", "degC", 0.1),
    _r("supply_voltage", 7, "u16", "supply voltage (not measured: n/a)", "V", 0.1),
    _r("track_count", 8, "u16", "tracks in the track table now", na=False),
    _r("interval_seq", 9, "u16", "sequence number 0-255 of the last closed interval (NTCIP volumeOccupancySequence)", na=False),
    _r("interval_length_s", 10, "u16", "length of the last closed interval (n/a before the first)", "s"),
    _r("interval_end_unix", 11, "u32", "UNIX time the last interval closed (n/a before the first)", "s"),
    _r("unix_time", 13, "u32", "UNIX time of this update", "s"),
    _r("dropped_frames", 15, "u16", "frames dropped since start (saturates)", na=False),
    _r("overruns", 16, "u16", "frames over the time budget since start (saturates)", na=False),
    _r("errors", 17, "u16", "pipeline and source errors since start (saturates)", na=False),
    _r("frame_p99", 18, "u16", "99th-percentile frame processing time", "ms", 0.1),
    _r("budget", 19, "u16", "frame time budget (frame period)", "ms", 0.1),
    _r("loop_state", 20, "u16", "frame loop state: " + ", ".join(f"{i} {s}" for i, s in enumerate(LOOP_STATES))
       + f", {LOOP_STATE_NO_IMAGE} not responding (set by the Modbus server process when no image came from the "
       "frame loop for outputs.modbus.stale_image_s)", na=False),
    _r("since_last_frame", 21, "u16", "time since the last frame result (n/a before the first; keeps counting "
       "while the frame loop does not respond)", "s", 0.1),
    _r("update_counter", 22, "u16", "incremented on every image update (results and heartbeats), mod 65536", na=False),
), "Read-only. Updated with every result and every heartbeat (at least every 0.5 s).")

LANE = Block("lane", LANE_BASE, LANE_STRIDE, (
    _r("lane_id", 0, "u16", "lane number 1..N (low byte); high byte direction of travel of the lane in use "
       "(configured, or learned once learned): 0 approaching, 1 receding, 2 both, 0xFF unknown (lanes not "
       "learned yet)", na=False),
    _r("volume", 1, "u16", "vehicles in the last closed interval"),
    _r("occupancy", 2, "u16", "occupancy in the interval (0-10000)", "%", 0.01),
    _r("ntcip_occupancy", 3, "u16", "NTCIP 1202 style occupancy: 0-200 in 0.5 % steps, or fault code "
       f"{NTCIP_OCC_WATCHDOG_FAULT} (watchdog fault) when the statistics are stale", na=False),
    _r("ntcip_volume", 4, "u16", "NTCIP style volume: 0-254, 255 = overflow", na=False),
    _r("mean_speed", 5, "u16", "mean speed in the interval (n/a if volume 0)", "km/h", 0.1),
    _r("speed_p85", 6, "u16", "85th-percentile speed", "km/h", 0.1),
    _r("headway", 7, "u16", "mean headway, front to front", "s", 0.01),
    _r("gap", 8, "u16", "mean gap, back to front (n/a when it cannot be measured)", "s", 0.01),
    _r("mean_length", 9, "u16", "mean measured vehicle length in the interval (n/a when none was measured)", "m", 0.1),
    _r("live", 10, "bits", "live, every frame: bit0 presence (call), 1 queue (not detected yet: 0), 2 wrong-way "
       "vehicle now, 8 statistics stale, 9 fail-safe presence, 10 no interval closed yet", na=False),
    _r("cumulative_volume", 11, "u32", "vehicles since start", na=False),
    *[_r(f"count_{g}", 13 + i, "u16", f"{g.replace('_', '/')} count in the interval") for i, (g, _) in enumerate(CLASS_COUNT_GROUPS)],
    _r("wrong_way_count", 19, "u16", "wrong-way events since start (mod 65536)", na=False),
    _r("interval_seq", 20, "u16", "sequence number 0-255 of the interval these statistics belong to"),
    _r("interval_length_s", 21, "u16", "length of that interval", "s"),
    _r("interval_end_unix", 22, "u32", "UNIX time that interval closed", "s"),
), "Read-only. Lane k (1..8) at 100 + 32*(k-1); offsets 24-31 reserved (0). Statistics change when an "
   "interval closes; `live` changes every frame. Lanes above N read n/a.",
   repeat=MAX_LANES, stride=LANE_STRIDE)

TRACK_HDR = Block("track_header", TRACK_HEADER, 8, (
    _r("frame_counter", 0, "u16", "frame counter of the table (low byte repeated in every record)", na=False),
    _r("valid_records", 1, "u16", "records in use (packed from record 0, nearest first)", na=False),
    _r("frame_time_ms", 2, "u32", "loop time of that frame since the outputs started (wraps after 49.7 days)", "ms", na=False),
), "Read-only. Offsets 4-7 reserved. One 125-register read from 992 returns the header and 14 records.")

TRACK = Block("track", TRACK_BASE, TRACK_RECORD, (
    _r("track_id", 0, "u16", "track id (0xFFFF = empty slot); CAN Obj_ID is its low byte"),
    _r("class_lane", 1, "u8x2", "low byte class (ARS408 enum: 0 point/unknown, 1 car, 2 truck/bus, 3 pedestrian, "
       "4 motorcycle, 5 bicycle), high byte lane 1..N (0xFF none)"),
    _r("x", 2, "s16", "lateral position, right +", "m", 0.1),
    _r("y", 3, "s16", "position along the boresight (distance)", "m", 0.1),
    _r("vx", 4, "s16", "lateral velocity, right +", "m/s", 0.1),
    _r("vy", 5, "s16", "velocity along the boresight, receding +", "m/s", 0.1),
    _r("speed", 6, "u16", "ground speed", "km/h", 0.1),
    _r("prob_tear", 7, "u8x2", "low byte class probability % (0xFF n/a); high byte = low byte of the header's "
       "frame counter: a record whose high byte differs from it was read from another frame (tearing)"),
), f"Read-only. Record k (0..{TRACK_SLOTS - 1}) at {TRACK_BASE} + {TRACK_RECORD}*k.",
   repeat=TRACK_SLOTS, stride=TRACK_RECORD)


def _cfg(name, off, doc, lo, hi, unit="", scale=1.0, kind="u16") -> Reg:
    return Reg(name, off, kind, doc, unit, scale, na=False, lo=lo, hi=hi, writable=True)


_LANE_GEOM = []
for _k in range(MAX_LANES):
    _o = 10 + 4 * _k
    _LANE_GEOM += [
        _cfg(f"lane{_k + 1}_x_min", _o, f"lane {_k + 1} left edge across the road (road frame of "
             "traffic.lane_centers_m, right +)", -1000, 1000, "m", 0.1, "s16"),
        _cfg(f"lane{_k + 1}_x_max", _o + 1, f"lane {_k + 1} right edge (> left edge)", -1000, 1000, "m", 0.1, "s16"),
        _cfg(f"lane{_k + 1}_direction", _o + 2, f"lane {_k + 1} direction of travel: 0 approaching, 1 receding", 0, 1),
        _cfg(f"lane{_k + 1}_enabled", _o + 3, f"lane {_k + 1} in use 0/1", 0, 1),
    ]

CONFIG = Block("configuration", CONFIG_BASE, CONFIG_SIZE, (
    _cfg("unit_id", 0, "Modbus RTU unit id (applied at once, after the reply)", 1, 247),
    _cfg("baud_code", 1, "RTU baud: 0 9600, 1 19200, 2 38400, 3 57600, 4 115200 (restart)", 0, 4),
    _cfg("parity_code", 2, "RTU parity: 0 none, 1 even, 2 odd (restart)", 0, 2),
    _cfg("stop_bits", 3, "RTU stop bits 1 or 2 (restart)", 1, 2),
    _cfg("interval_s", 4, "statistics interval length, traffic.interval_s (restart)", 1, 0xFFFF, "s"),
    _cfg("lanes", 5, "lanes N the outputs serve (restart)", 0, MAX_LANES),
    _cfg("can_enable", 6, "CAN output 0/1 (applied at once)", 0, 1),
    _cfg("can_bitrate_code", 7, "CAN bitrate: 0 125k, 1 250k, 2 500k, 3 1M (restart)", 0, 3),
    _cfg("can_sensor_id", 8, "ARS408 sensor id 0-7, id offset 0x10 x id (applied at once)", 0, 7),
    _cfg("can_output_mask", 9, "CAN messages: bit0 0x60B objects, 1 0x60C quality, 2 0x60D extended, 3 lane "
         "statistics, 4 presence (applied at once)", 0, 31),
    *_LANE_GEOM,
    _cfg("command", 90, f"write 0x{CMD_APPLY:04X} to validate and apply the staged values, 0x{CMD_RESTART_COMMS:04X} "
         f"to discard them; reads 0. 0x{CMD_REBOOT:04X} (reboot) is refused (exception 03)", 0, 0xFFFF),
    Reg("generation", 91, "u16", "configuration generation: +1 on every successful apply (read-only)", na=False),
    Reg("command_status", 92, "u16", "last command: 0 none, 1 applied, 2 rejected (inconsistent values), 3 discarded", na=False),
), "Holding registers showing the running configuration. Writable when outputs.modbus.config_writes is true "
   "(otherwise FC6/FC16 are not served: exception 01 at every address). Writes are validated per register "
   "(exception 02 for a register that is not writable, 03 for a value out of range) and staged: reads return "
   "the staged values; nothing takes effect before the command register is written. Registers 2042-2089 and "
   "2093-2099 are reserved. Values marked (restart) are kept and flagged (status bit 7) but take effect only "
   "after a restart; persisting them is the job of the configuration file. Lane geometry (2010-2041) shows the "
   "configured lanes in use (traffic.lane_mode = configured); applying it replaces them in the traffic layer at "
   "the next frame. The applied geometry must keep the lanes 1..N in use (N = register 9), and each lane's "
   "edges ordered; otherwise the command gets exception 03. With learned lanes, or without a traffic layer, the "
   "geometry reads 0 (not in use: the lane blocks' lane_id shows the learned directions) and is not writable "
   "(exception 02).",
   writable=True)

BLOCKS: tuple[Block, ...] = (IDENT, STATUS, LANE, TRACK_HDR, TRACK, CONFIG)
#: offsets in the configuration block of the lane geometry registers
GEOMETRY_OFFSETS = frozenset(r.offset for r in _LANE_GEOM)
_LANE_OFF = {r.name: r.offset for r in LANE.regs}
_LANE_IDX = {r.name: i for i, r in enumerate(LANE.regs)}
IMAGE_SIZE = CONFIG_BASE + CONFIG_SIZE
#: address ranges (start, end exclusive) the servers answer; everything else is exception 02
READ_RANGES: tuple[tuple[int, int], ...] = ((0, LANE_BASE + MAX_LANES * LANE_STRIDE), (TRACK_HEADER, TRACK_BASE + TRACK_SLOTS * TRACK_RECORD), (CONFIG_BASE, CONFIG_BASE + CONFIG_SIZE))


# --- encoding ---------------------------------------------------------------------------------
_LIMITS = {"u16": (0, 0xFFFF), "s16": (-0x8000, 0x7FFF), "u32": (0, 0xFFFFFFFF), "bits": (0, 0xFFFF)}


def encode(reg: Reg, value: Any) -> list[int]:
    """Physical value -> register words (None/NaN = not available; saturating)."""
    if reg.kind == "u8x2":
        lo, hi = value if value is not None else (None, None)
        return [(_byte(hi) << 8) | _byte(lo)]
    v = finite(value) if value is not None and not isinstance(value, int) else value
    if v is None:
        if not reg.na:
            raise ValueError(f"register {reg.name} has no 'not available' value")
        raw = {"u16": NA_U16, "s16": NA_S16, "u32": NA_U32}[reg.kind]
    else:
        lo, hi = _LIMITS[reg.kind]
        if reg.na:  # keep the n/a code out of the value range
            if reg.kind == "s16":
                lo += 1
            else:
                hi -= 1
        raw = int(round(v / reg.scale)) if reg.scale != 1.0 else int(round(v))
        raw = min(max(raw, lo), hi)
    if reg.kind == "u32":
        return [(raw >> 16) & 0xFFFF, raw & 0xFFFF]
    return [raw & 0xFFFF]


def decode(reg: Reg, words: list[int]) -> Any:
    """Register words -> physical value (None = not available); the inverse of :func:`encode`."""
    if reg.kind == "u8x2":
        lo, hi = words[0] & 0xFF, words[0] >> 8
        return (None if lo == NA_U8 else lo, None if hi == NA_U8 else hi)
    if reg.kind == "u32":
        raw = (words[0] << 16) | words[1]
        if reg.na and raw == NA_U32:
            return None
    else:
        raw = words[0]
        if reg.kind == "s16":
            if reg.na and raw == NA_S16:
                return None
            raw = raw - 0x10000 if raw & 0x8000 else raw
        elif reg.na and raw == NA_U16 and reg.kind == "u16":
            return None
    return raw * reg.scale if reg.scale != 1.0 else raw


def _byte(v: Any) -> int:
    f = finite(v)
    return NA_U8 if f is None else min(max(int(round(f)), 0), 0xFE)


def decode_block(block: Block, words: list[int]) -> dict[str, Any]:
    """Decode one block instance from ``words`` (the instance's registers, starting at its base)."""
    return {r.name: decode(r, words[r.offset: r.offset + r.size]) for r in block.regs}


def _write(image: list[int], block: Block, instance: int, values: dict[str, Any]) -> None:
    base = block.base + instance * block.stride
    for reg in block.regs:
        if reg.name in values:
            w = encode(reg, values[reg.name])
            image[base + reg.offset: base + reg.offset + len(w)] = w


def _na_block(block: Block) -> list[int]:
    words = [0] * block.size
    for reg in block.regs:
        w = encode(reg, None) if reg.na else [0] * reg.size
        words[reg.offset: reg.offset + reg.size] = w
    return words


# --- image builder ----------------------------------------------------------------------------
def _sat16(n: int) -> int:
    return min(max(int(n), 0), 0xFFFF)


def _cpu_temperature_c() -> float | None:
    try:
        with open("/sys/class/thermal/thermal_zone0/temp", encoding="ascii") as f:
            return int(f.read().strip()) / 1000.0
    except (OSError, ValueError):
        return None


def firmware_version() -> tuple[int, int, int]:
    try:
        from importlib.metadata import PackageNotFoundError, version

        text = version("radar-edge")
    except (ImportError, PackageNotFoundError):
        text = "0.1.0"
    parts = [int(p) if p.isdigit() else 0 for p in text.split(".")[:3]]
    return tuple((parts + [0, 0, 0])[:3])  # type: ignore[return-value]


@dataclass
class Links:
    """Status bits owned by other outputs or by the configuration (shared, single-word writes)."""

    can_up: bool = False
    config_pending_restart: bool = False
    writes_enabled: bool = False


class ImageBuilder:
    """Snapshot -> complete register image (list of ints, index = address).

    Built by the single writer (the frame loop's ``publish``) and swapped in whole, so a Modbus
    read never mixes two frames. The lane statistics part is cached until an interval closes.
    """

    def __init__(self, n_lanes: int, *, serial_number: int = 0, config_words: list[int] | None = None,
                 links: Links | None = None, wall_clock: Callable[[], float] = time.time,
                 temperature: Callable[[], float | None] = _cpu_temperature_c) -> None:
        self.n_lanes = n_lanes
        self.links = links or Links()
        self.wall = wall_clock
        self.temperature = temperature
        self._t0_ns: int | None = None
        self._updates = 0
        base = [0] * IMAGE_SIZE
        major, minor, patch = firmware_version()
        _write(base, IDENT, 0, {
            "magic": MAP_MAGIC, "map_version": MAP_VERSION, "word_order_test": WORD_ORDER_TEST, "device_type": 0,
            "fw_major_minor": (major << 8) | minor, "fw_patch": patch, "serial_number": serial_number,
            "lanes": n_lanes, "lane_base": LANE_BASE, "lane_stride": LANE_STRIDE, "track_base": TRACK_BASE,
            "track_record_size": TRACK_RECORD, "track_slots": TRACK_SLOTS, "config_base": CONFIG_BASE,
        })
        na_lane = _na_block(LANE)
        for k in range(MAX_LANES):
            a = LANE_BASE + k * LANE_STRIDE
            base[a: a + LANE_STRIDE] = na_lane
        self._empty_track = _na_block(TRACK)
        for k in range(TRACK_SLOTS):
            a = TRACK_BASE + k * TRACK_RECORD
            base[a: a + TRACK_RECORD] = self._empty_track
        _write(base, STATUS, 0, {r.name: None for r in STATUS.regs if r.na})  # n/a until the first update
        if config_words is not None:
            base[CONFIG_BASE: CONFIG_BASE + CONFIG_SIZE] = config_words
        self._base = base
        self._lane_cache: list[tuple[Any, bool, list[int]] | None] = [None] * MAX_LANES

    def initial_image(self) -> list[int]:
        """What the servers show before the first update: identification, everything else n/a or 0."""
        return list(self._base)

    def build(self, snap: Snapshot, config_words: list[int] | None = None) -> list[int]:
        if self._t0_ns is None:
            self._t0_ns = snap.t_ns
        self._updates += 1
        img = list(self._base)
        if config_words is not None:
            img[CONFIG_BASE: CONFIG_BASE + CONFIG_SIZE] = config_words
        now_unix = self.wall()
        h = snap.health
        img[IDENT.base + 4] = DEVICE_TYPES.get(snap.profile, 0)
        any_stale = any(snap.stats_stale) if snap.n_lanes else False
        bits = 0
        if not snap.fault:
            bits |= 1 << ST_RADAR_OK
            if snap.frame_seq >= 0:
                bits |= 1 << ST_TRACKING
        bits |= self.links.can_up << ST_CAN_UP
        bits |= self.links.config_pending_restart << ST_CONFIG_PENDING
        bits |= any_stale << ST_STATS_STALE
        bits |= snap.failsafe_presence << ST_FAILSAFE
        bits |= self.links.writes_enabled << ST_WRITES_ENABLED
        bits |= snap.fault << ST_ANY_FAULT
        clipped = h.adc_clipped_fraction
        bits |= (not snap.fault and clipped is not None and clipped > SATURATED_FRACTION) << ST_DEGRADED
        since = (snap.t_ns - snap.frame_t_ns) / 1e9 if snap.frame_seq >= 0 and snap.frame_t_ns else None
        last_ls = next((ls for ls in snap.lane_stats if ls is not None), None)
        end_unix = None if not snap.interval_end_ns else now_unix - (snap.t_ns - snap.interval_end_ns) / 1e9
        _write(img, STATUS, 0, {
            "status_bits": bits, "alarm": snap.alarm, "uptime_s": (snap.t_ns - self._t0_ns) // 1_000_000_000,
            "frame_counter": max(snap.frame_seq, 0) & 0xFFFF, "frame_rate": snap.frame_rate_hz,
            "temperature": self.temperature(), "supply_voltage": None, "track_count": len(snap.tracks[:TRACK_SLOTS]),
            "interval_seq": snap.interval_seq, "interval_length_s": None if last_ls is None else last_ls.interval_s,
            "interval_end_unix": end_unix, "unix_time": now_unix,
            "dropped_frames": _sat16(h.dropped_frames), "overruns": _sat16(h.overruns), "errors": _sat16(h.errors),
            "frame_p99": h.frame_p99_ms, "budget": h.budget_ms,
            "loop_state": LOOP_STATES.index(h.state) if h.state in LOOP_STATES else 0xFFFF,
            "since_last_frame": since, "update_counter": self._updates & 0xFFFF,
        })
        for k in range(snap.n_lanes):
            self._lane(img, k, snap, now_unix)
        self._tracks(img, snap)
        return img

    def _lane(self, img: list[int], k: int, snap: Snapshot, now_unix: float) -> None:
        ls = snap.lane_stats[k]
        stale = snap.stats_stale[k]
        direction = lane_direction_code(snap.lane_directions[k] if k < len(snap.lane_directions) else None)
        cached = self._lane_cache[k]
        a = LANE_BASE + k * LANE_STRIDE
        if cached is None or cached[0] is not ls or cached[1] != (stale, direction):
            vals: dict[str, Any] = {"lane_id": (k + 1) | (direction << 8), "cumulative_volume": snap.cumulative_volume[k],
                                    "wrong_way_count": snap.wrong_way_count[k] & 0xFFFF}
            if ls is None:
                vals.update({r.name: None for r in LANE.regs if r.na})
                vals.update(ntcip_occupancy=NTCIP_OCC_WATCHDOG_FAULT, ntcip_volume=0)
            else:
                occ = finite(ls.occupancy_pct)
                counts = dict(ls.class_counts)
                grouped = {f"count_{g}": sum(counts.pop(n, 0) for n in names) for g, names in CLASS_COUNT_GROUPS if names}
                grouped["count_other"] = sum(counts.values())  # what no named group took
                vals.update(grouped)
                vals.update(
                    volume=ls.volume, occupancy=occ, mean_speed=None if ls.volume == 0 else ls.mean_speed_kmh,
                    speed_p85=ls.speed_p85_kmh, headway=ls.headway_s, gap=ls.gap_s, mean_length=ls.mean_length_m,
                    ntcip_occupancy=NTCIP_OCC_WATCHDOG_FAULT if (stale or occ is None) else min(200, int(round(occ * 2))),
                    ntcip_volume=min(int(ls.volume), 255), interval_seq=ls.sequence & 0xFF,
                    interval_length_s=ls.interval_s,
                    interval_end_unix=now_unix - (snap.t_ns - snap.interval_end_ns) / 1e9 if snap.interval_end_ns else None,
                )
            words = [0] * LANE_STRIDE
            for reg in LANE.regs:
                if reg.name in vals:
                    words[reg.offset: reg.offset + reg.size] = encode(reg, vals[reg.name])
            self._lane_cache[k] = (ls, (stale, direction), words)
        else:
            words = cached[2]
        img[a: a + LANE_STRIDE] = words
        live = (snap.presence[k] << LV_PRESENCE) | (snap.wrong_way[k] << LV_WRONG_WAY) | (stale << LV_STALE)
        live |= (snap.failsafe_presence << LV_FAILSAFE) | ((ls is None) << LV_NO_INTERVAL)
        img[a + _LANE_OFF["live"]] = live
        o = a + _LANE_OFF["cumulative_volume"]
        img[o: o + 2] = encode(LANE.regs[_LANE_IDX["cumulative_volume"]], snap.cumulative_volume[k])
        img[a + _LANE_OFF["wrong_way_count"]] = snap.wrong_way_count[k] & 0xFFFF

    def _tracks(self, img: list[int], snap: Snapshot) -> None:
        fc = max(snap.frame_seq, 0) & 0xFFFF
        tracks = sorted(snap.tracks, key=lambda t: t.range_m)[:TRACK_SLOTS]
        t_ms = ((snap.frame_t_ns - self._t0_ns) // 1_000_000 if snap.frame_t_ns >= self._t0_ns else 0) & 0xFFFFFFFF
        _write(img, TRACK_HDR, 0, {"frame_counter": fc, "valid_records": len(tracks), "frame_time_ms": t_ms})
        tear = fc & 0xFF
        for k in range(TRACK_SLOTS):
            a = TRACK_BASE + k * TRACK_RECORD
            if k >= len(tracks):
                rec = list(self._empty_track)
                rec[7] = (tear << 8) | NA_U8
                img[a: a + TRACK_RECORD] = rec
                continue
            t = tracks[k]
            lane = None if t.lane is None or not 0 <= t.lane < MAX_LANES else t.lane + 1
            prob = None if t.class_probability is None else 100.0 * t.class_probability
            vals = (
                encode(TRACK.regs[0], t.track_id) + encode(TRACK.regs[1], (ars_class(t.cls), lane))
                + encode(TRACK.regs[2], t.x_m) + encode(TRACK.regs[3], t.y_m) + encode(TRACK.regs[4], t.vx_mps)
                + encode(TRACK.regs[5], t.vy_mps) + encode(TRACK.regs[6], t.speed_mps * 3.6)
            )
            vals.append((tear << 8) | _byte(prob))
            img[a: a + TRACK_RECORD] = vals


def ars_class(cls: str | None) -> int:
    return ARS_CLASS.get(cls or "point", 0)


# --- documentation ----------------------------------------------------------------------------
def _type_text(reg: Reg) -> str:
    return {"u16": "u16", "s16": "s16", "u32": "u32 (hi, lo)", "bits": "bits", "u8x2": "u8 | u8"}[reg.kind]


def _scale_text(reg: Reg) -> str:
    if reg.kind in ("bits", "u8x2"):
        return ""
    if reg.scale == 1.0:
        return reg.unit
    return f"x {reg.scale:g} {reg.unit}".rstrip()


def _na_text(reg: Reg) -> str:
    if reg.kind == "u8x2":
        return "0xFF per byte"
    if not reg.na:
        return ""
    return {"u16": "0xFFFF", "s16": "0x8000", "u32": "0xFFFFFFFF"}[reg.kind]


def markdown() -> str:
    """The register map as Markdown (what ``radar-edge registers`` prints)."""
    out = [
        "# radar-edge Modbus register map",
        "",
        f"Map version {MAP_VERSION >> 8}.{MAP_VERSION & 0xFF}. The same image is served over Modbus RTU (RS-485) "
        "and Modbus TCP and updated once per frame, whole.",
        "",
        "* **Address** is the 0-based PDU address on the wire. **Input** (FC4) and **Holding** (FC3) are the "
        "register numbers a PLC or SCADA tag uses (30001 + address, 40001 + address). **mbpoll -r** is the "
        "1-based reference mbpoll takes (address + 1): `-t 3` reads it with FC4, `-t 4` with FC3; e.g. the magic "
        "(address 0, 30001) is `mbpoll -m tcp -p 5020 -t 3 -r 1 -1 127.0.0.1`, the interval length (address 2004, "
        "42005) `mbpoll -m tcp -p 5020 -t 4 -r 2005 -1 127.0.0.1`. With `-0`, mbpoll takes the address itself.",
        "* Function codes served: FC3 and FC4 (the same registers), FC6 and FC16 (the configuration block, only "
        "with `outputs.modbus.config_writes`). Exception responses follow the Modbus Application Protocol v1.1b3 "
        "(function code + 0x80): 01 for any other function code (FC1, FC5, FC8, FC17, FC43 device identification, "
        "...), for FC6/FC16 while writes are off, and for a request too short to hold its fields; 02 for addresses "
        "outside the blocks or not writable; 03 for a quantity outside 1-125 (FC3/FC4) or 1-123 with a matching "
        "byte count (FC16), and for values out of range. Over RTU, function codes pymodbus cannot frame get no reply.",
        "* 16-bit values are big-endian; **32-bit values are two registers, high word first** "
        f"(registers 2-3 read 0x{WORD_ORDER_TEST >> 16:04X}, 0x{WORD_ORDER_TEST & 0xFFFF:04X}; mbpoll needs `-B`).",
        "* Fixed point: physical value = register x scale. **n/a** = not available: 0xFFFF (u16), 0x8000 (s16), "
        "0xFFFFFFFF (u32), 0xFF (byte). Values out of range saturate.",
        "* RTU answers only its unit id (`outputs.modbus.unit_id`, default 1); other ids get no reply. TCP "
        "answers every unit id.",
        "* Fail-safe: when frames stop for `outputs.failsafe.stale_after_s` (1 s) or the loop reports a fault, "
        "status bit 15 and the alarm register show it, the track table empties, lane presence goes to the "
        "fail-safe state (default all on, bit 9 of `live`) and lane statistics are flagged stale "
        f"(bit 8 of `live`, NTCIP occupancy {NTCIP_OCC_WATCHDOG_FAULT}).",
        "* When the frame loop sends no image for `outputs.modbus.stale_image_s` (1 s: frozen, hung or crashed), the "
        "Modbus server process shows the same fault itself (alarm 4, loop state "
        f"{LOOP_STATE_NO_IMAGE}), and clears it with the next image.",
        "* Readable ranges: " + ", ".join(f"{a}-{b - 1}" for a, b in READ_RANGES) + ".",
        "",
    ]
    for block in BLOCKS:
        last = block.end - 1
        out.append(f"## {block.name.replace('_', ' ').capitalize()} ({block.base}-{last})")
        out.append("")
        out.append(block.doc)
        out.append("")
        if block.repeat > 1:
            out.append(f"Instance k = 0..{block.repeat - 1} at {block.base} + {block.stride}*k; addresses below are "
                       "instance 0 (lane 1 / record 0).")
            out.append("")
        out.append("| Offset | Address | mbpoll -r | Input | Holding | Name | Type | Scale / unit | n/a | Description |")
        out.append("|---:|---:|---:|---:|---:|---|---|---|---|---|")
        for reg in block.regs:
            a = block.address(reg)
            addr = f"{a}-{a + 1}" if reg.size == 2 else f"{a}"
            inp = f"{30001 + a}"
            rng = ""
            if reg.writable:
                rng = f" Range {reg.lo * reg.scale:g}..{reg.hi * reg.scale:g} {reg.unit}".rstrip() + "."
            doc, typ = reg.doc.replace("|", "\\|"), _type_text(reg).replace("|", "\\|")
            out.append(f"| +{reg.offset} | {addr} | {a + 1} | {inp} | {40001 + a} | {reg.name} | {typ} | "
                       f"{_scale_text(reg)} | {_na_text(reg)} | {doc}.{rng} |")
        out.append("")
    return "\n".join(out)


def iter_registers() -> Iterable[tuple[Block, int, Reg, int]]:
    """Every (block, instance, reg, address) of the map."""
    for block in BLOCKS:
        for i in range(block.repeat):
            for reg in block.regs:
                yield block, i, reg, block.address(reg, i)


def default_config_words(values: dict[str, int]) -> list[int]:
    """Encode configuration values (register name -> physical value) as the 100-word block."""
    words = [0] * CONFIG_SIZE
    for reg in CONFIG.regs:
        if reg.name in values:
            w = encode(reg, values[reg.name])
            words[reg.offset: reg.offset + reg.size] = w
    return words


def config_values(words: list[int]) -> dict[str, Any]:
    return {reg.name: decode(reg, words[reg.offset: reg.offset + reg.size]) for reg in CONFIG.regs}



# --- lanes in use <-> lane geometry registers ---------------------------------------------------
def lane_direction_code(direction: int | None) -> int:
    """A traffic-layer lane direction (+1 away from the radar, -1 toward it, 0 both) -> register code."""
    if direction is None:
        return NA_U8
    return DIR_RECEDING if direction > 0 else DIR_APPROACHING if direction < 0 else DIR_BOTH


def lane_geometry_values(lanes: Iterable[Any]) -> dict[str, Any]:
    """Configuration register values (name -> physical value) of the lanes in use (objects with
    ``center_m``, ``width_m``, ``direction``); lanes beyond the first MAX_LANES are not shown."""
    values: dict[str, Any] = {}
    for k, ln in enumerate(list(lanes)[:MAX_LANES]):
        half = 0.5 * float(ln.width_m)
        values.update({f"lane{k + 1}_x_min": float(ln.center_m) - half, f"lane{k + 1}_x_max": float(ln.center_m) + half,
                       f"lane{k + 1}_direction": lane_direction_code(ln.direction), f"lane{k + 1}_enabled": 1})
    return values


def lane_geometry(values: dict[str, Any]) -> list[tuple[float, float, int]]:
    """``(x_min_m, x_max_m, direction +1/-1)`` of the enabled lanes of decoded configuration values, in order."""
    out = []
    for k in range(1, MAX_LANES + 1):
        if values.get(f"lane{k}_enabled"):
            d = 1 if values[f"lane{k}_direction"] == DIR_RECEDING else -1
            out.append((float(values[f"lane{k}_x_min"]), float(values[f"lane{k}_x_max"]), d))
    return out


# --- the Modbus server's own view of a silent frame loop ----------------------------------------
def no_image_fault(image: Any, silent_s: float, presence: str = "on") -> list[int]:
    """``image`` as the server process serves it when the frame loop sent nothing for ``silent_s``: the
    fault the frame loop's own watchdog would show (status bit 15 and stale bits, alarm 4, loop state
    :data:`LOOP_STATE_NO_IMAGE`, frame rate 0, track table empty, lanes stale with NTCIP fault code and
    fail-safe presence per ``presence`` on/off/hold) and ``since_last_frame`` counted on."""
    img = list(image)
    st = STATUS.base
    off = {r.name: r.offset for r in STATUS.regs}
    bits = img[st] & ~((1 << ST_RADAR_OK) | (1 << ST_TRACKING))
    bits |= (1 << ST_ANY_FAULT) | (1 << ST_STATS_STALE)
    if presence != "hold":
        bits |= 1 << ST_FAILSAFE
    img[st] = bits
    img[st + off["alarm"]] = ALARM_NO_PUBLISH
    img[st + off["frame_rate"]] = 0
    img[st + off["track_count"]] = 0
    img[st + off["loop_state"]] = LOOP_STATE_NO_IMAGE
    since_reg = STATUS.regs[_STATUS_IDX["since_last_frame"]]
    since = decode(since_reg, [img[st + off["since_last_frame"]]])
    if since is not None:
        img[st + off["since_last_frame"]] = encode(since_reg, since + silent_s)[0]
    n = min(img[IDENT.base + 9], MAX_LANES)
    for k in range(n):
        a = LANE_BASE + k * LANE_STRIDE
        live = img[a + _LANE_OFF["live"]] | (1 << LV_STALE)
        if presence == "on":
            live |= 1 << LV_PRESENCE
        elif presence == "off":
            live &= ~(1 << LV_PRESENCE)
        if presence != "hold":
            live |= 1 << LV_FAILSAFE
        img[a + _LANE_OFF["live"]] = live
        img[a + _LANE_OFF["ntcip_occupancy"]] = NTCIP_OCC_WATCHDOG_FAULT
    img[TRACK_HEADER + 1] = 0  # valid_records
    empty = _na_block(TRACK)
    tear = img[TRACK_HEADER] & 0xFF
    for k in range(TRACK_SLOTS):
        a = TRACK_BASE + k * TRACK_RECORD
        img[a: a + TRACK_RECORD] = empty
        img[a + 7] = (tear << 8) | NA_U8
    return img


_STATUS_IDX = {r.name: i for i, r in enumerate(STATUS.regs)}
