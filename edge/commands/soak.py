"""``radar-edge soak``: hours of traffic in accelerated replay, with memory and consistency checks."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from edge.commands.common import add_config_arguments, config_from_args

NAME = "soak"
HELP = "run hundreds of thousands of frames through pipeline and outputs; report memory growth and consistency"
DESCRIPTION = """\
Synthesises a seeded scenario once and replays it in a loop as fast as possible through the whole
frame loop, with the outputs attached (Modbus image, CAN encoding). Samples resident memory and
checks that track ids stay unique and recycle, frame and interval counters advance (and wrap)
cleanly, and lane statistics stay consistent. 200 000 lane frames are about two hours of traffic."""
EPILOG = """\
examples:
  radar-edge soak --profile lane --frames 200000 --json out/soak-lane.json
  radar-edge soak --profile surveillance --frames 20000 --no-outputs
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", default="lane", help="lane | surveillance | minimal (default lane)")
    p.add_argument("--frames", type=int, default=200_000, help="frames to run (default 200000)")
    p.add_argument("--record-frames", type=int, default=2000, help="distinct frames synthesised and looped")
    p.add_argument("--scenario", help="scenario (default: the profile's standard scene)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--no-outputs", action="store_true", help="without Modbus/CAN sinks")
    p.add_argument("--json", metavar="OUT", help="write the JSON report here")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    from edge.pipeline import PIPELINES
    from edge.soak import run_soak

    if args.profile not in PIPELINES:
        raise ValueError(f"unknown or unavailable profile {args.profile!r}; available: {', '.join(sorted(PIPELINES))}")
    extra = {"outputs.modbus.tcp_port": 0} if _has_key("outputs.modbus") else {}
    cfg = config_from_args(args, extra)
    rep = run_soak(args.profile, cfg, frames=args.frames, record_frames=args.record_frames, scenario=args.scenario,
                   seed=args.seed, outputs=not args.no_outputs, progress=sys.stderr.isatty())
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(rep, indent=2) + "\n", encoding="utf-8")
    r = rep["rss_mb"]
    print(f"{rep['frames']} frames ({rep['simulated_hours']:.2f} h of {rep['scenario']}) in {rep['wall_s']:.0f} s, "
          f"{rep['frames_per_s']:.0f} frames/s")
    print(f"RSS {r['at_10pct']:.1f} MB at 10 %, {r['at_end']:.1f} MB at the end: growth {r['growth_10_to_100pct']:+.2f} MB")
    print(f"tracks: {rep['tracks']['distinct_ids']} distinct ids, max id {rep['tracks']['max_id']}, "
          f"max concurrent {rep['tracks']['max_concurrent']}; errors {rep['errors']}, problems {rep['n_problems']}")
    for p in rep["problems"][:10]:
        print("  problem:", p)
    return 0 if rep["n_problems"] == 0 and rep["errors"] == 0 else 1


def _has_key(section: str) -> bool:
    from edge.config import SECTIONS

    return section in SECTIONS
