"""``radar-edge info``: what a source is -- waveform and derived radar characteristics."""

from __future__ import annotations

import argparse
import json

NAME = "info"
HELP = "show a source's waveform and derived radar characteristics (range/velocity resolution, FOV...)"
DESCRIPTION = """\
Describes the board behind a source URL without running the pipeline: carrier, chirp schedule,
sampling, array, and the characteristics derived from them -- range resolution c/(2B), maximum
unambiguous range, radial-speed limit and resolution, unambiguous angle of the array, field of
view, frame period. For sim://simo these reproduce Lim et al. Table 2, for sim://d2g Tavanti et al.
Table II."""
EPILOG = """\
examples:
  radar-edge info --source sim://simo
  radar-edge info --source sim://d2g --json
  radar-edge info --source replay://highway4.npz
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", metavar="URL", default="sim://simo", help="source URL (default: sim://simo)")
    p.add_argument("--json", action="store_true", help="machine-readable output")


def run(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from hal import characteristics, open_radar

    src = open_radar(args.source)
    fe = src.frontend
    ch = characteristics(fe)
    if args.json:
        print(json.dumps({"frontend": json.loads(fe.to_json()), "characteristics": asdict(ch)}, indent=2))
        return 0
    wf = fe.waveform
    print(f"source      {args.source}")
    print(f"board       {fe.board}: {fe.notes}")
    print(f"carrier     {wf.carrier_hz / 1e9:.3f} GHz, frame {wf.frame_period_s * 1e3:.0f} ms, "
          f"{fe.n_rx} RX{'' if fe.n_rx == 1 else f' at d = {fe.rx_spacing_m / wf.wavelength_m:.2f} lambda'}, "
          f"{fe.adc_bits}-bit {'I/Q' if fe.complex_iq else 'real'} ADC")
    print("chirps      " + "; ".join(
        f"{s.n_chirps}x {'up' if s.direction > 0 else 'down'} {s.bandwidth_hz / 1e6:.0f} MHz in {s.ramp_s * 1e3:g} ms"
        f"{f' every {s.pri_s * 1e3:g} ms' if s.n_chirps > 1 else ''}, {s.n_samples} samples at {s.sample_rate_hz / 1e3:g} kS/s"
        for s in wf.segments))
    print(f"frame shape {fe.frame_shape} (rx, chirps, samples), int16 I and Q")
    print()
    for k, v in ch.as_rows():
        print(f"  {k:<26}{v}")
    return 0
