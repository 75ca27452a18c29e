"""Surveillance front end: IIR canceller (step initialisation), range-Doppler map, cylinder wrapping."""

from __future__ import annotations

import numpy as np
import pytest

from edge.dsp.mti import iir_canceller, iir_canceller_matrix, iir_canceller_reference
from edge.dsp.range_doppler import RangeDopplerProcessor, threshold_map
from hal.waveform import SPEED_OF_LIGHT_MPS, characteristics, d2g_frontend
from hw_sim.boards import D2G_BOARD
from hw_sim.scene import LinearTrajectory, RadarPose, Scene, Target
from hw_sim.synth import synthesize_if

FE = d2g_frontend()


@pytest.fixture(scope="module")
def rdp() -> RangeDopplerProcessor:
    return RangeDopplerProcessor(FE)


def _cplx(rng: np.random.Generator, shape) -> np.ndarray:
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)


@pytest.mark.parametrize("k_c", [0.0, 0.3, 0.5, 0.9])
def test_step_initialisation_zero_first_output_and_matrix_equals_recursion(k_c):
    q = _cplx(np.random.default_rng(1), (2, 21, 64)) * 100
    u = iir_canceller_reference(q, k_c)
    assert np.abs(u[..., 0, :]).max() < 1e-9  # u[0] = 0: step initialisation
    h = iir_canceller_matrix(21, k_c)
    assert h.shape == (20, 21) and h.dtype == np.float32
    np.testing.assert_allclose(iir_canceller(q, h), u[..., 1:, :], rtol=0, atol=2e-3)


def test_without_step_initialisation_first_chirp_would_leak():
    # the garbled eq. (3) read literally (state 0) passes q[0]: the reason for the initialisation
    q = np.ones((1, 21, 4), dtype=np.complex128) * 50
    h = iir_canceller_matrix(21, 0.5)
    assert np.abs(iir_canceller(q.astype(np.complex64), h)).max() < 1e-4
    w_prev = np.zeros(4)
    w = q[0, 0] + 0.5 * w_prev
    assert np.abs(w - w_prev).max() == pytest.approx(50)


def test_single_delay_line_for_k_zero():
    q = _cplx(np.random.default_rng(2), (21, 8))
    np.testing.assert_allclose(iir_canceller(q, iir_canceller_matrix(21, 0.0)), q[1:] - q[:-1], atol=1e-5)


def test_canceller_rejects_unstable_gain():
    with pytest.raises(ValueError):
        iir_canceller_matrix(21, 1.0)


def _point_scene(range_m: float, v_mps: float, rcs: float = 1.0, z: float = 1.0) -> Scene:
    sc = Scene(pose=RadarPose(height_m=1.0), seed=3)
    sc.add_target(Target(1, "car", LinearTrajectory((0.0, range_m, z), (0.0, v_mps, 0.0)), np.zeros((1, 3)), [rcs]))
    return sc


def _map(rdp, scene, *, noise=False, leakage=False, jitter=True):
    board = D2G_BOARD
    if not jitter:
        from dataclasses import replace

        board = replace(D2G_BOARD, radio=replace(D2G_BOARD.radio, static_jitter_dbc=-300.0))
    x = synthesize_if(board, scene.pose, scene.scatterers(0.0), 0.0, np.random.default_rng(0), noise=noise, leakage=leakage)
    return rdp.process(x.astype(np.complex64)).amplitude


@pytest.mark.parametrize("v_mps", [0.8, -1.2, 2.5, -3.4, 6.0])
def test_rd_peak_at_expected_bin_including_aliased_doppler(rdp, v_mps):
    r0 = 10.0
    m = _map(rdp, _point_scene(r0, v_mps))
    assert m.shape == (256, 256) and m.dtype == np.float32
    i, j = np.unravel_index(np.argmax(m), m.shape)
    seg = FE.waveform.segments[0]
    lam = FE.waveform.wavelength_m
    # beat = S tau + 2 v / lambda (range-Doppler coupling, DESIGN: receding targets look farther)
    # plus the motion to the middle of the kept chirps 1..20
    r_exp = r0 + (2 * v_mps / lam) * SPEED_OF_LIGHT_MPS / (2 * seg.slope_hz_per_s) + v_mps * 10.5 * seg.pri_s
    assert abs(rdp.range_m[i] - r_exp) <= 1.5 * rdp.range_bin_m
    vmax = characteristics(FE).max_radial_speed_mps * 3.6
    v_alias = (v_mps * 3.6 + vmax) % (2 * vmax) - vmax
    d = abs(rdp.radial_speed_kmh[j] - v_alias)
    assert min(d, 2 * vmax - d) <= 1.5 * rdp.doppler_bin_kmh
    if abs(v_mps * 3.6) > vmax:  # really aliased: the map shows a different speed
        assert abs(rdp.radial_speed_kmh[j] - v_mps * 3.6) > 1.0


def test_static_target_and_leakage_removed(rdp):
    static = _point_scene(8.0, 0.0, rcs=20.0)
    moving = _point_scene(8.0, 0.7, rcs=20.0)
    m_static = _map(rdp, static, leakage=True, jitter=False)
    m_moving = _map(rdp, moving, leakage=True, jitter=False)
    assert m_moving.max() > 10.0
    assert m_static.max() < 1e-3 * m_moving.max()


def test_axes_match_table_ii(rdp):
    ch = characteristics(FE)
    assert rdp.v_max_kmh == pytest.approx(5.4, abs=0.06)  # Table II rounds 5.35
    assert rdp.range_m[-1] + rdp.range_bin_m == pytest.approx(ch.max_unambiguous_range_m, rel=1e-6)
    assert rdp.radial_speed_kmh[0] == pytest.approx(-rdp.v_max_kmh, rel=1e-5)


def test_wrap_unwrap_roundtrip_and_cylinder_radius(rdp):
    rb = np.array([0, 10, 100, 255])
    db = np.array([0, 64, 128, 255])
    p = rdp.wrap(rb, db)
    np.testing.assert_allclose(np.hypot(p[:, 0], p[:, 1]), rdp.v_max_kmh / np.pi, rtol=1e-5)
    r, v = rdp.unwrap(p)
    np.testing.assert_allclose(r, rdp.range_m[rb], rtol=1e-6)
    np.testing.assert_allclose(v, rdp.radial_speed_kmh[db], atol=1e-3)
    # -v_max and the last bin are neighbours on the cylinder
    assert np.linalg.norm(p[0] - rdp.wrap(np.array([0]), np.array([255]))[0]) < 2 * rdp.doppler_bin_kmh


def test_threshold_map_inclusive():
    a = np.array([[1.0, 2.0], [2.5, 0.1]], dtype=np.float32)
    ri, di = threshold_map(a, 2.0)
    assert list(zip(ri, di)) == [(0, 1), (1, 0)]
