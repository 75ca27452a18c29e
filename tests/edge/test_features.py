"""Cluster signatures (Tavanti eqs. 17-18) and track features (eq. 19) with known values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import circvar

from edge.classify.features import (
    FEATURE_NAMES,
    FeatureConfig,
    MapPoints,
    SignatureExtractor,
    TrackFeatureAccumulator,
)
from hal.waveform import SPEED_OF_LIGHT_MPS, d2g_frontend

FE = d2g_frontend()
CFG = FeatureConfig()
EX = SignatureExtractor(CFG, FE)
VMAX = EX.cylinder.vmax_kmh


def pts(range_m, v_kmh, amp, rbin, dbin, label):
    f = lambda a: np.asarray(a, dtype=np.float32)  # noqa: E731
    i = lambda a: np.asarray(a, dtype=np.int32)  # noqa: E731
    return MapPoints(f(range_m), f(v_kmh), f(amp), i(rbin), i(dbin), i(label))


def test_extractor_constants_from_the_d2g_waveform():
    assert VMAX == pytest.approx(5.348, abs=2e-3)  # Tavanti Table II: 5.4 km/h
    assert EX.n_samples == 64
    assert EX.slope_hz_per_s == pytest.approx(200e6 / 1.5e-3)
    # f_b = 2 mu r / c: 24 m is the edge of the positive-range half (fs / 2)
    assert EX.beat_hz(24.0) == pytest.approx(64 / 1.5e-3 / 2, rel=2e-3)


def test_circular_variance_known_values_and_scipy():
    v = np.array([1.0, 1.0, 1.0,  # cluster 0: one Doppler -> S = 0
                  -VMAX + 0.1, VMAX - 0.1,  # cluster 1: straddles the wrap
                  -VMAX, -VMAX / 2, 0.0, VMAX / 2])  # cluster 2: evenly around -> S = 1
    lab = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2])
    n = v.size
    sig = EX(pts(np.full(n, 5.0), v, np.ones(n), np.arange(n), np.arange(n), lab))
    assert sig.circular_variance[0] == pytest.approx(0.0, abs=1e-7)
    assert sig.circular_variance[1] == pytest.approx(1 - math.cos(math.pi * 0.1 / VMAX), abs=1e-6)
    assert sig.circular_variance[2] == pytest.approx(1.0, abs=1e-6)
    for c in range(3):
        th = np.pi * (v[lab == c].astype(np.float32) + VMAX) / VMAX
        assert sig.circular_variance[c] == pytest.approx(circvar(th), abs=1e-6)
    np.testing.assert_array_equal(sig.n_points, [3, 2, 4])


def test_centroid_is_on_the_cylinder_across_the_wrap():
    sig = EX(pts([4.0, 6.0], [VMAX - 0.2, -VMAX + 0.2], [1, 1], [0, 1], [0, 1], [0, 0]))
    c = sig.centroid[0]
    assert math.hypot(c[0], c[1]) == pytest.approx(VMAX / math.pi, rel=1e-9)
    r, v = EX.cylinder.from_cylinder(c)
    assert float(r) == pytest.approx(5.0) and sig.range_m[0] == pytest.approx(5.0)
    # the circular mean is at the wrap (+-v_max), not at the arithmetic mean 0
    assert abs(abs(float(v)) - VMAX) < 1e-4


def term(r, a):
    fb = 2 * (200e6 / 1.5e-3) * r / SPEED_OF_LIGHT_MPS
    return r**1.8 / 64 * (a * math.sqrt(1000.0**2 + fb**2) / fb) ** 2


def test_rcs_sums_local_range_peaks_per_doppler_column():
    # cluster 0, Doppler column 7: amplitudes along consecutive range bins 10..14 = 1 3 2 5 4
    #   -> peaks at bins 11 (3) and 13 (5); column 8: bins 20 and 22 (not adjacent) -> both peaks
    # cluster 1, column 7 (same column as cluster 0, other cells): a plateau 2 2 -> one peak
    r0 = 0.09375
    rb = np.array([10, 11, 12, 13, 14, 20, 22, 40, 41])
    amp = np.array([1, 3, 2, 5, 4, 2, 6, 2, 2], dtype=float)
    db = np.array([7, 7, 7, 7, 7, 8, 8, 7, 7])
    lab = np.array([0, 0, 0, 0, 0, 0, 0, 1, 1])
    rng = rb * r0
    order = np.random.default_rng(0).permutation(rb.size)  # input order must not matter
    sig = EX(pts(rng[order], np.zeros(9)[order], amp[order], rb[order], db[order], lab[order]))
    want0 = term(11 * r0, 3) + term(13 * r0, 5) + term(20 * r0, 2) + term(22 * r0, 6)
    want1 = term(40 * r0, 2)
    np.testing.assert_allclose(sig.rcs, [want0, want1], rtol=1e-5)


def test_rcs_if_compensation_and_exponent():
    """Without the IF corner (f_c = 0) the factor is 1: gamma = r^p / N_s |M|^2."""
    ex = SignatureExtractor(FeatureConfig(if_corner_hz=0.0, range_exponent=2.0), FE)
    sig = ex(pts([10.0], [0.0], [3.0], [5], [1], [0]))
    assert sig.rcs[0] == pytest.approx(10.0**2 / 64 * 9.0, rel=1e-6)
    # the corner boosts close targets more than far ones
    a = EX(pts([1.0], [0.0], [1.0], [5], [1], [0])).rcs[0] / (1.0**1.8 / 64)
    b = EX(pts([20.0], [0.0], [1.0], [5], [1], [0])).rcs[0] / (20.0**1.8 / 64)
    assert a > 1.5 and 1.0 < b < 1.01


def test_noise_points_and_empty_frames():
    sig = EX(pts([5.0, 6.0], [0, 0], [1, 1], [1, 2], [1, 1], [-1, -1]))
    assert len(sig) == 0
    sig = EX(MapPoints.empty())
    assert len(sig) == 0 and sig.centroid.shape == (0, 3)


def test_track_features_known_values():
    rng = np.random.default_rng(1)
    t = np.array([0.0, 0.2, 0.4, 0.8, 1.0, 1.2])  # frame 0.6 s missed
    r = 20.0 - 1.5 * t  # 1.5 m/s approaching = -5.4 km/h
    s = rng.uniform(0, 1, t.size)
    g = rng.uniform(10, 100, t.size)
    e = rng.uniform(1, 6, t.size)
    acc = TrackFeatureAccumulator(extent_percentile=90.0)
    for k in range(t.size):
        acc.add(t[k], s[k], g[k], r[k], e[k])
    x = acc.features()
    assert len(FEATURE_NAMES) == x.size == 6
    np.testing.assert_allclose(x, [s.mean(), s.var(ddof=1), g.mean(), g.var(ddof=1), 5.4, np.percentile(e, 90)],
                               rtol=1e-9)
    assert acc.mean_radial_speed_kmh() == pytest.approx(-5.4, rel=1e-9)
    assert acc.n == 6


def test_radial_speed_mean_of_absolute_values_and_least_squares():
    t = np.arange(5) * 0.2
    r = np.array([10.0, 10.2, 10.1, 10.4, 10.3])
    acc = TrackFeatureAccumulator()
    for tk, rk in zip(t, r):
        acc.add(tk, 0.1, 1.0, rk)
    v = np.diff(r) / 0.2 * 3.6
    assert acc.features()[4] == pytest.approx(np.abs(v).mean())
    assert acc.mean_radial_speed_kmh() == pytest.approx(np.polyfit(t, r, 1)[0] * 3.6)


def test_extent_feature_is_nan_without_extents_and_ignores_nan_frames():
    acc = TrackFeatureAccumulator(extent_percentile=50.0)
    for k in range(3):
        acc.add(0.2 * k, 0.1, 1.0, 10.0)
    assert np.isnan(acc.features()[5]) and np.all(np.isfinite(acc.features()[:5]))
    acc.add(0.6, 0.1, 1.0, 10.0, 4.0)
    acc.add(0.8, 0.1, 1.0, 10.0, float("nan"))
    acc.add(1.0, 0.1, 1.0, 10.0, 2.0)
    assert acc.features()[5] == pytest.approx(3.0)  # median of the two measured extents


@pytest.mark.parametrize("pct", [0.0, 37.5, 50.0, 90.0, 100.0])
def test_extent_percentile_equals_numpy(pct):
    rng = np.random.default_rng(int(pct))
    for n in (1, 2, 7, 60):
        e = rng.uniform(0.5, 12.0, n)
        acc = TrackFeatureAccumulator(extent_percentile=pct)
        for k in range(n):
            acc.add(0.2 * k, 0.1, 1.0, 10.0, e[k])
        assert acc.extent_m() == pytest.approx(np.percentile(e, pct), rel=1e-12, abs=1e-12)


def test_cluster_extent_spans_cells_within_level_of_the_peak():
    """Extent = range span of the cells at most extent_level_db below the cluster's peak, per cluster."""
    cfg = FeatureConfig(extent_level_db=20.0)
    ex = SignatureExtractor(cfg, FE)
    # cluster 0: peak 100 at 10 m, cells 20 (-14 dB) at 8 m and 5 (-26 dB) at 6 m -> 8..10 m
    # cluster 1: one cell at 15 m -> extent 0; noise (-1) at 1 m is ignored
    r = np.array([10.0, 8.0, 6.0, 15.0, 1.0])
    amp = np.array([100.0, 20.0, 5.0, 3.0, 1000.0])
    lab = np.array([0, 0, 0, 1, -1])
    sig = ex(pts(r, np.zeros(5), amp, np.arange(5), np.zeros(5, dtype=int), lab))
    np.testing.assert_allclose(sig.range_lo_m, [8.0, 15.0])
    np.testing.assert_allclose(sig.range_hi_m, [10.0, 15.0])
    np.testing.assert_allclose(sig.extent_m, [2.0, 0.0])
    wide = SignatureExtractor(FeatureConfig(extent_level_db=30.0), FE)(
        pts(r, np.zeros(5), amp, np.arange(5), np.zeros(5, dtype=int), lab))
    np.testing.assert_allclose(wide.extent_m, [4.0, 0.0])


@pytest.mark.parametrize("kernel", [True, False])
def test_cluster_extent_keeps_the_cells_at_the_body_doppler(kernel):
    """A car's body (strongest cell at 10 m, body cells at 8-12 m, wrapped Doppler near 3 km/h) and wheel cells whose
    micro-Doppler moved them to 6 and 14 m through the range-Doppler coupling: the extent spans the cells within
    extent_doppler_kmh of the strongest cell's wrapped Doppler (0: every cell); the cluster's span stays that of
    every cell."""
    r = np.array([10.0, 8.0, 12.0, 6.0, 14.0, 11.0])
    dop = np.array([3.0, 3.5, 2.4, 0.8, -4.0, 4.6])  # on the +-5.35 km/h cylinder, -4.0 is 3.7 from 3.0
    amp = np.array([100.0, 40.0, 30.0, 50.0, 60.0, 20.0])
    lab = np.zeros(6, dtype=int)
    cells = pts(r, dop, amp, np.arange(6), np.arange(6), lab)
    for gate, lo_hi in ((1.0, (8.0, 12.0)), (2.0, (8.0, 12.0)), (4.0, (6.0, 14.0)), (0.0, (6.0, 14.0))):
        ex = SignatureExtractor(FeatureConfig(extent_doppler_kmh=gate), FE)
        if not kernel:
            ex.kernel = None
        sig = ex(cells)
        assert (sig.body_lo_m[0], sig.body_hi_m[0]) == pytest.approx(lo_hi), gate
        assert sig.extent_m[0] == pytest.approx(lo_hi[1] - lo_hi[0]), gate
        assert (sig.range_lo_m[0], sig.range_hi_m[0]) == pytest.approx((6.0, 14.0)), gate  # the span of every cell
    # across the wrap: a cell at -5.2 km/h is 0.3 km/h from one at +5.2 on the cylinder (alias step 10.7 km/h)
    wrap = pts(np.array([10.0, 13.0]), np.array([5.2, -5.2]), np.array([100.0, 50.0]), np.arange(2), np.arange(2),
               np.zeros(2, dtype=int))
    ex = SignatureExtractor(FeatureConfig(extent_doppler_kmh=1.0), FE)
    if not kernel:
        ex.kernel = None
    assert ex(wrap).extent_m[0] == pytest.approx(3.0)


def test_doppler_speed_feature_is_the_unaliased_doppler_not_the_centroid_jitter():
    """speed_feature = "doppler": E(|v_r|) from each frame's wrapped Doppler unaliased with the range
    rate. A pedestrian crossing the beam (radial 1.5 km/h) whose centroid jitters by 0.3 m reads
    ~1.5 km/h; the paper's range displacement reads several times that (jitter / frame period)."""
    rng = np.random.default_rng(4)
    for v_kmh in (1.5, -27.0):  # a crossing pedestrian; a motorcycle, Doppler aliased (v_max 5.35 km/h)
        t = np.arange(15) * 0.2
        r = 12.0 + v_kmh / 3.6 * t + rng.normal(0.0, 0.3, t.size)
        dop = (v_kmh + VMAX) % (2 * VMAX) - VMAX
        by_doppler = TrackFeatureAccumulator(vmax_kmh=VMAX)
        by_range = TrackFeatureAccumulator()
        for k in range(t.size):
            by_doppler.add(t[k], 0.1, 1.0, r[k], 2.0, dop)
            by_range.add(t[k], 0.1, 1.0, r[k], 2.0, dop)
        assert by_doppler.features()[4] == pytest.approx(abs(v_kmh), abs=1e-3)
        if abs(v_kmh) < 5:
            assert by_range.features()[4] > 3 * abs(v_kmh)
    ex = SignatureExtractor(FeatureConfig(speed_feature="range_rate"), FE)
    assert ex.speed_vmax_kmh is None and EX.speed_vmax_kmh == pytest.approx(VMAX)


def test_single_frame_gives_nan_variances():
    acc = TrackFeatureAccumulator()
    acc.add(0.0, 0.2, 3.0, 5.0)
    x = acc.features()
    assert x[0] == 0.2 and x[2] == 3.0 and np.isnan(x[1]) and np.isnan(x[3]) and np.isnan(x[4])
    assert math.isnan(acc.mean_radial_speed_kmh())


def test_map_points_from_map():
    mag = np.zeros((6, 4), dtype=np.float32)
    mag[2, 1], mag[3, 1], mag[5, 3] = 2.0, 5.0, 1.9
    pts_ = MapPoints.from_map(mag, 2.0, np.arange(6) * 0.5, np.array([-2.0, -1.0, 0.0, 1.0]))
    np.testing.assert_array_equal(pts_.range_bin, [2, 3])
    np.testing.assert_array_equal(pts_.doppler_bin, [1, 1])
    np.testing.assert_allclose(pts_.range_m, [1.0, 1.5])
    np.testing.assert_allclose(pts_.doppler_kmh, [-1.0, -1.0])
    np.testing.assert_allclose(pts_.amplitude, [2.0, 5.0])
    assert pts_.n_clusters == 1 and len(pts_) == 2
    with pytest.raises(ValueError):
        MapPoints(np.zeros(2), np.zeros(3), np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2))


# --- radial speed (de-aliased Doppler) -------------------------------------------------------------

from edge.classify import features  # noqa: E402
from edge.classify.features import RadialSpeedEstimator  # noqa: E402


def wrapped(v):
    return (np.asarray(v) + VMAX) % (2 * VMAX) - VMAX


@pytest.mark.parametrize("v_true", [-41.0, -25.0, -9.8, -3.0, 4.7, 12.0, 36.2])
def test_radial_speed_dealiased_from_doppler_and_range(v_true):
    rng = np.random.default_rng(int(abs(v_true) * 10))
    t = np.arange(20) * 0.2
    r = 12.0 + v_true / 3.6 * t + rng.normal(0, 0.3, t.size)  # noisy centroid range
    est = RadialSpeedEstimator(VMAX)
    for tk, rk, vk in zip(t, r, wrapped(v_true + rng.normal(0, 0.2, t.size))):
        est.add(tk, rk, vk)
    v = est.speeds_kmh()
    np.testing.assert_allclose(v, v_true, atol=0.8)  # every frame on the right alias
    assert est.mean_radial_speed_kmh() == pytest.approx(v_true, abs=0.3)
    assert est.current_radial_speed_kmh() == pytest.approx(v_true, abs=0.8)


def test_radial_speed_robust_to_entry_lag_and_passing_tail():
    """A truck at -27 km/h: its centroid moves at half the speed while the body enters the beam,
    and the radial speed falls through zero as it passes the radar; the median stays on -27."""
    t = np.arange(20) * 0.2
    v = np.full(20, -27.0)
    v[-6:] = [-24.0, -21.0, -14.0, -5.0, 4.0, 13.0]  # passing beside the radar
    rate = v.copy()
    rate[:6] *= 0.5  # entry: the centroid lags
    r = 24.0 + np.concatenate([[0.0], np.cumsum(rate[1:] / 3.6 * 0.2)])
    est = RadialSpeedEstimator(VMAX)
    for tk, rk, vk in zip(t, r, wrapped(v)):
        est.add(tk, rk, vk)
    assert est.mean_radial_speed_kmh() == pytest.approx(-27.0, abs=0.1)
    # the whole-track least-squares range rate is far off (entry and tail): it would pick a wrong alias
    assert abs(np.polyfit(t, r, 1)[0] * 3.6 + 27.0) > VMAX


def test_radial_speed_needs_two_frames_and_ignores_repeated_times():
    est = RadialSpeedEstimator(VMAX)
    assert math.isnan(est.mean_radial_speed_kmh())
    est.add(0.0, 10.0, 1.0)
    est.add(0.0, 10.5, 1.0)  # same time: ignored
    assert len(est) == 1 and math.isnan(est.current_radial_speed_kmh())
    est.add(0.2, 10.1, 1.0)
    assert est.mean_radial_speed_kmh() == pytest.approx(1.0)


def _receding_truck(extent_final_m: float, lag: float = 0.45):
    """A body receding at 22 km/h beside the radar: its front (far edge) moves at full speed while its
    centroid, held back by the side coming into view behind the front, moves at ``lag`` of it."""
    t = np.arange(20) * 0.2
    v_true = 22.0
    front = 7.0 + v_true / 3.6 * t
    centroid = 6.0 + lag * v_true / 3.6 * t
    near = front - np.linspace(1.0, extent_final_m, t.size)
    return t, v_true, centroid, near, front


def test_event_speed_of_a_long_body_unaliased_with_its_leading_edge():
    t, v_true, centroid, near, front = _receding_truck(extent_final_m=9.0)
    est = RadialSpeedEstimator(VMAX)
    for tk, rk, vk, lo, hi in zip(t, centroid, wrapped(np.full(t.size, v_true)), near, front):
        est.add(tk, rk, vk, lo, hi)
    # the centroid's rate (9.9 km/h) is more than v_max off: every frame takes the wrong alias
    assert abs(est.trimmed_mean_radial_speed_kmh() - (v_true - 2 * VMAX)) < 0.01
    assert est.reference_rate_kmh(4.0) == pytest.approx(v_true, abs=0.01)  # the far (leading) edge
    assert est.trimmed_mean_radial_speed_kmh(4.0) == pytest.approx(v_true, abs=0.01)
    assert est.mean_radial_speed_kmh(4.0) == pytest.approx(v_true, abs=0.01)


def test_leading_edge_only_for_long_bodies_and_the_right_edge():
    # short body (median extent < 4 m): the centroid's rate as before, edges ignored
    t, v_true, centroid, near, front = _receding_truck(extent_final_m=3.0, lag=1.0)
    est = RadialSpeedEstimator(VMAX)
    for tk, rk, vk, lo in zip(t, centroid, wrapped(np.full(t.size, v_true)), near):
        est.add(tk, rk, vk, lo, lo + 0.5)  # edges that would give the wrong rate if used
    assert est.reference_rate_kmh(4.0) == pytest.approx(est.reference_rate_kmh())
    # approaching long body: the near edge leads
    est = RadialSpeedEstimator(VMAX)
    tt = np.arange(20) * 0.2
    lo = 20.0 - 25.0 / 3.6 * tt
    for tk, l in zip(tt, lo):
        est.add(tk, l + 2.0 - 0.5 * (-25.0 / 3.6) * tk, wrapped(-25.0), l, l + 9.0)  # centroid lags
    assert est.reference_rate_kmh(4.0) == pytest.approx(-25.0, abs=0.01)
    assert est.trimmed_mean_radial_speed_kmh(4.0) == pytest.approx(-25.0, abs=0.01)
    # without extents (the old add signature) nothing changes
    est2 = RadialSpeedEstimator(VMAX)
    for tk, rk, vk in zip(t, centroid, wrapped(np.full(t.size, v_true))):
        est2.add(tk, rk, vk)
    assert est2.reference_rate_kmh(4.0) == pytest.approx(est2.reference_rate_kmh())


def test_event_speed_leaves_out_frames_faster_than_the_target():
    """A motorcycle receding at 27 km/h from beside the radar: its first frames (radial speed -10..17
    km/h, changing faster than the reference rate can follow) took the alias nearest the track's rate,
    reading 28-30 km/h; the far frames (>= 10 m) show 27 at most, so those frames are left out."""
    t = np.arange(14) * 0.2
    r = np.array([2.9, 3.0, 4.0, 5.1, 6.5, 7.9, 9.3, 10.7, 12.1, 13.6, 15.1, 16.6, 18.1, 19.6])
    v = np.array([29.0, 28.3, 30.0, 29.7, 22.9, 24.2, 25.3, 26.0, 26.5, 26.7, 26.9, 26.9, 27.1, 27.1])
    est = RadialSpeedEstimator(VMAX)
    for tk, rk, vk in zip(t, r, wrapped(v)):
        est.add(tk, rk, vk)
    np.testing.assert_allclose(est.speeds_kmh(), v, atol=1e-9)  # every frame on the alias above
    kept = est.capped_speeds_kmh(cap_range_m=10.0, cap_margin_kmh=0.5)
    np.testing.assert_allclose(kept, v[4:], atol=1e-9)
    assert est.trimmed_mean_radial_speed_kmh(cap_range_m=10.0) == pytest.approx(float(np.mean(v[4:])))
    assert est.trimmed_mean_radial_speed_kmh() == pytest.approx(float(np.mean(v)))  # off: as before
    assert est.mean_radial_speed_kmh(cap_range_m=10.0) == pytest.approx(float(np.median(v[4:])))
    # a slow target (far frames below cap_min_kmh), or one without two far frames, is left alone
    assert est.capped_speeds_kmh(cap_range_m=10.0, cap_min_kmh=30.0).size == v.size
    assert est.capped_speeds_kmh(cap_range_m=20.0).size == v.size


def test_history_alias_takes_a_long_bodys_leading_edge_and_flags_what_it_cannot_decide():
    """A truck receding at 25.8 km/h, 10 m long, seen for 12 frames while it leaves beside the radar: its centroid
    moves 6 km/h slower (more of the body comes into view behind the front every frame) and takes the alias one step
    too slow, frame by frame; its far edge moves at its speed. A car seen in two frames gets no certain alias."""
    t = np.arange(12) * 0.2
    v_true = 25.8
    front = 6.0 + v_true / 3.6 * t
    centroid = 3.0 + (v_true - 6.0) / 3.6 * t
    est = RadialSpeedEstimator(VMAX)
    for tk, rk, hk, vk in zip(t, centroid, front, wrapped(np.full(t.size, v_true))):
        est.add(tk, rk, vk, range_lo_m=rk - 4.0, range_hi_m=hk)
    v_frame, _ = est.event_speed_kmh("frame")
    assert v_frame == pytest.approx(v_true - 2 * VMAX, abs=0.2)  # one alias step too slow
    v, certain = est.event_speed_kmh("history", alias_edge_m=3.0)
    assert v == pytest.approx(v_true, abs=0.2) and certain
    # the centroid only: wrong, and it says so (its rate lies 4.7 km/h from the speed it picks, nearly v_max)
    v_c, certain_c = est.event_speed_kmh("history", alias_edge_m=0.0)
    assert v_c == pytest.approx(v_true - 2 * VMAX, abs=0.2) and not certain_c
    short = RadialSpeedEstimator(VMAX)
    for tk, rk, vk in zip(t[:2], 10.0 + 30.0 / 3.6 * t[:2], wrapped(np.full(2, 30.0))):
        short.add(tk, rk, vk)
    assert not short.event_speed_kmh("history")[1]


def test_merge_adds_the_frames_another_part_saw():
    a, b = RadialSpeedEstimator(VMAX), RadialSpeedEstimator(VMAX)
    for k in range(4):
        a.add(0.2 * k, 10.0 + k, 1.0, 9.0 + k, 11.0 + k)
    for k in range(2, 7):
        b.add(0.2 * k, 12.0 + k, 1.5, 11.0 + k, 14.0 + k)
    a.merge(b)
    t, r = a.history()
    np.testing.assert_allclose(t, 0.2 * np.arange(7))
    np.testing.assert_allclose(r, [10, 11, 12, 13, 16, 17, 18])  # a's own frames kept where both saw one
    lo, hi = a.extents()
    np.testing.assert_allclose(lo, [9, 10, 11, 12, 15, 16, 17])
    np.testing.assert_allclose(hi, [11, 12, 16, 17, 18, 19, 20])  # where both saw the body: the union of the parts


def test_history_alias_leaves_out_a_far_edge_cut_off_at_the_largest_range():
    """The truck's front leaves the 24 m view half-way: its far edge then stays at 23.9 m, and a leading-edge rate
    over all frames is too slow for the right alias; without the frames beyond 21 m it is the truck's."""
    t = np.arange(14) * 0.2
    v_true = 25.8
    front = np.minimum(15.0 + v_true / 3.6 * t, 23.9)
    centroid = 6.0 + (v_true - 9.0) / 3.6 * t
    est = RadialSpeedEstimator(VMAX)
    for tk, rk, hk, vk in zip(t, centroid, front, wrapped(np.full(t.size, v_true))):
        est.add(tk, rk, vk, range_lo_m=rk - 4.0, range_hi_m=hk)
    assert est.event_speed_kmh("history")[0] == pytest.approx(v_true - 2 * VMAX, abs=0.2)
    v, certain = est.event_speed_kmh("history", edge_limit_m=21.0)
    assert v == pytest.approx(v_true, abs=0.2) and certain


# --- fit_alias: one reference fitted to the range history with the wrapped Doppler as its slope (issue 31 part 3) ---


def _feed(est, t, r, v, lo=None, hi=None):
    lo = np.full(t.size, np.nan) if lo is None else lo
    hi = np.full(t.size, np.nan) if hi is None else hi
    for tk, rk, vk, lk, hk in zip(t, r, wrapped(v), lo, hi):
        est.add(tk, rk, vk, lk, hk)
    return est


def _long_body_passing(v_true=25.0, length=12.0, n=24, clip=23.9):
    """A 12 m truck receding at ``v_true`` from beside the radar: while its front moves out to the 24 m view its
    rear is still beside the radar (the near edge stays at ~6 m, the centroid moves at about half the speed); once
    the front reaches the largest range the far edge stays there and the near edge moves at the speed."""
    t = np.arange(n) * 0.2
    front = 7.0 + v_true / 3.6 * t
    rear = np.maximum(front - length, 6.0)
    hi = np.minimum(front, clip)
    lo = np.minimum(rear, hi - 0.5)
    return t, v_true, 0.5 * (lo + hi), lo, hi


def test_fit_alias_decides_a_long_body_entering_and_leaving_the_view_by_its_edges():
    t, v_true, centroid, lo, hi = _long_body_passing()
    est = _feed(RadialSpeedEstimator(VMAX), t, centroid, np.full(t.size, v_true), lo, hi)
    # the per-frame choice follows the centroid's middle-half rate, about half the speed: one step slow
    assert est.event_speed_kmh("frame")[0] == pytest.approx(v_true - 2 * VMAX, abs=0.2)
    v, certain = est.event_speed_kmh("fit", edge_limit_m=21.0)
    assert v == pytest.approx(v_true, abs=0.2) and certain
    speeds, ref, _, _ = est.fit_alias(3.0, 0.75, 21.0)
    np.testing.assert_allclose(speeds, v_true, atol=1e-6)
    assert abs(ref - v_true) <= VMAX
    # the centroid alone, moving at about half the speed, fits the alias one step slow when nothing says where the
    # body is cut off; with the largest range, its frames cut off there are lower bounds and it fits the speed
    assert est.event_speed_kmh("fit", alias_edge_m=0.0)[0] == pytest.approx(v_true - 2 * VMAX, abs=0.2)
    assert est.event_speed_kmh("fit", alias_edge_m=0.0, edge_limit_m=21.0)[0] == pytest.approx(v_true, abs=0.2)


def _entering_at_the_largest_range(rng, v_true=-20.0, length=8.0, clip=23.9):
    """A van approaching at ``v_true`` from beyond the board's largest range: while its far part is beyond
    ``clip`` the cluster is cut there and its centroid lies nearer than the body's (noisy ranges and Doppler)."""
    n = int(rng.integers(6, 12))
    t = np.arange(n) * 0.2
    near = 23.0 + v_true / 3.6 * t
    hi = np.minimum(near + length, clip)
    lo = np.minimum(near, hi - 0.75)
    centroid = 0.5 * (lo + hi) + rng.normal(0.0, 0.35, n)
    lo = lo + rng.normal(0.0, 0.35, n)
    hi = np.minimum(hi + rng.normal(0.0, 0.2, n), clip)
    return t, centroid, v_true + rng.normal(0.0, 0.3, n), lo, hi


def test_fit_alias_takes_a_centroid_cut_off_at_the_largest_range_as_a_lower_bound(monkeypatch):
    """Frames whose far edge lies beyond ``edge_limit_m`` (the body cut off where the beat leaves the band): a path
    beyond their centroid costs nothing. Without that, a van entering the view approaching is often one step slow."""
    monkeypatch.setattr(features.native, "load", lambda name: None)  # the numpy reference, patched below
    rng = np.random.default_rng(7)
    cases = [_entering_at_the_largest_range(rng) for _ in range(100)]

    def off_by_a_step():
        n = 0
        for t, c, v, lo, hi in cases:
            est = _feed(RadialSpeedEstimator(VMAX), t, c, v, lo, hi)
            n += abs(est.event_speed_kmh("fit", edge_limit_m=21.0)[0] - float(np.mean(v))) > VMAX
        return n

    assert off_by_a_step() <= 3
    real = features.fit_candidates_reference
    monkeypatch.setattr(features, "fit_candidates_reference", lambda *a, **k: real(*a[:9]))  # no lower bounds
    assert off_by_a_step() >= 15  # 24 of 100


def test_event_speed_feature_is_on_the_fitted_alias_where_the_doppler_feature_is_a_step_slow():
    """The ``event`` speed feature (mean |v| of the frames the event speed averages) of the long body above: on the
    fitted alias, where the ``doppler`` feature (each frame on the centroid's middle-half rate) is one step slow."""
    t, v_true, centroid, lo, hi = _long_body_passing()
    est = _feed(RadialSpeedEstimator(VMAX), t, centroid, np.full(t.size, v_true), lo, hi)
    assert est.mean_abs_speed_kmh() == pytest.approx(v_true - 2 * VMAX, abs=0.2)
    v, certain, v_abs = est.event_speed_kmh("fit", edge_limit_m=21.0, abs_mean=True)
    assert (v, certain) == est.event_speed_kmh("fit", edge_limit_m=21.0)
    assert v_abs == pytest.approx(v_true, abs=0.2)
    # approaching: the magnitude, not the signed speed
    est = _feed(RadialSpeedEstimator(VMAX), t, centroid[::-1], np.full(t.size, -v_true), lo[::-1], hi[::-1])
    v, _, v_abs = est.event_speed_kmh("fit", edge_limit_m=21.0, abs_mean=True)
    assert v == pytest.approx(-v_true, abs=0.2) and v_abs == pytest.approx(v_true, abs=0.2)
    assert math.isnan(RadialSpeedEstimator(VMAX).event_speed_kmh("fit", abs_mean=True)[2])  # no frames


def test_fit_alias_of_a_short_fast_track():
    """A motorcycle receding at 36 km/h seen in five frames (2 m a frame) with a noisy centroid: right and certain;
    the same track approaching: right too."""
    rng = np.random.default_rng(3)
    t = np.arange(5) * 0.2
    for v_true in (36.0, -36.0):
        r = 12.0 + v_true / 3.6 * t + rng.normal(0.0, 0.25, t.size)
        vw = v_true + rng.normal(0.0, 0.3, t.size)
        v, certain = _feed(RadialSpeedEstimator(VMAX), t, r, vw).event_speed_kmh("fit")
        assert v == pytest.approx(v_true, abs=0.5) and certain


def test_fit_alias_ignores_static_clutter_a_track_began_on():
    """A track holds a bush at 8 m (zero Doppler) for eight frames, then a car receding at 26 km/h takes it over
    for seven: the clutter's frames say nothing of the car's alias; the per-frame choice's rate is pulled to the
    clutter's and misses the car by a step. A car at 20 km/h shows a wrapped Doppler of -1.4 km/h, as near zero as
    the bush's: static and moving are not told apart, and the event says so."""
    t = np.arange(15) * 0.2
    r = np.where(np.arange(15) < 8, 8.0, 8.5 + 26.0 / 3.6 * (t - t[8]))
    v = np.where(np.arange(15) < 8, 0.0, 26.0)
    est = _feed(RadialSpeedEstimator(VMAX), t, r, v)
    assert abs(est.event_speed_kmh("frame")[0] - 26.0) > VMAX
    speeds, ref, certain, on_path = est.fit_alias()
    assert abs(ref - 26.0) <= VMAX and certain
    np.testing.assert_allclose(speeds[8:], 26.0, atol=1e-6)
    assert on_path[8:].all() and not on_path[:7].any()  # the clutter's frames are not the car's
    assert est.event_speed_kmh("fit") == (pytest.approx(26.0, abs=1e-6), True)
    r = np.where(np.arange(15) < 8, 8.0, 8.5 + 20.0 / 3.6 * (t - t[8]))
    v = np.where(np.arange(15) < 8, 0.0, 20.0)
    assert not _feed(RadialSpeedEstimator(VMAX), t, r, v).event_speed_kmh("fit")[1]


def test_fit_alias_flags_what_it_cannot_decide():
    """Two frames decide nothing; a range moving half an alias step off the Doppler's speed fits two aliases
    alike. Either way the event is flagged (its value is one of the two aliases)."""
    t = np.arange(2) * 0.2
    short = _feed(RadialSpeedEstimator(VMAX), t, 10.0 + 30.0 / 3.6 * t, np.full(2, 30.0))
    assert not short.event_speed_kmh("fit")[1]
    t = np.arange(10) * 0.2
    coin = _feed(RadialSpeedEstimator(VMAX), t, 5.0 + (20.0 + VMAX) / 3.6 * t, np.full(10, 20.0))
    v, certain = coin.event_speed_kmh("fit")
    assert not certain and min(abs(v - 20.0), abs(v - 20.0 - 2 * VMAX)) < 0.01
    speeds, ref, certain, on_path = RadialSpeedEstimator(VMAX).fit_alias()
    assert speeds.size == 0 and math.isnan(ref) and not certain and on_path.size == 0


def test_fit_alias_on_the_latest_frames_only():
    t = np.arange(40) * 0.2
    r = np.where(np.arange(40) < 20, 8.0, 8.5 + 30.0 / 3.6 * (t - t[20]))
    v = np.where(np.arange(40) < 20, 0.0, 30.0)
    est = _feed(RadialSpeedEstimator(VMAX), t, r, v)
    speeds, ref, certain, _ = est.fit_alias(last_frames=10)
    assert speeds.size == 10 and abs(ref - 30.0) <= VMAX and certain


def test_fit_alias_of_an_event_judges_its_latest_frames_only():
    """A track that held static clutter for more than FIT_MAX_FRAMES frames before a car took it over: the event's
    speed is the car's, from the latest frames (the cap's far frames are those frames' own)."""
    from edge.classify.features import FIT_MAX_FRAMES

    n = FIT_MAX_FRAMES + 40
    t = np.arange(n) * 0.2
    r = np.where(np.arange(n) < n - 12, 8.0, 11.0 + 30.0 / 3.6 * (t - t[n - 12]))
    v = np.where(np.arange(n) < n - 12, 0.0, 30.0)
    est = _feed(RadialSpeedEstimator(VMAX), t, r, v)
    speed, certain = est.event_speed_kmh("fit", cap_range_m=10.0)
    assert speed == pytest.approx(30.0, abs=0.01) and certain


def test_dealias_one_equals_the_array_dealias():
    est = RadialSpeedEstimator(5.35)
    rng = np.random.default_rng(3)
    period = 2 * 5.35
    vw = np.concatenate([rng.uniform(-5.35, 5.35, 2000), [0.0, 5.35, -5.35, 1.0, 1.0, np.nan, 2.0]])
    ref = np.concatenate([rng.uniform(-150, 150, 2000), [0.5 * period, 5.35 + 1.5 * period, -5.35 - 2.5 * period,
                                                        1.0 + 0.5 * period, 1.0 - 0.5 * period, 3.0, np.nan]])
    want = np.array([est.dealias(v, r)[()] for v, r in zip(vw, ref)])
    got = np.array([est.dealias_one(v, r) for v, r in zip(vw, ref)])
    np.testing.assert_array_equal(got, want)  # half-way points round to even on both paths; NaN stays NaN
