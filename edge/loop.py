"""The fixed-budget frame loop.

One thread reads a frame, runs the pipeline, hands the result to the output sinks and accounts for
time. Three ways of keeping time:

* ``pace="loop"``: the loop is the scheduler (python-can ``ThreadBasedCyclicSendTask``): tick ``k``
  is at ``t0 + k * period`` on a monotonic clock, so there is no drift. A frame whose processing
  ends past its slot counts as an *overrun*; the ticks it overran are skipped and counted as
  *dropped* -- the loop never builds a backlog.
* ``pace="source"``: the source blocks until the board's next frame (hardware, real-time
  simulation, paced replay). The frame's deadline is its receive time plus one period; a frame that
  waited longer than a period before the loop got to it is stale and dropped. Frames the board made
  while the loop was busy are lost in the source's one-frame buffer and counted from the frame
  counter (``source.stats.dropped_frames``).
* ``pace="none"``: offline (evaluation, benchmarks, replay at speed 0): every frame is processed
  as fast as possible, no deadlines.

``pace="auto"`` picks ``source`` for sources that pace themselves and ``none`` for the others.

Errors follow an explicit policy (``loop.error_policy``): a source fault either skips the frame,
reconnects the source with exponential back-off, or stops the loop; a pipeline exception skips the
frame; ``max_consecutive_errors`` failures in a row stop the loop. Sinks get the result of every
frame and, when no frame arrives, a health heartbeat at least every ``health_period_s``.

A device that cannot be opened at start (a board not plugged in yet) does not end the run unless the
policy is ``stop``: the loop reports state ``fault`` to the sinks every ``health_period_s`` and
retries opening it with back-off (``reconnect_backoff_s`` doubling, at most 32 times it and 30 s),
for as long as it takes; then frames run as usual.

``errors`` in the health and the summary counts pipeline failures, source faults the loop saw, and
the faults the source handled itself (link faults, malformed frames and resynchronisations it
counts in ``source.stats``); ``reconnects`` counts the loop's and the source's own reconnects.

``adc_clipped_fraction`` in the health is the share of I and Q samples at the ADC's full scale over one frame a
second for the last ten seconds (a board that clips on its TX->RX leakage, or on a target pressed against the
radome); the outputs show it as *degraded* above :data:`hal.frame.SATURATED_FRACTION`.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Protocol

import numpy as np

from edge.config import LoopConfig
from edge.ops.affinity import check as check_cpus
from edge.ops.affinity import pinned
from edge.ops.heap import frozen_heap
from edge.pipeline import Pipeline, StageTimer
from edge.types import FrameResult, LoopHealth
from hal.base import RadarSource
from hal.clock import MonotonicClock
from hal.errors import DeviceError, RadarError, SourceClosedError, SourceTimeoutError
from hal.frame import SATURATED_FRACTION

log = logging.getLogger(__name__)

#: the loop samples one frame's ADC saturation this often (ns), and keeps the last ADC_CHECK_FRAMES of them
ADC_CHECK_PERIOD_NS = 1_000_000_000
ADC_CHECK_FRAMES = 10


class Sink(Protocol):
    """An output: gets every result (or ``None`` with a heartbeat); must never block."""

    def publish(self, result: FrameResult | None, health: LoopHealth) -> None: ...

    def close(self) -> None: ...


@dataclass
class LoopCounters:
    frames: int = 0
    dropped_frames: int = 0  # ticks skipped after overruns + stale frames (loop side)
    overruns: int = 0
    errors: int = 0
    source_errors: int = 0
    timeouts: int = 0
    reconnects: int = 0
    sink_errors: int = 0


@dataclass
class LoopSummary:
    """What ``run`` returns and what the CLI prints at stop."""

    frames: int
    dropped_frames: int
    source_dropped_frames: int
    overruns: int
    errors: int
    timeouts: int
    reconnects: int
    duration_s: float
    budget_ms: float
    stages: dict[str, dict[str, float]] = field(default_factory=dict)
    stop_reason: str = ""

    def lines(self) -> list[str]:
        out = [
            f"frames {self.frames}, dropped {self.dropped_frames} (loop) + {self.source_dropped_frames} (source), "
            f"overruns {self.overruns}, errors {self.errors}, timeouts {self.timeouts}, reconnects {self.reconnects}, "
            f"{self.duration_s:.1f} s ({self.stop_reason})",
            f"{'stage':<14}{'p50 ms':>9}{'p99 ms':>9}{'max ms':>9}{'p99/budget':>12}",
        ]
        for name, s in self.stages.items():
            frac = "  (waiting)" if name == "read" else f"{s['p99_ms'] / self.budget_ms:11.1%}"
            out.append(f"{name:<14}{s['p50_ms']:9.3f}{s['p99_ms']:9.3f}{s['max_ms']:9.3f}{frac}")
        return out


class FrameLoop:
    """Runs ``pipeline`` on frames from ``source`` (see the module docstring)."""

    def __init__(
        self,
        source: RadarSource,
        pipeline: Pipeline,
        config: LoopConfig | None = None,
        *,
        sinks: Iterable[Sink] = (),
        clock: Any = None,
        pace: str = "auto",
        read_timeout_s: float = 1.0,
        on_result: Callable[[FrameResult], None] | None = None,
    ) -> None:
        self.source = source
        self.pipeline = pipeline
        self.config = config or LoopConfig()
        self.sinks = list(sinks)
        self.clock = clock or MonotonicClock()
        if pace == "auto":
            # a source that does not pace itself is an offline one (replay at speed 0, simulation
            # without real time): as fast as possible
            pace = "source" if source.paces_itself else "none"
        if pace not in ("loop", "source", "none"):
            raise ValueError(f"pace must be 'loop', 'source', 'none' or 'auto', got {pace!r}")
        self.pace = pace
        self.read_timeout_s = read_timeout_s
        self.on_result = on_result
        check_cpus(self.config.cpus, "loop.cpus")
        self.period_ns = int(round(source.frontend.waveform.frame_period_s * 1e9))
        self.timer = StageTimer(self.config.stats_window_frames, clock_ns=self.clock.now_ns)
        self.counters = LoopCounters()
        self._running = False
        self._consecutive_errors = 0
        self._last_frame_ns = 0
        self._last_health_ns = 0
        self._state = "starting"
        # ADC saturation, sampled on one frame a second: (clipped, total) samples of the last ADC_CHECK_FRAMES
        self._adc_checks: deque[tuple[int, int]] = deque(maxlen=ADC_CHECK_FRAMES)
        self._adc_check_ns: int | None = None
        self._adc_saturated = False
        self.tick_times_ns: list[int] = []  # loop-paced tick times of the last run (bounded)

    # --- control -----------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask the loop to stop after the current frame (safe from a signal handler)."""
        self._running = False
        self.clock.interrupt()

    @property
    def budget_ms(self) -> float:
        return self.period_ns / 1e6

    def health(self) -> LoopHealth:
        s = self.timer.samples_ms("frame")
        p99 = float(np.percentile(s, 99)) if s.size else 0.0
        return LoopHealth(
            t_ns=self.clock.now_ns(),
            frames=self.counters.frames,
            dropped_frames=self.counters.dropped_frames + self.source.stats.dropped_frames,
            overruns=self.counters.overruns,
            errors=self.errors,
            source_ok=self._state == "running",
            last_frame_ns=self._last_frame_ns,
            frame_p99_ms=p99,
            budget_ms=self.budget_ms,
            state=self._state,
            adc_clipped_fraction=self.adc_clipped_fraction,
        )

    def _note_saturation(self) -> None:
        """Log when the ADC starts and stops saturating (the outputs' degraded status)."""
        clipped = self.adc_clipped_fraction
        saturated = clipped is not None and clipped > SATURATED_FRACTION
        if saturated and not self._adc_saturated:
            log.warning("the ADC saturates: %.2f %% of the samples at full scale over the last %d s "
                        "(a Distance2Go that clips on its TX->RX leakage: radar-edge calibrate --headroom)",
                        100.0 * clipped, len(self._adc_checks))
        elif self._adc_saturated and not saturated:
            log.info("the ADC no longer saturates")
        self._adc_saturated = saturated

    @property
    def adc_clipped_fraction(self) -> float | None:
        """Share of the samples at the ADC's full scale over the last :data:`ADC_CHECK_FRAMES` sampled frames."""
        total = sum(n for _, n in self._adc_checks)
        return sum(c for c, _ in self._adc_checks) / total if total else None

    @property
    def errors(self) -> int:
        """Pipeline failures, source faults the loop saw and the faults the source handled itself."""
        return self.counters.errors + self.counters.source_errors + self.source.stats.errors

    @property
    def reconnects(self) -> int:
        """Reconnects by the loop's error policy and by the source itself."""
        return self.counters.reconnects + self.source.stats.reconnects

    # --- the loop ------------------------------------------------------------------------------
    def run(self, max_frames: int | None = None, duration_s: float | None = None) -> LoopSummary:
        """Run until ``max_frames``, ``duration_s``, the end of the source, :meth:`stop` or a fatal error.

        With ``loop.cpus`` set the calling thread is pinned to those CPUs for the run. The start-up heap is
        frozen for the garbage collector while frames run (:func:`edge.ops.heap.frozen_heap`, issue 9: a full
        collection of it takes longer than a lane frame).
        """
        with pinned(self.config.cpus, "frame loop"), frozen_heap():
            return self._run(max_frames, duration_s)

    def _run(self, max_frames: int | None, duration_s: float | None) -> LoopSummary:
        clk = self.clock
        self._running = True
        t_start = clk.now_ns()
        t_end = None if duration_s is None else t_start + int(duration_s * 1e9)
        t0 = t_start
        k = 0
        reason = "stopped"
        heartbeat_ns = int(self.config.health_period_s * 1e9)
        self._state = "running"
        try:
            if not self.source.is_open and not self._open_source(t_end):
                reason = f"{duration_s} s" if self._running else "stopped"
                self._running = False
            while self._running:
                if max_frames is not None and self.counters.frames >= max_frames:
                    reason = f"{max_frames} frames"
                    break
                if t_end is not None and clk.now_ns() >= t_end:
                    reason = f"{duration_s} s"
                    break
                tick = t0 + k * self.period_ns
                if self.pace == "loop":
                    clk.sleep_until_ns(tick)
                    if not self._running:
                        break
                    if len(self.tick_times_ns) < 100_000:
                        self.tick_times_ns.append(tick)
                try:
                    timeout = min(self.read_timeout_s, self.config.health_period_s) if self.pace != "none" else None
                    with self.timer.stage("read"):
                        frame = self.source.read_frame(timeout=timeout)
                except SourceTimeoutError:
                    self.counters.timeouts += 1
                    if clk.now_ns() - max(self._last_frame_ns, t_start) > self.read_timeout_s * 1e9:
                        if self._state != "stalled":
                            log.warning("no frame for %.1f s: source stalled", self.read_timeout_s)
                        self._state = "stalled"
                    self._heartbeat(heartbeat_ns, force=True)
                    if self.pace == "loop":
                        k = self._next_tick(t0, k, clk.now_ns())
                    continue
                except SourceClosedError:
                    reason = "end of source"
                    break
                except RadarError as exc:
                    self.counters.source_errors += 1
                    self._state = "fault"
                    self._heartbeat(heartbeat_ns, force=True)
                    if not self._on_source_error(exc):
                        reason = f"source error: {exc}"
                        break
                    if self.pace == "loop":
                        k = self._next_tick(t0, k, clk.now_ns())
                    continue

                t_rx = clk.now_ns()
                if self._adc_check_ns is None or t_rx - self._adc_check_ns >= ADC_CHECK_PERIOD_NS:
                    self._adc_check_ns = t_rx
                    self._adc_checks.append(frame.clipped_samples())
                    self._note_saturation()
                if self.pace == "source" and frame.t_ns and t_rx - frame.t_ns > self.period_ns:
                    self.counters.dropped_frames += 1  # stale: waited more than a period
                    continue
                result = None
                t_proc = clk.now_ns()
                try:
                    with self.timer.stage("frame"):
                        result = self.pipeline.process(frame, self.timer)
                    self._consecutive_errors = 0
                    self._state = "running"
                except Exception as exc:  # noqa: BLE001 - the firmware boundary: a bad frame must not kill the service
                    self.counters.errors += 1
                    self._consecutive_errors += 1
                    self._state = "fault"
                    log.error("pipeline failed on frame %d: %s", frame.seq, exc, exc_info=log.isEnabledFor(logging.DEBUG))
                    if self._consecutive_errors >= self.config.max_consecutive_errors or self.config.error_policy == "stop":
                        reason = f"pipeline error: {exc}"
                        break
                t_done = clk.now_ns()
                self.counters.frames += 1
                self._last_frame_ns = t_done
                deadline = (tick + self.period_ns) if self.pace == "loop" else (frame.t_ns or t_proc) + self.period_ns
                if self.pace != "none" and t_done > deadline:
                    self.counters.overruns += 1
                if result is not None:
                    self._publish(result)
                    if self.on_result is not None:
                        self.on_result(result)
                if self.pace == "loop":
                    k = self._next_tick(t0, k, t_done)
        finally:
            self._state = "stopped"
            self._heartbeat(0, force=True)
            for s in self.sinks:
                try:
                    s.close()
                except Exception as exc:  # noqa: BLE001 - closing one output must not prevent closing the others
                    log.error("closing output %s failed: %s", type(s).__name__, exc)
            self.source.close()
            self.pipeline.close()
        return LoopSummary(
            frames=self.counters.frames,
            dropped_frames=self.counters.dropped_frames,
            source_dropped_frames=self.source.stats.dropped_frames,
            overruns=self.counters.overruns,
            errors=self.errors,
            timeouts=self.counters.timeouts,
            reconnects=self.reconnects,
            duration_s=(clk.now_ns() - t_start) / 1e9,
            budget_ms=self.budget_ms,
            stages=self.timer.summary(),
            stop_reason=reason,
        )

    def _open_source(self, t_end: int | None) -> bool:
        """Open the source; a device that is not there is served as a fault and retried (module docstring).

        False when the loop was stopped or ``t_end`` passed before it opened. With ``error_policy =
        "stop"`` the first failure is raised.
        """
        attempt = 0
        while self._running:
            try:
                self.source.open()
            except DeviceError as exc:
                if self.config.error_policy == "stop":
                    raise
                attempt += 1
                self.counters.source_errors += 1
                self._state = "fault"
                delay_s = min(30.0, self.config.reconnect_backoff_s * 2 ** min(attempt - 1, 5))
                level = logging.ERROR if attempt == 1 or attempt % 20 == 0 else logging.INFO
                log.log(level, "cannot open the source (attempt %d): %s; serving the fault, next attempt in %.1f s",
                        attempt, exc, delay_s)
                if not self._wait_serving(self.clock.now_ns() + int(delay_s * 1e9), t_end):
                    return False
                continue
            if attempt:
                log.warning("source opened after %d failed attempt(s)", attempt)
            self._state = "running"
            return True
        return False

    def _wait_serving(self, until_ns: int, t_end: int | None) -> bool:
        """Wait until ``until_ns`` publishing heartbeats; False if stopped or ``t_end`` came first."""
        period_ns = int(self.config.health_period_s * 1e9)
        while self._running:
            self._heartbeat(period_ns, force=True)
            now = self.clock.now_ns()
            if t_end is not None and now >= t_end:
                return False
            if now >= until_ns:
                return True
            self.clock.sleep_until_ns(min(until_ns, now + period_ns, t_end if t_end is not None else until_ns))
        return False

    def _next_tick(self, t0: int, k: int, now: int) -> int:
        """Index of the next tick on the grid; ticks already past are skipped and counted."""
        nxt = k + 1
        late = now - (t0 + nxt * self.period_ns)
        if late > 0:
            missed = math.ceil(late / self.period_ns)
            self.counters.dropped_frames += missed
            nxt += missed
        return nxt

    def _on_source_error(self, exc: RadarError) -> bool:
        """Apply the error policy; False means stop."""
        pol = self.config.error_policy
        self._consecutive_errors += 1
        log.error("source fault (%s): %s", pol, exc)
        if pol == "stop" or self._consecutive_errors >= self.config.max_consecutive_errors:
            return False
        if pol == "reconnect":
            backoff = min(30.0, self.config.reconnect_backoff_s * 2 ** min(self._consecutive_errors - 1, 5))
            self.source.close()
            self.clock.sleep_until_ns(self.clock.now_ns() + int(backoff * 1e9))
            try:
                self.source.open()
                self.counters.reconnects += 1
            except RadarError as exc2:
                log.error("reopening the source failed: %s", exc2)
        return True

    def _publish(self, result: FrameResult) -> None:
        h = self.health()
        self._last_health_ns = h.t_ns
        for s in self.sinks:
            try:
                s.publish(result, h)
            except Exception as exc:  # noqa: BLE001 - an output fault is counted, never fatal to the loop
                self.counters.sink_errors += 1
                log.error("output %s failed: %s", type(s).__name__, exc)

    def _heartbeat(self, period_ns: int, force: bool = False) -> None:
        now = self.clock.now_ns()
        if not force and now - self._last_health_ns < period_ns:
            return
        self._last_health_ns = now
        h = self.health()
        for s in self.sinks:
            try:
                s.publish(None, h)
            except Exception as exc:  # noqa: BLE001 - see _publish
                self.counters.sink_errors += 1
                log.error("output %s failed: %s", type(s).__name__, exc)
