"""Speed-alias and one-event-per-passage tallies of the surveillance evaluation (issue 31), on constructed rows."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from edge.evaluation.surveillance import _Instance, _speed_and_passage_tallies
from edge.types import ClassifiedEvent

STEP = 10.7


def _truth(tid, event, first, last):
    return SimpleNamespace(id=tid, event=event, first_frame=first, last_frame=last)


def _row(tid, event, cls, v_true, v_est, n_tracks=1, uncertain=False):
    return {"id": tid, "event": event, "class": cls, "mean_radial_speed_kmh_true": v_true,
            "mean_radial_speed_kmh_est": v_est, "speed_mae_kmh": None if v_est is None else abs(v_est - v_true),
            "n_tracks": n_tracks, "speed_uncertain": uncertain}


def _view(ids, lo, hi):
    return SimpleNamespace(id=np.array(ids), range_min_m=np.array(lo, dtype=float), range_max_m=np.array(hi, dtype=float))


def test_alias_steps_uncertain_flags_and_passages_of_one_event():
    truths = {100: _truth(100, 0, 0, 9), 200: _truth(200, 1, 20, 29), 300: _truth(300, 2, 40, 49)}
    rows = [_row(100, 0, "truck", 23.8, 13.1),  # one alias step slow
            _row(200, 1, "car", -31.0, -31.4, uncertain=True),
            _row(300, 2, "pedestrian", 4.0, 4.2)]
    views = [_view([100], [5.0], [15.0]) for _ in range(10)] + [_view([], [], []) for _ in range(50)]
    ev = ClassifiedEvent(7, "car", {}, 20.0, "receding", 0, 0)
    frag = _Instance(7, frames=[2, 3, 4], ranges=[16.0, 17.0, 30.0], event=ev)  # beside the truck in 2 of 3 frames
    clutter = _Instance(8, frames=[41, 42], ranges=[60.0, 60.0], event=ev)  # far from the walker: not its passage
    t = _speed_and_passage_tallies(rows, truths, [frag, clutter], views, STEP)
    assert t == {"vehicles_with_speed": 2, "vehicles_alias_off": 1, "vehicles_speed_uncertain": 1,
                 "vehicles_alias_off_unflagged": 1, "speed_abs_error_sum_certain_kmh": pytest.approx(10.7 + 0.2),
                 "speed_n_certain": 2, "single_passages_tracked": 3, "single_passages_one_event": 2}
    assert [r["speed_alias_steps"] for r in rows] == [-1, 0, 0]
    # the same truck flagged: still off by a step, but no longer an unseen error, and out of the certain speeds
    rows[0]["speed_uncertain"] = True
    t = _speed_and_passage_tallies(rows, truths, [frag, clutter], views, STEP)
    assert (t["vehicles_alias_off"], t["vehicles_alias_off_unflagged"], t["speed_n_certain"]) == (1, 0, 1)
    assert t["speed_abs_error_sum_certain_kmh"] == pytest.approx(0.2)
    assert [r["passage_events"] for r in rows] == [2, 1, 1]


def test_a_speed_whose_alias_is_not_sure_is_published_as_not_available():
    """With the alias chosen from the whole history: a target whose range moves 5 km/h off its Doppler (half an alias step: which alias is a coin toss) is
    published with radial speed NaN, n/a on CAN (DynProp unknown) and Modbus; one whose range agrees is published."""
    import math

    from edge.classify.features import FeatureConfig
    from edge.outputs.can_out import dyn_prop
    from edge.outputs.registers import TRACK, decode, encode
    from edge.track.surveillance import SurveillanceTracker
    from hal.waveform import d2g_frontend
    from tests.edge.survscene import blob, points

    def published(v_range):
        st = SurveillanceTracker(d2g_frontend(), 2.0, classify=False,
                                 features=FeatureConfig(event_speed_alias="history"))
        out = []
        for n in range(10):
            step = st.update(int(n * 0.2e9), points(blob(5.0 + v_range / 3.6 * 0.2 * n, 20.0, 300, 0)), seq=n)
            out += [t for t in step.tracks]
        return out

    sure = published(20.0)
    assert len(sure) >= 5 and all(t.radial_speed_mps * 3.6 == pytest.approx(20.0, abs=1.0) for t in sure[2:])
    unsure = published(25.0)
    assert unsure and all(math.isnan(t.radial_speed_mps) for t in unsure)
    assert dyn_prop(unsure[-1]) == 4
    assert decode(TRACK.regs[5], encode(TRACK.regs[5], unsure[-1].vy_mps)) is None


def test_a_speed_whose_fitted_alias_is_not_sure_is_published_as_not_available():
    """With event_speed_alias = "fit" (the alias fitted to the range history with the Doppler as slope): a target
    whose range moves half an alias step off its Doppler's speed is published as n/a; one whose range agrees is
    published at its speed, and its event is not flagged."""
    import math

    from edge.classify.features import FeatureConfig
    from edge.track.surveillance import SurveillanceTracker
    from hal.waveform import d2g_frontend
    from tests.edge.survscene import blob, points

    def published(v_range):
        st = SurveillanceTracker(d2g_frontend(), 2.0, classify=False, features=FeatureConfig(event_speed_alias="fit"))
        out = []
        for n in range(10):
            step = st.update(int(n * 0.2e9), points(blob(5.0 + v_range / 3.6 * 0.2 * n, 20.0, 300, 0)), seq=n)
            out += [t for t in step.tracks]
        return out, st.close()

    sure, events = published(20.0)
    assert len(sure) >= 5 and all(t.radial_speed_mps * 3.6 == pytest.approx(20.0, abs=1.0) for t in sure[2:])
    assert len(events) == 1 and not events[0].speed_uncertain
    assert events[0].mean_radial_speed_kmh == pytest.approx(20.0, abs=1.0)
    unsure, events = published(20.0 + 5.35)
    assert unsure and all(math.isnan(t.radial_speed_mps) for t in unsure)
    assert len(events) == 1 and events[0].speed_uncertain


def _body_points(lo, hi, v_kmh, amp=5.0):
    """The cells of a body from range ``lo`` to ``hi`` (m), nine Doppler bins around its wrapped ``v_kmh``."""
    from edge.classify.features import MapPoints
    from tests.edge.survscene import N_BINS, RANGE_SPAN_M, VMAX, wrap

    dr, dv = RANGE_SPAN_M / N_BINS, 2 * VMAX / N_BINS
    rb = np.arange(int(round(lo / dr)), int(round(hi / dr)) + 1)
    db = np.mod(int(round((wrap(v_kmh) + VMAX) / dv)) + np.arange(-4, 5), N_BINS)
    r, d = (a.ravel() for a in np.meshgrid(rb, db, indexing="ij"))
    return MapPoints((r * dr).astype(np.float32), (d * dv - VMAX).astype(np.float32),
                     np.full(r.size, amp, np.float32), r.astype(np.int32), d.astype(np.int32),
                     np.zeros(r.size, np.int32))


@pytest.mark.parametrize("speed_feature", ["doppler", "event"])
def test_the_event_speed_feature_is_the_event_speeds_alias_on_a_long_body(speed_feature):
    """A 12 m body receding at 25 km/h from beside the radar (its rear stays at 6 m while its front moves out, then
    the front is cut at 23.9 m): its centroid moves at about half the speed. The event speed, fitted to the edges, is
    25 km/h; the ``event`` speed feature is on that alias, the ``doppler`` one (each frame's alias from the centroid's
    middle-half rate) one step slow."""
    from edge.classify.features import FeatureConfig
    from edge.track.surveillance import SurveillanceTracker
    from hal.waveform import d2g_frontend

    st = SurveillanceTracker(d2g_frontend(), 2.0, classify=False,
                             features=FeatureConfig(event_speed_alias="fit", speed_feature=speed_feature))
    events = []
    for n in range(24):
        front = 7.0 + 25.0 / 3.6 * 0.2 * n
        hi = min(front, 23.9)
        events += st.update(int(n * 0.2e9), _body_points(min(max(front - 12.0, 6.0), hi - 0.5), hi, 25.0),
                            seq=n).classifications
    events += st.close()
    assert len(events) == 1 and events[0].mean_radial_speed_kmh == pytest.approx(25.0, abs=0.5)
    feature = events[0].features["abs_radial_speed_mean_kmh"]
    assert feature == pytest.approx(25.0 if speed_feature == "event" else 25.0 - STEP, abs=1.0)


def test_live_class_tallies_count_the_matched_tracks_frames_with_a_class():
    """Frames of matched tracks with a provisional class count; those of the target's class are right; frames
    without a class and unmatched tracks do not count."""
    from edge.evaluation.surveillance import _live_class_tallies

    truths = {1: SimpleNamespace(cls="car"), 2: SimpleNamespace(cls="pedestrian")}
    a = _Instance(10, frames=[0, 1, 2, 3], classes=[None, "truck", "car", "car"], target=1)
    b = _Instance(11, frames=[5, 6], classes=["pedestrian", "car"], target=2)
    stray = _Instance(12, frames=[7, 8], classes=["car", "car"])
    no_row = _Instance(13, frames=[9], classes=["car"], target=3)  # a target in view that has no truth row
    assert _live_class_tallies([a, b, stray, no_row], truths) == {"live_class_frames": 5, "live_class_correct": 3}
    assert _live_class_tallies([], truths) == {"live_class_frames": 0, "live_class_correct": 0}
