"""Known-answer tests of the lane profile's near-range and body-ghost handling (issue 3, detection probability):
the wider pairing tolerance near the radar, the per-detection angle-agreement window, the exact ghosts of a long
vehicle's equally spaced scatterers and its near face, and the lower track-aided threshold."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.dsp.angle import bartlett_consensus, steering_matrix
from edge.dsp.pairing import PairingModel, nearest_of_clusters, pair_beats
from edge.pipelines.lane import LaneConfig, LanePipeline
from hal.waveform import simo_frontend

FE = simo_frontend()
LAM = FE.waveform.wavelength_m
MODEL = PairingModel.from_waveform(FE.waveform)
SLOW_BIN_HZ = FE.waveform.segments[2].sample_rate_hz / FE.waveform.n_samples
TOL = (SLOW_BIN_HZ, SLOW_BIN_HZ)  # one slow bin, the default pair_tolerance_bins
KW = dict(min_range_m=5.0, max_range_m=375.0, max_speed_mps=70.0, tolerance_hz=TOL)
CFG = LaneConfig()


def _cluster_kw(cfg: LaneConfig = CFG) -> dict:
    return dict(length_m=cfg.cluster_length_m, speed_mps=cfg.cluster_speed_mps, lateral_m=cfg.cluster_lateral_m)


@pytest.mark.parametrize("range_m,paired", [(20.0, True), (60.0, False)])
def test_near_tolerance_pairs_a_near_target_whose_slow_peak_is_off_by_more_than_a_bin(range_m, paired):
    """A slow-down peak 1.2 slow bins off the fast pair's prediction: paired within pair_near_range_m with
    pair_near_tolerance_bins (1.5), rejected as a ghost farther out (1.0)."""
    f = MODEL.predict(np.array([range_m]), np.array([27.0]))[0]
    freqs = (f[[0]], f[[1]], f[[2]], f[[3]] + 1.2 * SLOW_BIN_HZ)
    near_tol = (CFG.pair_near_tolerance_bins * SLOW_BIN_HZ,) * 2
    out = pair_beats(freqs, MODEL, **KW, near_tolerance_hz=near_tol, near_range_m=CFG.pair_near_range_m)
    assert (out.range_m.size == 1) is paired
    base = pair_beats(freqs, MODEL, **KW)  # without the near tolerance: rejected at any range
    assert base.range_m.size == 0 and base.n_ghosts == 1


def test_angle_agreement_window_per_detection():
    """The same four looks (one 3.5 deg off the others) with a 2 deg and a 5 deg window: the first leaves that
    look out, the second keeps all four."""
    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    steer = steering_matrix(4, FE.rx_spacing_m, LAM, grid)
    m = np.arange(4)
    looks = []
    for az in (8.0, 8.0, 8.0, 11.5):
        looks.append(np.exp(-2j * np.pi * m * FE.rx_spacing_m * math.sin(math.radians(az)) / LAM))
    snaps = np.repeat(np.array(looks, np.complex64)[None], 2, axis=0)  # (2 det, 4 looks, 4 rx)
    az, _, kept, _ = bartlett_consensus(snaps, steer, grid, np.radians([2.0, 5.0]).astype(np.float32))
    assert kept[0].tolist() == [True, True, True, False]
    assert kept[1].tolist() == [True, True, True, True]
    assert abs(math.degrees(az[0]) - 8.0) < 0.1 and math.degrees(az[1]) > 8.3  # the fourth look pulls it
    # a scalar window gives the same as an array of equal values
    az_s, _, kept_s, _ = bartlett_consensus(snaps, steer, grid, math.radians(2.0))
    az_a, _, kept_a, _ = bartlett_consensus(snaps, steer, grid, np.full(2, math.radians(2.0), np.float32))
    np.testing.assert_array_equal(kept_s, kept_a)
    np.testing.assert_array_equal(az_s, az_a)


def _truck_pairs(r0: float, v: float, spacing_m: float = 3.0, n: int = 6):
    """Pairings of a long vehicle's equally spaced scatterers (near face, sides every L/5, far face). The weak
    side scatterers 1, 3 miss the slow-up threshold and 1, 4 the slow-down one (with every peak present, the
    true pairs share the ghosts' peaks and the pairing drops them itself)."""
    r = r0 + spacing_m * np.arange(n)
    f = MODEL.predict(r, np.full(n, v))  # (n, 4)
    return pair_beats((f[:, 0], f[:, 1], np.delete(f[:, 2], [1, 3]), np.delete(f[:, 3], [1, 4])), MODEL, **KW)


def test_equally_spaced_scatterers_fit_exact_ghosts_at_v_plus_minus_u_a_over_b():
    """Scatterers at R'-2u, R'-u, R'+u, R'+2u fit a target at R' with speed v +- u a/b in all four segments:
    the ghosts fit almost as well as the true pairs (residual a few hertz, a twentieth of a slow bin: only the
    segments' different sampling times set them apart) and lie within the body, at least 2u behind its near face."""
    r0, v = 40.0, 28.0
    out = _truck_pairs(r0, v)
    ghosts = np.abs(out.radial_speed_mps - v) > 1.0
    assert ghosts.sum() >= 1
    assert out.residual_hz[ghosts].max() < 0.1 * SLOW_BIN_HZ
    a_over_b = MODEL.a[0] / MODEL.b[0]
    u = np.abs(out.radial_speed_mps[ghosts] - v) / a_over_b  # the spacing that makes each ghost
    np.testing.assert_allclose(u, np.round(u / 3.0) * 3.0, atol=0.05)  # a multiple of the scatterer spacing
    behind = out.range_m[ghosts] - r0
    assert behind.min() >= 2 * u.min() - 0.2 and behind.max() <= 15.0 - 2 * u.min() + 0.2


def test_near_faces_keep_the_truck_near_face_and_drop_its_body():
    """Of a long vehicle's pairings the near face stays and the true pairs of its body (behind it at its speed)
    go; the body's ghost pairings (off its speed) are not the body and stay (the ghost law that dropped them was
    removed in issue 29: no measurable effect on the corpus's holdout)."""
    r0, v = 40.0, 28.0
    out = _truck_pairs(r0, v)
    x = np.full(out.range_m.size, 5.2)
    keep = nearest_of_clusters(out.range_m, out.radial_speed_mps, x, **_cluster_kw())
    true = np.abs(out.radial_speed_mps - v) <= CFG.cluster_speed_mps
    assert true.sum() >= 2 and keep[true].sum() == 1
    assert out.range_m[true & keep][0] == pytest.approx(r0, abs=0.05)
    assert keep[~true].all() and (~true).any()


def test_near_faces_keep_a_car_overtaking_a_van_close_behind():
    """A car 3 m or 10 m behind a van at 2.8 or 5 m/s more is another vehicle: both are kept."""
    x = np.array([-1.75, -1.6])
    kw = _cluster_kw()
    assert nearest_of_clusters(np.array([50.0, 53.0]), np.array([20.0, 22.8]), x, **kw).tolist() == [True, True]
    assert nearest_of_clusters(np.array([50.0, 60.0]), np.array([20.0, 25.0]), x, **kw).tolist() == [True, True]
    # at the van's speed, the same spacing is its body
    assert nearest_of_clusters(np.array([50.0, 53.0]), np.array([20.0, 20.2]), x, **kw).tolist() == [True, False]


def test_aided_threshold_is_below_the_detection_threshold_and_can_be_switched_off():
    pipe = LanePipeline(FE, LaneConfig(), None, None)
    assert pipe.peaks.aided_scale32 is not None and 1.0 < pipe.peaks.aided_scale32 < pipe.cfar_scale
    assert LanePipeline(FE, LaneConfig(aided_pfa=0.0), None, None).peaks.aided_scale32 is None
    assert LanePipeline(FE, LaneConfig(tracking=False), None, None).peaks.aided_scale32 is None
