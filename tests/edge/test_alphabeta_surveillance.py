"""SurveillanceTracker end to end on synthetic cluster maps: tracks, streaming classification."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.classify.features import MapPoints
from edge.classify.knn import KnnConfig, WeightedKNN
from edge.classify.reference import DEFAULT_CLASSES
from edge.track.alphabeta import AlphaBetaConfig
from edge.track.events import EventConfig
from edge.track.surveillance import SurveillanceTracker
from hal.waveform import d2g_frontend

FE = d2g_frontend()
DR = 24.0 / 256  # m per zero-padded range bin (N_R = 512, positive half)
VMAX = 5.348
DV = 2 * VMAX / 256  # km/h per Doppler bin (N_D = 256)
T = 0.2

#: synthetic "classes": Doppler spread (km/h), peak amplitude, range extent (m)
KIND = {"pedestrian": (3.0, 4.0, 0.4), "car": (0.6, 30.0, 1.5)}


def blob(rng, r, v, kind, label):
    """Cells of one target: a Gaussian bump around (r, v) on the (range, wrapped Doppler) grid."""
    sv, amp, sr = KIND[kind]
    a = amp * rng.exponential(1.0)  # Swerling I
    rb0, db0 = int(round(r / DR)), int(round((v + VMAX) / DV))
    nr, nd = int(sr / DR) + 2, int(sv / DV) + 2
    rb, db = np.meshgrid(np.arange(rb0 - nr, rb0 + nr + 1), np.arange(db0 - nd, db0 + nd + 1), indexing="ij")
    rb, db = rb.ravel(), db.ravel()
    val = a * np.exp(-0.5 * (((rb - rb0) * DR / (sr / 2)) ** 2 + ((db - db0) * DV / (sv / 2)) ** 2))
    keep = (val >= 2.0) & (rb >= 0)
    rb, db, val = rb[keep], np.mod(db[keep], 256), val[keep]
    return rb * DR, db * DV - VMAX, val, rb, db, np.full(rb.size, label)


def wrap(v_kmh):
    return (v_kmh + VMAX) % (2 * VMAX) - VMAX


def frame_points(rng, targets, t):
    """``targets``: (kind, range at t = 0 in m, radial speed km/h, unused); Doppler aliased as on the board."""
    cols = [blob(rng, r0 + vr * t / 3.6, wrap(vr), kind, k) for k, (kind, r0, vr, _) in enumerate(targets)
            if 0 < r0 + vr * t / 3.6 < 24]
    if not cols:
        return MapPoints.empty()
    cat = [np.concatenate(c) for c in zip(*cols)]
    return MapPoints(cat[0].astype(np.float32), cat[1].astype(np.float32), cat[2].astype(np.float32),
                     cat[3].astype(np.int32), cat[4].astype(np.int32), cat[5].astype(np.int32))


def reference_knn(rng):
    """A tiny reference set from single synthetic events, thresholded (labels all 0) as in the paper."""
    from edge.classify.features import SignatureExtractor, FeatureConfig, TrackFeatureAccumulator

    ex = SignatureExtractor(FeatureConfig(), FE)
    xs, ys = [], []
    for c, kind in enumerate(("pedestrian", "car")):
        for _ in range(15):
            vr = rng.uniform(3, 6) if kind == "pedestrian" else rng.uniform(15, 30)
            vr *= rng.choice([-1, 1])
            r0 = rng.uniform(8, 16)
            acc = TrackFeatureAccumulator()
            for n in range(12):
                p = frame_points(rng, [(kind, r0, vr, rng.uniform(-VMAX, VMAX))], n * T)
                if len(p):
                    sig = ex(p)
                    acc.add(n * T, sig.circular_variance[0], sig.rcs[0], sig.range_m[0], float(sig.extent_m[0]))
            xs.append(acc.features())
            ys.append(DEFAULT_CLASSES.index(kind))
    return WeightedKNN(DEFAULT_CLASSES, k=5).fit(np.array(xs), np.array(ys))


def test_two_crossing_targets_are_tracked_and_classified_when_they_end():
    rng = np.random.default_rng(3)
    knn = reference_knn(rng)
    st = SurveillanceTracker(FE, threshold=2.0, knn=knn, tracking=AlphaBetaConfig(), events=EventConfig())
    # a pedestrian walking away from 4 m at 5 km/h, a car approaching from 23 m at 20 km/h
    targets = [("pedestrian", 4.0, 5.0, 1.0), ("car", 23.0, -20.0, 2.5)]
    events, seen_ids = [], set()
    for n in range(40):
        t = n * T
        step = st.update(int(round(t * 1e9)), frame_points(rng, targets, t))
        seen_ids |= {tr.track_id for tr in step.tracks}
        for tr in step.tracks:
            assert tr.hits >= 3 and math.isnan(tr.az_rad) and tr.y_m == tr.range_m
        events += step.classifications
    events += st.close()
    assert seen_ids == {1, 2}
    by_id = {e.track_id: e for e in events}
    assert sorted(by_id) == [1, 2] and len(events) == 2
    ped, car = by_id[1], by_id[2]
    assert ped.cls == "pedestrian" and ped.direction == "receding"
    assert car.cls == "car" and car.direction == "approaching"
    assert ped.mean_radial_speed_kmh == pytest.approx(5.0, abs=1.0)
    assert car.mean_radial_speed_kmh == pytest.approx(-20.0, abs=1.0)
    assert sum(ped.probabilities.values()) == pytest.approx(1.0)
    assert set(ped.probabilities) == set(DEFAULT_CLASSES)
    # the car leaves the map (range < 0) after ~4.1 s: its track ends after N_u misses, before the end
    assert car.end_ns < 5e9 and car.start_ns == 0
    assert ped.features["frames"] >= 10


def test_event_end_closes_tracks_and_scintillation_is_dropped():
    rng = np.random.default_rng(4)
    st = SurveillanceTracker(FE, threshold=2.0, knn=reference_knn(rng), events=EventConfig(release_frames=3))
    out, ended_at = [], []
    # one isolated frame with a blob (scintillation), then a 6-frame passage, then silence
    frames = [[("car", 10.0, 0.0, 0.0)]] + [[]] * 4 + [[("car", 12.0, -10.0, 1.0)]] * 6 + [[]] * 5
    for n, tg in enumerate(frames):
        step = st.update(int(n * T * 1e9), frame_points(rng, tg, (n - 5) * T if tg and n >= 5 else 0.0))
        out += step.classifications
        if step.event.ended:
            ended_at.append(n)
            assert not st.tracker.tracks
    assert ended_at == [13]  # third quiet frame after the passage
    assert len(out) == 1 and out[0].cls == "car" and out[0].direction == "approaching"
    assert st.segmenter.discarded == 1 and st.segmenter.events == 1
    assert st.dropped == 1  # the scintillation track


def test_from_config_loads_the_packaged_reference_set():
    from edge.config import load_config

    # classify.knn applies to the numpy backend; the default ONNX model carries its own k
    cfg = load_config(env={}, overrides={"classify.onnx.backend": "numpy", "classify.knn.k": "5",
                                         "track.alphabeta.alpha": "0.3"})
    st = SurveillanceTracker.from_config(FE, cfg, threshold=2.0)
    assert isinstance(st.classifier.classifier, WeightedKNN)  # fed the configured features of the whole vector
    assert st.classifier.feature_names == KnnConfig().features
    assert st.classifier.k == 5 and st.classifier.classes == DEFAULT_CLASSES
    default = SurveillanceTracker.from_config(FE, load_config(env={}), threshold=2.0)
    assert type(default.classifier.classifier).__name__ == "OnnxKnnClassifier"
    assert default.classifier.k == KnnConfig().k and default.classifier.feature_names == KnnConfig().features
    assert st.tracker.filter.alpha == 0.3
    assert st.cylinder.vmax_kmh == pytest.approx(5.348, abs=2e-3)
    step = st.update(0, MapPoints.empty())
    assert step.tracks == () and step.classifications == () and not step.event.active


def test_kinematics_run_on_the_sensor_clock_given_by_seq():
    """A source read back to back (replay at full speed) has compressed host times: with ``seq`` (the
    board's frame counter) the speeds are those of the real-time run."""
    rng_a, rng_b = np.random.default_rng(7), np.random.default_rng(7)
    knn = reference_knn(np.random.default_rng(1))
    a = SurveillanceTracker(FE, threshold=2.0, knn=knn)
    b = SurveillanceTracker(FE, threshold=2.0, knn=knn)
    targets = [("car", 20.0, -25.0, 0.0)]
    out_a, out_b = [], []
    for n in range(25):
        sa = a.update(int(n * T * 1e9), frame_points(rng_a, targets, n * T))  # t_ns on the sensor clock
        sb = b.update(int(n * 1e6), frame_points(rng_b, targets, n * T), seq=n)  # host: 1 ms apart
        np.testing.assert_array_equal([t.radial_speed_mps for t in sa.tracks], [t.radial_speed_mps for t in sb.tracks])
        out_a += sa.classifications
        out_b += sb.classifications
    out_a += a.close()
    out_b += b.close()
    assert len(out_a) == 1 and out_a[0].mean_radial_speed_kmh == pytest.approx(-25.0, abs=1.0)
    assert out_a[0].mean_radial_speed_kmh == out_b[0].mean_radial_speed_kmh
    assert out_b[0].end_ns < 1e9  # events keep the caller's (host) stamps


def _estimator(t_s, r_m, v_kmh):
    from edge.classify.features import RadialSpeedEstimator

    e = RadialSpeedEstimator(VMAX)
    for t, r in zip(t_s, r_m):
        e.add(t, r, wrap(v_kmh))
    return e


def test_continuation_picks_the_track_started_where_the_ended_one_would_be():
    """A receding car (20 km/h) lost at 11.6 m: of the tracks started after its last cluster, the one
    whose first cluster is where 20 km/h takes it continues it; one that would need 6.5 km/h does not,
    nor one that moves the other way, nor anything when the continuation is off or the car was last
    seen closer than the minimum range."""
    from edge.classify.features import SignatureLog
    from edge.track.alphabeta import AlphaBetaTrack

    def tracker(**kw):
        st = SurveillanceTracker(FE, threshold=2.0, classify=False, tracking=AlphaBetaConfig(**kw))
        t = np.arange(6) * T
        st._speed[1] = _estimator(t, 6.0 + 20.0 / 3.6 * t, 20.0)
        st._speed[2] = _estimator([1.8, 2.0], [16.0, 17.1], 20.0)  # 4.4 m in 0.8 s: 20 km/h
        st._speed[3] = _estimator([1.8, 2.0], [13.0, 13.1], 20.0)  # 1.4 m in 0.8 s: 6.5 km/h
        for tid in (1, 2, 3):
            st._log[tid] = SignatureLog()
        return st

    tr = AlphaBetaTrack(1, np.zeros(6), np.zeros(3), created_ns=0, last_seen_ns=int(1e9))
    assert tracker()._successor(tr, {2, 3}) == 2
    assert tracker()._successor(tr, {3}) is None
    assert tracker(continuation_speed_kmh=0.0)._successor(tr, {2, 3}) is None
    assert tracker(continuation_min_range_m=12.0)._successor(tr, {2, 3}) is None
    st = tracker()
    st._speed[3] = _estimator([1.8, 2.0], [7.1, 6.0], -20.0)  # 20 km/h, but towards the radar
    assert st._successor(tr, {3}) is None


def test_radial_speed_estimator_prepend_keeps_time_order():
    a = _estimator([0.0, 0.2, 0.4], [5.0, 6.0, 7.0], 18.0)
    b = _estimator([0.4, 1.0, 1.2], [7.0, 10.0, 11.0], 18.0)
    b.prepend(a)
    assert len(b) == 5 and b.first()[:2] == (0.0, 5.0) and b.last()[:2] == (1.2, 11.0)
    assert b.mean_radial_speed_kmh() == pytest.approx(18.0, abs=0.5)


def _crossing_points(rng, targets, t, merged):
    """Like frame_points, but all targets' cells form one cluster (label 0) when ``merged``."""
    cols = [blob(rng, r0 + vr * t / 3.6, wrap(vr), kind, 0 if merged else k)
            for k, (kind, r0, vr, _) in enumerate(targets)]
    cat = [np.concatenate(c) for c in zip(*cols)]
    return MapPoints(cat[0].astype(np.float32), cat[1].astype(np.float32), cat[2].astype(np.float32),
                     cat[3].astype(np.int32), cat[4].astype(np.int32), cat[5].astype(np.int32))


def _crossing_events(seed, shared_span_m):
    rng = np.random.default_rng(seed)
    targets = [("pedestrian", 4.0, 4.0, 0.0), ("pedestrian", 12.0, -4.0, 0.0)]
    st = SurveillanceTracker(FE, threshold=2.0, classify=False, tracking=AlphaBetaConfig(shared_span_m=shared_span_m),
                             events=EventConfig())
    events = []
    for n in range(40):
        t = n * T
        events += st.update(int(round(t * 1e9)), _crossing_points(rng, targets, t, 12 <= n <= 24)).classifications
    return events + list(st.close())


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_walkers_crossing_in_one_cluster_keep_their_tracks(seed):
    """Two walkers (4 m receding at 4 km/h, 12 m approaching at 4 km/h) form one cluster for the 13
    frames around their crossing (DBSCAN cannot part them): both tracks coast through it on their
    predictions (shared_span_m) and each ends as one event with its own direction and speed. Without
    the shared-cluster rule (0), seed 7's approaching walker loses its track and restarts."""
    events = _crossing_events(seed, 0.5)
    assert len(events) == 2, [(e.track_id, e.mean_radial_speed_kmh) for e in events]
    by_dir = {e.direction: e for e in events}
    assert by_dir["receding"].mean_radial_speed_kmh == pytest.approx(4.0, abs=1.0)
    assert by_dir["approaching"].mean_radial_speed_kmh == pytest.approx(-4.0, abs=1.0)
    assert by_dir["receding"].track_id == 1 and by_dir["approaching"].track_id == 2
    if seed == 7:
        assert len(_crossing_events(seed, 0.0)) == 3
