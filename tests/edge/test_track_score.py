"""Score-based confirmation (edge.track.score): the likelihood ratio against a direct computation, and what it
changes in the tracker (a strong vehicle confirms in a few frames, clutter still never does)."""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import multivariate_normal

from edge.track import PdafTracker
from edge.track.score import confirm_threshold, false_density, score_increment
from tests.edge.trackscene import Vehicle, frames, scene_config


def test_score_increment_is_the_pda_likelihood_ratio():
    rng = np.random.default_rng(3)
    t, m, n = 4, 5, 3
    s = np.empty((t, m, n, n))
    for i in range(t):
        for j in range(m):
            a = rng.normal(size=(n, n))
            s[i, j] = a @ a.T + 0.5 * np.eye(n)
    v = rng.normal(size=(t, m, n)) * 1.5
    d2 = np.einsum("tmi,tmij,tmj->tm", v, np.linalg.inv(s), v)
    gated = d2 <= 11.3
    gated[0] = False  # a track with nothing in its gate
    pd, pg, lam = 0.9, 0.99, 2e-5
    got = score_increment(d2, np.linalg.det(s), gated, n, pd, pg, lam)
    for i in range(t):
        like = sum(multivariate_normal(np.zeros(n), s[i, j]).pdf(v[i, j]) for j in range(m) if gated[i, j])
        assert math.isclose(got[i], math.log(1.0 - pd * pg + pd * like / lam), rel_tol=1e-9, abs_tol=1e-12)
    assert math.isclose(got[0], math.log(1.0 - pd * pg))
    # one S per track broadcasts like one per (track, detection)
    s1 = s[:, :1].repeat(m, axis=1)
    d21 = np.einsum("tmi,tmij,tmj->tm", v, np.linalg.inv(s1), v)
    a = score_increment(d21, np.linalg.det(s1), gated, n, pd, pg, lam)
    b = score_increment(d21, np.linalg.det(s1[:, 0]), gated, n, pd, pg, lam)
    np.testing.assert_allclose(a, b, rtol=1e-12)
    # no detection at all: every track misses
    np.testing.assert_allclose(score_increment(np.zeros((2, 0)), np.ones(2), np.zeros((2, 0), bool), n, pd, pg, lam),
                               math.log(1.0 - pd * pg))


def test_wald_threshold_and_density():
    assert math.isclose(confirm_threshold(1e-4, 0.01), math.log(0.99 / 1e-4))
    assert false_density(1e-3, 100.0, 3) == 1e-5 and false_density(1e-3, 100.0, 2) == 1e-3


def _confirm_frame(cfg, vehicles, n_frames=40, **kw):
    tr = PdafTracker(cfg)
    for k, (t_ns, det, _) in enumerate(frames(vehicles, n_frames, **kw)):
        if tr.step(det, t_ns):
            return k
    return None


def test_a_strong_vehicle_confirms_sooner_with_the_score_and_clutter_still_never_does():
    car = [Vehicle(5.25, 25.0, 0.0, 25.0)]  # a receding car near the radar, detected every frame
    k_mofn = _confirm_frame(scene_config(confirmation="m_of_n"), car, seed=1)
    k_score = _confirm_frame(scene_config(confirmation="either"), car, seed=1)
    assert k_mofn == 4  # 5 of 10: the fifth frame
    assert k_score is not None and k_score <= 2, k_score
    # a weak far vehicle, detected in half the frames: the score never confirms later than M-of-N
    far = [Vehicle(-5.25, 330.0, 0.0, -28.0)]
    for seed in range(5):
        a = _confirm_frame(scene_config(confirmation="m_of_n"), far, 60, seed=seed, p_detect=0.5, az_sigma_deg=1.0)
        b = _confirm_frame(scene_config(confirmation="either"), far, 60, seed=seed, p_detect=0.5, az_sigma_deg=1.0)
        assert a is None or (b is not None and b <= a), (seed, a, b)
    # uniform moving clutter only (5 detections per frame over the road): no track confirms, whichever rule
    for rule in ("m_of_n", "either", "score"):
        tr = PdafTracker(scene_config(confirmation=rule))
        confirmed = 0
        for t_ns, det, _ in frames([], 600, seed=4, clutter_per_frame=5.0, clutter_box=(-10.0, 10.0, 10.0, 300.0)):
            confirmed += len(tr.step(det, t_ns))
        assert confirmed == 0, rule



def test_peak_coherence_one_source_two_sources_and_noise():
    import math as _m

    from edge.dsp.angle import peak_coherence, steering_matrix

    grid = np.radians(np.arange(-19.0, 19.01, 0.25))
    lam = 0.0124
    steer = steering_matrix(4, 1.5 * lam, lam, grid)
    rng = np.random.default_rng(1)
    k1, k2 = 40, 100  # -9 deg and +6 deg

    def looks(amps):
        x = np.zeros((4, 4), np.complex64)
        for k, a in amps:
            x += (a * np.exp(2j * _m.pi * rng.random((4, 1)))) * steer[k][None, :] * 2.0
        return x

    one = looks([(k1, 1.0)])
    two = looks([(k1, 1.0), (k2, 1.0)])
    snaps = np.stack([one, two])
    kept = np.ones((2, 4), bool)
    coh = peak_coherence(snaps, steer, np.array([k1, k1]), kept)
    assert coh[0] > 0.999 and coh[1] < 0.8, coh
    # a left-out look does not count; an empty input is fine
    kept[1, 1:] = False
    assert peak_coherence(snaps[1:], steer, np.array([k1]), kept[1:])[0] < 0.8
    assert peak_coherence(np.zeros((0, 4, 4), np.complex64), steer, np.zeros(0, int), np.zeros((0, 4), bool)).size == 0
