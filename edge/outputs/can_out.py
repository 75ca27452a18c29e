"""CAN output: the ARS408 object list plus lane messages, encoded with cantools, sent with python-can.

:class:`CanEncoder` is pure: ``frames(snapshot, now_ns) -> list[can.Message]`` (header first, a
cycle is never split; objects nearest first and truncated to the rate limit). :class:`CanSink`
owns the bus and a sender thread: ``publish`` only queues the snapshot, so the frame loop never
waits on CAN. Bus-off, ENOBUFS, send errors and a missing interface are counted faults; the sink
retries opening the bus every ``reconnect_s``.

Rate limit: a token bucket of ``0.9 x max_bus_load x bitrate / 135`` frames per second (135 bits is
an 8-byte standard frame with worst-case bit stuffing) holding at most 0.1 s of it, so the load over
any 1 s window stays below ``max_bus_load``. State and
presence go first, then lane statistics, then the object list, which is truncated to what fits.
"""

from __future__ import annotations

import collections
import errno
import logging
import math
import threading
import time
from typing import Any, Callable

import can

from edge.outputs.can_db import (BY_NAME, INTERFACE_VERSION, ORIENTATION_RMS_BOUNDS_DEG, RMS_INVALID, build_database,
                                 prob_of_exist_code, rms_code)
from edge.outputs.config import CanConfig, FailsafeConfig
from edge.outputs.registers import CLASS_COUNT_GROUPS, Links, ars_class, firmware_version
from edge.outputs.state import ALARM_NONE, ALARM_PIPELINE, ALARM_STOPPED, OutputState, Snapshot
from edge.types import FrameResult, LoopHealth, TrackState

log = logging.getLogger(__name__)

FRAME_BITS_WORST = 135  # 8-byte standard frame incl. worst-case stuffing, ACK, EOF, intermission
BUCKET_S = 0.1  # burst allowance
RATE_MARGIN = 0.9  # sustained rate, so that rate + burst stays within the limit over any 1 s window

MASK_OBJECTS, MASK_QUALITY, MASK_EXTENDED, MASK_LANE_STATS, MASK_PRESENCE = 1, 2, 4, 8, 16


def _clamp_phys(sig, value: Any) -> float:
    """Physical value inside the signal's raw range; None/NaN = n/a (all-ones raw, or raw 0 of a ``na_zero``
    signal) or the raw minimum. A value never encodes to the n/a raw value."""
    v = None if value is None else float(value)  # numpy scalars too
    if v is None or not math.isfinite(v):
        return sig.phys(sig.raw_max()) if sig.na else sig.phys(0)
    raw = round((v - sig.offset) / sig.scale)
    return sig.phys(min(max(raw, 1 if sig.na_zero else 0), sig.raw_max() - (1 if sig.na else 0)))


_SPECS = {m.name: {s.name: s for s in m.signals} for m in BY_NAME.values()}


def dyn_prop(t: TrackState) -> int:
    """ARS408 dynamic property from the track's velocity (boresight receding +); 4 unknown when it is n/a."""
    if not (math.isfinite(t.vx_mps) and math.isfinite(t.vy_mps)):
        return 4  # unknown: a speed not measured (the surveillance profile's alias not yet certain)
    if math.hypot(t.vx_mps, t.vy_mps) < 0.5:
        return 1  # stationary
    if abs(t.vx_mps) > abs(t.vy_mps):
        return 6  # crossing moving
    return 2 if t.vy_mps < 0 else 0  # oncoming / moving


def heading_deg(t: TrackState) -> float | None:
    """Heading of the velocity in the ARS408 frame (0 = receding along the boresight, left +); None when the
    track is slower than 0.5 m/s."""
    if not math.hypot(t.vx_mps, t.vy_mps) > 0.5:  # NaN (speed n/a) too
        return None
    return math.degrees(math.atan2(-t.vx_mps, t.vy_mps))


def orientation_rms_code(t: TrackState) -> int:
    """0x60C Obj_Orientation_rms: a bound on the heading's sd from the velocity's sds, (|vy| sd_vx + |vx| sd_vy)
    / |v|^2 (first order, whatever the correlation of vx and vy); 31 without a heading or its sds."""
    if heading_deg(t) is None or t.vx_sd_mps is None or t.vy_sd_mps is None:
        return RMS_INVALID
    sd_rad = (abs(t.vy_mps) * t.vx_sd_mps + abs(t.vx_mps) * t.vy_sd_mps) / (t.vx_mps ** 2 + t.vy_mps ** 2)
    return rms_code(math.degrees(sd_rad), ORIENTATION_RMS_BOUNDS_DEG)


class CanEncoder:
    """Snapshot -> CAN frames of one cycle, within the rate limit (pure apart from the token bucket)."""

    def __init__(self, cfg: CanConfig, *, wall_clock: Callable[[], float] = time.time) -> None:
        self.cfg = cfg
        self.wall = wall_clock
        self.sensor_id = cfg.sensor_id
        self.mask = (MASK_OBJECTS | (MASK_QUALITY if cfg.send_quality else 0) | (MASK_EXTENDED if cfg.send_extended else 0)
                     | (MASK_LANE_STATS if cfg.send_lane_stats else 0) | (MASK_PRESENCE if cfg.send_presence else 0))
        self.rate_fps = RATE_MARGIN * cfg.max_bus_load * cfg.bitrate / FRAME_BITS_WORST
        self.capacity = self.rate_fps * BUCKET_S
        self._tokens = self.capacity
        self._t_ns: int | None = None
        self._last_state_ns: int | None = None
        self._last_alarm: int | None = None
        self.counters = collections.Counter()
        self._set_db(self.sensor_id)

    def _set_db(self, sensor_id: int) -> None:
        self.db = build_database(sensor_id)
        self._m = {m.name: m for m in self.db.messages}
        self.sensor_id = sensor_id

    def set_runtime(self, sensor_id: int, mask: int) -> None:
        if sensor_id != self.sensor_id:
            self._set_db(sensor_id)
        self.mask = mask

    def _encode(self, name: str, values: dict[str, Any]) -> can.Message:
        spec = _SPECS[name]
        phys = {k: _clamp_phys(spec[k], v) for k, v in values.items()}
        m = self._m[name]
        # values are clamped to the raw range above, so cantools' own range check (strict) is redundant
        return can.Message(arbitration_id=m.frame_id, data=m.encode(phys, strict=False), is_extended_id=False,
                           dlc=m.length)

    def _refill(self, now_ns: int) -> None:
        if self._t_ns is not None:
            self._tokens = min(self.capacity, self._tokens + (now_ns - self._t_ns) / 1e9 * self.rate_fps)
        self._t_ns = now_ns

    def frames(self, snap: Snapshot, now_ns: int) -> list[can.Message]:
        self._refill(now_ns)
        out: list[can.Message] = []
        # 1. state and version: every state period, and at once when the alarm changes
        period = int(self.cfg.state_period_s * 1e9)
        if self._last_state_ns is None or now_ns - self._last_state_ns >= period or snap.alarm != self._last_alarm:
            out += [self.radar_state(snap), self.version()]
            self._last_state_ns, self._last_alarm = now_ns, snap.alarm
        # 2. presence: every frame, and every heartbeat while faulted
        if self.mask & MASK_PRESENCE and (snap.new_frame or snap.fault):
            out.append(self.presence(snap))
        # 3. lane statistics when an interval closed
        if self.mask & MASK_LANE_STATS and snap.new_interval:
            out += self.lane_stats(snap)
        budget = int(self._tokens) - len(out)
        if budget < 0:  # state/presence/lanes never wait: they only drain the bucket
            self.counters["over_budget_cycles"] += 1
        # 4. object list: each new frame, and each heartbeat while faulted (an empty list flushes receivers)
        if self.mask & MASK_OBJECTS and (snap.new_frame or snap.fault):
            per_obj = 1 + bool(self.mask & MASK_QUALITY) + bool(self.mask & MASK_EXTENDED)
            tracks = sorted(snap.tracks, key=lambda t: t.range_m)[:255]
            room = max(0, (budget - 1) // per_obj)
            if budget < 1:
                self.counters["object_cycles_skipped"] += 1
            else:
                if len(tracks) > room:
                    self.counters["objects_truncated"] += len(tracks) - room
                    tracks = tracks[:room]
                out += self.object_list(snap, tracks)
        self._tokens -= len(out)
        self.counters["frames"] += len(out)
        return out

    # --- messages ---------------------------------------------------------------------------
    def radar_state(self, snap: Snapshot) -> can.Message:
        persistent = snap.alarm in (ALARM_PIPELINE, ALARM_STOPPED)
        return self._encode("RadarState", {
            "RadarState_NVMwriteStatus": 0, "RadarState_NVMReadStatus": 1, "RadarState_MaxDistanceCfg": 0,
            "RadarState_Voltage_Error": 0, "RadarState_Temporary_Error": int(snap.alarm != ALARM_NONE and not persistent),
            "RadarState_Temperature_Error": 0, "RadarState_Interference": 0, "RadarState_Persistent_Error": int(persistent),
            "RadarState_RadarPowerCfg": 0, "RadarState_SensorID": self.sensor_id, "RadarState_SortIndex": 1,
            "RadarState_CtrlRelayCfg": 0, "RadarState_OutputTypeCfg": 1,
            "RadarState_SendQualityCfg": int(bool(self.mask & MASK_QUALITY)),
            "RadarState_SendExtInfoCfg": int(bool(self.mask & MASK_EXTENDED)),
            "RadarState_MotionRxState": 0, "RadarState_RCS_Threshold": 0,
        })

    def version(self) -> can.Message:
        major, minor, patch = firmware_version()
        return self._encode("VersionID", {"Version_MajorRelease": major, "Version_MinorRelease": minor,
                                          "Version_PatchLevel": patch})

    def presence(self, snap: Snapshot) -> can.Message:
        def bits(flags) -> int:
            return sum(1 << k for k, f in enumerate(flags[:8]) if f)

        return self._encode("Lane_Presence", {
            "Presence_Lanes": bits(snap.presence), "Presence_Queue": 0, "Presence_WrongWay": bits(snap.wrong_way),
            "Presence_StatsStale": bits(snap.stats_stale), "Presence_Failsafe": int(snap.failsafe_presence),
            "Presence_Sequence": snap.interval_seq, "Presence_Counter": max(snap.frame_seq, 0) & 0xFF,
            "Presence_Alarm": snap.alarm,
        })

    def lane_stats(self, snap: Snapshot) -> list[can.Message]:
        out = []
        last = next((ls for ls in snap.lane_stats if ls is not None), None)
        if last is not None:
            end = self.wall() - (snap.t_ns - snap.interval_end_ns) / 1e9
            out.append(self._encode("Interval_Status", {"Interval_Sequence": snap.interval_seq,
                                                         "Interval_Length": last.interval_s,
                                                         "Interval_UnixTime": int(end)}))
        for k, ls in enumerate(snap.lane_stats):
            if ls is None:
                continue
            lane, seq = k + 1, ls.sequence & 0xFF
            out.append(self._encode("Lane_Stats_A", {
                "LaneA_Lane": lane, "LaneA_Volume": ls.volume, "LaneA_Occupancy": ls.occupancy_pct,
                "LaneA_MeanSpeed": None if ls.volume == 0 else ls.mean_speed_kmh, "LaneA_Sequence": seq}))
            out.append(self._encode("Lane_Stats_B", {
                "LaneB_Lane": lane, "LaneB_SpeedP85": ls.speed_p85_kmh, "LaneB_Headway": ls.headway_s,
                "LaneB_Gap": ls.gap_s, "LaneB_Sequence": seq}))
            counts = dict(ls.class_counts)
            c = {g: sum(counts.pop(n, 0) for n in names) for g, names in CLASS_COUNT_GROUPS if names}
            c["other"] = sum(counts.values())
            out.append(self._encode("Lane_Class_Counts", {
                "LaneC_Lane": lane, "LaneC_Pedestrian": c["pedestrian"], "LaneC_Bicycle": c["bicycle"],
                "LaneC_Motorcycle": c["motorcycle"], "LaneC_Car": c["car"], "LaneC_TruckBus": c["truck_bus"],
                "LaneC_Other": c["other"], "LaneC_Sequence": seq}))
        return out

    def object_list(self, snap: Snapshot, tracks: list[TrackState]) -> list[can.Message]:
        out = [self._encode("Obj_0_Status", {"Obj_NofObjects": len(tracks),
                                             "Obj_MeasCounter": max(snap.frame_seq, 0) & 0xFFFF,
                                             "Obj_InterfaceVersion": INTERFACE_VERSION})]
        for t in tracks:
            out.append(self._encode("Obj_1_General", {
                "Obj_ID": t.track_id & 0xFF, "Obj_DistLong": t.y_m, "Obj_DistLat": -t.x_m,
                "Obj_VrelLong": t.vy_mps, "Obj_VrelLat": -t.vx_mps, "Obj_DynProp": dyn_prop(t),
                "Obj_RCS": t.rcs_dbsm}))  # None: raw 0, "not measured"
        if self.mask & MASK_QUALITY:  # DistLong is y and DistLat -x: their sds are y's and x's
            for t in tracks:
                out.append(self._encode("Obj_2_Quality", {
                    "Obj_ID": t.track_id & 0xFF, "Obj_DistLong_rms": rms_code(t.y_sd_m),
                    "Obj_DistLat_rms": rms_code(t.x_sd_m), "Obj_VrelLong_rms": rms_code(t.vy_sd_mps),
                    "Obj_VrelLat_rms": rms_code(t.vx_sd_mps), "Obj_ArelLong_rms": RMS_INVALID,
                    "Obj_ArelLat_rms": RMS_INVALID, "Obj_Orientation_rms": orientation_rms_code(t),
                    "Obj_MeasState": 1 if t.hits <= 1 else 2,
                    "Obj_ProbOfExist": prob_of_exist_code(t.existence_probability)}))
        if self.mask & MASK_EXTENDED:
            for t in tracks:
                heading = heading_deg(t)
                out.append(self._encode("Obj_3_Extended", {
                    "Obj_ID": t.track_id & 0xFF, "Obj_ArelLong": 0.0, "Obj_ArelLat": 0.0, "Obj_Class": ars_class(t.cls),
                    "Obj_OrientationAngle": 0.0 if heading is None else heading, "Obj_Length": t.length_m,
                    "Obj_Width": None}))  # None: raw 0, "not measured"
        return out


class CanSink:
    """Output sink: CAN frames from a sender thread; ``publish`` queues and returns at once.

    ``threaded=False`` sends inside ``publish`` (tests with a fake clock; the virtual bus never blocks).
    """

    def __init__(self, cfg: CanConfig, n_lanes: int, *, failsafe: FailsafeConfig | None = None,
                 links: Links | None = None, bus_factory: Callable[[], Any] | None = None,
                 clock_ns: Callable[[], int] = time.monotonic_ns, wall_clock: Callable[[], float] = time.time,
                 threaded: bool = True) -> None:
        self.cfg = cfg
        self.links = links or Links()
        self.state = OutputState(n_lanes, failsafe)
        self.encoder = CanEncoder(cfg, wall_clock=wall_clock)
        self._bus_factory = bus_factory or (lambda: can.Bus(interface=cfg.interface, channel=cfg.channel,
                                                            bitrate=cfg.bitrate))
        self._clock_ns = clock_ns
        self._threaded = threaded
        self.bus: Any = None
        self._next_open_ns = 0
        self._pause_until_ns = 0
        self._queue: collections.deque = collections.deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._runtime: tuple[bool, int, int] | None = None
        self.enabled = True
        self.faults = collections.Counter()
        self.sent = 0

    # --- frame loop side ---------------------------------------------------------------------
    def publish(self, result: FrameResult | None, health: LoopHealth) -> None:
        snap = self.state.update(result, health)
        if not self._threaded:
            self._process(snap, health.t_ns)
            return
        if len(self._queue) >= self.cfg.queue_frames:
            try:
                self._queue.popleft()
                self.faults["queue_overflow"] += 1
            except IndexError:  # the sender thread emptied it meanwhile
                pass
        self._queue.append(snap)
        self._wake.set()

    def set_runtime(self, enabled: bool, sensor_id: int, mask: int) -> None:
        """Applied from the Modbus configuration block (takes effect on the next cycle)."""
        self._runtime = (bool(enabled), int(sensor_id), int(mask))

    # --- sender side -------------------------------------------------------------------------
    def start(self) -> "CanSink":
        if self._threaded:
            self._thread = threading.Thread(target=self._run, name="can-out", daemon=True)
            self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(0.25)
            self._wake.clear()
            while True:
                try:
                    snap = self._queue.popleft()
                except IndexError:
                    break
                self._process(snap, self._clock_ns())
            self.watchdog()

    def watchdog(self, now_ns: int | None = None) -> bool:
        """The frame loop went silent: send the fault state and the fail-safe presence."""
        now = self._clock_ns() if now_ns is None else now_ns
        snap = self.state.check(now)
        if snap is None:
            return False
        self._process(snap, now)
        return True

    def _process(self, snap: Snapshot, now_ns: int) -> None:
        rt, self._runtime = self._runtime, None
        if rt is not None:
            self.enabled = rt[0]
            self.encoder.set_runtime(rt[1], rt[2])
        if not self.enabled:
            return
        frames = self.encoder.frames(snap, now_ns)
        self._send(frames, now_ns)

    def _open(self, now_ns: int) -> bool:
        if self.bus is not None:
            return True
        if now_ns < self._next_open_ns:
            return False
        try:
            self.bus = self._bus_factory()
            log.info("CAN output on %s:%s", self.cfg.interface, self.cfg.channel)
            self.links.can_up = True
            return True
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            self.faults["open_failed"] += 1
            self._next_open_ns = now_ns + int(self.cfg.reconnect_s * 1e9)
            self.links.can_up = False
            if self.faults["open_failed"] == 1:
                log.error("CAN interface %s:%s not available: %s (retrying every %.0f s)", self.cfg.interface,
                          self.cfg.channel, exc, self.cfg.reconnect_s)
            return False

    def _send(self, frames: list[can.Message], now_ns: int) -> None:
        if not frames or not self._open(now_ns):
            if frames:
                self.faults["frames_not_sent"] += len(frames)
            return
        if now_ns < self._pause_until_ns:
            self.faults["frames_not_sent"] += len(frames)
            return
        for i, msg in enumerate(frames):
            try:
                self.bus.send(msg, timeout=0.005)
                self.sent += 1
            except (can.CanError, OSError, ValueError) as exc:  # ValueError: a backend refusing the message
                code = getattr(exc, "error_code", None) or getattr(exc, "errno", None)
                kind = "enobufs" if code == errno.ENOBUFS else "bus_off" if code in (errno.ENETDOWN, errno.ENETUNREACH) else "send_error"
                self.faults[kind] += 1
                self.faults["frames_not_sent"] += len(frames) - i
                self.links.can_up = kind == "enobufs"
                if kind != "enobufs":  # bus off / interface gone: back off, then reopen
                    self._pause_until_ns = now_ns + int(self.cfg.reconnect_s * 1e9)
                    self._close_bus()
                    self._next_open_ns = self._pause_until_ns
                if sum(self.faults[k] for k in ("enobufs", "bus_off", "send_error")) <= 3:
                    log.warning("CAN send failed (%s): %s", kind, exc)
                return  # never split a cycle further: the rest of it is dropped
        self.links.can_up = True

    def _close_bus(self) -> None:
        bus, self.bus = self.bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError) as exc:
                log.debug("CAN shutdown: %s", exc)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        self._close_bus()
        self.links.can_up = False
