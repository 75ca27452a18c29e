"""``radar-edge soak``: hours of traffic in accelerated replay, with memory and consistency checks."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from edge.commands.common import add_config_arguments, config_from_args
from edge.config import parse_set_option

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
  radar-edge soak --frames 3000 --seq-start 65000 --set traffic.interval_s=5   # counters wrap early
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", default="lane", help="lane | surveillance | minimal (default lane)")
    p.add_argument("--frames", type=int, default=200_000, help="frames to run (default 200000)")
    p.add_argument("--record-frames", type=int, default=2000, help="distinct frames synthesised and looped")
    p.add_argument("--scenario", help="scenario (default: the profile's standard scene)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--no-outputs", action="store_true", help="without Modbus/CAN sinks")
    p.add_argument("--seq-start", type=int, default=0, metavar="N",
                   help="board frame counter of the first frame (e.g. 65400: the 16-bit output counters wrap early)")
    p.add_argument("--json", metavar="OUT", help="write the JSON report here")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    from edge.pipeline import PIPELINES
    from edge.soak import run_soak

    if args.profile not in PIPELINES:
        raise ValueError(f"unknown or unavailable profile {args.profile!r}; available: {', '.join(sorted(PIPELINES))}")
    # outputs on an OS-chosen Modbus TCP port and a private virtual CAN bus, unless --set says otherwise
    given = {parse_set_option(x)[0] for x in args.set}
    defaults = {"outputs.modbus.tcp_port": 0, "outputs.can.interface": "virtual",
                "outputs.can.channel": f"radar-edge-soak-{os.getpid()}"}
    extra = {k: v for k, v in defaults.items() if k not in given and _has_key(k.rsplit(".", 1)[0])}
    cfg = config_from_args(args, extra)
    rep = run_soak(args.profile, cfg, frames=args.frames, record_frames=args.record_frames, scenario=args.scenario,
                   seed=args.seed, outputs=not args.no_outputs, progress=sys.stderr.isatty(),
                   seq_start=args.seq_start)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(rep, indent=2) + "\n", encoding="utf-8")
    r = rep["rss_mb"]
    print(f"{rep['frames']} frames ({rep['simulated_hours']:.2f} h of {rep['scenario']}) in {rep['wall_s']:.0f} s, "
          f"{rep['frames_per_s']:.0f} frames/s")
    print(f"RSS {r['at_10pct']:.1f} MB at 10 %, {r['at_end']:.1f} MB at the end: "
          f"growth {r['growth_10_to_100pct']:+.2f} MB")
    t = rep["tracks"]
    print(f"tracks: {t['distinct_ids']} distinct ids, max id {t['max_id']}, max concurrent {t['max_concurrent']}, "
          f"ids recycled {t['id_reuses']} times")
    if rep["lane_intervals"]:
        print(f"lanes {rep['n_lanes']}: intervals closed {rep['lane_intervals']}, vehicles {rep['lane_volume']}")
    mb = rep.get("modbus")
    if mb:
        print(f"Modbus image read back {mb['reads']} times, frame counter wrapped {mb['frame_counter_wraps']} times; "
              f"server process RSS {mb['server_rss_mb']['at_end']:.1f} MB")
    print(f"errors {rep['errors']}, output errors {rep['sink_errors']}, dropped frames {rep['dropped_frames']}, "
          f"problems {rep['n_problems']}")
    for p in rep["problems"][:10]:
        print("  problem:", p)
    return 0 if rep["n_problems"] == 0 and rep["errors"] == 0 and rep["sink_errors"] == 0 else 1


def _has_key(section: str) -> bool:
    from edge.config import SECTIONS

    return section in SECTIONS
