"""``radar-edge simulate``: write a recording of a simulated scenario."""

from __future__ import annotations

import argparse

NAME = "simulate"
HELP = "simulate a scenario and write a recording (.npz) with ground truth"
DESCRIPTION = """\
Runs a scenario through the IF simulator of its board (1x4 SIMO for lane scenarios, Distance2Go
for surveillance ones) and writes a versioned .npz recording: front-end description, int16 I/Q
frames, timestamps and per-frame ground truth. Replay it with `radar-edge replay FILE` or
`--source replay://FILE`."""
EPILOG = """\
examples:
  radar-edge simulate --scenario highway4 --frames 300 --out highway4.npz
  radar-edge simulate --scenario my-site.toml --seed 7 --out site.npz
  radar-edge simulate --list
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", help="built-in scenario name or path to a .toml file")
    p.add_argument("--frames", type=int, default=None, help="number of frames (default: the scenario's duration)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.add_argument("--out", help="output file (.npz)")
    p.add_argument("--list", action="store_true", help="list the built-in scenarios and exit")


def run(args: argparse.Namespace) -> int:
    from hal import open_radar
    from hal.recording import RecordingWriter
    from hw_sim.scenario import builtin_names, load_scenario

    if args.list:
        for name in builtin_names():
            sc = load_scenario(name)
            print(f"{name:<22}{sc.board:<6}{sc.duration_s:6.1f} s  {sc.description}")
        return 0
    if not args.scenario or not args.out:
        raise ValueError("--scenario and --out are required (see --help)")
    sc = load_scenario(args.scenario)
    url = f"sim://{sc.board}?realtime=0"
    opts = {"scenario": args.scenario}
    if args.seed is not None:
        opts["seed"] = args.seed
    if args.frames is not None:
        opts["frames"] = args.frames
    with open_radar(url, **opts) as src:
        n_total = args.frames or int(round(sc.duration_s / src.frontend.waveform.frame_period_s))
        writer = RecordingWriter(src.frontend, meta={"scenario": sc.name, "seed": src.seed, "board": sc.board})
        for frame in _progress(src, n_total):
            writer.add(frame)
    path = writer.save(args.out)
    print(f"wrote {len(writer)} frames of {sc.name!r} ({sc.board}) to {path}")
    return 0


def _progress(it, total: int):
    try:
        from tqdm import tqdm
    except ImportError:
        return it
    return tqdm(it, total=total, unit="frame", desc="simulating", leave=False)
