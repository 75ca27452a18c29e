"""One track per target (Tavanti Fig. 9): the rigid-body merge of two tracks on one vehicle, and the
merge guard that needs another track near an enlarged cluster (SurveillanceTracker on hand-made
clusters, no simulator)."""

from __future__ import annotations

import numpy as np
import pytest

from edge.track.alphabeta import AlphaBetaConfig
from edge.track.events import EventConfig
from edge.track.surveillance import SurveillanceTracker
from hal.waveform import d2g_frontend
from tests.edge.survscene import VMAX, blob, points, wrap

FE = d2g_frontend()
T = 0.2


def tracker(cfg, events_cfg=None):
    return SurveillanceTracker(FE, 2.0, tracking=cfg, events=events_cfg, classify=False)


def feed(st, scene, frames):
    """Feed ``scene(n) -> list of (range, v, cells)`` to ``st`` for ``frames`` frames; yields each frame's step."""
    for n in range(frames):
        bl = [blob(r, v, c, k) for k, (r, v, c) in enumerate(scene(n))]
        yield st.update(int(n * T * 1e9), points(*bl), seq=n)


def run(cfg, scene, frames, events_cfg=None):
    """Feed ``scene`` for ``frames`` frames, then close; -> (tracker, ids per frame, events)."""
    st = tracker(cfg, events_cfg)
    ids, events = [], []
    for step in feed(st, scene, frames):
        ids.append({t.track_id for t in st.tracker.tracks})
        events.extend(step.classifications)
    events.extend(st.close())
    return st, ids, events


def car_front_and_rear(n, v=16.5):
    """A car receding at ``v`` km/h: its front cluster from frame 0, its rear part 3 m behind from frame 6
    (the body coming into view beside the radar), the same Doppler (one rigid body)."""
    r = 5.0 + v / 3.6 * T * n
    out = [(r, v, 400)]
    if n >= 6:
        out.append((r - 3.0, v, 250))
    return out


@pytest.mark.parametrize("min_speed, tracks_at_end", [(13.0, 1), (0.0, 2)])
def test_front_and_rear_of_one_car_become_one_track(min_speed, tracks_at_end):
    # the rigid-body rule alone (the body rule, body_length_m, would join the parts when the rear track ends)
    st, ids, events = run(AlphaBetaConfig(rigid_min_speed_kmh=min_speed, body_length_m=0.0), car_front_and_rear, 14)
    assert len(ids[-1]) == tracks_at_end
    assert len(events) == tracks_at_end
    assert st.rigid_merges == (1 if min_speed > 0 else 0)
    if min_speed > 0:
        # the merged track's signatures span both parts: its range extent covers the 3 m between them
        (ev,) = events
        assert ev.features["frames"] == 14
        assert ev.mean_radial_speed_kmh == pytest.approx(16.5, abs=1.0)


def test_the_rear_track_lives_only_rigid_frames_frames():
    cfg = AlphaBetaConfig(rigid_frames=3)
    _, ids, _ = run(cfg, car_front_and_rear, 14)
    assert [len(s) for s in ids[5:10]] == [1, 2, 2, 1, 1]  # born at 6, merged on its 3rd frame (8)


def walkers_side_by_side(n):
    """Two walkers 1.5 m apart at the same 5 km/h (same Doppler), receding together; the second one is
    seen from frame 4 on (entering the beam)."""
    r = 6.0 + 5.0 / 3.6 * T * n
    return [(r, 5.0, 150)] + ([(r + 1.5, 5.0, 150)] if n >= 4 else [])


def test_two_walkers_side_by_side_are_not_merged():
    st, ids, events = run(AlphaBetaConfig(), walkers_side_by_side, 20)
    assert len(ids[-1]) == 2 and len(events) == 2 and st.rigid_merges == 0
    # the speed floor is what keeps them apart: without it they are one rigid body
    st, ids, events = run(AlphaBetaConfig(rigid_min_speed_kmh=1.0), walkers_side_by_side, 20)
    assert st.rigid_merges == 1 and len(events) == 1


def car_passing_walker(n):
    """A car at 5 + 2 * 10.7 km/h (the walker's wrapped Doppler: aliased twice) from 2 m passes a walker
    appearing at 12 m on frame 3 at 5 km/h."""
    v_car = 5.0 + 4 * VMAX
    out = [(2.0 + v_car / 3.6 * T * n, v_car, 400)]
    if n >= 3:
        out.append((12.0 + 5.0 / 3.6 * T * n, 5.0, 150))
    return out


def test_a_car_passing_a_walker_with_its_wrapped_doppler_is_not_merged():
    st, ids, events = run(AlphaBetaConfig(corange_fragment_m=0.0), car_passing_walker, 16)
    assert st.rigid_merges == 0 and len(events) == 2
    # their separation changes by 1.2 m a frame: a loose separation test would merge them
    st, _, events = run(AlphaBetaConfig(corange_fragment_m=0.0, rigid_separation_m=30.0), car_passing_walker, 16)
    assert st.rigid_merges == 1 and len(events) == 1


def approaching_car_growing(n):
    """One approaching car whose cluster grows tenfold in one frame (150 -> 1500 cells) at 14 m, alone."""
    return [(20.0 - 25.0 / 3.6 * T * n, -25.0, 150 if n < 5 else 1500)]


@pytest.mark.parametrize("rule, held", [("always", False), ("young", True)])
def test_a_target_growing_alone_is_not_held_as_merged(rule, held):
    cfg = AlphaBetaConfig(merge_other_required=rule, rigid_min_speed_kmh=0.0)
    st, _, events = run(cfg, approaching_car_growing, 10)
    assert (st.merged_frames > 0) == held
    (ev,) = events
    assert (ev.features["frames"] < 10) == held


def car_passing_beside_the_radar(n):
    """A departing car seen first beside the radar (frames 0-4: a cluster at about 3 m with a small
    radial speed), then, from frame 4, its receding body at 16.5 km/h from 5 m on."""
    out = []
    if n <= 4:
        out.append((3.0 + 0.05 * n, 1.0, 300))
    if n >= 4:
        out.append((5.0 + 16.5 / 3.6 * T * (n - 4), 16.5, 400))
    return out


@pytest.mark.parametrize("max_frames, any_doppler, events_expected", [(8, False, 1), (0, False, 2), (0, True, 1)])
def test_the_part_seen_beside_the_radar_joins_the_departing_vehicle(max_frames, any_doppler, events_expected):
    # without the passage rule the body rule joins the part, whose extent touches the body's, only with
    # body_overlap_any_doppler: beside the radar its radial speed is far from the body's
    cfg = AlphaBetaConfig(passage_max_frames=max_frames, body_overlap_any_doppler=any_doppler)
    st, _, events = run(cfg, car_passing_beside_the_radar, 24)
    assert len(events) == events_expected
    assert st.passages == (1 if max_frames else 0)
    assert st.body_parts == (1 if any_doppler and not max_frames else 0)
    if max_frames:
        (ev,) = events
        assert ev.mean_radial_speed_kmh == pytest.approx(16.5, abs=1.0)  # the part's frames add no speed
        assert ev.features["frames"] == 25 - 1  # frame 4 holds both clusters: one united signature


def motorcycle_and_car_crossing_near_the_radar(n):
    """An approaching motorcycle at -35 km/h seen for 5 frames at 9 -> 5 m while a car departs from 4 m."""
    out = [(4.0 + 16.5 / 3.6 * T * n, 16.5, 400)]
    if n < 5:
        out.append((9.0 - 35.0 / 3.6 * T * n, -35.0, 200))
    return out


def test_a_short_track_of_another_vehicle_is_not_a_passage_part():
    st, _, events = run(AlphaBetaConfig(), motorcycle_and_car_crossing_near_the_radar, 24)
    assert st.passages == 0 and len(events) == 2
    # its speed is what tells it apart
    st, _, events = run(AlphaBetaConfig(passage_speed_kmh=100.0), motorcycle_and_car_crossing_near_the_radar, 24)
    assert st.passages == 1 and len(events) == 1


def motorcycle_handed_over(n):
    """A motorcycle receding at 25 km/h from 10 m: its first track's cluster until frame 5; in frame 5 a
    second part 2 m behind at another Doppler starts a track that carries on alone from frame 6."""
    v = 25.0
    r = 10.0 + v / 3.6 * T * n
    out = []
    if n <= 5:
        out.append((r, v, 100))
    if n >= 5:
        out.append((r - 2.0, v - 5.0, 100))
    return out


@pytest.mark.parametrize("same_frame, n_events", [(True, 1), (False, 2)])
def test_a_track_started_in_the_last_frame_of_another_can_continue_it(same_frame, n_events):
    st, _, events = run(AlphaBetaConfig(continuation_same_frame=same_frame), motorcycle_handed_over, 20)
    assert len(events) == n_events
    assert st.continued == (1 if same_frame else 0)
    if same_frame:
        (ev,) = events
        assert ev.start_ns == 0  # the event spans the first track's frames too


def test_trimmed_mean_speed_follows_the_mean_where_the_median_follows_the_far_frames():
    from edge.classify.features import RadialSpeedEstimator

    est = RadialSpeedEstimator(VMAX)
    # a car receding past the radar: radial speed rising 13 -> 17 km/h, then 17.5 km/h for 10 frames
    v = np.concatenate([np.linspace(13.0, 17.0, 6), np.full(10, 17.5)])
    r = 4.0 + np.cumsum(v / 3.6 * T)
    for k, (vk, rk) in enumerate(zip(v, r)):
        est.add(k * T, rk, wrap(vk))
    assert est.speeds_kmh() == pytest.approx(v, abs=0.01)  # every frame unaliased right
    assert est.trimmed_mean_radial_speed_kmh() == pytest.approx(float(np.mean(v)), abs=0.05)
    assert est.mean_radial_speed_kmh() == pytest.approx(17.5, abs=0.01)  # the median: the far frames
    assert abs(float(np.mean(v)) - 17.5) > 0.5


def truck_front_and_body(n, v=20.0):
    """A truck receding at ``v`` km/h: its front cluster from frame 0 on, a body cluster 3.5 m behind it from frame 2
    to frame 9 at a Doppler 2 km/h lower (beyond rigid_doppler_kmh: the body's aspect differs), then lost (the body
    leaves the beam first)."""
    r = 4.0 + v / 3.6 * T * n
    out = [(r + 3.5, v, 400)]
    if 2 <= n <= 9:
        out.append((r, v - 2.0, 300))
    return out


def car_passing_a_walker(n):
    """A car receding at 20 km/h passes a pedestrian walking away at 4 km/h 5 m from it; the walker is lost at 10."""
    out = [(14.0 + 20.0 / 3.6 * T * n, 20.0, 400)]
    if n <= 10:
        out.append((9.0 + 4.0 / 3.6 * T * n, 4.0, 150))
    return out


@pytest.mark.parametrize("body_m, events_expected", [(12.0, 1), (0.0, 2)])
def test_a_trucks_body_track_joins_its_front_track(body_m, events_expected):
    st, _, events = run(AlphaBetaConfig(body_length_m=body_m), truck_front_and_body, 16)
    assert len(events) == events_expected
    assert st.body_parts == (1 if body_m else 0)
    if body_m:
        (ev,) = events
        assert ev.mean_radial_speed_kmh == pytest.approx(20.0, abs=1.0) and not ev.speed_uncertain
        assert ev.start_ns == 0


def test_a_walker_beside_a_car_keeps_its_own_event():
    st, _, events = run(AlphaBetaConfig(body_length_m=12.0), car_passing_a_walker, 16)
    assert st.body_parts == 0 and len(events) == 2
    assert sorted(round(e.mean_radial_speed_kmh) for e in events) == [4, 20]


def car_passing_an_approaching_jogger(n):
    """A car receding at 22.1 km/h from 12 m passes a jogger approaching at 10 km/h from 15 m (beyond passage_range_m)
    at the same wrapped Doppler (0.7 km/h); the jogger is lost after eight frames."""
    out = [(12.0 + 22.1 / 3.6 * T * n, 22.1, 400)]
    if n <= 7:
        out.append((15.0 - 10.0 / 3.6 * T * n, -10.0, 150))
    return out


def test_a_jogger_approaching_beside_a_receding_car_keeps_its_own_event():
    # the body rule's "moving apart" guard: range rates of opposite sign, both beyond passage_speed_kmh
    st, _, events = run(AlphaBetaConfig(body_length_m=12.0), car_passing_an_approaching_jogger, 16)
    assert st.body_parts == 0 and len(events) == 2
    assert sorted(round(e.mean_radial_speed_kmh) for e in events) == [-10, 22]


class _ByExtent:
    """A stand-in for the k-NN: a vehicle (truck) when the range extent feature is at least 1.5 m, else a pedestrian."""

    classes = ("car", "pedestrian", "truck", "motorcycle")

    def predict(self, x):
        return np.where(np.asarray(x)[:, 5] >= 1.5, 2, 1)

    def predict_proba(self, x):
        p = np.zeros((len(x), 4))
        p[np.arange(len(x)), self.predict(x)] = 1.0
        return p


def slow_truck_front_and_rear(n, v=10.5):
    """A truck receding at ``v`` km/h, about one alias step (wrapped Doppler -0.2 km/h): its front (a long cluster)
    from frame 0 on, a rear part 4.5 m behind from frame 2 to frame 9 at a Doppler 2 km/h higher."""
    r = 4.0 + v / 3.6 * T * n
    out = [(r, v, 900)]
    if 2 <= n <= 9:
        out.append((r + 4.5, v + 2.0, 150))
    return out


def run_classified(cfg, scene, frames):
    st = SurveillanceTracker(FE, 2.0, tracking=cfg, knn=_ByExtent())
    events = [ev for step in feed(st, scene, frames) for ev in step.classifications]
    events.extend(st.close())
    return st, events


@pytest.mark.parametrize("by_class, events_expected", [(True, 1), (False, 2)])
def test_a_truck_slower_than_the_speed_floor_is_a_vehicle_by_its_class(by_class, events_expected):
    st, events = run_classified(AlphaBetaConfig(vehicle_by_class=by_class), slow_truck_front_and_rear, 16)
    assert len(events) == events_expected
    assert st.body_parts == (1 if by_class else 0)


def test_walkers_the_classifier_reads_as_pedestrians_stay_apart():
    st, events = run_classified(AlphaBetaConfig(vehicle_by_class=True), walkers_side_by_side, 20)
    assert len(events) == 2 and st.body_parts == st.passages == st.rigid_merges == 0


def truck_body_and_wheels(n, v=20.0):
    """A truck receding at ``v`` km/h from 10 m: its body (a 2.8 m long cluster) from frame 0 on, and from frame 2 to
    frame 9 a part inside the body's range extent, 1 m nearer, at a wrapped Doppler 5.2 km/h lower (a wheel, or the
    body seen at another aspect)."""
    r = 10.0 + v / 3.6 * T * n
    out = [(r, v, 900)]
    if 2 <= n <= 9:
        out.append((r - 1.0, v - 5.2, 100))
    return out


@pytest.mark.parametrize("any_doppler, events_expected", [(True, 1), (False, 2)])
def test_a_part_inside_the_bodys_extent_joins_it_at_any_doppler(any_doppler, events_expected):
    st, _, events = run(AlphaBetaConfig(body_overlap_any_doppler=any_doppler), truck_body_and_wheels, 16)
    assert len(events) == events_expected
    assert st.body_parts == (1 if any_doppler else 0)
    if any_doppler:
        (ev,) = events
        assert ev.mean_radial_speed_kmh == pytest.approx(20.0, abs=1.0)


def body_taken_over_by_its_front(n, v=20.0):
    """A truck receding at ``v`` km/h from 10 m: its rear part is seen from frame 0 to frame 11, its front part, 1 m
    farther and overlapping it at a Doppler 5 km/h higher, from frame 8 on (the younger track takes the body over)."""
    r = 10.0 + v / 3.6 * T * n
    out = []
    if n <= 11:
        out.append((r, v, 400))
    if n >= 8:
        out.append((r + 1.0, v + 5.0, 400))
    return out


def test_a_body_track_that_ends_hands_its_frames_to_the_younger_part_that_took_over():
    st, _, events = run(AlphaBetaConfig(), body_taken_over_by_its_front, 20)
    assert st.body_parts == 1 and len(events) == 1
    assert events[0].start_ns == 0  # the event spans the older part's frames


def car_leaves_then_motorcycle_arrives(n):
    """A car approaching at 33 km/h is seen from frame 0 to frame 9 (it leaves the view beside the radar); a
    motorcycle approaching at the same speed appears at 17 m in frame 11, after the car's last cluster."""
    out = []
    if n <= 9:
        out.append((20.0 - 33.0 / 3.6 * T * n, -33.0, 400))
    if 11 <= n <= 19:
        out.append((17.0 - 33.0 / 3.6 * T * (n - 11), -33.0, 200))
    return out


def test_a_vehicle_that_appears_after_another_left_is_not_its_part():
    st, _, events = run(AlphaBetaConfig(), car_leaves_then_motorcycle_arrives, 20)
    assert st.body_parts == 0 and len(events) == 2


def car_followed_by_a_motorcycle(n, v=-20.0):
    """A car approaching at 20 km/h from 26 m, seen until frame 15 (it leaves the view beside the radar); a motorcycle
    6 m behind it at the same speed from frame 12 on (they move at one range rate, not as one body)."""
    r = 26.0 + v / 3.6 * T * n
    out = []
    if n <= 15:
        out.append((r, v, 400))
    if n >= 12:
        out.append((r + 6.0, v, 200))
    return out


def test_a_vehicle_following_another_at_its_speed_does_not_take_it_over():
    st, _, events = run(AlphaBetaConfig(), car_followed_by_a_motorcycle, 26)
    assert st.body_parts == 0 and len(events) == 2


def walker_fading(n, restart_offset_m=0.0):
    """A walker receding at 4.5 km/h from 6 m, seen in frames 0-9, below the threshold in frames 10-19 (longer
    than max_missed_frames), then seen again from frame 20 where it walked to (plus ``restart_offset_m``).
    Run with :data:`LONG_EVENT`: other echoes (site clutter) keep the passage open meanwhile."""
    r = 6.0 + 4.5 / 3.6 * T * n
    if n <= 9:
        return [(r, 4.5, 120)]
    if n >= 20:
        return [(r + restart_offset_m, 4.5, 120)]
    return []


LONG_EVENT = EventConfig(release_frames=30)


@pytest.mark.parametrize("hold, n_events", [(0, 2), (10, 1)])
def test_a_walker_that_fades_longer_than_a_track_lives_is_one_event_with_the_hold(hold, n_events):
    st, ids, events = run(AlphaBetaConfig(continuation_hold_frames=hold), walker_fading, 36, LONG_EVENT)
    assert len(events) == n_events
    assert st.continued == (1 if hold else 0)
    if hold:
        (ev,) = events
        assert ev.start_ns == 0  # the event spans the first track's frames too
        # the first track's id stays taken while it waits: the second track gets another one
        assert ids[9] == {1} and ids[25] == {2}
        assert st.tracker.ids._used == set()  # every id released at the end


@pytest.mark.parametrize("hold, n_events", [(0, 2), (10, 1)])
def test_a_walker_that_fades_past_the_end_of_the_echo_is_one_event_with_the_hold(hold, n_events):
    # the default release: 7 quiet frames end the passage's echo (frame 16) while the walker's track waits; the
    # wait outlives that end, and the track the walker starts again at frame 20 continues it
    st, _, events = run(AlphaBetaConfig(continuation_hold_frames=hold), walker_fading, 36)
    assert st.segmenter.events == 2  # the echo ended and started again
    assert len(events) == n_events and st.continued == (1 if hold else 0)
    assert events[0].start_ns == 0
    assert st.tracker.ids._used == set()


def test_the_hold_joins_no_track_that_the_walk_does_not_reach():
    # the same walker seen again 6 m beyond where 4.5 km/h takes it: another target; the held track is
    # classified when its wait ends, before the second one
    st, _, events = run(AlphaBetaConfig(continuation_hold_frames=10), lambda n: walker_fading(n, 6.0), 36, LONG_EVENT)
    assert len(events) == 2 and st.continued == 0
    assert events[0].start_ns == 0 and events[1].start_ns > events[0].end_ns


def test_a_dropped_track_that_carries_an_ended_one_is_classified():
    # the faded walker's second track took the first one's rows; were it dropped now (coasting below th_v),
    # the passage would still give its event, from the first track's start
    st = tracker(AlphaBetaConfig(continuation_hold_frames=10), LONG_EVENT)
    for step in feed(st, walker_fading, 24):
        assert not step.classifications
    assert st.continued == 1
    (tr,) = st.tracker.tracks
    assert tr.track_id == 2
    st.tracker.tracks = []
    out = st._end_tracks((), (tr,), set(), 24)
    assert len(out) == 1 and out[0].start_ns == 0 and out[0].features["frames"] == 14


def test_a_standing_echo_is_not_held():
    # a swaying bush (0.5 km/h) seen, gone for 10 frames, seen again at its range: without speed, any later
    # track at that range would look like its successor; it is classified when it ends, as without the hold
    def bush(n):
        return [(8.0, 0.5 if n % 2 else -0.5, 80)] if n <= 9 or n >= 20 else []

    st = tracker(AlphaBetaConfig(continuation_hold_frames=10, static_zone_time_s=0.0), LONG_EVENT)
    published = []
    for n, step in enumerate(feed(st, bush, 36)):
        published.extend(n for _ in step.classifications)
    published.extend(36 for _ in st.close())
    assert published == [16, 36] and st.continued == 0  # the first when it ended (9 + max_missed_frames)


def test_the_hold_joins_nothing_while_another_target_is_in_view():
    # the same fading walker while a second walker approaches from 20 m: which of two targets a track continues
    # is ambiguous (two walkers in step), so the faded walker's two tracks stay two events
    def two(n):
        return walker_fading(n) + [(20.0 - 4.0 / 3.6 * T * n, -4.0, 120)]

    st, _, events = run(AlphaBetaConfig(continuation_hold_frames=10), two, 36, LONG_EVENT)
    assert st.continued == 0 and len(events) == 3


def test_a_dropped_standing_track_that_carries_another_gives_no_event():
    # a swaying bush's track that took an earlier bush track's rows (a continuation) and is dropped: site clutter,
    # forgotten as before; the same bookkeeping on a walker gives its event (previous test)
    st = tracker(AlphaBetaConfig(static_zone_time_s=0.0), LONG_EVENT)
    for _ in feed(st, lambda n: [(8.0, 0.5 if n % 2 else -0.5, 80)], 8):
        pass
    (tr,) = st.tracker.tracks
    st._start_ns[tr.track_id] = 0  # as a continuation sets it
    st.tracker.tracks = []
    assert st._end_tracks((), (tr,), set(), 8) == []


def slow_truck_passing_beside_the_radar(n, v=10.5):
    """A truck departing at ``v`` km/h (below rigid_min_speed_kmh, about one alias step): its near end seen beside
    the radar (frames 0-4, at about 3 m with a small radial speed), and from frame 2 on its receding body, a long
    cluster from 4.5 m on."""
    out = []
    if n <= 4:
        out.append((3.0 + 0.05 * n, 1.0, 150))
    if n >= 2:
        out.append((4.5 + v / 3.6 * T * (n - 2), v, 900))
    return out


@pytest.mark.parametrize("by_class, events_expected", [(True, 1), (False, 2)])
def test_a_slow_truck_is_the_host_of_its_passage_part_by_its_class(by_class, events_expected):
    # the part beside the radar joins a host slower than the speed floor when the classifier reads the host as a
    # vehicle (vehicle_by_class, as for the body rule)
    cfg = AlphaBetaConfig(vehicle_by_class=by_class, body_length_m=0.0)
    st, events = run_classified(cfg, slow_truck_passing_beside_the_radar, 24)
    assert len(events) == events_expected
    assert st.passages == (1 if by_class else 0)


def car_passing_a_crossing_walker(n):
    """A walker crossing the beam 5.8 m from the radar (radial speed about 0) in frames 0-7, while a car approaches
    at -15 km/h from 16 m: the car's cluster comes within 6 m of the walker's only in the walker's last frames."""
    out = [(16.0 - 15.0 / 3.6 * T * n, -15.0, 400)]
    if n <= 7:
        out.append((5.8 + 0.02 * n, 0.3, 120))
    return out


def test_a_walker_crossing_as_a_car_approaches_is_not_its_passage_part():
    # a part of a vehicle's body touches its extent in most frames; the walker comes near the car in two
    st, _, events = run(AlphaBetaConfig(body_length_m=0.0), car_passing_a_crossing_walker, 20)
    assert st.passages == 0 and len(events) == 2
    # with the extent test wide open, the nearness of one frame pair would still join it (the rule before)
    st, _, events = run(AlphaBetaConfig(body_length_m=0.0, body_gap_m=30.0), car_passing_a_crossing_walker, 20)
    assert st.passages == 1 and len(events) == 1


def car_leaving_the_band(n, v=20.0):
    """A car receding at ``v`` km/h, 3 m long, seen from 14 m until it leaves the map at 24 m (frame 11); from frame 9
    its far end is a second cluster 1.2 m behind its body (their extents touch), seen until frame 12, when the body's
    cluster is gone."""
    r = 14.0 + v / 3.6 * T * n
    out = []
    if n <= 10:
        out.append((r, v, 300))
    if 9 <= n <= 12:
        out.append((r + 1.2, v, 100))
    return out


@pytest.mark.parametrize("hold, events_expected", [(10, 1), (0, 2)])
def test_a_far_part_that_outlives_its_vehicles_track_joins_it_while_it_waits(hold, events_expected):
    # the body's track ends first and waits (continuation_hold_frames); the far part, seen beside it, then ends
    # and joins it, so the passage is one event from the body's first frame
    cfg = AlphaBetaConfig(continuation_hold_frames=hold, rigid_min_speed_kmh=0.0)
    st, _, events = run(cfg, car_leaving_the_band, 30, LONG_EVENT)
    assert len(events) == events_expected
    assert st.body_parts == (1 if hold else 0)
    if hold:
        (ev,) = events
        assert ev.start_ns == 0 and ev.mean_radial_speed_kmh == pytest.approx(20.0, abs=1.5)


def motorcycle_following_a_car_out(n, v=15.0):
    """A car receding at ``v`` km/h from 8 m, seen until frame 10, and a motorcycle 4 m behind it at the same speed,
    seen from frame 10 to 16: it follows the car at its rate, and their clusters never touch."""
    r = 8.0 + v / 3.6 * T * n
    out = []
    if n <= 10:
        out.append((r, v, 300))
    if 10 <= n <= 16:
        out.append((r - 4.0, v, 100))
    return out


def test_a_vehicle_following_a_waiting_track_out_keeps_its_own_event():
    # a waiting track takes a part only if their extents touch; one vehicle following another moves at its rate
    st, _, events = run(AlphaBetaConfig(continuation_hold_frames=10, rigid_min_speed_kmh=0.0),
                        motorcycle_following_a_car_out, 30, LONG_EVENT)
    assert st.body_parts == 0 and len(events) == 2
