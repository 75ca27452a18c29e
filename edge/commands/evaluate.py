"""``radar-edge evaluate``: run a scenario through its profile's pipeline and score it against truth."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from edge.commands.common import add_config_arguments, config_from_args, emit_json

NAME = "evaluate"
HELP = "score a pipeline against simulator ground truth (RMSE, detection probability, confusion matrix)"
DESCRIPTION = """\
Runs a scenario through its profile's pipeline without real-time pacing and compares every frame
with the simulator's ground truth. The JSON report (DESIGN §6 keys) holds per-target figures
(tracked fraction, position RMSE, speed error, class) and a summary (detection probability, false
tracks per minute, id switches, lane accuracy, per-lane count error, classification accuracy and
confusion matrix), plus frame times against the budget. Lane profile: each closed interval's per-lane statistics
(volume, occupancy, mean and 85th-percentile speed, headway, gap, counts per length class) against the truth, and
each vehicle's measured length and length class against its true one. With --json, a rounded summary and those
tables are printed (the file keeps full precision).

With --corpus FILE instead of --scenario, runs every (run, seed, variant) of one part of a declared evaluation corpus
(edge.evaluation.corpus: scenarios x variants x seeds, dev and holdout) in --jobs worker processes, and writes one
JSON with each run's figures and tallies and the metrics pooled per variant and over all runs as ratios of sums,
each with a 95 % cluster-bootstrap confidence interval over runs; --plot draws them as an SVG (surveillance:
with each variant's confusion matrix); --targets writes every run's per-target rows as JSON lines, to list what
failed where."""
EPILOG = """\
examples:
  radar-edge evaluate --scenario highway4 --json out/highway4.json
  radar-edge evaluate --scenario multi-random --events 20 --seed 3 --json out/multi.json
  radar-edge evaluate --scenario highway4-traffic --seed 7 --scenario-set radar.height_m=10 --json out/h10.json
  radar-edge evaluate --scenario highway4-traffic --seed 5 --record-tracks out/s5-tracks.npz --json out/s5.json
  radar-edge replay-traffic out/s5-tracks.npz --set traffic.count_late_max_m=0   # counting rules, in seconds
  radar-edge evaluate --corpus corpus/lane.toml --part dev --jobs 2 --json out/lane-dev.json --plot out/lane-dev.svg
  radar-edge evaluate --corpus corpus/surveillance.toml --part both --jobs 2 --json out/surv.json
  radar-edge evaluate --corpus corpus/surveillance.toml --part dev --jobs 2 --json out/dev.json --targets out/dev.jsonl
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", help="built-in scenario name, event generator, or .toml path (or --corpus)")
    p.add_argument("--corpus", metavar="FILE", help="an evaluation corpus file (TOML, edge.evaluation.corpus) "
                   "instead of --scenario")
    p.add_argument("--part", choices=("dev", "holdout", "both"), default="dev",
                   help="--corpus: which part to run (default dev)")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="--corpus: worker processes (default 1)")
    p.add_argument("--plot", metavar="OUT.svg", help="--corpus: also draw the pooled metrics with their intervals "
                   "(surveillance: and each variant's confusion matrix)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.add_argument("--frames", type=int, default=None, help="limit the number of frames")
    p.add_argument("--events", type=int, default=None, help="number of events for event generators")
    p.add_argument("--json", metavar="OUT", help="write the report here (default: print it)")
    p.add_argument("--targets", metavar="OUT.jsonl",
                   help="--corpus: also write every run's target rows (truth, what was published, the errors) as JSON "
                        "lines, each with its part, scenario, seed and variant (a single run's --json report has them)")
    p.add_argument("--record-tracks", metavar="FILE",
                   help="lane profile: also save the traffic layer's input (tracks per frame) and the true crossings "
                        "of the detection line, for radar-edge replay-traffic (about 17 MB for ten minutes of "
                        "four-lane traffic)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--scenario-set", action="append", default=[], metavar="KEY=VALUE",
                   help="change the simulated world, e.g. radar.height_m=10, physics.preset=v1 or "
                        "traffic.weave_sdlp_m=0.2 (set on every [[traffic]] table); TOML values, repeatable")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    from edge.evaluation import evaluate

    from edge.extras import available, install_hint

    if (args.corpus is None) == (args.scenario is None):
        print("radar-edge evaluate: give either --scenario or --corpus", file=sys.stderr)
        return 2
    if args.corpus is not None:
        return run_corpus(args)
    if args.targets is not None:
        print("radar-edge evaluate: --targets applies to --corpus (a single run's --json report has its targets)",
              file=sys.stderr)
        return 2
    cfg = config_from_args(args)
    progress = not args.no_progress and sys.stderr.isatty()
    if progress and not available("tqdm"):
        logging.getLogger(__name__).warning("no progress bar: tqdm is not installed (%s)", install_hint("tqdm"))
        progress = False
    from hw_sim.scenario import ScenarioError, patch_from_assignments

    try:
        patch = patch_from_assignments(args.scenario_set)
    except ScenarioError as exc:
        print(f"radar-edge evaluate: {exc}", file=sys.stderr)
        return 2
    report = evaluate(
        args.scenario, seed=args.seed, frames=args.frames, events=args.events, config=cfg,
        progress=progress, record_tracks=args.record_tracks, patch=patch,
    )
    emit_json(report, args.json)
    if args.json:
        print(console_summary(report))
    return 0


def run_corpus(args: argparse.Namespace) -> int:
    """``--corpus``: every run of the part(s) in worker processes, then the pooled document (module doc)."""
    from edge.evaluation.corpus import check_scenarios, console_table, corpus_document, load_corpus, run_jobs
    from edge.evaluation.corpus_plot import write_corpus_svg

    for opt in ("seed", "frames", "events", "record_tracks"):
        if getattr(args, opt) is not None:
            print(f"radar-edge evaluate: --{opt.replace('_', '-')} does not apply to --corpus (the corpus file "
                  "declares its runs)", file=sys.stderr)
            return 2
    if args.scenario_set:
        print("radar-edge evaluate: --scenario-set does not apply to --corpus (declare a variant)", file=sys.stderr)
        return 2
    if args.jobs < 1:
        print("radar-edge evaluate: --jobs must be at least 1", file=sys.stderr)
        return 2
    config_from_args(args)  # a bad --config or --set stops here, before any worker starts
    corpus = load_corpus(args.corpus)
    parts = ("dev", "holdout") if args.part == "both" else (args.part,)
    check_scenarios(corpus, parts)
    results = {}
    for part in parts:
        jobs = [dict(j, config=args.config, extra_set=list(args.set), targets=bool(args.targets))
                for j in corpus.jobs(part)]
        if not jobs:
            print(f"radar-edge evaluate: the corpus has no {part} runs", file=sys.stderr)
            return 2
        results[part] = run_jobs(jobs, args.jobs, progress=not args.no_progress, desc=f"corpus {part}")
    if args.targets:
        _write_targets(results, args.targets)
    doc = corpus_document(corpus, results, list(args.set))
    emit_json(doc, args.json)
    if args.plot:
        write_corpus_svg(doc, args.plot)
    print(console_table(doc), file=sys.stdout if args.json else sys.stderr)
    return 0


def _write_targets(results: dict[str, list[dict]], path: str) -> None:
    """Take the target rows out of the runs' records and write them to ``path``, one JSON line per target."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", encoding="utf-8") as fh:
        for part, recs in results.items():
            for rec in recs:
                key = {"part": part, "scenario": rec["scenario"], "seed": rec["seed"], "variant": rec["variant"]}
                for row in rec.pop("targets", None) or ():
                    fh.write(json.dumps({**key, **row}) + "\n")


def _num(v) -> str:
    """A figure for the console: 3 decimals, 1 from 100 on (the JSON keeps full precision); n/a for None/NaN."""
    if v is None or (isinstance(v, float) and v != v):
        return "n/a"
    if isinstance(v, bool) or isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return f"{v:.1f}" if abs(v) >= 100 else f"{v:.3f}"
    return str(v)


def _table(header: list[str], rows: list[list]) -> list[str]:
    cells = [header] + [[_num(c) for c in r] for r in rows]
    w = [max(len(r[i]) for r in cells) for i in range(len(header))]
    return ["  " + "  ".join(c.rjust(w[i]) if i else c.ljust(w[i]) for i, c in enumerate(r)) for r in cells]


def _err(e: dict | None, pct: bool = False) -> list:
    """mean, mean |e|, max |e| and share within tolerance of an error summary."""
    if not e or not e.get("n"):
        return ["n/a"] * 4
    within = e.get("within_tolerance")
    return [e["mean"], e["mean_abs"], e["max_abs"], "" if within is None else f"{100 * within:.0f}%"]


def console_summary(report: dict) -> str:
    """The report's summary for a terminal: one scalar a line, rounded; for the lane profile tables of the interval
    statistics and vehicle lengths against the truth."""
    s = report.get("summary", {})
    lines = [f"{report.get('scenario')} (seed {report.get('seed')}, {report.get('frames')} frames)"]
    lines += [f"  {k:<34} {_num(v)}" for k, v in s.items() if not isinstance(v, (dict, list))]
    if isinstance(s.get("count_error_per_lane"), list):
        lines.append(f"  {'count_error_per_lane':<34} {s['count_error_per_lane']}")
    iv = s.get("intervals")
    if iv:
        lines.append("interval statistics against the truth (measured - true; within: share of intervals in tolerance)")
        rows = []
        for name, unit, key in (("volume", "veh", "volume_error"), ("occupancy", "pp", "occupancy_error_pp"),
                                ("mean speed", "km/h", "mean_speed_error_kmh"),
                                ("85th pct speed", "km/h", "speed_p85_error_kmh"), ("headway", "s", "headway_error_s"),
                                ("gap", "%", "gap_error_pct"), ("mean length", "m", "mean_length_error_m")):
            a = iv["all_lanes"][key]
            per = [_num(iv["per_lane"][k][key]["mean_abs"]) for k in sorted(iv["per_lane"], key=int)]
            rows.append([f"{name} ({unit})", a["n"], *_err(a)[:3], _err(a)[3], " ".join(per)])
        lines += _table(["quantity", "n", "mean", "mean|e|", "max|e|", "within", "mean|e| per lane"], rows)
        g = iv["all_lanes"].get("gap_mean_s")
        if g:
            lines.append(f"  mean gap over the run: measured {_num(g[0])} s, true {_num(g[1])} s; "
                         f"intervals with a true gap but none measured: {iv['all_lanes'].get('gap_intervals_na')}")
    vl = s.get("vehicle_lengths")
    if vl:
        lines.append("vehicle lengths of the vehicles that crossed the line (measured - true)")
        rows = []
        for name, g in list(vl["by_kind"].items()) + [(f"[{c}]", g) for c, g in vl["by_class"].items()]:
            e = g["length_error_m"] or {}
            rows.append([name, g["vehicles"], g["length_measured_fraction"], e.get("mean"), e.get("sd"),
                         e.get("p5"), e.get("p95"), g["length_class_accuracy"], g["body_class_accuracy"]])
        lines += _table(["kind [body class]", "n", "measured", "err mean m", "sd", "p5", "p95", "class acc",
                         "body class acc"], rows)
    return "\n".join(lines)
