"""The same-vehicle box shared by the initiator, confirmer, deleter and re-anchoring: how far across and along a
point or track may lie from a track and still be the same vehicle."""

from __future__ import annotations

import math

import numpy as np

from edge.track.config import SameVehicleConfig
from edge.track.table import TrackTable

__all__ = ["SameVehicleBox", "box_close"]


class SameVehicleBox:
    """Half-sizes of the box: across the boresight growing with range as ``merge_lateral_sigmas`` azimuth sds
    (``azimuth_sigma_deg``) between ``merge_lateral_m`` and ``merge_lateral_max_m``; along it the largest of
    ``merge_along_m``, the speed times ``merge_headway_s`` and ``merge_extent_factor`` sds of the learned extent."""

    def __init__(self, cfg: SameVehicleConfig, azimuth_sigma_deg: float) -> None:
        self.cfg = cfg
        self.azimuth_sigma_deg = azimuth_sigma_deg

    def lateral_m(self, xy: np.ndarray) -> np.ndarray:
        """(N,) half-width across the boresight of the box at ground points ``xy`` (N, 2)."""
        c = self.cfg
        r = np.hypot(xy[:, 0], xy[:, 1])
        lat = c.merge_lateral_sigmas * r * math.radians(self.azimuth_sigma_deg)
        return np.minimum(np.maximum(lat, c.merge_lateral_m), max(c.merge_lateral_m, c.merge_lateral_max_m))

    def along_m(self, tracks: TrackTable) -> np.ndarray:
        """(T,) half-length along the boresight of each track's box."""
        c = self.cfg
        sp = np.hypot(tracks.x[:, 2], tracks.x[:, 3])
        return np.maximum(np.maximum(c.merge_along_m, c.merge_headway_s * sp),
                          c.merge_extent_factor * np.sqrt(tracks.ext_var))


def box_close(a_xy: np.ndarray, b_xy: np.ndarray, lat_m, along_m) -> np.ndarray:
    """(A, B) bool: points closer than the box half-sizes in x and y (scalars or (A,) per row)."""
    d = a_xy[:, None, :] - b_xy[None, :, :]
    lat = np.asarray(lat_m, dtype=float)
    lat = lat[:, None] if lat.ndim == 1 else lat
    along = np.asarray(along_m, dtype=float)
    along = along[:, None] if along.ndim == 1 else along
    return (np.abs(d[..., 0]) < lat) & (np.abs(d[..., 1]) < along)
