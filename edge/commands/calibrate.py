"""``radar-edge calibrate``: derive the surveillance threshold th_RD from frames of an empty scene."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from edge.commands.common import add_config_arguments, config_from_args

NAME = "calibrate"
HELP = "derive the surveillance detection threshold th_RD from frames of an empty scene"
DESCRIPTION = """\
Tavanti et al. set th_RD from radar frames taken with no moving target in view: every frame goes
through the IIR clutter/leakage canceller and the range-Doppler map, the largest map amplitude of
each frame is kept, and the first estimate of th_RD is the mean of these maxima. That estimate is
"often too low" (the paper then corrects it by hand), so this command adds a documented margin:

    th_RD = mean(maxima) + K * std(maxima)      (K = --margin-std, default 3)

With K = 3 only a fraction of a percent of empty frames reach the threshold anywhere on the map, and
a single bin over threshold never makes a DBSCAN cluster (M points are needed). The maps use the
canceller and window settings of the configuration (pipeline.surveillance.k_c, k_sf, n_range_fft,
n_doppler_fft). Point the source at the installed board with nothing moving in its beam (people,
vehicles, swaying branches) for at least a few dozen frames; the default is the simulated site."""
EPILOG = """\
examples:
  radar-edge calibrate                                   # simulated empty site (sim://d2g, empty-d2g)
  radar-edge calibrate --source d2g:///dev/ttyACM0 --frames 300 --json th.json
  radar-edge calibrate --frames 100 --margin-std 2 --set pipeline.surveillance.k_c=0.3

then use the result:  radar-edge run --set pipeline.surveillance.th_rd=VALUE   (or [pipeline.surveillance]
th_rd = VALUE in the configuration file)
"""

DEFAULT_SOURCE = "sim://d2g?scenario=empty-d2g&realtime=0"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", default=DEFAULT_SOURCE, help=f"radar source URL with an empty scene (default: {DEFAULT_SOURCE})")
    p.add_argument("--frames", type=int, default=50, help="frames to use (default: 50 = 10 s)")
    p.add_argument("--skip", type=int, default=0, help="frames to discard first (warm-up)")
    p.add_argument("--margin-std", type=float, default=3.0, help="K in th_RD = mean + K * std of the per-frame maxima (default: 3)")
    p.add_argument("--json", metavar="OUT", help="also write the statistics and the result here")
    add_config_arguments(p)


def calibrate_threshold(frames, processor, *, margin_std: float = 3.0) -> dict:
    """Per-frame maxima of the canceller's range-Doppler maps -> th_RD statistics.

    ``frames``: iterable of :class:`~hal.frame.RawFrame`; ``processor`` a
    :class:`~edge.dsp.range_doppler.RangeDopplerProcessor`. Returns a dict with ``th_rd``,
    ``mean_of_maxima`` (the paper's first estimate), ``std_of_maxima``, percentiles and ``frames``.
    """
    import numpy as np

    maxima = []
    where = []
    for f in frames:
        m = processor.process(f.iq()).amplitude
        k = int(np.argmax(m))
        maxima.append(float(m.flat[k]))
        where.append(float(processor.range_m[k // m.shape[1]]))
    if len(maxima) < 2:
        raise ValueError("calibration needs at least two frames")
    mx = np.asarray(maxima)
    mean, std = float(mx.mean()), float(mx.std(ddof=1))
    th = mean + margin_std * std
    return {
        "th_rd": th,
        "mean_of_maxima": mean,
        "std_of_maxima": std,
        "margin_std": margin_std,
        "max_of_maxima": float(mx.max()),
        "p50_of_maxima": float(np.percentile(mx, 50)),
        "p99_of_maxima": float(np.percentile(mx, 99)),
        "fraction_of_frames_over_th": float(np.mean(mx >= th)),
        "median_range_of_maximum_m": float(np.median(where)),
        "frames": int(mx.size),
    }


def run(args: argparse.Namespace) -> int:
    import itertools

    from edge.dsp.range_doppler import RangeDopplerProcessor
    from hal import open_radar

    if args.frames < 2:
        raise ValueError("--frames must be at least 2")
    cfg = config_from_args(args)
    sc = cfg.section("pipeline.surveillance")
    with open_radar(args.source) as src:
        proc = RangeDopplerProcessor(
            src.frontend, k_c=sc.k_c, k_sf=sc.k_sf, n_range_fft=sc.n_range_fft, n_doppler_fft=sc.n_doppler_fft
        )
        frames = itertools.islice(iter(src), args.skip, args.skip + args.frames)
        res = calibrate_threshold(frames, proc, margin_std=args.margin_std)
    res["source"] = args.source
    print(
        f"{res['frames']} frames: per-frame maximum mean {res['mean_of_maxima']:.3f}, std {res['std_of_maxima']:.3f}, "
        f"max {res['max_of_maxima']:.3f} (median at {res['median_range_of_maximum_m']:.1f} m)"
    )
    print(f"th_RD = {res['mean_of_maxima']:.3f} + {args.margin_std:g} x {res['std_of_maxima']:.3f} = {res['th_rd']:.3f}"
          f"   (current: {sc.th_rd:g})")
    print(f"use: --set pipeline.surveillance.th_rd={res['th_rd']:.3f}")
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(res, indent=2) + "\n", encoding="utf-8")
    sys.stdout.flush()
    return 0
