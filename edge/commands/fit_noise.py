"""``radar-edge fit-noise``: measure the lane detections' error against simulator truth and fit the SNR law."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from edge.commands.common import add_config_arguments, config_from_args

NAME = "fit-noise"
HELP = "fit the lane tracker's SNR measurement-noise law to simulated detections (track.pdaf snr_* fields)"
DESCRIPTION = """\
Runs a lane scenario through the lane pipeline, matches every detection to its vehicle's reference point
(the point the evaluation scores) and fits the law the tracker uses with measurement_noise = snr:
across the boresight var = r^2 (sigma0^2 / SNR + floor^2) + extent^2 (azimuth sd sigma0 at 0 dB SNR, an angle
floor, and the across-vehicle scatter of extended vehicles), along it var = sigma0_r^2 / SNR + floor_r^2.
Use point-like targets (highway4) for the angle law, then fix it and fit the extent on extended vehicles
(highway4-traffic): the defaults of track.pdaf were fitted that way (seeds 1, 2, 3, 5, 8 of highway4; seed 5,
1500 frames, of highway4-traffic). Prints the fit and per-cell sds (measured vs model)."""
EPILOG = """\
examples:
  radar-edge fit-noise --scenario highway4 --seed 1 --seed 2 --seed 3 --seed 5 --seed 8
  radar-edge fit-noise --scenario highway4-traffic --seed 5 --frames 1500 --azimuth-sigma0-deg 0.88 \\
      --azimuth-floor-deg 0.03 --json out/noise-traffic.json
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", required=True, help="lane scenario name or .toml path (SIMO board)")
    p.add_argument("--seed", type=int, action="append", help="random seed (repeatable; default: the scenario's)")
    p.add_argument("--frames", type=int, default=None, help="frames per seed (default: the whole scenario)")
    p.add_argument("--azimuth-sigma0-deg", type=float, default=None, help="hold the azimuth sd at 0 dB fixed")
    p.add_argument("--azimuth-floor-deg", type=float, default=None, help="hold the azimuth floor fixed")
    p.add_argument("--json", metavar="OUT", help="also write the fit and its cells here")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from edge.evaluation.lane_noise import detection_errors, fit_azimuth_law, fit_range_law
    from hw_sim.scenario import load_scenario_for_eval

    cfg = config_from_args(args)
    sc = load_scenario_for_eval(args.scenario)
    seeds = args.seed or [sc.seed]
    parts = [detection_errors(sc, seed=s, frames=args.frames, config=cfg) for s in seeds]
    errors = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    try:
        az = fit_azimuth_law(errors, sigma0_deg=args.azimuth_sigma0_deg, floor_deg=args.azimuth_floor_deg)
        rg = fit_range_law(errors)
    except ValueError as exc:
        print(f"fit-noise: {exc}")
        return 1
    print(f"{args.scenario} seeds {seeds}: {az['n_detections']} detections beyond 20 m")
    print(f"  across: sigma0 {az['sigma0_deg']:.3f} deg at 0 dB, floor {az['floor_deg']:.4f} deg, "
          f"extent {az['extent_m']:.3f} m")
    print(f"  along:  sigma0 {rg['sigma0_m']:.3f} m at 0 dB, floor {rg['floor_m']:.4f} m")
    print("  cell (SNR dB, range m, n): measured sd / model sd across, m")
    for (snr, r, var, n), m in zip(az["cells"], az["model_sd_m"]):
        print(f"    {snr:5.1f} {r:6.1f} {int(n):5d}: {var ** 0.5:.3f} / {m:.3f}")
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"scenario": args.scenario, "seeds": seeds, "across": az, "along": rg}, indent=2)
                       + "\n", encoding="utf-8")
    return 0
