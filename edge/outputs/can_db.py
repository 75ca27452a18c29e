"""The CAN message set: one definition -> the shipped DBC and the cantools database used to encode.

ARS408-21 object list (Continental's layout, so existing ARS408 decoders, DBCs and viewers read
it): 0x201 RadarState, 0x60A Obj_0_Status, 0x60B Obj_1_General, 0x60C Obj_2_Quality (optional),
0x60D Obj_3_Extended (class, size), 0x700 VersionID. Every ARS408 id is offset by 0x10 x sensor id.
All signals are Motorola (big-endian); start bits are DBC start bits (MSB position in the sawtooth
numbering), physical = raw x scale + offset.

Our lane messages live in 0x690-0x6FF, outside the ARS408 offset ranges, in a block of 8 ids per
sensor: ``0x690 + 8 x sensor_id`` + 0 Lane_Stats_A, +1 Lane_Stats_B, +2 Lane_Class_Counts,
+3 Lane_Presence, +4 Interval_Status. Lane statistics follow NTCIP 1202 semantics (interval
volume/occupancy/speed, rolling 0-255 sequence) with the Wavetronix additions (85th percentile,
headway, gap, class counts). "Not available" is the all-ones raw value of a signal (marked n/a).

ARS408 signals without an n/a code in Continental's DBC get one where we need it: raw 0 of Obj_RCS
(-64 dBm2, far below anything a radar detects), Obj_Length and Obj_Width (0 m) means "not measured"
(VAL_ ``not_measured``); a measured value never encodes to raw 0. The 0x60C quality codes follow
Continental's tables (:func:`rms_code`, :func:`prob_of_exist_code`): rms code 31 is "invalid" (not
estimated), ProbOfExist 0 is "invalid".
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import cantools
from cantools.database.can import Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion

SENDER = "RADAR"
ARS_ID_STEP = 0x10
LANE_ID_BASE, LANE_ID_STEP = 0x690, 0x08
INTERFACE_VERSION = 1

DYN_PROP = {0: "moving", 1: "stationary", 2: "oncoming", 3: "stationary_candidate", 4: "unknown",
            5: "crossing_stationary", 6: "crossing_moving", 7: "stopped"}
OBJ_CLASS = {0: "point", 1: "car", 2: "truck", 3: "pedestrian", 4: "motorcycle", 5: "bicycle", 6: "wide",
             7: "reserved"}
MEAS_STATE = {0: "deleted", 1: "new", 2: "measured", 3: "predicted", 4: "deleted_for_merge", 5: "new_from_merge"}
PROB_OF_EXIST = {0: "invalid", 1: "lt_25", 2: "lt_50", 3: "lt_75", 4: "lt_90", 5: "lt_99", 6: "lt_99_9", 7: "le_100"}
OUTPUT_TYPE = {0: "none", 1: "send_objects", 2: "send_clusters"}
NOT_MEASURED = {0: "not_measured"}

#: 0x60C rms codes: code k (0..30) means "standard deviation < 0.005 x (top / 0.005)^(k / 30)", a geometric table
#: from "<0.005" to "<10.000" (m, m/s, m/s^2; top 10) or to "<180.000" (orientation, deg; top 180), as in
#: Continental's ARS408 DBC; 31 = invalid
RMS_INVALID = 31
RMS_BOUNDS = tuple(0.005 * (10.0 / 0.005) ** (k / 30) for k in range(31))
ORIENTATION_RMS_BOUNDS_DEG = tuple(0.005 * (180.0 / 0.005) ** (k / 30) for k in range(31))
#: 0x60C Obj_ProbOfExist: code k (1..7) means "probability < PROB_OF_EXIST_BOUNDS[k - 1]" (7: <= 100 %); 0 = invalid
PROB_OF_EXIST_BOUNDS = (0.25, 0.5, 0.75, 0.9, 0.99, 0.999)


def rms_code(sd: float | None, bounds: tuple[float, ...] = RMS_BOUNDS) -> int:
    """The 0x60C rms code of a standard deviation: the first code whose bound exceeds it; 31 (invalid) when it
    is not estimated (None, NaN) or not below the table's top (a larger code would claim a better accuracy)."""
    if sd is None or not math.isfinite(sd) or sd < 0:
        return RMS_INVALID
    return bisect.bisect_right(bounds, float(sd))  # == 31 above the top


def prob_of_exist_code(p: float | None) -> int:
    """The 0x60C Obj_ProbOfExist code of an existence probability in [0, 1]; 0 (invalid) when unknown."""
    if p is None or not 0.0 <= p <= 1.0:  # NaN fails both comparisons
        return 0
    return 1 + bisect.bisect_right(PROB_OF_EXIST_BOUNDS, float(p))


def _rms_choices(bounds: tuple[float, ...], unit: str) -> dict[int, str]:
    return {**{k: f"<{b:.3f} {unit}" for k, b in enumerate(bounds)}, RMS_INVALID: "invalid"}
MOTION_RX = {0: "input_ok", 1: "speed_missing", 2: "yaw_rate_missing", 3: "speed_and_yaw_rate_missing"}


@dataclass(frozen=True)
class Sig:
    name: str
    start: int  # DBC start bit (MSB, Motorola sawtooth numbering)
    length: int
    scale: float = 1.0
    offset: float = 0.0
    unit: str = ""
    choices: dict[int, str] | None = None
    comment: str = ""
    na: bool = False  # the all-ones raw value means "not available"
    na_zero: bool = False  # raw 0 means "not measured" (ARS408 signals without an invalid code)

    def raw_max(self) -> int:
        return (1 << self.length) - 1

    def phys(self, raw: int) -> float:
        return raw * self.scale + self.offset


@dataclass(frozen=True)
class Msg:
    name: str
    frame_id: int  # for sensor id 0
    length: int
    signals: tuple[Sig, ...]
    comment: str
    ars408: bool  # offset by 0x10 x sensor id (else by 8 x sensor id in our lane block)
    cycle_ms: int | None = None

    def id_for(self, sensor_id: int) -> int:
        return self.frame_id + (ARS_ID_STEP if self.ars408 else LANE_ID_STEP) * sensor_id


def _ars(name, fid, length, sigs, comment, cycle_ms=None) -> Msg:
    return Msg(name, fid, length, tuple(sigs), comment, True, cycle_ms)


def _lane(name, off, length, sigs, comment) -> Msg:
    return Msg(name, LANE_ID_BASE + off, length, tuple(sigs), comment, False)


MESSAGES: tuple[Msg, ...] = (
    _ars("RadarState", 0x201, 8, [
        Sig("RadarState_NVMwriteStatus", 7, 1, comment="0 failed, 1 successful (always 0: no NVM writes over CAN)"),
        Sig("RadarState_NVMReadStatus", 6, 1, comment="1: configuration read at start"),
        Sig("RadarState_MaxDistanceCfg", 15, 10, 2.0, 0.0, "m"),
        Sig("RadarState_Voltage_Error", 17, 1),
        Sig("RadarState_Temporary_Error", 18, 1, comment="no frames (source stalled) or no results from the loop"),
        Sig("RadarState_Temperature_Error", 19, 1),
        Sig("RadarState_Interference", 20, 1),
        Sig("RadarState_Persistent_Error", 21, 1, comment="pipeline/source fault or the frame loop stopped"),
        Sig("RadarState_RadarPowerCfg", 25, 3),
        Sig("RadarState_SensorID", 34, 3),
        Sig("RadarState_SortIndex", 38, 3, choices={0: "no_sorting", 1: "sorted_by_range", 2: "sorted_by_RCS"}),
        Sig("RadarState_CtrlRelayCfg", 41, 1),
        Sig("RadarState_OutputTypeCfg", 43, 2, choices=OUTPUT_TYPE),
        Sig("RadarState_SendQualityCfg", 44, 1),
        Sig("RadarState_SendExtInfoCfg", 45, 1),
        Sig("RadarState_MotionRxState", 47, 2, choices=MOTION_RX),
        Sig("RadarState_RCS_Threshold", 60, 3),
    ], "ARS408 radar state: sent every state period and at once when the health changes", 1000),
    _ars("Obj_0_Status", 0x60A, 4, [
        Sig("Obj_NofObjects", 7, 8, comment="objects that follow in this cycle"),
        Sig("Obj_MeasCounter", 15, 16, comment="cycle counter = frame sequence mod 65536 (Modbus register 20)"),
        Sig("Obj_InterfaceVersion", 31, 4),
    ], "ARS408 object list header, first frame of every cycle"),
    _ars("Obj_1_General", 0x60B, 8, [
        Sig("Obj_ID", 7, 8, comment="track id (same as the Modbus track table)"),
        Sig("Obj_DistLong", 15, 13, 0.2, -500.0, "m", comment="distance along the boresight"),
        Sig("Obj_DistLat", 18, 11, 0.2, -204.6, "m", comment="lateral distance, left +"),
        Sig("Obj_VrelLong", 39, 10, 0.25, -128.0, "m/s", comment="velocity along the boresight, receding +"),
        Sig("Obj_VrelLat", 45, 9, 0.25, -64.0, "m/s", comment="lateral velocity, left +"),
        Sig("Obj_DynProp", 50, 3, choices=DYN_PROP),
        Sig("Obj_RCS", 63, 8, 0.5, -64.0, "dBm2", choices=NOT_MEASURED, na_zero=True,
            comment="radar cross-section; raw 0 (-64 dBm2) = not measured (no calibrated RCS estimate)"),
    ], "ARS408 object position and velocity, one per object"),
    _ars("Obj_2_Quality", 0x60C, 7, [
        Sig("Obj_ID", 7, 8),
        Sig("Obj_DistLong_rms", 15, 5, choices=_rms_choices(RMS_BOUNDS, "m"), comment="sd of Obj_DistLong"),
        Sig("Obj_DistLat_rms", 10, 5, choices=_rms_choices(RMS_BOUNDS, "m"), comment="sd of Obj_DistLat"),
        Sig("Obj_VrelLong_rms", 21, 5, choices=_rms_choices(RMS_BOUNDS, "m/s"), comment="sd of Obj_VrelLong"),
        Sig("Obj_VrelLat_rms", 16, 5, choices=_rms_choices(RMS_BOUNDS, "m/s"), comment="sd of Obj_VrelLat"),
        Sig("Obj_ArelLong_rms", 27, 5, choices=_rms_choices(RMS_BOUNDS, "m/s2"),
            comment="31: no acceleration estimate (constant-velocity tracks)"),
        Sig("Obj_ArelLat_rms", 38, 5, choices=_rms_choices(RMS_BOUNDS, "m/s2"),
            comment="31: no acceleration estimate (constant-velocity tracks)"),
        Sig("Obj_Orientation_rms", 33, 5, choices=_rms_choices(ORIENTATION_RMS_BOUNDS_DEG, "deg"),
            comment="bound on the heading's sd from the velocity's; 31 when the heading is unknown (slower than 0.5 m/s)"),
        Sig("Obj_MeasState", 52, 3, choices=MEAS_STATE),
        Sig("Obj_ProbOfExist", 55, 3, choices=PROB_OF_EXIST,
            comment="from the track's existence probability (confirmation and track score); 0 = unknown"),
    ], "ARS408 object quality (optional): standard deviations from the track covariance, existence probability"),
    _ars("Obj_3_Extended", 0x60D, 8, [
        Sig("Obj_ID", 7, 8),
        Sig("Obj_ArelLong", 15, 11, 0.01, -10.0, "m/s2", comment="0: not estimated (Obj_ArelLong_rms 31)"),
        Sig("Obj_ArelLat", 20, 9, 0.01, -2.5, "m/s2", comment="0: not estimated (Obj_ArelLat_rms 31)"),
        Sig("Obj_Class", 26, 3, choices=OBJ_CLASS, comment="from the track's class; 0 point = not classified"),
        Sig("Obj_OrientationAngle", 39, 10, 0.4, -180.0, "deg",
            comment="heading of the velocity; 0 when slower than 0.5 m/s (Obj_Orientation_rms 31)"),
        Sig("Obj_Length", 55, 8, 0.2, 0.0, "m", choices=NOT_MEASURED, na_zero=True,
            comment="measured vehicle length; raw 0 = not measured"),
        Sig("Obj_Width", 63, 8, 0.2, 0.0, "m", choices=NOT_MEASURED, na_zero=True,
            comment="raw 0 = not measured (no track measures a width: the lane board's 9.5 deg beam cannot resolve one)"),
    ], "ARS408 object extended information: class (truck covers truck/bus), size, heading"),
    _ars("VersionID", 0x700, 4, [
        Sig("Version_MajorRelease", 7, 8), Sig("Version_MinorRelease", 15, 8), Sig("Version_PatchLevel", 23, 8),
    ], "ARS408 version message: firmware major, minor, patch", 1000),
    _lane("Lane_Stats_A", 0, 8, [
        Sig("LaneA_Lane", 7, 8, comment="lane 1..8"),
        Sig("LaneA_Volume", 15, 16, unit="veh", comment="vehicles in the interval", na=True),
        Sig("LaneA_Occupancy", 31, 16, 0.01, 0.0, "%", na=True),
        Sig("LaneA_MeanSpeed", 47, 16, 0.1, 0.0, "km/h", na=True),
        Sig("LaneA_Sequence", 63, 8, comment="interval sequence 0-255 (NTCIP volumeOccupancySequence)"),
    ], "Per-lane interval statistics A, one per lane when an interval closes"),
    _lane("Lane_Stats_B", 1, 8, [
        Sig("LaneB_Lane", 7, 8),
        Sig("LaneB_SpeedP85", 15, 16, 0.1, 0.0, "km/h", na=True),
        Sig("LaneB_Headway", 31, 16, 0.01, 0.0, "s", comment="mean headway, front to front", na=True),
        Sig("LaneB_Gap", 47, 16, 0.01, 0.0, "s", comment="mean gap, back to front", na=True),
        Sig("LaneB_Sequence", 63, 8),
    ], "Per-lane interval statistics B, one per lane when an interval closes"),
    _lane("Lane_Class_Counts", 2, 8, [
        Sig("LaneC_Lane", 7, 8),
        Sig("LaneC_Pedestrian", 15, 8, na=True), Sig("LaneC_Bicycle", 23, 8, na=True),
        Sig("LaneC_Motorcycle", 31, 8, na=True), Sig("LaneC_Car", 39, 8, na=True),
        Sig("LaneC_TruckBus", 47, 8, na=True), Sig("LaneC_Other", 55, 8, na=True),
        Sig("LaneC_Sequence", 63, 8),
    ], "Per-lane class counts in the interval (saturate at 254)"),
    _lane("Lane_Presence", 3, 8, [
        Sig("Presence_Lanes", 7, 8, comment="bit k = lane k+1 occupied now (fail-safe value while faulted)"),
        Sig("Presence_Queue", 15, 8, comment="bit k = queue on lane k+1 (not detected yet: 0)"),
        Sig("Presence_WrongWay", 23, 8, comment="bit k = wrong-way vehicle on lane k+1 now"),
        Sig("Presence_StatsStale", 31, 8, comment="bit k = lane k+1 statistics stale"),
        Sig("Presence_Failsafe", 39, 1, comment="1 = fault: presence bits are the fail-safe value"),
        Sig("Presence_Sequence", 47, 8, comment="last interval sequence"),
        Sig("Presence_Counter", 55, 8, comment="frame counter mod 256"),
        Sig("Presence_Alarm", 63, 8, comment="alarm code (Modbus register 17)"),
    ], "Lane presence (detector call), every frame and every heartbeat while faulted"),
    _lane("Interval_Status", 4, 7, [
        Sig("Interval_Sequence", 7, 8),
        Sig("Interval_Length", 15, 16, unit="s"),
        Sig("Interval_UnixTime", 31, 32, unit="s", comment="UNIX time the interval closed"),
    ], "Interval closed: sequence, length, time; sent before the lane statistics"),
)

BY_NAME = {m.name: m for m in MESSAGES}


def build_database(sensor_id: int = 0) -> Database:
    """The cantools database of our message set for one sensor id."""
    if not 0 <= sensor_id <= 7:
        raise ValueError(f"sensor id must be 0..7, got {sensor_id}")
    msgs = []
    for m in MESSAGES:
        sigs = []
        for s in m.signals:
            comment = s.comment + ("; " if s.comment else "") + "all ones = n/a" if s.na else s.comment
            sigs.append(Signal(
                s.name, start=s.start, length=s.length, byte_order="big_endian", is_signed=False,
                conversion=BaseConversion.factory(scale=s.scale, offset=s.offset, choices=s.choices),
                minimum=s.phys(0), maximum=s.phys(s.raw_max()), unit=s.unit or None, comment=comment or None,
                receivers=[],
            ))
        msgs.append(Message(frame_id=m.id_for(sensor_id), name=m.name, length=m.length, signals=sigs,
                            senders=[SENDER], cycle_time=m.cycle_ms, comment=m.comment, strict=True))
    return Database(messages=msgs, nodes=[Node(SENDER, comment="radar-edge roadside radar")],
                    version="radar-edge outputs 1.0")


def dbc_text(sensor_id: int = 0) -> str:
    """The DBC file text (what ``radar-edge dbc`` writes and the package ships for sensor id 0)."""
    return build_database(sensor_id).as_dbc_string().replace("\r\n", "\n")  # cantools writes CRLF


def load_shipped():
    """The DBC shipped in the package (edge/outputs/radar_edge.dbc), loaded with cantools."""
    from importlib.resources import files

    text = files("edge.outputs").joinpath("radar_edge.dbc").read_text(encoding="utf-8")
    return cantools.database.load_string(text, database_format="dbc", strict=True)
