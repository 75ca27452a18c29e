"""Measurement error of the lane profile's detections against simulator truth, and the fit of the SNR noise law
behind ``track.pdaf``'s ``snr_*`` fields (``measurement_noise = "snr"``).

Every detection of a frame is matched to the vehicle it belongs to: the one vehicle whose reference point (the
evaluation's: :mod:`edge.evaluation.lane`) lies within its length + 2 m in ground range, 3 m across and 1.5 m/s in
radial speed (detections matching none or several are left out). Its error is split across (x) and along (y) the
boresight. The law fitted to the error across is

    var_x = r^2 (sigma0^2 / SNR + floor^2) + extent^2        (SNR linear, r the ground range)

the Cramer-Rao form of the Bartlett azimuth (``sigma0``: the sd at 0 dB, ``floor`` in angle) plus which of an extended
vehicle's scatterers gives the peak (``extent``), fitted to the variance of cells of 3 dB x 40 m (at least 30
detections each) by least squares on the log-variance weighted by the cell size. The range error is fitted the same
way (``var_y = sigma0_r^2 / SNR + floor_r^2``), on detections beyond 25 m of vehicles shorter than 10 m.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.optimize import least_squares

__all__ = ["detection_errors", "fit_azimuth_law", "fit_range_law"]

MIN_CELL = 30


def detection_errors(sc, *, seed: int, frames: int | None = None, config: Any = None) -> dict[str, np.ndarray]:
    """Run scenario ``sc`` (a loaded :class:`hw_sim.scenario.Scenario`) through the lane pipeline and return per
    matched detection: ``range_m`` (true ground range), ``snr_db``, ``err_x_m``, ``err_y_m``, ``length_m``."""
    from edge.config import load_config
    from edge.evaluation.lane import _installer_config, _to_radar_ground
    from edge.pipeline import StageTimer
    from edge.pipelines.lane import LanePipeline
    from hal.frame import RawFrame
    from hw_sim.simulator import FrameSimulator

    config = load_config(env={}) if config is None else config
    board = sc.sim_board()
    fe = board.frontend
    n_frames = frames or max(1, int(round(sc.duration_s / fe.waveform.frame_period_s)))
    scene = sc.build_scene(seed)
    sim = FrameSimulator(board, scene, seed)
    pipe = LanePipeline(fe, *_installer_config(config, sc))
    by_id = {tg.id: tg for tg in scene.targets}
    timer = StageTimer(window=16)
    cols: dict[str, list[np.ndarray]] = {k: [] for k in ("range_m", "snr_db", "err_x_m", "err_y_m", "length_m")}
    for n in range(n_frames):
        f = sim.frame(n)
        det = pipe.process(RawFrame(n, int(round(f.t_s * 1e9)), f.i, f.q, fe, f.truth), timer).detections
        tr = f.truth
        veh = [k for k in range(len(tr)) if tr.cls[k] != "clutter"]
        if not veh or not len(det):
            continue
        ids = tr.id[veh]
        ref = _to_radar_ground(scene.pose, np.array(
            [by_id[i].near_face_point(f.t_s) if hasattr(by_id[i], "near_face_point") else tr.position_m[k]
             for i, k in zip(ids, veh)]).reshape(-1, 3))
        length = np.array([getattr(by_id[i], "length_m", 0.0) for i in ids])
        rho_ref = np.hypot(ref[:, 0], ref[:, 1])
        dx = np.asarray(det.x_m, float)[:, None] - ref[None, :, 0]
        dy = np.asarray(det.y_m, float)[:, None] - ref[None, :, 1]
        ok = ((np.abs(np.hypot(det.x_m, det.y_m)[:, None] - rho_ref[None]) < length[None] + 2.0) & (np.abs(dx) < 3.0)
              & (np.abs(np.asarray(det.radial_speed_mps)[:, None] - tr.radial_speed_mps[veh][None]) < 1.5))
        one = ok.sum(axis=1) == 1
        m, j = np.nonzero(ok & one[:, None])
        cols["range_m"].append(rho_ref[j])
        cols["snr_db"].append(np.asarray(det.snr_db, float)[m])
        cols["err_x_m"].append(dx[m, j])
        cols["err_y_m"].append(dy[m, j])
        cols["length_m"].append(length[j])
    return {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}


def _cells(r: np.ndarray, snr: np.ndarray, err: np.ndarray, r_step: float = 40.0) -> np.ndarray:
    """Rows (snr_db centre, mean range, variance about the median, count) of 3 dB x ``r_step`` cells."""
    out = []
    for lo in np.arange(np.floor(snr.min() / 3.0) * 3.0, snr.max(), 3.0) if snr.size else []:
        for rlo in np.arange(0.0, r.max() + r_step, r_step):
            s = (snr >= lo) & (snr < lo + 3.0) & (r >= rlo) & (r < rlo + r_step)
            if s.sum() >= MIN_CELL:
                e = err[s] - np.median(err[s])
                out.append((lo + 1.5, r[s].mean(), e.var(), s.sum()))
    return np.array(out).reshape(-1, 4)


def fit_azimuth_law(errors: dict[str, np.ndarray], *, min_range_m: float = 20.0, sigma0_deg: float | None = None,
                    floor_deg: float | None = None) -> dict[str, Any]:
    """Fit ``sigma0_deg``, ``floor_deg`` and ``extent_m`` of the across law (module docstring) to
    :func:`detection_errors`; a value passed is held fixed (e.g. the angle law of point targets, fitting the extent
    of extended vehicles only). Returns the values, the cells and the model sd per cell."""
    sel = errors["range_m"] > min_range_m
    c = _cells(errors["range_m"][sel], errors["snr_db"][sel], errors["err_x_m"][sel])
    if c.shape[0] < 3:
        raise ValueError(f"too few cells with {MIN_CELL} detections each ({c.shape[0]}): run more frames")
    lin = 10.0 ** (c[:, 0] / 10.0)
    free = [sigma0_deg is None, floor_deg is None, True]
    start = np.array([math.radians(0.5), math.radians(0.02), 0.1])
    fixed = np.array([math.radians(sigma0_deg or 0.0), math.radians(floor_deg or 0.0), 0.0])

    def full(q):
        p = fixed.copy()
        p[np.array(free)] = q
        return p

    def model(p):
        return c[:, 1] ** 2 * (p[0] ** 2 / lin + p[1] ** 2) + p[2] ** 2

    res = least_squares(lambda q: (np.log(model(full(q))) - np.log(c[:, 2])) * np.sqrt(c[:, 3]),
                        start[np.array(free)])
    p = np.abs(full(res.x))
    return {"sigma0_deg": math.degrees(p[0]), "floor_deg": math.degrees(p[1]), "extent_m": float(p[2]),
            "n_detections": int(sel.sum()), "cells": c.tolist(), "model_sd_m": np.sqrt(model(p)).tolist()}


def fit_range_law(errors: dict[str, np.ndarray], *, min_range_m: float = 25.0, max_length_m: float = 10.0
                  ) -> dict[str, Any]:
    """Fit ``sigma0_m``, ``floor_m`` of the range law to the error along (module docstring), per 3 dB cell."""
    sel = (errors["range_m"] > min_range_m) & (errors["length_m"] < max_length_m)
    c = _cells(errors["range_m"][sel], errors["snr_db"][sel], errors["err_y_m"][sel], r_step=1e4)
    if c.shape[0] < 2:
        raise ValueError(f"too few cells with {MIN_CELL} detections each ({c.shape[0]}): run more frames")
    lin = 10.0 ** (c[:, 0] / 10.0)
    res = least_squares(lambda p: (np.log(p[0] ** 2 / lin + p[1] ** 2) - np.log(c[:, 2])) * np.sqrt(c[:, 3]),
                        [0.1, 0.01])
    return {"sigma0_m": float(abs(res.x[0])), "floor_m": float(abs(res.x[1])), "n_detections": int(sel.sum())}
