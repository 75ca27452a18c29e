"""``radar-edge registers``: print the Modbus register map (generated from the register table)."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "registers"
HELP = "print the Modbus register map as Markdown (addresses, 3xxxx/4xxxx numbers, scaling, n/a values)"
DESCRIPTION = """\
Prints the Modbus register map that `radar-edge run` serves over Modbus TCP and RTU (RS-485). It is
generated from the same declarative table the server image is built from, so it cannot drift: every
register with its 0-based PDU address, its 1-based input (3xxxx, FC4) and holding (4xxxx, FC3)
numbers, the reference mbpoll takes (address + 1, with -t 3 for FC4 or -t 4 for FC3), type,
fixed-point scale and unit, "not available" code and meaning. 32-bit values are high word first
(registers 2-3 read 0x1234 0x5678)."""
EPILOG = """\
examples:
  radar-edge registers                       # Markdown to stdout
  radar-edge registers --out docs/registers.md
  mbpoll -m tcp -p 5020 -a 1 -t 3:hex -r 1 -c 4 -1 127.0.0.1   # 30001-30004: magic, version, word-order test
  mbpoll -m tcp -p 5020 -a 1 -t 4 -r 2005 -1 127.0.0.1         # 42005 (address 2004): statistics interval
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", metavar="FILE", help="write the Markdown here instead of printing it")


def run(args: argparse.Namespace) -> int:
    from edge.outputs.registers import markdown

    text = markdown() + "\n"
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text, encoding="utf-8")
        print(f"wrote {out}")
    else:
        print(text, end="")
    return 0
