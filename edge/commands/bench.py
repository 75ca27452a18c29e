"""``radar-edge bench``: frame-time budget figures, peer pipeline and FFT bound."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from edge.commands.common import add_config_arguments, config_from_args

NAME = "bench"
HELP = "measure per-stage and whole-frame p50/p99 against the budget, vs a peer pipeline and the FFT bound"
DESCRIPTION = """\
Synthesises N frames of a scenario (seeded, untimed), then times the profile's pipeline on them
single-threaded: p50/p99 per stage and per frame as a fraction of the frame budget (33 ms lane,
200 ms surveillance), peak RSS, start-up time of a fresh process to its first frame, and -- on the
same frames -- the FFT-only lower bound and a peer pipeline built from general-purpose tools
(float64 numpy, scikit-learn, Stone Soup), both as ratios. Numbers depend on the machine: compare
runs on the same one. Set OMP_NUM_THREADS=1 for strictly single-threaded library code.
The frame is also reported in thread CPU time ("frame CPU time": no preemption by other processes)
and, with --repeat N, as percentiles of each frame's fastest run ("frame min/runs"): on a shared
machine other processes disturb a few frames of every run, and three disturbed frames set a p99
of 300 frames. --instructions adds instructions per frame under valgrind's callgrind, counted after
a warm-up in a replay child whose imports run uninstrumented: the repeatable speed figure."""
EPILOG = """\
examples:
  radar-edge bench --profile lane --frames 300 --json out/bench-lane.json
  OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 radar-edge bench --profile lane --repeat 5
  radar-edge bench --profile surveillance --frames 100
  radar-edge bench --profile minimal --no-peer --no-startup
  radar-edge bench --profile lane --scenario highway4-traffic --instructions --no-peer --no-startup
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", default="lane", help="lane | surveillance | minimal (default lane)")
    p.add_argument("--frames", type=int, default=300, help="frames to time (default 300)")
    p.add_argument("--scenario", help="scenario to synthesise (default: the profile's standard scene)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--no-peer", action="store_true", help="skip the peer pipeline")
    p.add_argument("--peer-frames", type=int, default=None, metavar="N",
                   help="frames given to the (slow) peer pipeline (default: a fifth of --frames, at least 30)")
    p.add_argument("--no-startup", action="store_true", help="skip the start-up measurement")
    p.add_argument("--repeat", type=int, default=1, metavar="N",
                   help="time the pipeline and the bound N times, keep the lowest p99, and report each frame's "
                        "fastest run as 'frame min/runs' (busy machines; default 1)")
    p.add_argument("--instructions", action="store_true",
                   help="also count instructions per frame of the pipeline and the FFT-only bound under valgrind's "
                        "callgrind (repeatable on any machine of the architecture; needs valgrind)")
    p.add_argument("--instr-warmup", type=int, default=100, metavar="N",
                   help="frames run before counting (default 100: tracks confirmed, clutter map learnt)")
    p.add_argument("--instr-frames", type=int, default=50, metavar="N", help="frames counted (default 50)")
    p.add_argument("--json", metavar="OUT", help="write the JSON report here")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    from edge.bench import run_bench
    from edge.pipeline import PIPELINES

    if args.profile not in PIPELINES:
        raise ValueError(f"unknown or unavailable profile {args.profile!r}; available: {', '.join(sorted(PIPELINES))}")
    if args.frames < 10:
        raise ValueError("--frames must be at least 10 for a meaningful p99")
    if args.instructions:
        from edge.bench.instructions import valgrind_missing

        if valgrind_missing():
            raise ValueError(valgrind_missing())
        if args.instr_warmup < 0 or args.instr_frames < 1:
            raise ValueError("--instr-warmup must be >= 0 and --instr-frames >= 1")
    cfg = config_from_args(args)
    rep = run_bench(args.profile, cfg, frames=args.frames, scenario=args.scenario, seed=args.seed,
                    peer=not args.no_peer, startup=not args.no_startup, progress=sys.stderr.isatty(),
                    peer_frames=args.peer_frames, repeat=args.repeat)
    if args.instructions:
        from edge.bench import board_of, synth_frames
        from edge.bench.instructions import measure

        n = args.instr_warmup + 2 * args.instr_frames
        frames = synth_frames(board_of(args.profile), args.scenario, args.seed, n)
        config_args = ([f"--config={args.config}"] if args.config else []) + [f"--set={s}" for s in args.set]
        rep["instructions"] = measure(frames, args.profile, warmup=args.instr_warmup, frames=args.instr_frames,
                                      config_args=config_args)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(rep, indent=2) + "\n", encoding="utf-8")
    print("\n".join(report_lines(rep)))
    return 0


def report_lines(rep: dict) -> list[str]:
    """The human-readable table of a bench report."""
    fr = rep["frame"]
    budget = fr["budget_ms"]
    best = f", best of {rep['repeat']} runs" if rep.get("repeat", 1) > 1 else ""
    out = [f"profile {rep['profile']}: {rep['frames']} frames of {rep['scenario']} (seed {rep['seed']}), "
           f"budget {budget:.0f} ms, single-threaded{best}",
           f"{'stage':<16}{'p50 ms':>9}{'p99 ms':>9}{'p50/budget':>12}{'p99/budget':>12}"]
    for name, s in rep["stages"].items():
        out.append(f"{name:<16}{s['p50_ms']:9.3f}{s['p99_ms']:9.3f}{s['p50_ms'] / budget:12.2%}"
                   f"{s['p99_ms'] / budget:12.2%}")
    out.append(f"{'frame':<16}{fr['p50_ms']:9.3f}{fr['p99_ms']:9.3f}{fr['p50_ms'] / budget:12.2%}"
               f"{fr['p99_budget_fraction']:12.2%}")
    if fr.get("cpu_p99_ms") is not None:  # thread CPU time of the same frames (no preemption by other processes)
        out.append(f"{'frame CPU time':<16}{fr['cpu_p50_ms']:9.3f}{fr['cpu_p99_ms']:9.3f}"
                   f"{fr['cpu_p50_ms'] / budget:12.2%}{fr['cpu_p99_ms'] / budget:12.2%}")
    if fr.get("min_over_runs_p99_ms") is not None:  # each frame's fastest run: without other processes' interference
        out.append(f"{'frame min/runs':<16}{fr['min_over_runs_p50_ms']:9.3f}{fr['min_over_runs_p99_ms']:9.3f}"
                   f"{fr['min_over_runs_p50_ms'] / budget:12.2%}{fr['min_over_runs_p99_ms'] / budget:12.2%}")
    b = rep.get("fft_bound")
    if b:
        out.append(f"{'FFT-only bound':<16}{b.get('p50_ms', float('nan')):9.3f}{b['p99_ms']:9.3f}"
                   f"   -> pipeline p99 is {b['ratio']:.2f}x the bound")
    p = rep.get("peer")
    if p:
        out.append(f"{'peer pipeline':<16}{p['p50_ms']:9.3f}{p['p99_ms']:9.3f}   -> pipeline p99 is {p['ratio']:.1f}x "
                   f"faster ({p['frames']} frames)")
        if p.get("description"):
            out.append(f"  peer: {p['description']}")
    elif rep.get("peer_unavailable"):
        out.append(f"peer pipeline: not measured -- {rep['peer_unavailable']}")
    lat = rep.get("classifier_latency")
    if lat:
        if "error" in lat:
            out.append(f"classifier latency: not measured -- {lat['error']}")
        else:
            parts = [f"{k} p50 {v['p50_us']:.0f} us / p99 {v['p99_us']:.0f} us"
                     for k, v in (("onnxruntime", lat.get("onnxruntime")), ("numpy", lat.get("numpy"))) if v]
            out.append(f"classifier per query (batch {lat.get('batch', 1)}): " + ", ".join(parts))
    ins = rep.get("instructions")
    if ins:
        line = (f"instructions per frame (callgrind, {ins['frames']} frames after {ins['warmup_frames']}): "
                f"pipeline {ins['pipeline_per_frame'] / 1e6:.2f} M")
        if ins.get("fft_bound_per_frame"):
            line += f", FFT-only bound {ins['fft_bound_per_frame'] / 1e6:.2f} M ({ins['ratio']:.1f}x)"
        out.append(line)
    line = f"peak RSS {rep['peak_rss_mb']:.0f} MB (this process)"
    if rep.get("startup_s"):
        st = rep.get("startup") or {}
        line += f"; radar-edge run: first frame {rep['startup_s']:.2f} s after start"
        if st.get("run_peak_rss_mb"):
            line += f", peak RSS {st['run_peak_rss_mb']:.0f} MB"
    out.append(line)
    env = rep.get("threads_env") or {}
    if env and not all(v == "1" for v in env.values()):
        out.append("note: OMP_NUM_THREADS/OPENBLAS_NUM_THREADS are not 1: BLAS may use threads (the service "
                   "unit sets them to 1; do the same for figures comparable with the device)")
    return out
