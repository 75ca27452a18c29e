"""``radar-edge pollbench``: does a Modbus client polling the whole map slow the frame loop down?

Runs the real frame loop (simulated source, the board's pipeline, the configured outputs with
Modbus TCP on an OS-chosen port) and ``clients`` clients, each in its own process, that read every
readable register (7 requests of <= 125 registers) at ``rate_hz`` (0 = as fast as the server
answers: a flood). The clients are switched on and off in alternating blocks so that slow drifts of
the machine's load hit both halves alike; the result is the frame-time p50/p99 of frames processed
with and without the pollers, and the frames dropped in each half.

    radar-edge pollbench --duration 60 --rate 20
    radar-edge pollbench --duration 60 --clients 4 --rate 0     # flood
    radar-edge pollbench --duration 60 --clients 4 --rate 0 --client-nice 19
    radar-edge pollbench --duration 60 --clients 4 --rate 0 \
        --loop-cpus 0 --server-cpus 1 --client-cpus 1          # the loop on a core of its own

On a development machine the clients share the CPU with the device under test; real Modbus masters
sit on other machines. ``--client-nice 19`` approximates that (the clients get only idle CPU); the
server process's own work is then what remains of the flood's cost. ``--loop-cpus``/``--server-cpus``
measure the deployed set-up with the frame loop on a core of its own (``loop.cpus``,
``outputs.modbus.cpus``); ``--client-cpus`` keeps the stand-in masters off the loop's core, as
masters on other machines are.
"""

from __future__ import annotations

import multiprocessing as mp
import threading
import time

import numpy as np


#: poll clients must be connected this soon after they were started (spawned interpreters import pymodbus)
CONNECT_TIMEOUT_S = 60.0


def _poller(port: int, rate_hz: float, active, stop, counter, ready, nice: int = 0,
            cpus: tuple[int, ...] = ()) -> None:
    import os
    import threading

    from edge.ops.affinity import pin

    pin(cpus, "poll client")  # stands in for a master on another machine: not on the loop's core
    if nice:
        os.nice(nice)  # stands in for a master on another machine: only CPU the device would leave idle
    from pymodbus.client import ModbusTcpClient
    from pymodbus.exceptions import ModbusException

    from edge.outputs.registers import READ_RANGES

    c = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    while not c.connect():  # the server may not accept yet: try again until the run is called off
        if stop.wait(0.05):
            c.close()
            return
    try:
        ready.wait(CONNECT_TIMEOUT_S)  # every client connected: the timed run starts
    except threading.BrokenBarrierError:
        c.close()
        return
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
        if rate_hz > 0:
            nxt += 1.0 / rate_hz
            time.sleep(max(0.0, nxt - time.monotonic()))
    c.close()


def _stop_clients(procs, stop) -> None:
    stop.set()
    for proc in procs:
        proc.join(10)
        if proc.is_alive():
            proc.terminate()


def measure(duration_s: float = 60.0, block_s: float = 5.0, rate_hz: float = 20.0, source: str | None = None,
            clients: int = 1, client_nice: int = 0, loop_cpus: tuple[int, ...] = (),
            server_cpus: tuple[int, ...] = (), client_cpus: tuple[int, ...] = ()) -> dict:
    from edge.config import load_config
    from edge.loop import FrameLoop
    from edge.outputs import build_sinks
    from edge.pipeline import build_pipeline, resolve_profile
    from hal import open_radar

    overrides: dict = {"outputs.modbus.tcp_port": 0}
    if loop_cpus:
        overrides["loop.cpus"] = list(loop_cpus)
    if server_cpus:
        overrides["outputs.modbus.cpus"] = list(server_cpus)
    if source:
        overrides["source.url"] = source
    cfg = load_config(env={}, overrides=overrides)
    src = open_radar(cfg["source"].url)
    profile = resolve_profile(cfg["loop"].profile, src.frontend.board)
    pipe = build_pipeline(profile, src.frontend, cfg)
    sinks = build_sinks(cfg, pipe.n_lanes, strict=True)
    port = sinks[0].tcp_address[1]
    ctx = mp.get_context("spawn")
    n_clients = max(1, clients)
    active, stop, counter = ctx.Event(), ctx.Event(), ctx.Value("i", 0)
    ready = ctx.Barrier(n_clients + 1)
    procs = [ctx.Process(target=_poller, args=(port, rate_hz, active, stop, counter, ready, client_nice,
                                               tuple(client_cpus)), daemon=True)
             for _ in range(n_clients)]
    for proc in procs:
        proc.start()
    try:
        ready.wait(CONNECT_TIMEOUT_S)  # the flood blocks start with every client connected, not while they start
    except threading.BrokenBarrierError:
        _stop_clients(procs, stop)
        for s in sinks:
            s.close()
        src.close()
        raise RuntimeError(f"the {n_clients} poll client(s) did not connect to the Modbus server on port {port} "
                           f"within {CONNECT_TIMEOUT_S:.0f} s") from None
    samples: dict[bool, list[float]] = {True: [], False: []}
    dropped = {True: 0, False: 0}
    seen = [0]
    t0 = time.monotonic()
    loop_ref: list = []

    def on_result(result) -> None:
        lp = loop_ref[0]
        d = lp.counters.dropped_frames + lp.source.stats.dropped_frames
        dropped[active.is_set()] += d - seen[0]  # drops since the last frame belong to the state they happened in
        seen[0] = d
        on = int((time.monotonic() - t0) / block_s) % 2 == 1
        if on != active.is_set():
            (active.set if on else active.clear)()
        samples[active.is_set()].append(lp.timer.current.get("frame", float("nan")))

    loop = FrameLoop(src, pipe, cfg["loop"], sinks=sinks, read_timeout_s=cfg["source"].read_timeout_s,
                     on_result=on_result)
    loop_ref.append(loop)
    try:
        loop.run(duration_s=duration_s)
    finally:
        _stop_clients(procs, stop)
    out = {"profile": profile, "duration_s": duration_s, "block_s": block_s, "rate_hz": rate_hz,
           "clients": len(procs), "client_nice": client_nice,
           "loop_cpus": list(loop_cpus), "server_cpus": list(server_cpus), "client_cpus": list(client_cpus), "full_map_polls": counter.value}
    for key, on in (("without_poller", False), ("with_poller", True)):
        a = np.asarray(samples[on], dtype=float)
        a = a[np.isfinite(a)]
        out[key] = {"frames": int(a.size), "p50_ms": float(np.percentile(a, 50)) if a.size else None,
                    "p99_ms": float(np.percentile(a, 99)) if a.size else None, "dropped_frames": dropped[on]}
    if out["without_poller"]["p99_ms"] and out["with_poller"]["p99_ms"]:
        out["p99_ratio"] = out["with_poller"]["p99_ms"] / out["without_poller"]["p99_ms"]
    return out
