"""Ranges where something stands in the surveillance profile's view (``track.alphabeta.static_zone_*``).

Swaying foliage (a bush, a tree crown) keeps its place while its leaves move: the IIR canceller passes it, and DBSCAN
finds a cluster at the same range with a wrapped Doppler near zero in a large share of the frames, which a tracker
follows as a target that never leaves. :class:`StaticZones` keeps, per range cell of the board's range resolution,
the exponentially weighted share of frames with such a slow cluster over the cell: every cell its cells span
counts, so a bush whose centroid wanders across a cell boundary counts in both cells. A cell whose share is at least
the occupancy is a static zone, and a slow cluster whose centroid lies there is site clutter: it starts and feeds no
track. A target crossing the beam stays a few seconds at one range, which adds less than the occupancy to the cells
it spans at the default time constant; a vehicle's wrapped Doppler is near zero only in the frames it needs to cross
one range cell, or, at an alias, while its body covers a cell (a 10 m truck at 11 km/h: 3 s).
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

    def update(self, range_m, doppler_kmh, lo_m=None, hi_m=None) -> list[int]:
        """One frame's clusters (centroid ranges m, wrapped Dopplers km/h; sequences; optionally the near and far
        range of each cluster's cells): the indices of the slow clusters whose centroid lies in a static zone
        (judged on the frames before this one); then every cell a slow cluster's cells span (its centroid's
        without a span) counts one frame with a slow cluster. A loop over the frame's few clusters: numpy's
        per-call cost would exceed the work."""
        share, cell, last = self.share, self.cell_m, self.share.size - 1
        standing: list[int] = []
        seen: set[int] = set()
        for k, (r, v) in enumerate(zip(range_m, doppler_kmh)):
            if not abs(v) <= self.speed_kmh:
                continue
            c = min(max(int(r / cell), 0), last)
            if share[c] >= self.occupancy:
                standing.append(k)
            seen.add(c)
            if lo_m is not None:
                a = min(max(int(lo_m[k] / cell), 0), last)
                b = min(max(int(hi_m[k] / cell), 0), last)
                seen.update(range(a, b + 1))
        before = {c: float(share[c]) for c in seen}
        # share += w (seen - share): share - w share where nothing was seen, share + w (1 - share) where it was
        np.multiply(share, self.weight, out=self._decay)
        share -= self._decay
        w = self.weight
        for c, was in before.items():
            share[c] = was + w * (1.0 - was)
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
