"""The surveillance back end's cheaper code paths compute what the numpy forms compute, bit for bit (issue 30).

The pipeline's outputs are pinned end to end by tests/native/test_surv_identity.py and the surveillance tests;
these tests pin the pieces on random inputs (hypothesis, seeded): numpy's pairwise float64 sum in plain Python,
and the radial speed estimator's current speed and mean |speed| against their numpy forms.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.classify.features import RadialSpeedEstimator, _np_sum


def _bits(x: float) -> str:
    return float(x).hex()


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.sampled_from([0, 1, 2, 7, 8, 9, 15, 16, 17, 127, 128, 129, 130, 255, 300, 1000]))
def test_np_sum_is_numpys_pairwise_sum(seed, n):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=n) * 10.0 ** rng.integers(-8, 17, size=n)
    x[rng.random(n) < 0.1] = 0.0
    x[rng.random(n) < 0.1] = -0.0
    assert _bits(_np_sum(x.tolist())) == _bits(np.add.reduce(x))
    z = np.where(rng.random(n) < 0.5, -0.0, 0.0)  # signed zeros only
    assert _bits(_np_sum(z.tolist())) == _bits(np.add.reduce(z))


def _estimator(rng: np.random.Generator, n: int, t0: float) -> RadialSpeedEstimator:
    e = RadialSpeedEstimator(5.35)
    t = t0
    for _ in range(n):
        t += 0.2 * int(rng.integers(1, 4))  # dropped frames too
        e.add(t, float(rng.uniform(0.0, 25.0)), float(rng.uniform(-5.35, 5.35)), 1.0, 2.0)
    return e


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.integers(1, 200), st.sampled_from([0.0, 37.4, 1e5, 3e8]))
def test_radial_speed_estimator_plain_paths_equal_numpy(seed, n, t0):
    rng = np.random.default_rng(seed)
    e = _estimator(rng, n, t0)
    a, b = e._current_radial_speed_kmh(), e._current_radial_speed_kmh_numpy()
    assert _bits(a) == _bits(b)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the mean of no speeds (one frame)
        ref = float(np.mean(np.abs(e.speeds_kmh()))) if len(e) >= 2 else math.nan
    assert _bits(e.mean_abs_speed_kmh()) == _bits(ref)


def test_current_speed_after_prepend_and_merge_equals_numpy():
    rng = np.random.default_rng(5)
    a, b, c = _estimator(rng, 30, 0.0), _estimator(rng, 20, 100.0), _estimator(rng, 25, 2.1)
    b.prepend(a)
    b.merge(c)
    assert _bits(b._current_radial_speed_kmh()) == _bits(b._current_radial_speed_kmh_numpy())
    assert _bits(b.mean_abs_speed_kmh()) == _bits(float(np.mean(np.abs(b.speeds_kmh()))))


def test_dealias_rounds_half_to_even_and_keeps_signed_zero():
    e = RadialSpeedEstimator(5.0)  # period 10 km/h
    # (rho - v) / period exactly -0.5, 0.5, 1.5, and a small negative quotient (np.rint gives -0.0)
    for t_v in ((0.0, 5.0), (0.0, -5.0), (0.0, -15.0), (0.0, 1.0), (0.0, -0.0)):
        e._v.clear()
        e._t.clear()
        e._r.clear()
        for k in range(4):
            e._t.append(0.2 * k)
            e._r.append(10.0 + t_v[0] * k)
            e._v.append(t_v[1])
        e._current = None
        assert _bits(e._current_radial_speed_kmh()) == _bits(e._current_radial_speed_kmh_numpy())


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.lists(st.integers(0, 2**40), min_size=1, max_size=12))
def test_median_of_counts_equals_numpy(values):
    from collections import deque

    from edge.classify.features import plain_median as _median

    assert _bits(_median(deque(values))) == _bits(float(np.median(deque(values))))


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.floats(0.1, 20.0))
def test_within_decides_as_numpys_norm_or_defers(seed, radius):
    from edge.track.surveillance import _within

    rng = np.random.default_rng(seed)
    d = rng.normal(size=3) * radius
    if seed % 4 == 0:  # on the sphere, up to rounding: too close to tell
        d *= radius / float(np.linalg.norm(d))
    if seed % 7 == 0:
        d[int(seed % 3)] = np.nan
    got = _within(float(d[0]), float(d[1]), float(d[2]), radius)
    ref = float(np.linalg.norm(d)) <= radius
    assert got is None or got == ref
    if seed % 4 == 0 or seed % 7 == 0:
        assert got is None


def test_published_state_is_the_constructors():
    from edge.types import TrackState, track_state

    for r, v in ((3.5, -1.25), (0.0, math.nan)):
        fast = track_state(7, 0.0, r, 0.0, v, r, v, math.nan, 12, 9, True, None)  # as the surveillance tracker
        plain = TrackState(track_id=7, x_m=0.0, y_m=r, vx_mps=0.0, vy_mps=v, range_m=r, radial_speed_mps=v,
                           az_rad=math.nan, age_frames=12, hits=9, confirmed=True)
        assert list(vars(fast).items()).__repr__() == list(vars(plain).items()).__repr__()
        if not math.isnan(v):
            assert fast == plain and hash(fast) == hash(plain)


# --- the alpha-beta tracker's per-track steps in plain Python against their former numpy forms ------------------

def _corange_numpy(tracker, rows, cols, cen):
    tol = tracker.config.corange_fragment_m
    r = cen[:, 2]
    seen = np.array([tracker.tracks[i].seen_frames for i in rows.tolist()], dtype=np.int64)
    near = np.abs(r[cols][:, None] - r[cols][None, :]) <= tol
    score = np.where(near, seen[None, :], -1)
    owner = np.where(score.max(axis=1) > seen, np.argmax(score, axis=1), np.arange(rows.size))
    keep = owner == np.arange(rows.size)
    absorbed = {int(cols[a]): tracker.tracks[int(rows[owner[a]])].track_id for a in np.flatnonzero(~keep).tolist()}
    rows, cols = rows[keep], cols[keep]
    free = np.ones(cen.shape[0], dtype=bool)
    free[cols] = False
    for j in absorbed:
        free[j] = False
    fj = np.flatnonzero(free)
    if fj.size and cols.size:
        d = np.abs(r[fj][:, None] - r[cols][None, :])
        b = np.argmin(d, axis=1)
        for j, k, ok in zip(fj.tolist(), b.tolist(), (d[np.arange(fj.size), b] <= tol).tolist()):
            if ok:
                absorbed[j] = tracker.tracks[int(rows[k])].track_id
    return rows, cols, absorbed


def _range_gate_numpy(tracker, pred):
    cfg = tracker.config
    missed = np.array([t.missed for t in tracker.tracks], dtype=np.float64)
    rated = np.array([t.vis > 0 for t in tracker.tracks], dtype=bool)
    g = cfg.range_gate_m + cfg.range_gate_rate_factor * np.abs(pred[:, 5]) * (missed + 1.0)
    return np.where(rated, g, np.inf)


def _occluded_numpy(tracker, tr, pred, cen, cols):
    from edge.track.alphabeta import POS

    if tracker.occlusion_test is None or cols.size == 0 or tr.occluded >= tracker.config.merge_max_frames:
        return False
    d = np.linalg.norm(cen[cols] - pred[POS], axis=1)
    j = int(np.argmin(d))
    return bool(d[j] <= tracker.config.gate_radius) and bool(tracker.occlusion_test(tr, int(cols[j])))


def _random_tracker(rng, n_tracks):
    from edge.track.alphabeta import AlphaBetaConfig, AlphaBetaTrack, AlphaBetaTracker
    from edge.track.cylinder import Cylinder

    tracker = AlphaBetaTracker(AlphaBetaConfig(), Cylinder(5.35))
    for k in range(n_tracks):
        tr = AlphaBetaTrack(k + 1, rng.normal(size=6), rng.normal(size=3), 0, 0, age=int(rng.integers(0, 9)),
                            vis=int(rng.integers(0, 9)), missed=int(rng.integers(0, 4)))
        tracker.tracks.append(tr)
    return tracker


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.integers(1, 6), st.integers(0, 7))
def test_alphabeta_corange_gate_and_occlusion_equal_numpy(seed, n_tracks, n_cen):
    rng = np.random.default_rng(seed)
    tracker = _random_tracker(rng, n_tracks)
    cen = rng.normal(size=(n_cen, 3))
    cen[:, 2] = np.round(rng.uniform(0.0, 3.0, n_cen), 1)  # ranges on a 0.1 m grid: ties and |dr| = tol
    if n_cen and seed % 5 == 0:
        cen[int(rng.integers(n_cen)), int(rng.integers(3))] = np.nan
    pred = rng.normal(size=(n_tracks, 6))
    pred[:, 5] *= 10.0 ** rng.integers(-3, 3, n_tracks)
    np.testing.assert_array_equal(tracker._range_gate(pred), _range_gate_numpy(tracker, pred), strict=True)
    a = min(n_tracks, n_cen)
    rows = rng.permutation(n_tracks)[:a].astype(np.intp)
    cols = rng.permutation(n_cen)[:a].astype(np.intp)
    if a:
        got, ref = tracker._corange_fragments(rows, cols, cen), _corange_numpy(tracker, rows, cols, cen)
        np.testing.assert_array_equal(got[0], ref[0], strict=True)
        np.testing.assert_array_equal(got[1], ref[1], strict=True)
        assert list(got[2].items()) == list(ref[2].items())
    asked: list[tuple[int, int]] = []
    tracker.occlusion_test = lambda tr, j: asked.append((tr.track_id, j)) or (j % 2 == 0)
    for k, tr in enumerate(tracker.tracks):
        tr.occluded = int(rng.integers(0, 12))
        got = tracker._occluded(tr, pred[k], cen, cols)
        mine, asked[:] = list(asked), []
        assert got == _occluded_numpy(tracker, tr, pred[k], cen, cols)
        assert asked == mine  # the same centroid asked about
        asked.clear()


def test_with_class_is_dataclasses_replace():
    import dataclasses

    from edge.pipelines.surveillance import _with_class
    from edge.types import TrackState

    ts = TrackState(track_id=3, x_m=0.0, y_m=4.0, vx_mps=0.0, vy_mps=-1.0, range_m=4.0, radial_speed_mps=-1.0,
                    az_rad=math.nan, age_frames=5, hits=4, confirmed=True, lane=2, rcs_dbsm=1.5)
    fast, plain = _with_class(ts, "car", 0.75), dataclasses.replace(ts, cls="car", class_probability=0.75)
    assert repr(list(vars(fast).items())) == repr(list(vars(plain).items()))
    assert type(fast) is TrackState and ts.cls is None


def test_detections_equal_from_polar():
    from types import SimpleNamespace

    from edge.classify.features import ClusterSignatures
    from edge.pipelines.surveillance import SurveillancePipeline
    from edge.dsp.range_doppler import RangeDopplerProcessor
    from edge.types import Detections
    from hal.waveform import d2g_frontend

    pipe = SurveillancePipeline.__new__(SurveillancePipeline)
    pipe.rd = RangeDopplerProcessor(d2g_frontend())
    rng = np.random.default_rng(3)
    for n_pts in ([12, 0, 40], [5, 7], [0, 0], []):
        n_pts = np.array(n_pts, dtype=np.intp)
        L = n_pts.size
        cen = rng.normal(size=(L, 3))
        sig = ClusterSignatures(cen, rng.uniform(0.0, 24.0, L), rng.random(L), rng.random(L), n_pts, rng.random(L))
        got = pipe._detections(SimpleNamespace(signatures=sig), L)
        ok = n_pts > 0
        if not ok.any():
            ref = Detections.empty()
        else:
            _, vw = pipe.rd.unwrap(cen[ok])
            nan = np.full(int(ok.sum()), np.nan, dtype=np.float32)
            ref = Detections.from_polar(sig.range_m[ok], nan, nan, nan,
                                        extra={"doppler_wrapped_kmh": vw, "n_points": n_pts[ok].astype(np.int32)})
        for f in ("range_m", "radial_speed_mps", "az_rad", "snr_db", "x_m", "y_m"):
            np.testing.assert_array_equal(getattr(got, f), getattr(ref, f), strict=True)
        assert list(got.extra) == list(ref.extra)
        for k in ref.extra:
            np.testing.assert_array_equal(got.extra[k], ref.extra[k], strict=True)
