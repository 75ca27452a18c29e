"""Known-answer tests of the IF synthesis: beat frequency, Doppler phase, inter-channel phase, ADC."""

import numpy as np
import pytest

from hal.waveform import SPEED_OF_LIGHT_MPS as C
from hw_sim.boards import D2G_BOARD, SIMO_BOARD
from hw_sim.scene import LinearTrajectory, RadarPose, Scene, Target
from hw_sim.synth import quantize, synthesize_if


def _scene(pos, vel, rcs=10.0, pose=RadarPose(height_m=0.0)):
    sc = Scene(pose=pose, seed=3)
    sc.add_target(Target(1, "car", LinearTrajectory(pos, vel), np.zeros((1, 3)), np.array([rcs])))
    return sc


def _peak_freq(x, fs, n_fft=65536):
    """Frequency of the strongest component by zero-padded FFT (interpolation tolerance fs/n_fft)."""
    spec = np.abs(np.fft.fft(x * np.hanning(x.size), n_fft))
    k = int(np.argmax(spec))
    return np.fft.fftfreq(n_fft, 1 / fs)[k]


@pytest.mark.parametrize("az_deg", [-10.0, 0.0, 7.0])
@pytest.mark.parametrize("range_m, v_r", [(120.0, -25.0), (40.0, 12.0), (250.0, 30.0)])
def test_simo_beat_frequency_per_segment(range_m, v_r, az_deg):
    az = np.radians(az_deg)
    pos = (range_m * np.sin(az), range_m * np.cos(az), 0.0)
    vel = (v_r * np.sin(az), v_r * np.cos(az), 0.0)
    sc = _scene(pos, vel)
    board = SIMO_BOARD
    wf = board.frontend.waveform
    lam = wf.wavelength_m
    x = synthesize_if(board, sc.pose, sc.scatterers(0.0), 0.0, np.random.default_rng(0), noise=False, leakage=False)
    for k, seg in enumerate(wf.segments):
        # mid-ramp range (the scatterer moves during the frame)
        t_mid = seg.t_start_s + seg.n_samples / seg.sample_rate_hz / 2
        r = range_m + v_r * t_mid
        expected = seg.slope_hz_per_s * 2 * r / C + 2 * v_r / lam
        got = _peak_freq(x[0, k], seg.sample_rate_hz)
        tol = 2 * seg.sample_rate_hz / 65536 + 2.0  # interpolation grid + within-ramp migration
        assert got == pytest.approx(expected, abs=tol), f"segment {k}"


@pytest.mark.parametrize("az_deg", [-15.0, -4.0, 0.0, 9.0, 15.0])
def test_simo_inter_channel_phase(az_deg):
    az = np.radians(az_deg)
    r = 150.0
    sc = _scene((r * np.sin(az), r * np.cos(az), 0.0), (0.0, 0.0, 0.0))
    board = SIMO_BOARD
    lam = board.frontend.waveform.wavelength_m
    d = board.frontend.rx_spacing_m
    x = synthesize_if(board, sc.pose, sc.scatterers(0.0), 0.0, np.random.default_rng(0), noise=False, leakage=False)
    spec = np.fft.fft(x[:, 0, :], axis=-1)
    k = int(np.argmax(np.abs(spec[0])))
    dphi = np.angle(spec[1:, k] * np.conj(spec[:-1, k]))
    expected = -2 * np.pi * d * np.sin(az) / lam
    wrapped = np.angle(np.exp(1j * expected))
    np.testing.assert_allclose(dphi, wrapped, atol=0.01)


@pytest.mark.parametrize("v_r", [0.5, -1.2, 3.0])  # 3 m/s is beyond +-1.49 m/s: aliases like the board
def test_d2g_doppler_phase_step_across_chirps(v_r):
    r = 10.0
    sc = _scene((0.0, r, 0.0), (0.0, v_r, 0.0), rcs=1.0)
    board = D2G_BOARD
    seg = board.frontend.waveform.segments[0]
    x = synthesize_if(board, sc.pose, sc.scatterers(0.0), 0.0, np.random.default_rng(0), noise=False, leakage=False)
    spec = np.fft.fft(x[0], axis=-1)  # (21, 64)
    k = int(np.argmax(np.abs(spec[0, :32])))
    step = np.angle(spec[1:, k] * np.conj(spec[:-1, k]))
    # the phase at the range peak is the chirp's mean IF phase; it advances by 2 pi f_mid 2 v_r T_PRI / c
    # per chirp, with f_mid the transmit frequency at the middle of the sampling window
    t_mid = seg.sample_offset_s + (seg.n_samples - 1) / seg.sample_rate_hz / 2
    f_mid = seg.f_start_hz + seg.slope_hz_per_s * t_mid
    expected = np.angle(np.exp(2j * np.pi * f_mid * 2 * v_r * seg.pri_s / C))
    np.testing.assert_allclose(step, expected, atol=0.02)


def test_adc_output_is_int16_within_12_bits_and_clips():
    rng = np.random.default_rng(1)
    x = (rng.standard_normal((2, 3, 64)) + 1j * rng.standard_normal((2, 3, 64))) * 3000
    i, q = quantize(x, 12)
    assert i.dtype == np.int16 and q.dtype == np.int16
    assert i.min() == -2048 and i.max() == 2047  # clipped at full scale
    small = quantize(np.array([1.4 - 2.6j]), 12)
    assert small[0][0] == 1 and small[1][0] == -3


def test_radar_equation_amplitude_scales_with_range():
    b = SIMO_BOARD
    lam = b.frontend.waveform.wavelength_m
    p = b.radio.received_power_w(np.array([10.0, 10.0]), np.array([100.0, 200.0]), np.zeros(2), np.zeros(2), lam)
    assert p[0] / p[1] == pytest.approx(16.0)  # R^-4
