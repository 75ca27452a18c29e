"""FFT-only bound and peer pipeline of the ``lane`` profile (``radar-edge bench --profile lane``).

``fft_bound``: the transform the profile cannot avoid -- int16 I/Q into complex64 and one
single-precision FFT (``scipy.fft``, ``workers=1``) of every segment of every receive channel,
``(n_rx, 4, n_samples)`` per frame. Nothing else: no window, no clutter map, no detection.

``peer``: the chain a radar engineer would otherwise glue together from general-purpose tools,
written plainly (vectorised numpy where numpy makes it natural, but no tuning):

* float64 throughout: ``i + 1j q`` as complex128, Hann window, ``numpy.fft.fft``;
* the same static-clutter map (exponential average of the complex spectra) and non-coherent
  channel sum as the product, in float64;
* OS-CFAR computed at every bin (``sliding_window_view`` + ``numpy.partition`` over the circular
  reference window), local maxima above the threshold, parabolic log-power interpolation;
* a plain per-detection Bartlett scan over the angle grid in float64 with the same segment-agreement
  rule (a pairing is kept if ``angle_min_agreeing`` segments point within ``angle_outlier_deg`` of
  their median);
* Stone Soup's PDA tracker: ``PDAHypothesiser`` + ``PDA`` data associator, ``KalmanPredictor`` with a
  nearly-constant-velocity ``CombinedLinearGaussianTransitionModel``, ``KalmanUpdater`` with a
  linear (x, y) measurement model, the Gaussian mixture of the PDA hypotheses reduced by
  ``gm_reduce_single`` (Stone Soup's PDA tutorial), ``MultiMeasurementInitiator`` (M of N-like
  confirmation after ``track.pdaf.confirm_m`` updates, GNN on Mahalanobis distance) and a
  ``CovarianceBasedDeleter`` (a PDA update always holds the missed-detection hypothesis, so the
  update-time deleters never fire on PDA tracks).

Product pieces reused by the peer, because no library provides them: the four-segment beat pairing
(:func:`edge.dsp.pairing.pair_beats`), the OS-CFAR scale factor for the design P_FA
(:func:`edge.dsp.cfar.os_cfar_scale`, a root of Rohling's formula), the ground projection
(:func:`edge.dsp.geometry.polar_to_ground`) and the same-vehicle body filter
(:func:`edge.dsp.pairing.nearest_of_clusters`; without it every vehicle would give the tracker
several detections and the peer would do more work than the product). The peer stops at tracks: the
product's ``traffic`` stage (lanes and interval statistics) has no counterpart in it.

Without Stone Soup, :func:`peer` returns ``None`` (the bench report says why).
"""

from __future__ import annotations

import logging
import math
from datetime import datetime, timedelta, timezone
from typing import Any, Callable

import numpy as np
import scipy.fft
import scipy.signal

from hal.waveform import SPEED_OF_LIGHT_MPS

log = logging.getLogger(__name__)

#: one line for the report
PEER_DESCRIPTION = ("float64 numpy FFT + OS-CFAR + pairing + Bartlett, "
                    "Stone Soup PDA tracker (PDAHypothesiser, PDA, Kalman)")

#: why the peer could not be built (``None`` when it could); read by the bench report
PEER_UNAVAILABLE: str | None = None


def fft_bound(frontend: Any, config: Any = None) -> Callable[[Any], np.ndarray]:
    """int16 -> complex64 and one complex64 FFT per channel and segment (``scipy.fft``, one worker)."""
    buf = np.empty(frontend.frame_shape, dtype=np.complex64)

    def run(frame: Any) -> np.ndarray:
        buf.real = frame.i
        buf.imag = frame.q
        return scipy.fft.fft(buf, axis=-1, workers=1)

    return run


def peer(frontend: Any, config: Any) -> Callable[[Any], Any] | None:
    """The peer pipeline (module docstring) as ``f(frame) -> list of Stone Soup tracks``; ``None``
    when Stone Soup is not installed."""
    global PEER_UNAVAILABLE
    try:
        from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
        from stonesoup.dataassociator.probability import PDA
        from stonesoup.deleter.error import CovarianceBasedDeleter
        from stonesoup.deleter.time import UpdateTimeStepsDeleter
        from stonesoup.functions import gm_reduce_single
        from stonesoup.hypothesiser.distance import DistanceHypothesiser
        from stonesoup.hypothesiser.probability import PDAHypothesiser
        from stonesoup.initiator.simple import MultiMeasurementInitiator
        from stonesoup.measures import Mahalanobis
        from stonesoup.models.measurement.linear import LinearGaussian
        from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
        from stonesoup.predictor.kalman import KalmanPredictor
        from stonesoup.types.array import StateVectors
        from stonesoup.types.detection import Detection
        from stonesoup.types.state import GaussianState
        from stonesoup.types.update import GaussianStateUpdate
        from stonesoup.updater.kalman import KalmanUpdater
    except ImportError as exc:
        PEER_UNAVAILABLE = f"Stone Soup is not installed ({exc}); pip install stonesoup"
        log.warning("lane peer pipeline unavailable: %s", PEER_UNAVAILABLE)
        return None
    PEER_UNAVAILABLE = None

    from edge.dsp.cfar import os_cfar_scale
    from edge.dsp.geometry import polar_to_ground
    from edge.dsp.pairing import PairingModel, nearest_of_clusters, pair_beats

    cfg = config.section("pipeline.lane")
    tc = config.section("track.pdaf")
    wf = frontend.waveform
    n_rx = frontend.n_rx
    n = wf.n_samples
    fs = np.array([s.sample_rate_hz for s in wf.segments])
    slope = np.array([s.slope_hz_per_s for s in wf.segments])
    win = np.hanning(n)
    freq = np.fft.fftfreq(n)[None, :] * fs[:, None]  # (4, n) Hz
    c = SPEED_OF_LIGHT_MPS
    fd = 2.0 * (cfg.max_speed_kmh / 3.6) / wf.wavelength_m
    f_near, f_far = slope * 2 * cfg.min_range_m / c, slope * 2 * cfg.max_range_m / c
    valid = (freq >= (np.minimum(f_near, f_far) - fd)[:, None]) & (freq <= (np.maximum(f_near, f_far) + fd)[:, None])
    alpha = 1.0 - math.exp(-wf.frame_period_s / cfg.clutter_map_time_s) if cfg.clutter_map_time_s > 0 else 0.0
    background = np.zeros(frontend.frame_shape, dtype=np.complex128)
    n_train, n_guard = cfg.cfar_train_cells, cfg.cfar_guard_cells
    n_ref = 2 * n_train
    rank = max(1, min(n_ref, int(round(cfg.cfar_rank_fraction * n_ref))))
    scale = os_cfar_scale(cfg.cfar_pfa, n_ref, rank, n_looks=n_rx)
    half = n_train + n_guard
    ref_cols = np.r_[0:n_train, n_train + 2 * n_guard + 1:2 * half + 1]  # window columns that are reference cells
    model = PairingModel.from_waveform(wf)
    tol = (cfg.pair_tolerance_bins * fs[2] / n, cfg.pair_tolerance_bins * fs[3] / n)
    grid = np.radians(np.arange(-cfg.angle_max_deg, cfg.angle_max_deg + 1e-9, cfg.angle_step_deg))
    m = np.arange(n_rx)
    steer = np.exp(-2j * np.pi * np.outer(np.sin(grid), m) * frontend.rx_spacing_m / wf.wavelength_m)
    cal = np.asarray(cfg.calibration_gain) * np.exp(1j * np.radians(cfg.calibration_phase_deg))
    outlier = math.radians(cfg.angle_outlier_deg)

    # Stone Soup: state (x, vx, y, vy); measurement (x, y)
    transition = CombinedLinearGaussianTransitionModel(
        [ConstantVelocity(tc.q_lateral_m2ps3), ConstantVelocity(tc.q_along_m2ps3)])
    az_sigma = math.radians(tc.azimuth_sigma_deg)
    sx = math.hypot(tc.extent_sigma_m, 100.0 * az_sigma)  # lateral: azimuth error at a typical 100 m
    sy = math.hypot(tc.range_sigma_m, tc.extent_along_sigma_m)
    meas_model = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.diag([sx * sx, sy * sy]))
    predictor = KalmanPredictor(transition)
    updater = KalmanUpdater(meas_model)
    pda = PDA(hypothesiser=PDAHypothesiser(predictor=predictor, updater=updater, clutter_spatial_density=None,
                                           prob_detect=tc.prob_detect, prob_gate=tc.prob_gate))
    prior = GaussianState(np.zeros((4, 1)), np.diag([0.0, tc.init_speed_sigma_mps ** 2, 0.0,
                                                     tc.init_speed_sigma_mps ** 2]))
    # a PDA update always holds the missed-detection hypothesis, so Stone Soup's update-time deleters
    # never fire on PDA tracks: delete when the position covariance has grown to 4x the measurement's
    deleter = CovarianceBasedDeleter(covar_trace_thresh=4.0 * (sx * sx + sy * sy), mapping=[0, 2])
    initiator = MultiMeasurementInitiator(
        prior_state=prior, measurement_model=meas_model,
        deleter=UpdateTimeStepsDeleter(time_steps_since_update=max(2, tc.confirm_n - tc.confirm_m + 1)),
        data_associator=GNNWith2DAssignment(DistanceHypothesiser(predictor, updater, Mahalanobis(),
                                                                 missed_distance=3.0)),
        updater=updater, min_points=tc.confirm_m)
    tracks: set = set()
    epoch = datetime(2000, 1, 1, tzinfo=timezone.utc)

    def cfar(power: np.ndarray) -> np.ndarray:
        padded = np.concatenate([power[:, -half:], power, power[:, :half]], axis=1)
        windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1, axis=1)[:, :, ref_cols]
        noise = np.partition(windows, rank - 1, axis=-1)[..., rank - 1]
        return noise * scale

    def angle(snaps: np.ndarray) -> tuple[float, int]:
        """Bartlett over the grid per segment and summed; ``snaps`` (4 seg, n_rx) calibrated."""
        per_seg = np.abs(snaps @ steer.conj().T) ** 2  # (4, n_grid)
        own = grid[np.argmax(per_seg, axis=1)]
        agree = np.abs(own - np.median(own)) <= outlier
        spec = (per_seg[agree] / per_seg[agree].sum(axis=1, keepdims=True)).sum(axis=0)
        k = int(np.argmax(spec))
        if 0 < k < grid.size - 1:
            den = spec[k - 1] - 2 * spec[k] + spec[k + 1]
            d = 0.5 * (spec[k - 1] - spec[k + 1]) / den if den < 0 else 0.0
        else:
            d = 0.0
        return float(grid[k] + d * (grid[1] - grid[0])), int(agree.sum())

    def run(frame: Any) -> list:
        nonlocal background
        x = frame.i.astype(np.float64) + 1j * frame.q.astype(np.float64)
        spec = np.fft.fft(x * win, axis=-1) / n  # (rx, seg, bin) complex128
        if alpha > 0:
            background += alpha * (spec - background)
            spec = spec - background
        power = (np.abs(spec) ** 2).sum(axis=0)  # (seg, bin)
        thr = cfar(power)
        left, right = np.roll(power, 1, axis=1), np.roll(power, -1, axis=1)
        peaks = valid & (power > thr) & (power > left) & (power >= right)
        freqs, bins = [], []
        for k in range(4):
            b = np.flatnonzero(peaks[k])
            if b.size > cfg.max_peaks_per_segment:
                b = b[np.argsort(power[k, b])[-cfg.max_peaks_per_segment:]]
            lm, l0, lp = (np.log(power[k, (b + o) % n] + 1e-30) for o in (-1, 0, 1))
            den = lm - 2 * l0 + lp
            d = np.where(den < 0, 0.5 * (lm - lp) / np.where(den < 0, den, -1.0), 0.0)
            freqs.append(freq[k, b] + np.clip(d, -0.5, 0.5) * fs[k] / n)
            bins.append(b)
        pairs = pair_beats(tuple(freqs), model, min_range_m=cfg.min_range_m, max_range_m=cfg.max_range_m,
                           max_speed_mps=cfg.max_speed_kmh / 3.6, tolerance_hz=tol,
                           max_shared=cfg.pair_max_shared_peaks)
        az, keep = [], []
        for j in range(pairs.range_m.size):
            pk = [bins[k][pairs.peak_index[j, k]] for k in range(4)]
            snaps = np.stack([spec[:, k, pk[k]] for k in range(4)]) / cal  # (seg, rx)
            a, n_agree = angle(snaps)
            az.append(a)
            if n_agree >= cfg.angle_min_agreeing:
                keep.append(j)
        az_a = np.asarray(az, dtype=np.float64)
        xg, yg = polar_to_ground(pairs.range_m.astype(np.float64), az_a, cfg.mounting_height_m, cfg.target_height_m)
        keep_a = np.asarray(keep, dtype=np.int64)
        if cfg.cluster_length_m > 0 and keep_a.size > 1:
            keep_a = keep_a[nearest_of_clusters(pairs.range_m[keep_a].astype(np.float64),
                                                pairs.radial_speed_mps[keep_a].astype(np.float64), xg[keep_a],
                                                length_m=cfg.cluster_length_m, speed_mps=cfg.cluster_speed_mps,
                                                lateral_m=cfg.cluster_lateral_m)]
        # Stone Soup PDA tracking
        ts = epoch + timedelta(microseconds=frame.t_ns // 1000)
        dets = {Detection(np.array([[xg[j]], [yg[j]]]), timestamp=ts, measurement_model=meas_model) for j in keep_a}
        hyps = pda.associate(tracks, dets, ts) if tracks else {}
        used = set()
        for track, multi in hyps.items():
            states, weights = [], []
            for h in multi:
                if h:
                    used.add(h.measurement)
                    states.append(updater.update(h))
                else:
                    states.append(h.prediction)
                weights.append(float(h.probability))
            mean, cov = gm_reduce_single(StateVectors([s.state_vector for s in states]),
                                         np.stack([s.covar for s in states], axis=2), np.asarray(weights))
            track.append(GaussianStateUpdate(mean, cov, multi, ts))
        tracks.difference_update(deleter.delete_tracks(tracks))
        tracks.update(initiator.initiate(dets - used, ts))
        return list(tracks)

    return run
