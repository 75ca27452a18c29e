"""The traffic layer's input recorded during a lane evaluation, and the traffic layer run again on it.

``radar-edge evaluate --scenario highway4-traffic --record-tracks run.npz`` saves, frame by frame, the tracks the
traffic layer (:class:`edge.traffic.TrafficMonitor`) was given and the true crossings of the detection line.
``radar-edge replay-traffic run.npz --set traffic.count_late_max_m=0`` runs the traffic layer again on them with
other settings and scores its counts against the same truth (:mod:`edge.evaluation.counting`): seconds for what
takes a ten-minute evaluation, so that counting rules, lane geometry and interval settings can be tried and
compared on the same traffic. With the recorded settings the replay gives the evaluation's counts exactly.

What a replay cannot change: the tracks. Settings of ``pipeline.lane`` and ``track.pdaf`` need a new evaluation,
and so do effects of the traffic layer on the tracker (the tracker takes the traffic layer's mounting-yaw
estimate as the road direction of its lane-keeping model): a replay with other yaw settings counts the recorded
tracks, which were followed with the recorded run's yaw. The true crossings are those of the recorded detection
line, so ``traffic.detection_line_m`` cannot change in a replay. A calibration file is neither read nor written.

File format (version 1): a numpy ``.npz`` (no pickled objects), columns one row per published track and frame:

=================  =========================================================================================
``meta``           JSON text as uint8: ``format_version``, ``scenario``, ``seed``, ``frames``, ``frame_period_s``,
                   ``n_lanes``, ``traffic`` (the resolved ``traffic`` section the evaluation ran with),
                   ``counts`` (the evaluation's count figures: error, volumes, mismatches), ``events``
``frame_t_ns``     ``(F,)`` int64 frame times
``frame_start``    ``(F + 1,)`` int64: the tracks of frame ``f`` are rows ``frame_start[f]:frame_start[f + 1]``
``frame_has_motion_x``  ``(F,)`` bool: the frame came with the motion model's lateral positions (below)
``track_<field>``  ``(N,)`` the :class:`edge.types.TrackState` fields: ``track_id``, ``age_frames``, ``hits``
                   (int64), ``confirmed`` (bool), ``lane`` (int64, -1 = none), ``cls`` (str, "" = none), the
                   floats (float64; NaN = none for ``class_probability``, ``rcs_dbsm``, ``length_m`` and the
                   quality fields ``x_sd_m`` ... ``existence_probability``, NaN too in logs written before them)
``motion_x_m``     ``(N,)`` float64: the tracker's motion-model ``x`` per track (the yaw estimator's input)
``true_lane``, ``true_t_s``, ``true_vehicle``, ``true_class``
                   the true crossings of the detection line: lane, time (s), vehicle id, class
``true_either_lane``  the lane a vehicle straddling into it at the line may be counted in instead (int64, -1 =
                   none; absent in logs written before it)
=================  =========================================================================================
"""

from __future__ import annotations

import dataclasses
import json
import operator
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from edge.evaluation.counting import CountTally
from edge.types import TrackState

FORMAT_VERSION = 1

_INT_FIELDS = ("track_id", "age_frames", "hits")
_FLOAT_FIELDS = ("x_m", "y_m", "vx_mps", "vy_mps", "range_m", "radial_speed_mps", "az_rad")
_QUALITY_FIELDS = ("x_sd_m", "y_sd_m", "vx_sd_mps", "vy_sd_mps", "existence_probability")  # may be absent
_OPTIONAL_FLOAT_FIELDS = ("class_probability", "rcs_dbsm", "length_m", *_QUALITY_FIELDS)
_ROW_FIELDS = _INT_FIELDS + _FLOAT_FIELDS + _OPTIONAL_FLOAT_FIELDS + ("confirmed", "lane", "cls")
_ROW = operator.attrgetter(*_ROW_FIELDS)  # a track's fields as one tuple
#: the per-track columns and their types
_TRACK_COLUMNS: dict[str, type] = {"track_confirmed": bool, "track_lane": np.int64, "track_cls": str,
                                   **{f"track_{f}": np.int64 for f in _INT_FIELDS},
                                   **{f"track_{f}": np.float64 for f in _FLOAT_FIELDS + _OPTIONAL_FLOAT_FIELDS}}
_KEYS = ("meta", "frame_t_ns", "frame_start", "frame_has_motion_x", "motion_x_m", "true_lane", "true_t_s",
         "true_vehicle", "true_class", *(k for k in _TRACK_COLUMNS if k[len("track_"):] not in _QUALITY_FIELDS))


class TrackLogError(ValueError):
    """A track log that cannot be read or replayed as asked; the message says why."""


class TrackLogRecorder:
    """Collects the traffic layer's input frame by frame (:attr:`edge.pipelines.lane.LanePipeline.traffic_tap`).
    The tracks' fields are kept as columns, converted every ``chunk_rows`` rows (ten minutes of four-lane traffic
    is about 300 000 rows: as TrackState objects they would hold a few hundred MB)."""

    def __init__(self, chunk_rows: int = 8192) -> None:
        self._chunk_rows = chunk_rows
        self._t_ns: list[int] = []
        self._start: list[int] = [0]
        self._has_mx: list[bool] = []
        self._mx: list[float] = []
        self._rows: list[tuple] = []  # the tracks not yet converted, as tuples of _ROW_FIELDS
        self._chunks: list[dict[str, np.ndarray]] = []
        self._n = 0

    def __call__(self, tracks: tuple[TrackState, ...], t_ns: int, motion_x_m: np.ndarray | None) -> None:
        self._t_ns.append(int(t_ns))
        self._rows.extend(map(_ROW, tracks))
        self._n += len(tracks)
        ok = motion_x_m is not None and len(motion_x_m) == len(tracks)
        self._has_mx.append(ok)
        self._mx.extend(np.asarray(motion_x_m, dtype=np.float64).tolist() if ok else [np.nan] * len(tracks))
        self._start.append(self._n)
        if len(self._rows) >= self._chunk_rows:
            self._flush()

    def _flush(self) -> None:
        if not self._rows:
            return
        cols = dict(zip(_ROW_FIELDS, zip(*self._rows)))
        chunk = {f"track_{f}": np.array(cols[f], dtype=np.int64) for f in _INT_FIELDS}
        chunk.update({f"track_{f}": np.array(cols[f], dtype=np.float64) for f in _FLOAT_FIELDS})
        chunk.update({f"track_{f}": np.array([np.nan if v is None else v for v in cols[f]], dtype=np.float64)
                      for f in _OPTIONAL_FLOAT_FIELDS})
        chunk["track_confirmed"] = np.array(cols["confirmed"], dtype=bool)
        chunk["track_lane"] = np.array([-1 if v is None else v for v in cols["lane"]], dtype=np.int64)
        chunk["track_cls"] = np.array(["" if v is None else v for v in cols["cls"]], dtype=str)
        self._chunks.append(chunk)
        self._rows = []

    def save(self, path: str | Path, meta: dict, true_cross: list[tuple[int, float, int, str]]) -> Path:
        """Write the log with ``meta`` (module docstring) and the true crossings; returns the path written."""
        self._flush()
        cols: dict[str, np.ndarray] = {
            "meta": np.frombuffer(json.dumps({"format_version": FORMAT_VERSION, **meta}).encode(), dtype=np.uint8),
            "frame_t_ns": np.array(self._t_ns, dtype=np.int64),
            "frame_start": np.array(self._start, dtype=np.int64),
            "frame_has_motion_x": np.array(self._has_mx, dtype=bool),
            "motion_x_m": np.array(self._mx, dtype=np.float64),
            "true_lane": np.array([c[0] for c in true_cross], dtype=np.int64),
            "true_t_s": np.array([c[1] for c in true_cross], dtype=np.float64),
            "true_vehicle": np.array([c[2] for c in true_cross], dtype=np.int64),
            "true_class": np.array([c[3] for c in true_cross], dtype=str),
        }
        if true_cross and len(true_cross[0]) > 4:
            cols["true_either_lane"] = np.array([c[4] for c in true_cross], dtype=np.int64)
        for key, dtype in _TRACK_COLUMNS.items():
            parts = [c[key] for c in self._chunks]
            cols[key] = np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("wb") as fh:  # (np.savez_compressed would append .npz to a name without it)
            np.savez_compressed(fh, **cols)
        return path


@dataclass(frozen=True)
class TrackLog:
    """A loaded track log (module docstring): ``meta`` and the columns by name."""

    meta: dict
    cols: dict[str, np.ndarray]

    @property
    def frames(self) -> int:
        return int(self.cols["frame_t_ns"].size)

    @property
    def true_crossings(self) -> list[tuple]:
        """``(lane, t_s, vehicle id, class)``, and the lane a straddling vehicle may be counted in instead (-1:
        none) where the log has it."""
        c = self.cols
        cols = [c["true_lane"].tolist(), c["true_t_s"].tolist(), c["true_vehicle"].tolist(), c["true_class"].tolist()]
        if "true_either_lane" in c:
            cols.append(c["true_either_lane"].tolist())
        return list(zip(*cols))

    def frame_tracks(self) -> Iterator[tuple[int, tuple[TrackState, ...], np.ndarray | None]]:
        """Per frame ``(t_ns, tracks, motion_x_m or None)``, as the traffic layer was given them (one frame's
        TrackState objects at a time: a ten-minute log holds ~300 000 rows)."""
        c = self.cols
        names = ("track_id", *_FLOAT_FIELDS, "age_frames", "hits", "confirmed", "lane", "cls", *_OPTIONAL_FLOAT_FIELDS)
        cols = [c[f"track_{f}"] for f in names]
        i_lane, i_cls = names.index("lane"), names.index("cls")
        start, mx, has = c["frame_start"], c["motion_x_m"], c["frame_has_motion_x"]
        for f, t in enumerate(c["frame_t_ns"].tolist()):
            a, b = int(start[f]), int(start[f + 1])
            rows = []
            for v in zip(*(col[a:b].tolist() for col in cols)):
                v = list(v)
                v[i_lane] = None if v[i_lane] < 0 else v[i_lane]
                v[i_cls] = v[i_cls] or None
                for k in range(i_cls + 1, len(v)):  # NaN: not given
                    if v[k] != v[k]:
                        v[k] = None
                rows.append(TrackState(**dict(zip(names, v))))
            yield int(t), tuple(rows), (mx[a:b] if has[f] else None)


def load_track_log(path: str | Path) -> TrackLog:
    """Read a track log; :class:`TrackLogError` naming what is wrong with a file that is not one."""
    path = Path(path)
    if not path.is_file():
        raise TrackLogError(f"{path}: no such file (record one with radar-edge evaluate --record-tracks)")
    if not zipfile.is_zipfile(path):
        raise TrackLogError(f"{path}: not a track log (a numpy .npz archive) written by radar-edge evaluate "
                            "--record-tracks")
    try:
        with np.load(path, allow_pickle=False) as z:
            cols = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise TrackLogError(f"{path}: not a track log (.npz) written by radar-edge evaluate --record-tracks: {exc}") \
            from exc
    if "meta" not in cols or "frame_start" not in cols:
        raise TrackLogError(f"{path}: not a track log (a recording of raw frames is replayed with radar-edge replay)")
    missing = [k for k in _KEYS if k not in cols]
    if missing:
        raise TrackLogError(f"{path}: incomplete track log: no {', '.join(missing)}")
    try:
        meta = json.loads(cols["meta"].tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TrackLogError(f"{path}: its meta block is not JSON: {exc}") from exc
    if meta.get("format_version") != FORMAT_VERSION:
        raise TrackLogError(f"{path}: track log format version {meta.get('format_version')!r}, this radar-edge reads "
                            f"version {FORMAT_VERSION}")
    n = cols["track_track_id"].size
    for f in _QUALITY_FIELDS:
        cols.setdefault(f"track_{f}", np.full(n, np.nan))
    start = cols["frame_start"]
    if (start.size != cols["frame_t_ns"].size + 1 or start[0] != 0 or start[-1] != n or np.any(np.diff(start) < 0)
            or any(cols[k].size != n for k in (*_TRACK_COLUMNS, "motion_x_m"))):
        raise TrackLogError(f"{path}: inconsistent track log (frame index and track columns disagree)")
    return TrackLog(meta, cols)


def recorded_traffic_settings(log: TrackLog) -> tuple[dict, list[str]]:
    """The recorded ``traffic`` section as values this version knows, and the recorded keys it does not (a log
    written by another version: those settings are dropped, settings it did not have take their defaults)."""
    from edge.traffic import TrafficConfig

    known = {f.name for f in dataclasses.fields(TrafficConfig)}
    rec = log.meta["traffic"]
    return {k: v for k, v in rec.items() if k in known}, sorted(k for k in rec if k not in known)


def replay_traffic(log: TrackLog, traffic_config: Any, progress: Callable[[int], None] | None = None) -> dict:
    """Run the traffic layer with ``traffic_config`` (a :class:`edge.traffic.TrafficConfig`) on the recorded tracks
    and score its counts against the recorded truth. Returns ``{"counts", "events", "lane_centers_m",
    "estimated_yaw_deg"}``: ``counts`` as :meth:`edge.evaluation.counting.CountTally.summary`, ``events`` the
    traffic events (kind, track id, lane, t_s), the lane centres in use at the end and the mounting yaw.
    ``progress(frames done)`` is called now and then."""
    from edge.traffic import TrafficMonitor

    recorded_line = log.meta["traffic"]["detection_line_m"]
    if traffic_config.detection_line_m != recorded_line:
        raise TrackLogError(f"traffic.detection_line_m = {traffic_config.detection_line_m} in the replay, but the "
                            f"truth was recorded at {recorded_line} m: record again with the new line")
    cfg = dataclasses.replace(traffic_config, calibration_file="")
    mon = TrafficMonitor(cfg)
    tally = CountTally(int(log.meta["n_lanes"]))
    events = []
    for n, (t_ns, tracks, mx) in enumerate(log.frame_tracks()):
        upd = mon.update(tracks, t_ns, mx)
        tally.add_frame(upd.lane_stats, mon)
        events.extend({"kind": ev.kind, "track_id": ev.track_id, "lane": ev.lane, "t_s": round(t_ns * 1e-9, 3)}
                      for ev in upd.events)
        if progress is not None and n % 1000 == 999:
            progress(n + 1)
    tally.close(mon)
    return {"counts": tally.summary(log.true_crossings), "events": events,
            "lane_centers_m": [round(ln.center_m, 3) for ln in mon.lanes],
            "estimated_yaw_deg": float(np.degrees(mon.yaw_rad))}
