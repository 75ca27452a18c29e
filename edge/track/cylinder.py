"""The wrapped range-Doppler map as the lateral surface of a cylinder (Tavanti eqs. 6, 7, 14).

The Distance2Go's unambiguous radial-speed interval is only ``(-v_max, v_max]`` (about ±5.4 km/h),
so a target's Doppler spread wraps around. Tavanti wraps the map along the Doppler axis onto a
cylinder embedded in 3-D Euclidean space::

    theta = pi (v + v_max) / v_max                 polar angle in [0, 2 pi)
    v'    = (v_max / pi) cos(theta)                km/h
    v''   = (v_max / pi) sin(theta)                km/h
    r     = range                                  m

Units follow DESIGN §5: the Doppler coordinates are in km/h and the range in metres, so DBSCAN's
``eps`` and the tracker's ``R_gate`` are distances in that mixed metric. The cylinder radius is
``v_max / pi`` km/h (circumference ``2 v_max``, one full Doppler interval).

Points are arrays with a last axis ``(v', v'', r)``; every function is vectorised.
"""

from __future__ import annotations

import math

import numpy as np

from edge import native

__all__ = ["Cylinder"]


class Cylinder(native.KernelUser):
    """Geometry of the wrapped map for a given maximum unambiguous radial speed ``vmax_kmh``."""

    def __init__(self, vmax_kmh: float) -> None:
        if not (vmax_kmh > 0 and math.isfinite(vmax_kmh)):
            raise ValueError(f"vmax_kmh must be a positive number, got {vmax_kmh!r}")
        self.vmax_kmh = float(vmax_kmh)
        self.radius_kmh = self.vmax_kmh / math.pi
        #: the compiled projections of (n, 3) points and (n, 6) states (edge/native/_alphabeta.pyx), None: numpy
        self.kernel = native.load("_alphabeta")

    # --- eq. 6 and its inverse (eq. 7) ---------------------------------------------------------
    def angle_of_speed(self, v_kmh: np.ndarray) -> np.ndarray:
        """Polar angle (rad) of a wrapped radial speed: ``pi (v + v_max) / v_max``, any shape."""
        return np.pi * (np.asarray(v_kmh) + self.vmax_kmh) / self.vmax_kmh

    def speed_of_angle(self, theta_rad: np.ndarray) -> np.ndarray:
        """Wrapped radial speed (km/h) in ``[-v_max, v_max)`` of a polar angle (eq. 7)."""
        th = np.mod(np.asarray(theta_rad), 2.0 * np.pi)
        return th * self.vmax_kmh / np.pi - self.vmax_kmh

    def to_cylinder(self, range_m: np.ndarray, v_kmh: np.ndarray, dtype=np.float32) -> np.ndarray:
        """``(range_m, v_kmh)`` (same shape ``S``) -> points ``S + (3,)`` = ``(v', v'', r)`` (eq. 6)."""
        th = self.angle_of_speed(v_kmh)
        out = np.empty(np.shape(range_m) + (3,), dtype=dtype)
        out[..., 0] = self.radius_kmh * np.cos(th)
        out[..., 1] = self.radius_kmh * np.sin(th)
        out[..., 2] = range_m
        return out

    def from_cylinder(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points ``(..., 3)`` -> ``(range_m, v_kmh)`` with the polar angle of ``(v', v'')`` (eq. 7)."""
        p = np.asarray(points)
        th = np.arctan2(p[..., 1], p[..., 0])
        return p[..., 2], self.speed_of_angle(th)

    # --- eq. 14 --------------------------------------------------------------------------------
    def project_points(self, points: np.ndarray) -> np.ndarray:
        """Radial projection of ``(..., 3)`` points onto the cylinder surface (a copy).

        A point on the axis (``v' = v'' = 0``) has no polar angle; it is put at angle 0.
        """
        p = np.array(points, dtype=np.float64, copy=True)
        if self.kernel is not None and p.ndim == 2 and p.shape[1] == 3 and p.flags.c_contiguous:
            self.kernel.project_points(p, self.radius_kmh)
            return p
        th = np.arctan2(p[..., 1], p[..., 0])
        p[..., 0] = self.radius_kmh * np.cos(th)
        p[..., 1] = self.radius_kmh * np.sin(th)
        return p

    def project_states(self, states: np.ndarray) -> np.ndarray:
        """The operator N of eq. 14 on states ``(..., 6)`` = ``(v', u', v'', u'', r, u_r)``.

        Positions are projected radially onto the cylinder; the normal component
        ``(u . n) n`` with ``n = (cos th, sin th, 0)`` is removed from the velocity, leaving it tangent
        to the surface. ``r`` and ``u_r`` are unchanged. Returns a new float64 array.
        """
        s = np.array(states, dtype=np.float64, copy=True)
        if self.kernel is not None and s.ndim == 2 and s.shape[1] == 6 and s.flags.c_contiguous:
            self.kernel.project_states(s, self.radius_kmh)
            return s
        th = np.arctan2(s[..., 2], s[..., 0])
        c, sn = np.cos(th), np.sin(th)
        normal = s[..., 1] * c + s[..., 3] * sn
        s[..., 0] = self.radius_kmh * c
        s[..., 2] = self.radius_kmh * sn
        s[..., 1] = s[..., 1] - normal * c
        s[..., 3] = s[..., 3] - normal * sn
        return s
