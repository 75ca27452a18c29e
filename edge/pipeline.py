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
    """Times named stages into fixed-size ring buffers (no allocation per frame after warm-up).

    ``stage(name)`` hands out one cached context manager per name, which writes the duration
    straight into that stage's ring: timing nine stages costs a few microseconds a frame.
    """

    def __init__(self, window: int = 4096, clock_ns: Callable[[], int] = time.perf_counter_ns) -> None:
        self.window = window
        self._clock = clock_ns
        self._stages: dict[str, _Stage] = {}
        #: the latest duration of every stage (ms)
        self.current: dict[str, float] = {}

    def stage(self, name: str) -> "_Stage":
        st = self._stages.get(name)
        if st is None:
            st = self._stages[name] = _Stage(self, name)
        return st

    def record(self, name: str, dt_ns: int) -> None:
        self.stage(name)._record(dt_ns)

    def samples_ms(self, name: str) -> np.ndarray:
        st = self._stages.get(name)
        if st is None or not st.n:
            return np.zeros(0)
        return np.asarray(st.buf[: min(st.n, self.window)], dtype=np.float64) / 1e6

    def names(self) -> list[str]:
        return list(self._stages)

    def summary(self) -> dict[str, dict[str, float]]:
        out = {}
        for name, st in self._stages.items():
            s = self.samples_ms(name)
            out[name] = {
                "p50_ms": float(np.percentile(s, 50)),
                "p99_ms": float(np.percentile(s, 99)),
                "max_ms": float(s.max()),
                "n": int(st.n),
            }
        return out


class _Stage:
    """One stage's context manager and ring buffer (durations in ns, a plain list: no numpy per frame)."""

    __slots__ = ("name", "buf", "n", "_clock", "_current", "_window", "_t0")

    def __init__(self, timer: StageTimer, name: str) -> None:
        self.name = name
        self.buf: list[int] = [0] * timer.window
        self.n = 0
        self._clock = timer._clock
        self._current = timer.current
        self._window = timer.window
        self._t0 = 0

    def __enter__(self) -> None:
        self._t0 = self._clock()

    def __exit__(self, *exc: object) -> None:
        dt_ns = self._clock() - self._t0
        n = self.n
        self.buf[n % self._window] = dt_ns
        self.n = n + 1
        self._current[self.name] = dt_ns / 1e6

    def _record(self, dt_ns: int) -> None:
        n = self.n
        self.buf[n % self._window] = dt_ns
        self.n = n + 1
        self._current[self.name] = dt_ns / 1e6


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
    from edge import native

    native.warn_if_missing()  # once per process: a kernel that is not built leaves the slower numpy fallback
    cls = pipeline_class(profile)
    if hasattr(cls, "from_config"):
        return cls.from_config(frontend, config)
    return cls(frontend, config.section(f"pipeline.{profile}"))
