"""``radar-edge bench``: per-stage frame times against the budget, a peer pipeline and the FFT bound.

Frames are synthesised first (seeded, not timed), then the same frames go, single-threaded, through

* the product pipeline of the profile (per-stage and whole-frame p50/p99),
* the *FFT-only lower bound*: just the transforms the profile cannot avoid, in single precision,
* the *peer pipeline*: what a user would otherwise glue together for the same job (float64 numpy,
  scikit-learn, Stone Soup), where the profile provides one.

Each profile provides its bound and peer in ``edge.bench.<profile>`` as ``fft_bound(frontend)`` and
``peer(frontend, config)``, both returning a callable ``f(frame) -> object``. The JSON document has
the keys of DESIGN §6.
"""

from __future__ import annotations

import importlib
import logging
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from edge.pipeline import BOARD_PROFILE, StageTimer, build_pipeline

log = logging.getLogger(__name__)

DEFAULT_SCENARIO = {"simo": "highway4", "d2g": "tavanti-test1"}


def _percentiles(samples_ms: list[float] | np.ndarray) -> dict[str, float]:
    a = np.asarray(samples_ms, dtype=np.float64)
    return {"p50_ms": float(np.percentile(a, 50)), "p99_ms": float(np.percentile(a, 99))}


def time_callable(fn: Callable[[Any], Any], frames: list, warmup: int = 3) -> np.ndarray:
    """Per-frame wall time (ms) of ``fn`` over ``frames`` after ``warmup`` untimed calls."""
    for f in frames[:warmup]:
        fn(f)
    out = np.empty(len(frames))
    for k, f in enumerate(frames):
        t0 = time.perf_counter_ns()
        fn(f)
        out[k] = (time.perf_counter_ns() - t0) / 1e6
    return out


def board_of(profile: str) -> str:
    for board, prof in BOARD_PROFILE.items():
        if prof == profile:
            return board
    return "simo"


def synth_frames(board: str, scenario: str | None, seed: int, n: int, progress: bool = False) -> list:
    from hal import open_radar

    url = f"sim://{board}?realtime=0&loop=1"
    with open_radar(url, scenario=scenario or DEFAULT_SCENARIO[board], seed=seed, frames=n) as src:
        it = iter(src)
        if progress:
            try:
                from tqdm import tqdm

                it = tqdm(it, total=n, unit="frame", desc="synthesising", leave=False)
            except ImportError:
                pass
        return list(it)


def startup_seconds(frames: list) -> float:
    """Wall time of a fresh ``radar-edge run`` from process start to its first processed frame."""
    from hal.recording import RecordingWriter

    with tempfile.TemporaryDirectory() as d:
        w = RecordingWriter(frames[0].frontend)
        for f in frames[:2]:
            w.add(f)
        path = w.save(Path(d) / "startup.npz")
        cmd = [sys.executable, "-m", "edge", "run", "--source", f"replay://{path}?speed=0", "--frames", "1",
               "--no-outputs", "--status-every", "0"]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        return time.perf_counter() - t0


def run_bench(
    profile: str,
    config: Any,
    *,
    frames: int = 300,
    scenario: str | None = None,
    seed: int = 1,
    peer: bool = True,
    startup: bool = True,
    progress: bool = False,
) -> dict:
    board = board_of(profile)
    recorded = synth_frames(board, scenario, seed, frames, progress)
    fe = recorded[0].frontend
    budget_ms = fe.waveform.frame_period_s * 1e3

    # product pipeline: warm up on a throw-away instance (state!), then time a fresh one
    warm = build_pipeline(profile, fe, config)
    for f in recorded[: min(5, len(recorded))]:
        warm.process(f, StageTimer(16))
    warm.close()
    pipe = build_pipeline(profile, fe, config)
    timer = StageTimer(max(16, len(recorded)))
    frame_ms = np.empty(len(recorded))
    for k, f in enumerate(recorded):
        t0 = time.perf_counter_ns()
        pipe.process(f, timer)
        frame_ms[k] = (time.perf_counter_ns() - t0) / 1e6
    pipe.close()
    stages = {name: _percentiles(timer.samples_ms(name)) for name in timer.names()}
    frame = _percentiles(frame_ms)
    frame["budget_ms"] = budget_ms
    frame["p99_budget_fraction"] = frame["p99_ms"] / budget_ms

    out: dict[str, Any] = {
        "profile": profile,
        "frames": len(recorded),
        "scenario": scenario or DEFAULT_SCENARIO[board],
        "seed": seed,
        "stages": stages,
        "frame": frame,
        "peak_rss_mb": None,
        "startup_s": None,
        "peer": None,
        "fft_bound": None,
    }
    hooks = _hooks(profile)
    if hooks is not None and hasattr(hooks, "fft_bound"):
        t = time_callable(hooks.fft_bound(fe), recorded)
        p99 = float(np.percentile(t, 99))
        out["fft_bound"] = {"p99_ms": p99, "ratio": frame["p99_ms"] / p99}
    if peer and hooks is not None and hasattr(hooks, "peer"):
        fn = hooks.peer(fe, config)
        if fn is not None:
            n_peer = min(len(recorded), max(30, len(recorded) // 5))  # the peer is slow: a subset
            t = time_callable(fn, recorded[:n_peer])
            p99 = float(np.percentile(t, 99))
            out["peer"] = {"p99_ms": p99, "p50_ms": float(np.percentile(t, 50)), "frames": n_peer,
                           "ratio": p99 / frame["p99_ms"]}
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    if startup:
        out["startup_s"] = startup_seconds(recorded)
    return out


def _hooks(profile: str):
    try:
        return importlib.import_module(f"edge.bench.{profile}")
    except ModuleNotFoundError:
        log.info("no FFT bound or peer pipeline for profile %s", profile)
        return None
