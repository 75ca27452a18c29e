"""Event segmentation: start on a threshold crossing, end with hysteresis against scintillation."""

from __future__ import annotations

import pytest

from edge.track.events import EventConfig, EventSegmenter


def run(levels, cfg=EventConfig(), thr=2.0):
    seg = EventSegmenter(cfg, thr)
    return seg, [seg.step(k * 200_000_000, lv) for k, lv in enumerate(levels)]


def test_event_starts_after_min_frames_and_ends_after_release_frames():
    levels = [0, 0, 3, 3, 3, 0, 0, 0, 0, 0, 0, 0, 0]
    seg, st = run(levels, EventConfig(min_event_frames=2, release_frames=7))
    assert [s.started for s in st].index(True) == 3
    assert st[3].event_start_ns == 2 * 200_000_000  # the event starts at the first crossing
    # quiet from frame 5: the 7th quiet frame (11) ends it
    assert [s.active for s in st] == [False] * 3 + [True] * 8 + [False] * 2
    assert st[11].ended and st[11].event_start_ns == 400_000_000 and not st[12].ended
    assert seg.events == 1 and seg.state == seg.IDLE


def test_single_spike_is_scintillation():
    seg, st = run([0, 5, 0, 0, 0, 0, 0, 0, 0, 0], EventConfig(min_event_frames=2, release_frames=3))
    assert not any(s.active for s in st)
    assert st[1].pending and st[4].discarded
    assert seg.events == 0 and seg.discarded == 1


def test_fading_target_keeps_the_event_open():
    """Quiet gaps shorter than release_frames do not end the event (premature stop)."""
    levels = [3, 3, 0, 0, 3, 0, 0, 0, 3, 3] + [0] * 4
    seg, st = run(levels, EventConfig(min_event_frames=2, release_frames=4))
    assert [s.ended for s in st].count(True) == 1 and st[-1].ended
    assert all(s.active for s in st[1:-1])


def test_level_hysteresis():
    """Between release_ratio * th and th a frame neither starts an event nor counts as quiet."""
    cfg = EventConfig(min_event_frames=1, release_frames=2, release_ratio=0.5)
    seg, st = run([3, 1.5, 1.5, 1.5, 0.5, 0.5, 1.5], cfg)
    assert [s.active for s in st] == [True, True, True, True, True, False, False]
    assert st[5].ended
    assert not st[6].pending  # 1.5 < th does not start a new event


def test_bad_threshold_rejected():
    with pytest.raises(ValueError):
        EventSegmenter(EventConfig(), 0.0)
