"""Compiled kernels against the numpy reference, end to end: the same frames through a profile's pipeline once
with the kernels and once with ``RADAR_EDGE_KERNELS=0``, then the detections and the confirmed tracks of every
frame compared (identical, or the largest difference when they are not); for the surveillance profile
(``--profile surveillance``, scenario tavanti-test1 by default) also the tracks' provisional classes and every
classified event (exactly).

``python -m edge.native.check --scenario highway4-traffic --frames 120`` (synthesised frames) or
``python -m edge.native.check --recording rec.npz``; exit status 0 when both paths agree within ``--atol``
(detections bit for bit by default; confirmed tracks within ``--track-atol``, 1e-9 m and m/s, because the
tracker kernel's small matrix products sum in another order than BLAS), 1 when not, 2 when a kernel is not built. ``deploy/check-arm64.sh`` runs it on the
arm64 build; ``tests/native`` on short runs.
"""

from __future__ import annotations

import argparse
import os
import sys
from contextlib import contextmanager
from typing import Any, Iterator

import numpy as np

DET_FIELDS = ("range_m", "radial_speed_mps", "az_rad", "snr_db", "x_m", "y_m")
TRACK_FIELDS = ("x_m", "y_m", "vx_mps", "vy_mps")


@contextmanager
def kernels(on: bool) -> Iterator[None]:
    """Within the block, stages built use the compiled kernels (``on``) or the numpy reference."""
    old = os.environ.get("RADAR_EDGE_KERNELS")
    os.environ["RADAR_EDGE_KERNELS"] = "1" if on else "0"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("RADAR_EDGE_KERNELS", None)
        else:
            os.environ["RADAR_EDGE_KERNELS"] = old


def outputs(profile: str, frames: list, config: Any, *, use_kernels: bool) -> list[dict[str, np.ndarray]]:
    """Per frame: the detections' fields and the confirmed tracks' ids and states (copies), from a fresh pipeline."""
    from edge.pipeline import StageTimer, build_pipeline

    with kernels(use_kernels):
        pipe = build_pipeline(profile, frames[0].frontend, config)
    out = []
    try:
        for f in frames:
            r = pipe.process(f, StageTimer(16))
            d = r.detections
            rec = {k: np.array(getattr(d, k), dtype=np.float64, copy=True) for k in DET_FIELDS}
            conf = [t for t in r.tracks if t.confirmed]
            rec["track_id"] = np.array([t.track_id for t in conf], dtype=np.int64)
            for k in TRACK_FIELDS:
                rec["track_" + k] = np.array([getattr(t, k) for t in conf], dtype=np.float64)
            # surveillance: provisional classes of the tracks and the events classified in this frame
            rec["track_cls"] = [(t.cls, t.class_probability) for t in conf]
            rec["events"] = [_event(e) for e in r.classifications]
            out.append(rec)
        flush = getattr(pipe, "flush", None)
        if out and flush is not None:
            out[-1]["events"] = out[-1]["events"] + [_event(e) for e in flush()]
    finally:
        pipe.close()
    return out


def _event(e: Any) -> tuple:
    """A classified event as a comparable tuple (exact floats)."""
    return (e.track_id, e.cls, tuple(sorted(e.probabilities.items())), e.mean_radial_speed_kmh, e.direction,
            e.start_ns, e.end_ns, tuple(sorted(e.features.items())), e.speed_uncertain)


def compare(a: list[dict[str, np.ndarray]], b: list[dict[str, np.ndarray]]) -> dict[str, Any]:
    """Frames whose detection count or confirmed-track ids differ, and the largest absolute difference per
    field over the frames where they agree (0.0 everywhere: bit-identical)."""
    rep: dict[str, Any] = {"frames": len(a), "count_mismatch_frames": [], "max_abs_diff": {}, "class_mismatch_frames": []}
    for k, (x, y) in enumerate(zip(a, b)):
        if x.get("events") != y.get("events") or x.get("track_cls") != y.get("track_cls"):
            rep["class_mismatch_frames"].append(k)
        if x["range_m"].size != y["range_m"].size or not np.array_equal(x["track_id"], y["track_id"]):
            rep["count_mismatch_frames"].append(k)
            continue
        for key in x:
            if key in ("track_id", "track_cls", "events") or x[key].size == 0:
                continue
            diff = np.abs(x[key] - y[key])
            both_nan = np.isnan(x[key]) & np.isnan(y[key])
            m = float(np.max(np.where(both_nan, 0.0, np.nan_to_num(diff, nan=np.inf))))
            rep["max_abs_diff"][key] = max(rep["max_abs_diff"].get(key, 0.0), m)
    rep["detections"] = int(sum(x["range_m"].size for x in a))
    rep["confirmed_track_frames"] = int(sum(x["track_id"].size for x in a))
    rep["events"] = int(sum(len(x.get("events", ())) for x in a))
    return rep


#: default largest difference of a confirmed track's position (m) or velocity (m/s): the tracker kernel's small
#: matrix products sum in another order than BLAS (about 1e-12 here); detections must be bit-identical
TRACK_ATOL = 1e-9


def agree(rep: dict[str, Any], atol: float = 0.0, track_atol: float = TRACK_ATOL) -> bool:
    """Same counts and ids in every frame; detections within ``atol``, tracks within ``track_atol``."""
    return not rep["count_mismatch_frames"] and not rep.get("class_mismatch_frames") and all(
        v <= (track_atol if k.startswith("track_") else atol) for k, v in rep["max_abs_diff"].items())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m edge.native.check", description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default=None,
                   help="hw_sim scenario (default highway4-traffic; tavanti-test1 for --profile surveillance)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--recording", help="a recording (.npz) instead of synthesised frames")
    p.add_argument("--profile", default="auto")
    p.add_argument("--atol", type=float, default=0.0,
                   help="largest allowed absolute difference of a detection field (default 0: bit for bit)")
    p.add_argument("--track-atol", type=float, default=TRACK_ATOL,
                   help=f"largest allowed difference of a confirmed track's state (default {TRACK_ATOL:g} m, m/s)")
    args = p.parse_args(argv)

    from edge import native
    from edge.config import load_config
    from edge.pipeline import resolve_profile

    print(native.status())
    if native.missing():
        return 2
    if args.recording:
        import itertools

        from hal import open_radar

        with open_radar(f"replay://{args.recording}?speed=0") as src:
            frames = list(itertools.islice(iter(src), args.frames))
    else:
        from edge.bench import synth_frames

        scenario = args.scenario or ("tavanti-test1" if args.profile == "surveillance" else "highway4-traffic")
        frames = synth_frames("simo" if args.profile in ("auto", "lane") else "d2g", scenario, args.seed,
                              args.frames)
    profile = resolve_profile(args.profile, frames[0].frontend.board)
    cfg = load_config(None)
    rep = compare(outputs(profile, frames, cfg, use_kernels=True), outputs(profile, frames, cfg, use_kernels=False))
    ok = agree(rep, args.atol, args.track_atol)
    print(f"{profile} profile, {rep['frames']} frames, {rep['detections']} detections, "
          f"{rep['confirmed_track_frames']} confirmed track-frames, {rep['events']} events: "
          + ("kernels == numpy reference" if ok else "DIFFERENT") + f" (atol {args.atol:g})")
    if rep["count_mismatch_frames"]:
        print(f"  detection count or confirmed track ids differ in {len(rep['count_mismatch_frames'])} frames, "
              f"first {rep['count_mismatch_frames'][:5]}")
    if rep["class_mismatch_frames"]:
        print(f"  track classes or classified events differ in {len(rep['class_mismatch_frames'])} frames, "
              f"first {rep['class_mismatch_frames'][:5]}")
    for k, v in sorted(rep["max_abs_diff"].items()):
        if v > 0:
            print(f"  max |difference| {k}: {v:.3g}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
