"""Synthetic detections for tracker and traffic tests (seeded; no IF simulator).

Vehicles move on straight lines (optionally with a lateral manoeuvre); each frame a vehicle is
detected with probability ``p_detect`` at its reference point with polar noise; uniform clutter is
added in a box. Everything is returned as :class:`edge.types.Detections` per frame.

Two sensor models (``noise``): ``"constant"`` (default) draws the polar noise with the given sd whatever
SNR it reports (uniform 10-30 dB): track such scenes with :func:`scene_config` (the tracker's
``measurement_noise = "constant"``). ``"snr"`` reports a radar-equation SNR per detection (``snr_100m_db`` at
100 m, R^-4, Swerling 1 fluctuation) and draws the noise from it with the law of the tracker's
``measurement_noise = "snr"`` (``sigma^2 = sigma0^2 / SNR + floor^2``, the PdafConfig defaults), plus
``extent_sigma_m`` isotropic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge.track import PdafConfig
from edge.types import Detections

FRAME_NS = 33_000_000


def scene_config(**kw) -> PdafConfig:
    """Tracker configuration for ``noise="constant"`` scenes: their noise does not depend on the SNR they
    report, so the tracker is told so (``measurement_noise = "constant"``); ``kw`` as for PdafConfig."""
    kw.setdefault("measurement_noise", "constant")
    return PdafConfig(**kw)


@dataclass
class Vehicle:
    x0_m: float
    y0_m: float
    vx_mps: float
    vy_mps: float
    t_start_s: float = 0.0
    t_end_s: float = 1e9
    lane_change: tuple[float, float, float] | None = None  # (t_start_s, duration_s, dx_m)
    length_m: float = 0.0  # > 0: extended target, 1-3 detections per frame spread along its length

    def position(self, t_s: float) -> tuple[float, float]:
        x = self.x0_m + self.vx_mps * t_s
        y = self.y0_m + self.vy_mps * t_s
        if self.lane_change is not None:
            ts, dur, dx = self.lane_change
            u = min(max((t_s - ts) / dur, 0.0), 1.0)
            x += dx * (3 * u * u - 2 * u * u * u)  # smooth step
        return x, y

    def active(self, t_s: float) -> bool:
        return self.t_start_s <= t_s <= self.t_end_s

    def velocity(self, t_s: float, eps: float = 1e-3) -> tuple[float, float]:
        a, b = self.position(t_s - eps), self.position(t_s + eps)
        return (b[0] - a[0]) / (2 * eps), (b[1] - a[1]) / (2 * eps)


def frames(
    vehicles: list[Vehicle],
    n_frames: int,
    *,
    seed: int = 0,
    p_detect: float = 1.0,
    range_sigma_m: float = 0.15,
    az_sigma_deg: float = 0.5,
    vr_sigma_mps: float = 0.3,
    clutter_per_frame: float = 0.0,
    clutter_box: tuple[float, float, float, float] = (-15.0, 15.0, 5.0, 250.0),
    frame_ns: int = FRAME_NS,
    min_y_m: float = 3.0,
    fov_deg: float = 20.0,
    noise: str = "constant",
    snr_100m_db: float = 30.0,
    extent_sigma_m: float = 0.0,
):
    """Yield ``(t_ns, Detections, truth)`` with ``truth`` a list of (index, x, y, vx, vy) per vehicle in view
    (beyond ``min_y_m`` and within ``fov_deg`` of boresight)."""
    rng = np.random.default_rng(seed)
    az_sigma = np.radians(az_sigma_deg)
    law = PdafConfig()
    for k in range(n_frames):
        t_ns = k * frame_ns
        t_s = t_ns * 1e-9
        r, vr, az, truth, snr = [], [], [], [], []
        for i, v in enumerate(vehicles):
            if not v.active(t_s):
                continue
            x, y = v.position(t_s)
            vx, vy = v.velocity(t_s)
            if y < min_y_m or abs(np.degrees(np.arctan2(x, y))) > fov_deg:
                continue
            truth.append((i, x, y, vx, vy))
            if rng.random() > p_detect:
                continue
            pts = [(x, y)]
            if v.length_m > 0:
                sp = np.hypot(vx, vy) or 1.0
                off = rng.uniform(-0.5, 0.5, 1 + min(rng.poisson(1.0), 2)) * v.length_m
                pts = [(x + o * vx / sp, y + o * vy / sp) for o in off]
            for px, py in pts:
                rho = np.hypot(px, py)
                if noise == "snr":
                    s_db = snr_100m_db - 40.0 * np.log10(rho / 100.0) + 10.0 * np.log10(rng.exponential())
                    s_db = min(max(s_db, 4.0), 60.0)
                    snr.append(s_db)
                    lin = 10.0 ** (min(max(s_db, law.snr_min_db), law.snr_max_db) / 10.0)
                    sd_r = np.hypot(law.snr_range_sigma_m / np.sqrt(lin), law.snr_range_floor_m)
                    sd_az = np.radians(np.hypot(law.snr_azimuth_sigma_deg / np.sqrt(lin), law.snr_azimuth_floor_deg))
                    px, py = px + rng.normal(0, extent_sigma_m), py + rng.normal(0, extent_sigma_m)
                    rho = np.hypot(px, py)
                else:
                    sd_r, sd_az = range_sigma_m, az_sigma
                r.append(rho + rng.normal(0, sd_r))
                az.append(np.arctan2(px, py) + rng.normal(0, sd_az))
                vr.append((px * vx + py * vy) / rho + rng.normal(0, vr_sigma_mps))
        nc = rng.poisson(clutter_per_frame) if clutter_per_frame > 0 else 0
        if nc:
            x0, x1, y0, y1 = clutter_box
            cx, cy = rng.uniform(x0, x1, nc), rng.uniform(y0, y1, nc)
            r.extend(np.hypot(cx, cy))
            az.extend(np.arctan2(cx, cy))
            vr.extend(rng.uniform(-40, 40, nc))
        n = len(r)
        if noise == "snr":
            snr_db = np.concatenate([snr, np.full(n - len(snr), 6.0)])  # clutter: weak
        else:
            snr_db = rng.uniform(10, 30, n)
        det = Detections.from_polar(r, vr, az, snr_db) if n else Detections.empty()
        yield t_ns, det, truth
