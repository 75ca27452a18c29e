"""The lane tracker's cheaper code paths compute what the plain forms compute (issue 9).

The stage fixtures (tests/edge/test_lane_stages.py) pin the tracker's outputs on recorded detections; these
tests pin the pieces: the inline TrackState construction, the IMM update of both modes by broadcasting
(against the flat (track, mode) rows with repeated weights) and the row operations of the track table.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge.track import PdafConfig, PdafTracker, TrackTable, imm
from edge.track import tracker as tracker_module
from edge.track.roles import build_roles
from edge.track.roles import initiate as initiate_module
from edge.track.pdaf import Innovations, combined_update, innovations
from edge.types import TrackState
from tests.edge.trackscene import Vehicle, frames

SCENE = [Vehicle(-5.25, 200.0, 0.0, -27.0, length_m=12.0), Vehicle(-1.75, 150.0, 0.0, -22.0),
         Vehicle(1.75, 20.0, 0.0, 30.0, length_m=4.5), Vehicle(5.25, 40.0, 0.0, 25.0)]


def _published(cfg: PdafConfig, n_frames: int = 150) -> list[tuple[TrackState, ...]]:
    tr = PdafTracker(cfg)
    return [tr.step(det, t_ns) for t_ns, det, _ in frames(SCENE, n_frames, seed=3, p_detect=0.9,
                                                           clutter_per_frame=2.0)]


@pytest.mark.parametrize("tentative", [False, True])
def test_published_states_equal_the_dataclass_constructor(tentative, monkeypatch):
    cfg = dataclasses.replace(PdafConfig(), publish_tentative=tentative)
    fast = _published(cfg)
    n = sum(len(f) for f in fast)
    assert n > 300 and any(t.length_m is not None for f in fast for t in f)
    assert any(not t.confirmed for f in fast for t in f) == tentative
    for f in fast:
        for t in f:
            plain = TrackState(**vars(t))
            assert t == plain and list(vars(t).items()) == list(vars(plain).items()) and hash(t) == hash(plain)
    # the fallback through the constructor gives the same states
    monkeypatch.setattr(tracker_module, "_TRACK_STATE_PLAIN", False)
    assert _published(cfg) == fast


def _random_modes(rng, t, m, n):
    xpm = rng.normal(size=(t, 2, 4)) * [20.0, 100.0, 3.0, 25.0]
    a = rng.normal(size=(t, 2, 4, 4))
    ppm = a @ a.swapaxes(-1, -2) + 0.1 * np.eye(4)
    zh = xpm[:, :, :n] + rng.normal(size=(t, 2, n))
    h = np.zeros((t, 2, n, 4))
    h[..., 0, 0] = h[..., 1, 1] = 1.0
    if n == 3:
        h[..., 2, :] = rng.normal(size=(t, 2, 4))
    r = np.broadcast_to(np.diag([0.3, 1.0, 0.09][:n]), (t * 2, n, n))
    z = rng.normal(size=(m, n)) * [20.0, 100.0, 25.0][:n]
    inn = innovations(z, zh.reshape(2 * t, n), h.reshape(2 * t, n, 4), ppm.reshape(2 * t, 4, 4), r)
    beta = rng.uniform(size=(t, m))
    beta /= beta.sum(axis=1, keepdims=True) * rng.uniform(1.0, 3.0, size=(t, 1))
    beta0 = 1.0 - beta.sum(axis=1)
    return xpm, ppm, h, inn, beta, beta0


@pytest.mark.parametrize("n", [2, 3])
def test_both_modes_by_broadcasting_equal_the_flat_rows(n):
    rng = np.random.default_rng(11 + n)
    t, m = 7, 5
    xpm, ppm, h, inn, beta, beta0 = _random_modes(rng, t, m, n)
    flat_x, flat_p = combined_update(xpm.reshape(2 * t, 4), ppm.reshape(2 * t, 4, 4), h.reshape(2 * t, n, 4), inn,
                                     np.repeat(beta, 2, axis=0), np.repeat(beta0, 2))
    by_mode = Innovations(inn.v.reshape(t, 2, m, n), inn.d2.reshape(t, 2, m), inn.s.reshape(t, 2, n, n),
                          inn.s_inv.reshape(t, 2, n, n), inn.det_s.reshape(t, 2))
    x, p = combined_update(xpm, ppm, h, by_mode, beta[:, None, :], beta0[:, None])
    np.testing.assert_allclose(x, flat_x.reshape(t, 2, 4), rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(p, flat_p.reshape(t, 2, 4, 4), rtol=1e-13, atol=1e-12)
    # the textbook form beta0 P + (1 - beta0)(P - K S K') + K spread K' of one row
    k = ppm[0, 1] @ h[0, 1].T @ np.linalg.inv(by_mode.s[0, 1])
    v = by_mode.v[0, 1]
    vbar = beta[0] @ v
    spread = (v * beta[0][:, None]).T @ v - np.outer(vbar, vbar)
    pc = ppm[0, 1] - k @ by_mode.s[0, 1] @ k.T
    ref = beta0[0] * ppm[0, 1] + (1 - beta0[0]) * pc + k @ spread @ k.T
    np.testing.assert_allclose(p[0, 1], ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(x[0, 1], xpm[0, 1] + k @ vbar, rtol=1e-12)
    # mode likelihoods: broadcast gate and volume against repeated rows
    gated = inn.d2.reshape(t, 2, m)[:, 0] < 9.0
    vol = rng.uniform(1.0, 5.0, size=t)
    flat = imm.mode_likelihood(inn, np.repeat(gated, 2, axis=0), np.repeat(vol, 2), 0.9, 0.99).reshape(t, 2)
    np.testing.assert_array_equal(imm.mode_likelihood(by_mode, gated[:, None, :], vol[:, None], 0.9, 0.99), flat)


def test_track_table_rows_keep_their_dtypes():
    tab = TrackTable()
    rng = np.random.default_rng(2)
    x = rng.normal(size=(5, 4))
    p = np.repeat(np.eye(4)[None], 5, axis=0) * rng.uniform(1, 2, size=(5, 1, 1))
    tab.append(x, p, 1.7, 0.6)
    tab.append(x[:2] + 1.0, p[:2], 2.0, 0.5)
    dtypes = {c: getattr(tab, c).dtype for c in TrackTable._COLUMNS}
    assert len(tab) == 7 and dtypes["history"] == np.uint32 and dtypes["track_id"] == np.int32
    np.testing.assert_array_equal(tab.xm[:, 1], np.concatenate([x, x[:2] + 1.0]))
    np.testing.assert_array_equal(tab.mu[:5], [[0.6, 0.4]] * 5)
    np.testing.assert_array_equal(tab.ext_var, [1.7] * 5 + [2.0] * 2)
    mask = np.array([True, False, True, True, False, False, True])
    before = {c: getattr(tab, c).copy() for c in TrackTable._COLUMNS}
    tab.keep(mask)
    assert len(tab) == 4
    for c in TrackTable._COLUMNS:
        assert getattr(tab, c).dtype == dtypes[c]
        np.testing.assert_array_equal(getattr(tab, c), before[c][mask])


# --- issue 9, second pass: fewer numpy calls per frame, same numbers -------------------------------------------

def _covariances(rng, shape, n):
    a = rng.normal(size=shape + (n, n))
    return a @ a.swapaxes(-1, -2) * 0.3 + 0.05 * np.eye(n)


@pytest.mark.parametrize("n", [2, 3])
def test_mahalanobis_d2_of_given_innovations_is_the_innovations_d2(n):
    from edge.track.pdaf import mahalanobis_d2

    rng = np.random.default_rng(21)
    t, m = 5, 7
    h = rng.normal(size=(t, n, 4))
    p = _covariances(rng, (t,), 4)
    r = _covariances(rng, (t,), n)
    inn = innovations(rng.normal(size=(m, n)), rng.normal(size=(t, n)), h, p, r)
    np.testing.assert_array_equal(mahalanobis_d2(inn.v, inn.s), inn.d2)
    ref = np.einsum("tmi,tij,tmj->tm", inn.v, np.linalg.inv(inn.s), inn.v)
    np.testing.assert_allclose(inn.d2, ref, rtol=1e-10)


def test_pair_quadratic_forms_and_inverses_match_linalg():
    from edge.track.pdaf import _quad_each, _sym_inv_det

    rng = np.random.default_rng(22)
    s = _covariances(rng, (4, 6), 3)
    v = rng.normal(size=(4, 6, 3))
    inv, det = _sym_inv_det(s)
    np.testing.assert_allclose(inv, np.linalg.inv(s), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(det, np.linalg.det(s), rtol=1e-9)
    np.testing.assert_allclose(_quad_each(v, inv), np.einsum("...i,...ij,...j->...", v, np.linalg.inv(s), v),
                               rtol=1e-9)


def test_pair_update_sums_each_rows_pairs_whatever_their_order():
    """combined_update_pairs (one product with the row-membership matrix) against np.add.at, with the IMM's row
    order (all mode-0 rows, then all mode-1 rows), rows without pairs and one row with a single pair."""
    from edge.track.pdaf import PairInnovations, combined_update_pairs

    rng = np.random.default_rng(23)
    t, n = 6, 3
    xp = rng.normal(size=(t, 4))
    pp = _covariances(rng, (t,), 4)
    h = rng.normal(size=(t, n, 4))
    rows = np.array([0, 0, 2, 4, 4, 4, 1, 1, 3, 5, 5, 5])[[0, 1, 2, 3, 4, 5, 6, 7, 9, 10, 11]]  # row 3 without pairs
    k = rows.size
    s_inv = np.linalg.inv(_covariances(rng, (k,), n))
    v = rng.normal(size=(k, n))
    w = rng.uniform(0.05, 0.4, k)
    pin = PairInnovations(rows, np.arange(k), v, np.zeros(k), s_inv, np.ones(k))
    x, p = combined_update_pairs(xp, pp, h, pin, w)
    ph = pp @ h.transpose(0, 2, 1)
    gain = ph[rows] @ s_inv
    dx = (gain @ v[:, :, None])[:, :, 0]
    dxbar, kbar, spread = np.zeros((t, 4)), np.zeros((t, 4, n)), np.zeros((t, 4, 4))
    np.add.at(dxbar, rows, dx * w[:, None])
    np.add.at(kbar, rows, gain * w[:, None, None])
    np.add.at(spread, rows, (dx * w[:, None])[:, :, None] * dx[:, None, :])
    p_ref = pp - kbar @ ph.transpose(0, 2, 1) + spread - dxbar[:, :, None] * dxbar[:, None, :]
    np.testing.assert_allclose(x, xp + dxbar, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(p, 0.5 * (p_ref + p_ref.transpose(0, 2, 1)), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(x[3], xp[3])  # no pair: the prediction stays
    np.testing.assert_allclose(p[3], 0.5 * (pp[3] + pp[3].T), rtol=0, atol=0)


def test_imm_prediction_cache_follows_yaw_and_period_changes():
    """The keep mode's F, Q are rebuilt in place when only the yaw moves: every (dt, yaw) gets the matrices a
    fresh predictor would use."""
    cfg = PdafConfig()
    cached = tracker_module.ImmPredictor(cfg)
    tracks = TrackTable()
    rng = np.random.default_rng(24)
    x = np.column_stack([rng.uniform(-8, 8, 3), rng.uniform(30, 200, 3), rng.normal(0, 1, 3), rng.uniform(-30, 30, 3)])
    tracks.append(x, np.repeat(np.eye(4)[None], 3, axis=0), 1.0, 0.6)
    for dt, yaw in [(0.033, 0.0), (0.033, 0.01), (0.034, 0.01), (0.034, -0.02), (0.033, -0.02), (0.033, 0.0)]:
        fresh = tracker_module.ImmPredictor(cfg)
        a, b = cached.predict(tracks, dt, yaw), fresh.predict(tracks, dt, yaw)
        for name in ("x", "p", "xm", "pm", "c"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        fk, qk = imm.keep_model(dt, yaw, cfg.imm_keep_tau_s, cfg.imm_keep_q_across_m2ps3, cfg.q_along_m2ps3)
        np.testing.assert_array_equal(cached._cached[2][0], fk)
        np.testing.assert_array_equal(cached._cached[3][0], qk)


@pytest.mark.parametrize("yaw", [0.0, 0.05, -0.3])
def test_keep_model_closed_form_is_the_rotated_model(yaw):
    import math

    dt, tau, qa, ql = 0.033, 1.5, 0.02, 2.0
    f, q = imm.keep_model(dt, yaw, tau, qa, ql)
    rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    phi = rot @ np.diag([math.exp(-dt / tau), 1.0]) @ rot.T
    a = rot @ np.diag([qa, ql]) @ rot.T
    np.testing.assert_allclose(f[2:, 2:], phi, rtol=0, atol=1e-15)
    np.testing.assert_allclose(f[:2], np.hstack([np.eye(2), dt * np.eye(2)]), rtol=0, atol=0)
    np.testing.assert_allclose(q, np.block([[dt**3 / 3 * a, dt**2 / 2 * a], [dt**2 / 2 * a, dt * a]]), rtol=1e-14,
                               atol=1e-18)
    np.testing.assert_array_equal(q, q.T)


def test_deleter_pairs_are_triu_indices_for_any_sequence_of_track_counts():
    deleter = build_roles(PdafConfig()).deleter
    rng = np.random.default_rng(9)
    for t in [2, 5, 3, 31, 32, 33, 2, 70, 40, 0, 1, *rng.integers(0, 150, size=20).tolist()]:
        ia, ib = deleter.pairs(t)
        ra, rb = np.triu_indices(t, 1)
        assert ia.dtype == ra.dtype and np.array_equal(ia, ra) and np.array_equal(ib, rb), t


def test_detection_noise_of_some_rows_is_those_rows_of_all():
    cfg = PdafConfig()
    mm = tracker_module.MeasurementModel(cfg)
    rng = np.random.default_rng(4)
    z = np.column_stack([rng.uniform(-10, 10, 9), rng.uniform(5, 250, 9), rng.normal(0, 20, 9)])
    meas = tracker_module.Measurements(z, rng.uniform(-5, 70, 9), True)
    rows = np.array([7, 0, 3])
    for n in (2, 3):
        full = mm.of_detections(meas, n)
        some = mm.of_detections(meas, n, rows=rows)
        assert some.shape == (3, n, n) and np.array_equal(some, full[rows])


@pytest.mark.parametrize("with_pairs", [False, True])
def test_seed_merge_in_plain_python_equals_the_array_form(with_pairs, monkeypatch):
    """Candidates in clusters (so seeds merge), equal SNRs (the tie rule), resolved pairs (their own box)."""
    cfg = PdafConfig()
    rng = np.random.default_rng(11)
    n_merged = 0
    for trial in range(60):
        m = int(rng.integers(2, 9))
        centres = rng.uniform([-8.0, 20.0, -30.0], [8.0, 200.0, 30.0], size=(2, 3))
        z = centres[rng.integers(0, 2, m)] + rng.normal(0.0, [1.0, 2.0, 0.3], size=(m, 3))
        snr = np.round(rng.uniform(5.0, 12.0, m))  # ties
        pair = np.where(rng.uniform(size=m) < 0.4, rng.integers(0, 2, m), -1) if with_pairs else None
        meas = tracker_module.Measurements(z, snr, True, pair)
        out = []
        for plain_max in (0, 100):
            monkeypatch.setattr(initiate_module, "_SEED_MERGE_PLAIN_MAX", plain_max)
            tracks = TrackTable()
            build_roles(cfg).initiator.initiate(tracks, meas, np.zeros(m, bool))
            out.append(tracks)
        assert np.array_equal(out[0].x, out[1].x) and np.array_equal(out[0].p, out[1].p)
        assert np.array_equal(out[0].pm, out[1].pm)
        n_merged += len(out[0]) < m
    assert n_merged > 20


def test_tracker_outputs_equal_with_the_plain_seed_merge_off(monkeypatch):
    fast = _published(PdafConfig(), 80)
    monkeypatch.setattr(initiate_module, "_SEED_MERGE_PLAIN_MAX", 0)
    assert _published(PdafConfig(), 80) == fast


def test_published_quality_fields_describe_the_track_errors():
    """The standard deviations of the published position and velocity (what CAN 0x60C encodes) are the state
    covariance's, and they describe the errors: point vehicles without extent, the published state of each
    confirmed track against the nearest true vehicle. The existence probability of a confirmed track is Wald's
    confirmation confidence or more. Before, every quality field was None and CAN sent 'invalid'."""
    cfg = dataclasses.replace(PdafConfig(), lateral_smoother=False)
    scene = [dataclasses.replace(v, length_m=0.0) for v in SCENE]
    tr = PdafTracker(cfg)
    z, n = {"x": [], "y": [], "vx": [], "vy": []}, 0
    for t_ns, det, truth in frames(scene, 150, seed=3, p_detect=0.9, clutter_per_frame=2.0):
        out = tr.step(det, t_ns)
        for t in out:
            a, b = cfg.score_false_confirm_prob, cfg.score_true_reject_prob  # posterior odds (1 - b) / a
            assert t.confirmed and t.existence_probability >= (1.0 - b) / (1.0 - b + a) - 1e-12
            for sd in (t.x_sd_m, t.y_sd_m, t.vx_sd_mps, t.vy_sd_mps):
                assert sd is not None and 0.0 < sd < 10.0
            if t.age_frames < 30 or not truth:  # settled tracks
                continue
            _, x, y, vx, vy = min(truth, key=lambda g: (g[1] - t.x_m) ** 2 + (g[2] - t.y_m) ** 2)
            for k, err, sd in (("x", t.x_m - x, t.x_sd_m), ("y", t.y_m - y, t.y_sd_m),
                               ("vx", t.vx_mps - vx, t.vx_sd_mps), ("vy", t.vy_mps - vy, t.vy_sd_mps)):
                z[k].append(err / sd)
            n += 1
    assert n > 300
    for k, v in z.items():  # normalised errors: about unit spread (a 3-sigma bound holds for nearly all)
        v = np.abs(np.asarray(v))
        assert np.mean(v < 3.0) > 0.9, (k, np.mean(v < 3.0), np.sqrt(np.mean(v ** 2)))
