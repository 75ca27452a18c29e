"""Beyond-the-paper options of the surveillance chain: sidelobe guard, Doppler-aided range rate,
merge guard / occlusion, whole-passage reference signatures."""

from __future__ import annotations

import numpy as np
import pytest

from edge.classify.features import MapPoints
from edge.dsp.range_doppler import detection_mask
from edge.track.alphabeta import AlphaBetaConfig, AlphaBetaTracker
from edge.track.cylinder import Cylinder
from edge.track.surveillance import SurveillanceTracker
from hal.waveform import d2g_frontend
from tests.edge.survscene import VMAX, blob, points

FE = d2g_frontend()
CYL = Cylinder(VMAX)
T = 0.2


def meas(range_m, v_kmh):
    return CYL.to_cylinder(np.asarray(range_m, dtype=np.float64), np.asarray(v_kmh, dtype=np.float64), dtype=np.float64)


# --- sidelobe guard --------------------------------------------------------------------------------

def test_detection_mask_without_guard_is_the_threshold():
    rng = np.random.default_rng(0)
    a = rng.exponential(1.0, (64, 32)).astype(np.float32)
    np.testing.assert_array_equal(detection_mask(a, 2.0), a >= 2.0)
    np.testing.assert_array_equal(detection_mask(a, 2.0, 0.0), a >= 2.0)


def test_detection_mask_guard_drops_sidelobes_of_a_strong_echo_only():
    a = np.full((40, 32), 0.1, dtype=np.float32)
    a[10, :] = 3.0  # Doppler sidelobes of a strong echo: 30 dB below it, above th_RD
    a[10, 5] = 100.0  # the echo
    a[30, 20] = 4.0  # a weak target on another range row and Doppler column
    m = detection_mask(a, 2.0, 25.0)
    assert m[10, 5] and m[30, 20]
    assert m[10].sum() == 1  # the row's sidelobes are gone
    assert (a >= 2.0).sum() == 33 and m.sum() == 2


# --- Doppler-aided range rate and merge guard (SurveillanceTracker on hand-made clusters) -----------


def test_doppler_aided_range_rate_follows_a_fast_car():
    """A 36 km/h car (2 m per frame, Doppler aliased 3 times): after a few frames the track's range rate
    is the unaliased radial speed, not the slowly converging alpha-beta rate."""
    v = -36.0
    out = {}
    for frames in (0, 4):
        st = SurveillanceTracker(FE, 2.0, tracking=AlphaBetaConfig(doppler_range_rate_frames=frames), classify=False)
        for n in range(8):
            st.update(int(n * T * 1e9), points(blob(22.0 + v / 3.6 * n * T, v, 200, 0)), seq=n)
        (tr,) = st.tracker.tracks
        out[frames] = tr.state[5] / T * 3.6
    assert out[4] == pytest.approx(v, abs=1.0)
    assert abs(out[0] - v) > abs(out[4] - v)


def test_merged_cluster_keeps_the_tracks_prediction_and_hidden_track_survives():
    """A pedestrian (100 cells) walking away at 2 km/h is joined for 8 frames (more than N_u = 7) by a
    car's cluster (1500 cells) that swallows it: the pedestrian's track coasts through the merge on its
    own prediction instead of ending, and its features skip the merged frames. The car has no track of
    its own here, so this needs merge_other_required = "young" (an established track's enlarged cluster
    is a merge without another track near it)."""
    cfg = AlphaBetaConfig(merge_ratio=6.0, max_missed_frames=7, merge_other_required="young")
    st = SurveillanceTracker(FE, 2.0, tracking=cfg, classify=False)
    v_ped = 2.0
    ped_id = None
    for n in range(30):
        r_ped = 8.0 + v_ped / 3.6 * n * T
        if 10 <= n < 18:  # one merged cluster around the pedestrian
            pts = points(blob(r_ped + 0.3, 1.0, 1500, 0))
        else:
            pts = points(blob(r_ped, v_ped, 100, 0))
        step = st.update(int(n * T * 1e9), pts, seq=n)
        if n == 5:
            (ts,) = step.tracks
            ped_id = ts.track_id
        if n >= 5:
            assert ped_id in {t.track_id for t in st.tracker.tracks}, n
        assert not step.classifications
    assert st.merged_frames >= 1
    acc = st._acc[ped_id]
    assert acc.n < 30  # merged frames left out of the features
    (tr,) = st.tracker.tracks
    assert tr.track_id == ped_id and tr.state[4] == pytest.approx(8.0 + v_ped / 3.6 * 29 * T, abs=0.5)


def test_occluded_track_neither_hit_nor_missed():
    """The tracker-level occlusion hook: a track whose prediction lies in an assigned cluster the test
    accepts coasts without counting misses (bounded by merge_max_frames)."""
    cfg = AlphaBetaConfig(max_missed_frames=3, merge_max_frames=4, init_velocity="zero")
    trk = AlphaBetaTracker(cfg, CYL)
    for n in range(3):
        trk.step(n, meas([10.0, 11.0], [2.0, 2.5]))
    trk.occlusion_test = lambda tr, j: True
    ids = {t.track_id for t in trk.tracks}
    ages = {t.track_id: t.age for t in trk.tracks}
    for n in range(3, 7):  # one cluster only: the other track is hidden in it
        s = trk.step(n, meas([10.0], [2.0]))
        assert not s.ended and not s.dropped
        assert len(s.occluded) == 1
    assert {t.track_id for t in trk.tracks} == ids
    hidden = next(t for t in trk.tracks if t.track_id == s.occluded[0])
    assert hidden.missed == 0 and hidden.age == ages[hidden.track_id]
    s = trk.step(7, meas([10.0], [2.0]))  # merge_max_frames reached: now it misses
    assert not s.occluded and hidden.missed == 1
    trk.occlusion_test = None
    for n in range(8, 10):
        s = trk.step(n, meas([10.0], [2.0]))
    assert [t.track_id for t in s.ended] == [hidden.track_id]


def test_reference_frames_option():
    from edge.classify.refgen import build_reference_set

    with pytest.raises(ValueError):
        build_reference_set(events_per_class=1, frames="all")


def test_a_growing_vehicle_is_not_held_as_merged():
    """A truck entering the beam: its lone cluster grows 100 -> 800 (8x in one frame, a young track with
    no other track near) and then a few tens of percent a frame to 6000 (over 6x the median of its
    history, never 6x its last cluster). No frame is taken as merged: every one feeds its features and
    the track follows it (the guard used to hold it on its prediction for merge_max_frames)."""
    st = SurveillanceTracker(FE, 2.0, tracking=AlphaBetaConfig(merge_ratio=6.0), classify=False)
    sizes = [100, 110, 800, 1100, 1600, 2300, 3300, 4500, 6000, 6000, 6000, 6000]
    v = 18.0  # receding, km/h
    for n, size in enumerate(sizes):
        st.update(int(n * T * 1e9), points(blob(6.0 + v / 3.6 * n * T, v, size, 0)), seq=n)
    (tr,) = st.tracker.tracks
    assert st.merged_frames == 0
    assert st._acc[tr.track_id].n == len(sizes)
    assert tr.state[4] == pytest.approx(6.0 + v / 3.6 * (len(sizes) - 1) * T, abs=1.0)


def test_a_young_fragment_does_not_hide_in_the_vehicle_cluster():
    """A long vehicle's cluster splits for two frames into the body and a small fragment, which starts a
    second track. When the fragment is gone, that track has no known size (fewer than
    merge_history_frames clusters): it misses and ends instead of coasting as hidden in the vehicle's
    cluster (and being published) for the rest of the passage."""
    cfg = AlphaBetaConfig(merge_ratio=6.0, max_missed_frames=7)
    st = SurveillanceTracker(FE, 2.0, tracking=cfg, classify=False)
    v = 18.0
    ids_seen = []
    for n in range(20):
        r = 8.0 + v / 3.6 * n * T
        if n in (4, 5):
            pts = points(blob(r, v, 1500, 0), blob(r - 2.5, v, 120, 1))
        else:
            pts = points(blob(r, v, 1500, 0))
        step = st.update(int(n * T * 1e9), pts, seq=n)
        ids_seen.append({t.track_id for t in step.tracks})
    assert len(st.tracker.tracks) == 1  # the fragment's track ended (N_u misses), the body's lives on
    assert all(len(s) == 1 for s in ids_seen[8:])  # and is not published beside the body's track


# --- fragments of one target (fragment_gap_m) and the SignatureLog they are united with --------------

def test_signature_log_of_one_cluster_per_frame_is_the_tracks_own_features():
    from edge.classify.features import SignatureExtractor, SignatureLog, TrackFeatureAccumulator

    ex = SignatureExtractor(__import__("edge.classify.features", fromlist=["FeatureConfig"]).FeatureConfig(), FE)
    acc, lg = TrackFeatureAccumulator(vmax_kmh=VMAX), SignatureLog()
    for n in range(6):
        sig = ex(points(blob(10.0 + 0.4 * n, 3.0 + n, 90 + 20 * n, 0)))
        acc.add(n * T, sig.circular_variance[0], sig.rcs[0], sig.range_m[0], float(sig.extent_m[0]),
                float(sig.doppler_kmh[0]))
        lg.add(n, n * T, sig.n_points[0], sig.cos_sum[0], sig.sin_sum[0], sig.rcs[0], sig.n_points[0] * sig.range_m[0],
               sig.range_lo_m[0], sig.range_hi_m[0], sig.doppler_kmh[0])
    x = lg.accumulator(vmax_kmh=VMAX).features()
    assert np.all(np.isfinite(x))
    np.testing.assert_allclose(x, acc.features(), rtol=1e-9)


def test_signature_log_unites_two_clusters_of_a_frame_as_one_signature():
    """Rows of two tracks for the same frames give the features of the union of their cells, as if one
    cluster had held them (eq. 18's resultant and eq. 17's sum are additive over cells)."""
    from edge.classify.features import FeatureConfig, SignatureExtractor, SignatureLog, TrackFeatureAccumulator

    ex = SignatureExtractor(FeatureConfig(), FE)
    a, b, whole = SignatureLog(), SignatureLog(), TrackFeatureAccumulator()
    for n in range(5):
        p1, p2 = blob(8.0 + 0.5 * n, 2.0, 150, 0), blob(11.0 + 0.5 * n, -4.0, 100, 1)
        sig = ex(points(p1, p2))
        for lg, k in ((a, 0), (b, 1)):
            lg.add(n, n * T, sig.n_points[k], sig.cos_sum[k], sig.sin_sum[k], sig.rcs[k], sig.n_points[k] * sig.range_m[k])
        one = points(p1, p2)
        one = MapPoints(one.range_m, one.doppler_kmh, one.amplitude, one.range_bin, one.doppler_bin,
                        np.zeros(len(one), dtype=np.int32))
        s1 = ex(one, n_clusters=1)
        whole.add(n * T, s1.circular_variance[0], s1.rcs[0], s1.range_m[0])
    a.extend(b)
    assert a.frames() == 5 and len(a) == 10
    np.testing.assert_allclose(a.accumulator().features(), whole.features(), rtol=1e-6)


def _split_vehicle_run(gap_m: float, fragment_offset_m: float, frames=range(3, 9)):
    """A receding vehicle (1500 cells) whose cluster splits off a 150-cell fragment ``fragment_offset_m``
    behind it in ``frames`` (long enough for the fragment's own track to be confirmed)."""
    # the fragment rule alone (the body rule, body_length_m, would join a part moving with the vehicle when it ends)
    st = SurveillanceTracker(FE, 2.0, tracking=AlphaBetaConfig(fragment_gap_m=gap_m, body_length_m=0.0), classify=False)
    v = 18.0
    events = []
    for n in range(20):
        r = 8.0 + v / 3.6 * n * T
        blobs = [blob(r, v, 1500, 0)]
        if n in frames:
            blobs.append(blob(r - fragment_offset_m, v - 3.0, 150, 1))
        events += st.update(int(n * T * 1e9), points(*blobs), seq=n).classifications
    events += st.close()
    return st, events


def test_a_fragment_track_joins_the_vehicle_signature():
    """With fragment linking the fragment's track publishes no event of its own and its cells join the
    vehicle's signature in the frames they shared; without it (the paper) the target gives two events."""
    st, events = _split_vehicle_run(2.0, 1.5)
    assert len(events) == 1 and st.fragments == 1
    (ev,) = events
    assert ev.features["frames"] == 20  # the frames of the union (the fragment's are among the vehicle's)
    _, alone = _split_vehicle_run(0.0, 1.5)
    assert len(alone) == 2
    main = max(alone, key=lambda e: e.features["frames"])
    # the union's cells spread further in Doppler than the vehicle's own cluster
    assert ev.features["circ_var_mean"] > main.features["circ_var_mean"]


def test_a_separate_target_is_not_a_fragment():
    """A second cluster 6 m away (beyond fragment_gap_m from the vehicle's cells) keeps its own event;
    so does one linked in fewer than fragment_link_fraction of its frames."""
    st, events = _split_vehicle_run(2.0, 6.0)
    assert len(events) == 2 and st.fragments == 0
    # adjacent in 2 of its 12 frames only (a car passing a pedestrian): not a fragment
    cfg = AlphaBetaConfig(fragment_gap_m=2.0, fragment_link_fraction=0.5)
    st = SurveillanceTracker(FE, 2.0, tracking=cfg, classify=False)
    events = []
    for n in range(12):
        ped = blob(12.0 + 1.5 / 3.6 * n * T, 1.5, 120, 1)
        car_r = 2.0 + 30.0 / 3.6 * n * T  # passes the pedestrian around frames 6-7
        blobs = [ped] + ([blob(car_r, 30.0, 900, 0)] if n < 10 else [])
        events += st.update(int(n * T * 1e9), points(*blobs), seq=n).classifications
    events += st.close()
    assert len(events) == 2 and st.fragments == 0


# --- visibility count (th_v) ------------------------------------------------------------------------

@pytest.mark.parametrize("count, tracked", [("paper", False), ("with_creation", True)])
def test_a_target_seen_every_other_frame_is_tracked_when_the_creation_frame_counts(count, tracked):
    """A weak target (a pedestrian at 20 m) clustered in every other frame. The paper's vis / age deletes
    a new track at its first miss (0 / 1 < th_v), so it is never confirmed; counting the creation frame
    ((0 + 1) / (1 + 1) = 0.5) keeps it and it is tracked."""
    cfg = AlphaBetaConfig(visibility_count=count, init_velocity="zero")
    trk = AlphaBetaTracker(cfg, CYL)
    confirmed = False
    for n in range(12):
        r = 20.0 - 1.3 * n * T
        trk.step(n, meas([r], [-4.7]) if n % 2 == 0 else np.zeros((0, 3)))
        confirmed |= bool(trk.confirmed())
    assert confirmed is tracked


def test_a_young_fragment_whose_centroid_hardly_moves_still_joins():
    """Beside the radar more of a truck comes into view each frame, so a fragment's centroid hardly
    moves (here 1 km/h against the truck's 18): its speed over three frames means nothing and does not
    keep it from being linked; it joins the truck instead of being classified as a pedestrian."""
    st = SurveillanceTracker(FE, 2.0, tracking=AlphaBetaConfig(fragment_gap_m=2.0), classify=False)
    v = 18.0
    events = []
    for n in range(20):
        r = 8.0 + v / 3.6 * n * T
        blobs = [blob(r, v, 1500, 0)]
        if n in (5, 6, 7):
            blobs.append(blob(8.0 + v / 3.6 * 5 * T - 1.5 + 0.05 * (n - 5), 6.0, 150, 1))
        events += st.update(int(n * T * 1e9), points(*blobs), seq=n).classifications
    events += st.close()
    assert len(events) == 1 and st.fragments == 1


@pytest.mark.parametrize("min_frames, held", [(0, True), (5, False)])
def test_two_young_fragments_do_not_count_as_another_target(min_frames, held):
    """A truck entering the beam shows as two small clusters (two young tracks), then as one cluster 10x
    larger. With merge_other_min_frames = 5 the young track next to it is no "other target": the track
    that takes the big cluster is not held on its prediction and the frame feeds its features; with 0
    (any track) it was held as merged."""
    cfg = AlphaBetaConfig(merge_ratio=6.0, merge_other_min_frames=min_frames)
    st = SurveillanceTracker(FE, 2.0, tracking=cfg, classify=False)
    v = 15.0
    for n in range(4):
        r = 8.0 + v / 3.6 * n * T
        if n < 3:
            pts = points(blob(r, v, 100, 0), blob(r + 1.5, v, 100, 1))
        else:
            pts = points(blob(r + 0.75, v, 1200, 0))
        st.update(int(n * T * 1e9), pts, seq=n)
    assert (st.merged_frames > 0) == held
    frames = sorted(acc.n for acc in st._acc.values())
    assert frames[-1] == (3 if held else 4)
