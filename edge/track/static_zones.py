"""Ranges where something stands in the surveillance profile's view (``track.alphabeta.static_zone_*``).

Swaying foliage (a bush, a tree crown) keeps its place while its leaves move: the IIR canceller passes it, and DBSCAN
finds a cluster at the same range with a wrapped Doppler near zero in a large share of the frames, which a tracker
follows as a target that never leaves. :class:`StaticZones` keeps, per range cell of the board's range resolution,
the exponentially weighted share of frames with such a slow cluster. A cell whose share is at least the occupancy
is a static zone, and a slow cluster there is site clutter: it starts and feeds no track. A target crossing the beam
stays a few seconds at one range, which adds less than the occupancy to its cell's share at the default time
constant; a vehicle's wrapped Doppler is near zero only in the frames it needs to cross one range cell.
"""

from __future__ import annotations

import math

import numpy as np


class StaticZones:
    """Occupancy of slow clusters per range cell; see the module docstring."""

    def __init__(self, cell_m: float, max_range_m: float, frame_period_s: float, time_s: float, speed_kmh: float,
                 occupancy: float) -> None:
        if not cell_m > 0 or not time_s > 0:
            raise ValueError("static zones need a positive range cell and time constant")
        self.cell_m = float(cell_m)
        self.weight = 1.0 - math.exp(-frame_period_s / time_s)
        self.speed_kmh = float(speed_kmh)
        self.occupancy = float(occupancy)
        self.share = np.zeros(int(math.ceil(max_range_m / cell_m)) + 2)

    def _cells(self, range_m: np.ndarray) -> np.ndarray:
        return np.clip((np.asarray(range_m, dtype=float) / self.cell_m).astype(np.intp), 0, self.share.size - 1)

    def update(self, range_m: np.ndarray, doppler_kmh: np.ndarray) -> np.ndarray:
        """One frame's clusters (centroid range m, wrapped Doppler km/h): which are slow clusters in a static zone
        (bool, judged on the frames before this one); then this frame's slow clusters join the shares."""
        slow = np.abs(np.asarray(doppler_kmh, dtype=float)) <= self.speed_kmh
        cells = self._cells(range_m)
        standing = slow & (self.share[cells] >= self.occupancy)
        seen = np.zeros(self.share.size)
        seen[cells[slow]] = 1.0
        self.share += self.weight * (seen - self.share)
        return standing

    def zones_m(self) -> list[tuple[float, float]]:
        """The static zones as they stand: (near, far) range intervals in metres."""
        on = self.share >= self.occupancy
        out: list[tuple[float, float]] = []
        for k in np.flatnonzero(on).tolist():
            lo, hi = k * self.cell_m, (k + 1) * self.cell_m
            if out and abs(out[-1][1] - lo) < 1e-9:
                out[-1] = (out[-1][0], hi)
            else:
                out.append((lo, hi))
        return out
