"""``radar-edge doctor``: is this box ready to run the radar? Every failure comes with its fix."""

from __future__ import annotations

import argparse
import sys

from edge.commands.common import add_config_arguments

NAME = "doctor"
HELP = "check the installation: config, serial ports, board, CAN, Modbus, model, kernels, temperature, clock"
DESCRIPTION = """\
Checks, in order: the configuration file; the radar source (the Distance2Go's serial port and its
permissions for the service user, then the board itself: it is opened, its endpoint list read and
one frame received, a warning when its samples clip at the ADC's full scale); Modbus RTU (the RS-485 UART, not the serial console) and the Modbus TCP port;
the CAN interface (up, bitrate as configured, bus state, restart-ms); the model files and their
input schema (a warning when classify.features differ from those the model's reference set was
built with); the recordings directory and its quota; the compiled kernels (a warning when the
numpy fallback runs); the CPU temperature and throttling
(`vcgencmd get_throttled`); clock synchronisation (timedatectl, chrony).

Each line is ok, warn, FAIL or skipped (with the reason); a failure is followed by the fix. Exit
status 1 if anything failed. Stop the service first to check the board (it holds the port), or use
--no-board."""
EPILOG = """\
examples:
  radar-edge doctor                                   # /etc/radar-edge/radar-edge.toml
  sudo systemctl stop radar-edge && radar-edge doctor && sudo systemctl start radar-edge
  radar-edge doctor --no-board --json > doctor.json  # while the service runs; for a ticket
  radar-edge doctor --root /mnt/sdcard --no-board     # a mounted SD card image
"""

_MARK = {"ok": "ok  ", "warn": "warn", "fail": "FAIL", "skipped": "skip"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--no-board", action="store_true", help="do not open the board (the service is using it)")
    p.add_argument("--user", metavar="NAME", help="judge permissions for this user (default: radar-edge if it exists)")
    p.add_argument("--root", metavar="DIR", default="/", help="file-system root to inspect (default /)")
    add_config_arguments(p)


def run(args: argparse.Namespace) -> int:
    from edge.config import parse_set_option
    from edge.ops.doctor import System, as_json, run_checks

    system = System(args.root, user=args.user)
    overrides = dict(parse_set_option(s) for s in args.set)
    checks = run_checks(system, args.config, overrides, open_board=not args.no_board)
    failed = sum(c.status == "fail" for c in checks)
    if args.json:
        print(as_json(checks))
    else:
        width = max(len(c.name) for c in checks)
        print(f"radar-edge doctor (permissions for user {system.access.user})")
        for c in checks:
            print(f"  {_MARK.get(c.status, c.status)}  {c.name:<{width}}  {c.detail}")
            if c.fix and c.status in ("fail", "warn"):
                print(f"  {'':4}  {'':<{width}}  fix: {c.fix}")
        warned = sum(c.status == "warn" for c in checks)
        print(f"{len(checks)} checks: {failed} failed, {warned} warnings", file=sys.stdout)
    return 1 if failed else 0
