"""``radar-edge run``: the product's main job."""

from __future__ import annotations

import argparse
import logging
import signal
import sys

from edge.commands.common import StartupError, add_config_arguments, config_from_args
from edge.outputs.cli_options import add_output_arguments, output_overrides

NAME = "run"
HELP = "run the frame loop on a radar source and serve the results (default: simulated SIMO board)"
DESCRIPTION = """\
Opens the radar source, builds the pipeline of its profile (lane for the 1x4 SIMO board,
surveillance for the Distance2Go; the minimal range-FFT pipeline where a profile is not available),
and runs the fixed-budget frame loop until Ctrl-C/SIGTERM, --frames or --duration. Results go to the
configured outputs (Modbus, CAN). A status line is printed every second; at stop, a summary with
frames, drops, overruns and p50/p99 per stage against the frame budget."""
EPILOG = """\
examples:
  radar-edge run --duration 10
  radar-edge run --source "sim://d2g?scenario=tavanti-test1" --frames 40
  radar-edge run --source replay://highway4.npz?speed=0 --set loop.error_policy=stop
  radar-edge run --config /etc/radar-edge/radar-edge.toml
  radar-edge run --modbus-tcp 0.0.0.0:502 --modbus-rtu /dev/ttyAMA0 --can socketcan:can0
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", metavar="URL", help="radar source URL (default: source.url from the config)")
    add_loop_arguments(p)


def add_loop_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``run`` and ``replay``."""
    p.add_argument("--frames", type=int, default=None, help="stop after N frames")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--profile", choices=("auto", "lane", "surveillance", "minimal"), help="pipeline profile (default: by board)")
    p.add_argument("--no-outputs", action="store_true", help="do not start Modbus/CAN outputs")
    p.add_argument("--status-every", type=float, default=1.0, metavar="S", help="status line period, 0 = none")
    p.add_argument("--view", action="store_true", help="live terminal table of tracks, lane counters and budget use")
    add_config_arguments(p)
    add_output_arguments(p)


def build_sinks(cfg, n_lanes: int, traffic=None) -> list:
    """Start the configured outputs; one that cannot start is a :class:`StartupError` naming it.
    ``traffic``: the pipeline's traffic layer (lanes in use, lane geometry writes)."""
    try:
        from edge import outputs
        from edge.outputs.modbus import OutputError
    except ImportError:  # pragma: no cover - outputs are part of the package
        return []
    try:
        return list(outputs.build_sinks(cfg, n_lanes, traffic=traffic))
    except OutputError as exc:
        raise StartupError(str(exc)) from exc


def run(args: argparse.Namespace) -> int:
    from edge.config import log_config
    from edge.loop import FrameLoop
    from edge.pipeline import build_pipeline, resolve_profile
    from hal import open_radar

    extra = output_overrides(args)
    if args.source:
        extra["source.url"] = args.source
    if args.profile:
        extra["loop.profile"] = args.profile
    cfg = config_from_args(args, extra)
    log_config(cfg)
    source = open_radar(cfg["source"].url)
    profile = resolve_profile(cfg["loop"].profile, source.frontend.board)
    pipeline = build_pipeline(profile, source.frontend, cfg)
    n_lanes = pipeline.n_lanes
    sinks = [] if args.no_outputs else build_sinks(cfg, n_lanes, getattr(pipeline, "traffic", None))
    from edge.ops import attach

    pipeline = attach(cfg, pipeline, sinks, view=getattr(args, "view", False))
    if getattr(args, "view", False):
        args.status_every = 0  # the view replaces the status line
    budget_ms = source.frontend.waveform.frame_period_s * 1e3
    status = _Status(args.status_every, budget_ms)
    loop = FrameLoop(
        source, pipeline, cfg["loop"], sinks=sinks, read_timeout_s=cfg["source"].read_timeout_s,
        on_result=status.on_result if args.status_every > 0 else None,
    )
    status.loop = loop
    print(f"radar-edge run: {cfg['source'].url} -> {profile} pipeline, frame budget {budget_ms:.0f} ms "
          f"(Ctrl-C to stop)", flush=True)
    old = {s: signal.signal(s, lambda *_: loop.stop()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        summary = loop.run(max_frames=args.frames, duration_s=args.duration)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    print("\n".join(summary.lines()), flush=True)
    logging.getLogger(__name__).info("stopped: %s", summary.stop_reason)
    return 0 if not summary.stop_reason.startswith(("source error", "pipeline error")) else 1


class _Status:
    """Prints one line per period: frames, detections, tracks and the frame time against budget."""

    def __init__(self, every_s: float, budget_ms: float) -> None:
        self.every_ns = int(every_s * 1e9)
        self.budget_ms = budget_ms
        self.loop = None
        self._last = 0

    def on_result(self, result) -> None:
        if result.t_ns - self._last < self.every_ns:
            return
        self._last = result.t_ns
        loop = self.loop
        t = loop.timer.current.get("frame", 0.0)
        c = loop.counters
        line = (
            f"seq {result.seq:6d}  detections {len(result.detections):3d}  tracks {len(result.tracks):3d}  "
            f"frame {t:6.2f} ms ({t / self.budget_ms:5.1%} of budget)  dropped {c.dropped_frames + loop.source.stats.dropped_frames}"
            f"  overruns {c.overruns}"
        )
        if result.classifications:
            line += "  " + ", ".join(f"#{e.track_id} {e.cls}" for e in result.classifications)
        print(line, file=sys.stdout, flush=True)
