"""The compiled tracker core (edge.native._track) against its numpy reference (edge.track.pdaf, the duplicate test of
edge.track.roles.delete): the innovations and the duplicate test bit-identical, the per-hypothesis update equal to
rounding (RTOL), on random frames and on recorded ones; the lane pipeline's detections identical and its published
tracks the same to rounding (PUBLISHED_ATOL) with and without the kernels. Missing kernel: these tests fail, except under
RADAR_EDGE_KERNELS=0, where they skip."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge import native
from edge.track import PdafConfig, PdafTracker
from edge.track.pdaf import gate_threshold, innovations, innovations_each, mahalanobis_d2
from edge.track.synthetic import road_frames
from tests.edge.test_track_pregate import _random_frame

if not native.enabled():
    pytest.skip("RADAR_EDGE_KERNELS=0: the numpy reference runs, no kernel to compare", allow_module_level=True)

K = native.load("_track")
_FIELDS = ("v", "d2", "s", "s_inv", "det_s", "s_track")


@pytest.fixture(autouse=True)
def _kernel_built():
    """Every test here fails without the kernel (a comparison of numpy with itself would pass)."""
    assert K is not None, "edge.native._track is not built (pip install -e . with a C compiler)"


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in _FIELDS if hasattr(a, f))


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("t,m", [(90, 140), (30, 40), (5, 8), (1, 1), (0, 5), (4, 0)])
@pytest.mark.parametrize("n", [2, 3])
def test_innovations_each_is_bit_identical(seed, t, m, n):
    rng = np.random.default_rng(seed)
    z, zh, h, p, r_track, r_meas = _random_frame(rng, max(t, 1), max(m, 2))
    z, zh, h, p, r_track = z[:m, :n], zh[:t, :n], h[:t, :n], p[:t], r_track[:t, :n, :n]
    r_meas = np.ascontiguousarray(r_meas[:m, :n, :n])
    for prune in (None, gate_threshold(0.99, n)):
        ref = innovations_each(z, zh, h, p, r_track, r_meas, prune)
        assert _same(ref, innovations_each(z, zh, h, p, r_track, r_meas, prune, K))
    ref = innovations(z, zh, h, p, r_track)
    assert _same(ref, innovations(z, zh, h, p, r_track, kernel=K))
    assert np.array_equal(mahalanobis_d2(ref.v, ref.s), mahalanobis_d2(ref.v, ref.s, K))


def test_innovations_each_into_reused_buffers_is_bit_identical():
    """Frames of different sizes through one PairBuffers (grown, then reused with stale contents from a larger
    frame): each result equals the numpy reference; the views share the buffers; copies start empty."""
    import copy
    import pickle

    from edge.track.pdaf import PairBuffers

    buf = PairBuffers()
    rng = np.random.default_rng(7)
    shared = []
    for t, m, n in [(30, 40, 3), (90, 140, 3), (20, 10, 3), (90, 140, 2), (5, 8, 3), (0, 5, 3), (4, 0, 2)]:
        z, zh, h, p, r_track, r_meas = _random_frame(rng, max(t, 1), max(m, 2))
        z, zh, h, p, r_track = z[:m, :n], zh[:t, :n], h[:t, :n], p[:t], r_track[:t, :n, :n]
        r_meas = np.ascontiguousarray(r_meas[:m, :n, :n])
        for prune in (None, gate_threshold(0.99, n)):
            ref = innovations_each(z, zh, h, p, r_track, r_meas, prune)
            got = innovations_each(z, zh, h, p, r_track, r_meas, prune, K, buf)
            assert _same(ref, got)
            if t * m:
                shared.append(np.shares_memory(got.s, buf.views(1, 1, 1)[1]))
    assert all(shared) and len(shared) >= 8
    assert copy.deepcopy(buf)._flat is None and pickle.loads(pickle.dumps(buf))._flat is None
    args = (np.zeros((3, 2)), np.zeros((4, 2)), np.zeros((4, 2, 4)), np.zeros((4, 4, 4)), np.zeros((4, 2, 2)),
            np.zeros((3, 2, 2)), 1.0, False)
    for bad in ((np.zeros(23), np.zeros(48), np.zeros(48)), (np.zeros(24), np.zeros(47), np.zeros(48)),
                (np.zeros(24), np.zeros(48), np.zeros(48, np.float32)), (np.zeros(24), np.zeros(96)[::2], np.zeros(48)),
                (np.zeros(24), np.zeros(48))):
        with pytest.raises(ValueError, match="output buffer"):
            K.innovations_each(*args, bad)
    ro = np.zeros(48)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="output buffer"):
        K.innovations_each(*args, (np.zeros(24), ro, np.zeros(48)))
    for bad_h, bad_p in [(np.zeros((4, 2, 4)), np.zeros((3, 4, 4))), (np.zeros((4, 2, 3)), np.zeros((4, 4, 4))),
                         (np.zeros((4, 3, 4)), np.zeros((4, 4, 4))), (np.zeros((4, 2, 4)), np.zeros((4, 4, 3)))]:
        with pytest.raises(ValueError, match="inconsistent shapes"):
            K.innovations_each(np.zeros((3, 2)), np.zeros((4, 2)), bad_h, bad_p, np.zeros((4, 2, 2)),
                               np.zeros((3, 2, 2)), 1.0, False)


def _track_part(h, p, r_track):
    """The track part ``st`` of ``innovations_each``'s numpy reference: ``0.5 (a + a')``, ``a = H P H' + r_track``."""
    from edge.track.pdaf import hph_product

    a = hph_product(h, p) + r_track
    return 0.5 * (a + a.transpose(0, 2, 1))


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("n", [2, 3])
def test_hph_product_in_the_kernel_is_bit_identical(seed, n):
    """``H P H'`` of ``innovations_each``'s kernel against :func:`edge.track.pdaf.hph_product` (through ``st``) on
    random dense ``H`` and ``P`` of wide range (signs, zeros, signed zeros, inf, NaN), strided and in Fortran order;
    the explicit product equals numpy's matmul to rounding."""
    from edge.track.pdaf import hph_product

    rng = np.random.default_rng(seed)
    t = 50
    h = rng.normal(0, 1, (t, 3, 4)) * 10.0 ** rng.integers(-6, 6, (t, 3, 4))
    p = rng.normal(0, 1, (t, 4, 4)) * 10.0 ** rng.integers(-6, 6, (t, 4, 4))
    h[rng.random(h.shape) < 0.2] = 0.0
    h[rng.random(h.shape) < 0.05] = -0.0
    p[rng.random(p.shape) < 0.1] = -0.0
    hn, ha = h[:, :n], np.abs(h[:, :n])
    bound = ha @ np.abs(p) @ ha.transpose(0, 2, 1)  # the sum of the terms' magnitudes
    assert (np.abs(hph_product(hn, p) - hn @ p @ hn.transpose(0, 2, 1)) <= 1e-14 * bound).all()
    h[3, 0, 1], p[4, 2, 2], p[5, 0, 3] = np.inf, np.nan, -np.inf
    r_track = rng.normal(0, 1, (t, n, n))
    z, zh, rm = rng.normal(0, 1, (2, n)), rng.normal(0, 1, (t, n)), np.zeros((2, n, n))
    with np.errstate(invalid="ignore"):  # inf * 0
        ref = _track_part(h[:, :n], p, r_track)
    for hh, pp in [(h[:, :n], p), (np.ascontiguousarray(h[:, :n]), p[::-1].copy()[::-1]),
                   (np.asfortranarray(h[:, :n]), np.asfortranarray(p))]:
        st = K.innovations_each(z, zh, hh, pp, r_track, rm, 0.0, False)[5]
        assert st.tobytes() == ref.tobytes()


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=12, max_size=12),
       st.floats(1e-4, 1e4), st.floats(-0.99, 0.99))
def test_inverse_and_distance_of_one_pair_are_bit_identical(vals, scale, corr):
    """One pair, any 3x3 covariance with a correlation: the cofactor inverse and the quadratic form."""
    z = np.array([vals[:3]])
    zh = np.array([vals[3:6]])
    h = np.zeros((1, 3, 4))
    h[0, :3, :3] = np.diag(np.abs(vals[6:9]) * 1e-3 + 1.0)
    p = np.eye(4)[None] * scale
    r_track = np.diag(np.abs(vals[9:12]) + 0.1)[None].copy()
    r_track[0, 0, 1] = r_track[0, 1, 0] = corr * np.sqrt(r_track[0, 0, 0] * r_track[0, 1, 1])
    r_meas = np.eye(3)[None] * 0.5
    assert _same(innovations_each(z, zh, h, p, r_track, r_meas), innovations_each(z, zh, h, p, r_track, r_meas,
                                                                                  kernel=K))


def _tables(rng, t):
    """A track table of ``t`` tracks on four lanes, some pairs nearly alike (duplicates), some close in speed."""
    tr = PdafTracker(PdafConfig())
    base = np.column_stack([rng.choice([-5.25, -1.75, 1.75, 5.25], t), rng.uniform(10, 250, t),
                            rng.normal(0, 0.3, t), rng.choice([-25.0, 25.0], t) + rng.normal(0, 0.5, t)])
    twin = rng.uniform(size=t) < 0.3
    base[twin] = np.roll(base, 1, axis=0)[twin] + rng.normal(0, [0.3, 1.0, 0.2, 0.3], (int(twin.sum()), 4))
    base[rng.integers(0, t, 2)] = 0.0  # standing tracks: the common heading's floor
    p = np.eye(4)[None] * rng.uniform(0.05, 2.0, (t, 1, 1))
    tr.tracks.append(base, p, 1.0)
    tb = tr.tracks
    tb.confirmed[:] = rng.uniform(size=t) < 0.7
    tb.hits[:] = rng.integers(1, 30, t)
    tb.close_run[:] = rng.integers(0, 4, t)
    return tr.deleter, tb


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("t", [2, 3, 20, 64, 100])
@pytest.mark.parametrize("persist", [30, 2])
def test_duplicates_pair_test_is_identical(seed, t, persist):
    """The duplicate test with the kernel's pair tests and same-vehicle runs against numpy; with ``persist`` 2 the
    runs (0 to 3 frames before this one) decide for boxed pairs whose lateral speeds differ."""
    import dataclasses

    rng = np.random.default_rng(seed)
    deleter, tb = _tables(rng, t)
    deleter.cfg = dataclasses.replace(deleter.cfg, merge_persist_frames=persist)
    tb.x[rng.uniform(size=t) < 0.3, 2] += 3.0  # lateral speeds apart: boxed, yet two vehicles unless they persist
    assert deleter.kernel is K
    runs = tb.close_run.copy()
    pair = rng.integers(-1, 3, t)
    resolved = (pair, rng.integers(0, 5, t))
    for res in (None, resolved):
        tb.close_run = runs.copy()
        fast = deleter.duplicates(tb, res)
        fast_runs = tb.close_run.copy()
        tb.close_run = runs.copy()
        deleter.kernel = None
        try:
            ref = deleter.duplicates(tb, res)
        finally:
            deleter.kernel = K
        assert np.array_equal(fast, ref) and np.array_equal(fast_runs, tb.close_run)
    assert not fast.all() and (t < 20 or fast.any())  # tables with duplicates and distinct vehicles


def _pairs_frame(rng, n_rows: int, m: int, n: int):
    """Mode rows with states and covariances, detections, and validated pairs (1-3 per row, some rows none)."""
    xs = np.column_stack([rng.normal(0, 4, n_rows), rng.uniform(10, 250, n_rows), rng.normal(0, 0.5, n_rows),
                          rng.normal(0, 25, n_rows)])
    a = rng.normal(0, 1, (n_rows, 4, 4))
    ps = a @ a.transpose(0, 2, 1) * rng.uniform(0.05, 2.0, (n_rows, 1, 1)) + 0.01 * np.eye(4)
    from edge.track import kalman
    zh, h = kalman.measurement_prediction(xs, n == 3)
    r_track = np.zeros((n_rows, n, n))
    r_track[:, 0, 0] = r_track[:, 1, 1] = rng.uniform(0.2, 3.0, n_rows)
    r_track[:, 0, 1] = r_track[:, 1, 0] = rng.uniform(-0.1, 0.1, n_rows)
    if n == 3:
        r_track[:, 2, 2] = 0.09
    rows = np.sort(rng.integers(0, n_rows, 2 * n_rows))
    cols = rng.integers(0, m, rows.size)
    z = zh[rng.integers(0, n_rows, m)] + rng.normal(0, 1.0, (m, n))
    r_meas = np.zeros((m, n, n))
    r_meas[:, 0, 0], r_meas[:, 1, 1] = rng.uniform(0.05, 4.0, m), rng.uniform(0.05, 0.5, m)
    w = rng.uniform(0.0, 0.5, rows.size)
    w[rng.uniform(size=w.size) < 0.1] = 0.0  # underflowed weights
    return xs, ps, h, zh, r_track, z, r_meas, rows, cols, w


#: relative tolerance of the compiled per-hypothesis update against numpy (H P H' and the per-row sums are
#: summed in another order than numpy's BLAS products; measured: a few 1e-16, states 1e-12 m after 150 frames)
RTOL = 1e-12


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("n", [2, 3])
@pytest.mark.parametrize("scaled", [False, True])
def test_pair_update_equals_numpy_to_rounding(seed, n, scaled):
    from edge.track.pdaf import PairInnovations, combined_update_pairs, pair_innovations

    rng = np.random.default_rng(seed)
    xs, ps, h, zh, r_track, z, r_meas, rows, cols, w = _pairs_frame(rng, 40, 30, n)
    scale = np.where(rng.uniform(size=rows.size) < 0.5, 0.3, 1.0)
    pin = pair_innovations(z, zh, h, ps, r_track, r_meas, rows, cols, scale if scaled else None)
    pos = w > 0
    x_ref, p_ref = combined_update_pairs(xs, ps, h, PairInnovations(rows[pos], cols[pos], pin.v[pos], pin.d2[pos],
                                                                    pin.s_inv[pos], pin.det_s[pos]), w[pos])
    x, p, v, d2, det_s = K.pair_update(xs, ps, h, zh, r_track, z, r_meas, rows, cols,
                                       scale if scaled else np.zeros(0), scaled, w)
    assert np.array_equal(v, pin.v)
    np.testing.assert_allclose(d2, pin.d2, rtol=RTOL)
    np.testing.assert_allclose(det_s, pin.det_s, rtol=RTOL)
    np.testing.assert_allclose(x, x_ref, rtol=RTOL, atol=RTOL * np.abs(x_ref).max())
    np.testing.assert_allclose(p, p_ref, rtol=RTOL, atol=RTOL * np.abs(p_ref).max())
    assert np.array_equal(p, p.transpose(0, 2, 1))
    untouched = np.setdiff1d(np.arange(xs.shape[0]), rows[pos])
    assert untouched.size and np.array_equal(x[untouched], xs[untouched])
    x2, p2 = K.update_pairs(xs, ps, h, rows, pin.v, np.ascontiguousarray(pin.s_inv), w)
    np.testing.assert_allclose(x2, x_ref, rtol=RTOL, atol=RTOL * np.abs(x_ref).max())
    np.testing.assert_allclose(p2, p_ref, rtol=RTOL, atol=RTOL * np.abs(p_ref).max())


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("per_track_pi", [False, True])
def test_imm_cycle_equals_numpy_to_rounding(seed, per_track_pi):
    from edge.track import imm

    rng = np.random.default_rng(seed)
    t = 40
    xm = np.column_stack([rng.normal(0, 4, t), rng.uniform(10, 250, t), rng.normal(0, 0.5, t),
                          rng.normal(0, 25, t)])[:, None, :] + rng.normal(0, 0.3, (t, 2, 4))
    a = rng.normal(0, 1, (t, 2, 4, 4))
    pm = a @ a.swapaxes(-1, -2) + 0.01 * np.eye(4)
    mu = rng.uniform(0.001, 1.0, (t, 1))
    mu = np.hstack([mu, 1.0 - mu])
    pi = imm.switch_matrix(0.01, 0.1)
    if per_track_pi:
        pi = np.repeat(pi[None], t, axis=0)
        pi[:, 0, 1] = rng.uniform(0.001, 0.05, t)
        pi[:, 0, 0] = 1.0 - pi[:, 0, 1]
    f = np.stack([imm.keep_model(0.033, 0.1, 3.0, 0.01, 2.0)[0], np.eye(4) + np.diag([0.033, 0.033], 2)])
    q = np.stack([imm.keep_model(0.033, 0.1, 3.0, 0.01, 2.0)[1], 0.01 * np.eye(4)])
    x0, p0, c_ref = imm.mix(xm, pm, mu, pi)
    xpm_ref, ppm_ref = imm.predict_modes(x0, p0, f, q)
    x_ref, p_ref = imm.moment_match(xpm_ref, ppm_ref, c_ref)
    x, p, xpm, ppm, c = K.imm_predict(xm, pm, mu, pi if pi.ndim == 3 else pi[None], f, q)
    assert np.array_equal(c, c_ref)
    for got, ref in ((xpm, xpm_ref), (ppm, ppm_ref), (x, x_ref), (p, p_ref)):
        np.testing.assert_allclose(got, ref, rtol=RTOL, atol=RTOL * np.abs(ref).max())
    x2, p2 = K.moment_match(xpm_ref, ppm_ref, c_ref)
    np.testing.assert_allclose(x2, x_ref, rtol=RTOL, atol=RTOL * np.abs(x_ref).max())
    np.testing.assert_allclose(p2, p_ref, rtol=RTOL, atol=RTOL * np.abs(p_ref).max())


@pytest.mark.parametrize("near_factor", [0.0, 0.5, 1.0])
def test_imm_mode_update_on_recorded_frames_equals_numpy_to_rounding(near_factor):
    """The inputs of the IMM update as the tracker makes them (a 30-vehicle road after 40 frames, five frames):
    both modes' posteriors and likelihoods, kernel against numpy."""
    from edge.track.table import Measurements

    tr = PdafTracker(PdafConfig(extent_near_side_factor=near_factor))
    frames = list(road_frames(30, 45, clutter_per_frame=10.0, seed=5))
    for t_ns, det in frames[:40]:
        tr.step(det, t_ns)
    mm, checked = tr.measurement_model, 0
    for t_ns, det in frames[40:]:
        meas = Measurements.from_detections(det, True)
        dt = (t_ns - tr.last_t_ns) * 1e-9
        pred = tr.predictor.predict(tr.tracks, dt, 0.0)
        mp = mm.predict(pred, meas, tr.tracks.ext_var, tr.associator.prune_gamma(3))
        hyp = tr.associator.associate(meas, mp.inn, tr.tracks.confirmed, tr.tracks.hits)
        gamma = tr.associator.gamma(3)
        args = (pred, mp, meas, hyp.beta, hyp.beta0, hyp.gated, gamma, 0.9, 0.99)
        fast = mm.mode_update(*args)
        mm.kernel = None
        try:
            ref = mm.mode_update(*args)
        finally:
            mm.kernel = K
        for got, want in zip(fast, ref):
            np.testing.assert_allclose(got, want, rtol=RTOL, atol=RTOL * np.abs(want).max())
        checked += int(hyp.gated.sum())
        tr.step(det, t_ns)
    assert checked > 100


def test_lateral_line_on_recorded_frames_equals_numpy_to_rounding():
    """The straight-line lateral filter of every track on the tracker's own frames (30 vehicles, clutter), kernel
    against numpy on the same inputs each frame."""
    import copy

    from edge.track.roles.post import LateralSmoother

    tr = PdafTracker(PdafConfig())
    (smoother,) = [p for p in tr.post_steps if isinstance(p, LateralSmoother)]
    assert smoother.kernel is K
    run, checked = smoother.run, []

    def both(tracks, frame):
        ref = copy.deepcopy(tracks)
        smoother.kernel = None
        try:
            run(ref, frame)
        finally:
            smoother.kernel = K
        out = run(tracks, frame)
        for col in ("lat", "lat_p", "lat_cusum"):
            got, want = getattr(tracks, col), getattr(ref, col)
            np.testing.assert_allclose(got, want, rtol=RTOL, atol=RTOL * max(np.abs(want).max(initial=0.0), 1.0))
        checked.append(len(tracks))
        return out

    smoother.run = both
    for t_ns, det in road_frames(30, 60, clutter_per_frame=10.0, seed=7):
        tr.step(det, t_ns)
    assert sum(checked) > 1000


def _spd(rng, k: int, n: int, scale: float) -> np.ndarray:
    """(k, n, n) random symmetric positive definite matrices."""
    a = rng.normal(size=(k, n, n)) * scale
    return a @ a.transpose(0, 2, 1) + scale * scale * np.eye(n)


def _lateral_numpy(age, seed_var, lat, lat_p, dt, q, beta, z, r, rm, xp, pp, cusum, xs, ps, gamma, min_fraction,
                   cusum_nats, keep, hold_prob, unresolved):
    """LateralSmoother.run's numpy path on plain arrays: the seeding, ``LateralSmoother._line`` (the
    ``edge.track.kalman`` lateral functions) and the restarts."""
    from edge.track import kalman

    lat_p = lat_p.copy()
    new = age == 2
    lat_p[new, 1, 1] = np.minimum(lat_p[new, 1, 1], seed_var)
    lat_p[new, 0, 1] = lat_p[new, 1, 0] = 0.0
    ref, ref_p = xs[:, 0::2], ps[:, 0::2, 0::2]
    lat, lat_p = kalman.lateral_predict(lat, lat_p, dt, q)
    ti, mi = np.nonzero(beta > 0)
    if ti.size:
        var = r[ti, 0, 0] if rm is None else r[ti, 0, 0] + rm[mi, 0, 0]
        zz, w = z[mi, 0], beta[ti, mi]
        llr = kalman.lateral_log_likelihood_ratio(len(lat), ti, w, zz, var, lat[:, 0], lat_p[:, 0, 0], xp[:, 0],
                                                  pp[:, 0, 0])
        cusum = np.maximum(cusum + llr, 0.0)
        lat, lat_p = kalman.lateral_pda_update(lat, lat_p, zz, var, ti, w)
    off = kalman.lateral_inconsistent(lat, lat_p, ref, ref_p, gamma, min_fraction) | (cusum > cusum_nats)
    hold = None
    if keep is not None:
        hold = keep[0] > hold_prob
        off |= hold
    if unresolved is not None and beta.size and (beta > 0).any():
        best = np.argmax(beta, axis=1)
        off |= unresolved[best] & (beta[np.arange(beta.shape[0]), best] > 0.5)
    if off.any():
        lat[off], lat_p[off] = ref[off], ref_p[off]
        cusum = np.where(off, 0.0, cusum)
        if hold is not None and hold.any():
            _, xk, pk = keep
            lat[hold, 1] = xk[hold, 2]
            lat_p[hold, 1, 1] = pk[hold, 2, 2]
            lat_p[hold, 0, 1] = lat_p[hold, 1, 0] = pk[hold, 0, 2]
    return lat, lat_p, cusum


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("t,m", [(40, 30), (5, 8), (1, 1), (3, 0), (12, 2)])
@pytest.mark.parametrize("hold,unresolved,per_detection", [(True, True, True), (False, False, False),
                                                           (True, False, True), (False, True, False)])
def test_lateral_frame_equals_numpy_to_rounding(seed, t, m, hold, unresolved, per_detection):
    """``lateral_frame`` (the lateral smoother's whole frame) against the role's numpy path, on random frames with
    seeded lines, manoeuvre holds and unresolved carrying detections: equal to rounding."""
    rng = np.random.default_rng(seed)
    age = rng.integers(1, 5, t).astype(np.int32)
    lat = rng.normal(size=(t, 2)) * [3.0, 1.0]
    lat_p = _spd(rng, t, 2, 0.5)
    beta = np.where(rng.random((t, m)) < 0.3, rng.random((t, m)), 0.0)
    beta[rng.random((t, m)) < 0.1] = 0.9  # carrying detections (> 0.5), some tied
    n = 3 if per_detection else 2
    z = rng.normal(size=(m, n)) * 3.0
    r = _spd(rng, t, n, 0.4)
    rm = _spd(rng, m, n, 0.3) if per_detection else None
    xp, xs = rng.normal(size=(t, 4)) * 3.0, rng.normal(size=(t, 4)) * 3.0
    pp, ps = _spd(rng, t, 4, 0.6), _spd(rng, t, 4, 0.6)
    cusum = np.where(rng.random(t) < 0.5, rng.random(t) * 8.0, 0.0)
    keep = (rng.random(t), rng.normal(size=(t, 4)), _spd(rng, t, 4, 0.5)) if hold else None
    unr = rng.random(m) < 0.4 if unresolved else None
    args = (age, 0.09, lat, lat_p, 1 / 30, 0.2, beta, z, r, rm, xp, pp, cusum, xs, ps, 6.6, 0.1, 5.0)
    want = _lateral_numpy(*args, keep, 0.6, unr)
    no_keep = (np.zeros(0), np.zeros((0, 4)), np.zeros((0, 4, 4)))
    got = K.lateral_frame(*args[:9], np.zeros((0, 1, 1)) if rm is None else rm, rm is not None, *args[10:],
                          keep is not None, *(no_keep if keep is None else keep), 0.6, unr is not None,
                          np.zeros(0, bool) if unr is None else unr)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=RTOL, atol=RTOL * max(np.abs(w).max(initial=0.0), 1.0))
    assert np.array_equal(lat_p, args[3])  # the inputs are not written


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("t", [0, 1, 7, 64])
def test_delete_tests_are_identical(seed, t):
    """``delete_tests`` against the deleter's numpy tests, ``TrackDeleter._position_spread`` and
    ``SameVehicleBox.along_m`` on random tables (standing, slow and fast tracks, some out of the field, a few NaN
    covariances): identical."""
    from edge.track.roles.delete import TrackDeleter
    from edge.track.table import TrackTable

    rng = np.random.default_rng(seed)
    tr = PdafTracker(PdafConfig())
    deleter = tr.deleter
    tb = TrackTable()
    tb.x = np.column_stack([rng.normal(0.0, 40.0, t), rng.uniform(-5.0, 320.0, t),
                            rng.choice([0.0, 0.4, 3.0, -25.0], t) * rng.random(t),
                            rng.choice([0.0, 0.7, 30.0, -30.0], t) * rng.random(t)])
    tb.p = _spd(rng, t, 4, 1.5)
    tb.p[rng.random(t) < 0.1, 1, 1] = np.nan
    tb.misses = rng.integers(0, 12, t).astype(np.int32)
    tb.ext_var = rng.random(t) * 4.0
    tb.close_run = np.zeros(t, np.int32)
    tb.confirmed = rng.random(t) < 0.5
    tb.hits, tb.age = rng.integers(1, 20, t).astype(np.int32), rng.integers(20, 40, t).astype(np.int32)
    c, fov, box = deleter.cfg, deleter.fov, deleter.box
    dead, pdx, pdy, along = K.delete_tests(tb.x, tb.p, tb.misses, tb.ext_var, c.delete_after_misses,
                                           c.max_position_sigma_m, fov.min_range_m, fov.max_range_m,
                                           math.radians(fov.max_azimuth_deg), box.cfg.merge_along_m,
                                           box.cfg.merge_headway_s, box.cfg.merge_extent_factor)
    deleter.kernel = None
    try:
        want = deleter.delete(tb)  # the numpy tests (no duplicate on one track or none)
    finally:
        deleter.kernel = K
    if t >= 2:  # the numpy deleter's answer includes the duplicates (close runs restarted as it left them)
        tb.close_run = np.zeros(t, np.int32)
        dead = dead | deleter.duplicates(tb)
    assert np.array_equal(dead, want)
    want_dx, want_dy = TrackDeleter._position_spread(tb)
    assert np.array_equal(pdx, want_dx, equal_nan=True) and np.array_equal(pdy, want_dy, equal_nan=True)
    assert np.array_equal(along, box.along_m(tb))
    assert t < 64 or 0 < dead.sum() < t  # some tracks die, some live


def test_delete_with_the_kernel_is_identical():
    """The deleter's whole step (tests, duplicates, close runs) with and without the kernel on the tracker's own
    tables (30 vehicles with clutter, 40 frames)."""
    import copy

    tr = PdafTracker(PdafConfig())
    deleter, checked = tr.deleter, []
    run = deleter.delete

    def both(tracks, resolved=None):
        ref = copy.deepcopy(tracks)
        deleter.kernel = None
        try:
            want = run(ref, resolved)
        finally:
            deleter.kernel = K
        got = run(tracks, resolved)
        assert np.array_equal(got, want) and np.array_equal(tracks.close_run, ref.close_run)
        checked.append(len(tracks))
        return got

    deleter.delete = both
    for t_ns, det in road_frames(30, 40, clutter_per_frame=10.0, seed=3):
        tr.step(det, t_ns)
    assert sum(checked) > 500


def _same_measurements(a, b) -> bool:
    return (np.array_equal(a.z, b.z) and a.z.dtype == b.z.dtype and np.array_equal(a.snr_db, b.snr_db)
            and a.with_radial_speed == b.with_radial_speed
            and all((u is None and v is None) or (u is not None and v is not None and np.array_equal(u, v)
                                                  and u.dtype == v.dtype)
                    for u, v in ((a.pair, b.pair), (a.unresolved, b.unresolved))))


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("m", [0, 1, 6, 40])
@pytest.mark.parametrize("use_radial_speed", [True, False])
def test_measurements_are_identical(seed, m, use_radial_speed):
    """``Measurements.from_detections`` with the ``measurements`` kernel against its numpy form on random float32
    detections: some at the radar (ground range below 1e-6 m), resolved and unresolved pairs or none, a NaN or an
    infinity in some frames (the numpy form then runs), float64 columns (likewise): identical."""
    from edge.track.table import Measurements
    from edge.types import Detections

    rng = np.random.default_rng(seed)
    f32 = np.float32
    x = (rng.normal(0.0, 20.0, m) * (rng.random(m) > 0.15)).astype(f32)
    y = (rng.uniform(0.0, 250.0, m) * (rng.random(m) > 0.15)).astype(f32)
    det = Detections(np.hypot(x, y).astype(f32) + f32(0.5), rng.normal(0.0, 20.0, m).astype(f32),
                     np.arctan2(x, y).astype(f32), rng.uniform(5.0, 40.0, m).astype(f32), x, y)
    if seed % 4 == 1:
        det.extra["resolved_pair"] = np.where(rng.random(m) < 0.3, rng.integers(0, 3, m), -1).astype(np.int32)
        det.extra["unresolved_pair"] = rng.random(m) < 0.3
    elif seed % 4 == 2:
        det.extra["resolved_pair"] = np.full(m, -1, np.int32)
        det.extra["unresolved_pair"] = np.zeros(m, bool)
    if seed % 4 == 3 and m:
        bad = rng.integers(0, m)
        det.snr_db[bad] = np.inf
        det.radial_speed_mps[rng.integers(0, m)] = np.nan
    want = Measurements.from_detections(det, use_radial_speed)
    got = Measurements.from_detections(det, use_radial_speed, K)
    assert _same_measurements(got, want)
    if seed % 4 != 3 or not m:
        assert K.measurements(det.x_m, det.y_m, det.snr_db, det.radial_speed_mps, det.range_m,
                              use_radial_speed) is not None  # the kernel answered
    wide = Detections(*(c.astype(np.float64) for c in (det.range_m, det.radial_speed_mps, det.az_rad, det.snr_db,
                                                       det.x_m, det.y_m)), det.extra)
    assert _same_measurements(Measurements.from_detections(wide, use_radial_speed, K), want)
    cols = (det.range_m, det.radial_speed_mps, det.az_rad, det.snr_db, det.x_m, det.y_m)
    if seed % 4 == 1 and m:  # the extra columns in other forms: int64 (kept as it is), a list, mis-sized
        pair = det.extra["resolved_pair"]
        for other in (pair.astype(np.int64), pair.tolist(), np.zeros(m + 1, np.int32), pair.astype(np.int16)):
            alt = Detections(*cols, dict(det.extra, resolved_pair=other))
            got = Measurements.from_detections(alt, use_radial_speed, K)
            assert _same_measurements(got, Measurements.from_detections(alt, use_radial_speed))
            if isinstance(other, np.ndarray) and other.dtype == np.int64 and got.pair is not None:
                assert got.pair is other
        alt = Detections(*cols, dict(det.extra, unresolved_pair=det.extra["unresolved_pair"].astype(np.uint8)))
        assert _same_measurements(Measurements.from_detections(alt, use_radial_speed, K),
                                  Measurements.from_detections(alt, use_radial_speed))
    if m:  # strided and byte-swapped float32 columns
        for form in (lambda c: np.repeat(c, 2)[::2], lambda c: c.astype(">f4")):
            alt = Detections(*(form(c) for c in cols), det.extra)
            assert _same_measurements(Measurements.from_detections(alt, use_radial_speed, K), want)


#: absolute tolerance on published positions (m), speeds (m/s), their sds and the existence probability between
#: the kernel and numpy paths (measured: 6e-13 over 7000 published tracks, IMM and CV)
PUBLISHED_ATOL = 1e-9
_EXACT = ("track_id", "age_frames", "hits", "confirmed", "lane", "cls")


def assert_same_published(fast, ref):
    """The same tracks (ids, ages, hits, confirmation exact) with every float within PUBLISHED_ATOL."""
    assert len(fast) == len(ref)
    for a, b in zip(fast, ref):
        da, db = vars(a), vars(b)
        assert da.keys() == db.keys()
        for key in da:
            if key in _EXACT or da[key] is None or db[key] is None:
                assert da[key] == db[key], key
            else:
                assert abs(da[key] - db[key]) <= PUBLISHED_ATOL, (key, da[key], db[key])


def numpy_only(tracker: PdafTracker) -> PdafTracker:
    """The tracker with every role on its numpy reference."""
    tracker.measurement_model.kernel = tracker.deleter.kernel = tracker.associator.kernel = None
    tracker.initiator.kernel = tracker.kernel = tracker.confirmer.kernel = None
    for role in (tracker.predictor, tracker.updater):
        if hasattr(role, "kernel"):
            role.kernel = None
    return tracker


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("t,m", [(20, 30), (64, 140), (3, 12)])
def test_seed_block_is_identical(seed, t, m):
    """The initiator's test of detections against the tracks' same-vehicle boxes (and radial speeds)."""
    from edge.track.table import Measurements

    rng = np.random.default_rng(seed)
    deleter, tb = _tables(rng, t)
    z = np.column_stack([tb.x[rng.integers(0, t, m), :2] + rng.normal(0, 3.0, (m, 2)), rng.normal(0, 25, m)])
    tr = PdafTracker(PdafConfig())
    assert tr.initiator.kernel is K
    for pair in (None, rng.integers(-3, 2, m)):
        meas = Measurements(z, rng.uniform(5, 30, m), True, pair)
        resolved = meas.pair >= 0 if meas.pair is not None else np.zeros(m, bool)
        fast = tr.initiator._near_kernel(tb, meas, resolved)
        assert np.array_equal(fast, tr.initiator._near(tb, meas, resolved))
        assert not fast.all()
    assert t < 20 or fast.any()


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("t,m", [(20, 30), (64, 140), (3, 12), (0, 6), (5, 0)])
@pytest.mark.parametrize("radial", [True, False])
def test_seed_candidates_are_identical(seed, t, m, radial):
    """The initiator's candidate seeds (claimed, resolved, in range, moving, outside the tracks' boxes) with the
    ``seed_candidates`` kernel against the numpy form: the same rows and resolved flags."""
    from edge.track.table import Measurements

    rng = np.random.default_rng(seed)
    deleter, tb = _tables(rng, max(t, 1))
    if t == 0:
        tb.keep(np.zeros(1, bool))
    rows = rng.integers(0, max(t, 1), m)
    z = np.column_stack([tb.x[rows, :2] if t else rng.normal(0, 30.0, (m, 2)), rng.normal(0, 25, m)])
    z[:, :2] += rng.normal(0, 3.0, (m, 2))
    z[rng.random(m) < 0.1, 1] = rng.choice([0.5, 400.0])  # out of the field's range
    z[rng.random(m) < 0.1, 2] = 0.1  # standing
    z = z if radial else np.ascontiguousarray(z[:, :2])
    init = PdafTracker(PdafConfig()).initiator
    assert init.kernel is K
    used = rng.random(m) < 0.4
    for pair in (None, rng.integers(-3, 2, m)):
        meas = Measurements(z, rng.uniform(5, 30, m), radial, pair)
        idx, resolved = init.candidates(tb, meas, used)
        init.kernel = None
        try:
            want_idx, want_resolved = init.candidates(tb, meas, used)
        finally:
            init.kernel = K
        assert idx.dtype == want_idx.dtype and np.array_equal(idx, want_idx)
        assert resolved.dtype == want_resolved.dtype and np.array_equal(resolved, want_resolved)
    assert m < 30 or 0 < idx.size < m  # some detections seed, some do not


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("t,m", [(30, 40), (5, 1), (1, 6), (0, 4)])
def test_carrying_pairs_are_identical(seed, t, m):
    """``resolved_pairs`` with the ``carrying_pairs`` kernel against its numpy form (``np.argmax`` and the 0.5 test)
    on random weights with ties, rows of zeros, weights of exactly 0.5 and NaN: the same pairs and detections."""
    from edge.track.roles.delete import resolved_pairs

    rng = np.random.default_rng(seed)
    beta = np.where(rng.random((t, m)) < 0.4, rng.choice([0.2, 0.5, 0.7, 0.9], (t, m)), 0.0)
    if t and seed % 2:
        beta[rng.integers(0, t), rng.integers(0, m)] = np.nan
    pair = rng.integers(-1, 3, m).astype(np.int64)
    want = resolved_pairs(pair, beta)
    got = resolved_pairs(pair, beta, K)
    assert len(got) == len(want) == 2
    for g, w in zip(got, want):
        assert g.dtype == w.dtype and np.array_equal(g, w)
    assert resolved_pairs(None, beta, K) is None and resolved_pairs(pair[:0], beta[:, :0], K) is None
    assert t < 30 or (got[0] >= 0).any()  # some tracks are carried by a resolved detection


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("t,m", [(30, 40), (4, 0), (0, 3), (7, 2)])
def test_count_hits_is_identical(seed, t, m):
    """The tracker's hit count (``hit = gated.any(axis=1)``, ``TrackTable.count``) with the ``count_hits`` kernel
    against numpy on random tables (long miss runs, full histories): the same hits and columns."""
    from edge.track.table import TrackTable

    rng = np.random.default_rng(seed)
    gated = rng.random((t, m)) < 0.05
    cols = dict(age=rng.integers(1, 500, t).astype(np.int32), hits=rng.integers(1, 400, t).astype(np.int32),
                misses=rng.integers(0, 30, t).astype(np.int32),
                history=rng.integers(0, 2**32, t, dtype=np.uint64).astype(np.uint32))
    ref, fast = TrackTable(), TrackTable()
    for k, v in cols.items():
        setattr(ref, k, v.copy())
        setattr(fast, k, v.copy())
    hit = gated.any(axis=1)
    ref.count(hit)
    got, fast.misses, fast.history = K.count_hits(gated, fast.age, fast.hits, fast.misses, fast.history)
    assert got.dtype == hit.dtype and np.array_equal(got, hit)
    for k in cols:
        a, b = getattr(fast, k), getattr(ref, k)
        assert a.dtype == b.dtype and np.array_equal(a, b), k
    assert t < 30 or 0 < hit.sum() < t


def _copy_table(tb):
    import copy
    return copy.deepcopy(tb)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("method", ["pdaf", "jpda"])
@pytest.mark.parametrize("t,m", [(90, 140), (20, 16), (12, 1), (1, 5), (3, 3)])
def test_association_is_bit_identical(seed, method, t, m):
    """Gate, seniority, gate volumes and PDAF/JPDA weights; some tentative tracks, some resolved pairs."""
    from edge.track.config import AssociationConfig, section
    from edge.track.roles.associate import PdaAssociator
    from edge.track.table import Measurements

    rng = np.random.default_rng(seed)
    z, zh, h, p, r_track, r_meas = _random_frame(rng, t, max(m, 2))
    z, r_meas = z[:m], np.ascontiguousarray(r_meas[:m])
    a = PdaAssociator(section(PdafConfig(association=method), AssociationConfig))
    assert a.kernel is K
    inn = innovations_each(z, zh, h, p, r_track, r_meas, gate_threshold(0.99, 3), K)
    confirmed = rng.uniform(size=t) < 0.6
    hits = rng.integers(1, 5, t)
    for pair in (None, rng.integers(-3, 2, m)):
        for conf in (confirmed, np.ones(t, bool)):
            meas = Measurements(z, np.zeros(m), True, pair)
            fast = a.associate(meas, inn, conf, hits)
            vol_fast, inn.gate_volume = inn.gate_volume, None
            a.kernel = None
            try:
                ref = a.associate(meas, inn, conf, hits)
            finally:
                a.kernel = K
            assert np.array_equal(fast.gated, ref.gated)
            assert np.array_equal(fast.beta, ref.beta) and np.array_equal(fast.beta0, ref.beta0)
            assert np.array_equal(vol_fast, inn.gate_volume)
    assert t * m < 100 or ref.gated.sum() >= 5  # frames with validated pairs


def _run_tracker(frames, use_kernels: bool, motion: str = "imm"):
    tr = PdafTracker(PdafConfig(motion_model=motion))
    if not use_kernels:
        numpy_only(tr)
    out = []
    for t_ns, det in frames:
        out.append(tr.step(det, t_ns))
    return out


@pytest.mark.parametrize("motion", ["imm", "cv"])
def test_tracker_on_a_busy_road_is_identical_with_the_kernels(motion):
    """48 vehicles and clutter (the pre-gate on, thousands of pairs): the same published tracks, to rounding."""
    frames = list(road_frames(48, 90, clutter_per_frame=15.0, seed=3))
    fast = _run_tracker(frames, True, motion)
    ref = _run_tracker(frames, False, motion)
    assert sum(len(o) for o in ref) > 48 * 40
    for a, b in zip(fast, ref):
        assert_same_published(a, b)


def test_lane_pipeline_confirmed_tracks_identical(monkeypatch):
    """highway4-traffic seed 1, 120 frames through the lane pipeline with and without the compiled kernels:
    the same detections, bit for bit, and the same published tracks, to rounding."""
    from edge.bench import board_of, synth_frames
    from edge.config import load_config
    from edge.pipeline import StageTimer, build_pipeline

    frames = synth_frames(board_of("lane"), "highway4-traffic", 1, 120)
    fe = frames[0].frontend

    def run():
        pipe = build_pipeline("lane", fe, load_config(env={}))
        out = [pipe.process(f, StageTimer(16)) for f in frames]
        pipe.close()
        return out

    fast = run()
    monkeypatch.setenv("RADAR_EDGE_KERNELS", "0")
    ref = run()
    n_conf = 0
    for a, b in zip(fast, ref):
        for col in ("x_m", "y_m", "radial_speed_mps", "snr_db"):
            assert np.array_equal(getattr(a.detections, col), getattr(b.detections, col))
        assert_same_published(a.tracks, b.tracks)
        n_conf += sum(1 for t in a.tracks if t.confirmed)
    assert n_conf > 500  # a busy road: the comparison covers many confirmed tracks


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("t,m", [(30, 40), (64, 140), (5, 7), (3, 0)])
@pytest.mark.parametrize("per_pair", [True, False])
def test_update_extent_is_bit_identical(seed, t, m, per_pair):
    """The along-heading spread learnt from a frame: the kernel sums in numpy's order (pairwise over the
    detections), so the result is the same bit for bit."""
    mm, xp, ext_var, inn, beta = _extent_case(np.random.default_rng(seed), t, m, per_pair)
    assert mm.kernel is K
    fast = mm.update_extent(xp, ext_var, inn, beta)
    mm.kernel = None
    ref = mm.update_extent(xp, ext_var, inn, beta)
    assert np.array_equal(fast, ref)
    assert m == 0 or (fast != ext_var).any()  # some tracks learnt


def _extent_case(rng, t, m, per_pair):
    from edge.track.roles.measure import SnrNoiseModel, ConstantNoiseModel
    from edge.track.config import MeasurementConfig, section
    from edge.track.pdaf import Innovations

    cfg = section(PdafConfig(), MeasurementConfig)
    mm = SnrNoiseModel(cfg) if per_pair else ConstantNoiseModel(cfg)
    xp = np.column_stack([rng.normal(0, 4, t), rng.uniform(10, 250, t), rng.normal(0, 0.5, t),
                          rng.choice([-25.0, 0.3, 25.0], t) + rng.normal(0, 0.5, t)])
    v = rng.normal(0, 1.5, (t, m, 3))
    a = rng.normal(0, 1, (t, m, 3, 3) if per_pair else (t, 3, 3))
    s = a @ a.swapaxes(-1, -2) + np.eye(3)
    beta = np.where(rng.uniform(size=(t, m)) < 0.2, rng.uniform(0, 1, (t, m)), 0.0)
    beta[rng.uniform(size=t) < 0.3] *= 0.1  # some tracks with little weight (no update)
    inn = Innovations(v, np.zeros((t, m)), s, s, np.ones(s.shape[:-2]))
    return mm, xp, rng.uniform(0.1, 4.0, t), inn, beta


def _published_both(tr: PdafTracker):
    """(kernel, numpy) results of ``tr.published()`` on the same table, and both paths' motion-model x."""
    fast = tr.published()
    fast_x = tr.published_motion_x_m
    tr.kernel = None
    try:
        ref = tr.published()
    finally:
        tr.kernel = K
    return fast, ref, fast_x, tr.published_motion_x_m


@pytest.mark.parametrize("smoother,length,tentative,motion", [
    (True, True, False, "imm"), (False, True, False, "imm"), (True, False, True, "cv"), (False, False, True, "cv")])
def test_published_is_bit_identical(smoother, length, tentative, motion):
    """``PdafTracker.published`` from the ``publish_rows`` kernel against numpy on the tracker's own tables (30
    vehicles with clutter, every frame): every field exactly equal, None where numpy has None."""
    tr = PdafTracker(PdafConfig(motion_model=motion, lateral_smoother=smoother, publish_length=length,
                                publish_tentative=tentative))
    assert tr.kernel is K
    n, blended, lengths = 0, 0, 0
    for t_ns, det in road_frames(30, 70, clutter_per_frame=10.0, seed=11):
        tr.step(det, t_ns)
        fast, ref, fx, rx = _published_both(tr)
        assert [vars(a) for a in fast] == [vars(b) for b in ref]
        assert (fx is None and rx is None) or np.array_equal(fx, rx)
        n += len(ref)
        blended += int(smoother and (tr.tracks.lat_cusum != 0).any())
        lengths += sum(1 for b in ref if b.length_m is not None)
    assert n > 30 * 30
    assert not smoother or blended > 10  # the lateral blend ran
    assert not length or lengths > 300


@pytest.mark.parametrize("motion", ["imm", "cv"])
def test_measurement_prediction_is_bit_identical(motion):
    """``MeasurementModel.predict`` (SNR noise model) from the ``measure_predict`` kernel against numpy on the
    tracker's own predictions each frame (30 vehicles with clutter): z_hat, H, the track's R, the modes' z_hat and H,
    the heading kept for the extent update and the innovations (``S`` with its ``H P H'``), all exactly equal."""
    tr = PdafTracker(PdafConfig(motion_model=motion))
    mm = tr.measurement_model
    assert mm.kernel is K and mm.per_detection
    predict, checked = mm.predict, []

    def both(pred, meas, ext_var, prune_gamma=None):
        mm.kernel = None
        try:
            ref = predict(pred, meas, ext_var, prune_gamma)
            head_ref = mm._head
        finally:
            mm.kernel = K
        out = predict(pred, meas, ext_var, prune_gamma)
        for f in ("zh", "h", "r", "rm", "zhm", "hm"):
            a, b = getattr(out, f), getattr(ref, f)
            assert (a is None and b is None) or np.array_equal(a, b), f
        assert _same(out.inn, ref.inn)  # v, d2, S, S^-1, |S| and the track part (H P H' in the kernel)
        assert mm._head[0] is head_ref[0] and all(np.array_equal(a, b) for a, b in zip(mm._head[1], head_ref[1]))
        checked.append(len(pred.x) * (out.zh.shape[1] == 3))
        return out

    mm.predict = both
    for t_ns, det in road_frames(30, 60, clutter_per_frame=10.0, seed=5):
        tr.step(det, t_ns)
    assert sum(checked) > 1000  # with the radial-speed row


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("n", [2, 3])
def test_detection_noise_is_bit_identical(seed, n):
    """The SNR model's per-detection sensor noise (``snr_noise``) against ``kalman.snr_polar_noise`` on random
    detections: SNRs below, inside and above the clip range, positions at and near the radar; every row, subsets."""
    from edge.track.table import Measurements

    rng = np.random.default_rng(seed)
    m = 200
    z = np.column_stack([rng.normal(0, 30, m), rng.uniform(-5, 250, m), rng.normal(0, 25, m)])[:, :n]
    z[:3, :2] = [[0.0, 0.0], [1e-7, 0.0], [0.0, -1e-7]]
    meas = Measurements(z, rng.uniform(-20.0, 90.0, m), n == 3)
    mm = PdafTracker(PdafConfig()).measurement_model
    assert mm.kernel is K
    rows = rng.choice(m, 40, replace=False)
    fast = (mm.of_detections(meas), mm.of_detections(meas, 2, rows=rows))
    mm.kernel = None
    ref = (mm.of_detections(meas), mm.of_detections(meas, 2, rows=rows))
    for a, b in zip(fast, ref):
        assert a.shape == b.shape and np.array_equal(a, b)


@pytest.mark.parametrize("confirmation,keep_from", [("m_of_n", 200.0), ("m_of_n", 0.0), ("score", 200.0),
                                                    ("either", 60.0)])
def test_moving_and_expired_is_identical(confirmation, keep_from):
    """The confirmer's moving flags and expired tentative tracks from the ``moving_expired`` kernel against numpy
    (``update_moving``, ``tentative_expired``) on the tracker's own tables each frame (30 vehicles with clutter)."""
    import copy

    tr = PdafTracker(PdafConfig(confirmation=confirmation, tentative_keep_from_m=keep_from))
    conf = tr.confirmer
    assert conf.kernel is K
    run, expired_total, moved_total = conf.moving_and_expired, [0], [0]

    def both(tracks):
        ref = copy.deepcopy(tracks)
        conf.kernel = None
        try:
            want = run(ref)
        finally:
            conf.kernel = K
        got = run(tracks)
        assert got.dtype == want.dtype == bool and np.array_equal(got, want)
        assert np.array_equal(tracks.moved, ref.moved)
        expired_total[0] += int(want.sum())
        moved_total[0] += int(ref.moved.sum())
        return got

    conf.moving_and_expired = both
    for t_ns, det in road_frames(30, 70, clutter_per_frame=12.0, seed=9):
        tr.step(det, t_ns)
    assert expired_total[0] > 20 and moved_total[0] > 500


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("t,m", [(90, 140), (30, 40), (5, 8), (1, 1), (3, 0)])
@pytest.mark.parametrize("n", [2, 3])
def test_seed_exclusion_claimed_is_identical(seed, t, m, n):
    """The claimed detections of the constant-noise exclusion gate: the kernel's inverse, distances and test equal
    ``(mahalanobis_d2(v, S) <= gamma).any(axis=0)``, also for thresholds right at a pair's distance."""
    rng = np.random.default_rng(seed)
    z, zh, h, p, r_track, r_meas = _random_frame(rng, t, max(m, 2))
    v = np.ascontiguousarray(z[None, :m, :n] - zh[:, None, :n])
    s = np.ascontiguousarray((h @ p @ h.transpose(0, 2, 1) + r_track)[:, :n, :n])
    s[:, 0, 1] += rng.normal(0, 1e-3, t)  # not quite symmetric: the general cofactors, as inv_det
    d2 = mahalanobis_d2(v, s)
    gammas = [gate_threshold(0.999, n), 1e-3, np.inf] + ([float(np.median(d2))] if d2.size else [])
    for gamma in gammas:
        got = K.claimed_any(v, s, gamma)
        assert got.dtype == np.uint8
        assert np.array_equal(got.view(bool), (d2 <= gamma).any(axis=0))


@pytest.mark.parametrize("seed", range(4))
def test_mode_probabilities_and_moment_match(seed):
    """The IMM's mode probabilities bit-identical to numpy (floor, underflow to 0 and NaN rows included), the
    moment-matched state equal to rounding."""
    from edge.track import imm

    rng = np.random.default_rng(seed)
    t = 50
    c = rng.uniform(0.0, 1.0, (t, 1))
    c = np.hstack([c, 1.0 - c])
    lik = rng.uniform(0.0, 5.0, (t, 2)) * 10.0 ** rng.uniform(-300, 3, (t, 1))
    lik[0] = 0.0
    lik[1, 1] = np.nan
    lik[2] = [1e-320, 0.0]
    xm = rng.normal(0, 10, (t, 2, 4))
    a = rng.normal(0, 1, (t, 2, 4, 4))
    pm = a @ a.swapaxes(-1, -2) + 0.01 * np.eye(4)
    mu, x, p = K.mode_probabilities_match(c, lik, 1e-3, xm, pm)
    mu_ref = imm.update_mode_probabilities(c, lik, 1e-3)
    assert np.array_equal(mu, mu_ref, equal_nan=True)
    ok = np.isfinite(mu_ref).all(axis=1)
    assert ok.sum() == t - 1
    x_ref, p_ref = imm.moment_match(xm[ok], pm[ok], mu_ref[ok])
    np.testing.assert_allclose(x[ok], x_ref, rtol=1e-12, atol=1e-12 * np.abs(x_ref).max())
    np.testing.assert_allclose(p[ok], p_ref, rtol=1e-12, atol=1e-12 * np.abs(p_ref).max())


@pytest.mark.parametrize("seed", range(3))
def test_imm_predict_with_far_switch_equals_numpy(seed):
    """The switching matrices built in the kernel from the tracks' ranges (``x_far``) equal
    ``ImmPredictor._far_switch``: the predicted mode probabilities bit-identical, the prediction to rounding; ranges
    before, inside and beyond the fall, and one track on the radar."""
    from edge.track import imm
    from edge.track.config import MotionConfig
    from edge.track.roles.predict import ImmPredictor

    cfg = MotionConfig()
    assert cfg.imm_far_p_keep_to_manoeuvre < cfg.imm_p_keep_to_manoeuvre  # the default uses the far switch
    pred = ImmPredictor(cfg)
    rng = np.random.default_rng(seed)
    t = 60
    x = np.column_stack([rng.normal(0, 4, t), rng.uniform(0, 300, t), rng.normal(0, 0.5, t), rng.normal(0, 25, t)])
    x[0, :2] = 0.0
    x[1, :2] = [0.0, cfg.imm_far_from_m]
    x[2, :2] = [0.0, cfg.imm_far_to_m]
    xm = x[:, None, :] + rng.normal(0, 0.3, (t, 2, 4))
    a = rng.normal(0, 1, (t, 2, 4, 4))
    pm = a @ a.swapaxes(-1, -2) + 0.01 * np.eye(4)
    mu = rng.uniform(0.001, 1.0, (t, 1))
    mu = np.hstack([mu, 1.0 - mu])
    f = np.stack([imm.keep_model(0.033, 0.1, 3.0, 0.01, 2.0)[0], np.eye(4) + np.diag([0.033, 0.033], 2)])
    q = np.stack([imm.keep_model(0.033, 0.1, 3.0, 0.01, 2.0)[1], 0.01 * np.eye(4)])
    pi = pred._far_switch(np.hypot(x[:, 0], x[:, 1]))
    ref = K.imm_predict(xm, pm, mu, pi, f, q)
    got = K.imm_predict(xm, pm, mu, np.ascontiguousarray(pred.pi[None]), f, q, x, cfg.imm_far_from_m,
                        max(cfg.imm_far_to_m - cfg.imm_far_from_m, 1e-9), math.log(cfg.imm_p_keep_to_manoeuvre),
                        math.log(cfg.imm_far_p_keep_to_manoeuvre))
    assert np.array_equal(got[4], ref[4])  # c: the switching matrices were the same
    for g, r in zip(got, ref):
        assert np.array_equal(g, r)  # the same kernel arithmetic after the switch
    x0, p0, c_ref = imm.mix(xm, pm, mu, pi)
    assert np.array_equal(got[4], c_ref)


@pytest.mark.parametrize("seed", range(4))
def test_keep_model_into_is_identical(seed):
    """``keep_model_into`` writes ``imm.keep_model``'s F and Q into the first mode bit for bit (yaw either side of the
    boresight, no decay with tau 0) and leaves the other mode alone."""
    from edge.track import imm

    rng = np.random.default_rng(seed)
    for _ in range(50):
        dt, yaw = rng.uniform(0.001, 0.2), rng.uniform(-1.5, 1.5)
        tau = 0.0 if rng.uniform() < 0.2 else rng.uniform(0.1, 10.0)
        q_across, q_along = rng.uniform(0.0, 0.1), rng.uniform(0.0, 5.0)
        f = rng.normal(0, 1, (2, 4, 4))
        q = rng.normal(0, 1, (2, 4, 4))
        other = f[1].copy(), q[1].copy()
        K.keep_model_into(f, q, dt, yaw, tau, q_across, q_along, dt**3 / 3.0, dt**2 / 2.0)
        f_ref, q_ref = imm.keep_model(dt, yaw, tau, q_across, q_along)
        assert f[0].tobytes() == f_ref.tobytes() and q[0].tobytes() == q_ref.tobytes()
        assert np.array_equal(f[1], other[0]) and np.array_equal(q[1], other[1])


@pytest.mark.parametrize("seed", range(4))
def test_imm_seeded_is_identical(seed):
    """``ImmPredictor.seeded`` with the ``imm_seeded`` kernel against its numpy lines on a table whose last rows are
    new seeds: the mode probabilities, the lane-keeping mode's covariance and the combined one bit for bit, with one
    speed variance for all seeds, one per seed, none (no radial speed) and the lateral speed sd off."""
    import copy
    from edge.track.config import MotionConfig
    from edge.track.roles.predict import ImmPredictor
    from edge.track.table import TrackTable

    rng = np.random.default_rng(seed)
    t, k = 12, 5
    base = TrackTable()
    a = rng.normal(0, 1, (t, 4, 4))
    base.append(rng.normal(0, 30, (t, 4)), a @ a.swapaxes(-1, -2) + np.eye(4), 1.0)
    for sigma in (0.5, 0.0):
        pred = ImmPredictor(MotionConfig(imm_keep_init_lateral_speed_sigma_mps=sigma, imm_init_keep_prob=0.8))
        assert pred.kernel is K
        for speed_var in (2.25, rng.uniform(0.5, 9.0, k), None):
            yaw = rng.uniform(-0.5, 0.5)
            fast, ref = copy.deepcopy(base), copy.deepcopy(base)
            pred.seeded(fast, k, yaw, speed_var)
            pred.kernel = None
            try:
                pred.seeded(ref, k, yaw, speed_var)
            finally:
                pred.kernel = K
            for c in ("mu", "pm", "p", "x", "xm"):
                assert getattr(fast, c).tobytes() == getattr(ref, c).tobytes(), (c, sigma, speed_var)
            assert not np.array_equal(fast.mu, base.mu)
            assert (sigma == 0 or speed_var is None) == np.array_equal(fast.pm, base.pm)


def test_imm_predict_takes_strided_tracks():
    """The tracks' columns as views with strides (a table's rows, every other one): the same bits as contiguous."""
    from edge.track import imm

    rng = np.random.default_rng(3)
    t = 30
    xm = rng.normal(0, 5, (2 * t, 2, 4))
    a = rng.normal(0, 1, (2 * t, 2, 4, 4))
    pm = a @ a.swapaxes(-1, -2) + 0.01 * np.eye(4)
    mu = rng.uniform(0.001, 1.0, (2 * t, 1))
    mu = np.hstack([mu, 1.0 - mu])
    x = rng.normal(0, 100, (2 * t, 4))
    f = np.stack([imm.keep_model(0.033, 0.1, 3.0, 0.01, 2.0)[0], np.eye(4) + np.diag([0.033, 0.033], 2)])
    q = np.stack([imm.keep_model(0.033, 0.1, 3.0, 0.01, 2.0)[1], 0.01 * np.eye(4)])
    pi = np.ascontiguousarray(imm.switch_matrix(0.02, 0.1)[None])
    far = (100.0, 120.0, math.log(0.02), math.log(0.002))
    got = K.imm_predict(xm[::2], pm[::2], mu[::2], pi, f, q, x[::2], *far)
    want = K.imm_predict(*(np.ascontiguousarray(c[::2]) for c in (xm, pm, mu)), pi, f, q,
                         np.ascontiguousarray(x[::2]), *far)
    assert all(g.tobytes() == w.tobytes() for g, w in zip(got, want))
    with pytest.raises(ValueError, match="inconsistent shapes"):
        K.imm_predict(xm[::2], pm[1::2][:-1], mu[::2], pi, f, q)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("receding_only", [True, False])
@pytest.mark.parametrize("height_above_m,target_height_m", [(0.0, None), (5.0, None), (5.0, 0.5)])
def test_reanchor_match_is_identical(seed, receding_only, height_above_m, target_height_m):
    """Re-anchoring's matches (missed confirmed tracks and their nearest unclaimed detection) from the kernel equal
    the numpy reference ``Reanchor.matches``, on frames built so that many tracks have candidates, with and without
    the scatterer height's widening of the speed test."""
    from dataclasses import replace
    from types import SimpleNamespace

    from edge.track.config import ReanchorConfig, SameVehicleConfig
    from edge.track.roles.box import SameVehicleBox
    from edge.track.roles.post import Reanchor

    cfg = replace(ReanchorConfig(), reanchor_receding_only=receding_only)
    if cfg.reanchor_m <= 0:
        cfg = replace(cfg, reanchor_m=8.0)
    role = Reanchor(cfg, SameVehicleBox(SameVehicleConfig(), 1.0),
                    SimpleNamespace(height_above_target_m=height_above_m, target_height_m=target_height_m), 2.0)
    k, k_slow = role.height_speed_k
    assert k == 2.0 * height_above_m and k_slow == (k if target_height_m is None else target_height_m * height_above_m)
    rng = np.random.default_rng(seed)
    t, m = 60, 80
    # ranges from under the mounting, where the widening is metres per second, to far away
    x = np.column_stack([rng.normal(0, 3, t), rng.uniform(8, 80, t), rng.normal(0, 0.3, t), rng.normal(0, 20, t)])
    near = rng.integers(0, t, m)  # detections a little nearer than some track, at about its radial speed
    rho = np.hypot(x[near, 0], x[near, 1])
    vr = (x[near, 0] * x[near, 2] + x[near, 1] * x[near, 3]) / rho
    back = rng.uniform(-1.0, cfg.reanchor_m + 2.0, m)
    z = np.column_stack([x[near, 0] * (rho - back) / rho + rng.normal(0, 0.5, m), x[near, 1] * (rho - back) / rho,
                         vr + rng.normal(0, 3.0 if height_above_m else 0.5, m)])
    z[:4] = z[4:8]  # equally near duplicates: the first wins
    tracks = SimpleNamespace(x=x, confirmed=rng.uniform(size=t) < 0.8)
    gated = rng.uniform(size=(t, m)) < 0.005
    frame = SimpleNamespace(meas=SimpleNamespace(z=z), hyp=SimpleNamespace(gated=gated),
                            hit=gated.any(axis=1) | (rng.uniform(size=t) < 0.2))
    role.min_range_m = 3.0  # some detections lie nearer: they never match
    ref = role.matches(tracks, frame)
    args = (receding_only, cfg.reanchor_min_m, cfg.reanchor_m, role.box.cfg.merge_lateral_m, k, role.min_range_m,
            k_slow)
    i, j = K.reanchor_match(x, tracks.confirmed, frame.hit, gated, z, cfg.reanchor_speed_mps, *args)
    assert ref is not None and ref[0].size >= 2  # the frame exercises the matching
    assert np.array_equal(i, ref[0]) and np.array_equal(j, ref[1]) and i.dtype == j.dtype == np.int64
    # strided columns give the same rows; no missed confirmed track: empty int64 rows
    i2, j2 = K.reanchor_match(np.repeat(x, 2, axis=1)[:, ::2], tracks.confirmed, frame.hit, gated,
                              np.repeat(z, 2, axis=0)[::2], cfg.reanchor_speed_mps, *args)
    assert np.array_equal(i2, i) and np.array_equal(j2, j)
    i0, j0 = K.reanchor_match(x, tracks.confirmed, np.ones(t, bool), gated, z, cfg.reanchor_speed_mps, *args)
    assert i0.shape == j0.shape == (0,) and i0.dtype == j0.dtype == np.int64


def test_a_failing_measurements_kernel_is_not_hidden():
    """The ``measurements`` kernel declines columns by their dtype (it returns None) and raises no error for them: an
    error inside the kernel reaches the caller, and float64 columns go to the numpy form."""
    from types import SimpleNamespace

    from edge.track.table import Measurements
    from edge.types import Detections

    def boom(*_):
        raise ValueError("kernel failure")

    f32 = np.float32
    det = Detections(*(np.array([30.0, 60.0], f32) for _ in range(6)))
    with pytest.raises(ValueError, match="kernel failure"):
        Measurements.from_detections(det, True, SimpleNamespace(measurements=boom))
    wide = Detections(*(np.array([30.0, 60.0]) for _ in range(6)))
    assert K.measurements(wide.x_m, wide.y_m, wide.snr_db, wide.radial_speed_mps, wide.range_m, True) is None
    assert Measurements.from_detections(wide, True, K).z.shape == (2, 3)  # the numpy form


@pytest.mark.parametrize("height_m", [0.0, 6.5])
@pytest.mark.parametrize("confirmation", ["m_of_n", "score", "either"])
def test_confirming_is_identical(confirmation, height_m):
    """The rows the confirmer confirms: the ``confirm_ready`` kernel against :meth:`Confirmer.confirming_numpy`, on
    the tracker's own tables each frame (30 vehicles with clutter) and on random tables with ties at every
    threshold of the block test, NaN states and standing confirmed tracks; without and with the radar's height
    above the scatterers (the speed tests' height term)."""
    from types import SimpleNamespace

    tr = PdafTracker(PdafConfig(confirmation=confirmation), height_above_target_m=height_m)
    conf = tr.confirmer
    assert conf.kernel is K
    seen = {"rows": 0, "frames": 0}
    confirm = conf.confirm

    def both(tracks, ids):
        got = conf.confirming(tracks)
        want = conf.confirming_numpy(tracks)
        assert isinstance(got, list) and got == want.tolist()
        seen["rows"] += len(got)
        seen["frames"] += 1
        return confirm(tracks, ids)

    conf.confirm = both
    for t_ns, det in road_frames(30, 70, clutter_per_frame=12.0, seed=9):
        tr.step(det, t_ns)
    assert seen["rows"] > 20 and seen["frames"] > 60

    c, box = conf.cfg, conf.box.cfg
    rng = np.random.default_rng(5)
    blocked = 0
    for trial in range(300):
        t = int(rng.integers(0, 12))
        x = rng.normal(0.0, 1.0, (t, 4)) * np.array([3.0, 20.0, 2.0, 10.0])
        if trial % 2:  # one platoon: most pairs within the block test's box
            x = rng.normal(0.0, 1.0, (t, 4)) * np.array([1.5, 8.0, 0.5, 1.5]) + np.array([0.0, 0.0, 0.0, 25.0])
        if t > 1:  # ties: a row's offsets to another exactly at the block test's limits
            j, k = rng.choice(t, 2, replace=False)
            x[j] = x[k]
            for col, lim in ((1, c.confirm_block_along_m), (0, box.merge_lateral_m), (0, c.confirm_block_lateral_m),
                             (1, c.confirm_block_behind_m)):
                if rng.uniform() < 0.3:
                    x[j, col] = x[k, col] + lim
            if rng.uniform() < 0.3:
                x[k, 2:4] = 0.0  # a standing confirmed track: heading (0, 0)
            if rng.uniform() < 0.2:
                x[int(rng.integers(t)), int(rng.integers(4))] = np.nan
        tracks = SimpleNamespace(
            x=x, history=rng.integers(0, 2**32, t, dtype=np.uint32),
            confirmed=rng.uniform(size=t) < 0.5, moved=rng.uniform(size=t) < 0.8,
            score=rng.normal(conf.confirmed_log_odds, 2.0, t))
        if t:
            tracks.score[int(rng.integers(t))] = conf.confirmed_log_odds
            tracks.score[int(rng.integers(t))] = np.nan
        got = conf.confirming(tracks)
        assert got == conf.confirming_numpy(tracks).tolist()
        blocked += int(np.count_nonzero(conf._ready(tracks) & tracks.moved)) - len(got)
    assert blocked > 30


def _columns(rng, t):
    """Arrays shaped and typed like the track table's columns, ``t`` rows."""
    return [rng.normal(size=(t, 4)), rng.normal(size=(t, 4, 4)), rng.integers(-5, 5, t, dtype=np.int32),
            rng.integers(0, 2**32, t, dtype=np.uint32), rng.uniform(size=t) < 0.5, rng.normal(size=(t, 2, 4)),
            rng.normal(size=(t, 2, 4, 4)), np.full(t, np.nan), rng.normal(size=(t, 0))]


def _identical(a, b) -> bool:
    return (a.dtype == b.dtype and a.shape == b.shape and a.flags.c_contiguous == b.flags.c_contiguous
            and a.tobytes() == b.tobytes())


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("t,k", [(0, 0), (0, 3), (5, 0), (7, 2), (40, 9)])
def test_concat_rows_is_identical(seed, t, k):
    """``concat_rows`` against ``np.concatenate`` pair by pair: the same dtype, shape and bytes, also for strided and
    Fortran-ordered parts, a part of another dtype (numpy's promotion) or of another row shape (numpy's error)."""
    rng = np.random.default_rng(seed)
    olds, news = _columns(rng, t), _columns(rng, k)
    news[0] = rng.normal(size=(k, 8))[:, 0::2]  # strided, like the straight-line filter's x[:, 0::2]
    news[1] = np.asfortranarray(news[1])
    olds[3] = olds[3][::-1]  # a negative stride in a column
    news[7] = news[7].astype(np.float32)  # promoted by np.concatenate
    got = K.concat_rows(olds, news)
    assert len(got) == len(olds)
    for a, b, g in zip(olds, news, got):
        want = np.concatenate([a, b])
        assert _identical(g, want) and g.flags.writeable and not np.shares_memory(g, a)
    with pytest.raises(ValueError):
        K.concat_rows([np.zeros((t, 4))], [np.zeros((k, 3))])


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("t", [0, 1, 6, 40])
def test_take_rows_is_identical(seed, t):
    """``take_rows`` against ``take(rows, axis=0)``: the same dtype, shape and bytes for every column, rows from a
    mask, repeated or unordered, a strided column; an index out of range raises IndexError."""
    rng = np.random.default_rng(seed)
    cols = _columns(rng, t)
    cols.append(rng.normal(size=(t, 6))[:, ::2])
    masks = [rng.uniform(size=t) < 0.7, np.zeros(t, bool), np.ones(t, bool)]
    row_sets = [m.nonzero()[0] for m in masks] + ([rng.integers(0, t, 2 * t)] if t else [])
    for rows in row_sets:
        for a, g in zip(cols, K.take_rows(cols, rows)):
            assert _identical(g, a.take(rows, axis=0)) and g.flags.writeable
    for bad in ([t], [-1]):
        with pytest.raises(IndexError):
            K.take_rows(cols[:1], np.array(bad, dtype=np.intp))


def test_track_table_append_and_keep_with_the_kernel_are_identical():
    """The track table's ``append`` and ``keep`` with the kernel give the same columns (dtype, shape, bytes) as without,
    over a run of seeding and deleting."""
    from edge.track.table import TrackTable

    assert tuple(c[0] for c in K._TABLE_COLUMNS) == TrackTable._COLUMNS
    rng = np.random.default_rng(3)
    fast, ref = TrackTable(), TrackTable()
    for step in range(40):
        k = int(rng.integers(0, 5))
        x, p = rng.normal(size=(k, 4)), rng.normal(size=(k, 4, 4))
        if step % 3 == 1:  # strided and Fortran-ordered states, signed zeros and NaN
            x, p = rng.normal(size=(k, 8))[:, ::2], np.asfortranarray(p)
            if k:
                x[0, 0], p[0, 2, 2] = -0.0, np.nan
        ext, keep_prob = float(rng.choice([1.0, 2.5])), float(rng.choice([0.5, 0.8]))
        fast.append(x, p, ext, keep_prob, kernel=K)
        ref.append(x, p, ext, keep_prob)
        for tb in (fast, ref):  # the columns change between frames as the tracker changes them
            tb.score = tb.score + 0.25 * step
        mask = rng.uniform(size=len(ref)) < 0.8
        fast.keep(mask, K)
        ref.keep(mask)
        for c in TrackTable._COLUMNS:
            assert _identical(getattr(fast, c), getattr(ref, c)), c
    assert len(ref) > 3
    # a column of another dtype or byte order: append_rows declines, the columns are joined as numpy joins them
    for other in (fast.score.astype(np.float32), fast.score.astype(">f8")):
        fast.score, ref.score = other, other.copy()
        assert not K.append_rows(fast, x, p, 1.0, 0.5)
        fast.append(x, p, 1.0, kernel=K)
        ref.append(x, p, 1.0)
        for c in TrackTable._COLUMNS:
            assert _identical(getattr(fast, c), getattr(ref, c)), c


def _state_bits(s) -> list:
    """A TrackState's ``__dict__`` as (key, type, value) in key order, floats by their bit pattern."""
    return [(k, type(v), np.float64(v).view(np.uint64).item() if isinstance(v, float) else v)
            for k, v in vars(s).items()]


@pytest.mark.parametrize("plain", [True, False])
@pytest.mark.parametrize("smoother,length,tentative", [(True, True, False), (False, False, True)])
def test_published_states_are_bit_identical(monkeypatch, plain, smoother, length, tentative):
    """The TrackStates the ``publish_states`` kernel makes (and, for a TrackState that is not the plain dataclass,
    those made from ``publish_rows``) against numpy's: the same type, the same ``__dict__`` keys in the same order,
    the same value types, floats bit for bit."""
    import edge.track.tracker as tracker_mod
    from edge.types import TrackState

    monkeypatch.setattr(tracker_mod, "_TRACK_STATE_PLAIN", plain)
    tr = PdafTracker(PdafConfig(lateral_smoother=smoother, publish_length=length, publish_tentative=tentative))
    n = 0
    for t_ns, det in road_frames(30, 50, clutter_per_frame=10.0, seed=12):
        tr.step(det, t_ns)
        fast, ref, fx, rx = _published_both(tr)
        assert type(fast) is tuple and len(fast) == len(ref)
        for a, b in zip(fast, ref):
            assert type(a) is TrackState and _state_bits(a) == _state_bits(b)
        assert (fx is None and rx is None) or np.array_equal(fx, rx)
        n += len(ref)
    assert n > 20 * 30


def test_published_from_strided_columns_is_bit_identical():
    """``publish_table`` reads the track table's columns through their strides: every column a strided view (every
    other row of a doubled array) gives numpy's TrackStates bit for bit."""
    from edge.track.table import TrackTable

    tr = PdafTracker(PdafConfig())
    frames = list(road_frames(20, 45, clutter_per_frame=10.0, seed=13))
    for t_ns, det in frames:
        tr.step(det, t_ns)
    for c in TrackTable._COLUMNS:
        a = getattr(tr.tracks, c)
        setattr(tr.tracks, c, np.repeat(a, 2, axis=0)[::2])
    assert not tr.tracks.x.flags.c_contiguous
    fast, ref, fx, rx = _published_both(tr)
    assert len(ref) > 10 and [_state_bits(a) for a in fast] == [_state_bits(b) for b in ref]
    assert np.array_equal(fx, rx)


def _polar_points(rng, t):
    """Ground states (T, 4) for the converted polar noise: spread, at the radar, NaN, signed zeros."""
    xp = np.column_stack([rng.normal(0, 20, t), rng.uniform(-5, 300, t), rng.normal(0, 3, (t, 2))])
    if t > 3:
        xp[0, :2] = 0.0
        xp[1, :2] = (-0.0, 0.0)
        xp[2, :2] = (3e-7, -2e-7)  # inside the 1e-6 floor of the range
        xp[3, 0] = np.nan
    return xp


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("t", [0, 1, 7, 60])
def test_polar_noise_is_identical(seed, t):
    """``polar_noise`` gives ``kalman.polar_position_noise``'s noise bit for bit (NaN included), from strided states;
    that function's explicit product equals numpy's matmul ``J diag(d) J'`` to rounding."""
    from edge.track import kalman

    rng = np.random.default_rng(seed)
    xp = _polar_points(rng, t)
    var_r, var_az, f = 0.3**2, math.radians(1.5)**2, 0.4
    rr = K.polar_noise(xp, var_r, var_az, f**2)
    want = kalman.polar_position_noise(xp[:, :2], 0.3, math.radians(1.5), f)
    assert rr.shape == want.shape and rr.dtype == want.dtype and rr.tobytes() == want.tobytes()
    r = np.hypot(xp[:, 0], xp[:, 1])
    sn, cs = xp[:, 0] / np.maximum(r, 1e-6), xp[:, 1] / np.maximum(r, 1e-6)
    j = np.stack([np.column_stack([sn, r * cs]), np.column_stack([cs, -r * sn])], axis=1)
    blas = (j * np.array([var_r, var_az])) @ j.transpose(0, 2, 1) + f**2 * np.eye(2)
    fin = np.isfinite(want).all(axis=(1, 2))
    np.testing.assert_allclose(want[fin], blas[fin], rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("height", [0.0, 6.5])
@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("t,m", [(30, 40), (5, 8), (1, 1), (3, 0), (0, 4)])
@pytest.mark.parametrize("n", [2, 3])
def test_claimed_any_polar_is_identical(seed, t, m, n, height):
    """``claimed_any_polar`` against ``claimed_any`` with the ``S`` of ``MeasurementModel.with_sensor`` and against
    numpy's ``(mahalanobis_d2(v, S) <= gamma).any(axis=0)``, also at thresholds right at a pair's distance; with the
    radar ``height`` above the assumed scatterers, the scatterer height's term included."""
    from edge.track.config import MeasurementConfig, section
    from edge.track.roles.measure import SnrNoiseModel

    rng = np.random.default_rng(seed)
    mm = SnrNoiseModel(section(PdafConfig(), MeasurementConfig))
    mm.height_above_target_m = height
    c = mm.cfg
    dz, h_var = height, PdafConfig().scatterer_height_sigma_m**2
    xp = _polar_points(rng, t)
    if t > 3:
        xp[3, 0] = 1.0  # no NaN here: a NaN S claims nothing either way, but the sweep below wants finite distances
    a = rng.normal(0, 1, (t, n, n))
    s_track = a @ a.swapaxes(-1, -2) + np.eye(n)
    v = rng.normal(0, 3.0, (t, m, n))
    s = mm.with_sensor(xp, s_track, h_var)
    d2 = mahalanobis_d2(v, s)
    for gamma in [gate_threshold(0.999, n), 1e-3, np.inf] + ([float(np.median(d2))] if d2.size else []):
        got = K.claimed_any_polar(v, s_track, xp, c.range_sigma_m**2, math.radians(c.azimuth_sigma_deg)**2,
                                  c.extent_sigma_m**2, gamma, dz, h_var)
        assert got.dtype == np.uint8
        assert np.array_equal(got, K.claimed_any(v, s, gamma))
        assert np.array_equal(got.view(bool), (d2 <= gamma).any(axis=0))


@pytest.mark.parametrize("height", [0.0, 6.5])
def test_seed_exclusion_claimed_on_tracker_frames_is_identical(height):
    """The tracker's claimed detections (constant-noise exclusion gate) with the kernels against the numpy form on
    its own frames (30 vehicles with clutter), with and without the scatterer height's term."""
    tr = PdafTracker(PdafConfig(), height_above_target_m=height)
    mm = tr.measurement_model
    assert mm.kernel is K and tr.associator.cfg.seed_exclusion_noise == "constant"
    claimed, seen = tr.associator.claimed, [0, 0]

    def both(mp, xp, model):
        got = claimed(mp, xp, model)
        mm.kernel = None
        try:
            want = claimed(mp, xp, model)
        finally:
            mm.kernel = K
        assert got.dtype == want.dtype == bool and np.array_equal(got, want)
        seen[0] += int(got.sum())
        seen[1] += got.size
        return got

    tr.associator.claimed = both
    for t_ns, det in road_frames(30, 60, clutter_per_frame=12.0, seed=4):
        tr.step(det, t_ns)
    assert seen[0] > 300 and seen[1] > seen[0]


def _same_var_s(a, b) -> bool:
    if a is None or b is None or isinstance(a, float) or isinstance(b, float):
        return type(a) is type(b) and (a is None or a == b)
    return a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("k", [1, 3, 12])
@pytest.mark.parametrize("radial", [True, False])
def test_seed_states_are_identical(seed, k, radial):
    """New tracks' states, covariances and speed variances from the ``seed_states`` kernel against
    :meth:`SeedInitiator.seed_states_numpy`, bit for bit: seeds beside the radar across the road (``|e_s . p|`` at
    and below 1), NaN, negative zeros, strided noise, road yaws of either sign."""
    tr = PdafTracker(PdafConfig())
    ini = tr.initiator
    assert ini.kernel is K
    rng = np.random.default_rng(seed)
    for yaw in (0.0, 0.2, -0.35, math.pi / 2):
        seeds = np.column_stack([rng.normal(0, 5, k), rng.uniform(-3, 250, k), rng.normal(0, 20, k)])
        if k > 2:
            cy, sy = math.cos(yaw), math.sin(yaw)
            seeds[0, :2] = (0.0, 1.0 / cy) if abs(cy) > 0.5 else (-1.0 / sy, 0.0)  # |e_s . p| = 1 (to rounding)
            seeds[1, :2] = (-0.0, 0.3)  # beside the radar
            seeds[2, int(rng.integers(3))] = np.nan
        if not radial:
            seeds = seeds[:, :2]
        r = np.ascontiguousarray(rng.normal(0, 1, (k, 3, 3)))[:, :2, :2]  # strided, like rm[rows, :2, :2]
        got = ini.seed_states(seeds, r, yaw, radial)
        ini.kernel = None
        try:
            want = ini.seed_states(seeds, r, yaw, radial)
        finally:
            ini.kernel = K
        for a, b in zip(got[:2], want[:2]):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
        assert _same_var_s(got[2], want[2])


def test_seed_states_on_tracker_frames_are_identical():
    """The initiator's new tracks with and without the kernel on the tracker's own frames (30 vehicles with clutter)."""
    tr = PdafTracker(PdafConfig())
    ini = tr.initiator
    seed_states, seen = ini.seed_states, [0]

    def both(seeds, r, yaw, radial):
        got = seed_states(seeds, r, yaw, radial)
        ini.kernel = None
        try:
            want = seed_states(seeds, r, yaw, radial)
        finally:
            ini.kernel = K
        for a, b in zip(got[:2], want[:2]):
            assert a.tobytes() == b.tobytes()
        assert _same_var_s(got[2], want[2])
        seen[0] += seeds.shape[0]
        return got

    ini.seed_states = both
    for t_ns, det in road_frames(30, 60, clutter_per_frame=12.0, seed=6):
        tr.road_yaw_rad = 0.05 * math.sin(t_ns * 1e-9)
        tr.step(det, t_ns)
    assert seen[0] > 100


def test_kernel_arrays_are_read_with_their_strides_and_checked():
    """The kernels read their arrays through the numpy C API (edge/native/_views.pxi): strided columns give the same
    bits as contiguous ones; another dtype, byte order, a read-only output column, a non-array, or a non-contiguous
    array where the kernel needs a contiguous one are refused."""
    rng = np.random.default_rng(5)
    t, m = 12, 7
    gated = rng.random((2 * t, 2 * m)) < 0.2
    cols = [rng.integers(1, 50, 2 * t).astype(np.int32) for _ in range(3)] + [
        rng.integers(0, 2**32, 2 * t, dtype=np.uint64).astype(np.uint32)]
    age, hits = cols[0][::2].copy(), cols[1][::2].copy()
    want = K.count_hits(np.ascontiguousarray(gated[::2, ::2]), age, hits, cols[2][::2].copy(), cols[3][::2].copy())
    age_s, hits_s = cols[0].copy(), cols[1].copy()
    got = K.count_hits(gated[::2, ::2], age_s[::2], hits_s[::2], cols[2][::2], cols[3][::2])
    assert all(g.tobytes() == w.tobytes() for g, w in zip(got, want))
    assert np.array_equal(age_s[::2], age) and np.array_equal(hits_s[::2], hits)
    assert np.array_equal(age_s[1::2], cols[0][1::2])  # the rows between untouched
    ok = [gated[::2, :m], age.copy(), hits.copy(), cols[2][::2], cols[3][::2]]
    ro = age.copy()
    ro.flags.writeable = False
    for i, bad, err in [(1, age.astype(np.int64), ValueError), (3, cols[2][::2].astype(">i4"), ValueError),
                        (1, ro, ValueError), (0, gated[::2, :m].tolist(), TypeError),
                        (0, gated[::2, :m].astype(np.int8), ValueError), (4, cols[3][::2, None], ValueError)]:
        args = list(ok)
        args[i] = bad
        with pytest.raises(err):
            K.count_hits(*args)
    # reach_m, pdx, pdy, pair and det must be contiguous (the former typed memoryviews' ``::1``)
    x = rng.normal(0, 10, (t, 4))
    vec = np.ones(2 * t)
    pair = np.full(t, -1, np.int64)
    run = np.zeros(t, np.int32)
    K.duplicate_pairs(x, 1.0, 1.0, vec[:t], 1.0, vec[:t], vec[:t], 9.0, pair, pair, True, run, 3)
    with pytest.raises(ValueError):
        K.duplicate_pairs(x, 1.0, 1.0, vec[::2], 1.0, vec[:t], vec[:t], 9.0, pair, pair, True, run, 3)
