"""The radio physics variants of issue 28 (elevation pattern, road bounce, receiver imperfections, gain
offset, mounting) change the frames as documented, and the v1 preset reproduces the old instrument."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hw_sim import D2G_BOARD, SIMO_BOARD, FrameSimulator, RadarPose, board_for, load_scenario
from hw_sim.boards import D2G_MAX_TX_POWER, D2G_TX_POWER_STEP_DB, with_tx_power
from hw_sim.physics import Physics, parse_physics
from hw_sim.scenario import ScenarioError
from hw_sim.radio import KRAUS_DEG2, SPHERE_DEG2, elevation_beamwidth_deg
from hw_sim.scene import ScattererSet
from hw_sim.synth import clipped_fraction, quantize, synthesize_if

POSE = RadarPose(height_m=7.0, tilt_deg=1.5)


def _v1(**changes) -> Physics:
    """The v1 instrument with only ``changes`` switched on."""
    return parse_physics({"preset": "v1", **changes})


def _scat(points, rcs=10.0, vel=None) -> ScattererSet:
    p = np.atleast_2d(np.asarray(points, dtype=np.float64))
    k = p.shape[0]
    v = np.zeros((k, 3)) if vel is None else np.broadcast_to(np.asarray(vel, dtype=np.float64), (k, 3)).copy()
    return ScattererSet(p, v, np.full(k, float(rcs)), np.linspace(0.0, 0.5, k), np.zeros(k, dtype=np.int32))


def _ref(board):
    return dataclasses.replace(board, fast_synthesis=False)


# --- v1 reproduces the old instrument ------------------------------------------------------------------


def test_v1_preset_gives_the_old_boards_and_bit_exact_frames():
    v1 = _v1()
    assert board_for("simo", v1) == SIMO_BOARD
    assert board_for("d2g", v1) == D2G_BOARD
    sc = load_scenario("highway4-traffic")
    scene = sc.build_scene(3)
    old = FrameSimulator(SIMO_BOARD, scene, 3)
    new = FrameSimulator(board_for("simo", v1), scene, 3)
    phys = FrameSimulator(board_for("simo", Physics()), scene, 3)
    for n in (0, 17, 90):
        a, b, c = old.frame(n), new.frame(n), phys.frame(n)
        assert np.array_equal(a.i, b.i) and np.array_equal(a.q, b.q)
        assert not np.array_equal(a.i, c.i)  # the physical defaults do change the frames


def test_physics_choices_are_validated():
    from hw_sim.physics import PhysicsError

    with pytest.raises(PhysicsError, match="elevation"):
        parse_physics({"elevation": "flat"})
    with pytest.raises(PhysicsError, match="polarisation"):
        parse_physics({"polarisation": "circular"})
    with pytest.raises(PhysicsError, match="dc_offset_counts"):
        parse_physics({"dc_offset_counts": -1.0})


# --- elevation pattern ----------------------------------------------------------------------------------


def test_elevation_widths_implied_by_lim_table1_gains():
    assert elevation_beamwidth_deg(13.6, 18.56) == pytest.approx(75.3, abs=0.05)
    assert elevation_beamwidth_deg(10.8, 36.35) == pytest.approx(73.2, abs=0.05)
    assert elevation_beamwidth_deg(13.6, 18.56, SPHERE_DEG2) == pytest.approx(97.0, abs=0.05)
    assert KRAUS_DEG2 / SPHERE_DEG2 == pytest.approx(0.78, abs=0.005)
    simo = board_for("simo", Physics())
    assert simo.radio.tx.el_beamwidth_deg == pytest.approx(75.26, abs=0.01)
    assert simo.radio.rx.el_beamwidth_deg == pytest.approx(73.22, abs=0.01)
    assert board_for("simo", _v1()).radio.tx.el_beamwidth_deg == 12.0
    # the Distance2Go keeps its datasheet pattern whatever the choice
    for choice in ("gain-implied", "wide", "narrow"):
        d2g = board_for("d2g", _v1(elevation=choice)).radio
        assert (d2g.tx.el_beamwidth_deg, d2g.rx.el_beamwidth_deg) == (20.0, 20.0)


def _peak_power(x: np.ndarray) -> float:
    """Peak power of channel 0's range spectrum of the first chirp (rectangular window)."""
    return float(np.max(np.abs(np.fft.fft(x[0, 0])) ** 2))


def test_near_echo_power_in_the_two_elevation_patterns_and_no_adc_clipping():
    """A car's face (10 m^2 in three scatterers, 0.5 m high) 15 m out from a 7 m radar: 39.7 dB stronger
    with the gain-implied pattern than with the narrow one (documented in hw_sim.radio.with_elevation)."""
    car = _scat([[-0.63, 15.0, 0.5], [0.0, 15.0, 0.5], [0.63, 15.0, 0.5]], rcs=10.0 / 3.0)
    one = _scat([[0.0, 15.0, 0.5]], rcs=10.0)
    p = {}
    for choice in ("narrow", "gain-implied", "wide"):
        b = board_for("simo", _v1(elevation=choice))
        p[choice] = _peak_power(synthesize_if(b, POSE, one, 0.0, np.random.default_rng(0), noise=False, leakage=False))
    assert 10 * math.log10(p["gain-implied"] / p["narrow"]) == pytest.approx(39.7, abs=0.1)
    assert 10 * math.log10(p["wide"] / p["narrow"]) == pytest.approx(40.5, abs=0.1)
    # post-FFT SNR of that echo: about 59 dB (gain-implied) against about 20 dB (narrow)
    b = board_for("simo", _v1(elevation="gain-implied"))
    noise = synthesize_if(b, POSE, _scat(np.zeros((0, 3))), 0.0, np.random.default_rng(1), leakage=False)
    n_pow = float(np.mean(np.abs(np.fft.fft(noise[0, 0])) ** 2))
    assert 10 * math.log10(p["gain-implied"] / n_pow) == pytest.approx(59.3, abs=1.0)
    assert 10 * math.log10(p["narrow"] / n_pow) == pytest.approx(19.6, abs=1.0)
    # the full frame (leakage, noise) of the car with the physical defaults does not clip the 12-bit ADC
    x = synthesize_if(board_for("simo", Physics()), POSE, car, 0.0, np.random.default_rng(2), seed=1)
    assert clipped_fraction(x, 12) == 0.0
    assert 1000 < np.max(np.abs(np.r_[x.real.ravel(), x.imag.ravel()])) < 2047


def test_adc_clipping_is_reported_and_applied():
    """quantize clips to the 12-bit range and clipped_fraction reports it: a +6 dB hotter SIMO unit clips on
    its own TX->RX leakage (1400 counts -> 2800)."""
    empty = _scat(np.zeros((0, 3)))
    hot = board_for("simo", _v1(gain_offset_db=6.0))
    x = synthesize_if(hot, POSE, empty, 0.0, np.random.default_rng(0))
    frac = clipped_fraction(x, 12)
    assert frac > 0.2
    i, q = quantize(x, 12)
    assert np.mean((np.abs(i) >= 2047) | (i == -2048)) > 0.2
    assert i.max() == 2047 and np.abs(x.real).max() > 2500  # held at the rail
    assert clipped_fraction(synthesize_if(SIMO_BOARD, POSE, empty, 0.0, np.random.default_rng(0)), 12) == 0.0


# --- road bounce ----------------------------------------------------------------------------------------


def _two_ray_analytic(d_m, z_m, board, pose, eps_r=3.2, tan_d=0.03, sigma_mm=2.0):
    """Independent four-path factor for a scatterer straight ahead (x = 0) at ground distance d, height z."""
    lam = board.frontend.waveform.wavelength_m
    h = pose.height_m
    r_d = np.hypot(d_m, h - z_m)
    r_i = np.hypot(d_m, h + z_m)
    sin_psi = (h + z_m) / r_i
    eps = eps_r * (1 - 1j * tan_d)
    root = np.sqrt(eps - (1 - sin_psi**2))
    gamma = (sin_psi - root) / (sin_psi + root) * np.exp(-2 * (2 * np.pi * sigma_mm * 1e-3 * sin_psi / lam) ** 2)
    tilt = math.radians(pose.tilt_deg)
    el_d = -np.arctan2(h - z_m, d_m) + tilt
    el_i = -np.arctan2(h + z_m, d_m) + tilt
    zero = np.zeros_like(el_d)
    a_t = np.sqrt(board.radio.tx.gain_linear(zero, el_i) / board.radio.tx.gain_linear(zero, el_d))
    a_r = np.sqrt(board.radio.rx.gain_linear(zero, el_i) / board.radio.rx.gain_linear(zero, el_d))
    ray = gamma * r_d / r_i * np.exp(2j * np.pi * (r_i - r_d) / lam)
    return (1 + ray * a_t) * (1 + ray * a_r)


def test_road_bounce_equals_the_analytic_four_path_factor_and_lobes():
    """A static scatterer 0.5 m above the road, straight ahead of a 7 m radar: the frame with the bounce is
    the free-space frame times the four-path factor, whose nulls sit where the image path is a whole
    number of wavelengths longer (d_n = 2 h z / (n lambda) for Gamma near -1) and peaks half-way."""
    pose = RadarPose(height_m=7.0, tilt_deg=1.5)
    free = board_for("simo", _v1(elevation="gain-implied"))
    bounce = board_for("simo", _v1(elevation="gain-implied", road_bounce=True))
    lam = free.frontend.waveform.wavelength_m
    z = 0.5
    ds = np.array([60.0, 97.3, 140.0, 233.0])
    ratios = []
    for d in ds:
        s = _scat([[0.0, d, z]])
        for ref in (False, True):
            b0, b1 = (_ref(free), _ref(bounce)) if ref else (free, bounce)
            x0 = synthesize_if(b0, pose, s, 0.0, np.random.default_rng(0), noise=False, leakage=False)
            x1 = synthesize_if(b1, pose, s, 0.0, np.random.default_rng(0), noise=False, leakage=False)
            f = _two_ray_analytic(d, z, free, pose)
            ratio = x1[:, :, 512] / x0[:, :, 512]
            tol = 1e-9 if ref else 3e-3  # the fast path forms its weights in complex64
            assert np.allclose(ratio, f, rtol=tol, atol=tol), (d, ref)
        ratios.append(abs(f) ** 2)
    # lobing: power factor vs ground distance on a fine grid, nulls and peaks where two-ray theory puts them
    d = np.linspace(40.0, 300.0, 20001)
    pf = 10 * np.log10(np.abs(_two_ray_analytic(d, z, free, pose)) ** 2)
    from hw_sim.radio import road_bounce_factor

    p = np.stack([np.zeros_like(d), d, np.full_like(d, z)], axis=1)
    impl = road_bounce_factor(bounce.radio, bounce.road, pose.position, pose.rotation(), p, lam)
    assert np.allclose(10 * np.log10(np.abs(impl) ** 2), pf, atol=1e-6)
    for n in (2, 3, 4, 5):
        d_null = 2 * pose.height_m * z / (n * lam)
        d_peak = 2 * pose.height_m * z / ((n + 0.5) * lam)
        near_null = np.abs(d - d_null) < 0.02 * d_null
        near_peak = np.abs(d - d_peak) < 0.02 * d_peak
        assert pf[near_null].min() < -25.0, n
        assert pf[near_peak].max() > 9.0, n
    assert min(ratios) < 0.5 and max(ratios) > 3.0  # the sampled distances include a trough and a crest


def test_fast_synthesis_matches_the_reference_with_the_physical_defaults():
    """Same tolerance as test_traffic's v1 comparison: the bounce and receiver enter both paths alike."""
    rng = np.random.default_rng(0)
    k = 40
    scat = ScattererSet(
        np.c_[rng.uniform(-8, 8, k), rng.uniform(5, 300, k), rng.uniform(0, 2, k)],
        np.c_[rng.uniform(-2, 2, k), rng.uniform(-40, 40, k), np.zeros(k)],
        rng.uniform(0.5, 20, k), rng.random(k), np.zeros(k, int))
    pose = RadarPose(height_m=7.0, tilt_deg=1.5, yaw_deg=2.0)
    board = board_for("simo", Physics())
    assert board.fast_synthesis and board.road is not None and board.receiver is not None
    fast = synthesize_if(board, pose, scat, 0.4, np.random.default_rng(1), noise=False, seed=5)
    ref = synthesize_if(_ref(board), pose, scat, 0.4, np.random.default_rng(1), noise=False, seed=5)
    assert np.max(np.abs(fast - ref)) < 2e-3 * np.max(np.abs(ref))


# --- receiver imperfections -----------------------------------------------------------------------------


def test_iq_imbalance_image_level_in_the_range_spectrum():
    """A moving scatterer's echo and its image at the mirrored beat frequency: the image is
    10 log10(|nu|^2 / |mu|^2) below it (within 0.5 dB), about -30 dB with the defaults."""
    phys = Physics()
    b = board_for("simo", _v1(iq_gain_imbalance_db=phys.iq_gain_imbalance_db,
                              iq_phase_imbalance_deg=phys.iq_phase_imbalance_deg))
    mu, nu = b.receiver.iq_coefficients()
    expect_db = 10 * math.log10(abs(nu) ** 2 / abs(mu) ** 2)
    assert -33.0 < expect_db < -27.0
    s = _scat([[0.0, 80.0, 0.5]], rcs=10.0, vel=[0.0, -20.0, 0.0])
    x = synthesize_if(b, POSE, s, 0.0, np.random.default_rng(0), noise=False, leakage=False)
    ideal = synthesize_if(board_for("simo", _v1()), POSE, s, 0.0, np.random.default_rng(0), noise=False, leakage=False)
    assert np.allclose(x, mu * ideal + nu * np.conj(ideal))
    n = x.shape[2]
    win = np.hanning(n)
    spec = np.abs(np.fft.fft(x[0, 0] * win)) ** 2
    k_sig = int(np.argmax(spec))
    k_img = (-k_sig) % n
    assert k_sig not in (0, n // 2)
    measured = 10 * math.log10(spec[k_img] / spec[k_sig])
    assert measured == pytest.approx(expect_db, abs=0.5)
    # the ideal receiver has no image there
    spec0 = np.abs(np.fft.fft(ideal[0, 0] * win)) ** 2
    assert 10 * math.log10(spec0[k_img] / spec0[k_sig]) < expect_db - 40


def test_dc_offset_lands_in_range_bin_zero_per_seed():
    b = board_for("simo", _v1(dc_offset_counts=4.0))
    empty = _scat(np.zeros((0, 3)))
    x5 = synthesize_if(b, POSE, empty, 0.0, np.random.default_rng(0), noise=False, leakage=False, seed=5)
    _, dc5 = b.receiver.board_errors(5, 4)
    assert np.allclose(x5, dc5[:, None, None])
    assert np.all(np.abs(dc5) > 0) and 1.0 < np.sqrt(np.mean(np.abs(dc5) ** 2) / 2) < 12.0
    x6 = synthesize_if(b, POSE, empty, 0.0, np.random.default_rng(0), noise=False, leakage=False, seed=6)
    assert not np.allclose(x5, x6)  # another unit, another offset
    # with the thermal noise on, bin 0 of the range spectrum holds the offset (N dc), other bins the noise
    xn = synthesize_if(b, POSE, empty, 0.0, np.random.default_rng(1), leakage=False, seed=5)
    spec = np.fft.fft(xn[:, 0], axis=1)
    n = xn.shape[2]
    assert np.allclose(spec[:, 0] / n, dc5, atol=0.5)
    assert np.all(np.abs(spec[:, 0]) ** 2 > 30 * np.mean(np.abs(spec[:, 1:]) ** 2, axis=1))


def test_channel_mismatch_changes_the_inter_channel_phases_by_the_drawn_amounts():
    b = board_for("simo", _v1(channel_mismatch_db=0.5, channel_mismatch_deg=5.0))
    s = _scat([[3.0, 120.0, 0.5]], rcs=10.0, vel=[0.0, -25.0, 0.0])
    ideal = synthesize_if(board_for("simo", _v1()), POSE, s, 0.0, np.random.default_rng(0), noise=False, leakage=False)
    x = synthesize_if(b, POSE, s, 0.0, np.random.default_rng(0), noise=False, leakage=False, seed=11)
    m, _ = b.receiver.board_errors(11, 4)
    k = int(np.argmax(np.abs(np.fft.fft(ideal[0, 0]))))
    peak = np.fft.fft(x[:, 0], axis=1)[:, k]
    peak0 = np.fft.fft(ideal[:, 0], axis=1)[:, k]
    d_phase = np.angle(peak / peak0, deg=True)
    assert np.allclose(d_phase, np.angle(m, deg=True), atol=1e-6)
    assert np.allclose(20 * np.log10(np.abs(peak / peak0)), 20 * np.log10(np.abs(m)), atol=1e-6)
    # inter-channel phase steps (what the angle estimator sees) change by the drawn differences
    step = np.angle(peak[1:] / peak[:-1], deg=True) - np.angle(peak0[1:] / peak0[:-1], deg=True)
    drawn = np.angle(m[1:] / m[:-1], deg=True)
    assert np.allclose((step - drawn + 180) % 360 - 180, 0.0, atol=1e-6)
    assert np.std(np.angle(m, deg=True)) > 1.0  # the draw is not trivially small
    m2, _ = b.receiver.board_errors(12, 4)
    assert not np.allclose(m, m2)
    # one element (Distance2Go): nothing to mismatch against
    assert np.array_equal(b.receiver.board_errors(11, 1)[0], np.ones(1))


def test_phase_noise_is_a_common_per_chirp_phase_of_the_echoes():
    sigma = 2.0
    b = board_for("simo", _v1(elevation="gain-implied", phase_noise_deg_rms=sigma))
    ideal_b = board_for("simo", _v1(elevation="gain-implied"))
    s = _scat([[0.0, 40.0, 0.5]], rcs=1000.0)  # strong: the thermal noise's own phase jitter stays below 0.05 deg
    ideal = synthesize_if(ideal_b, POSE, s, 0.0, np.random.default_rng(0), noise=False, leakage=False)
    spec0 = np.fft.fft(ideal, axis=2)
    k = np.argmax(np.abs(spec0[0]), axis=1)  # peak bin of each chirp (segments differ)
    rows = np.arange(k.size)
    ref_peak = spec0[:, rows, k]
    errs = []
    for n in range(150):
        x = synthesize_if(b, POSE, s, 0.0, np.random.default_rng(n), leakage=False)
        d = np.angle(np.fft.fft(x, axis=2)[:, rows, k] / ref_peak, deg=True)  # (R, C)
        assert np.ptp(d, axis=0).max() < 0.3  # common to the four channels (one LO)
        errs.append(d.mean(axis=0))
    assert np.std(np.concatenate(errs)) == pytest.approx(sigma, rel=0.1)
    # without noise (a known-answer frame) no phase error is drawn
    assert np.array_equal(synthesize_if(b, POSE, s, 0.0, np.random.default_rng(0), noise=False, leakage=False), ideal)


def test_imperfections_off_keep_the_frame_rng_draws():
    """With every receiver imperfection at zero the frame's noise draws are those of the v1 instrument."""
    s = _scat([[0.0, 40.0, 0.5]])
    a = synthesize_if(board_for("simo", _v1(road_bounce=True)), POSE, s, 0.0, np.random.default_rng(3))
    b = synthesize_if(board_for("simo", _v1()), POSE, s, 0.0, np.random.default_rng(3))
    an = synthesize_if(board_for("simo", _v1(road_bounce=True)), POSE, s, 0.0, np.random.default_rng(3), noise=False)
    bn = synthesize_if(board_for("simo", _v1()), POSE, s, 0.0, np.random.default_rng(3), noise=False)
    assert np.allclose(a - an, b - bn)  # identical noise


# --- gain offset ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["simo", "d2g"])
@pytest.mark.parametrize("offset_db", [-6.0, 3.0, 6.0])
def test_gain_offset_scales_signal_and_leakage_not_noise(name, offset_db):
    base = board_for(name, _v1())
    off = board_for(name, _v1(gain_offset_db=offset_db))
    s = _scat([[0.5, 12.0, 0.5]], rcs=2.0)
    pose = POSE if name == "simo" else RadarPose(height_m=1.0)
    x0 = synthesize_if(base, pose, s, 0.0, np.random.default_rng(0), noise=False)
    x1 = synthesize_if(off, pose, s, 0.0, np.random.default_rng(0), noise=False)
    assert 20 * math.log10(np.linalg.norm(x1) / np.linalg.norm(x0)) == pytest.approx(offset_db, abs=1e-9)
    empty = _scat(np.zeros((0, 3)))
    n0 = synthesize_if(base, pose, empty, 0.0, np.random.default_rng(1), leakage=False)
    n1 = synthesize_if(off, pose, empty, 0.0, np.random.default_rng(1), leakage=False)
    assert np.array_equal(n0, n1)


@pytest.mark.parametrize("level", [0, 3, 6])
def test_tx_power_level_scales_signal_and_leakage_not_noise(level):
    base = board_for("d2g", _v1())
    low = with_tx_power(base, level)
    s = _scat([[0.5, 12.0, 0.5]], rcs=2.0)
    pose = RadarPose(height_m=1.0)
    x0 = synthesize_if(base, pose, s, 0.0, np.random.default_rng(0), noise=False)
    x1 = synthesize_if(low, pose, s, 0.0, np.random.default_rng(0), noise=False)
    expect = -(D2G_MAX_TX_POWER - level) * D2G_TX_POWER_STEP_DB
    assert 20 * math.log10(np.linalg.norm(x1) / np.linalg.norm(x0)) == pytest.approx(expect, abs=1e-9)
    empty = _scat(np.zeros((0, 3)))
    l0 = synthesize_if(base, pose, empty, 0.0, np.random.default_rng(1), noise=False)  # the leakage alone
    l1 = synthesize_if(low, pose, empty, 0.0, np.random.default_rng(1), noise=False)
    assert 20 * math.log10(np.linalg.norm(l1) / np.linalg.norm(l0)) == pytest.approx(expect, abs=1e-9)
    n0 = synthesize_if(base, pose, empty, 0.0, np.random.default_rng(1), leakage=False)
    n1 = synthesize_if(low, pose, empty, 0.0, np.random.default_rng(1), leakage=False)
    assert np.array_equal(n0, n1)
    # a board 6 dB hot at level 1 makes the frames of the nominal board at full power
    hot = with_tx_power(board_for("d2g", _v1(gain_offset_db=6.0)), 1)
    x2 = synthesize_if(hot, pose, s, 0.0, np.random.default_rng(0), noise=False)
    x3 = synthesize_if(base, pose, s, 0.0, np.random.default_rng(0), noise=False)
    assert np.allclose(x2, x3, rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match="0..7"):
        with_tx_power(base, 8)


def test_scenario_tx_power_is_a_d2g_radar_setting():
    sc = load_scenario("tavanti-test1", {"radar": {"tx_power": 2}})
    assert sc.tx_power == 2 and sc.sim_board().radio.tx_backoff_db == pytest.approx(5 * D2G_TX_POWER_STEP_DB)
    assert load_scenario("tavanti-test1").sim_board().radio.tx_backoff_db == 0.0
    with pytest.raises(ScenarioError, match="tx_power"):
        load_scenario("tavanti-test1", {"radar": {"tx_power": 9}})
    with pytest.raises(ScenarioError, match="Distance2Go"):
        load_scenario("highway4", {"radar": {"tx_power": 3}})


# --- mounting -------------------------------------------------------------------------------------------


def test_mounting_patch_changes_truth_geometry_and_frames():
    base = load_scenario("highway4-traffic")
    moved = load_scenario("highway4-traffic", {"radar": {"height_m": 10.0, "yaw_deg": 3.0, "tilt_deg": 2.5}})
    assert (moved.pose.height_m, moved.pose.yaw_deg, moved.pose.tilt_deg) == (10.0, 3.0, 2.5)
    s0, s1 = base.build_scene(4), moved.build_scene(4)
    t = 5.0
    g0, g1 = s0.truth(t), s1.truth(t)
    assert np.array_equal(g0.id, g1.id) and np.allclose(g0.position_m, g1.position_m)  # same traffic
    # slant range from the higher mast, azimuth turned by the yaw (a far vehicle's azimuth shifts by -3 deg)
    expect_r = np.linalg.norm(g1.position_m - np.array([0.0, 0.0, 10.0]), axis=1)
    assert np.allclose(g1.range_m, expect_r)
    assert np.all(g1.range_m > g0.range_m)
    far = g0.range_m > 150
    assert far.any()
    assert np.allclose(np.degrees(g1.az_rad[far] - g0.az_rad[far]), -3.0, atol=0.1)
    b = moved.sim_board()
    f0 = FrameSimulator(base.sim_board(), s0, 4).frame(150)
    f1 = FrameSimulator(b, s1, 4).frame(150)
    assert not np.array_equal(f0.i, f1.i)
