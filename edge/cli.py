"""``radar-edge``: the command line of the product.

Each subcommand lives in its own module under :mod:`edge.commands` with ``NAME``, ``HELP``,
``DESCRIPTION``, ``add_arguments(parser)`` and ``run(args) -> int``; :data:`COMMANDS` lists them in
the order ``--help`` shows them. Heavy imports happen inside ``run`` so ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from edge.commands.common import StartupError
from edge.config import ConfigError
from edge.extras import MissingExtraError
from edge.pipeline import PipelineError
from hal.errors import RadarError

COMMANDS: tuple[str, ...] = (
    "edge.commands.run",
    "edge.commands.info",
    "edge.commands.simulate",
    "edge.commands.replay",
    "edge.commands.evaluate",
    "edge.commands.ablate",
    "edge.commands.replay_traffic",
    "edge.commands.fit_noise",
    "edge.commands.bench",
    "edge.commands.soak",
    "edge.commands.pollbench",
    "edge.commands.registers",
    "edge.commands.dbc",
    "edge.commands.doctor",
    "edge.commands.plot",
    "edge.commands.calibrate",
    "edge.commands.train",
    "edge.commands.export_onnx",
)

EPILOG = """\
examples:
  radar-edge run --duration 10                      # lane profile on the simulated 1x4 SIMO board
  radar-edge run --source sim://d2g --frames 50     # surveillance profile on a simulated Distance2Go
  radar-edge info --source sim://simo               # waveform and derived radar characteristics
  radar-edge simulate --scenario highway4 --frames 300 --out highway4.npz
  radar-edge replay highway4.npz --speed 0

source URLs: sim://simo?scenario=NAME&seed=N  sim://d2g?scenario=NAME
             replay://FILE.npz?speed=1  d2g:///dev/ttyACM0
"""


def product_version() -> str:
    """The installed package's version (the firmware version Modbus and CAN report)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("radar-edge")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "0+unknown"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="radar-edge",
        description="Edge firmware for roadside 24 GHz FMCW traffic radar: detection, tracking, "
        "classification and lane statistics in a fixed frame budget, served over Modbus and CAN.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"radar-edge {product_version()}",
                        help="print the product version and exit")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for mod_name in COMMANDS:
        mod = importlib.import_module(mod_name)
        p = sub.add_parser(
            mod.NAME,
            help=mod.HELP,
            description=getattr(mod, "DESCRIPTION", mod.HELP),
            epilog=getattr(mod, "EPILOG", None),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose >= 2 else logging.INFO if verbose == 1 else logging.WARNING)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_logging(args.verbose, args.quiet)
    try:
        return int(args._run(args) or 0)
    except (ConfigError, PipelineError, RadarError, ValueError, FileNotFoundError, MissingExtraError,
            StartupError) as exc:
        logging.getLogger("radar-edge").debug("error", exc_info=True)
        print(f"radar-edge {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # the reader went away (radar-edge ... | head): stop quietly, as Unix tools do
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # (the interpreter's final flush would raise again)
        return 141


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
