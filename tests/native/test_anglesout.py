"""The angle stage's output kernel (edge/native/_anglesout.pyx: SNR, kept pairings, the resolver's looks) against the
stage's numpy form (AngleStage with ``_k_out`` None): the same Angles record bit for bit, on random spectra and
pairings (noise NaN away from local maxima, track-aided pairings on such bins) and on seeded hw_sim runs through the
lane pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from edge.lane.angles import AngleStage
from edge.lane.records import PairList, Spectra
from edge.pipelines.lane import LaneConfig
from hw_sim.boards import SIMO_BOARD
from tests.native.conftest import require_kernel

FE = SIMO_BOARD.frontend


def _assert_same(a, b) -> None:
    for name in ("range_m", "radial_speed_mps", "residual_hz", "az_rad", "snr_db", "resolved_pair", "spectrum",
                 "looks"):
        x, y = getattr(a, name), getattr(b, name)
        if y is None:
            assert x is None, name
            continue
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(np.ascontiguousarray(x).view(np.uint8), np.ascontiguousarray(y).view(np.uint8),
                                      err_msg=name)  # bits (NaN, -0)
    assert a.unresolved_pair is None and b.unresolved_pair is None


@pytest.mark.parametrize("seed", range(12))
def test_kernel_equals_numpy_on_random_pairings(seed):
    kern = require_kernel("_anglesout")
    rng = np.random.default_rng(seed)
    stage = AngleStage(FE, LaneConfig(), want_looks=bool(seed % 3))
    n_seg, n_bin = FE.frame_shape[1], FE.frame_shape[2]
    pad = 8
    n_kept = 0
    for n in (1, 3, 10, 25):
        spec = ((rng.normal(size=FE.frame_shape) + 1j * rng.normal(size=FE.frame_shape))
                * 10 ** rng.uniform(-3, 1)).astype(np.complex64)
        power = (np.abs(spec) ** 2).sum(axis=0).astype(np.float32)
        ppad = np.concatenate([power[:, -pad:], power, power[:, :pad]], axis=1)
        noise = np.where(rng.random((n_seg, n_bin)) < 0.3, power * np.float32(0.1), np.float32(np.nan))
        noise[0, :3] = 0.0  # (the 1e-30 floor)
        floor = np.median(power, axis=1).astype(np.float32)
        bins = rng.integers(0, n_bin, (n, 4)).astype(np.int64)
        pairs = PairList(bins, rng.uniform(5, 300, n).astype(np.float32), rng.uniform(-30, 30, n).astype(np.float32),
                         rng.uniform(0, 50, n).astype(np.float32))
        spectra = Spectra(spec, ppad, pad)
        stage._k_out = kern
        a = stage(spectra, noise, floor, pairs)
        stage._k_out = None
        b = stage(spectra, noise, floor, pairs)
        _assert_same(a, b)
        n_kept += b.range_m.size
    assert n_kept > 0


@pytest.mark.parametrize("scenario,frames", [("highway4-traffic", 120), ("side-by-side", 150)])
def test_kernel_equals_numpy_on_a_pipeline_run(scenario, frames):
    kern = require_kernel("_anglesout")
    from edge.pipeline import StageTimer
    from tests.edge import lane_golden as g

    pipe, it = g.build(scenario, 1, 5.0)
    stage = pipe.angles
    assert stage._k_out is kern
    real = type(stage).__call__
    seen = {"frames": 0, "kept": 0, "looks": 0}

    def both(spectra, noise, floor, pairs):
        a = real(stage, spectra, noise, floor, pairs)
        stage._k_out = None
        try:
            b = real(stage, spectra, noise, floor, pairs)
        finally:
            stage._k_out = kern
        _assert_same(a, b)
        seen["frames"] += 1
        seen["kept"] += a.range_m.size
        seen["looks"] += 0 if a.looks is None else int((a.looks != 0).any(axis=2).sum())
        return a

    # the pipeline calls its stage object: a stand-in that runs both forms
    pipe.angles = type("Wrapped", (), {"__call__": staticmethod(both), "grid": stage.grid})()
    t = StageTimer(16)
    for f in it(frames):
        pipe.process(f, t)
    assert seen["frames"] == frames and seen["kept"] > 100 and seen["looks"] > 100, seen


def test_finish_converts_other_layouts():
    """finish on Fortran-ordered, strided and uint8 inputs gives what it gives on their C-contiguous forms."""
    kern = require_kernel("_anglesout")
    rng = np.random.default_rng(7)
    n, n_seg, n_bin, pad = 9, 4, 64, 3
    power = rng.gamma(2.0, 1.0, (n_seg, n_bin)).astype(np.float32)
    ppad = np.concatenate([power[:, -pad:], power, power[:, :pad]], axis=1)
    noise = np.where(rng.random((n_seg, n_bin)) < 0.5, power * np.float32(0.1), np.float32(np.nan))
    pk = rng.integers(0, n_bin, (n, 4)).astype(np.int64)
    cols = [rng.uniform(1, 100, n).astype(np.float32) for _ in range(4)]
    kept = rng.random((n, 4)) < 0.8
    used = kept & (rng.random((n, 4)) < 0.8)
    snaps = (rng.normal(size=(n, 4, 4)) + 1j * rng.normal(size=(n, 4, 4))).astype(np.complex64)
    base = kern.finish(ppad, pad, noise, np.float32(0.5), pk, *cols, kept, used, snaps, 3, True)
    other = kern.finish(np.asfortranarray(ppad), pad, np.asfortranarray(noise), np.float32(0.5), np.asfortranarray(pk),
                        *(np.repeat(c, 2)[::2] for c in cols), kept.view(np.uint8), np.asfortranarray(used),
                        snaps.transpose(2, 0, 1).copy().transpose(1, 2, 0), 3, True)
    assert len(base) == 7 and base[6].dtype == np.int32 and (base[6] == -1).all() and base[0].size > 0
    for a, b in zip(base, other):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a.view(np.uint8), b.view(np.uint8))
    with pytest.raises(IndexError):
        kern.finish(ppad, pad, noise, np.float32(0.5), pk + n_bin, *cols, kept, used, snaps, 3, True)
