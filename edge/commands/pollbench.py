"""``radar-edge pollbench``: what Modbus polling (up to a flood) costs the frame loop."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

NAME = "pollbench"
HELP = "measure what Modbus TCP polling, up to a flood from several masters, costs the frame loop"
DESCRIPTION = """\
Runs the real frame loop (simulated source, the board's pipeline, Modbus TCP on an OS-chosen
loopback port) and CLIENTS polling clients, each a process of its own reading the whole register
map (7 requests of up to 125 registers) RATE times a second, or as fast as the server answers with
--rate 0 (a flood). The clients are switched on and off in alternating blocks so that slow drifts of
the machine's load hit both halves alike. Reports frame p50/p99 and dropped frames with and
without the pollers, their ratio, and the full-map polls served.

On a development machine the clients share the CPUs with the device under test, while real
masters sit on other machines: --client-cpus keeps them off the loop's core and --client-nice lets
them take only idle CPU time. --loop-cpus and --server-cpus measure the deployed set-up with the
frame loop on a core of its own (loop.cpus, outputs.modbus.cpus)."""
EPILOG = """\
examples:
  radar-edge pollbench --duration 60 --rate 20                       # one SCADA master at 20 Hz
  radar-edge pollbench --duration 60 --clients 4 --rate 0            # a flood, unpinned
  radar-edge pollbench --duration 60 --clients 4 --rate 0 \\
      --loop-cpus 0 --server-cpus 1 --client-cpus 1 --json out/flood.json
"""


def _cpus(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(c) for c in text.split(",") if c.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected CPU numbers separated by commas, got {text!r}") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, default=60.0, help="seconds of frames (default 60)")
    p.add_argument("--block", type=float, default=5.0, help="poller on/off block length in s (default 5)")
    p.add_argument("--rate", type=float, default=20.0,
                   help="full-map polls per second per client (default 20; 0 = as fast as possible, a flood)")
    p.add_argument("--clients", type=int, default=1, help="polling clients, one process each (default 1)")
    p.add_argument("--client-nice", type=int, default=0, metavar="N",
                   help="nice value of the clients (19: they take only CPU time the device leaves idle; default 0)")
    p.add_argument("--loop-cpus", type=_cpus, default=(), metavar="LIST",
                   help="pin the frame loop to these CPUs, e.g. 0 (loop.cpus; default: not pinned)")
    p.add_argument("--server-cpus", type=_cpus, default=(), metavar="LIST",
                   help="pin the Modbus server process, e.g. 1 or 1,2,3 (outputs.modbus.cpus; default: not pinned)")
    p.add_argument("--client-cpus", type=_cpus, default=(), metavar="LIST",
                   help="pin the polling clients (stand-ins for masters on other machines; default: not pinned)")
    p.add_argument("--source", help="radar source URL (default: source.url of the configuration)")
    p.add_argument("--json", metavar="OUT", help="write the JSON report here")


def run(args: argparse.Namespace) -> int:
    from edge.outputs.pollbench import measure

    if args.duration <= 0 or args.block <= 0 or args.clients < 1 or args.rate < 0:
        raise ValueError("--duration and --block must be > 0, --clients >= 1 and --rate >= 0")
    try:
        rep = measure(args.duration, args.block, args.rate, args.source, args.clients, args.client_nice,
                      args.loop_cpus, args.server_cpus, args.client_cpus)
    except RuntimeError as exc:  # the poll clients never connected
        print(f"radar-edge pollbench: error: {exc}", file=sys.stderr)
        return 1
    text = json.dumps(rep, indent=2)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(text + "\n", encoding="utf-8")
    q, f = rep["without_poller"], rep["with_poller"]
    print(f"{rep['clients']} client(s) at {'flood' if not rep['rate_hz'] else str(rep['rate_hz']) + ' Hz'}: "
          f"{rep['full_map_polls']} full-map polls served")
    for name, r in (("quiet", q), ("polled", f)):
        if r["frames"]:
            print(f"  {name:7s} frames {r['frames']:6d}  p50 {r['p50_ms']:6.2f} ms  p99 {r['p99_ms']:6.2f} ms  "
                  f"dropped {r['dropped_frames']}")
    if "p99_ratio" in rep:
        print(f"  p99 polled/quiet = {rep['p99_ratio']:.3f}")
    return 0
