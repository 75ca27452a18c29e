"""The traffic layer of the lane profile: lanes, presence, interval statistics and events per frame.

Public API (stable; used by ``edge.pipelines.lane``)::

    from edge.traffic import TrafficConfig, TrafficMonitor
    monitor = TrafficMonitor(cfg.section("traffic"))
    upd = monitor.update(tracks, t_ns)   # tracks: tuple[TrackState, ...] from edge.track
    upd.tracks        # the same tracks with ``lane``, ``length_m`` and ``cls`` set (None: off every lane, not measured)
    upd.presence      # tuple[bool, ...], one flag per lane: a vehicle overlaps the presence zone
    upd.lane_stats    # tuple[LaneStats, ...], non-empty on the frame that closes an interval
    upd.events        # tuple[TrafficEvent, ...]: wrong_way, stopped_vehicle (once per occurrence)
    monitor.lanes     # current tuple[Lane, ...] (configured or learned; empty until learned)
    monitor.yaw_rad   # mounting yaw in use (configured until estimated)
    monitor.yaw_sigma_rad  # its uncertainty (mounting_yaw_sigma_deg until estimated; 0 if not estimated)
    monitor.close()   # with traffic.calibration_file: save the self-calibration (edge.traffic.calibration)

Lane indices are 0-based, ordered like the scenario's ``[[lane]]`` tables (left to right when
learned). Only confirmed tracks are used. Per-track memory is keyed by ``track_id`` and reset when an
id is recycled (its ``age_frames`` drops).

Counting (volume at the detection line, one count per vehicle however its tracks behave): a confirmed track
crossing the line in its lane's direction of travel is counted at the interpolated crossing time, unless the
track was counted already (``count_once_per_track``: a track that jumped back behind the line and crossed it
again is still one vehicle). The volume is the lane's direction of travel: a track crossing against it is not
counted, a wrong-way driver is an event. A track first seen up to ``count_late_max_m`` past the line counts its
vehicle at the crossing time extrapolated back at its along-road speed, unless a crossing of about that time and
speed was counted in the lane (``count_late_match_*``: the same vehicle's earlier track), and not if that time lies
before the monitor's first frame. No ground truth is used: the rules rest on what one vehicle's tracks can look
like.

Lengths and classes: each confirmed track's length is measured from the body extents the lane pipeline finds
behind its detections (``update(..., extent_m=...)``; :class:`edge.traffic.stats.LengthMeter`); the tracks returned
carry it in ``length_m`` and its length class (``length_class_names``) in ``cls``, both None until measured (a
track's own ``cls``, from a classifier, is kept). Interval records read the lengths when the interval closes.

Events: ``wrong_way`` when a track in a lane moves against the lane's direction faster than
``wrong_way_min_speed_mps`` for ``wrong_way_min_frames`` frames in a row (once per track), counting
only frames with a detection where its lane is sure (``wrong_way_lane_sigmas`` times range x the yaw's and the
tracks' azimuth uncertainty inside the lane: no alarms from a neighbouring lane while the yaw self-calibrates,
nor from a far track whose lateral position is metres off); not again for a track within
``wrong_way_same_driver_m`` and ``wrong_way_same_driver_speed_mps`` of one that raised it and still runs (the same
driver's second track);
``stopped_vehicle`` when a track that once moved faster than ``moving_speed_mps`` stands (slower than
``stopped_speed_mps``) in a lane for ``stopped_min_s`` (again only after it moved off).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np

from edge import native
from edge.fastinit import one_dict_init
from edge.traffic.calibration import Calibration, CalibrationError, CalibrationWriter, load_calibration
from edge.traffic.config import TrafficConfig
from edge.traffic.lanes import (Lane, LaneLearner, YawEstimator, align_yaw, assign_lanes_with_margin,
                                configured_lanes)
from edge.traffic.stats import Crossing, IntervalStatistics, LengthMeter
from edge.types import LaneStats, TrackState, TrafficEvent

log = logging.getLogger(__name__)

#: the start-up alignment of the tracks to configured lanes (lanes.align_yaw) runs this often
_ALIGN_EVERY_NS = 200_000_000

__all__ = ["TrafficMonitor", "TrafficUpdate"]


@one_dict_init
@dataclass(frozen=True)
class TrafficUpdate:
    tracks: tuple[TrackState, ...]
    presence: tuple[bool, ...]
    lane_stats: tuple[LaneStats, ...]
    events: tuple[TrafficEvent, ...]


@dataclass
class _Memo:
    age: int
    s_m: float
    t_ns: int
    max_speed_mps: float
    wrong_frames: int = 0
    wrong_emitted: bool = False
    hits: int = -1  # the track's hit count when last seen (coasting frames add no evidence)
    stopped_since_ns: int | None = None
    stopped_emitted: bool = False
    counted: bool = False  # the track's vehicle was counted at the detection line (count_once_per_track)
    meter: LengthMeter | None = None  # its length measurement (edge.traffic.stats)


#: columns of the kernel's memo table (``_M_COLS`` wide): ``M_COUNTED`` and ``M_COLS`` of edge/native/_traffic.pyx
_M_COUNTED, _M_COLS = 9, 10

#: TrackState validates in ``__post_init__``: then only ``dataclasses.replace`` is a faithful copy
_TRACK_POST_INIT = hasattr(TrackState, "__post_init__")


def _with(tr: TrackState, lane: int | None, cls: str | None, length_m: float | None) -> TrackState:
    """``dataclasses.replace(tr, lane=lane, cls=cls, length_m=length_m)`` without its per-call field introspection
    (hot path)."""
    if _TRACK_POST_INIT:
        return dataclasses.replace(tr, lane=lane, cls=cls, length_m=length_m)
    out = object.__new__(TrackState)  # a frozen dataclass without __post_init__: copy its fields
    d = out.__dict__
    d.update(tr.__dict__)
    d["lane"] = lane
    d["cls"] = cls
    d["length_m"] = length_m
    return out


class TrafficMonitor(native.KernelUser):
    def __init__(self, config: TrafficConfig | None = None) -> None:
        self.config = cfg = config or TrafficConfig()
        self.yaw_rad = math.radians(cfg.mounting_yaw_deg)
        self.lanes: tuple[Lane, ...] = configured_lanes(cfg) if cfg.lane_mode == "configured" else ()
        self.yaw_estimator = YawEstimator(cfg)
        self._yaw_sigma_cfg = math.radians(cfg.mounting_yaw_sigma_deg)
        self.yaw_sigma_rad = 0.0 if not cfg.estimate_yaw else self._yaw_sigma_cfg
        self._yaw_se: float | None = None  # standard error of this run's yaw estimate (None: none yet)
        self._aligned: tuple[float, float] | None = None  # the last successful start-up alignment (yaw, sigma)
        self._align_due_ns = -(2**62)  # when the next one is due
        self._handed_over = False  # the ended tracks' directions gave a yaw more certain than the alignment's
        self.learner = LaneLearner(cfg)
        self.stats = IntervalStatistics(cfg)
        self._memo: dict[int, _Memo] = {}
        #: the compiled per-track work (edge.native._traffic), None: the numpy/Python reference
        self._kernel = native.load("_traffic")
        self._lane_arrays: tuple = (None,) * 4  # (lanes, centres, half widths, directions) for the kernel
        #: the kernel's memory of the tracks it follows, one row per track id (edge.native._traffic's M_* columns;
        #: mf: along-road position when last seen, largest speed) and their length meters
        self._mi = np.zeros((0, _M_COLS), dtype=np.int64)
        self._mf = np.zeros((0, 2))
        self._meters: list[LengthMeter | None] = []
        self._params: tuple = (None, None)  # (config, the kernel's parameters from it)
        self._accs: list = []  # each lane's accumulator (self.stats.lane(k)) for the kernel
        self._last_t_ns: int | None = None
        self._first_t_ns: int | None = None
        self._next_learn_ns: int | None = None
        #: the calibration saved by an earlier run, in use until this run's estimate is better
        self.saved_calibration: Calibration | None = None
        self._writer: CalibrationWriter | None = None
        self._next_save_ns: int | None = None
        if cfg.calibration_file:
            self._restore(cfg.calibration_file)
            self._writer = CalibrationWriter(cfg.calibration_file)

    def _restore(self, path: str) -> None:
        cfg = self.config
        try:
            cal = load_calibration(path)
        except CalibrationError as e:
            log.warning("traffic calibration ignored (%s): %s", path, e)
            return
        if cal is None:
            log.info("no traffic calibration in %s yet: starting uncalibrated", path)
            return
        if cal.lane_mode != cfg.lane_mode:
            log.warning("traffic calibration in %s is for lane_mode %s, configured %s: ignored", path, cal.lane_mode,
                        cfg.lane_mode)
            return
        if cfg.estimate_yaw:
            self.yaw_rad = cal.yaw_rad
            self.yaw_sigma_rad = cal.yaw_stderr_rad
        if cfg.lane_mode == "learned" and cal.lanes:
            self.lanes = cal.lanes
        self.saved_calibration = cal
        log.info("traffic calibration restored from %s: yaw %.3f +- %.3f deg, %d lanes", path,
                 math.degrees(cal.yaw_rad), math.degrees(cal.yaw_stderr_rad), len(cal.lanes))

    def calibration(self) -> Calibration:
        """What the monitor knows now (yaw in use and its uncertainty, lanes)."""
        saved = self.saved_calibration
        if saved is not None:
            se, votes = saved.yaw_stderr_rad, saved.yaw_votes
        else:
            se, votes = self._yaw_se, self.yaw_estimator.n_votes
            if se is None or not math.isfinite(se):
                se = self._yaw_sigma_cfg
        return Calibration(self.yaw_rad, se, votes, self.config.lane_mode, tuple(self.lanes))

    def close(self) -> None:
        """Save the calibration a last time (with ``calibration_file``) and stop the writer."""
        if self._writer is not None:
            if self._last_t_ns is not None:
                self._writer.submit(self.calibration())
            self._writer.close()
            self._writer = None

    def _yaw_in_use(self, est: float | None, se: float | None) -> tuple[float, float]:
        """(yaw, sigma) from this run's estimate ``est`` (its standard error ``se``) and the saved calibration: the
        saved one holds until the estimate is more certain, or is dropped when the estimate says the radar was
        re-aimed."""
        cfg = self.config
        saved = self.saved_calibration
        if saved is not None:
            settled = self.yaw_estimator.n_votes >= cfg.yaw_min_tracks
            if est is not None and settled and abs(est - saved.yaw_rad) > max(
                    math.radians(cfg.calibration_moved_deg), 3.0 * math.hypot(se, saved.yaw_stderr_rad)):
                log.warning("mounting yaw %.2f deg differs from the saved %.2f deg: radar re-aimed? saved "
                            "calibration dropped", math.degrees(est), math.degrees(saved.yaw_rad))
                self.saved_calibration = None
            elif est is None or se >= saved.yaw_stderr_rad:
                return saved.yaw_rad, saved.yaw_stderr_rad
            else:
                self.saved_calibration = None  # this run's estimate is now the better one
        if est is None:
            return self.yaw_rad, self._yaw_sigma_cfg
        return est, min(se, self._yaw_sigma_cfg)

    def set_lanes(self, lanes) -> None:
        """Replace the configured lanes, same count: ``(center_m, width_m, direction +1 away / -1 toward)`` each
        (a Modbus lane geometry apply); from the next frame on tracks are assigned to them."""
        if self.config.lane_mode != "configured" or len(lanes) != len(self.lanes):
            raise ValueError(f"lane geometry needs {len(self.lanes)} configured lanes (lane_mode "
                             f"{self.config.lane_mode}), got {len(lanes)}")
        self.lanes = tuple(Lane(float(c), float(w), 1 if d > 0 else -1) for c, w, d in lanes)
        log.info("lanes set: %s", [(round(ln.center_m, 2), round(ln.width_m, 2), ln.direction_name) for ln in self.lanes])

    @property
    def n_lanes(self) -> int:
        """Lanes known now; with learned lanes not yet learned, as many as ``lane_centers_m`` lists
        (what the outputs reserve at start)."""
        return len(self.lanes) or len(self.config.lane_centers_m)

    @staticmethod
    def _counted_near(recent, t_ns: int, speed_mps: float, tol_ns: int, dv_mps: float) -> bool:
        """One of the counted crossings ``recent`` lies within ``tol_ns`` of ``t_ns`` and ``dv_mps`` of its speed."""
        return any(abs(c.t_ns - t_ns) <= tol_ns and abs(c.speed_mps - speed_mps) < dv_mps for c in recent)

    def _count_late(self, tr: TrackState, lane: int, direction: int, s_m: float, vs_mps: float, speed_mps: float,
                    meter: LengthMeter, t_ns: int, margin_m: float) -> bool:
        """A track first seen (confirmed) past the detection line: its vehicle crossed the line untracked (its
        earlier track was lost or taken over by a neighbour just before the line and it was re-born after it;
        or it crossed while still tentative). Counted at the crossing time extrapolated back at its along-road
        speed, unless a crossing in the lane at about that time and speed was already counted (the same vehicle's
        earlier track, or a second track on a long truck). ``margin_m``: how far inside its
        lane it lies, for the longer reach of receding tracks (``count_late_receding_max_m``). Returns whether it
        was counted."""
        cfg = self.config
        ahead = (s_m - cfg.detection_line_m) * direction  # metres past the line in the direction of travel
        v_dir = vs_mps * direction
        reach = cfg.count_late_max_m
        if direction > 0 and cfg.count_late_receding_max_m > reach and margin_m >= cfg.count_late_far_margin_m:
            reach = cfg.count_late_receding_max_m
        if not (0.0 < ahead <= reach) or v_dir < cfg.moving_speed_mps:
            return False
        tc = t_ns - int(round(ahead / v_dir * 1e9))
        if self._first_t_ns is None or tc <= self._first_t_ns:  # crossed before the monitor started
            return False
        acc = self.stats.lane(lane)
        if self._counted_near(acc.recent, tc, speed_mps, int(cfg.count_late_match_s * 1e9),
                              cfg.count_late_match_speed_mps):
            return False
        acc.add(Crossing(tc, speed_mps, float("nan"), tr.cls, meter))
        return True

    def _same_wrong_way_driver(self, conf: list[TrackState], j: int, s: list[float], vs: list[float]) -> bool:
        """Whether confirmed track ``j``, qualifying for wrong_way, is within wrong_way_same_driver_m along the road
        and wrong_way_same_driver_speed_mps of another that raised it and still runs: the same driver's second
        track (a glint of its body, a new track after a loss), not a second driver."""
        cfg = self.config
        if cfg.wrong_way_same_driver_speed_mps <= 0.0:
            return False
        for i, t in enumerate(conf):
            m = self._memo.get(t.track_id)
            if (i != j and m is not None and m.wrong_emitted and t.age_frames >= m.age
                    and abs(s[i] - s[j]) <= cfg.wrong_way_same_driver_m
                    and abs(vs[i] - vs[j]) <= cfg.wrong_way_same_driver_speed_mps):
                return True
        return False

    def _pass_params(self) -> tuple:
        """The configuration's parameters of ``_traffic.monitor_pass`` (in its order)."""
        cfg = self.config
        if self._params[0] is not cfg:
            zone_lo = cfg.detection_line_m - 0.5 * cfg.presence_zone_m
            self._params = (cfg, (
                cfg.detection_line_m, cfg.length_range_m[0], cfg.length_range_m[1], cfg.default_vehicle_length_m,
                zone_lo, cfg.detection_line_m + 0.5 * cfg.presence_zone_m, zone_lo - 20.0,
                cfg.wrong_way_min_speed_mps, cfg.stopped_speed_mps, cfg.moving_speed_mps, cfg.wrong_way_same_driver_m,
                cfg.wrong_way_same_driver_speed_mps, cfg.length_min_m, cfg.wrong_way_min_frames,
                int(cfg.stopped_min_s * 1e9), cfg.length_min_frames, cfg.length_outliers + 1,
                cfg.count_late_max_m > 0, cfg.count_once_per_track))
        return self._params[1]

    def _kernel_pass(self, tracks, conf, sel, ids, id_list, kin, cy: float, sy: float, sure_k: float, ext,
                     t_ns: int, dt_ns: int) -> TrafficUpdate:
        """The per-track part of :meth:`update` with the kernel (``_traffic.monitor_pass``, the road frame and lanes
        of ``_traffic.road_lanes`` included: ``cy``, ``sy`` the yaw's cosine and sine, ``sure_k`` the wrong-way gate);
        the counting decisions that read and add the lanes' counted crossings stay here, in the reference's order.
        ``ext``: the confirmed tracks' body extents (m; None: not measured)."""
        stats = self.stats
        lanes = self.lanes
        n_lanes = len(lanes)
        accs = self._accs  # stats.lane(k) of every lane (the accumulators are made once and never replaced)
        if len(accs) != n_lanes:
            accs = self._accs = [stats.lane(k) for k in range(n_lanes)]
        params = self._params[1] if self._params[0] is self.config else self._pass_params()
        while True:
            res = self._kernel.monitor_pass(
                tracks, sel, conf, ids, self._mi, self._mf, self._meters, LengthMeter, kin, cy, sy,
                self._lane_arrays[1], self._lane_arrays[2], sure_k, self._lane_arrays[3], ext, t_ns, dt_ns, params,
                accs, stats.class_names, stats._edge_list, TrackState,
                _with if _TRACK_POST_INIT else None)
            if res is not None:
                break
            old = self._mi.shape[0]  # a track id beyond the tables: grow them
            cap = max(int(ids.max()) + 1, 2 * old, 64)
            mi, mf = np.zeros((cap, self._mi.shape[1]), dtype=np.int64), np.zeros((cap, self._mf.shape[1]))
            mi[:old], mf[:old] = self._mi, self._mf
            self._mi, self._mf = mi, mf
            self._meters.extend([None] * (cap - old))
        published, presence, raw_events, actions = res
        for a in actions:  # (few: tracks born in a lane and crossings; the track's s, vs, speed, margin last)
            j, k = a[1], a[2]
            tid = id_list[j]
            meter = self._meters[tid]
            if a[0] == 0:
                self._mi[tid, _M_COUNTED] = self._count_late(conf[j], k, lanes[k].direction, a[3], a[4], a[5],
                                                             meter, t_ns, a[6])
            else:
                stats.lane(k).add(Crossing(a[3], a[6], float("nan"), conf[j].cls, meter))
                self._mi[tid, _M_COUNTED] = 1
        start = stats.start_ns  # (stats.tick returns () before the interval's end: not called then)
        closed = () if start is not None and t_ns < start + stats.interval_ns else stats.tick(t_ns, n_lanes)
        events = tuple(TrafficEvent(kind, tid, lane, t_ns) for kind, tid, lane in raw_events) if raw_events else ()
        return TrafficUpdate(published, tuple(presence), closed, events)

    def update(self, tracks: tuple[TrackState, ...], t_ns: int, yaw_x_m: np.ndarray | None = None,
               extent_m: np.ndarray | None = None) -> TrafficUpdate:
        """``yaw_x_m``: per track of ``tracks`` the across-boresight position the yaw estimator takes instead of
        ``x_m`` (the motion model's, when the published one comes from a filter that assumes the road direction:
        ``track.pdaf.lateral_smoother``; its tracks would vote for the yaw they assumed). ``extent_m``: per track
        the along-road extent of the body behind its detection this frame (NaN without one; the lane pipeline's
        ``body_extent_m``): the tracks' lengths are measured from it (without it, lengths and classes stay n/a)."""
        cfg = self.config
        kern = self._kernel
        if kern is not None:
            tracks = tuple(tracks)
            # (the motion model's x and the extents of the confirmed tracks gathered with the table when they are
            # float64 arrays with a value per track; else None)
            conf, sel, kin, ids, id_list, yaw_x_sel, ext_sel = kern.track_kin(tracks, yaw_x_m, extent_m, TrackState)
        else:
            sel = [k for k, t in enumerate(tracks) if t.confirmed and t.track_id > 0]
            conf = [tracks[k] for k in sel]
        dt_ns = 0 if self._last_t_ns is None else max(t_ns - self._last_t_ns, 0)
        dt_ns = min(dt_ns, 1_000_000_000)  # a stall does not count as occupied time
        self._last_t_ns = t_ns
        if self._first_t_ns is None:
            self._first_t_ns = t_ns
        # one (n, 6) array: track id, age, x, y, vx, vy (ids and ages are exact in float64)
        if kern is None:
            kin = np.array([(t.track_id, t.age_frames, t.x_m, t.y_m, t.vx_mps, t.vy_mps) for t in conf],
                           dtype=np.float64).reshape(-1, 6)
            ids = kin[:, 0].astype(np.int64)
            age = kin[:, 1].astype(np.int64)
            x, y, vx, vy = kin[:, 2], kin[:, 3], kin[:, 4], kin[:, 5]

        # mounting yaw and lanes
        est = None
        yaw_sigma = 0.0  # the configured yaw is taken as measured when it is not estimated
        if cfg.estimate_yaw:
            if kern is not None:
                if yaw_x_sel is None and yaw_x_m is not None and len(yaw_x_m) == len(tracks):
                    yaw_x_sel = np.asarray(yaw_x_m, dtype=np.float64)[sel]
                self.yaw_estimator.add_table(kin, yaw_x_sel)
            elif yaw_x_m is not None and len(yaw_x_m) == len(tracks):
                yaw_x_sel = np.asarray(yaw_x_m, dtype=np.float64)[sel]
                self.yaw_estimator.add(ids, age, yaw_x_sel, y)
            else:
                yaw_x_sel = None
                self.yaw_estimator.add(ids, age, x, y)
            est = self.yaw_estimator.estimate_rad()
            se = self.yaw_estimator.stderr_rad if est is not None else None
            settled = self.yaw_estimator.n_votes >= cfg.yaw_min_tracks
            aligning = (cfg.lane_mode == "configured" and bool(self.lanes) and self.saved_calibration is None
                        and not self._handed_over)
            if aligning and settled and (self._aligned is None or se <= self._aligned[1]):
                self._handed_over, aligning = True, False  # the ended tracks' directions are the more certain yaw
                if self._aligned is not None:
                    log.info("mounting yaw from the tracks' directions now (%.3f +- %.3f deg; in lanes "
                             "%.3f +- %.3f deg)", math.degrees(est), math.degrees(se),
                             *(math.degrees(a) for a in self._aligned))
            if aligning:
                # start-up with configured lanes: the yaw that puts this frame's tracks into them (lanes.align_yaw), at
                # the motion model's positions as for the votes (the published ones follow the yaw assumed so far)
                # (every frame until the first succeeds, then five times a second: the yaw does not change between),
                # until the ended tracks' directions give a yaw at least as certain
                if t_ns >= self._align_due_ns:
                    moving = np.abs(kin[:, 5]) >= cfg.moving_speed_mps
                    aligned = align_yaw(kin[:, 2] if yaw_x_sel is None else yaw_x_sel, kin[:, 3],
                                        np.where(moving, np.sign(kin[:, 5]), 0.0), self.lanes,
                                        math.radians(cfg.mounting_yaw_deg), 5.0 * self._yaw_sigma_cfg, cfg.yaw_min_tracks)
                    if aligned is not None:
                        self._aligned = aligned
                        self._align_due_ns = t_ns + _ALIGN_EVERY_NS
                if self._aligned is not None and (not settled or se > self._aligned[1]):
                    est, se = self._aligned
            self._yaw_se = se
            self.yaw_rad, yaw_sigma = self._yaw_in_use(est, se)
        self.yaw_sigma_rad = yaw_sigma
        if self._writer is not None:
            if self._next_save_ns is None:
                self._next_save_ns = t_ns + int(cfg.calibration_save_every_s * 1e9)
            elif t_ns >= self._next_save_ns:
                self._next_save_ns = t_ns + int(cfg.calibration_save_every_s * 1e9)
                if est is not None or self.saved_calibration is not None or (cfg.lane_mode == "learned" and self.lanes):
                    self._writer.submit(self.calibration())
        if cfg.lane_mode == "learned":
            self.learner.add(kin[:, 2], kin[:, 3], kin[:, 4], kin[:, 5])
            if self._next_learn_ns is None or t_ns >= self._next_learn_ns:
                yaw_ready = not cfg.estimate_yaw or est is not None or self.saved_calibration is not None
                lanes = self.learner.learn(self.yaw_rad) if yaw_ready else ()
                if lanes:
                    self.lanes = lanes
                    self._next_learn_ns = t_ns + int(cfg.relearn_every_s * 1e9)
                    log.info("lanes learned: %s (yaw %.2f deg)", [(round(l.center_m, 2), l.direction_name)
                                                                    for l in lanes], math.degrees(self.yaw_rad))

        lanes = self.lanes
        n_lanes = len(lanes)

        # the road frame (to_road's operations; of the velocities only the along-road part is used)
        cy, sy = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        # wrong-way gate: the track is wrong_way_lane_sigmas standard deviations inside its lane, the lateral
        # uncertainty being range x the yaw's (a wrong yaw turns the road frame about the radar) and the track's
        # own azimuth error's
        lat_sigma = math.hypot(yaw_sigma, math.radians(cfg.wrong_way_azimuth_sigma_deg))
        gated = lat_sigma > 0.0 and cfg.wrong_way_lane_sigmas > 0.0
        if kern is not None:
            if self._lane_arrays[0] is not lanes:  # (the lanes change rarely)
                self._lane_arrays = (lanes, np.array([ln.center_m for ln in lanes], dtype=np.float64),
                                     0.5 * np.array([ln.width_m for ln in lanes], dtype=np.float64),
                                     np.array([ln.direction for ln in lanes], dtype=np.int64))
            if ext_sel is None and extent_m is not None and len(extent_m) == len(tracks):
                ext_sel = np.ascontiguousarray(np.asarray(extent_m, dtype=np.float64)[sel])
            return self._kernel_pass(tracks, conf, sel, ids, id_list, kin, cy, sy,
                                     cfg.wrong_way_lane_sigmas * lat_sigma if gated else -1.0, ext_sel, t_ns, dt_ns)
        u, s_arr = x * cy + y * sy, -x * sy + y * cy
        vs_arr = -vx * sy + vy * cy
        # plain Python floats for the per-track loop (numpy scalars are slow one at a time)
        s, vs = s_arr.tolist(), vs_arr.tolist()
        speed = np.hypot(vx, vy).tolist()
        lane_idx, margin = assign_lanes_with_margin(u, lanes)
        sure = lane_idx >= 0
        if gated:
            sure &= margin >= cfg.wrong_way_lane_sigmas * lat_sigma * np.hypot(x, y)
        lane_sure = sure.tolist()
        lane_idx = lane_idx.tolist()
        id_list = ids.tolist()
        presence = [False] * n_lanes
        ext = None
        if extent_m is not None and len(extent_m) == len(tracks):
            ext = np.asarray(extent_m, dtype=np.float64)[sel].tolist()
        r_lo, r_hi = cfg.length_range_m
        stats = self.stats
        default_length = cfg.default_vehicle_length_m
        zone_lo = cfg.detection_line_m - 0.5 * cfg.presence_zone_m
        zone_hi = cfg.detection_line_m + 0.5 * cfg.presence_zone_m
        reach = zone_lo - 20.0  # a near face this far before the zone cannot put a body (17 m at most) into it
        events: list[TrafficEvent] = []
        out_tracks: dict[int, TrackState] = {}
        line = cfg.detection_line_m
        seen = set()
        for j, tr in enumerate(conf):
            tid = id_list[j]
            seen.add(tid)
            k = lane_idx[j]
            lane = k if k >= 0 else None
            memo = self._memo.get(tid)
            fresh = memo is None or tr.age_frames < memo.age
            if fresh:
                memo = self._memo[tid] = _Memo(tr.age_frames, s[j], t_ns, speed[j],
                                               meter=LengthMeter(cfg.length_outliers))
            meter = memo.meter
            if ext is not None and r_lo <= tr.range_m <= r_hi and ext[j] == ext[j]:  # (not NaN)
                meter.add(ext[j])
            length_pub, cls_pub = stats.measured(meter)
            if fresh:
                if lane is not None and cfg.count_late_max_m > 0:
                    memo.counted = self._count_late(tr, lane, lanes[k].direction, s[j], vs[j], speed[j],
                                                    meter, t_ns, float(margin[j]))
            else:
                # detection line crossing (either direction), time interpolated
                s0, s1 = memo.s_m, s[j]
                crossed = (s0 - line) * (s1 - line) < 0 or (s1 == line and s0 != line)
                # the volume counts vehicles travelling in the lane's direction (a wrong-way driver is an event)
                against = lane is not None and vs[j] * lanes[k].direction < 0
                if crossed and lane is not None and not against and not (memo.counted and cfg.count_once_per_track):
                    f = (line - s0) / (s1 - s0)
                    tc = memo.t_ns + int(round(f * (t_ns - memo.t_ns)))
                    stats.lane(lane).add(Crossing(tc, speed[j], float("nan"), tr.cls, meter))
                    memo.counted = True
                memo.age, memo.s_m, memo.t_ns = tr.age_frames, s1, t_ns
                memo.max_speed_mps = max(memo.max_speed_mps, speed[j])
            if lane is not None:
                # the body spans the near face s to s + L (farther from the radar in either direction of travel)
                if reach <= s[j] <= zone_hi:
                    stats.lane(k).samples.append((t_ns, dt_ns, s[j], meter))
                    if s[j] + (length_pub if length_pub is not None else default_length) >= zone_lo:
                        presence[k] = True
                # wrong way
                # only frames with a detection count: a track seeded with a wrong velocity (a steep near
                # detection) that coasts out of view must not raise the event on its prediction alone; nor
                # frames where the yaw is too uncertain to tell its lane from the neighbouring one
                if tr.hits > memo.hits and lane_sure[j]:
                    if vs[j] * lanes[k].direction < -cfg.wrong_way_min_speed_mps:
                        memo.wrong_frames += 1
                    else:
                        memo.wrong_frames = 0
                if memo.wrong_frames >= cfg.wrong_way_min_frames and not memo.wrong_emitted:
                    memo.wrong_emitted = True
                    if not self._same_wrong_way_driver(conf, j, s, vs):
                        events.append(TrafficEvent("wrong_way", tid, lane, t_ns))
            # stopped vehicle
            if speed[j] < cfg.stopped_speed_mps and memo.max_speed_mps >= cfg.moving_speed_mps and lane is not None:
                if memo.stopped_since_ns is None:
                    memo.stopped_since_ns = t_ns
                if not memo.stopped_emitted and t_ns - memo.stopped_since_ns >= int(cfg.stopped_min_s * 1e9):
                    memo.stopped_emitted = True
                    events.append(TrafficEvent("stopped_vehicle", tid, lane, t_ns))
            elif speed[j] >= cfg.moving_speed_mps:
                memo.stopped_since_ns = None
                memo.stopped_emitted = False
            elif speed[j] >= cfg.stopped_speed_mps:
                memo.stopped_since_ns = None
            memo.hits = tr.hits
            if tr.cls is not None:
                cls_pub = tr.cls
            out_tracks[id(tr)] = tr if (tr.lane, tr.cls, tr.length_m) == (lane, cls_pub, length_pub) else _with(
                tr, lane, cls_pub, length_pub)
        for tid in [k for k in self._memo if k not in seen]:
            del self._memo[tid]
        for k in range(n_lanes):
            stats.lane(k).frames.append((t_ns, dt_ns))
        closed = stats.tick(t_ns, n_lanes)
        # tracks not confirmed: no length measured (the tracker's own is the spread of its detections, not a length)
        published = tuple(out_tracks.get(id(t)) or (t if t.length_m is None else _with(t, t.lane, t.cls, None))
                          for t in tracks)
        return TrafficUpdate(published, tuple(presence), closed, tuple(events))
