"""``radar-edge replay-traffic``: the traffic layer again on the tracks of a recorded evaluation."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from edge.commands.common import add_config_arguments, config_from_args

NAME = "replay-traffic"
HELP = "re-run the traffic layer (counts, lanes, events) on the tracks recorded by evaluate --record-tracks"
DESCRIPTION = """\
Runs the traffic layer -- lane assignment, counting at the detection line, interval statistics,
wrong-way and stopped-vehicle events -- again on the tracks that `radar-edge evaluate --record-tracks`
saved, with the recorded traffic settings changed by --set traffic.KEY=VALUE or a --config file,
and scores the counts against the recorded ground truth. Seconds instead of a full evaluation: the
way to try counting rules or lane geometry on the same traffic.

With no changes it reproduces the evaluation's counts exactly. Only `traffic` settings act on a
replay: the tracks themselves (pipeline.lane, track.pdaf) need a new evaluation, and the detection
line cannot move (the truth was recorded at it). The format is documented in
edge/evaluation/track_log.py."""
EPILOG = """\
examples:
  radar-edge evaluate --scenario highway4-traffic --seed 5 --record-tracks out/s5-tracks.npz --json out/s5.json
  radar-edge replay-traffic out/s5-tracks.npz                                  # the evaluation's counts again
  radar-edge replay-traffic out/s5-tracks.npz --set traffic.count_late_max_m=0 --json out/s5-no-late.json
  radar-edge replay-traffic out/s*-tracks.npz --set traffic.count_late_match_s=0.5   # several runs, one table
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", nargs="+", help="track log(s) written by radar-edge evaluate --record-tracks (.npz); with "
                                           "several, a table of their count errors follows")
    p.add_argument("--json", metavar="OUT", help="also write the result as JSON here (a list with several logs)")
    add_config_arguments(p)


def _traffic_settings(args: argparse.Namespace, recorded: dict):
    """The recorded traffic section (:func:`edge.evaluation.track_log.recorded_traffic_settings`) with the user's
    explicit traffic settings (file, environment, --set) on top."""
    from edge.config import ConfigError, build_section

    other = [k for k in (s.split("=", 1)[0].strip() for s in args.set) if not k.startswith("traffic.")]
    if other:
        raise ConfigError(f"{', '.join(other)}: a replay re-runs the traffic layer only; settings outside traffic.* "
                          "change the tracks and need a new radar-edge evaluate --record-tracks")
    cfg = config_from_args(args)
    user = dataclasses.asdict(cfg.section("traffic"))
    changed = {k: v for k, v in user.items() if f"traffic.{k}" in cfg.origin}
    return build_section("traffic", {**recorded, **changed}), changed


def _fmt(errors: list[int]) -> str:
    return "[" + ", ".join(f"{e:+d}" if e else "0" for e in errors) + "]"


def _replay_one(args: argparse.Namespace, path: str) -> dict:
    """Replay one log, print its block, return its JSON document."""
    from edge.evaluation.track_log import load_track_log, recorded_traffic_settings, replay_traffic

    log = load_track_log(path)
    meta = log.meta
    recorded, unknown = recorded_traffic_settings(log)
    traffic_cfg, changed = _traffic_settings(args, recorded)
    progress = None
    bar = None
    if sys.stderr.isatty():
        try:
            from tqdm import tqdm
        except ImportError:  # (tqdm comes with the train and test extras)
            tqdm = None
        if tqdm is not None:
            bar = tqdm(total=log.frames, desc=f"replay-traffic {Path(path).name}", unit="frame")
            progress = lambda n: bar.update(n - bar.n)  # noqa: E731
    try:
        result = replay_traffic(log, traffic_cfg, progress)
    finally:
        if bar is not None:
            bar.close()
    rec, new = meta["counts"], result["counts"]
    print(f"{path}: {meta['scenario']} seed {meta['seed']}, {meta['frames']} frames, {len(log.true_crossings)} true "
          f"crossings of the line at {traffic_cfg.detection_line_m:g} m")
    print("changed: " + (", ".join(f"traffic.{k}={v!r}" for k, v in changed.items()) or "nothing (recorded settings)"))
    if unknown:
        print("recorded settings this version does not have (dropped): " + ", ".join(f"traffic.{k}" for k in unknown))
    print(f"lanes at the end          {result['lane_centers_m']} m ({traffic_cfg.lane_mode}), mounting yaw "
          f"{result['estimated_yaw_deg']:.2f} deg")
    print(f"true volume per lane      {new['volume_true_per_lane']}")
    print(f"count error per lane      recorded {_fmt(rec['count_error_per_lane'])} -> replayed "
          f"{_fmt(new['count_error_per_lane'])}")
    for kind in ("missed", "extra", "straddling"):
        items = new["count_mismatches"].get(kind, [])
        was = len(rec.get("count_mismatches", {}).get(kind, []))
        print(f"{kind:<6} {len(items)} (recorded {was})" + (": " if items else ""))
        for it in items:
            print("    " + ", ".join(f"{k}={v}" for k, v in it.items()))
    kinds = sorted({e["kind"] for e in result["events"]} | {e["kind"] for e in meta["events"]})
    for k in kinds:
        print(f"{k} events {sum(e['kind'] == k for e in result['events'])} "
              f"(recorded {sum(e['kind'] == k for e in meta['events'])})")
    return {"track_log": str(path), "scenario": meta["scenario"], "seed": meta["seed"], "frames": meta["frames"],
            "changed": changed, "dropped_recorded_settings": unknown,
            "recorded": {"counts": rec, "events": meta["events"]}, **result}


def run(args: argparse.Namespace) -> int:
    docs = []
    for n, path in enumerate(args.file):
        if n:
            print()
        docs.append(_replay_one(args, path))
    if len(docs) > 1:  # the logs side by side: per-lane errors and the sum of their magnitudes, recorded -> replayed
        print()
        w = max(len(d["track_log"]) for d in docs)
        print(f"{'track log':<{w}}  {'recorded':<22} {'replayed':<22} |error| recorded -> replayed")
        tot_r = tot_n = 0
        for d in docs:
            er, en = d["recorded"]["counts"]["count_error_per_lane"], d["counts"]["count_error_per_lane"]
            sr, sn = sum(map(abs, er)), sum(map(abs, en))
            tot_r, tot_n = tot_r + sr, tot_n + sn
            print(f"{d['track_log']:<{w}}  {_fmt(er):<22} {_fmt(en):<22} {sr} -> {sn}")
        print(f"{'all':<{w}}  {'':<22} {'':<22} {tot_r} -> {tot_n}")
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(docs[0] if len(docs) == 1 else docs, indent=2) + "\n", encoding="utf-8")
    return 0
