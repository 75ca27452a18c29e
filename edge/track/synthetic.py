"""A tracker-only load: the lane tracker on synthetic detections of ``n`` vehicles on a four-lane road plus clutter,
to measure the cost of :meth:`edge.track.tracker.PdafTracker.step` against the number of confirmed tracks
(issue 30: the cost must grow about linearly with the tracks).

The vehicles drive 5 m/s on four lanes (x = +-1.75, +-5.25 m; two lanes receding, two approaching), 50-300 m out,
spaced evenly along each lane, so they stay in view for the run. Each frame every vehicle is detected once at a
random point of its 4.5 m length with the polar noise of the tracker's SNR law (radar equation, ``R^-4``, 30 dB at
100 m, Swerling 1), and Poisson clutter (weak, uniform radial speed) falls in the road box. Seeded.
"""

from __future__ import annotations

import time

import numpy as np

from edge.track.config import PdafConfig
from edge.types import Detections

__all__ = ["road_frames", "step_cost"]

FRAME_NS = 33_000_000
_LANES = ((-5.25, -5.0), (-1.75, -5.0), (1.75, 5.0), (5.25, 5.0))  # (x_m, vy_mps)


def road_frames(n_vehicles: int, n_frames: int, clutter_per_frame: float = 10.0, seed: int = 0,
                snr_100m_db: float = 30.0):
    """Yield ``(t_ns, Detections)`` for ``n_frames`` frames of ``n_vehicles`` vehicles (see the module docstring)."""
    rng = np.random.default_rng(seed)
    law = PdafConfig()
    lane = np.arange(n_vehicles) % 4
    k_in_lane = np.arange(n_vehicles) // 4
    per_lane = max(int(np.ceil(n_vehicles / 4)), 1)
    x0 = np.array([_LANES[i][0] for i in lane])
    vy = np.array([_LANES[i][1] for i in lane])
    y0 = 50.0 + (k_in_lane + 0.5 * (lane % 2)) * (250.0 / per_lane)
    for k in range(n_frames):
        t_s = k * FRAME_NS * 1e-9
        off = rng.uniform(-2.25, 2.25, n_vehicles)
        px, py = x0, y0 + vy * t_s + off
        rho = np.hypot(px, py)
        s_db = snr_100m_db - 40.0 * np.log10(rho / 100.0) + 10.0 * np.log10(rng.exponential(size=n_vehicles))
        s_db = np.clip(s_db, 4.0, 60.0)
        lin = 10.0 ** (np.clip(s_db, law.snr_min_db, law.snr_max_db) / 10.0)
        sd_r = np.hypot(law.snr_range_sigma_m / np.sqrt(lin), law.snr_range_floor_m)
        sd_az = np.radians(np.hypot(law.snr_azimuth_sigma_deg / np.sqrt(lin), law.snr_azimuth_floor_deg))
        r = rho + rng.normal(0.0, 1.0, n_vehicles) * sd_r
        az = np.arctan2(px, py) + rng.normal(0.0, 1.0, n_vehicles) * sd_az
        vr = py * vy / rho + rng.normal(0.0, 0.3, n_vehicles)
        nc = rng.poisson(clutter_per_frame) if clutter_per_frame > 0 else 0
        cx, cy = rng.uniform(-8.0, 8.0, nc), rng.uniform(5.0, 300.0, nc)
        yield (k * FRAME_NS,
               Detections.from_polar(np.concatenate([r, np.hypot(cx, cy)]),
                                     np.concatenate([vr, rng.uniform(-40.0, 40.0, nc)]),
                                     np.concatenate([az, np.arctan2(cx, cy)]),
                                     np.concatenate([s_db, np.full(nc, 6.0)])))


def step_cost(n_vehicles: int, n_frames: int = 200, warmup: int = 40, clutter_per_frame: float = 10.0,
              seed: int = 0, config: PdafConfig | None = None) -> dict:
    """Run a fresh lane tracker over :func:`road_frames` and time ``step`` (thread CPU time) after ``warmup``
    frames: ``{"vehicles", "confirmed" (mean published tracks), "p50_us", "p99_us", "mean_us"}``."""
    from edge.track.tracker import PdafTracker

    tracker = PdafTracker(config)
    times, published = [], []
    for k, (t_ns, det) in enumerate(road_frames(n_vehicles, n_frames, clutter_per_frame, seed)):
        t0 = time.thread_time_ns()
        out = tracker.step(det, t_ns)
        dt = time.thread_time_ns() - t0
        if k >= warmup:
            times.append(dt * 1e-3)
            published.append(sum(1 for tr in out if tr.confirmed))
    a = np.asarray(times)
    return {"vehicles": n_vehicles, "confirmed": float(np.mean(published)), "p50_us": float(np.percentile(a, 50)),
            "p99_us": float(np.percentile(a, 99)), "mean_us": float(a.mean())}


if __name__ == "__main__":  # python -m edge.track.synthetic [n ...]
    import sys

    for n in [int(a) for a in sys.argv[1:]] or [5, 20, 64]:
        print(step_cost(n))
