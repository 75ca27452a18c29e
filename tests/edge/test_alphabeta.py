"""Benedict-Bordner alpha-beta tracker on the wrapped map (Tavanti eqs. 9-14, §II-E steps 1-9)."""

from __future__ import annotations

import math
from datetime import datetime, timedelta

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from edge.config import load_config
from edge.track.alphabeta import (
    AlphaBetaConfig,
    AlphaBetaTracker,
    BenedictBordnerFilter,
    GreedyAssociator,
    IdPool,
    benedict_bordner_beta,
    greedy_assign,
)
from edge.track.cylinder import Cylinder

VMAX = 5.348  # km/h, Distance2Go lambda / (4 T_PRI)
CYL = Cylinder(VMAX)


def meas(range_m, v_kmh):
    return CYL.to_cylinder(np.asarray(range_m, dtype=np.float64), np.asarray(v_kmh, dtype=np.float64), dtype=np.float64)


# --- filter maths ---------------------------------------------------------------------------------

def test_beta_is_benedict_bordner():
    assert benedict_bordner_beta(0.19) == pytest.approx(0.19**2 / 1.81, rel=1e-15)
    f = BenedictBordnerFilter(0.19, CYL)
    assert f.beta == pytest.approx(0.0199447513812, rel=1e-9)
    assert benedict_bordner_beta(1.0) == 1.0


def test_config_defaults_are_table_iii_and_registered():
    cfg = load_config(env={})
    ab = cfg.section("track.alphabeta")
    assert (ab.alpha, ab.gate_radius, ab.max_missed_frames, ab.visibility_threshold, ab.min_seen_frames) == (
        0.19, 6.0, 7, 0.25, 3)


def test_one_step_known_answer_along_range():
    """Init at r0, update with r1: r = r0 + alpha (r1 - r0), u_r = beta (r1 - r0); Doppler untouched."""
    a = 0.19
    b = a * a / (2 - a)
    f = BenedictBordnerFilter(a, CYL)
    s0 = f.initiate(meas([10.0], [2.0]))
    np.testing.assert_allclose(s0[0, [1, 3, 5]], 0.0)
    pred = f.predict(s0)
    np.testing.assert_allclose(pred, s0, atol=1e-12)
    s1 = f.update(pred, meas([11.0], [2.0]))
    assert s1[0, 4] == pytest.approx(10.0 + a * 1.0, abs=1e-12)
    assert s1[0, 5] == pytest.approx(b * 1.0, abs=1e-12)
    np.testing.assert_allclose(s1[0, [0, 2]], s0[0, [0, 2]], atol=1e-12)
    # next prediction: r + u_r
    p2 = f.predict(s1)
    assert p2[0, 4] == pytest.approx(10.0 + a + b, abs=1e-12)


def test_range_axis_matches_scalar_reference_and_converges():
    """A constant-velocity target in range: the filter equals a plain scalar alpha-beta recursion and
    converges with zero lag (type-2 loop), to the true rate."""
    a = 0.19
    b = a * a / (2 - a)
    f = BenedictBordnerFilter(a, CYL)
    r_true = 24.0 - 0.1 * np.arange(200)  # m, 0.1 m per frame towards the radar
    s = f.initiate(meas([r_true[0]], [-3.0]))
    p, v = r_true[0], 0.0
    for rk in r_true[1:]:
        s = f.update(f.predict(s), meas([rk], [-3.0]))
        pp = p + v
        p, v = pp + a * (rk - pp), v + b * (rk - pp)
        assert s[0, 4] == pytest.approx(p, abs=1e-9)
        assert s[0, 5] == pytest.approx(v, abs=1e-9)
    assert s[0, 4] == pytest.approx(r_true[-1], abs=1e-4)
    assert s[0, 5] == pytest.approx(-0.1, abs=1e-5)


def test_update_equals_stone_soup_alpha_beta_followed_by_projection():
    """Eq. 13 = N{Stone Soup AlphaBetaUpdater(predicted, m)} with the same alpha and beta."""
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.prediction import StatePrediction
    from stonesoup.updater.alphabeta import AlphaBetaUpdater

    a = 0.19
    f = BenedictBordnerFilter(a, CYL)
    mm = LinearGaussian(ndim_state=6, mapping=(0, 2, 4), noise_covar=np.eye(3))
    up = AlphaBetaUpdater(measurement_model=mm, alpha=a, beta=benedict_bordner_beta(a))
    rng = np.random.default_rng(4)
    t0 = datetime(2026, 1, 1)
    for _ in range(20):
        s = f.initiate(meas([rng.uniform(1, 20)], [rng.uniform(-VMAX, VMAX)]))
        s[0, [1, 3, 5]] = rng.normal(0, 0.5, 3)
        s = CYL.project_states(s)
        pred = f.predict(s)
        m = meas([rng.uniform(1, 20)], [rng.uniform(-VMAX, VMAX)])
        ours = f.update(pred, m)
        sp = StatePrediction(pred[0].reshape(6, 1), timestamp=t0 + timedelta(seconds=1))
        det = Detection(m[0].reshape(3, 1), timestamp=t0 + timedelta(seconds=1), measurement_model=mm)
        ss = up.update(SingleHypothesis(sp, det), time_interval=timedelta(seconds=1))
        ref = CYL.project_states(np.asarray(ss.state_vector, dtype=np.float64).reshape(1, 6))
        np.testing.assert_allclose(ours, ref, atol=1e-12)


# --- cylinder projection N (eq. 14) ---------------------------------------------------------------

def test_projection_puts_state_on_cylinder_with_tangent_velocity():
    rng = np.random.default_rng(1)
    s = rng.normal(0, 3, size=(50, 6))
    p = CYL.project_states(s)
    radius = np.hypot(p[:, 0], p[:, 2])
    np.testing.assert_allclose(radius, VMAX / math.pi, rtol=1e-12)
    normal = (p[:, 1] * p[:, 0] + p[:, 3] * p[:, 2]) / radius
    np.testing.assert_allclose(normal, 0.0, atol=1e-12)
    np.testing.assert_allclose(p[:, 4:], s[:, 4:])  # range and its rate untouched
    # the angle is the one of the unconstrained point, and N is idempotent
    np.testing.assert_allclose(np.arctan2(p[:, 2], p[:, 0]), np.arctan2(s[:, 2], s[:, 0]), atol=1e-12)
    np.testing.assert_allclose(CYL.project_states(p), p, atol=1e-12)


def test_projection_known_answer():
    """At theta = 0 the normal is (1, 0, 0): u_v' is removed, u_v'' kept."""
    s = np.array([[3.0, 2.0, 0.0, 5.0, 7.0, -1.0]])
    p = CYL.project_states(s)
    np.testing.assert_allclose(p, [[VMAX / math.pi, 0.0, 0.0, 5.0, 7.0, -1.0]], atol=1e-12)


def test_wrapping_round_trip():
    v = np.linspace(-VMAX, VMAX, 101)[:-1]
    pts = CYL.to_cylinder(np.full_like(v, 5.0), v, dtype=np.float64)
    r, v2 = CYL.from_cylinder(pts)
    np.testing.assert_allclose(v2, v, atol=1e-9)
    np.testing.assert_allclose(r, 5.0)
    # the two ends of the Doppler axis are the same place on the cylinder
    np.testing.assert_allclose(CYL.to_cylinder(1.0, VMAX, np.float64), CYL.to_cylinder(1.0, -VMAX, np.float64), atol=1e-12)


def test_track_follows_target_across_the_doppler_wrap():
    """A Doppler ramp crossing +v_max -> -v_max stays one track; in the flat (unwrapped) metric the
    jump of 2 v_max would exceed a tight gate."""
    cfg = AlphaBetaConfig(gate_radius=1.0)
    trk = AlphaBetaTracker(cfg, CYL)
    v = np.mod(3.0 + 0.4 * np.arange(30) + VMAX, 2 * VMAX) - VMAX  # wraps around twice
    r = 12.0 + 0.1 * np.arange(30)
    assert np.any(np.diff(v) < -VMAX)  # the ramp really wraps
    ids = set()
    for k in range(30):
        st = trk.step(k, meas([r[k]], [v[k]]))
        ids |= set(st.assigned)
        assert not st.dropped and not st.ended
    assert ids == {1} and len(trk.tracks) == 1
    tr = trk.tracks[0]
    rr, vv = CYL.from_cylinder(BenedictBordnerFilter.measurement_of(tr.state[None]))
    assert float(rr[0]) == pytest.approx(r[-1], abs=0.05)
    # the linear model lags a little on the circle (chord vs arc): less than one Doppler cell (0.5 km/h)
    assert float(vv[0]) == pytest.approx(v[-1], abs=0.5)
    assert math.hypot(tr.state[0], tr.state[2]) == pytest.approx(VMAX / math.pi, rel=1e-12)
    assert tr.vis == 29 and tr.age == 29


# --- association ----------------------------------------------------------------------------------

def _greedy_oracle(cost):
    c = np.array(cost, dtype=float)
    pairs = []
    while np.isfinite(c).any():
        best = None
        for i in range(c.shape[0]):
            for j in range(c.shape[1]):
                if np.isfinite(c[i, j]) and (best is None or c[i, j] < c[best]):
                    best = (i, j)
        pairs.append(best)
        c[best[0], :] = np.inf
        c[:, best[1]] = np.inf
    return pairs


def test_greedy_assign_is_greedy_not_optimal():
    cost = np.array([[1.0, 2.0], [1.5, 10.0]])
    rows, cols = greedy_assign(cost)
    assert list(zip(rows.tolist(), cols.tolist())) == [(0, 0), (1, 1)]
    r_opt, c_opt = linear_sum_assignment(cost)
    assert cost[r_opt, c_opt].sum() < cost[rows, cols].sum()  # Hungarian would pair differently


def test_greedy_assign_matches_oracle_with_infinities():
    rng = np.random.default_rng(7)
    for _ in range(200):
        n, m = rng.integers(0, 6, size=2)
        c = rng.random((n, m))
        c[rng.random((n, m)) < 0.3] = np.inf
        rows, cols = greedy_assign(c)
        assert list(zip(rows.tolist(), cols.tolist())) == _greedy_oracle(c)


def test_gate_uses_last_assigned_centroid():
    assoc = GreedyAssociator(6.0, "last_measurement")
    pred = np.array([[1.0, 0.0, 20.0]])
    last = np.array([[1.0, 0.0, 10.0]])
    cen = np.array([[1.0, 0.0, 15.9], [1.0, 0.0, 16.1], [1.0, 0.0, 20.0]])
    cost = assoc.cost_matrix(pred, last, cen)
    assert np.isfinite(cost[0, 0]) and cost[0, 0] == pytest.approx(4.1)
    assert np.isinf(cost[0, 1]) and np.isinf(cost[0, 2])  # 6.1 and 10 m from the last centroid
    cost_p = GreedyAssociator(6.0, "prediction").cost_matrix(pred, last, cen)
    assert np.all(np.isfinite(cost_p))


def test_centroid_outside_gate_starts_a_new_track():
    trk = AlphaBetaTracker(AlphaBetaConfig(), CYL)
    trk.step(0, meas([10.0], [1.0]))
    st = trk.step(1, meas([10.5, 17.0], [1.0, 1.0]))
    assert st.assigned == {1: 0, 2: 1}
    assert st.created == (2,)
    assert np.isinf(st.cost[0, 1]) and st.cost[0, 0] == pytest.approx(0.5)


def test_two_tracks_keep_their_centroids_in_any_order():
    trk = AlphaBetaTracker(AlphaBetaConfig(), CYL)
    trk.step(0, meas([5.0, 14.0], [-2.0, 3.0]))
    for k in range(1, 10):
        c = meas([5.0 + 0.2 * k, 14.0 - 0.3 * k], [-2.0, 3.0])
        st = trk.step(k, c[::-1] if k % 2 else c)
        want = {1: 1, 2: 0} if k % 2 else {1: 0, 2: 1}
        assert st.assigned == want


# --- counters and deletion ------------------------------------------------------------------------

def _run(trk, present):
    """Feed a single target (centroid when present[k]) and collect ended/dropped track ids."""
    ended, dropped = [], []
    for k, p in enumerate(present):
        st = trk.step(k, meas([10.0 + 0.1 * k], [1.0]) if p else np.zeros((0, 3)))
        ended += [t.track_id for t in st.ended]
        dropped += [t.track_id for t in st.dropped]
    return ended, dropped


def test_age_and_vis_counters():
    trk = AlphaBetaTracker(AlphaBetaConfig(), CYL)
    _run(trk, [1, 1, 0, 1, 1])
    tr = trk.tracks[0]
    assert (tr.age, tr.vis, tr.missed, tr.seen_frames) == (4, 3, 0, 4)


#: the paper's vis / age (the default counts the creation frame, see test_visibility_count_with_creation)
PAPER_VIS = AlphaBetaConfig(visibility_count="paper")


def test_track_missing_its_second_frame_is_deleted_by_th_v():
    trk = AlphaBetaTracker(PAPER_VIS, CYL)
    ended, dropped = _run(trk, [1, 0])
    assert (ended, dropped) == ([], [1]) and not trk.tracks  # vis / age = 0 / 1 < 0.25


def test_visibility_count_with_creation():
    """(vis + 1) / (age + 1): a new track survives its first misses while that is >= th_v = 0.25
    (1/2, 1/3, 1/4) and is deleted at the fourth (1/5), unless it is seen again."""
    trk = AlphaBetaTracker(AlphaBetaConfig(visibility_count="with_creation"), CYL)
    assert _run(trk, [1, 0, 0, 0]) == ([], []) and len(trk.tracks) == 1
    assert _run(trk, [0]) == ([], [1]) and not trk.tracks
    trk = AlphaBetaTracker(AlphaBetaConfig(visibility_count="with_creation"), CYL)
    _run(trk, [1, 0, 0, 0, 1, 0, 1])
    (tr,) = trk.tracks
    assert (tr.age, tr.vis, tr.seen_frames) == (6, 2, 3) and trk.confirmed() == [tr]


def test_departure_after_n_u_misses_and_the_three_frame_rule():
    cfg = PAPER_VIS
    # seen in 5 frames (vis 4), then 7 misses: vis/age = 4/11 >= 0.25 -> ends, classified
    trk = AlphaBetaTracker(cfg, CYL)
    ended, dropped = _run(trk, [1] * 5 + [0] * 6)
    assert (ended, dropped) == ([], []) and len(trk.tracks) == 1
    ended, dropped = _run(trk, [0])
    assert (ended, dropped) == ([1], [])
    # seen in 3 frames (vis 2): departs at the 7th miss although vis/age = 2/9 < th_v -- departure is
    # checked first (step 7) and the departed track is frozen, so it ends and is classified
    trk = AlphaBetaTracker(cfg, CYL)
    ended, dropped = _run(trk, [1] * 3 + [0] * 7)
    assert (ended, dropped) == ([1], [])
    # seen in 2 frames: departs too, but is dropped (fewer than 3 frames, step 9)
    trk = AlphaBetaTracker(cfg, CYL)
    ended, dropped = _run(trk, [1, 1, 0, 0, 0, 0, 0, 0, 0])
    assert (ended, dropped) == ([], [1])
    # still in the scene with vis/age < th_v: deleted before N_u (vis 1: age 4 -> 1/4 kept, age 5 -> 1/5)
    trk = AlphaBetaTracker(cfg, CYL)
    assert _run(trk, [1, 1, 0, 0, 0]) == ([], [])
    st = trk.step(5, np.zeros((0, 3)))
    assert [t.track_id for t in st.dropped] == [1] and st.dropped[0].missed == 4


def test_close_all_drops_tracks_seen_in_fewer_than_three_frames():
    trk = AlphaBetaTracker(AlphaBetaConfig(), CYL)
    trk.step(0, meas([5.0, 15.0], [1.0, -1.0]))
    trk.step(1, meas([5.1, 15.1], [1.0, -1.0]))
    trk.step(2, meas([5.2], [1.0]))  # track 2 misses once: vis/age = 1/2, kept
    assert [t.track_id for t in trk.confirmed()] == [1]
    ended, dropped = trk.close_all()
    assert [t.track_id for t in ended] == [1] and [t.track_id for t in dropped] == [2]
    assert not trk.tracks and len(trk.ids) == 0


def test_ids_are_small_and_recycled():
    trk = AlphaBetaTracker(PAPER_VIS, CYL)
    st = trk.step(0, meas([3.0, 10.0, 20.0], [0.0, 0.0, 0.0]))
    assert st.created == (1, 2, 3)
    trk.step(1, meas([3.0, 20.0], [0.0, 0.0]))  # track 2 deleted (th_v), id 2 is free again
    st = trk.step(2, meas([3.0, 20.0, 12.0], [0.0, 0.0, 0.0]))
    assert st.created == (2,)


def test_id_pool_exhaustion_is_counted():
    trk = AlphaBetaTracker(AlphaBetaConfig(max_track_id=2), CYL)
    st = trk.step(0, meas([3.0, 10.0, 20.0], [0.0, 0.0, 0.0]))
    assert st.created == (1, 2) and trk.ids_exhausted == 1
    pool = IdPool(3)
    assert [pool.acquire() for _ in range(4)] == [1, 2, 3, None]
    pool.release(2)
    assert pool.acquire() == 2


# --- co-range fragments ---------------------------------------------------------------------------

def test_corange_fragment_starts_no_track_and_is_reported_absorbed():
    """A second cluster at the target's range (its legs' wrapped micro-Doppler) starts no track; one
    0.6 m away (beyond corange_fragment_m = 0.5) does; with the option off (0) both start tracks."""
    trk = AlphaBetaTracker(AlphaBetaConfig(), CYL)
    trk.step(0, meas([12.0], [3.0]))
    st = trk.step(1, meas([11.9, 11.6], [3.1, -4.0]))  # 0.3 m apart: the legs of target 1
    assert st.assigned == {1: 0} and st.created == () and st.absorbed == {1: 1}
    st = trk.step(2, meas([11.8, 11.2], [3.1, -4.0]))  # 0.6 m: another target
    assert st.assigned == {1: 0, 2: 1} and st.created == (2,) and st.absorbed == {}
    off = AlphaBetaTracker(AlphaBetaConfig(corange_fragment_m=0.0), CYL)
    off.step(0, meas([12.0], [3.0]))
    st = off.step(1, meas([11.9, 11.6], [3.1, -4.0]))
    assert st.created == (2,) and st.absorbed == {}


def test_corange_centroid_goes_to_the_most_seen_track():
    """A young track (a fragment started before the target's track had frames) that is assigned a
    centroid at the range of an older track's centroid loses it to that track and coasts."""
    trk = AlphaBetaTracker(AlphaBetaConfig(corange_fragment_m=0.0), CYL)
    for k in range(4):
        trk.step(k, meas([15.0 - 0.4 * k], [3.0]))
    trk.step(4, meas([13.4, 13.3], [3.1, -4.0]))  # option off: the legs start track 2
    assert [t.track_id for t in trk.tracks] == [1, 2]
    trk.config = AlphaBetaConfig(corange_fragment_m=0.5)
    st = trk.step(5, meas([13.0, 12.9], [3.1, -4.0]))
    assert st.assigned == {1: 0} and st.absorbed == {1: 1}
    assert trk.tracks[1].missed == 1 and trk.tracks[0].missed == 0


def test_range_gate_keeps_a_slow_track_from_jumping_to_another_walker():
    """A walker's track (0.2 m per frame) misses a frame; a centroid 4 m from its prediction is inside
    R_gate = 6 (m | km/h) but outside the range gate 2.5 + 3 * 0.2 * 2 = 3.7 m: it starts its own
    track, while with the range gate off (paper) the walker's track takes it."""
    def run(cfg):
        trk = AlphaBetaTracker(cfg, CYL)
        for k in range(6):
            trk.step(k, meas([10.0 + 0.2 * k], [0.7]))
        trk.step(6, np.zeros((0, 3)))
        return trk.step(7, meas([11.4 + 4.0], [0.7]))

    st = run(AlphaBetaConfig())
    assert st.assigned == {2: 0} and st.created == (2,)
    st = run(AlphaBetaConfig(range_gate_m=0.0))
    assert st.assigned == {1: 0} and st.created == ()
