"""The exact pre-gate (edge.track.pdaf.innovations_each, prune_gamma): pairs it rules out lie outside every gate,
so the association, the updates and the published tracks are the same as without it, bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge.track import PdafConfig, PdafTracker, pdaf
from edge.track.roles import measure as measure_module
from edge.track.pdaf import association_weights, gate_threshold, innovations_each
from tests.edge.trackscene import Vehicle, frames


def _random_frame(rng, t: int, m: int):
    """``t`` tracks and ``m`` detections along a four-lane road 10-300 m out; half the detections near a track."""
    xt = np.column_stack([rng.choice([-5.25, -1.75, 1.75, 5.25], t) + rng.normal(0, 0.3, t), rng.uniform(10, 300, t),
                          rng.normal(0, 0.3, t), rng.uniform(-33, 33, t)])
    near = rng.integers(0, t, m // 2)
    z_near = xt[near, :2] + rng.normal(0, [0.8, 1.5], (near.size, 2))
    z_far = np.column_stack([rng.uniform(-8, 8, m - near.size), rng.uniform(5, 300, m - near.size)])
    xy = np.vstack([z_near, z_far])
    rho = np.hypot(xy[:, 0], xy[:, 1])
    vr = np.concatenate([(xt[near, 0] * xt[near, 2] + xt[near, 1] * xt[near, 3]) / np.hypot(xt[near, 0], xt[near, 1])
                         + rng.normal(0, 0.4, near.size), rng.uniform(-35, 35, m - near.size)])
    z = np.column_stack([xy, vr])
    h = np.zeros((t, 3, 4))
    h[:, 0, 0] = h[:, 1, 1] = 1.0
    rt = np.hypot(xt[:, 0], xt[:, 1])
    h[:, 2, 0], h[:, 2, 1] = xt[:, 2] / rt * 0.01, xt[:, 3] / rt * 0.01
    h[:, 2, 2], h[:, 2, 3] = xt[:, 0] / rt, xt[:, 1] / rt
    zh = np.column_stack([xt[:, :2], (xt[:, 0] * xt[:, 2] + xt[:, 1] * xt[:, 3]) / rt])
    a = rng.normal(0, 1, (t, 4, 4))
    p = a @ a.transpose(0, 2, 1) * rng.uniform(0.05, 2.0, (t, 1, 1)) + 0.01 * np.eye(4)
    r_track = np.zeros((t, 3, 3))
    r_track[:, 0, 0] = r_track[:, 1, 1] = rng.uniform(0.2, 3.0, t)
    r_track[:, 2, 2] = 0.09
    r_meas = np.zeros((m, 3, 3))
    var_az = (rho * np.radians(rng.uniform(0.05, 1.5, m))) ** 2
    r_meas[:, 0, 0], r_meas[:, 1, 1], r_meas[:, 0, 1] = var_az + 0.2, 0.05, rng.normal(0, 0.01, m)
    r_meas[:, 1, 0] = r_meas[:, 0, 1]
    return z, zh, h, p, r_track, r_meas


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("method", ["pdaf", "jpda"])
def test_pregate_keeps_every_gated_pair_and_the_weights(seed, method):
    rng = np.random.default_rng(seed)
    z, zh, h, p, r_track, r_meas = _random_frame(rng, 90, 140)
    gamma = gate_threshold(0.99, 3)
    full = innovations_each(z, zh, h, p, r_track, r_meas)
    pruned = innovations_each(z, zh, h, p, r_track, r_meas, gamma)
    kept = np.isfinite(pruned.d2)
    assert kept.mean() < 0.5  # the pre-gate rules most pairs out on a long road
    assert (full.d2[~kept] > gamma).all()  # ... only pairs outside the gate
    assert np.array_equal(pruned.d2[kept], full.d2[kept]) and np.array_equal(pruned.det_s[kept], full.det_s[kept])
    assert ((full.d2 <= gamma) & kept).sum() > 100  # a frame with plenty of gated pairs
    allowed = rng.uniform(size=full.d2.shape) < 0.9
    for allow in (None, allowed):
        a = association_weights(full, gamma, 0.9, 0.99, method, allow)
        b = association_weights(pruned, gamma, 0.9, 0.99, method, allow)
        for x, y in zip(a, b):
            assert np.array_equal(x, y)


def _run(pregate: bool, cfg: PdafConfig, scene, n_frames: int, seed: int):
    tr = PdafTracker(cfg)
    tr.associator.pregate = pregate
    out = [tr.step(det, t_ns) for t_ns, det, _ in frames(scene, n_frames, seed=seed, p_detect=0.9, noise="snr",
                                                        clutter_per_frame=4.0, extent_sigma_m=0.4)]
    return out, tr.tracks


@pytest.mark.parametrize("exclusion", ["constant", "snr"])
def test_tracker_outputs_are_the_same_with_and_without_the_pregate(exclusion, monkeypatch):
    """Sixteen vehicles in four lanes over 20-260 m with clutter: the published tracks and the whole track table are
    identical with and without the pre-gate (the exclusion gate's noise model sets the pre-gate's threshold)."""
    monkeypatch.setattr(pdaf, "_PREGATE_MIN_PAIRS", 0)  # on for every frame, however few the pairs
    pruned = []
    real = pdaf.innovations_each

    def spy(*args):
        inn = real(*args)
        pruned.append(int(np.isinf(inn.d2).sum()))
        return inn

    monkeypatch.setattr(measure_module, "innovations_each", spy)
    rng = np.random.default_rng(5)
    scene = [Vehicle(x, y, 0.0, v, length_m=4.5) for x, v in ((-5.25, -27.0), (-1.75, -22.0), (1.75, 25.0),
                                                                (5.25, 30.0)) for y in rng.uniform(20, 260, 4)]
    cfg = dataclasses.replace(PdafConfig(), seed_exclusion_noise=exclusion)
    (a, ta), (b, tb) = _run(True, cfg, scene, 60, 2), _run(False, cfg, scene, 60, 2)
    assert a == b
    assert sum(pruned) > 1000  # the pre-gate ruled pairs out
    assert sum(len(x) for x in a) > 200  # tracks confirmed and published
    for col in type(ta)._COLUMNS:
        assert np.array_equal(getattr(ta, col), getattr(tb, col)), col
