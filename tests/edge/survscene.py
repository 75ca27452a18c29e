"""Hand-made range-Doppler clusters for the surveillance tracker's tests (no simulator): a target is a
small rectangle of cells on the Distance2Go's (range, wrapped Doppler) grid."""

from __future__ import annotations

import numpy as np

from edge.classify.features import MapPoints

VMAX = 5.348  # km/h: the Distance2Go's unambiguous radial speed
N_BINS = 256  # range and Doppler bins of the map
RANGE_SPAN_M = 24.0


def wrap(v_kmh):
    """Radial speed (km/h) as the board's Doppler shows it, in [-VMAX, VMAX)."""
    return (v_kmh + VMAX) % (2 * VMAX) - VMAX


def blob(r, v, n, label, amp=5.0):
    """``n`` cells around (r, wrapped v): a small rectangle on the (range, Doppler) grid."""
    dr, dv = RANGE_SPAN_M / N_BINS, 2 * VMAX / N_BINS
    rb0, db0 = int(round(r / dr)), int(round((wrap(v) + VMAX) / dv))
    w = max(1, int(np.sqrt(n)))
    k = np.arange(n)
    rb = rb0 + k // w - (n // w) // 2
    db = np.mod(db0 + k % w - w // 2, N_BINS)
    return rb * dr, db * dv - VMAX, np.full(n, amp), rb, db, np.full(n, label)


def points(*blobs):
    """The cells of ``blobs`` as one frame's MapPoints (an empty frame without blobs)."""
    if not blobs:
        z = np.zeros(0)
        return MapPoints(z.astype(np.float32), z.astype(np.float32), z.astype(np.float32), z.astype(np.int32),
                         z.astype(np.int32), z.astype(np.int32))
    cat = [np.concatenate(c) for c in zip(*blobs)]
    return MapPoints(cat[0].astype(np.float32), cat[1].astype(np.float32), cat[2].astype(np.float32),
                     cat[3].astype(np.int32), cat[4].astype(np.int32), cat[5].astype(np.int32))
