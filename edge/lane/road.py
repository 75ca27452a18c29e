"""The road as detection sees it: lane directions and centres across the road, and a ground position's lateral
offset in the road frame (the operations of :func:`edge.traffic.lanes.to_road`)."""

from __future__ import annotations

import math

import numpy as np


class RoadFrame:
    """Per-lane arrays of the lanes in the feedback, cached while the lanes stay the same object (they change only
    when the traffic layer learns or is given them)."""

    def __init__(self) -> None:
        self._lane_cache: tuple = (None, 0.0, None)  # (lanes, their span across, directions)
        self._centres_cache: tuple = (None, None)  # (lanes, their centres)

    def lane_arrays(self, lanes) -> tuple[float, np.ndarray]:
        """(span of the road across (m), (L + 1,) lane directions and a 0 after them, which lane index -1 --
        outside every lane -- reads) of ``lanes``."""
        if self._lane_cache[0] is not lanes:
            self._lane_cache = (lanes, max(ln.center_m + 0.5 * ln.width_m for ln in lanes)
                                - min(ln.center_m - 0.5 * ln.width_m for ln in lanes),
                                np.array([ln.direction for ln in lanes] + [0]))
        return self._lane_cache[1], self._lane_cache[2]

    def lane_centres(self, lanes) -> np.ndarray:
        """(L,) lane centres across the road (m) of ``lanes``."""
        if self._centres_cache[0] is not lanes:
            self._centres_cache = (lanes, np.array([ln.center_m for ln in lanes]))
        return self._centres_cache[1]

    @staticmethod
    def across_road(x: np.ndarray, y: np.ndarray, yaw_rad: float) -> np.ndarray:
        """Lateral offset (float64, m) of ground positions in the road frame of ``yaw_rad``, as
        edge.traffic.lanes.to_road computes it (its operations only: the lanes' coordinate)."""
        return x.astype(np.float64) * math.cos(yaw_rad) + y.astype(np.float64) * math.sin(yaw_rad)
