"""The track-aided pairing's selection and fit kernels (edge/native/_aided.pyx ``select_predictions``, ``fit_prep``,
``fit_finish``) against their numpy references (PairStage.aided_selection with reference_predictions, the einsums of
PairStage._aided_fit, the whole _aided_fit): the same tracks, ranges, speeds, beats, bins and residuals bit for bit, on
random tracks and fits (every set of found segments, strided and uint8 arrays) and on a seeded hw_sim run."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge.dsp.pairing import Pairs
from edge.lane.records import Feedback
from hw_sim import SIMO_BOARD
from tests.native.conftest import require_kernel


def _stage(**overrides):
    from edge.pipelines.lane import LaneConfig, LanePipeline

    return LanePipeline(SIMO_BOARD.frontend, dataclasses.replace(LaneConfig(), **overrides)).pairs


def _same(a, b) -> None:
    assert type(a) is type(b) and a.dtype == b.dtype and a.shape == b.shape, (a, b)
    assert a.tobytes() == b.tobytes()


def _select_args(stage, fb, dt, pairs):
    cfg = stage.config
    dz = cfg.mounting_height_m - cfg.target_height_m
    return (fb.track_state, fb.confirmed, fb.moved, fb.hits, dt, pairs.range_m, pairs.radial_speed_mps, dz * dz,
            cfg.min_range_m, cfg.max_range_m, cfg.aided_gate_m, cfg.aided_gate_mps, stage._coef,
            cfg.aided_tentative_min_range_m, cfg.aided_tentative_min_hits, cfg.aided_tentative_approaching)


def _random_tracks(rng, n):
    x = np.stack([rng.uniform(-8.0, 8.0, n), rng.uniform(-20.0, 380.0, n), rng.normal(0.0, 0.5, n),
                  rng.choice([-30.0, -0.5, 25.0], n)], axis=1)
    if n:  # some on the far-range limit itself
        x[0, 0], x[0, 1] = 0.0, 200.0
    return x


@pytest.mark.parametrize("overrides", [{}, {"aided_tentative_min_range_m": 0.0},
                                       {"aided_tentative_approaching": False},
                                       {"aided_tentative_min_range_m": 120.0, "aided_tentative_min_hits": 4}])
def test_select_predictions_equals_selection_and_predictions(overrides):
    k = require_kernel("_aided")
    stage = _stage(**overrides)
    rng = np.random.default_rng(7)
    n_kept = n_far = 0
    for t in range(120):
        n = int(rng.integers(0, 25))
        x = _random_tracks(rng, n)
        hits_dtype = (np.int32, np.int64)[t % 2]
        fb = Feedback(t_ns=0, track_state=x, confirmed=rng.random(n) < 0.4, moved=rng.random(n) < 0.7,
                      hits=rng.integers(0, 6, n).astype(hits_dtype))
        dt = float(rng.choice([0.0, 0.033, 0.066]))
        xp, yp = x[:, 0] + x[:, 2] * dt, x[:, 1] + x[:, 3] * dt
        r = np.sqrt(xp * xp + yp * yp + 6.5 ** 2)
        v = (xp * x[:, 2] + yp * x[:, 3]) / np.maximum(r, 1e-9)
        kk = rng.random(n) < 0.3
        pr = (r[kk] + rng.choice([0.0, 2.4, 2.6, -2.6], kk.sum())).astype(np.float32)
        pv = (v[kk] + rng.choice([0.0, 1.4, 1.6], kk.sum())).astype(np.float32)
        pairs = Pairs(np.zeros((pr.size, 4), np.int64), pr, pv, np.zeros(pr.size, np.float32), 0, 0)
        sel = stage.aided_selection(fb)
        n_far += int(np.count_nonzero(~fb.confirmed[sel]))
        ref = stage.reference_predictions(x, sel, dt, pairs)
        out = k.select_predictions(*_select_args(stage, fb, dt, pairs))
        if ref is None:
            assert out[0].size == 0
        else:
            for a, b in zip(out, ref):
                _same(a, b)
            n_kept += ref[0].size
        if t % 5 == 0 and n:  # a strided state and a strided bool column
            xs = np.zeros((n, 6))
            xs[:, :4] = x
            fb2 = Feedback(t_ns=0, track_state=xs[:, :4], confirmed=np.repeat(fb.confirmed, 2)[::2],
                           moved=np.repeat(fb.moved, 3)[::3], hits=fb.hits)
            out2 = k.select_predictions(*_select_args(stage, fb2, dt, pairs))
            for a, b in zip(out2, out):
                _same(a, b)
    assert n_kept > 100
    if overrides.get("aided_tentative_min_range_m", 1.0) > 0:
        assert n_far > 10


def test_select_predictions_declines_other_types():
    k = require_kernel("_aided")
    stage = _stage()
    x = _random_tracks(np.random.default_rng(1), 4)
    pairs = Pairs(np.zeros((0, 4), np.int64), np.zeros(0, np.float32), np.zeros(0, np.float32),
                  np.zeros(0, np.float32), 0, 0)
    fb = Feedback(t_ns=0, track_state=x, confirmed=np.ones(4, bool), moved=np.ones(4, bool),
                  hits=np.ones(4, np.int32))
    assert k.select_predictions(*_select_args(stage, fb, 0.0, pairs)) is not None
    for bad in (dict(track_state=x.astype(np.float32)), dict(track_state=x[:, :3]), dict(hits=np.ones(4)),
                dict(confirmed=np.ones(4, np.int32)), dict(moved=np.ones(3, bool)),
                dict(moved=np.ones(4, np.uint8)), dict(confirmed=np.ones(4, np.uint8))):
        assert k.select_predictions(*_select_args(stage, dataclasses.replace(fb, **bad), 0.0, pairs)) is None
    p64 = dataclasses.replace(pairs, range_m=np.zeros(0), radial_speed_mps=np.zeros(0))
    assert k.select_predictions(*_select_args(stage, fb, 0.0, p64)) is None


def _random_fit(rng, stage, m, min_seg):
    """A fit's inputs: found segments (every set), frequencies near the predictions of tracks ``r_hat``, ``v_hat``."""
    r_hat = rng.uniform(3.0, 380.0, m)
    v_hat = rng.uniform(-45.0, 45.0, m)
    f_hat = stage.model.predict(r_hat, v_hat)
    found = rng.random((m, 4)) < 0.75
    found[: min(m, 16)] = (np.arange(16)[: min(m, 16), None] >> np.arange(4)) & 1 == 1
    good = found.sum(axis=1) >= min_seg
    jitter = rng.normal(0.0, 1.0, (m, 4)) * stage.bin_hz * rng.choice([0.1, 1.0, 30.0], (m, 1))
    fsel = np.where(found, f_hat + jitter, 0.0)
    bsel = np.where(found, rng.integers(0, 256, (m, 4)), -1).astype(np.int64)
    if m:
        f_hat[0, 0] = -0.5 * stage.bin_hz[0]  # a prediction at half a bin below zero (rint's tie, the modulo)
    return found, fsel, good, r_hat, v_hat, f_hat, bsel


@pytest.mark.parametrize("seed", range(6))
def test_fit_prep_equals_einsum(seed):
    k = require_kernel("_aided")
    stage = _stage()
    rng = np.random.default_rng(seed)
    A = stage._model_ab
    for m in (0, 1, 2, 5, 16, 40):
        found, fsel, good, *_ = _random_fit(rng, stage, m, (1, 2, 3)[seed % 3])
        w_ref = found[good].astype(np.float64)
        fs_ref = fsel[good]
        nrm_ref = np.einsum("mk,ki,kj->mij", w_ref, A, A)
        rhs_ref = np.einsum("mk,ki,mk->mi", w_ref, A, fs_ref)[:, :, None]
        for f_in, s_in, g_in in ((found, fsel, good), (found.view(np.uint8), np.asfortranarray(fsel), good.view(np.uint8))):
            w, fs, nrm, rhs, masks = k.fit_prep(f_in, s_in, g_in, A)
            for a, b in ((w, w_ref), (fs, fs_ref), (nrm, nrm_ref), (rhs, rhs_ref)):
                _same(a, b)
            want = 0
            for row in found[good]:
                want |= 1 << int(row @ (1 << np.arange(4)))
            assert masks == want


@pytest.mark.parametrize("seed", range(8))
def test_aided_fit_kernel_equals_reference(seed):
    require_kernel("_aided")
    min_seg = (2, 3, 4, 4)[seed % 4]
    stage = _stage(aided_min_segments=min_seg)
    rng = np.random.default_rng(50 + seed)
    n_out = 0
    for m in (1, 2, 3, 7, 16, 30, 80):
        found, fsel, good, r_hat, v_hat, f_hat, bsel = _random_fit(rng, stage, m, min_seg)
        if not good.any():
            continue
        ref = stage._aided_fit(found, fsel, good, r_hat, v_hat, f_hat, bsel)
        for f_in, g_in in ((found, good), (found.view(np.uint8), good.view(np.uint8))):
            out = stage._aided_fit_kernel(f_in, fsel, g_in, r_hat, v_hat, f_hat, bsel)
            assert out is not None
            for a, b in zip(out, ref):
                _same(a, b)
        n_out += ref[1].size
    assert n_out > 10


def test_aided_fit_kernel_declines_a_singular_fit():
    """A normal matrix that np.linalg.solve refuses (no segment found; one segment alone, when LAPACK's pivot is an
    exact zero): the kernel path declines, and the reference raises np.linalg.LinAlgError as before."""
    require_kernel("_aided")
    stage = _stage(aided_min_segments=1)
    sing = stage.singular_masks()
    assert sing & 1 and not sing & (1 << 0b1111) and not sing & (1 << 0b0011)
    b = next(b for b in (1, 2, 4, 8) if sing & (1 << b))
    rng = np.random.default_rng(3)
    found, fsel, good, r_hat, v_hat, f_hat, bsel = _random_fit(rng, stage, 16, 1)
    found[3] = (b >> np.arange(4)) & 1 == 1
    fsel[3] = np.where(found[3], f_hat[3], 0.0)
    good[3] = True
    assert stage._aided_fit_kernel(found, fsel, good, r_hat, v_hat, f_hat, bsel) is None
    with pytest.raises(np.linalg.LinAlgError):
        stage._aided_fit(found, fsel, good, r_hat, v_hat, f_hat, bsel)
    good &= [not sing & (1 << int(row @ (1 << np.arange(4)))) for row in found]  # without such rows: the same fit
    for x, y in zip(stage._aided_fit_kernel(found, fsel, good, r_hat, v_hat, f_hat, bsel),
                    stage._aided_fit(found, fsel, good, r_hat, v_hat, f_hat, bsel)):
        _same(x, y)


def test_track_aided_kernels_equal_reference_in_the_pipeline(monkeypatch):
    """Every track_aided call of a seeded highway4-traffic run (150 frames): the kernels' selection, predictions,
    search and fit give the numpy reference's pairs (the stage's kernels switched off) bit for bit."""
    require_kernel("_aided")
    require_kernel("_pairs")
    from edge.pipeline import StageTimer
    from tests.edge import lane_golden as g

    pipe, frames = g.build("highway4-traffic", 1, 5.0)
    stage = pipe.pairs
    real = stage.track_aided
    n = {"calls": 0, "pairs": 0}

    def spy(*args):
        out = real(*args)
        kp, ka = stage.kernel, stage._k_aided_pred
        stage.kernel = stage._k_aided_pred = None
        try:
            ref = real(*args)
        finally:
            stage.kernel, stage._k_aided_pred = kp, ka
        assert len(out) == len(ref) == 4
        for a, b in zip(out, ref):
            _same(a, b)
        n["calls"] += 1
        n["pairs"] += ref[1].size
        return out

    monkeypatch.setattr(stage, "track_aided", spy)
    t = StageTimer(16)
    for f in frames(150):
        pipe.process(f, t)
    assert n["calls"] > 50 and n["pairs"] > 5, n
