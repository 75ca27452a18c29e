"""The resolver kernel (edge/native/_resolve.pyx: CellResolver.step in one call) against its numpy reference
(CellResolver.reference_step): the same splits, angles, two-source hints and every cell's state bit for bit, on random
frames (vehicles side by side, cells created, dropped and cut, empty looks and frames) and on the resolver inputs
recorded in the lane stage fixtures (hw_sim frames); its eigenvalues against LAPACK's to float64 rounding."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from edge.dsp.angle import steering_matrix
from edge.lane.resolve import CellResolver, ResolverConfig
from hw_sim.boards import SIMO_BOARD
from tests.native.conftest import require_kernel

D, LAM = 0.0186, 0.01244
GRID = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
STEER = steering_matrix(4, D, LAM, GRID)


def _pair(kern, **cfg) -> tuple[CellResolver, CellResolver]:
    res = CellResolver(ResolverConfig(**cfg), STEER, GRID, 0.033, D / LAM, kernel=kern)
    ref = CellResolver(ResolverConfig(**cfg), STEER, GRID, 0.033, D / LAM)
    assert res.kernel is not None and ref.kernel is None
    return res, ref


def _assert_same_step(res: CellResolver, ref: CellResolver, rng_m, v, snaps, az) -> np.ndarray:
    a = res.step(rng_m, v, snaps, az)
    b = ref.step(rng_m, v, snaps, az)
    for name, x, y in (("split", a[0], b[0]), ("angles", a[1], b[1]), ("two", res.two_sources, ref.two_sources)):
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)
    c, d = res.cells, ref.cells
    np.testing.assert_array_equal(c.range_m, np.array(d.range_m, np.float64).reshape(-1))
    np.testing.assert_array_equal(c.v_mps, np.array(d.v_mps, np.float64).reshape(-1))
    assert c.cov.dtype == d.cov.dtype == np.complex64
    np.testing.assert_array_equal(c.cov.view(np.float32), d.cov.view(np.float32))  # (bits, not only values)
    for name in ("n", "misses", "streak"):
        np.testing.assert_array_equal(getattr(c, name), np.array(getattr(d, name), np.int64).reshape(-1))
    return a[0]


def _frame(rng, t: int):
    """Up to 8 vehicles (the first two side by side, one slow), noisy looks, one look left out."""
    n = int(rng.integers(0, 9))
    r0 = np.array([30.0, 30.0, 55.0, 80.0, 12.0, 100.0, 140.0, 60.0])[:n] - 0.9 * t * 0.033 * 25.0 % 60.0
    rng_m = (np.abs(r0) + 5.0 + rng.normal(0.0, 0.2, n)).astype(np.float32)
    v = np.array([-25.0, -25.0, 20.0, -30.0, 0.5, 22.0, -10.0, 15.0])[:n].astype(np.float32)
    th = np.array([-0.06, 0.06, 0.1, -0.2, 0.0, 0.05, 0.15, -0.1])[:n] + rng.normal(0.0, 0.003, n)
    m = np.arange(4)[None, :]
    a = np.exp(-2j * np.pi * (D / LAM) * m * np.sin(th)[:, None])
    b = np.exp(-2j * np.pi * (D / LAM) * m * np.sin(-th)[:, None])
    ph = np.exp(2j * np.pi * rng.random((n, 4, 1)))
    amp = 10 ** rng.uniform(-1.0, 2.0, (n, 1, 1))
    snaps = amp * (a[:, None, :] + ph * b[:, None, :] * (np.arange(n) < 2)[:, None, None]
                   + 0.05 * (rng.normal(size=(n, 4, 4)) + 1j * rng.normal(size=(n, 4, 4))))
    snaps = snaps.astype(np.complex64)
    if n:
        snaps[0, 3] = 0.0  # a look left out
    return rng_m, v, snaps, th.astype(np.float32)


@pytest.mark.parametrize("seed,cfg", [
    (0, {}), (1, {"follow_direction": False}), (2, {"max_cells": 5, "min_frames": 3, "min_split_frames": 2}),
    (3, {"min_frames": 3, "min_split_frames": 2, "min_lateral_m": 1.0}), (4, {"max_misses": 0, "memory_frames": 3.0}),
    (5, {"min_eig_ratio": 0.01, "min_power_ratio": 0.01, "min_lateral_m": 0.5, "min_frames": 2}),
])
def test_kernel_equals_reference_on_random_frames(seed, cfg):
    kern = require_kernel("_resolve")
    res, ref = _pair(kern, **cfg)
    rng = np.random.default_rng(seed)
    n_split = n_two = n_det = 0
    for t in range(160):
        rng_m, v, snaps, az = _frame(rng, t)
        split = _assert_same_step(res, ref, rng_m, v, snaps, az)
        n_split += int(split.sum())
        n_two += int(res.two_sources.sum())
        n_det += rng_m.size
    assert n_det > 400 and n_two > 20
    if cfg.get("min_frames", 6) <= 3:
        assert n_split > 0  # splits happen
    if "max_cells" in cfg:
        assert len(res.cells.range_m) <= cfg["max_cells"]


def test_kernel_converts_other_arrays():
    """The kernel on float64, strided and complex128 detections gives what it gives on their float32 / complex64
    C-contiguous forms (the stage's former conversions); the cell table stays complex64 and C-contiguous."""
    kern = require_kernel("_resolve")
    res = CellResolver(ResolverConfig(min_frames=3, min_split_frames=2), STEER, GRID, 0.033, D / LAM, kernel=kern)
    other = copy.deepcopy(res)
    rng = np.random.default_rng(12)
    n_split = 0
    for t in range(60):
        rng_m, v, snaps, az = _frame(rng, t)
        a = res.step(rng_m, v, snaps, az)
        b = other.step(rng_m.astype(np.float64), np.repeat(v, 2)[::2], snaps.astype(np.complex128),
                       list(az.astype(np.float64)) if az.size else az)
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x.view(np.uint8), y.view(np.uint8))
        for name in ("range_m", "v_mps", "cov", "n", "misses", "streak"):
            x, y = getattr(res.cells, name), getattr(other.cells, name)
            assert x.dtype == y.dtype and x.shape == y.shape, name
            np.testing.assert_array_equal(x.view(np.uint8), y.view(np.uint8), err_msg=name)
        assert res.cells.cov.dtype == np.complex64 and res.cells.cov.flags.c_contiguous
        n_split += int(a[0].sum())
    assert n_split > 0


def test_kernel_follows_a_copy_and_starts_empty():
    """A deep copy carries the kernel and the cell table; reset empties it."""
    kern = require_kernel("_resolve")
    res, ref = _pair(kern, min_frames=3, min_split_frames=2)
    rng = np.random.default_rng(9)
    for t in range(20):
        _assert_same_step(res, ref, *_frame(rng, t))
    res2, ref2 = copy.deepcopy(res), copy.deepcopy(ref)
    assert res2.kernel is kern
    for t in range(20, 40):
        _assert_same_step(res2, ref2, *_frame(rng, t))
    res.reset()
    assert len(res.cells.range_m) == 0 and res.cells.cov.shape == (0, 4, 4)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.sampled_from([1e-6, 1e-3, 0.05, 1.0]))
def test_kernel_eigenvalues_equal_lapack_to_float64_rounding(seed, noise):
    kern = require_kernel("_resolve")
    rng = np.random.default_rng(seed)
    x = (rng.normal(size=(8, 4, 3)) + 1j * rng.normal(size=(8, 4, 3))) * np.array([1.0, 0.3, noise])
    cov = np.einsum("kar,kbr->kab", x, x.conj()).astype(np.complex64)
    w = kern.eigvals(np.ascontiguousarray(cov).view(np.float32))
    ref = np.linalg.eigvalsh(cov.astype(np.complex128))
    np.testing.assert_allclose(w, ref, rtol=0, atol=1e-13 * np.abs(ref).max())


@pytest.mark.parametrize("stem", ["lane_stages_side_by_side_s31", "lane_stages_misaimed_s31",
                                  "lane_stages_wrong_way_s6"])
def test_kernel_equals_reference_on_recorded_frames(stem):
    """The resolver inputs recorded from hw_sim frames through the pipeline, every frame in order."""
    kern = require_kernel("_resolve")
    from tests.edge import lane_golden as g

    data, meta = g.load(g.fixture_path(stem))
    fr = g.Frames(data)
    re, im = (np.array(v) for v in meta["steer"])
    steer = (re + 1j * im).astype(meta["steer_dtype"])
    grid = np.array(meta["grid"], np.float32)
    wf = SIMO_BOARD.frontend.waveform
    args = (ResolverConfig(), steer, grid, wf.frame_period_s, SIMO_BOARD.frontend.rx_spacing_m / wf.wavelength_m)
    res, ref = CellResolver(*args, kernel=kern), CellResolver(*args)
    n_frames = n_det = n_two = 0
    min_agreeing = meta["angle_kw"]["min_agreeing"]
    for k in range(meta["frames"]):
        if not fr.has("res_in_rng", k):
            continue
        looks = g._looks(fr.get("angle_in_snaps", k), fr.get("angle_kept", k), fr.get("angle_used", k), min_agreeing)
        _assert_same_step(res, ref, fr.get("res_in_rng", k), fr.get("res_in_vel", k), looks, fr.get("res_in_az", k))
        n_frames += 1
        n_det += looks.shape[0]
        n_two += int(res.two_sources.sum())
    assert n_frames > 100 and n_det > 100 and n_two > 0
