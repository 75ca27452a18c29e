"""``radar-edge plot``: a recording as pictures."""

from __future__ import annotations

import argparse
from pathlib import Path

from edge.commands.common import add_config_arguments, config_from_args

NAME = "plot"
HELP = ("render a recording as PNGs (range over time, range-Doppler/range-azimuth map, road view, lane statistics), "
        "or an evaluation report's accuracy")
DESCRIPTION = """\
Replays a recording (radar-edge simulate, or the on-device recorder in /var/lib/radar-edge/recordings)
through its profile's pipeline and draws:

  FILE-range-time.png  range profile of every frame (waterfall), detections, track ids, ground truth
  FILE-frame-map.png   one frame: range-Doppler map with clusters and track ids (Distance2Go,
                       Tavanti Fig. 9) or range-azimuth map in road coordinates (SIMO, Lim Fig. 12)
  FILE-road.png        detections and track trajectories in road coordinates with the lanes
                       (Lim Figs. 12-14)
  FILE-lanes.png       lane statistics over time (volume, mean speed, occupancy), or per-frame
                       detections/tracks/presence when the profile has no lane statistics

Figures use what the pipeline returns (detections, tracks, FrameResult.intermediates) and say so
when a field is absent.

Given a report of radar-edge evaluate (.json) instead, draws FILE-accuracy.png: for the lane profile
the position RMSE per 50 m range bin, the detection probability per class and range bin against the
99 % line, and the detection probability apart from and while overlapping another vehicle (with the
untracked frames split into acquisition, gaps and loss); for the surveillance profile the confusion
matrix and the detection probability per class.

Needs matplotlib (pip install 'radar-edge[plot]')."""
EPILOG = """\
examples:
  radar-edge simulate --scenario highway4 --frames 300 --out highway4.npz
  radar-edge plot highway4.npz --out plots/
  radar-edge plot rec.npz --figure frame-map --frame 120
  radar-edge plot /var/lib/radar-edge/recordings/20260101T120000Z-00001234-surveillance.npz --profile minimal
  radar-edge evaluate --scenario highway4-traffic --json out/traffic.json && radar-edge plot out/traffic.json --out plots/
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="recording (.npz), or a radar-edge evaluate report (.json)")
    p.add_argument("--out", default=".", metavar="DIR", help="directory for the PNGs (default: current)")
    p.add_argument("--figure", action="append", choices=("range-time", "frame-map", "road", "lanes"),
                   help="only this figure (repeatable; default: all)")
    p.add_argument("--frame", type=int, default=None, metavar="K", help="frame for frame-map (default: the busiest)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="use only the first N frames")
    p.add_argument("--profile", choices=("auto", "lane", "surveillance", "minimal"), help="pipeline profile")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    from edge.ops.plots import FIGURES, PlotError, render, replay, require_matplotlib

    try:
        require_matplotlib()
    except PlotError as exc:
        print(f"radar-edge plot: {exc}")
        return 2
    if str(args.file).lower().endswith(".json"):
        from edge.ops.report_plots import load_report, plot_report

        try:
            print(plot_report(load_report(args.file), args.out, Path(args.file).stem))
        except PlotError as exc:
            print(f"radar-edge plot: {exc}")
            return 2
        return 0
    cfg = config_from_args(args)
    rep = replay(args.file, cfg, args.profile if args.profile and args.profile != "auto" else None, args.frames)
    for path in render(rep, args.out, tuple(args.figure or FIGURES), args.frame):
        print(path)
    return 0
