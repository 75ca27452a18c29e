"""``radar-edge replay``: run the pipeline on a recording."""

from __future__ import annotations

import argparse

from edge.commands import run as run_cmd

NAME = "replay"
HELP = "run the pipeline on a recording, at recorded speed or as fast as possible"
DESCRIPTION = """\
Shorthand for `radar-edge run --source replay://FILE?speed=S`: replays a recording made by
`radar-edge simulate` (or recorded on a device) through the pipeline of its board's profile."""
EPILOG = """\
examples:
  radar-edge replay highway4.npz             # at the recorded frame rate
  radar-edge replay highway4.npz --speed 0   # as fast as possible
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="recording (.npz)")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed; 0 = as fast as possible (default 1)")
    p.add_argument("--loop", action="store_true", help="start again at the end")
    run_cmd.add_loop_arguments(p)


def run(args: argparse.Namespace) -> int:
    if args.speed < 0:
        raise ValueError("--speed must be >= 0")
    args.source = f"replay://{args.file}?speed={args.speed:g}&loop={int(args.loop)}"
    return run_cmd.run(args)
