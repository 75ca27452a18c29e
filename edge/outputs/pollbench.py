"""Does a Modbus client polling the whole map slow the frame loop down?

Runs the real frame loop (simulated source, the board's pipeline, the configured outputs with
Modbus TCP on an OS-chosen port) and a client in another process that reads every readable
register (7 requests of <= 125 registers) at ``rate_hz``. The client is switched on and off in
alternating blocks so that slow drifts of the machine's load hit both halves alike; the result is
the frame-time p50/p99 of frames processed with and without the poller.

    python -m edge.outputs.pollbench --duration 60 --rate 20
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import time

import numpy as np


def _poller(port: int, rate_hz: float, active, stop, counter) -> None:
    from pymodbus.client import ModbusTcpClient
    from pymodbus.exceptions import ModbusException

    from edge.outputs.registers import READ_RANGES

    c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    c.connect()
    nxt = time.monotonic()
    while not stop.is_set():
        if not active.wait(0.1):
            nxt = time.monotonic()
            continue
        try:
            for a, b in READ_RANGES:
                for s in range(a, b, 125):
                    r = c.read_holding_registers(s, count=min(125, b - s), device_id=1)
                    if r.isError():
                        raise RuntimeError(f"poll failed: {r}")
        except ModbusException:  # the server goes away when the loop ends (before `stop` is set)
            break
        with counter.get_lock():
            counter.value += 1
        nxt += 1.0 / rate_hz
        time.sleep(max(0.0, nxt - time.monotonic()))
    c.close()


def measure(duration_s: float = 60.0, block_s: float = 5.0, rate_hz: float = 20.0, source: str | None = None) -> dict:
    from edge.config import load_config
    from edge.loop import FrameLoop
    from edge.outputs import build_sinks
    from edge.pipeline import build_pipeline, resolve_profile
    from hal import open_radar

    overrides = {"outputs.modbus.tcp_port": 0}
    if source:
        overrides["source.url"] = source
    cfg = load_config(env={}, overrides=overrides)
    src = open_radar(cfg["source"].url)
    profile = resolve_profile(cfg["loop"].profile, src.frontend.board)
    pipe = build_pipeline(profile, src.frontend, cfg)
    sinks = build_sinks(cfg, int(getattr(pipe, "n_lanes", 0)), strict=True)
    port = sinks[0].tcp_address[1]
    ctx = mp.get_context("spawn")
    active, stop, counter = ctx.Event(), ctx.Event(), ctx.Value("i", 0)
    proc = ctx.Process(target=_poller, args=(port, rate_hz, active, stop, counter), daemon=True)
    proc.start()
    samples: dict[bool, list[float]] = {True: [], False: []}
    t0 = time.monotonic()
    loop_ref: list = []

    def on_result(result) -> None:
        on = int((time.monotonic() - t0) / block_s) % 2 == 1
        if on != active.is_set():
            (active.set if on else active.clear)()
        samples[active.is_set()].append(loop_ref[0].timer.current.get("frame", float("nan")))

    loop = FrameLoop(src, pipe, cfg["loop"], sinks=sinks, read_timeout_s=cfg["source"].read_timeout_s,
                     on_result=on_result)
    loop_ref.append(loop)
    try:
        loop.run(duration_s=duration_s)
    finally:
        stop.set()
        proc.join(10)
        if proc.is_alive():
            proc.terminate()
    out = {"profile": profile, "duration_s": duration_s, "block_s": block_s, "rate_hz": rate_hz,
           "full_map_polls": counter.value}
    for key, on in (("without_poller", False), ("with_poller", True)):
        a = np.asarray(samples[on], dtype=float)
        a = a[np.isfinite(a)]
        out[key] = {"frames": int(a.size), "p50_ms": float(np.percentile(a, 50)) if a.size else None,
                    "p99_ms": float(np.percentile(a, 99)) if a.size else None}
    if out["without_poller"]["p99_ms"] and out["with_poller"]["p99_ms"]:
        out["p99_ratio"] = out["with_poller"]["p99_ms"] / out["without_poller"]["p99_ms"]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m edge.outputs.pollbench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=60.0, help="seconds of frames (default 60)")
    p.add_argument("--block", type=float, default=5.0, help="poller on/off block length in s (default 5)")
    p.add_argument("--rate", type=float, default=20.0, help="full-map polls per second (default 20)")
    p.add_argument("--source", help="radar source URL (default: source.url of the configuration)")
    a = p.parse_args(argv)
    print(json.dumps(measure(a.duration, a.block, a.rate, a.source), indent=2))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
