"""StageTimer: per-stage ring buffers, latest values and the summary the loop reports."""

import numpy as np
import pytest

from edge.pipeline import StageTimer


class StepClock:
    """A clock that advances by the next programmed step on every read (ns)."""

    def __init__(self, steps):
        self.steps = list(steps)
        self.t = 0

    def __call__(self) -> int:
        self.t += self.steps.pop(0)
        return self.t


def test_stages_timed_with_the_given_clock():
    # enter/exit reads: a 0 -> 1 ms, b 0 -> 3 ms, a again 0 -> 2 ms
    clock = StepClock([0, 1_000_000, 0, 3_000_000, 0, 2_000_000])
    t = StageTimer(8, clock_ns=clock)
    with t.stage("a"):
        pass
    with t.stage("b"):
        pass
    with t.stage("a"):
        pass
    assert t.names() == ["a", "b"]
    np.testing.assert_allclose(t.samples_ms("a"), [1.0, 2.0])
    np.testing.assert_allclose(t.samples_ms("b"), [3.0])
    assert t.current == {"a": 2.0, "b": 3.0}
    s = t.summary()
    assert s["a"]["n"] == 2 and s["a"]["max_ms"] == pytest.approx(2.0)
    assert s["a"]["p50_ms"] == pytest.approx(1.5)
    assert t.samples_ms("never").size == 0


def test_ring_keeps_the_last_window_and_counts_all():
    t = StageTimer(4)
    for k in range(1, 11):  # 1..10 ms
        t.record("frame", k * 1_000_000)
    got = np.sort(t.samples_ms("frame"))
    np.testing.assert_allclose(got, [7.0, 8.0, 9.0, 10.0])
    assert t.summary()["frame"]["n"] == 10
    assert t.current["frame"] == pytest.approx(10.0)


def test_stage_timed_even_when_the_body_raises():
    clock = StepClock([0, 5_000_000])
    t = StageTimer(4, clock_ns=clock)
    with pytest.raises(ValueError):
        with t.stage("x"):
            raise ValueError("boom")
    np.testing.assert_allclose(t.samples_ms("x"), [5.0])
