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
        self._decay = np.empty_like(self.share)

    def update(self, range_m, doppler_kmh) -> list[int]:
        """One frame's clusters (centroid ranges m, wrapped Dopplers km/h; sequences): the indices of the slow
        clusters in a static zone (judged on the frames before this one); then this frame's slow clusters join the
        shares. A loop over the frame's few clusters: numpy's per-call cost would exceed the work."""
        share, cell, last = self.share, self.cell_m, self.share.size - 1
        standing: list[int] = []
        seen: dict[int, float] = {}
        for k, (r, v) in enumerate(zip(range_m, doppler_kmh)):
            if not abs(v) <= self.speed_kmh:
                continue
            c = min(max(int(r / cell), 0), last)
            if c not in seen:
                seen[c] = float(share[c])
            if seen[c] >= self.occupancy:
                standing.append(k)
        # share += w (seen - share): share - w share where nothing was seen, share + w (1 - share) where it was
        np.multiply(share, self.weight, out=self._decay)
        share -= self._decay
        w = self.weight
        for c, s in seen.items():
            share[c] = s + w * (1.0 - s)
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
