"""Evaluation of the lane profile against simulator ground truth (DESIGN §6).

The scenario is simulated frame by frame on the SIMO board and run through :class:`LanePipeline`
without real-time pacing. The installer's part of the configuration comes from the scenario unless
the configuration sets it explicitly: the mounting height (``pipeline.lane.mounting_height_m``) and
the lane geometry (``traffic.lane_centers_m``/``lane_widths_m``/``lane_directions``). The mounting yaw
is *not* taken from the scenario: a mis-aimed radar must be found by the traffic layer's estimate.

Definitions (all in the radar's ground frame: x lateral, y along the boresight's ground projection):

* reference point of a vehicle: the centre of the face the radar sees, at road level
  (:meth:`hw_sim.vehicles.Vehicle.near_face_point`); point targets: their trajectory point;
* in view: ground range in [``min_range_m``, ``max_range_m``] (10-300 m) and azimuth within the
  board's field of view; targets of class ``clutter`` (multipath ghosts) are never vehicles;
* per frame, confirmed tracks are assigned one-to-one to vehicles (Hungarian, Euclidean cost) within
  a gate of ``gate_m`` plus the vehicle's length (a track may sit anywhere on a long truck);
* ``tracked_fraction``: in-view frames with an assigned track / in-view frames; ``untracked_frames``: the
  others split into those before its first assigned frame (acquisition), between (gaps) and after its last
  (lost before leaving the view), summed per class in ``untracked_frames_by_class``;
  ``position_rmse_m``: eq. (20) over the assigned frames, split into ``position_bias_xy_m`` (mean error,
  across and along the boresight) and ``position_sd_xy_m`` (its sd): a bias (reference point, geometry)
  and noise are fixed differently; ``position_rmse_m_within``: eq. (20) over the assigned frames within each
  50 m step of ground range (``{"50": .., "100": .., ..}``, cumulative; ``position_rmse_m_max_within`` in the
  summary is the worst vehicle's per step): far away one detection's lateral error is about a metre (4
  channels), so a vehicle first seen 250 m out carries its first second's error in its whole-time figure,
  while Lim's reference trajectories (Table 3) came from a camera over a stretch of known length;
  ``speed_mae_kmh``: |track speed - speed|;
* ``detection_probability``: assigned (vehicle, frame) pairs / in-view pairs, all vehicles;
  ``detection_probability_raw``: the same with any detection (before the tracker) within the gate;
* ``id_switches``: changes of the assigned track id along a vehicle's assigned frames;
* false track: a confirmed track episode (an id, consecutive frames) that is assigned to a vehicle in
  fewer than half of its frames *in view* (the same region as for vehicles; vehicles out of view count
  for the assignment, so a track on a vehicle at 310 m is not false). Frames of a track outside the
  region are not scored, as vehicles outside it are not: the traffic generator removes a receding
  vehicle once its centre passes ``range_m`` (380 m in the built-in scenarios) while its track, on the
  rear face two metres nearer, rightly coasts on for a few frames; ``false_tracks_per_min`` over the
  evaluated time;
  ``false_tracks_first_30s``: those whose episode began in the first ``START_S`` (30) seconds. Every run starts
  the pipeline cold with traffic already on the road (the traffic generator populates it before t = 0), and no
  figure leaves the first seconds out, so start-up phantoms count; this one makes them visible;
  ``false_tracks_near``: those whose episode began within ``NEAR_M`` (25 m) ground range of the radar, where
  vehicles pass under or beside the mounting (phantoms near the radar);
* ``lane_accuracy``: assigned pairs whose track lane equals the vehicle's true lane at that frame (per vehicle
  too, over its assigned frames); ``lane_accuracy_keeping`` and ``lane_accuracy_changing``: the same over the
  frames of vehicles outside and inside a lane change (the simulator's 4 s lateral move; the true lane switches
  when the vehicle crosses the boundary, halfway through it);
* ``visible_frames_*`` (tallies; the corpus's ``detection_probability_visible``): the separate vehicles' frames
  where under ``SHADOWED_SHARE`` of the vehicle's echo is shadowed by another vehicle's body (the simulator's
  ``GroundTruth.shadowed_fraction``, 20 dB of knife-edge loss), tracked and in view: what no radar at the mounting
  sees is left out. Equal to the separate frames where the truth carries no shadowing;
* ``detection_probability_by_overlap``: per class, the detection probability over the in-view frames where
  the vehicle is ``separate`` and where it is ``overlapping`` another vehicle, and the overlapping share:
  in at least ``OVERLAP_SEGMENTS`` of the four chirp segments its near face's beat frequency lies within
  ``OVERLAP_BINS`` FFT bins of the beats spanned by another vehicle's body (near face to far end, at its
  radial speed), and the two are less than the array's beamwidth (lambda / (N d), 9.5 deg) apart in azimuth.
  Neither the waveform nor Bartlett separates such a pair; only the side-by-side resolver can. A diagnosis
  of where the misses come from (the headline ``detection_probability`` counts every frame);
* ``count_error_per_lane``: measured volume at the traffic layer's detection line (closed intervals
  plus the open one) minus the true number of reference points crossing it in the lane's direction of travel
  (a wrong-way driver is an event, not volume), per lane; ``volume_measured_either_per_lane``: the measured
  volumes with a vehicle whose body straddles a lane boundary at the line (reference point and width against the
  lanes) counted right in either of the two lanes, as a loop under it may count it (``count_abs_error_either``);
* ``wrong_way``: the ``wrong_way`` alarms scored against the truth (scenarios with ``[[lane]]`` tables):
  ``drivers`` = vehicles in view driving against their lane's direction faster than 3 m/s for 15 frames,
  ``correct`` = alarms whose track followed such a vehicle when raised, ``false`` = the other alarms,
  ``missed`` = drivers without a correct alarm; per driver alarmed, ``delay_s`` from its first frame in view
  against its lane to its first alarm and ``alarm_range_m``, its ground range then.
* ``stopped_vehicle``: the ``stopped_vehicle`` alarms scored the same way: ``vehicles`` = vehicles standing
  (slower than 0.5 m/s) in a lane in view for 5 s, ``delay_s`` from when they came to a standstill.
* ``intervals`` (scenarios with ``[[lane]]`` tables): each closed interval record of the traffic layer against the
  truth of its lane and interval (:mod:`edge.evaluation.lane_intervals`: volume, occupancy over the presence zone
  from the vehicles' true positions and lengths, mean and 85th-percentile speed, headway, gap, counts per length
  class, mean length), errors over all lanes and per lane with the share within the acceptance tolerances, and
  every interval's measured/true pair (``records``);
* ``vehicle_lengths``: of the vehicles whose near face crossed the detection line, the latest length and class
  published on their assigned tracks against their true length, its length class and their body class (by kind
  and by body class; a vehicle never measured counts as wrong); per target ``length_m_true``/``length_m_est``,
  ``length_class_true``/``length_class_est``;
* ``tallies``: the sums and counts behind the headline figures (frames in view and tracked, all and ``separate``;
  false tracks, in all and in the first 30 s, and the minutes; true volume and the sum of |measured - true| over
  lanes; squared position error and its frame count within ``TALLY_RANGE_M`` (200 m), and the sum of the vehicles'
  own position RMSEs there with their number (vehicles with ``VEHICLE_RMSE_MIN_FRAMES`` assigned frames or more:
  each vehicle weighs the same, a far motorcycle as much as a near truck); the squared position error in the road
  frame over the same frames (``position_road_sq_error_sum_m2``: the track turned by the traffic layer's yaw in use,
  the truth by the mounting's, so that a turn of the board's boresight, which the yaw estimate takes up, cancels);
  |speed error| sum and count;
  lane-correct and lane-assigned frames), so that the evaluation corpus (:mod:`edge.evaluation.corpus`) pools runs
  as ratios of sums;
* ``count_mismatches``: the true crossings left unmatched (``missed``) and the counted ones left unmatched
  (``extra``) when each lane's two lists are matched one-to-one by time (at most
  ``edge.evaluation.counting.COUNT_MATCH_S`` apart), and the straddling vehicles counted in the lane they
  straddled into (``straddling``, out of the other two).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from edge.dsp.pairing import PairingModel
from edge.evaluation.counting import CountTally
from edge.evaluation.lane_intervals import LaneIntervalTruth, length_class, score_intervals, score_vehicles
from edge.evaluation.track_log import TrackLogRecorder
from edge.pipeline import StageTimer
from edge.pipelines.lane import LanePipeline
from hal.frame import RawFrame

log = logging.getLogger(__name__)

MIN_RANGE_M = 10.0
MAX_RANGE_M = 300.0
GATE_M = 3.0
RANGE_BIN_M = 50.0
OVERLAP_BINS = 1.5  # a beat this many FFT bins from another vehicle's span shares its peak (Hann main lobe: 2)
OVERLAP_SEGMENTS = 2  # ... in this many of the four segments (the pairing tolerates one shared peak)
TALLY_RANGE_M = 200.0  # the pooled position error (summary ``tallies``) counts assigned frames within this ground range
VEHICLE_RMSE_MIN_FRAMES = 10  # a vehicle's own position RMSE (tallies) needs this many assigned frames within it
START_S = 30.0  # ``false_tracks_first_30s``: false tracks confirmed this soon after the (cold) start
NEAR_M = 25.0  # ``false_tracks_near``: false tracks confirmed within this ground range of the radar
SHADOWED_SHARE = 0.5  # a vehicle-frame with this share of its echo shadowed by another body is not "visible"


def _installer_config(config: Any, sc) -> tuple[Any, Any, Any]:
    lane_cfg = config.section("pipeline.lane")
    track_cfg = config.section("track.pdaf")
    traffic_cfg = config.section("traffic")
    origin = getattr(config, "origin", {})
    if "pipeline.lane.mounting_height_m" not in origin:
        lane_cfg = dataclasses.replace(lane_cfg, mounting_height_m=sc.pose.height_m)
    if sc.lanes and not any(k in origin for k in ("traffic.lane_centers_m", "traffic.lane_widths_m",
                                                  "traffic.lane_directions")):
        traffic_cfg = dataclasses.replace(
            traffic_cfg,
            lane_centers_m=tuple(ln.center_x_m - sc.pose.x_m for ln in sc.lanes),
            lane_widths_m=tuple(ln.width_m for ln in sc.lanes),
            lane_directions=tuple(ln.direction for ln in sc.lanes),
        )
    return lane_cfg, track_cfg, traffic_cfg


def _to_radar_ground(pose, p_world: np.ndarray) -> np.ndarray:
    """World points (n, 3) -> radar ground frame (n, 2) (yaw applied, height dropped)."""
    yaw = math.radians(pose.yaw_deg)
    d = p_world[:, :2] - np.array([pose.x_m, pose.y_m])
    x = d[:, 0] * math.cos(yaw) - d[:, 1] * math.sin(yaw)
    y = d[:, 0] * math.sin(yaw) + d[:, 1] * math.cos(yaw)
    return np.stack([x, y], axis=1)


#: a vehicle in view in a lane slower than STOPPED_TRUE_MPS for STOPPED_TRUE_S is a stopped vehicle (ground truth
#: for scoring the stopped_vehicle alarms)
STOPPED_TRUE_MPS = 0.5
STOPPED_TRUE_S = 5.0
#: a vehicle in view driving against its lane's direction faster than this for this many frames is a
#: wrong-way driver (ground truth for scoring the wrong_way alarms)
WRONG_WAY_TRUE_MPS = 3.0
WRONG_WAY_TRUE_FRAMES = 15


def _overlapping(model, bin_hz: np.ndarray, r_near: np.ndarray, length: np.ndarray, v: np.ndarray,
                 az: np.ndarray, beamwidth_rad: float) -> np.ndarray:
    """Per vehicle, whether another vehicle shares its range-Doppler cell and its beam (see the module doc).

    ``r_near`` slant range of the near face, ``length`` along the range, ``v`` radial speed, ``az`` azimuth,
    all (n,). In each chirp segment a vehicle's body spans the beats ``a_k r + b_k v`` for ``r`` from its near
    face to its far end; vehicle i overlaps j where its near face's beat lies within ``OVERLAP_BINS`` bins of
    j's span in at least ``OVERLAP_SEGMENTS`` segments and the two are less than a beamwidth apart.
    """
    n = r_near.size
    if n < 2:
        return np.zeros(n, bool)
    a, b = model.a[None, :], model.b[None, :]
    f_i = a * r_near[:, None] + b * v[:, None]  # (n, K)
    f_far = a * (r_near + length)[:, None] + b * v[:, None]
    margin = OVERLAP_BINS * bin_hz[None, None, :]
    lo, hi = np.minimum(f_i, f_far)[None, :, :] - margin, np.maximum(f_i, f_far)[None, :, :] + margin
    inside = (f_i[:, None, :] >= lo) & (f_i[:, None, :] <= hi)  # (i, j, K)
    close = (inside.sum(axis=2) >= OVERLAP_SEGMENTS) & (np.abs(az[:, None] - az[None, :]) < beamwidth_rad)
    np.fill_diagonal(close, False)
    return close.any(axis=1)


def _overlap_summary(separate: list[int] | None, overlapping: list[int] | None) -> dict:
    """One class's ``detection_probability_by_overlap`` from its [in view, tracked] counts apart and overlapping."""
    n_sep, n_ovl = (separate or [0])[0], (overlapping or [0])[0]
    return {"separate": separate[1] / n_sep if n_sep else None,
            "overlapping": overlapping[1] / n_ovl if n_ovl else None,
            "overlapping_fraction": n_ovl / (n_sep + n_ovl)}


def _rmse_within(sq_err: list[float], rng: list[float]) -> dict[str, float]:
    """A vehicle's eq. (20) over its assigned frames within each multiple of RANGE_BIN_M of ground range, up to
    the farthest it was assigned at: ``{"50": rmse, "100": ..}`` (cumulative, a key only where frames lie)."""
    if not sq_err:
        return {}
    e, g = np.asarray(sq_err), np.asarray(rng)
    out = {}
    for k in range(1, int(g.max() // RANGE_BIN_M) + 2):
        sel = g <= k * RANGE_BIN_M
        if sel.any():
            out[str(int(k * RANGE_BIN_M))] = float(math.sqrt(e[sel].mean()))
    return out


class _TargetAcc:
    __slots__ = ("cls", "lanes", "n_view", "n_hit", "sq_err", "err_rng", "err_xy", "spd_err", "ids", "last_id",
                 "switches", "n_raw", "vr_true", "vr_est", "dir_true", "wrong_frames", "wrong_first_t", "stand_since_t",
                 "stopped_t", "first_hit", "last_hit", "lane_ok", "kind", "length_m", "len_pub", "cls_pub")

    def __init__(self, cls: str, kind: str = "", length_m: float = 0.0) -> None:
        self.cls = cls
        self.kind = kind or cls  # body type (hw_sim.vehicles.BODY_TYPES: van and bus too)
        self.length_m = length_m
        self.len_pub: float | None = None  # the latest length and class published on its assigned track
        self.cls_pub: str | None = None
        self.lanes: list[int] = []
        self.n_view = self.n_hit = self.n_raw = self.switches = self.lane_ok = 0
        self.sq_err: list[float] = []
        self.err_rng: list[float] = []  # the vehicle's ground range (m) at each sq_err
        self.err_xy: list[tuple[float, float]] = []  # track - reference point (x across, y along), m
        self.spd_err: list[float] = []
        self.vr_true: list[float] = []
        self.vr_est: list[float] = []
        self.dir_true = 0.0
        self.last_id: int | None = None
        self.wrong_frames = 0  # frames in view driving against its lane's direction (a wrong-way driver)
        self.wrong_first_t: float | None = None  # time of the first of them, s
        self.stand_since_t: float | None = None  # standing in a lane in view since (s), None while moving
        self.stopped_t: float | None = None  # start of its first standstill of STOPPED_TRUE_S (a stopped vehicle)
        self.first_hit = self.last_hit = -1  # in-view frame index (0 = its first in view) of its first/last assigned one

    def missed_phases(self) -> tuple[int, int, int]:
        """Its untracked in-view frames split into (before its first track, gaps between, after its last)."""
        if self.n_hit == 0:
            return self.n_view, 0, 0
        before, after = self.first_hit, self.n_view - 1 - self.last_hit
        return before, self.n_view - self.n_hit - before - after, after


def _event_score(since: dict[int, float], alarms: list[tuple[int | None, float, float | None]],
                 who: str = "drivers") -> dict:
    """An event's alarms against the truth. ``since``: the vehicles the event is true of and when it became so;
    ``alarms``: per event raised, the vehicle its track followed (None: none), its time and that vehicle's ground
    range then."""
    correct = [(v, t, r) for v, t, r in alarms if v in since]
    first: dict[int, tuple[float, float]] = {}
    for v, t, r in correct:
        first.setdefault(v, (t, r))
    return {who: len(since), "alarms": len(alarms), "correct": len(correct),
            "false": len(alarms) - len(correct), "missed": len(set(since) - set(first)),
            # per vehicle alarmed: seconds from when the event became true of it to its first alarm, and its
            # ground range then
            "delay_s": [round(t - since[v], 3) for v, (t, _) in sorted(first.items())],
            "alarm_range_m": [round(r, 1) for _, (_, r) in sorted(first.items())]}


def _wrong_way_score(acc: dict[int, "_TargetAcc"], alarms: list[tuple[int | None, float, float | None]]) -> dict:
    """Drivers: vehicles in view against their lane for WRONG_WAY_TRUE_FRAMES, since their first such frame."""
    return _event_score({i: a.wrong_first_t for i, a in acc.items() if a.wrong_frames >= WRONG_WAY_TRUE_FRAMES},
                        alarms)


def _stopped_score(acc: dict[int, "_TargetAcc"], alarms: list[tuple[int | None, float, float | None]]) -> dict:
    """Stopped vehicles: standing in a lane in view for STOPPED_TRUE_S, since they came to a standstill."""
    return _event_score({i: a.stopped_t for i, a in acc.items() if a.stopped_t is not None}, alarms, "vehicles")


def _vehicle_rmse_tallies(acc: dict[int, "_TargetAcc"]) -> dict:
    """The sum of the vehicles' own position RMSEs within ``TALLY_RANGE_M`` and their number (vehicles with at least
    ``VEHICLE_RMSE_MIN_FRAMES`` assigned frames there)."""
    total, n = 0.0, 0
    for a in acc.values():
        e = [e2 for e2, r in zip(a.sq_err, a.err_rng) if r <= TALLY_RANGE_M]
        if len(e) >= VEHICLE_RMSE_MIN_FRAMES:
            total += math.sqrt(sum(e) / len(e))
            n += 1
    return {"position_vehicle_rmse_sum_m": total, "position_vehicles": n}


def _changing_lanes(target: Any, t_s: float) -> bool:
    """Whether ``target`` is inside one of its lane changes at ``t_s`` (the simulator's half-cosine lateral move,
    :class:`hw_sim.vehicles.RoadTrajectory`; a target without a road trajectory never changes lanes)."""
    for t0, dur, _ in getattr(getattr(target, "trajectory", None), "lane_changes", ()):
        if t0 <= t_s <= t0 + dur:
            return True
    return False


def _road_sq_error(track_xy, true_xy, yaw_in_use: float, yaw_true: float) -> float:
    """Squared distance (m^2) between a track and its vehicle in the road frame: the track's ground position turned
    by the yaw the traffic layer uses, the vehicle's by the mounting's true yaw (both in the traffic layer's
    convention: across = x cos + y sin, along = -x sin + y cos)."""
    ct, st, cv, sv = math.cos(yaw_in_use), math.sin(yaw_in_use), math.cos(yaw_true), math.sin(yaw_true)
    x, y, xv, yv = float(track_xy[0]), float(track_xy[1]), float(true_xy[0]), float(true_xy[1])
    du = (x * ct + y * st) - (xv * cv + yv * sv)
    ds = (-x * st + y * ct) - (-xv * sv + yv * cv)
    return du * du + ds * ds


def _straddled_lane(x_m: float, width_m: float, lane: int, lanes: list) -> int:
    """The lane of ``lane``'s direction beside it that a body ``width_m`` wide centred at lateral ``x_m`` reaches
    into (-1: none; ``lanes`` the scenario's): a loop detector under it may count it in either lane."""
    if not 0 <= lane < len(lanes):
        return -1
    for k, ln in enumerate(lanes):
        if (k != lane and ln.direction == lanes[lane].direction
                and abs(x_m - ln.center_x_m) < 0.5 * (width_m + ln.width_m)):
            return k
    return -1


def _near_count(false_eps: list) -> int:
    """The false-track episodes (``[first frame, last frame, frames, assigned frames, id, x_m, y_m]``, the position
    where the episode began) that began within ``NEAR_M`` ground range of the radar."""
    return sum(1 for ep in false_eps if math.hypot(ep[5], ep[6]) < NEAR_M)


def _tallies(acc: dict[int, "_TargetAcc"], pd_overlap: dict, false_eps: list, n_start: int, n_frames: int,
             period: float, counts: dict, sq_200: list, lane_ok: int, lane_n: int,
             visible: list[int] | None = None, lane_keep: list[int] | None = None) -> dict:
    """The run's sums and counts behind its figures (module doc), so that runs pool as ratios of sums: every
    frame from the first on counts (a run starts with traffic already flowing, as after a power cut)."""
    sep = [v for (_, overlapping), v in pd_overlap.items() if not overlapping]
    true_v, meas_v = counts["volume_true_per_lane"], counts["volume_measured_per_lane"]
    return {
        "minutes": n_frames * period / 60.0,
        "minutes_first_30s": n_start * period / 60.0,
        "vehicle_frames_in_view": int(sum(a.n_view for a in acc.values())),
        "vehicle_frames_tracked": int(sum(a.n_hit for a in acc.values())),
        # vehicles sharing no range-Doppler cell and beam with another (detection_probability_by_overlap), <= 300 m
        "separate_frames_in_view": int(sum(v[0] for v in sep)),
        "separate_frames_tracked": int(sum(v[1] for v in sep)),
        # ... of those, the frames where less than SHADOWED_SHARE of the vehicle's echo is shadowed by another body
        "visible_frames_in_view": int((visible or [0, 0])[0]),
        "visible_frames_tracked": int((visible or [0, 0])[1]),
        "false_tracks": len(false_eps),
        # false confirmed tracks whose episode began in the first START_S seconds (start-up phantoms)
        "false_tracks_first_30s": sum(1 for ep in false_eps if ep[0] < n_start),
        # ... and those whose episode began within NEAR_M of the radar
        "false_tracks_near": _near_count(false_eps),
        "id_switches": int(sum(a.switches for a in acc.values())),
        "count_true": int(sum(true_v)),
        "count_abs_error": int(sum(abs(m - t) for m, t in zip(meas_v, true_v))),
        # the same, a vehicle straddling two lanes at the line counted right in either (counting.count_mismatches)
        "count_abs_error_either": int(sum(abs(m - t) for m, t in zip(
            counts.get("volume_measured_either_per_lane", meas_v), true_v))),
        # position error of assigned frames within TALLY_RANGE_M ground range
        "position_sq_error_sum_m2": float(sq_200[0]),
        "position_n": int(sq_200[1]),
        "position_road_sq_error_sum_m2": float(sq_200[2]),
        **_vehicle_rmse_tallies(acc),
        "speed_abs_error_sum_kmh": float(sum(sum(a.spd_err) for a in acc.values())),
        "speed_n": int(sum(len(a.spd_err) for a in acc.values())),
        "lane_correct": int(lane_ok),
        "lane_assigned": int(lane_n),
        # the same over the frames of vehicles outside a lane change (_changing_lanes)
        "lane_keeping_correct": int((lane_keep or [0, 0])[0]),
        "lane_keeping_assigned": int((lane_keep or [0, 0])[1]),
    }


def evaluate(sc, *, seed: int | None = None, frames: int | None = None, events: int | None = None,
             config: Any = None, progress: bool = False, record_tracks: str | Path | None = None,
             world: tuple | None = None) -> dict:
    """The report of the module docstring. ``record_tracks``: also write the traffic layer's input and the true
    crossings there (:mod:`edge.evaluation.track_log`, for ``radar-edge replay-traffic``). ``world``: the
    ``(scene, simulator)`` of ``sc`` and ``seed`` to use (e.g. a :class:`hw_sim.simulator.FrameCache` shared by
    several evaluations of one recording); built here by default."""
    from edge.config import load_config
    from hw_sim.simulator import FrameSimulator

    if config is None:
        config = load_config(env={})
    seed = sc.seed if seed is None else seed
    board = sc.sim_board()
    fe = board.frontend
    period = fe.waveform.frame_period_s
    n_frames = frames if frames else max(1, int(round(sc.duration_s / period)))
    if world is None:
        scene = sc.build_scene(seed)
        sim = FrameSimulator(board, scene, seed)
    else:
        scene, sim = world
    lane_cfg, track_cfg, traffic_cfg = _installer_config(config, sc)
    pipe = LanePipeline(fe, lane_cfg, track_cfg, traffic_cfg)
    recorder = None
    if record_tracks is not None:
        if pipe.traffic is None:
            raise ValueError("--record-tracks records the traffic layer's input, but tracking is off in this "
                             "configuration")
        recorder = pipe.traffic_tap = TrackLogRecorder()
    by_id = {tg.id: tg for tg in scene.targets}
    half_fov = math.radians(fe.fov_deg / 2.0)
    line = traffic_cfg.detection_line_m
    n_lanes = max(len(sc.lanes), len(traffic_cfg.lane_centers_m))

    timer = StageTimer(window=max(n_frames, 16))
    frame_ms = np.zeros(n_frames)
    sim_ms = np.zeros(n_frames)
    cpu_ms = np.zeros(n_frames)
    acc: dict[int, _TargetAcc] = {}
    episodes: dict[int, list[int]] = {}  # track id -> [start frame, last frame, frames, assigned frames]
    closed_eps: list[list[int]] = []
    lane_ok = lane_n = 0
    lane_keep = [0, 0]  # lane_ok and lane_n over the frames of vehicles outside a lane change (_changing_lanes)
    sq_200 = [0.0, 0, 0.0]  # position squared error (m^2) summed over assigned frames within TALLY_RANGE_M, their
    # number, and the squared error summed in the road frame (_tallies)
    yaw_true = math.radians(scene.pose.yaw_deg)
    range_bins: dict[int, list[float]] = {}
    pd_bins: dict[int, list[int]] = {}  # range bin -> [in view, detected, tracked]
    pd_cls_bins: dict[tuple[str, int], list[int]] = {}  # (class, range bin) -> [in view, detected, tracked]
    tally = CountTally(n_lanes)  # what the traffic layer counted at its detection line
    prev_s: dict[int, float] = {}
    true_cross: list[tuple[int, float, int, str, int]] = []  # (lane, t_s, vehicle id, class, _straddled_lane)
    events: list[dict] = []
    # wrong-way scoring: the scenario's lane directions (+1 away from the radar), the vehicle each event's
    # track followed when it was raised
    lane_dir = [1 if ln.direction == "away" else -1 for ln in sc.lanes]
    ww_event_vehicle: list[tuple[int | None, float, float | None]] = []
    stop_event_vehicle: list[tuple[int | None, float, float | None]] = []
    # range-Doppler-beam overlap of vehicles: the waveform's beat model, FFT bin widths and the array's
    # Rayleigh beamwidth lambda / (N d)
    pair_model = PairingModel.from_waveform(fe.waveform)
    bin_hz = np.array([sg.sample_rate_hz / sg.n_samples for sg in fe.waveform.segments])
    beamwidth = fe.waveform.wavelength_m / (fe.n_rx * fe.rx_spacing_m)
    pd_overlap: dict[tuple[str, bool], list[int]] = {}  # (class, overlapping) -> [in view, tracked]
    visible = [0, 0]  # separate and not shadowed: [in view, tracked]
    # per-lane interval truth (edge.evaluation.lane_intervals) and the traffic layer's closed interval records
    class_edges, class_names = tuple(traffic_cfg.length_class_edges_m), tuple(traffic_cfg.length_class_names)
    itruth = LaneIntervalTruth(n_lanes, line, traffic_cfg.presence_zone_m, traffic_cfg.interval_s,
                               tuple(lane_dir) + (1,) * (n_lanes - len(lane_dir)), class_edges, class_names)
    interval_records = []

    it = range(n_frames)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc=f"evaluate {sc.name}", unit="frame")
    for n in it:
        t0 = time.perf_counter()
        f = sim.frame(n)
        t1 = time.perf_counter()
        frame = RawFrame(n, int(round(f.t_s * 1e9)), f.i, f.q, fe, f.truth)
        c1 = time.thread_time()
        res = pipe.process(frame, timer)
        t2 = time.perf_counter()
        cpu_ms[n] = (time.thread_time() - c1) * 1e3
        sim_ms[n], frame_ms[n] = (t1 - t0) * 1e3, (t2 - t1) * 1e3
        yaw_in_use = pipe.traffic.yaw_rad if pipe.traffic is not None else math.radians(traffic_cfg.mounting_yaw_deg)
        new_events = res.events
        for ev in new_events:
            events.append({"kind": ev.kind, "track_id": ev.track_id, "lane": ev.lane, "t_s": round(f.t_s, 3)})
        tally.add_frame(res.lane_stats, pipe.traffic)
        interval_records.extend(res.lane_stats)

        tr = f.truth
        veh = [k for k in range(len(tr)) if tr.cls[k] != "clutter"]
        ids = tr.id[veh]
        ref_w = np.array([by_id[i].near_face_point(f.t_s) if hasattr(by_id[i], "near_face_point") else tr.position_m[k]
                          for i, k in zip(ids, veh)]).reshape(-1, 3)
        ref = _to_radar_ground(scene.pose, ref_w)
        vel = tr.velocity_mps[veh]
        speed_kmh = np.hypot(vel[:, 0], vel[:, 1]) * 3.6
        lanes = tr.lane[veh]
        ground_rng = np.hypot(ref[:, 0], ref[:, 1])
        in_view = (ground_rng >= MIN_RANGE_M) & (ground_rng <= MAX_RANGE_M) & (
            np.abs(np.arctan2(ref[:, 0], ref[:, 1])) <= half_fov)
        lengths = np.array([getattr(by_id[i], "length_m", 0.0) for i in ids])
        gate = GATE_M + lengths
        overlap = _overlapping(pair_model, bin_hz, np.linalg.norm(ref_w - scene.pose.position, axis=1), lengths,
                               tr.radial_speed_mps[veh], tr.az_rad[veh], beamwidth)
        shadowed = None if getattr(tr, "shadowed_fraction", None) is None else tr.shadowed_fraction[veh]

        # true crossings of the detection line by the reference points (world y along the road; lanes run along
        # y): the point the tracks follow, so a vehicle whose near face has crossed as the run ends (or had as it
        # began) is counted by both or neither
        ref_y = ref_w[:, 1] - scene.pose.y_m
        if lane_dir:
            itruth.add_frame(float(f.t_s), ids, lanes, ref_y, tr.position_m[veh][:, 1] - scene.pose.y_m, lengths,
                             np.hypot(vel[:, 0], vel[:, 1]))
        for j, i in enumerate(ids):
            s_prev = prev_s.get(int(i))
            # in the lane's direction of travel: the volume the traffic layer counts (a wrong-way driver is an
            # event)
            if (s_prev is not None and (s_prev - line) * (ref_y[j] - line) < 0 and 0 <= lanes[j] < n_lanes
                    and (ref_y[j] - s_prev) * lane_dir[lanes[j]] > 0):
                true_cross.append((int(lanes[j]), float(f.t_s), int(i), tr.cls[veh[j]],
                                   _straddled_lane(float(ref_w[j, 0]), float(getattr(by_id[int(i)], "width_m", 0.0)),
                                                   int(lanes[j]), sc.lanes)))
            prev_s[int(i)] = float(ref_y[j])

        tracks = [t for t in res.tracks if t.confirmed and t.track_id > 0]
        tpos = np.array([[t.x_m, t.y_m] for t in tracks]).reshape(-1, 2)
        assigned_track = np.full(len(ids), -1)
        t_assigned = np.zeros(len(tracks), bool)
        if len(tracks) and len(ids):
            dist = np.linalg.norm(ref[:, None, :] - tpos[None, :, :], axis=2)
            cost = np.where(dist <= gate[:, None], dist, 1e6)
            r_i, c_i = linear_sum_assignment(cost)
            ok = cost[r_i, c_i] < 1e6
            assigned_track[r_i[ok]] = c_i[ok]
            t_assigned[c_i[ok]] = True
        for ev in new_events:
            if ev.kind in ("wrong_way", "stopped_vehicle"):
                k_tr = [k for k, t in enumerate(tracks) if t.track_id == ev.track_id]
                hit = [j for j in range(len(ids)) if k_tr and assigned_track[j] == k_tr[0]]
                (ww_event_vehicle if ev.kind == "wrong_way" else stop_event_vehicle).append(
                    (int(ids[hit[0]]), float(f.t_s), float(ground_rng[hit[0]])) if hit else (None, float(f.t_s), None))
        det_xy = np.stack([res.detections.x_m, res.detections.y_m], axis=1).astype(np.float64)

        for j, i in enumerate(ids):
            a = acc.get(int(i))
            if a is None:
                a = acc[int(i)] = _TargetAcc(tr.cls[veh[j]], getattr(by_id[int(i)], "kind", ""), float(lengths[j]))
            if not in_view[j]:
                continue
            a.n_view += 1
            if 0 <= lanes[j] < len(lane_dir) and vel[j, 1] * lane_dir[lanes[j]] < -WRONG_WAY_TRUE_MPS:
                a.wrong_frames += 1
                if a.wrong_first_t is None:
                    a.wrong_first_t = float(f.t_s)
            if 0 <= lanes[j] < len(lane_dir) and speed_kmh[j] < STOPPED_TRUE_MPS * 3.6:
                if a.stand_since_t is None:
                    a.stand_since_t = float(f.t_s)
                if a.stopped_t is None and f.t_s - a.stand_since_t >= STOPPED_TRUE_S - 1e-9:
                    a.stopped_t = a.stand_since_t
            else:
                a.stand_since_t = None
            rb = pd_bins.setdefault(int(ground_rng[j] // RANGE_BIN_M), [0, 0, 0])
            rc = pd_cls_bins.setdefault((a.cls, int(ground_rng[j] // RANGE_BIN_M)), [0, 0, 0])
            ro = pd_overlap.setdefault((a.cls, bool(overlap[j])), [0, 0])
            # separate and not mostly shadowed by another vehicle's body (the truth's shadowed_fraction)
            rv = visible if not overlap[j] and not (shadowed is not None and shadowed[j] >= SHADOWED_SHARE) else None
            rb[0] += 1
            rc[0] += 1
            ro[0] += 1
            if rv is not None:
                rv[0] += 1
            a.lanes.append(int(lanes[j]))
            a.dir_true += float(tr.radial_speed_mps[veh[j]])
            if det_xy.shape[0] and np.min(np.linalg.norm(det_xy - ref[j], axis=1)) <= gate[j]:
                a.n_raw += 1
                rb[1] += 1
                rc[1] += 1
            k = assigned_track[j]
            if k < 0:
                continue
            rb[2] += 1
            rc[2] += 1
            ro[1] += 1
            if rv is not None:
                rv[1] += 1
            t = tracks[k]
            if t.length_m is not None:
                a.len_pub = t.length_m
            if t.cls is not None:
                a.cls_pub = t.cls
            if a.first_hit < 0:
                a.first_hit = a.n_view - 1
            a.last_hit = a.n_view - 1
            a.n_hit += 1
            exy = tpos[k] - ref[j]
            e2 = float(np.sum(exy**2))
            a.sq_err.append(e2)
            a.err_rng.append(float(ground_rng[j]))
            a.err_xy.append((float(exy[0]), float(exy[1])))
            range_bins.setdefault(int(ground_rng[j] // RANGE_BIN_M), []).append(e2)
            if ground_rng[j] <= TALLY_RANGE_M:
                sq_200[0] += e2
                sq_200[1] += 1
                sq_200[2] += _road_sq_error(tpos[k], ref[j], yaw_in_use, yaw_true)
            a.spd_err.append(abs(t.speed_mps * 3.6 - speed_kmh[j]))
            a.vr_true.append(float(tr.radial_speed_mps[veh[j]]) * 3.6)
            a.vr_est.append(t.radial_speed_mps * 3.6)
            if a.last_id is not None and a.last_id != t.track_id:
                a.switches += 1
            a.last_id = t.track_id
            lane_n += 1
            ok = int(t.lane is not None and t.lane == lanes[j])
            lane_ok += ok
            a.lane_ok += ok
            if not _changing_lanes(by_id[int(i)], f.t_s):
                lane_keep[0] += ok
                lane_keep[1] += 1

        t_rng = np.hypot(tpos[:, 0], tpos[:, 1])
        t_in_view = (t_rng >= MIN_RANGE_M) & (t_rng <= MAX_RANGE_M) & (np.abs(np.arctan2(tpos[:, 0], tpos[:, 1])) <= half_fov)
        for k, t in enumerate(tracks):
            ep = episodes.get(t.track_id)
            if ep is None or ep[1] != n - 1:
                if ep is not None:
                    closed_eps.append(ep)
                ep = episodes[t.track_id] = [n, n, 0, 0, t.track_id, t.x_m, t.y_m]
            ep[1] = n
            ep[2] += int(t_in_view[k])
            ep[3] += int(t_assigned[k] and t_in_view[k])
    closed_eps.extend(episodes.values())
    tally.close(pipe.traffic)  # the crossings of the open interval
    counts = tally.summary(true_cross)

    duration_min = n_frames * period / 60.0
    false_eps = [ep for ep in closed_eps if ep[2] > 0 and ep[3] < 0.5 * ep[2]]
    false_tracks = len(false_eps)
    n_start = min(n_frames, int(math.ceil(START_S / period - 1e-9)))  # frames of the first START_S seconds
    targets = []
    for i, a in sorted(acc.items()):
        if a.n_view == 0:
            continue
        lane = int(np.bincount(np.array(a.lanes) + 1).argmax()) - 1 if a.lanes else -1
        targets.append({
            "id": i,
            "class": a.cls,
            "lane": None if lane < 0 else lane,
            "frames_in_view": a.n_view,
            "tracked_fraction": a.n_hit / a.n_view,
            "detected_fraction_raw": a.n_raw / a.n_view,
            # its untracked in-view frames: before its first track (acquisition), between tracks, after its last
            "untracked_frames": dict(zip(("before_first", "gaps", "after_last"), a.missed_phases())),
            "position_rmse_m": float(math.sqrt(np.mean(a.sq_err))) if a.sq_err else None,
            "position_rmse_m_within": _rmse_within(a.sq_err, a.err_rng),
            # the error split into a bias (mean) and a noise (sd), across (x) and along (y) the boresight:
            # rmse^2 = |bias|^2 + sd_x^2 + sd_y^2
            "position_bias_xy_m": ([round(float(v), 4) for v in np.mean(a.err_xy, axis=0)] if a.err_xy else None),
            "position_sd_xy_m": ([round(float(v), 4) for v in np.std(a.err_xy, axis=0)] if a.err_xy else None),
            "speed_mae_kmh": float(np.mean(a.spd_err)) if a.spd_err else None,
            "id_switches": a.switches,
            "lane_accuracy": a.lane_ok / a.n_hit if a.n_hit else None,
            "predicted_class": None,
            "kind": a.kind,
            "length_m_true": a.length_m if a.length_m > 0 else None,
            "length_m_est": a.len_pub,
            "length_class_true": length_class(a.length_m, class_edges, class_names) if a.length_m > 0 else None,
            "length_class_est": a.cls_pub,
            "direction_true": "receding" if a.dir_true > 0 else "approaching",
            "direction_est": (None if not a.vr_est else ("receding" if np.mean(a.vr_est) > 0 else "approaching")),
            "mean_radial_speed_kmh_true": float(np.mean(a.vr_true)) if a.vr_true else None,
            "mean_radial_speed_kmh_est": float(np.mean(a.vr_est)) if a.vr_est else None,
        })
    n_view = sum(a.n_view for a in acc.values())
    n_hit = sum(a.n_hit for a in acc.values())
    n_raw = sum(a.n_raw for a in acc.values())
    rmses = [t["position_rmse_m"] for t in targets if t["position_rmse_m"] is not None]
    within: dict[str, list[float]] = {}
    for t in targets:
        for k, v in t["position_rmse_m_within"].items():
            within.setdefault(k, []).append(v)
    spd = [e for a in acc.values() for e in a.spd_err]
    summary = {
        "position_rmse_m_mean": float(np.mean(rmses)) if rmses else None,
        "position_rmse_m_max": float(np.max(rmses)) if rmses else None,
        "position_rmse_m_max_within": {k: float(max(v)) for k, v in sorted(within.items(),
                                                                            key=lambda kv: float(kv[0]))},
        "speed_mae_kmh": float(np.mean(spd)) if spd else None,
        "detection_probability": n_hit / n_view if n_view else None,
        "detection_probability_raw": n_raw / n_view if n_view else None,
        "min_tracked_fraction": min((t["tracked_fraction"] for t in targets), default=None),
        "false_tracks_per_min": false_tracks / duration_min if duration_min > 0 else None,
        "false_tracks": false_tracks,
        # where the false tracks were confirmed (radar ground frame), for diagnosis
        "false_track_episodes": [{"track_id": int(ep[4]), "first_frame": int(ep[0]), "frames": int(ep[1] - ep[0] + 1),
                                  "x_m": round(float(ep[5]), 2), "y_m": round(float(ep[6]), 2)}
                                 for ep in closed_eps if ep[2] > 0 and ep[3] < 0.5 * ep[2]],
        "id_switches": int(sum(a.switches for a in acc.values())),
        "lane_accuracy": lane_ok / lane_n if lane_n else None,
        "lane_accuracy_keeping": lane_keep[0] / lane_keep[1] if lane_keep[1] else None,
        "lane_accuracy_changing": ((lane_ok - lane_keep[0]) / (lane_n - lane_keep[1]) if lane_n > lane_keep[1]
                                   else None),
        "count_error_per_lane": counts["count_error_per_lane"],
        "volume_true_per_lane": counts["volume_true_per_lane"],
        "volume_measured_per_lane": counts["volume_measured_per_lane"],
        "volume_measured_either_per_lane": counts["volume_measured_either_per_lane"],
        # which crossings make the count errors: per lane, true and counted crossings matched one-to-one by time
        # (within COUNT_MATCH_S); the unmatched ones, for diagnosis (counts of the open interval included), and the
        # straddling vehicles counted in the lane they straddled into
        "count_mismatches": counts["count_mismatches"],
        "rmse_by_range_m": {f"{int(k * RANGE_BIN_M)}-{int((k + 1) * RANGE_BIN_M)}": float(math.sqrt(np.mean(v)))
                            for k, v in sorted(range_bins.items())},
        "detection_probability_by_range": {
            f"{int(k * RANGE_BIN_M)}-{int((k + 1) * RANGE_BIN_M)}": {"tracked": v[2] / v[0], "raw": v[1] / v[0]}
            for k, v in sorted(pd_bins.items())},
        # per ground-truth class (cars include vans: hw_sim.vehicles.BODY_TYPES), all ranges and per range bin
        "detection_probability_by_class": {
            c: sum(v[2] for (cc, _), v in pd_cls_bins.items() if cc == c) / sum(v[0] for (cc, _), v in pd_cls_bins.items()
                                                                                 if cc == c)
            for c in sorted({cc for cc, _ in pd_cls_bins})},
        "detection_probability_by_class_and_range": {
            c: {f"{int(k * RANGE_BIN_M)}-{int((k + 1) * RANGE_BIN_M)}": {"tracked": v[2] / v[0], "raw": v[1] / v[0]}
                for (cc, k), v in sorted(pd_cls_bins.items()) if cc == c}
            for c in sorted({cc for cc, _ in pd_cls_bins})},
        # per class, the untracked in-view frames summed by phase (acquisition after entering the view, gaps
        # between tracks, loss before leaving it): which of the three a lower detection probability comes from
        "untracked_frames_by_class": {
            c: dict(zip(("before_first", "gaps", "after_last"),
                        (int(v) for v in np.sum([a.missed_phases() for a in acc.values() if a.cls == c and a.n_view],
                                                 axis=0))))
            for c in sorted({a.cls for a in acc.values() if a.n_view})},
        # per class, the detection probability apart from and while overlapping another vehicle in range,
        # Doppler and beam (module doc), and the share of in-view frames that overlap
        "detection_probability_by_overlap": {c: _overlap_summary(pd_overlap.get((c, False)), pd_overlap.get((c, True)))
                                             for c in sorted({cc for cc, _ in pd_overlap})},
        "vehicles_in_view": len(targets),
        "estimated_yaw_deg": math.degrees(pipe.traffic.yaw_rad) if pipe.traffic is not None else None,
        "true_yaw_deg": float(scene.pose.yaw_deg),
        # lanes in use at the end (configured, or learned with traffic.lane_mode = "learned"), road frame
        "lane_mode": traffic_cfg.lane_mode,
        "lane_centers_m": ([round(ln.center_m, 3) for ln in pipe.traffic.lanes] if pipe.traffic is not None else None),
        "lane_centers_true_m": [round(ln.center_x_m - sc.pose.x_m, 3) for ln in sc.lanes],
        "events": events,
        # wrong-way alarms against the truth: a vehicle driving against its lane for WRONG_WAY_TRUE_FRAMES
        # frames in view is a wrong-way driver; an alarm is correct when its track followed one
        "wrong_way": _wrong_way_score(acc, ww_event_vehicle) if lane_dir else None,
        "stopped_vehicle": _stopped_score(acc, stop_event_vehicle) if lane_dir else None,
        "classification_accuracy": None,
        "confusion_matrix": None,
        "false_tracks_first_30s": sum(1 for ep in false_eps if ep[0] < n_start),
        "false_tracks_near": _near_count(false_eps),
        # sums and counts behind the figures, for pooling runs as ratios of sums (edge.evaluation.corpus)
        "tallies": _tallies(acc, pd_overlap, false_eps, n_start, n_frames, period, counts, sq_200, lane_ok, lane_n,
                            visible, lane_keep),
    }
    if lane_dir:
        # per-lane interval statistics against the truth, and the lengths and classes of the vehicles that crossed
        crossed = {c[2] for c in true_cross}
        summary["intervals"] = score_intervals(interval_records, itruth.intervals(), itruth.t0_s or 0.0,
                                               traffic_cfg.interval_s, class_names)
        summary["vehicle_lengths"] = score_vehicles(
            [t for t in targets if t["id"] in crossed and t["length_m_true"] is not None], class_names)
    budget_ms = period * 1e3
    track_log = None
    if recorder is not None:
        meta = {"scenario": sc.name, "seed": seed, "frames": n_frames, "frame_period_s": period, "n_lanes": n_lanes,
                "traffic": dataclasses.asdict(traffic_cfg), "counts": counts, "events": events}
        track_log = str(recorder.save(record_tracks, meta, true_cross))
    return {
        "scenario": sc.name,
        "profile": "lane",
        "seed": seed,
        "frames": n_frames,
        "track_log": track_log,
        "targets": targets,
        "summary": summary,
        "frame_time_ms": {
            "p50": float(np.percentile(frame_ms, 50)),
            "p99": float(np.percentile(frame_ms, 99)),
            "budget": budget_ms,
            "p99_budget_fraction": float(np.percentile(frame_ms, 99)) / budget_ms,
        },
        # CPU time of the pipeline thread: the same figure without the scheduling noise of a busy host
        "frame_cpu_time_ms": {"p50": float(np.percentile(cpu_ms, 50)), "p99": float(np.percentile(cpu_ms, 99))},
        "simulation_time_ms": {"p50": float(np.percentile(sim_ms, 50)), "p99": float(np.percentile(sim_ms, 99))},
        "stages_ms": {k: {"p50": v["p50_ms"], "p99": v["p99_ms"]} for k, v in timer.summary().items()},
    }
