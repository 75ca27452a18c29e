"""Evaluation of the surveillance profile against simulator ground truth (DESIGN §6, Tavanti §III).

The scenario is synthesised frame by frame on the simulated Distance2Go and streamed through
:class:`~edge.pipelines.surveillance.SurveillancePipeline` without pacing. Ground truth per target
(:func:`hw_sim.events.event_truth`): class, direction and mean radial speed over the frames where the
target has scatterers inside the beam (range <= 24 m, |azimuth| <= 21°; :func:`hw_sim.events.frame_view`); a frame's
radial speed is that of the target's scatterers in view at its velocity, weighted by their echo power on the
scenario's board (the radar equation with its antenna patterns; :func:`hw_sim.synth.echo_power_w`) as its range.

Scoring:

* **Track instances**: a published track id from its first confirmed frame to the
  :class:`~edge.types.ClassifiedEvent` that ends it. An instance is matched to the true target in
  view whose weighted range (below) is nearest over the instance's frames, among the targets for
  which the mean distance from the range of the cluster the tracker associated (frames where the
  track coasted are left out: the alpha = 0.19 filter lags fast targets by metres) to the range extent of their scatterers in view is
  within :data:`MATCH_RANGE_M` (the range-Doppler coupling of a 40 km/h car alone shifts a cluster
  by 2 m). Unmatched instances are false tracks.
* **Per target**: the matched instance with the most frames gives ``predicted_class``, the
  estimated mean radial speed and direction; a target without an instance is *missed* (its predicted
  class is null and it counts as an error, as in Tavanti Table VI). ``tracked_fraction`` = visible
  frames with a matched confirmed track / visible frames; ``detected_frames`` = visible frames with a cluster
  within :data:`MATCH_RANGE_M` of it before tracking; ``position_rmse_m`` = range RMSE of the
  matched track against the echo-power-weighted range of the target's scatterers (the Distance2Go
  measures no azimuth: range only); ``speed_mae_kmh`` = |estimated -
  true| mean radial speed. ``n_tracks`` > 1 means the target's track split (counted in ``id_switches``).
* **Detection probability before tracking** (Tavanti §III-D-3: 70/84/88/92 %): visible (target,
  frame) pairs with a DBSCAN cluster centroid within :data:`MATCH_RANGE_M` of the target's extent.
* **Accuracies**: ``classification_accuracy`` over every true target (missed = wrong, Table VI);
  ``classification_accuracy_classified`` over targets with a track; ``classification_accuracy_detected``
  over targets with clusters on at least :data:`MIN_DETECTED_FRAMES` frames before tracking (the
  paper's single-target test sets only hold passages that triggered a recording).
* **Speed aliasing and passages** (issue 31, :func:`_speed_and_passage_tallies`): a vehicle (car, motorcycle,
  truck) whose |estimated - true| mean radial speed exceeds half the Doppler alias step (``2 v_max``, 10.7 km/h on
  the Distance2Go) is *off by an alias step*; ``alias_step_fraction`` counts them among the vehicles with a speed,
  ``speed_uncertain_fraction`` the vehicles whose event flags its speed as uncertain (alias not determined), and
  ``alias_step_unflagged_fraction`` those off by an alias step without that flag (an error a reader of the event
  cannot see); ``speed_mae_certain_kmh`` is ``speed_mae_kmh`` over the targets whose speed is not flagged.
  ``one_event_fraction`` is the share of tracked single-target passages that ended as exactly one event: one
  event matched to the target and no unmatched event overlapping its time in view (a fragment of the vehicle that
  matched nothing is still a second event of the passage).
* **Live classes**: ``live_class_accuracy`` is the share of the published frames of tracks matched to a target,
  among those with a provisional class (``TrackState.cls``), whose class is the target's.
* **Confusion matrix**: ``matrix[i][j]`` = targets of true class ``labels[i]`` predicted as
  ``labels[j]``; the last column, ``missed``, counts targets without a track.

``tallies`` in the summary holds the sums and counts behind the figures (classification of single- and
multi-target events' targets, detection frames, speed and range errors, false tracks, minutes, classified events per
tracked passage) so that the evaluation corpus (:mod:`edge.evaluation.corpus`) pools runs as ratios of sums.

Lane fields (``lane``, ``lane_accuracy``, ``count_error_per_lane``) are null: the profile has no lanes.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edge.pipeline import StageTimer, build_pipeline
from edge.types import ClassifiedEvent, RawFrame
from hal.waveform import characteristics

log = logging.getLogger(__name__)

PROFILE = "surveillance"
MATCH_RANGE_M = 2.5
MIN_MATCH_OVERLAP = 0.5
MIN_DETECTED_FRAMES = 3
#: an unmatched event whose track stayed this close to a single target's scatterers is a fragment of that passage
PASSAGE_BODY_M = MATCH_RANGE_M


@dataclass
class _Instance:
    track_id: int
    frames: list[int] = field(default_factory=list)
    ranges: list[float] = field(default_factory=list)
    event: ClassifiedEvent | None = None
    target: int | None = None
    range_err: list[float] = field(default_factory=list)
    meas: list[float | None] = field(default_factory=list)  # range of the cluster associated (None: coasting)
    classes: list[str | None] = field(default_factory=list)  # the published provisional class per frame


def _ratio(num: int, den: int) -> float | None:
    return num / den if den else None


def _interval_distance(r: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Distance of ranges ``r`` to the interval ``[lo, hi]`` (0 inside)."""
    return np.maximum(0.0, np.maximum(lo - r, r - hi))


def _tallies(targets: list[dict], truths: dict, hits: dict[int, np.ndarray], false_tracks: int, minutes: float,
             range_sq: dict[int, tuple[float, int]]) -> dict:
    """The run's sums and counts behind its figures: classification of the targets of single-target events (one
    target in the slot) and of multi-target ones, detection before tracking over visible frames, the |mean radial
    speed| errors, the squared range errors of the matched tracks, false tracks and minutes, and the classified
    events per tracked passage (above 1 where a passage's track split)."""
    size: dict[int, int] = {}
    for t in truths.values():
        size[t.event] = size.get(t.event, 0) + 1
    single = [r for r in targets if size.get(r["event"], 0) == 1]
    multi = [r for r in targets if size.get(r["event"], 0) > 1]
    tracked = [r for r in targets if r["n_tracks"] > 0]
    spd = [r["speed_mae_kmh"] for r in targets if r["speed_mae_kmh"] is not None]
    return {
        "minutes": minutes,
        "events": len(size),
        "targets": len(targets),
        "single_targets": len(single),
        "single_correct": sum(1 for r in single if r["predicted_class"] == r["class"]),
        "multi_targets": len(multi),
        "multi_correct": sum(1 for r in multi if r["predicted_class"] == r["class"]),
        "correct": sum(1 for r in targets if r["predicted_class"] == r["class"]),
        "direction_correct": sum(1 for r in targets if r["direction_est"] == r["direction_true"]),
        "detected_frames": int(sum(int(np.sum(h)) for h in hits.values())),
        "visible_frames": int(sum(h.size for h in hits.values())),
        "speed_abs_error_sum_kmh": float(sum(spd)),
        "speed_n": len(spd),
        "range_sq_error_sum_m2": float(sum(v[0] for v in range_sq.values())),
        "range_n": int(sum(v[1] for v in range_sq.values())),
        "false_tracks": int(false_tracks),
        "passages_tracked": len(tracked),
        "passage_events": int(sum(r["n_tracks"] for r in targets)),
    }


VEHICLE_CLASSES = ("car", "motorcycle", "truck")


def _live_class_tallies(done: list[_Instance], truths: dict) -> dict:
    """The published frames of tracks matched to a target that carry a provisional class, and those whose class is
    the target's (``live_class_accuracy``: what a reader of the live outputs sees while the target is in view)."""
    frames = correct = 0
    for inst in done:
        if inst.target not in truths:  # unmatched, or matched to a target without a truth row (as the targets' rows)
            continue
        cls = truths[inst.target].cls
        for c in inst.classes:
            if c is not None:
                frames += 1
                correct += int(c == cls)
    return {"live_class_frames": frames, "live_class_correct": correct}


def _speed_and_passage_tallies(targets: list[dict], truths: dict, done: list[_Instance], views: list,
                               alias_step_kmh: float) -> dict:
    """Sets each target row's ``speed_alias_steps`` (the error in alias steps, rounded; None without a speed),
    ``speed_uncertain`` (the event's flag) and, for targets of single-target events, ``passage_events``: events
    matched to it plus unmatched events of the same body (an unmatched instance whose published ranges lie within
    :data:`PASSAGE_BODY_M` of the target's scatterers in view in at least half of its frames: a fragment of the
    vehicle; static site clutter elsewhere does not count). Returns the tallies behind ``alias_step_fraction``,
    ``alias_step_unflagged_fraction``, ``speed_uncertain_fraction``, ``speed_mae_certain_kmh`` and
    ``one_event_fraction`` (module doc)."""
    size: dict[int, int] = {}
    for t in truths.values():
        size[t.event] = size.get(t.event, 0) + 1
    loose = [i for i in done if i.target is None and i.event is not None and i.frames]
    vehicles = off = uncertain = off_unflagged = single = one = certain_n = 0
    certain_err = 0.0
    for row in targets:
        t = truths[row["id"]]
        err = row["speed_mae_kmh"]
        row["speed_alias_steps"] = None
        if err is not None:
            signed = row["mean_radial_speed_kmh_est"] - row["mean_radial_speed_kmh_true"]
            row["speed_alias_steps"] = int(np.round(signed / alias_step_kmh))
        if row["class"] in VEHICLE_CLASSES and err is not None:
            vehicles += 1
            off += int(abs(err) > 0.5 * alias_step_kmh)
            uncertain += int(bool(row.get("speed_uncertain")))
            off_unflagged += int(abs(err) > 0.5 * alias_step_kmh and not row.get("speed_uncertain"))
        if err is not None and not row.get("speed_uncertain"):
            certain_err += err
            certain_n += 1
        if size.get(t.event, 0) == 1 and row["n_tracks"] > 0:
            extra = 0
            for inst in loose:
                near = 0
                for n, r in zip(inst.frames, inst.ranges):
                    fv = views[n]
                    k = np.flatnonzero(fv.id == t.id)
                    if k.size and _interval_distance(np.array([r]), fv.range_min_m[k[0]], fv.range_max_m[k[0]])[0] \
                            <= PASSAGE_BODY_M:
                        near += 1
                extra += int(near >= 0.5 * len(inst.frames))
            row["passage_events"] = row["n_tracks"] + extra
            single += 1
            one += int(row["passage_events"] == 1)
    return {"vehicles_with_speed": vehicles, "vehicles_alias_off": off, "vehicles_speed_uncertain": uncertain,
            "vehicles_alias_off_unflagged": off_unflagged, "speed_abs_error_sum_certain_kmh": certain_err,
            "speed_n_certain": certain_n, "single_passages_tracked": single, "single_passages_one_event": one}


def evaluate(scenario: Any, *, seed: int | None, frames: int | None, events: int | None, config: Any,
             progress: bool = False) -> dict:
    from hw_sim.events import SURVEILLANCE_CLASSES, event_truth, frame_view
    from hw_sim.simulator import FrameSimulator

    s = scenario.seed if seed is None else int(seed)
    board = scenario.sim_board()
    fe = board.frontend
    period = fe.waveform.frame_period_s
    n_frames = int(frames) if frames else max(1, int(round(scenario.duration_s / period)))
    scene = scenario.build_scene(s)
    sim = FrameSimulator(board, scene, s)
    pipe = build_pipeline(PROFILE, fe, config)
    timer = StageTimer(window=max(16, n_frames))
    frame_ms = np.zeros(n_frames)

    views = []  # per frame: targets in view (ids, weighted range, extent)
    open_inst: dict[int, _Instance] = {}
    done: list[_Instance] = []
    det_hits: dict[int, list[bool]] = {}

    def close_events(evts, n):
        for ev in evts:
            inst = open_inst.pop(ev.track_id, None) or _Instance(ev.track_id)
            inst.event = ev
            done.append(inst)

    it = range(n_frames)
    if progress:
        try:
            from tqdm import tqdm

            it = tqdm(it, desc=f"evaluate {scenario.name}", unit="frame")
        except ImportError:  # pragma: no cover - tqdm is optional
            pass
    for n in it:
        f = sim.frame(n)
        raw = RawFrame(seq=n, t_ns=int(round(n * period * 1e9)), i=f.i, q=f.q, frontend=fe, truth=f.truth)
        t0 = time.perf_counter_ns()
        res = pipe.process(raw, timer)
        frame_ms[n] = (time.perf_counter_ns() - t0) / 1e6
        fv = frame_view(scene, f.t_s, board=board)
        views.append(fv)
        det_r = np.asarray(res.detections.range_m, dtype=float)
        for tid, lo, hi in zip(fv.id[fv.in_beam], fv.range_min_m[fv.in_beam], fv.range_max_m[fv.in_beam]):
            d = _interval_distance(det_r, lo, hi)
            det_hits.setdefault(int(tid), []).append(bool(d.size and d.min() <= MATCH_RANGE_M))
        for tid in res.intermediates.get("tracks_ended_without_event", ()):
            # dropped, or joined to another track of the same target: its id may be reused by a new track
            if tid in open_inst:
                done.append(open_inst.pop(tid))
        meas = res.intermediates.get("track_cluster_range_m", {})
        for ts in res.tracks:
            inst = open_inst.setdefault(ts.track_id, _Instance(ts.track_id))
            inst.frames.append(n)
            inst.ranges.append(float(ts.range_m))
            inst.meas.append(meas.get(ts.track_id))
            inst.classes.append(ts.cls)
        close_events(res.classifications, n)
    close_events(pipe.flush(), n_frames)
    done.extend(open_inst.values())  # tracks that never produced an event (should not happen)

    truths = {t.id: t for t in event_truth(scene, period, n_frames, views)}
    # match instances to targets by mean range error over common frames
    for inst in done:
        if not inst.frames:
            continue
        pairs = [(n, r) for n, r in zip(inst.frames, inst.meas) if r is not None]
        if not pairs:
            pairs = list(zip(inst.frames, inst.ranges))
        errs: dict[int, list[tuple[float, float]]] = {}
        for n, r in pairs:
            fv = views[n]
            for tid, rw, lo, hi in zip(fv.id, fv.range_m, fv.range_min_m, fv.range_max_m):
                gap = float(_interval_distance(np.array([r]), lo, hi)[0])
                errs.setdefault(int(tid), []).append((abs(r - float(rw)), gap))
        best, best_err = None, np.inf
        for tid, e in errs.items():
            err = np.asarray(e)
            if (len(e) >= MIN_MATCH_OVERLAP * len(pairs) and err[:, 1].mean() <= MATCH_RANGE_M
                    and err[:, 0].mean() < best_err):
                best, best_err = tid, float(err[:, 0].mean())
        if best is not None:
            inst.target = best
            ids_rng = {n: dict(zip(views[n].id.tolist(), views[n].range_m.tolist())) for n in inst.frames}
            inst.range_err = [r - ids_rng[n][best] for n, r in zip(inst.frames, inst.ranges) if best in ids_rng[n]]

    labels = list(SURVEILLANCE_CLASSES)
    cm = np.zeros((len(labels), len(labels) + 1), dtype=int)
    targets = []
    correct = classified = 0
    speed_err, rmse_all, splits = [], [], 0
    range_sq: dict[int, tuple[float, int]] = {}  # per target: squared range errors summed, their number
    for tid, t in truths.items():
        mine = [i for i in done if i.target == tid and i.event is not None]
        tracked_frames = {n for i in done if i.target == tid for n in i.frames}
        vis_frames = {n for n, fv in enumerate(views) if tid in fv.id[fv.in_beam]}
        row = {
            "id": tid, "event": t.event, "class": t.cls, "lane": None,
            "tracked_fraction": len(tracked_frames & vis_frames) / max(1, len(vis_frames)),
            "detected_frames": int(np.sum(det_hits.get(tid, []))),
            "position_rmse_m": None, "speed_mae_kmh": None, "predicted_class": None,
            "class_probability": None, "direction_true": t.direction, "direction_est": None,
            "mean_radial_speed_kmh_true": round(t.mean_radial_speed_kmh, 3), "mean_radial_speed_kmh_est": None,
            "n_tracks": len(mine), "visible_frames": t.visible_frames, "features": None, "speed_uncertain": None,
        }
        ti = labels.index(t.cls) if t.cls in labels else None
        if mine:
            main = max(mine, key=lambda i: len(i.frames))
            ev = main.event
            err = np.asarray([e for i in mine for e in i.range_err])
            rm = float(np.sqrt(np.mean(err**2))) if err.size else None
            range_sq[tid] = (float(np.sum(err**2)), int(err.size))
            v_est = float(ev.mean_radial_speed_kmh)
            row.update({
                "predicted_class": ev.cls, "class_probability": ev.probabilities.get(ev.cls),
                "features": {k: float(v) for k, v in ev.features.items()},
                "direction_est": ev.direction, "mean_radial_speed_kmh_est": round(v_est, 3) if np.isfinite(v_est) else None,
                "position_rmse_m": rm,
                "speed_mae_kmh": abs(v_est - t.mean_radial_speed_kmh) if np.isfinite(v_est) else None,
                "speed_uncertain": bool(getattr(ev, "speed_uncertain", False)),
            })
            classified += 1
            correct += int(ev.cls == t.cls)
            splits += len(mine) - 1
            if row["speed_mae_kmh"] is not None:
                speed_err.append(row["speed_mae_kmh"])
            if rm is not None:
                rmse_all.append(rm)
            if ti is not None and ev.cls in labels:
                cm[ti, labels.index(ev.cls)] += 1
        elif ti is not None:
            cm[ti, -1] += 1
        targets.append(row)

    # the paper's test sets hold passages that triggered a recording: targets with clusters on
    # at least MIN_DETECTED_FRAMES frames before tracking ("detected")
    detected = {tid for tid, h in det_hits.items() if int(np.sum(h)) >= MIN_DETECTED_FRAMES}
    n_det = sum(1 for tid in truths if tid in detected)
    correct_det = sum(
        1 for r in targets if r["id"] in detected and r["predicted_class"] == r["class"]
    )
    false_tracks = sum(1 for i in done if i.target is None and i.event is not None)
    minutes = n_frames * period / 60.0
    hits = {tid: np.asarray(h) for tid, h in det_hits.items()}
    per_class = {}
    for c in labels:
        h = [hits[tid] for tid, t in truths.items() if t.cls == c and tid in hits]
        per_class[c] = float(np.concatenate(h).mean()) if h else None
    all_hits = np.concatenate(list(hits.values())) if hits else np.zeros(0)
    n_t = len(truths)
    tallies = _tallies(targets, truths, hits, false_tracks, minutes, range_sq)
    alias_step_kmh = 2.0 * characteristics(fe).max_radial_speed_mps * 3.6  # 2 v_max
    tallies.update(_speed_and_passage_tallies(targets, truths, done, views, alias_step_kmh))
    tallies.update(_live_class_tallies(done, truths))
    summ = timer.summary()
    report = {
        "scenario": scenario.name,
        "profile": PROFILE,
        "seed": s,
        "frames": n_frames,
        "events": events,
        "targets": targets,
        "summary": {
            "position_rmse_m_mean": float(np.mean(rmse_all)) if rmse_all else None,
            "speed_mae_kmh": float(np.mean(speed_err)) if speed_err else None,
            "detection_probability": float(all_hits.mean()) if all_hits.size else None,
            "false_tracks_per_min": false_tracks / minutes if minutes > 0 else None,
            "id_switches": splits,
            "lane_accuracy": None,
            "count_error_per_lane": None,
            "classification_accuracy": correct / n_t if n_t else None,
            "confusion_matrix": {"labels": labels, "columns": labels + ["missed"], "rows": "true class",
                                 "matrix": cm.tolist()},
            # surveillance extras
            "targets": n_t,
            "missed_targets": int(cm[:, -1].sum()),
            "classification_accuracy_classified": correct / classified if classified else None,
            "detected_targets": n_det,
            "classification_accuracy_detected": correct_det / n_det if n_det else None,
            "direction_accuracy": (
                sum(1 for r in targets if r["direction_est"] == r["direction_true"]) / n_t if n_t else None
            ),
            "detection_probability_per_class": per_class,
            "false_tracks": false_tracks,
            # sums and counts behind the figures, for pooling runs as ratios of sums (edge.evaluation.corpus)
            "alias_step_fraction": _ratio(tallies["vehicles_alias_off"], tallies["vehicles_with_speed"]),
            "speed_uncertain_fraction": _ratio(tallies["vehicles_speed_uncertain"], tallies["vehicles_with_speed"]),
            "alias_step_unflagged_fraction": _ratio(tallies["vehicles_alias_off_unflagged"],
                                                    tallies["vehicles_with_speed"]),
            "speed_mae_certain_kmh": _ratio(tallies["speed_abs_error_sum_certain_kmh"], tallies["speed_n_certain"]),
            "one_event_fraction": _ratio(tallies["single_passages_one_event"], tallies["single_passages_tracked"]),
            "live_class_accuracy": _ratio(tallies["live_class_correct"], tallies["live_class_frames"]),
            "tallies": tallies,
        },
        "frame_time_ms": {
            "p50": float(np.percentile(frame_ms, 50)),
            "p99": float(np.percentile(frame_ms, 99)),
            "budget": period * 1000.0,
        },
        "stages_ms": {k: {"p50": v["p50_ms"], "p99": v["p99_ms"]} for k, v in summ.items()},
    }
    return report
