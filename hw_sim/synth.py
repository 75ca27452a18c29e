"""Vectorised IF synthesis: point scatterers -> int16 I/Q ADC frames for any waveform.

For a chirp of start frequency ``f_s`` and signed slope ``S``, the mixer output of a scatterer whose
round-trip delay to receive element ``m`` is ``tau_m(t)`` has phase (cycles)

    phi(t') = f_s tau(t') + S t' tau(t') - S tau(t')^2 / 2,    tau(t') = tau_c + tau_dot t'

with ``t'`` the time since the ramp started. This one expression contains the beat frequency
``S tau``, the Doppler shift ``f_s tau_dot = 2 v_r / lambda`` (range-Doppler coupling included), the
Doppler phase step between chirps (through ``tau_c`` at each chirp start), the slow change of the beat
within a ramp, and the inter-channel phase of the array (exact geometry per element, no far-field
approximation). Phases are formed in float64 cycles and reduced before the complex exponential.

Receive elements sit on the radar's x axis at ``x_m = (m - (n_rx - 1) / 2) d``; a target at azimuth
``theta`` (right +) therefore shows an inter-channel phase step of ``-2 pi d sin(theta) / lambda``
from element ``m`` to ``m + 1``; the pipeline's steering vector is ``exp(-j 2 pi m d sin(theta) / lambda)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hal.waveform import SPEED_OF_LIGHT_MPS, FrontendInfo
from hw_sim.radio import RadioModel, ReceiverImperfections, RoadSurface, road_bounce_factor
from hw_sim.scene import RadarPose, ScattererSet


@dataclass(frozen=True)
class SimBoard:
    """A simulated board: what it samples (``frontend``) and how its RF behaves (``radio``)."""

    frontend: FrontendInfo
    radio: RadioModel
    #: per-element complex gain errors (amplitude and phase) the calibration must remove; 1 = ideal
    channel_gain: tuple[complex, ...] = ()
    #: use :func:`hw_sim.fastsynth.synthesize_if_fast` (one exponential per scatterer and sample, not per
    #: element too); for many-scatterer scenes on multi-element boards
    fast_synthesis: bool = False
    #: the road that reflects every echo (:func:`hw_sim.radio.road_bounce_factor`); None = free space
    road: RoadSurface | None = None
    #: the receive chain's imperfections (:class:`hw_sim.radio.ReceiverImperfections`); None = ideal
    receiver: ReceiverImperfections | None = None

    def rx_positions_radar(self) -> np.ndarray:
        n = self.frontend.n_rx
        d = self.frontend.rx_spacing_m
        x = (np.arange(n) - (n - 1) / 2.0) * d
        return np.stack([x, np.zeros(n), np.zeros(n)], axis=1)

    def reference_bandwidth_hz(self) -> float:
        return max(s.sample_rate_hz for s in self.frontend.waveform.segments)


def synthesize_if(
    board: SimBoard,
    pose: RadarPose,
    scat: ScattererSet,
    t_frame_s: float,
    rng: np.random.Generator,
    *,
    noise: bool = True,
    leakage: bool = True,
    seed: int = 0,
) -> np.ndarray:
    """Complex IF in ADC counts (before quantisation), shape ``(n_rx, n_chirps, n_samples)``, complex128.

    ``scat`` holds the scatterers at ``t_frame_s``; each moves on a straight line during the frame. With
    ``board.road`` every echo carries the road-bounce factor (per scatterer and chirp). With
    ``board.receiver`` the echoes get a per-chirp phase error drawn from ``rng`` (only with ``noise``; drawn
    before every other draw of the frame, so with it off the frame's draws are those of an ideal receiver),
    and the whole IF the unit's channel mismatch, I/Q imbalance and DC offset, drawn from ``seed`` (the
    scene's: one unit per seed).
    """
    rx = board.receiver
    chirp_phase = None
    if rx is not None and noise and rx.phase_noise_deg_rms > 0:
        n_ch = board.frontend.frame_shape[1]
        chirp_phase = np.exp(1j * np.radians(rx.phase_noise_deg_rms) * rng.standard_normal(n_ch))
    if board.fast_synthesis:
        from hw_sim.fastsynth import synthesize_if_fast

        out = synthesize_if_fast(board, pose, scat, t_frame_s, rng, noise=noise, leakage=leakage, chirp_phase=chirp_phase)
    else:
        out = _synthesize_if_reference(board, pose, scat, t_frame_s, rng, noise, leakage, chirp_phase)
    if rx is not None and rx.active:
        out = rx.apply(out, seed)
    return out


def radar_polar(pose: RadarPose, position_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Range (m), azimuth and elevation (rad) in the radar's frame of world points ``position_m`` (..., 3)."""
    rel = pose.to_radar(position_m)
    return (np.linalg.norm(rel, axis=-1), np.arctan2(rel[..., 0], rel[..., 1]),
            np.arctan2(rel[..., 2], np.hypot(rel[..., 0], rel[..., 1])))


def echo_power_w(board: SimBoard, pose: RadarPose, position_m: np.ndarray, rcs_m2: np.ndarray) -> np.ndarray:
    """Each scatterer's echo power at the ADC input (W) at one instant, as the synthesis makes it: the radar
    equation with the board's antenna patterns, the IF high-pass at its beat frequency and, when the board has a
    road, the road bounce. It is what weights a target's scatterers in its cluster."""
    wf = board.frontend.waveform
    rng_m, az, el = radar_polar(pose, np.asarray(position_m, dtype=np.float64))
    p_w = board.radio.received_power_w(np.asarray(rcs_m2, dtype=np.float64), rng_m, az, el, wf.wavelength_m)
    if board.radio.if_highpass_hz > 0:
        f_b = abs(wf.segments[0].slope_hz_per_s) * 2.0 * rng_m / SPEED_OF_LIGHT_MPS
        p_w = p_w * (f_b * f_b / (f_b * f_b + board.radio.if_highpass_hz**2))
    if board.road is not None:
        bounce = road_bounce_factor(board.radio, board.road, pose.position, pose.rotation(), position_m, wf.wavelength_m)
        p_w = p_w * np.abs(bounce) ** 2
    return p_w


def _synthesize_if_reference(board, pose, scat, t_frame_s, rng, noise, leakage, chirp_phase):
    """The reference synthesis (one exponential per scatterer, element and sample); see synthesize_if."""
    fe = board.frontend
    wf = fe.waveform
    c = SPEED_OF_LIGHT_MPS
    lam = wf.wavelength_m
    n_rx, n_ch, n_s = fe.frame_shape
    out = np.zeros((n_rx, n_ch, n_s), dtype=np.complex128)

    rot = pose.rotation()  # rows: radar axes in world
    radar_pos = pose.position
    tx_pos = radar_pos
    rx_pos = radar_pos + board.rx_positions_radar() @ rot  # (n_rx, 3) world
    counts_gain = board.radio.signal_counts_gain(board.reference_bandwidth_hz())

    k = scat.rcs_m2.size
    if k:
        rng_m, az, el = radar_polar(pose, scat.position_m)
        p_w = board.radio.received_power_w(scat.rcs_m2, rng_m, az, el, lam)
        amp = np.sqrt(p_w) * counts_gain  # (K,)
        if board.radio.if_highpass_hz > 0:  # first-order IF high-pass before the ADC, at the beat frequency
            f_b = abs(wf.segments[0].slope_hz_per_s) * 2.0 * rng_m / c
            amp = amp * f_b / np.sqrt(f_b * f_b + board.radio.if_highpass_hz**2)
        keep = amp > 1e-3 * board.radio.noise_rms_counts  # drop scatterers far below the noise
        pos0, vel, amp, ph0 = scat.position_m[keep], scat.velocity_mps[keep], amp[keep], scat.phase_cycles[keep]
    else:
        pos0 = vel = np.zeros((0, 3))
        amp = ph0 = np.zeros(0)
    # chirp-to-chirp gain jitter of the static returns (leakage, clutter): what an MTI leaves behind
    jitter = None
    if board.radio.static_jitter_dbc > -200:
        sj = 10.0 ** (board.radio.static_jitter_dbc / 20.0) / np.sqrt(2.0)
        jitter = 1.0 + sj * (rng.standard_normal(n_ch) + 1j * rng.standard_normal(n_ch))
        static = ~np.any(vel != 0.0, axis=1)

    row = 0
    for seg in wf.segments:
        t_c = t_frame_s + seg.t_start_s + np.arange(seg.n_chirps) * seg.pri_s  # (C,)
        t_n = seg.sample_offset_s + np.arange(seg.n_samples) / seg.sample_rate_hz  # (N,)
        S = seg.slope_hz_per_s
        fs0 = seg.f_start_hz
        if amp.size:
            # positions at each chirp start: (K, C, 3)
            p = pos0[:, None, :] + vel[:, None, :] * (t_c - t_frame_s)[None, :, None]
            d_tx = p - tx_pos  # (K, C, 3)
            r_tx = np.linalg.norm(d_tx, axis=2)  # (K, C)
            u_tx = d_tx / r_tx[..., None]
            d_rx = p[:, None, :, :] - rx_pos[None, :, None, :]  # (K, R, C, 3)
            r_rx = np.linalg.norm(d_rx, axis=3)  # (K, R, C)
            u_rx = d_rx / r_rx[..., None]
            tau_c = (r_tx[:, None, :] + r_rx) / c  # (K, R, C)
            tau_dot = (np.einsum("kcj,kj->kc", u_tx, vel)[:, None, :] + np.einsum("krcj,kj->krc", u_rx, vel)) / c
            tau = tau_c[..., None] + tau_dot[..., None] * t_n  # (K, R, C, N)
            cyc = fs0 * tau + S * t_n * tau - 0.5 * S * tau * tau + ph0[:, None, None, None]
            cyc -= np.floor(cyc)
            sig = np.exp(2j * np.pi * cyc) * amp[:, None, None, None]
            if board.road is not None:
                bounce = road_bounce_factor(board.radio, board.road, radar_pos, rot, p, lam)  # (K, C)
                sig *= bounce[:, None, :, None]
            if jitter is not None and static.any():
                sig[static] *= jitter[None, row : row + seg.n_chirps, None]
            sig = sig.sum(axis=0)
            if chirp_phase is not None:
                sig *= chirp_phase[None, row : row + seg.n_chirps, None]
            out[:, row : row + seg.n_chirps, :] += sig
        if leakage and board.radio.leakage_power_dbm > -200:
            a_l = np.sqrt(10.0 ** ((board.radio.leakage_power_dbm - 30.0) / 10.0)) * counts_gain
            tau_l = 2.0 * board.radio.leakage_range_m / c
            cyc_l = fs0 * tau_l + S * t_n * tau_l - 0.5 * S * tau_l**2
            leak = a_l * np.exp(2j * np.pi * cyc_l)[None, None, :]
            if jitter is not None:
                leak = leak * jitter[None, row : row + seg.n_chirps, None]
            out[:, row : row + seg.n_chirps, :] += leak
        if noise:
            # receiver gain is fixed; a decimated segment has proportionally less noise bandwidth
            sigma = board.radio.noise_rms_counts * np.sqrt(seg.sample_rate_hz / board.reference_bandwidth_hz())
            shape = (n_rx, seg.n_chirps, n_s)
            out[:, row : row + seg.n_chirps, :] += sigma * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
        row += seg.n_chirps
    if board.channel_gain:
        out *= np.asarray(board.channel_gain, dtype=np.complex128)[:, None, None]
    return out


def clipped_fraction(if_counts: np.ndarray, adc_bits: int = 12) -> float:
    """Fraction of I and Q samples of ``if_counts`` beyond the ADC's signed range (clipped by :func:`quantize`)."""
    lo, hi = -(2 ** (adc_bits - 1)) - 0.5, 2 ** (adc_bits - 1) - 0.5
    rails = np.concatenate([if_counts.real.ravel(), if_counts.imag.ravel()])
    return float(np.mean((rails < lo) | (rails >= hi)))


def quantize(if_counts: np.ndarray, adc_bits: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Round to the ADC grid and clip to its signed range; returns int16 (I, Q)."""
    lo, hi = -(2 ** (adc_bits - 1)), 2 ** (adc_bits - 1) - 1
    i = np.clip(np.rint(if_counts.real), lo, hi).astype(np.int16)
    q = np.clip(np.rint(if_counts.imag), lo, hi).astype(np.int16)
    return i, q
