"""Polar measurements of a raised, tilted radar -> ground-plane Cartesian coordinates (Lim eq. 16).

Lim's eq. (16), ``x = R sin(theta)``, ``y = R cos(theta)``, holds for a radar at target height. On an
overpass the measured range is slant and the array's azimuth ``theta`` is a cone angle about the
array axis (``sin(theta)`` is the direction cosine along it). For a radar at ``height_m`` whose
boresight is tilted down by ``tilt_rad`` and a target at ``target_height_m``, the direction
``u = (sin theta, rho cos phi, rho sin phi)`` in the radar frame (``rho = cos theta``) must reach the
target's height, which fixes ``phi = tilt + asin((target_height - height) / (R rho))``. Then, in the
ground frame of the radar's foot (x lateral, y along the boresight's ground projection)::

    x = R sin(theta)
    y = R rho (cos phi cos tilt + sin phi sin tilt) = R rho cos(phi - tilt)

i.e. ``y = sqrt((R cos theta)^2 - dz^2)``: the ground range along the boresight. With
``height = target_height`` it reduces to eq. (16).
"""

from __future__ import annotations

import numpy as np


def polar_to_ground(range_m: np.ndarray, az_rad: np.ndarray, height_m: float, target_height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """``(x_m, y_m)`` float32 on the ground plane; ``range_m`` slant, ``az_rad`` array cone angle.

    Targets nearer than the height difference (no real solution) are put at ``y = 0``.
    """
    r = np.asarray(range_m, dtype=np.float32)
    az = np.asarray(az_rad, dtype=np.float32)
    dz = np.float32(height_m - target_height_m)
    x = r * np.sin(az)
    rc = r * np.cos(az)
    y = np.sqrt(np.maximum(rc * rc - dz * dz, np.float32(0)))
    return x.astype(np.float32, copy=False), y.astype(np.float32, copy=False)  # (fresh arrays: no copies)
