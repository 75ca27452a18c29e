"""``radar-edge dbc``: write the CAN database (DBC) of the object list and lane messages."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "dbc"
HELP = "write the DBC of the CAN output (ARS408 object list + lane statistics and presence)"
DESCRIPTION = """\
Generates the DBC file that describes what `radar-edge run` sends on CAN: the Continental ARS408
object list (0x201 RadarState, 0x60A header, 0x60B per object, 0x60C quality, 0x60D class and size,
0x700 version; ARS408 ids offset by 0x10 x sensor id) and our lane messages in 0x690-0x6FF (8 ids per
sensor id: lane statistics A/B, class counts, presence, interval status). It is generated from the
same definition the encoder uses; the package ships the file for sensor id 0
(edge/outputs/radar_edge.dbc). Load it in cantools, SavvyCAN, Vector tools or `cantools decode`."""
EPILOG = """\
examples:
  radar-edge dbc                               # DBC for sensor id 0 to stdout
  radar-edge dbc --out radar_edge.dbc
  radar-edge dbc --sensor-id 2 --out radar_edge_s2.dbc
  candump -L can0 | cantools decode --single-line radar_edge.dbc
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", metavar="FILE", help="write the DBC here instead of printing it")
    p.add_argument("--sensor-id", type=int, default=0, choices=range(8), metavar="0-7",
                   help="ARS408 sensor id the ids are offset for (default 0)")


def run(args: argparse.Namespace) -> int:
    from edge.outputs.can_db import dbc_text

    text = dbc_text(args.sensor_id)
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text, encoding="utf-8")
        print(f"wrote {out}")
    else:
        print(text, end="")
    return 0
