"""Known-answer tests of the Kalman/PDAF maths and a cross-check against Stone Soup's PDA."""

from __future__ import annotations

import math
from datetime import datetime, timedelta

import numpy as np
import pytest

from edge.track import kalman
from edge.track.pdaf import association_weights, combined_update, gate_threshold, innovations, unit_ball_volume


def test_cv_transition_and_process_noise_known_answer():
    f = kalman.cv_transition(0.5)
    np.testing.assert_array_equal(f, [[1, 0, 0.5, 0], [0, 1, 0, 0.5], [0, 0, 1, 0], [0, 0, 0, 1]])
    q = kalman.cv_process_noise(2.0, 3.0, 5.0)
    # per axis q * [[dt^3/3, dt^2/2], [dt^2/2, dt]] with dt = 2
    assert q[0, 0] == pytest.approx(3.0 * 8 / 3) and q[0, 2] == pytest.approx(3.0 * 2) and q[2, 2] == pytest.approx(6.0)
    assert q[1, 1] == pytest.approx(5.0 * 8 / 3) and q[1, 3] == pytest.approx(10.0) and q[3, 3] == pytest.approx(10.0)
    assert q[0, 1] == 0 and q[0, 3] == 0 and q[2, 3] == 0
    np.testing.assert_array_equal(q, q.T)


def test_process_noise_matches_stonesoup_constant_velocity():
    models = pytest.importorskip("stonesoup.models.transition.linear")
    m = models.CombinedLinearGaussianTransitionModel([models.ConstantVelocity(0.7), models.ConstantVelocity(2.5)])
    dt = timedelta(seconds=0.033)
    # Stone Soup orders the state (x, vx, y, vy); ours is (x, y, vx, vy)
    perm = [0, 2, 1, 3]
    ss_q = m.covar(time_interval=dt)[np.ix_(perm, perm)]
    ss_f = m.matrix(time_interval=dt)[np.ix_(perm, perm)]
    np.testing.assert_allclose(kalman.cv_process_noise(0.033, 0.7, 2.5), ss_q, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(kalman.cv_transition(0.033), ss_f, rtol=1e-12)


def test_gate_threshold_and_volume():
    assert gate_threshold(0.99, 2) == pytest.approx(9.2103, abs=1e-4)  # -2 ln(0.01)
    assert gate_threshold(0.99, 3) == pytest.approx(11.3449, abs=1e-4)
    assert unit_ball_volume(2) == pytest.approx(math.pi)
    assert unit_ball_volume(3) == pytest.approx(4 * math.pi / 3)


def test_polar_noise_known_answer():
    # on boresight at 100 m: sd along y = sigma_r, along x = r sigma_az
    r = kalman.polar_position_noise(np.array([[0.0, 100.0]]), 0.2, 0.01, 0.0)[0]
    np.testing.assert_allclose(r, [[1.0, 0.0], [0.0, 0.04]], atol=1e-12)
    # 90 degrees off boresight the roles swap; the floor adds isotropically
    r = kalman.polar_position_noise(np.array([[50.0, 0.0]]), 0.2, 0.01, 0.1)[0]
    np.testing.assert_allclose(r, [[0.04 + 0.01, 0.0], [0.0, 0.25 + 0.01]], atol=1e-12)


def test_radial_speed_jacobian_matches_finite_differences():
    rng = np.random.default_rng(3)
    xp = np.column_stack([rng.uniform(-10, 10, 5), rng.uniform(5, 200, 5), rng.uniform(-3, 3, 5), rng.uniform(-30, 30, 5)])
    zh, h = kalman.measurement_prediction(xp, True)
    eps = 1e-6
    for j in range(4):
        d = np.zeros(4)
        d[j] = eps
        zp, _ = kalman.measurement_prediction(xp + d, True)
        zm, _ = kalman.measurement_prediction(xp - d, True)
        np.testing.assert_allclose((zp - zm)[:, 2] / (2 * eps), h[:, 2, j], rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(zh[:, 2], (xp[:, 0] * xp[:, 2] + xp[:, 1] * xp[:, 3]) / np.hypot(xp[:, 0], xp[:, 1]))


def _one_track(z, r=np.eye(2)):
    xp = np.array([[0.0, 0.0, 1.0, 1.0]])
    pp = np.eye(4)[None]
    zh, h = kalman.measurement_prediction(xp, False)
    return xp, pp, h, innovations(np.asarray(z, float), zh, h, pp, r[None])


def test_pdaf_weights_known_answer():
    # S = H P H' + R = 2 I; two measurements at d2 = 1 and 4, one outside the gate
    xp, pp, h, inn = _one_track([[math.sqrt(2), 0.0], [0.0, math.sqrt(8)], [10.0, 10.0]])
    np.testing.assert_allclose(inn.d2[0], [1.0, 4.0, 100.0])
    pd, pg = 0.9, 0.99
    gamma = gate_threshold(pg, 2)
    beta, beta0, gated = association_weights(inn, gamma, pd, pg, "pdaf")
    assert gated.tolist() == [[True, True, False]]
    # by hand: |S| = 4, V = pi gamma * 2, N = exp(-d2/2) / (2 pi * 2), lambda = M / V = 2 / V
    vol = math.pi * gamma * 2.0
    lik = [pd * math.exp(-0.5 * d) / (4 * math.pi) * vol / 2.0 for d in (1.0, 4.0)]
    b = 1 - pd * pg
    den = b + sum(lik)
    np.testing.assert_allclose(beta[0], [lik[0] / den, lik[1] / den, 0.0], rtol=1e-12)
    assert beta0[0] == pytest.approx(b / den, rel=1e-12)
    assert beta0[0] + beta[0].sum() == pytest.approx(1.0)


def test_combined_update_with_one_certain_measurement_is_the_kalman_update():
    xp, pp, h, inn = _one_track([[1.0, -2.0]])
    x, p = combined_update(xp, pp, h, inn, np.array([[1.0]]), np.array([0.0]))
    # K = P H' S^-1 = [[.5, 0], [0, .5], [0, 0], [0, 0]] for P = I, S = 2 I
    np.testing.assert_allclose(x[0], [0.5, -1.0, 1.0, 1.0])
    np.testing.assert_allclose(p[0], np.diag([0.5, 0.5, 1.0, 1.0]))
    # no measurement: the prediction is kept
    x0, p0 = combined_update(xp, pp, h, inn, np.array([[0.0]]), np.array([1.0]))
    np.testing.assert_allclose(x0, xp)
    np.testing.assert_allclose(p0, pp)


def test_jpda_equals_pdaf_without_shared_detections_and_shares_otherwise():
    zh = np.array([[0.0, 0.0], [0.0, 50.0]])
    xp = np.column_stack([zh, np.zeros((2, 2))])
    pp = np.repeat(np.eye(4)[None], 2, axis=0)
    _, h = kalman.measurement_prediction(xp, False)
    r = np.repeat(np.eye(2)[None], 2, axis=0)
    gamma = gate_threshold(0.99, 2)
    z = np.array([[0.3, 0.1], [0.0, 50.5], [-0.2, 49.8]])
    inn = innovations(z, zh, h, pp, r)
    a = association_weights(inn, gamma, 0.9, 0.99, "pdaf")
    b = association_weights(inn, gamma, 0.9, 0.99, "jpda")
    np.testing.assert_allclose(a[0], b[0], rtol=1e-12)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-12)
    # two tracks 1 m apart, one detection between them: JPDA gives each less than PDAF does
    zh = np.array([[0.0, 0.0], [1.0, 0.0]])
    xp = np.column_stack([zh, np.zeros((2, 2))])
    inn = innovations(np.array([[0.5, 0.0]]), zh, h, pp, r)
    bp, _, _ = association_weights(inn, gamma, 0.9, 0.99, "pdaf")
    bj, b0j, _ = association_weights(inn, gamma, 0.9, 0.99, "jpda")
    assert np.all(bj < bp) and np.all(b0j > 0)
    np.testing.assert_allclose(b0j + bj.sum(axis=1), 1.0)


def test_pdaf_matches_stonesoup_pda_one_target_in_clutter():
    """Same CV model, same measurement model, same P_D/P_G, non-parametric clutter density:
    our batched PDAF and Stone Soup's PDAHypothesiser + PDA + KalmanUpdater + Gaussian-mixture
    reduction give the same state and covariance at every step."""
    pytest.importorskip("stonesoup")
    from stonesoup.dataassociator.probability import PDA
    from stonesoup.functions import gm_reduce_single
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.array import StateVectors
    from stonesoup.types.detection import Clutter, Detection
    from stonesoup.types.state import GaussianState
    from stonesoup.types.track import Track
    from stonesoup.types.update import GaussianStateUpdate
    from stonesoup.updater.kalman import KalmanUpdater

    q, dt, pd, pg = 0.5, 0.033, 0.9, 0.99
    r = np.diag([0.09, 0.25])
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(q), ConstantVelocity(q)])
    meas_model = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=r)
    predictor = KalmanPredictor(transition)
    updater = KalmanUpdater(meas_model)
    hyp = PDAHypothesiser(predictor=predictor, updater=updater, clutter_spatial_density=None,
                          prob_detect=pd, prob_gate=pg)
    pda = PDA(hypothesiser=hyp)

    perm = [0, 2, 1, 3]  # ours (x, y, vx, vy) <-> Stone Soup (x, vx, y, vy)
    t0 = datetime(2026, 1, 1)
    x0 = np.array([1.0, 50.0, 0.2, -20.0])
    p0 = np.diag([0.5, 0.5, 4.0, 4.0])
    track = Track([GaussianState(x0[perm].reshape(-1, 1), p0[np.ix_(perm, perm)], timestamp=t0)])
    x, p = x0[None].copy(), p0[None].copy()
    f = kalman.cv_transition(dt)
    qm = kalman.cv_process_noise(dt, q, q)
    gamma = gate_threshold(pg, 2)

    rng = np.random.default_rng(7)
    truth = x0.copy()
    n_multi = 0
    for k in range(1, 40):
        ts = t0 + timedelta(seconds=k * dt)
        truth = f @ truth
        zs = []
        if rng.random() < pd:
            zs.append(truth[:2] + rng.multivariate_normal([0, 0], r))
        zs.extend(truth[:2] + rng.uniform(-2.0, 2.0, (rng.poisson(3), 2)))
        z = np.array(zs).reshape(-1, 2)
        dets = {Detection(zz.reshape(-1, 1), timestamp=ts, measurement_model=meas_model) for zz in zs}
        # Stone Soup
        hyps = pda.associate({track}, dets, ts)[track]
        states, weights = [], []
        for hh in hyps:
            states.append(updater.update(hh) if hh else hh.prediction)
            weights.append(float(hh.probability))
        n_multi += sum(1 for hh in hyps if hh) > 1
        mean, cov = gm_reduce_single(StateVectors([s.state_vector for s in states]),
                                     np.stack([s.covar for s in states], axis=2), np.asarray(weights))
        track.append(GaussianStateUpdate(mean, cov, hyps, ts))
        # ours
        xp, pp = kalman.predict(x, p, f, qm)
        zh, h = kalman.measurement_prediction(xp, False)
        inn = innovations(z, zh, h, pp, r[None])
        beta, beta0, _ = association_weights(inn, gamma, pd, pg, "pdaf")
        x, p = combined_update(xp, pp, h, inn, beta, beta0)
        np.testing.assert_allclose(x[0], np.asarray(mean, float).ravel()[perm], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(p[0], np.asarray(cov, float)[np.ix_(perm, perm)], rtol=1e-8, atol=1e-10)
    assert n_multi >= 5, "the scenario must exercise several validated detections per frame"


# --- one R per detection (measurement_noise = "snr") ---------------------------------------------------------------

from edge.track import imm  # noqa: E402
from edge.track.pdaf import (_sym_inv_det, association_weights, combined_update,  # noqa: E402
                             gate_volume_each, innovations_each)


def _random_tracks(rng, t, n):
    xp = np.column_stack([rng.uniform(-8, 8, t), rng.uniform(20, 200, t), rng.uniform(-1, 1, t), rng.uniform(-30, 30, t)])
    a = rng.normal(size=(t, 4, 4))
    pp = a @ a.transpose(0, 2, 1) * 0.3 + np.eye(4)[None] * 0.05
    zh, h = kalman.measurement_prediction(xp, n == 3)
    b = rng.normal(size=(t, n, n))
    r_track = b @ b.transpose(0, 2, 1) * 0.05 + np.eye(n)[None] * 0.01
    return xp, pp, zh, h, r_track


@pytest.mark.parametrize("n", [2, 3])
def test_closed_form_inverse_and_determinant_match_numpy(n):
    rng = np.random.default_rng(7)
    a = rng.normal(size=(5, 6, n, n))
    s = a @ a.swapaxes(-1, -2) + 0.1 * np.eye(n)
    inv, det = _sym_inv_det(s)
    np.testing.assert_allclose(inv, np.linalg.inv(s), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(det, np.linalg.det(s), rtol=1e-9)


@pytest.mark.parametrize("method", ["pdaf", "jpda"])
@pytest.mark.parametrize("n", [2, 3])
def test_per_detection_path_with_one_common_r_is_the_constant_r_pdaf(method, n):
    """Every detection with the same R: innovations, gate, weights and the update equal the constant-R functions
    (the per-hypothesis gains are then one gain)."""
    rng = np.random.default_rng(11 + n)
    t, m = 4, 9
    xp, pp, zh, h, r_track = _random_tracks(rng, t, n)
    c = rng.normal(size=(n, n))
    r_common = c @ c.T * 0.1 + np.eye(n) * 0.02
    z = zh[rng.integers(0, t, m)] + rng.normal(0, 0.7, (m, n))
    each = innovations_each(z, zh, h, pp, r_track, np.repeat(r_common[None], m, axis=0))
    one = innovations(z, zh, h, pp, r_track + r_common[None])
    np.testing.assert_allclose(each.d2, one.d2, rtol=1e-9)
    np.testing.assert_allclose(each.det_s, np.repeat(one.det_s[:, None], m, axis=1), rtol=1e-9)
    gamma = gate_threshold(0.99, n)
    b1, b01, g1 = association_weights(one, gamma, 0.9, 0.99, method)
    b2, b02, g2 = association_weights(each, gamma, 0.9, 0.99, method)
    assert g1.any() and (~g1).any()
    np.testing.assert_array_equal(g1, g2)
    np.testing.assert_allclose(b2, b1, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(b02, b01, rtol=1e-9)
    x1, p1 = combined_update(xp, pp, h, one, b1, b01)
    x2, p2 = combined_update(xp, pp, h, each, b2, b02)
    np.testing.assert_allclose(x2, x1, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(p2, p1, rtol=1e-8, atol=1e-10)
    vol = unit_ball_volume(n) * gamma ** (n / 2) * np.sqrt(one.det_s)
    np.testing.assert_allclose(gate_volume_each(each, g2, gamma), vol, rtol=1e-9)
    np.testing.assert_allclose(imm.mode_likelihood_each(each, g2, vol, 0.9, 0.99),
                               imm.mode_likelihood(one, g1, vol, 0.9, 0.99), rtol=1e-9)


def test_per_detection_update_is_the_moment_matched_mixture_of_per_hypothesis_kalman_updates():
    """Different R per detection: the posterior is the mixture, weighted by beta (and beta0 for 'none is the
    target'), of one Kalman update per detection with its own S and gain; checked track by track in plain loops."""
    rng = np.random.default_rng(5)
    t, m, n = 3, 6, 3
    xp, pp, zh, h, r_track = _random_tracks(rng, t, n)
    c = rng.normal(size=(m, n, n))
    r_meas = c @ c.transpose(0, 2, 1) * rng.uniform(0.01, 1.0, m)[:, None, None] + np.eye(n)[None] * 0.01
    z = zh[rng.integers(0, t, m)] + rng.normal(0, 0.5, (m, n))
    inn = innovations_each(z, zh, h, pp, r_track, r_meas)
    beta, beta0, gated = association_weights(inn, gate_threshold(0.99, n), 0.9, 0.99, "pdaf")
    assert (gated.sum(axis=1) >= 2).any()
    x, p = combined_update(xp, pp, h, inn, beta, beta0)
    for i in range(t):
        means, covs, ws = [xp[i]], [pp[i]], [beta0[i]]
        for j in range(m):
            s = h[i] @ pp[i] @ h[i].T + r_track[i] + r_meas[j]
            k = pp[i] @ h[i].T @ np.linalg.inv(s)
            means.append(xp[i] + k @ (z[j] - zh[i]))
            covs.append((np.eye(4) - k @ h[i]) @ pp[i])
            ws.append(beta[i, j])
            # the likelihood uses this detection's own S
            assert inn.det_s[i, j] == pytest.approx(np.linalg.det(s), rel=1e-9)
        ws = np.array(ws)
        assert ws.sum() == pytest.approx(1.0)
        mean = sum(w * mu for w, mu in zip(ws, means))
        cov = sum(w * (cv + np.outer(mu - mean, mu - mean)) for w, mu, cv in zip(ws, means, covs))
        np.testing.assert_allclose(x[i], mean, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(p[i], cov, rtol=1e-8, atol=1e-10)


def test_snr_polar_noise_known_answer():
    # on boresight at 100 m, 20 dB: sd across = r * sqrt(s0^2 / 100 + floor^2), along = the range law
    s0, fl = np.radians(1.0), np.radians(0.1)
    r = kalman.snr_polar_noise(np.array([[0.0, 100.0], [0.0, 100.0]]), np.array([20.0, 80.0]), 0.2, 0.01, s0, fl, 0.3,
                               (0.0, 40.0))
    np.testing.assert_allclose(r[0], [[100.0**2 * (s0**2 / 100 + fl**2) + 0.09, 0.0],
                                      [0.0, 0.04 / 100 + 1e-4 + 0.09]], rtol=1e-12)
    np.testing.assert_allclose(r[1, 0, 0], 100.0**2 * (s0**2 / 1e4 + fl**2) + 0.09, rtol=1e-12)  # clipped at 40 dB
    # off boresight: the same rotation as the constant model
    xy = np.array([[30.0, 80.0]])
    snr = np.array([15.0])
    lin = 10 ** 1.5
    want = kalman.polar_position_noise(xy, math.sqrt(0.04 / lin + 1e-4), math.sqrt(s0**2 / lin + fl**2), 0.3)
    np.testing.assert_allclose(kalman.snr_polar_noise(xy, snr, 0.2, 0.01, s0, fl, 0.3), want, rtol=1e-12)
