"""The pipeline interface the two profiles implement, and per-stage timing.

A pipeline is built once per source front end (windows, constants and buffers are computed in
``__init__``), then called once per frame::

    result = pipeline.process(frame, timer)

``timer.stage("range_fft")`` is a context manager that times one stage; the loop keeps the
durations in a bounded ring buffer and reports p50/p99 per stage. Pipelines never block on I/O.
"""

from __future__ import annotations

import importlib
import time
from typing import Any, Callable

import numpy as np

from edge.types import FrameResult, FrontendInfo, RawFrame

#: profile name -> "module:Class"
PIPELINES: dict[str, str] = {
    "minimal": "edge.pipelines.minimal:MinimalPipeline",
    "lane": "edge.pipelines.lane:LanePipeline",
    "surveillance": "edge.pipelines.surveillance:SurveillancePipeline",
}

#: board -> profile used when ``loop.profile = "auto"`` (falls back to "minimal" until it exists)
BOARD_PROFILE: dict[str, str] = {"simo": "lane", "d2g": "surveillance"}


class PipelineError(RuntimeError):
    """A pipeline cannot be built for this front end or configuration."""


class StageTimer:
    """Times named stages into fixed-size ring buffers (no allocation per frame after warm-up)."""

    def __init__(self, window: int = 4096, clock_ns: Callable[[], int] = time.perf_counter_ns) -> None:
        self.window = window
        self._clock = clock_ns
        self._buf: dict[str, np.ndarray] = {}
        self._n: dict[str, int] = {}
        self.current: dict[str, float] = {}

    def stage(self, name: str) -> "_Stage":
        return _Stage(self, name)

    def record(self, name: str, dt_ns: int) -> None:
        buf = self._buf.get(name)
        if buf is None:
            buf = self._buf[name] = np.zeros(self.window, dtype=np.float64)
            self._n[name] = 0
        n = self._n[name]
        buf[n % self.window] = dt_ns / 1e6
        self._n[name] = n + 1
        self.current[name] = dt_ns / 1e6

    def samples_ms(self, name: str) -> np.ndarray:
        n = self._n.get(name, 0)
        return self._buf[name][: min(n, self.window)] if n else np.zeros(0)

    def names(self) -> list[str]:
        return list(self._buf)

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for name in self._buf:
            s = self.samples_ms(name)
            out[name] = {
                "p50_ms": float(np.percentile(s, 50)),
                "p99_ms": float(np.percentile(s, 99)),
                "max_ms": float(s.max()),
                "n": int(self._n[name]),
            }
        return out


class _Stage:
    __slots__ = ("_t", "_name", "_t0")

    def __init__(self, timer: StageTimer, name: str) -> None:
        self._t = timer
        self._name = name

    def __enter__(self) -> None:
        self._t0 = self._t._clock()

    def __exit__(self, *exc: object) -> None:
        self._t.record(self._name, self._t._clock() - self._t0)


class Pipeline:
    """Base class: ``profile`` name, ``stages`` in order, and :meth:`process`."""

    profile: str = ""
    stages: tuple[str, ...] = ()
    #: lanes the outputs reserve blocks for (Modbus lane statistics, CAN lane messages); 0 = no lanes
    n_lanes: int = 0

    def __init__(self, frontend: FrontendInfo, config: Any) -> None:
        self.frontend = frontend
        self.config = config

    def process(self, frame: RawFrame, timer: StageTimer) -> FrameResult:  # pragma: no cover - abstract
        raise NotImplementedError

    def close(self) -> None:
        """Release resources (models, files); called once when the loop stops."""


def pipeline_class(profile: str) -> type[Pipeline]:
    try:
        mod, cls = PIPELINES[profile].split(":")
    except KeyError:
        raise PipelineError(f"unknown profile {profile!r}; available: {', '.join(sorted(PIPELINES))}") from None
    return getattr(importlib.import_module(mod), cls)


def resolve_profile(requested: str, board: str) -> str:
    """``auto`` -> the board's profile if it is available, else ``minimal``."""
    if requested != "auto":
        return requested
    p = BOARD_PROFILE.get(board, "minimal")
    return p if p in PIPELINES else "minimal"


def build_pipeline(profile: str, frontend: FrontendInfo, config: Any) -> Pipeline:
    """Build the pipeline for ``profile`` with its config section ``pipeline.<profile>``.

    A pipeline that also needs other sections (the lane profile reads ``track.pdaf`` and ``traffic``,
    the surveillance profile its tracker and classifier) provides a classmethod
    ``from_config(frontend, config)`` taking the whole resolved configuration, used instead.
    """
    cls = pipeline_class(profile)
    if hasattr(cls, "from_config"):
        return cls.from_config(frontend, config)
    return cls(frontend, config.section(f"pipeline.{profile}"))
