"""Lane-frame cost against the number of confirmed tracks (``radar-edge bench --tracks 5,20,64``).

For each count N a synthetic scene holds N cars in view for the whole run: the ``highway4`` overpass
geometry (7 m, 1.5 deg down) widened to eight 3.5 m lanes, slow dense queues (15-68 km/h, a speed per lane,
neighbours 3 km/h apart so that the lane pipeline's same-body filter does not merge them; 64 cars are about
30 m apart per lane), staggered in range across lanes, all inside 25-290 m for the whole run, approaching
in lanes 0-3 and receding in 4-7.

Detection runs (and is timed) as usual. By default the tracker is then fed every car of the frame's ground
truth with :data:`TRUTH_SIGMA` noise (a synthetic driver: the four-segment pairing of dense queues loses
cars -- 64 cars give about 30-45 detections and 43 confirmed tracks -- so the pipeline's own detections
cannot hold N tracks); ``detections="pipeline"`` keeps them. The report gives the frame p50/p99 (wall and
thread CPU time) over the frames after a warm-up in which the tracks confirm, and the confirmed tracks the
tracker held (mean, min, max).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

#: vehicle counts of the issue's acceptance (5: ``highway4``; 20; 64: the tracker's design maximum)
DEFAULT_COUNTS = (5, 20, 64)
#: eight lanes (lateral centre m, direction, speed km/h): the highway4 overpass view, widened
LANES = ((-12.25, "toward", 20.0), (-8.75, "toward", 35.0), (-5.25, "toward", 50.0), (-1.75, "toward", 65.0),
         (1.75, "away", 60.0), (5.25, "away", 45.0), (8.75, "away", 30.0), (12.25, "away", 15.0))
Y_NEAR_M, Y_FAR_M = 25.0, 290.0


def scene_toml(n: int, duration_s: float) -> str:
    """A scenario TOML with ``n`` cars spread over the four lanes, in view for ``duration_s``."""
    lines = ['[scenario]', f'name = "tracks-{n}"', 'board = "simo"',
             f'description = "{n} cars in slow queues on four lanes (bench --tracks)"',
             f'duration_s = {duration_s:.3f}', 'seed = 1', '', '[radar]', 'height_m = 7.0', 'tilt_deg = 1.5',
             'occluded_behind = true', '']
    for x, d, _ in LANES:
        lines += ['[[lane]]', f'center_x_m = {x}', f'direction = "{d}"', '']
    per_lane = [n // len(LANES) + (1 if k < n % len(LANES) else 0) for k in range(len(LANES))]
    vid = 0
    for lane, ((_, d, v), m) in enumerate(zip(LANES, per_lane)):
        if m == 0:
            continue
        travel = (v + 3.0) / 3.6 * duration_s  # the faster of the alternating speeds
        # approaching cars end nearer, receding ones farther: start them where they stay in the window
        lo, hi = (Y_NEAR_M + travel, Y_FAR_M) if d == "toward" else (Y_NEAR_M, Y_FAR_M - travel)
        # staggered across lanes: cars of different lanes at different ranges (the 4-element array resolves
        # little in angle)
        step = (hi - lo) / m
        ys = lo + step * (np.arange(m) + (lane + 0.5) / len(LANES))
        for k, y in enumerate(ys):
            vid += 1
            # neighbours 3 km/h apart: the lane pipeline takes detections within cluster_length_m (17 m) and
            # cluster_speed_mps (0.6 m/s) of each other for one vehicle's body
            lines += ['[[vehicle]]', f'id = {vid}', 'kind = "car"', f'lane = {lane}', f'y_m = {y:.2f}',
                      f'speed_kmh = {v + 3.0 * (k % 2)}', '']
    return "\n".join(lines)


#: measurement noise of the truth-driven detections (1 sigma): slant range m, radial speed m/s, azimuth rad --
#: about the lane profile's own (track.pdaf range_sigma_m, azimuth_sigma_deg)
TRUTH_SIGMA = (0.3, 0.1, np.radians(0.5))


def truth_detections(truth: Any, like: Any, rng: np.random.Generator, lane_cfg: Any) -> Any:
    """Detections of every target of the frame's ground truth, with :data:`TRUTH_SIGMA` noise, in the dtypes of
    ``like`` (the pipeline's own detections of the frame)."""
    from edge.dsp.geometry import polar_to_ground
    from edge.types import Detections

    n = len(truth)
    r = truth.range_m + rng.normal(0.0, TRUTH_SIGMA[0], n)
    v = truth.radial_speed_mps + rng.normal(0.0, TRUTH_SIGMA[1], n)
    az = truth.az_rad + rng.normal(0.0, TRUTH_SIGMA[2], n)
    x, y = polar_to_ground(r, az, lane_cfg.mounting_height_m, lane_cfg.target_height_m)
    cols = {"range_m": r, "radial_speed_mps": v, "az_rad": az, "snr_db": np.full(n, 25.0), "x_m": x, "y_m": y}
    return Detections(**{k: c.astype(getattr(like, k).dtype) for k, c in cols.items()})


def run_tracks(config: Any, counts: tuple[int, ...] = DEFAULT_COUNTS, *, frames: int = 150,
               warmup_frames: int = 45, seed: int = 1, progress: bool = False,
               detections: str = "truth") -> dict[str, Any]:
    """Frame cost of the lane pipeline per vehicle count: ``{"frames", "warmup_frames", "by_count": {N: {...}}}``
    with ``p50_ms``, ``p99_ms``, ``cpu_p50_ms``, ``cpu_p99_ms``, ``p99_budget_fraction`` and the confirmed
    tracks held (``confirmed_mean/min/max``) over the timed frames."""
    from edge.bench import synth_frames
    from edge.ops.heap import frozen_heap
    from edge.pipeline import StageTimer, build_pipeline

    if detections not in ("truth", "pipeline"):
        raise ValueError(f"detections must be 'truth' or 'pipeline', got {detections!r}")
    out: dict[str, Any] = {"frames": frames, "warmup_frames": warmup_frames, "seed": seed,
                           "detections": detections, "by_count": {}}
    total = warmup_frames + frames
    for n in counts:
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / f"tracks-{n}.toml"
            path.write_text(scene_toml(n, duration_s=(total + 5) * 0.034), encoding="utf-8")
            recorded = synth_frames("simo", str(path), seed, total, progress)
        fe = recorded[0].frontend
        budget_ms = fe.waveform.frame_period_s * 1e3
        warm = build_pipeline("lane", fe, config)  # imports, caches: a throw-away instance
        for f in recorded[:5]:
            warm.process(f, StageTimer(16))
        warm.close()
        pipe = build_pipeline("lane", fe, config)
        if detections == "truth":  # detection runs (and costs) as usual; the tracker gets every car
            rng = np.random.default_rng(seed)
            own_detect, lane_cfg = pipe.detect, config.section("pipeline.lane")

            def detect(frame, timer, feedback, _own=own_detect, _rng=rng, _cfg=lane_cfg):
                det, inter = _own(frame, timer, feedback)
                return truth_detections(frame.truth, det, _rng, _cfg), inter

            pipe.detect = detect
        timer = StageTimer(max(16, total))
        wall, cpu, held = np.empty(total), np.empty(total), np.empty(total, dtype=np.int64)
        with frozen_heap():
            for k, f in enumerate(recorded):
                t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
                r = pipe.process(f, timer)
                cpu[k] = (time.thread_time_ns() - c0) / 1e6
                wall[k] = (time.perf_counter_ns() - t0) / 1e6
                held[k] = sum(1 for t in r.tracks if t.confirmed)
        pipe.close()
        w, c, h = wall[warmup_frames:], cpu[warmup_frames:], held[warmup_frames:]
        p50, p99 = (float(v) for v in np.percentile(w, [50, 99]))
        cp50, cp99 = (float(v) for v in np.percentile(c, [50, 99]))
        out["by_count"][str(n)] = {
            "vehicles": n, "confirmed_mean": float(h.mean()), "confirmed_min": int(h.min()),
            "confirmed_max": int(h.max()), "p50_ms": p50, "p99_ms": p99, "cpu_p50_ms": cp50, "cpu_p99_ms": cp99,
            "budget_ms": budget_ms, "p99_budget_fraction": p99 / budget_ms, "cpu_p99_budget_fraction": cp99 / budget_ms,
        }
    return out


def report_lines(rep: dict[str, Any]) -> list[str]:
    """The table of :func:`run_tracks`'s report."""
    how = ("detection as usual, the tracker fed every car of the ground truth with noise"
           if rep.get("detections") == "truth" else "the pipeline's own detections")
    out = [f"cost against confirmed tracks (lane profile, {rep['frames']} frames after {rep['warmup_frames']} "
           f"warm-up frames; {how}):",
           f"{'vehicles':>9}{'confirmed':>16}{'p50 ms':>9}{'p99 ms':>9}{'CPU p50':>9}{'CPU p99':>9}{'p99/budget':>12}"]
    for r in rep["by_count"].values():
        held = f"{r['confirmed_mean']:.1f} [{r['confirmed_min']}-{r['confirmed_max']}]"
        out.append(f"{r['vehicles']:>9}{held:>16}{r['p50_ms']:9.3f}{r['p99_ms']:9.3f}{r['cpu_p50_ms']:9.3f}{r['cpu_p99_ms']:9.3f}"
                   f"{r['p99_budget_fraction']:12.2%}")
    return out
