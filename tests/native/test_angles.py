"""The angle kernel (edge/native/_angles.pyx: the Bartlett consensus after numpy's beamforming product) against its
numpy reference (edge.dsp.angle.bartlett_consensus): the same azimuths, spectra and agreeing/used looks bit for bit,
on random snapshots (vehicles sharing looks, outliers, noise-only looks, ties) and on the snapshots recorded in the
lane stage fixtures (hw_sim frames)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from edge.dsp.angle import bartlett_consensus, beamform
from edge.lane.angles import AngleStage
from edge.pipelines.lane import LaneConfig
from hw_sim.boards import SIMO_BOARD
from tests.native.conftest import require_kernel

FE = SIMO_BOARD.frontend
LAM = FE.waveform.wavelength_m


def _stage(**overrides) -> AngleStage:
    return AngleStage(FE, dataclasses.replace(LaneConfig(), **overrides), want_looks=False)


def _assert_same(out, ref) -> None:
    for name, x, y in zip(("az", "spectrum", "kept", "used"), out, ref):
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)
        np.testing.assert_array_equal(x.view(np.uint8), y.view(np.uint8), err_msg=name)  # bits (NaN, -0)


def _random_snaps(rng, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 4 looks, 4 rx) snapshots of one source each (a few looks replaced by another source or by noise), peak
    bins (some shared between detections) and speeds (pairs of detections at one speed)."""
    m = np.arange(FE.n_rx)
    az = np.radians(rng.uniform(-25.0, 25.0, n))
    ph = -2j * np.pi * m[None, :] * FE.rx_spacing_m * np.sin(az)[:, None] / LAM  # (n, rx)
    amp = 10 ** (rng.uniform(0.0, 3.0, n) / 2)
    snaps = amp[:, None, None] * np.exp(ph)[:, None, :] * np.exp(2j * np.pi * rng.random((n, 4, 1)))
    snaps = snaps + (rng.normal(size=snaps.shape) + 1j * rng.normal(size=snaps.shape)) * 0.3
    other = rng.random((n, 4)) < 0.15
    o_az = np.radians(rng.uniform(-19.0, 19.0, (n, 4)))
    o = np.exp(-2j * np.pi * m * FE.rx_spacing_m * np.sin(o_az)[..., None] / LAM) * 5.0
    snaps = np.where(other[..., None], snaps + o, snaps)
    if n:
        snaps[rng.integers(0, n), rng.integers(0, 4)] = 0.0  # an empty look (the 1e-30 floor)
    bins = rng.integers(0, 40, (n, 4))
    speeds = np.round(rng.uniform(-30.0, 30.0, n), 1).astype(np.float32)
    if n > 2:
        speeds[1] = speeds[0]
    return snaps.astype(np.complex64), bins, speeds


@pytest.mark.parametrize("seed", range(30))
def test_kernel_equals_reference_on_random_snapshots(seed):
    require_kernel("_angles")
    rng = np.random.default_rng(seed)
    overrides = [{}, {"angle_skip_shared_looks": False}, {"angle_shared_bins": 3, "angle_shared_speed_mps": 0.0},
                 {"angle_min_agreeing": 2}, {"angle_outlier_lateral_m": 0.0}]
    stage = _stage(**overrides[seed % len(overrides)])
    assert stage.kernel is not None
    n_used_diff = 0
    for n in (1, 2, 5, 12, 30):
        snaps, bins, speeds = _random_snaps(rng, n)
        outlier = (np.float32(math.radians(4.0)) if n % 2
                   else np.maximum(np.float32(0.07), np.float32(2.0) / rng.uniform(5.0, 100.0, n).astype(np.float32)))
        ref = stage.reference(snaps, outlier, bins, speeds)
        _assert_same(stage.consensus(snaps, outlier, bins, speeds), ref)
        n_used_diff += int((ref[2] != ref[3]).sum())
    if stage.config.angle_skip_shared_looks:
        assert n_used_diff > 0  # the shared-look rule left looks out


@pytest.mark.parametrize("seed", range(10))
def test_kernel_window_near_the_radar_equals_numpy(seed):
    """consensus with the pairings' ranges (the stage's call): the window widened near the radar in the kernel
    (max(outlier, lateral / max(range, 1)) in float32) against outlier_window's numpy and the reference, with ranges
    below 1 m, exactly 1 m, NaN and far; and for float64 ranges (the numpy window then)."""
    require_kernel("_angles")
    rng = np.random.default_rng(50 + seed)
    stage = _stage(**[{}, {"angle_outlier_lateral_m": 4.0, "angle_outlier_deg": 0.5}][seed % 2])
    for n in (1, 2, 7, 20):
        snaps, bins, speeds = _random_snaps(rng, n)
        p_rng = rng.choice([0.25, 1.0, 3.0, 7.5, 40.0, 250.0], n).astype(np.float32)
        if n > 3:
            p_rng[rng.integers(0, n)] = np.nan
        window = stage.outlier_window(stage._outlier_rad, p_rng)
        assert window.dtype == np.float32
        ref = stage.reference(snaps, window, bins, speeds)
        _assert_same(stage.consensus(snaps, stage._outlier_rad, bins, speeds, p_rng), ref)
        _assert_same(stage.consensus(snaps, window, bins, speeds), ref)
        ref64 = stage.reference(snaps, stage.outlier_window(stage._outlier_rad, p_rng.astype(np.float64)), bins,
                                speeds)
        _assert_same(stage.consensus(snaps, stage._outlier_rad, bins, speeds, p_rng.astype(np.float64)), ref64)


@pytest.mark.parametrize("stem", ["lane_stages_misaimed_s31", "lane_stages_side_by_side_s31",
                                  "lane_stages_wrong_way_s6"])
def test_kernel_equals_reference_on_recorded_snapshots(stem):
    kern = require_kernel("_angles")
    from tests.edge import lane_golden as g

    data, meta = g.load(g.fixture_path(stem))
    fr = g.Frames(data)
    re, im = (np.array(v) for v in meta["steer"])
    steer = (re + 1j * im).astype(meta["steer_dtype"])
    grid = np.array(meta["grid"], np.float32)
    kw = meta["angle_kw"]
    n_frames = n_det = 0
    for k in range(meta["frames"]):
        if not fr.has("angle_az", k):
            continue
        snaps = fr.get("angle_in_snaps", k)
        outlier, pk, speeds = fr.get("angle_in_outlier", k), fr.get("angle_in_pk", k), fr.get("angle_in_speeds", k)
        ref = bartlett_consensus(snaps, steer, grid, outlier, pk if kw["peak_bins"] else None, kw["shared_bins"],
                                 kw["min_agreeing"], speeds=speeds, min_speed_diff=kw["min_speed_diff"])
        y = beamform(snaps, steer)
        out = kern.consensus(y.view(np.float32), grid, np.ascontiguousarray(outlier, np.float32),
                             np.ascontiguousarray(pk, np.int64) if kw["peak_bins"] else None, kw["shared_bins"],
                             kw["min_agreeing"], 2, np.ascontiguousarray(speeds, np.float32),
                             np.float32(kw["min_speed_diff"]))
        _assert_same((out[0], out[1], out[2].view(bool), out[3].view(bool)), ref)
        n_frames += 1
        n_det += snaps.shape[0]
    assert n_frames > 100 and n_det > 200


@pytest.mark.parametrize("seed", range(6))
def test_kernel_equals_reference_on_flat_empty_and_nan_looks(seed):
    """Looks whose angle spectrum is flat (one receive channel: every angle ties), nearly flat (ties after the
    normalisation), empty (the 1e-30 floor) or NaN: the first largest angle as numpy's argmax, bit for bit."""
    require_kernel("_angles")
    rng = np.random.default_rng(900 + seed)
    stage = _stage()
    for n in (1, 3, 8):
        snaps, bins, speeds = _random_snaps(rng, n)
        i = rng.integers(0, n, 4)
        snaps[i[0], 0] = 0
        snaps[i[0], 0, 0] = 3.0 + 1.0j  # flat
        snaps[i[1], 1] = 0
        snaps[i[1], 1, :2] = (2.0, 1e-4j)  # nearly flat
        snaps[i[2], 2] = 0  # empty
        if seed % 2:
            snaps[i[3], 3, 1] = np.nan  # NaN at every angle
        outlier = np.float32(math.radians(4.0))
        ref = stage.reference(snaps, outlier, bins, speeds)
        _assert_same(stage.consensus(snaps, outlier, bins, speeds), ref)
