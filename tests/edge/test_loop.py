"""The frame loop on a fake clock: overruns are counted drops, never drift or a backlog."""

from __future__ import annotations

import numpy as np
import pytest

from edge.config import LoopConfig
from edge.loop import FrameLoop
from edge.pipeline import Pipeline
from edge.types import Detections, FrameResult
from hal.base import RadarSource, RawRead
from hal.clock import FakeClock
from hal.errors import DeviceError, SourceClosedError
from hal.waveform import d2g_frontend

PERIOD_NS = 200_000_000


class FakeSource(RadarSource):
    """Non-pacing source: returns the next frame immediately; can inject faults."""

    scheme = "fake"
    paces_itself = False

    def __init__(self, clock, n_frames=1000, faults=()):
        super().__init__(clock_ns=clock.now_ns)
        self._fe = d2g_frontend()
        self.n = n_frames
        self.faults = set(faults)
        self.k = 0
        self.opens = 0
        self.buffered_max = 0

    @property
    def frontend(self):
        return self._fe

    def _open(self):
        self.opens += 1

    def _read_raw(self, timeout_s):
        if self.k >= self.n:
            raise SourceClosedError("end")
        k = self.k
        self.k += 1
        if k in self.faults:
            raise DeviceError(f"injected fault at {k}")
        z = np.zeros(self._fe.frame_shape, dtype=np.int16)
        return RawRead(seq=k, i=z, q=z)

    def _close(self):
        pass


class ScriptedPipeline(Pipeline):
    """Takes a scripted amount of (fake) time per frame; may raise."""

    profile = "fake"

    def __init__(self, clock, durations_ms, fail_on=()):
        super().__init__(d2g_frontend(), None)
        self.clock = clock
        self.durations_ms = durations_ms
        self.fail_on = set(fail_on)
        self.seen = []

    def process(self, frame, timer):
        n = len(self.seen)
        self.seen.append(frame.seq)
        self.clock.advance_ns(int(self.durations_ms(n) * 1e6))
        if n in self.fail_on:
            raise RuntimeError("scripted failure")
        return FrameResult("fake", frame.seq, frame.t_ns, Detections.empty())


class RecordingSink:
    def __init__(self):
        self.results = []
        self.health = []
        self.closed = False

    def publish(self, result, health):
        if result is not None:
            self.results.append(result.seq)
        self.health.append(health)

    def close(self):
        self.closed = True


def test_deadline_grid_has_no_drift_and_overruns_are_counted_drops():
    clk = FakeClock()
    # every 10th frame takes 450 ms (2.25 periods); the others 50 ms
    pipe = ScriptedPipeline(clk, lambda n: 450.0 if n % 10 == 9 else 50.0)
    src = FakeSource(clk)
    sink = RecordingSink()
    loop = FrameLoop(src, pipe, LoopConfig(), sinks=[sink], clock=clk, pace="loop")
    t0 = clk.now_ns()
    summary = loop.run(max_frames=100)
    ticks = np.array(loop.tick_times_ns)
    # every tick lies exactly on the grid t0 + k * period: no drift
    assert np.all((ticks - t0) % PERIOD_NS == 0)
    assert summary.frames == 100
    assert summary.overruns == 10
    # each 450 ms frame overruns its slot and spills into the next two, which are skipped and counted
    assert summary.dropped_frames == 20
    # the last processed tick comes after 99 processed and 18 skipped ones (the final overrun's
    # two skipped ticks follow it)
    assert (ticks[-1] - t0) // PERIOD_NS == 99 + 18
    assert len(ticks) == 100
    # nothing queued: the source was read exactly once per processed frame
    assert src.k == 100
    assert sink.results == pipe.seen and sink.closed
    assert summary.stages["frame"]["p50_ms"] == pytest.approx(50.0)
    assert summary.stages["frame"]["max_ms"] == pytest.approx(450.0)


def test_no_overrun_when_within_budget():
    clk = FakeClock()
    loop = FrameLoop(FakeSource(clk), ScriptedPipeline(clk, lambda n: 199.0), clock=clk, pace="loop")
    s = loop.run(max_frames=50)
    assert (s.frames, s.overruns, s.dropped_frames) == (50, 0, 0)
    assert clk.now_ns() - 1_000_000_000 == 49 * PERIOD_NS + 199_000_000


def test_source_paced_loop_with_late_reader_counts_source_drops():
    from hal import open_radar

    clk = FakeClock()
    src = open_radar("sim://d2g?seed=1&frames=30", clock=clk)
    pipe = ScriptedPipeline(clk, lambda n: 450.0 if n == 3 else 20.0)
    loop = FrameLoop(src, pipe, clock=clk)
    assert loop.pace == "source"
    s = loop.run()
    assert s.overruns == 1
    # frame 3 is read when it completes (4 periods after open) and processed until 6.25 periods:
    # the board finished frames 4 and 5 meanwhile and kept only the newest, so frame 4 is lost
    assert s.source_dropped_frames == 1
    assert pipe.seen[:6] == [0, 1, 2, 3, 5, 6]
    assert s.frames == 29 and s.stop_reason == "end of source"


def test_pipeline_errors_skip_the_frame_and_stop_after_too_many():
    clk = FakeClock()
    pipe = ScriptedPipeline(clk, lambda n: 10.0, fail_on={2, 5})
    sink = RecordingSink()
    loop = FrameLoop(FakeSource(clk), pipe, LoopConfig(error_policy="skip"), sinks=[sink], clock=clk)
    s = loop.run(max_frames=10)
    assert s.errors == 2 and s.frames == 10
    assert 2 not in sink.results and 5 not in sink.results
    loop = FrameLoop(
        FakeSource(clk), ScriptedPipeline(clk, lambda n: 10.0, fail_on=set(range(100))),
        LoopConfig(error_policy="skip", max_consecutive_errors=3), clock=clk,
    )
    s = loop.run(max_frames=10)
    assert s.errors == 3 and s.stop_reason.startswith("pipeline error")


def test_source_fault_policy_reconnect_skip_stop():
    clk = FakeClock()
    src = FakeSource(clk, n_frames=20, faults={4, 9})
    loop = FrameLoop(src, ScriptedPipeline(clk, lambda n: 5.0), LoopConfig(error_policy="reconnect"), clock=clk)
    s = loop.run()
    assert s.reconnects == 2 and src.opens == 3 and s.frames == 18 and s.stop_reason == "end of source"

    src = FakeSource(clk, n_frames=20, faults={4})
    s = FrameLoop(src, ScriptedPipeline(clk, lambda n: 5.0), LoopConfig(error_policy="skip"), clock=clk).run()
    assert s.reconnects == 0 and src.opens == 1 and s.frames == 19

    src = FakeSource(clk, n_frames=20, faults={4})
    s = FrameLoop(src, ScriptedPipeline(clk, lambda n: 5.0), LoopConfig(error_policy="stop"), clock=clk).run()
    assert s.frames == 4 and s.stop_reason.startswith("source error")
    assert not src.is_open


class StallSource(FakeSource):
    """Delivers 3 frames, then nothing for ``stall_reads`` timeouts (time passes), then ends."""

    def __init__(self, clock, stall_reads):
        super().__init__(clock)
        self.clock = clock
        self.stall_reads = stall_reads

    def _read_raw(self, timeout_s):
        if self.k < 3:
            return super()._read_raw(timeout_s)
        if self.k < 3 + self.stall_reads:
            self.k += 1
            self.clock.advance_ns(int(timeout_s * 1e9))
            return None
        raise SourceClosedError("end")


def test_stalled_source_publishes_health_heartbeats():
    clk = FakeClock()
    sink = RecordingSink()
    cfg = LoopConfig(health_period_s=0.5)
    loop = FrameLoop(StallSource(clk, stall_reads=8), ScriptedPipeline(clk, lambda n: 1.0), cfg,
                     sinks=[sink], clock=clk, read_timeout_s=1.0, pace="source")
    s = loop.run()
    assert s.frames == 3 and s.timeouts == 8
    beats = [h for h in sink.health[3:]]
    # one heartbeat per 0.5 s read timeout while stalled, the state turning "stalled" after 1 s
    gaps = np.diff([h.t_ns for h in beats[:-1]])
    assert np.all(gaps <= 500_000_000)
    first_stalled = next(h for h in beats if h.state == "stalled")
    # reported within 1.5 s of the last frame (read timeout 1 s + one heartbeat period)
    assert first_stalled.t_ns - beats[0].last_frame_ns <= 1_500_000_000
    k = beats.index(first_stalled)
    assert all(h.state == "running" for h in beats[:k])
    assert all(h.state == "stalled" for h in beats[k:-1]) and beats[-1].state == "stopped"
    assert all(h.frames == 3 for h in beats)


def test_stop_from_another_context_ends_the_loop():
    clk = FakeClock()
    loop_ref = {}

    def dur(n):
        if n == 4:
            loop_ref["loop"].stop()
        return 1.0

    loop = FrameLoop(FakeSource(clk), ScriptedPipeline(clk, dur), clock=clk, pace="loop")
    loop_ref["loop"] = loop
    s = loop.run()
    assert s.frames == 5 and s.stop_reason == "stopped"


def test_frames_run_with_the_start_up_heap_frozen_and_it_is_handed_back_at_stop():
    """issue 9: a full garbage collection of the start-up heap takes longer than a lane frame; the loop runs its
    frames with that heap frozen (gc.freeze) and unfreezes it when it stops."""
    import gc

    clk = FakeClock()
    frozen = []

    class Probe(ScriptedPipeline):
        def process(self, frame, timer):
            frozen.append(gc.get_freeze_count())
            return super().process(frame, timer)

    gc.unfreeze()
    loop = FrameLoop(FakeSource(clk), Probe(clk, lambda n: 1.0), LoopConfig(), clock=clk, pace="none")
    assert loop.run(max_frames=5).frames == 5
    assert len(frozen) == 5 and min(frozen) > 1000  # the modules, the pipeline, this test's objects
    assert gc.get_freeze_count() == 0


def test_frozen_heap_collects_first_and_keeps_later_garbage_collectable():
    import gc
    import weakref

    from edge.ops.heap import frozen_heap

    class Node:
        pass

    gc.unfreeze()
    dead = Node()
    dead.self = dead  # a reference cycle: only the cyclic collector frees it
    ref = weakref.ref(dead)
    del dead
    with frozen_heap() as n:
        assert ref() is None  # collected before freezing, not frozen for good
        assert n > 1000 and gc.get_freeze_count() > 0
        late = Node()
        late.self = late
        late_ref = weakref.ref(late)
        del late
        gc.collect()
        assert late_ref() is None  # objects made while frozen are collected as usual
    assert gc.get_freeze_count() == 0


class AbsentSource(FakeSource):
    """A device that is not there for the first ``absent_opens`` attempts to open it."""

    def __init__(self, clock, absent_opens, n_frames=5):
        super().__init__(clock, n_frames=n_frames)
        self.clock = clock
        self.absent = absent_opens
        self.open_times_ns = []

    def _open(self):
        self.opens += 1
        self.open_times_ns.append(self.clock.now_ns())
        if self.opens <= self.absent:
            raise DeviceError("cannot open /dev/radar-d2g: [Errno 2] No such file or directory")


def test_a_device_missing_at_start_is_served_as_a_fault_and_retried_with_backoff():
    """Before, the first failed open ended the run (``radar-edge run`` exit 2, a systemd restart storm)."""
    clk = FakeClock()
    sink = RecordingSink()
    src = AbsentSource(clk, absent_opens=8)
    loop = FrameLoop(src, ScriptedPipeline(clk, lambda n: 1.0), LoopConfig(reconnect_backoff_s=1.0, health_period_s=0.5),
                     sinks=[sink], clock=clk)
    s = loop.run()
    assert src.opens == 9 and s.frames == 5 and s.stop_reason == "end of source"
    assert s.errors == 8  # each failed open is a counted source fault
    gaps_s = np.diff(src.open_times_ns) / 1e9
    assert gaps_s.tolist() == pytest.approx([1, 2, 4, 8, 16, 30, 30, 30])  # doubling, at most 30 s
    waiting = [h for h in sink.health if h.frames == 0 and h.state != "stopped"]
    assert waiting and all(h.state == "fault" and not h.source_ok for h in waiting)
    assert [h.errors for h in waiting] == sorted(h.errors for h in waiting) and waiting[-1].errors == 8
    assert np.diff([h.t_ns for h in waiting]).max() <= 500_000_000  # a heartbeat every health period
    assert sink.results == [0, 1, 2, 3, 4]


def test_missing_device_stop_policy_duration_and_stop_while_waiting():
    clk = FakeClock()
    with pytest.raises(DeviceError):
        FrameLoop(AbsentSource(clk, 1), ScriptedPipeline(clk, lambda n: 1.0), LoopConfig(error_policy="stop"),
                  clock=clk).run()
    s = FrameLoop(AbsentSource(clk, 100), ScriptedPipeline(clk, lambda n: 1.0), LoopConfig(), clock=clk).run(duration_s=10)
    assert s.frames == 0 and s.stop_reason == "10 s" and s.errors == 4  # opens at 0, 1, 3, 7 s
    loop_ref = {}

    class StopSink(RecordingSink):
        def publish(self, result, health):
            super().publish(result, health)
            if len(self.health) == 5:
                loop_ref["loop"].stop()

    loop = FrameLoop(AbsentSource(clk, 100), ScriptedPipeline(clk, lambda n: 1.0), LoopConfig(), sinks=[StopSink()],
                     clock=clk)
    loop_ref["loop"] = loop
    s = loop.run()
    assert s.frames == 0 and s.stop_reason == "stopped"


class ClippingSource(FakeSource):
    """Frames whose I rail sits at the ADC's full scale for half of its samples in frames ``clipping``."""

    def __init__(self, clock, n_frames, clipping):
        super().__init__(clock, n_frames)
        self.clipping = clipping

    def _read_raw(self, timeout_s):
        raw = super()._read_raw(timeout_s)
        if raw.seq in self.clipping:
            i = np.zeros(self._fe.frame_shape, dtype=np.int16)
            i[..., : i.shape[-1] // 2] = self._fe.adc_max
            return RawRead(seq=raw.seq, i=i, q=raw.q)
        return raw


def test_health_carries_the_adc_saturation_of_one_frame_a_second_over_ten_seconds(caplog):
    caplog.set_level("INFO", logger="edge.loop")
    clk = FakeClock()
    src = ClippingSource(clk, 200, clipping=range(50, 100))  # 200 ms frames: clipping from 10 s to 20 s
    sink = RecordingSink()
    loop = FrameLoop(src, ScriptedPipeline(clk, lambda n: 20.0), LoopConfig(), sinks=[sink], clock=clk, pace="loop")
    loop.run(max_frames=200)
    frac = [h.adc_clipped_fraction for h in sink.health[:-1]]  # the last is the stop heartbeat
    assert frac[0] == 0.0 and max(frac[:50]) == 0.0
    # one frame in five is sampled (frames 0, 5, 10, ...), the last ten of them kept
    assert frac[50] == pytest.approx(0.25 / 10, rel=1e-6)  # the first clipping frame sampled, among ten
    assert frac[99] == pytest.approx(0.25)  # ten seconds of clipping: a quarter of the samples
    # it shows until the sample of frame 145 pushes out that of frame 95, the last clipping one sampled
    assert [k for k, f in enumerate(frac) if f > 0] == list(range(50, 145))
    # the log says so once when it starts and once when it ends
    msgs = [r.getMessage() for r in caplog.records if "ADC" in r.getMessage()]
    assert len(msgs) == 2 and msgs[0].startswith("the ADC saturates: 2.50 %") and msgs[1] == "the ADC no longer saturates"
