"""Fast IF synthesis for many scatterers (busy multi-lane scenes on the SIMO board).

Same physics as :func:`hw_sim.synth.synthesize_if`, factored so the expensive part is one complex
exponential per scatterer and sample instead of one per scatterer, *element* and sample:

    cyc_{k,m}(t') = a_{k,m} + b_k t' + q_k t'^2

* ``a_{k,m} = f_s tau_{k,m} - S tau_{k,m}^2 / 2 + phase_k`` uses the exact delay to element ``m``
  (inter-channel phase, Doppler phase between chirps, exact geometry as in the reference synthesis);
* ``b_k = f_s tau_dot + S tau - S tau tau_dot`` (beat frequency plus Doppler, with range-Doppler
  coupling) and ``q_k = S tau_dot - S tau_dot^2 / 2`` (the beat drifting as the target moves during the
  ramp) use the delay averaged over the array.

The only approximation is the per-element difference of the beat frequency, ``S (tau_m - tau_mean)``,
below 2 Hz for the 1x4 SIMO array at 24 GHz (d = 1.5 lambda, 200 MHz / 5 ms): it is applied as a
constant phase at the middle of the sampling window, leaving a zero-mean phase ramp of at most
+-0.005 cycle across a ramp (``tests/hw_sim/test_traffic.py`` bounds the difference to the reference).
The element sum is a matrix product ``(R, K) @ (K, N)``; phases of the ``(K, N)`` block are formed in
float32 (|cycles| < 1000, so the error is below 1e-4 cycle) and evaluated with float32 ``cos``/``sin``; the
complex product is four real matrix products.
"""

from __future__ import annotations

import numpy as np

from hal.waveform import SPEED_OF_LIGHT_MPS
from hw_sim.radio import road_bounce_factor
from hw_sim.scene import RadarPose, ScattererSet
from hw_sim.synth import radar_polar


def synthesize_if_fast(board, pose: RadarPose, scat: ScattererSet, t_frame_s: float, rng: np.random.Generator,
                       *, noise: bool = True, leakage: bool = True,
                       chirp_phase: np.ndarray | None = None) -> np.ndarray:
    """Complex IF in ADC counts, ``(n_rx, n_chirps, n_samples)`` complex128 (see module docstring).

    The road-bounce factor (``board.road``) and the per-chirp phase error ``chirp_phase`` ``(n_chirps,)``
    enter the per-scatterer weights exactly as in the reference synthesis.
    """
    fe = board.frontend
    wf = fe.waveform
    c = SPEED_OF_LIGHT_MPS
    lam = wf.wavelength_m
    n_rx, n_ch, n_s = fe.frame_shape
    out = np.zeros((n_rx, n_ch, n_s), dtype=np.complex128)

    rot = pose.rotation()
    tx_pos = pose.position
    rx_pos = tx_pos + board.rx_positions_radar() @ rot
    counts_gain = board.radio.signal_counts_gain(board.reference_bandwidth_hz())

    if scat.rcs_m2.size:
        rng_m, az, el = radar_polar(pose, scat.position_m)
        amp = np.sqrt(board.radio.received_power_w(scat.rcs_m2, rng_m, az, el, lam)) * counts_gain
        keep = amp > 1e-3 * board.radio.noise_rms_counts
        pos0, vel, amp, ph0 = scat.position_m[keep], scat.velocity_mps[keep], amp[keep], scat.phase_cycles[keep]
    else:
        pos0 = vel = np.zeros((0, 3))
        amp = ph0 = np.zeros(0)
    k = amp.size

    row = 0
    for seg in wf.segments:
        n_c = seg.n_chirps
        t_c = seg.t_start_s + np.arange(n_c) * seg.pri_s  # (C,) since frame start
        t_n = seg.sample_offset_s + np.arange(n_s) / seg.sample_rate_hz
        S = seg.slope_hz_per_s
        fs0 = seg.f_start_hz
        if k:
            p = pos0[:, None, :] + vel[:, None, :] * t_c[None, :, None]  # (K, C, 3)
            d_tx = p - tx_pos
            r_tx = np.linalg.norm(d_tx, axis=2)  # (K, C)
            d_rx = p[:, None, :, :] - rx_pos[None, :, None, :]  # (K, R, C, 3)
            r_rx = np.linalg.norm(d_rx, axis=3)  # (K, R, C)
            tau = (r_tx[:, None, :] + r_rx) / c  # (K, R, C)
            rd_tx = np.einsum("kcj,kj->kc", d_tx, vel) / r_tx
            rd_rx = np.einsum("krcj,kj->krc", d_rx, vel) / r_rx
            tau_dot = (rd_tx[:, None, :] + rd_rx) / c  # (K, R, C)
            tm = tau.mean(axis=1)  # (K, C)
            tdm = tau_dot.mean(axis=1)
            # per-element beat offset S (tau_m - tau_mean), applied as its phase at mid-window so the
            # residual is a zero-mean ramp (exact peak phase to first order)
            a = fs0 * tau - 0.5 * S * tau * tau + ph0[:, None, None] + S * (tau - tm[:, None, :]) * t_n.mean()
            a -= np.floor(a)
            w = amp[:, None, None] * np.exp(2j * np.pi * a)  # (K, R, C)
            if board.road is not None:
                w *= road_bounce_factor(board.radio, board.road, tx_pos, rot, p, lam)[:, None, :]
            if chirp_phase is not None:
                w *= chirp_phase[None, None, row:row + n_c]
            w = w.astype(np.complex64)
            b = (fs0 * tdm + S * tm - S * tm * tdm).astype(np.float32)
            q = (S * tdm - 0.5 * S * tdm * tdm).astype(np.float32)
            t32 = t_n.astype(np.float32)
            cyc = b[..., None] * t32 + q[..., None] * (t32 * t32)  # (K, C, N) float32
            cyc -= np.floor(cyc)
            cyc *= np.float32(2.0 * np.pi)
            cos_ = np.cos(cyc)  # contiguous float32 (K, C, N)
            sin_ = np.sin(cyc)
            wr = np.ascontiguousarray(w.real.transpose(2, 1, 0))  # (C, R, K)
            wi = np.ascontiguousarray(w.imag.transpose(2, 1, 0))
            cc = cos_.transpose(1, 0, 2)  # (C, K, N)
            ss = sin_.transpose(1, 0, 2)
            re = wr @ cc - wi @ ss  # (C, R, N)
            im = wr @ ss + wi @ cc
            out[:, row:row + n_c, :] += (re + 1j * im).transpose(1, 0, 2)
        if leakage and board.radio.leakage_power_dbm > -200:
            a_l = np.sqrt(10.0 ** ((board.radio.leakage_power_dbm - 30.0) / 10.0)) * counts_gain
            tau_l = 2.0 * board.radio.leakage_range_m / c
            cyc_l = fs0 * tau_l + S * t_n * tau_l - 0.5 * S * tau_l**2
            out[:, row:row + n_c, :] += a_l * np.exp(2j * np.pi * cyc_l)[None, None, :]
        if noise:
            sigma = board.radio.noise_rms_counts * np.sqrt(seg.sample_rate_hz / board.reference_bandwidth_hz())
            shape = (n_rx, n_c, n_s)
            out[:, row:row + n_c, :] += sigma * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
        row += n_c
    if board.channel_gain:
        out *= np.asarray(board.channel_gain, dtype=np.complex128)[:, None, None]
    return out
