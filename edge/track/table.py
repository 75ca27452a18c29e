"""The lane tracker's records: the track table (a struct of arrays, one row per track), the id pool and one frame's
measurements (float64, ground plane)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from edge.types import Detections

__all__ = ["IdPool", "TrackTable", "Measurements"]


class IdPool:
    """Small integer ids ``1..max_id``, handed out lowest-first at start, then oldest-released first
    (a released id waits as long as possible before it is reused, so consumers do not confuse vehicles)."""

    def __init__(self, max_id: int) -> None:
        self._free: deque[int] = deque(range(1, max_id + 1))
        self._used: set[int] = set()

    def acquire(self) -> int | None:
        if not self._free:
            return None
        i = self._free.popleft()
        self._used.add(i)
        return i

    def release(self, track_id: int) -> None:
        if track_id in self._used:
            self._used.remove(track_id)
            self._free.append(track_id)

    @property
    def in_use(self) -> int:
        return len(self._used)


@dataclass
class TrackTable:
    """All tracks as columns (row = track). ``track_id`` is 0 until a track is confirmed."""

    x: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    p: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    track_id: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    age: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    hits: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    misses: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    history: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint32))  # bit 0 = this frame hit
    confirmed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    moved: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # was ever surely moving
    ext_var: np.ndarray = field(default_factory=lambda: np.zeros(0))  # along-heading detection spread, m^2
    close_run: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))  # frames next to a twin
    score: np.ndarray = field(default_factory=lambda: np.zeros(0))  # log-likelihood-ratio track score (edge.track.score)
    # IMM (motion_model = "imm"): per-mode states and mode probabilities; x, p are their moment-matched mixture
    xm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 4)))
    pm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 4, 4)))
    mu: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    # lateral_smoother: the straight-line filter across the boresight, [x, vx] and its covariance
    lat: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    lat_p: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    lat_cusum: np.ndarray = field(default_factory=lambda: np.zeros(0))  # CUSUM of the IMM-vs-line likelihood ratio

    _COLUMNS = ("x", "p", "track_id", "age", "hits", "misses", "history", "confirmed", "moved", "ext_var",
                "close_run", "score", "xm", "pm", "mu", "lat", "lat_p",
                "lat_cusum")

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def keep(self, mask: np.ndarray, kernel=None) -> None:
        """Keep the rows where the boolean array ``mask`` (T,) is true. ``kernel``: the compiled ``edge.native._track``,
        which copies the rows of every column in one call (the same arrays)."""
        rows = mask.nonzero()[0]  # one take per column: half the cost of compress, which finds the rows each time
        if kernel is not None:
            for c, a in zip(self._COLUMNS, kernel.take_rows([getattr(self, c) for c in self._COLUMNS], rows)):
                setattr(self, c, a)
            return
        for c in self._COLUMNS:
            setattr(self, c, getattr(self, c).take(rows, axis=0))

    def count(self, hit: np.ndarray) -> None:
        """One frame older; ``hit`` (T,) the tracks with a validated detection this frame."""
        self.age += 1
        self.hits += hit
        self.misses = (self.misses + 1) * ~hit  # int32: 0 on a hit
        self.history = (self.history << np.uint32(1)) | hit  # uint32, bit 0 = this frame

    def append(self, x: np.ndarray, p: np.ndarray, ext_var: float, keep_prob: float = 0.5, kernel=None) -> None:
        """Add ``k`` tentative tracks at states ``x`` (k, 4), ``p`` (k, 4, 4): both IMM modes at the state with the
        probabilities ``(keep_prob, 1 - keep_prob)``, the straight-line filter at its lateral part. ``kernel``: the
        compiled ``edge.native._track``, which makes every column in one call (``append_rows``, the same arrays), or
        joins them (``concat_rows``) when a column is not of the table's dtypes and shapes."""
        if kernel is not None and kernel.append_rows(self, x, p, ext_var, keep_prob):  # every column in one call
            return
        k = x.shape[0]
        zeros, ones, no, ones_u32, zeros_f, ext, mu = _new_rows(k, ext_var, keep_prob)
        new = (x, p, zeros, ones, ones, zeros, ones_u32, no, no, ext, zeros, zeros_f, x[:, None].repeat(2, axis=1),
               p[:, None].repeat(2, axis=1), mu, x[:, 0::2], p[:, 0::2, 0::2], zeros_f)  # in _COLUMNS' order
        cols = self._COLUMNS
        if kernel is not None:
            joined = kernel.concat_rows([getattr(self, c) for c in cols], list(new))
        else:
            cat = np.concatenate
            joined = [cat([getattr(self, c), a]) for c, a in zip(cols, new)]
        for c, a in zip(cols, joined):
            setattr(self, c, a)


_NEW_ROWS: dict[tuple[int, float, float], tuple[np.ndarray, ...]] = {}


def _new_rows(k: int, ext_var: float, keep_prob: float) -> tuple[np.ndarray, ...]:
    """The constant columns of ``k`` new tracks (read-only, cached: ``TrackTable.append`` copies them): int32 zeros
    and ones, bool zeros, uint32 ones, float zeros, ``ext_var`` and the mode probabilities ``(keep, 1 - keep)``."""
    key = (k, ext_var, keep_prob)
    rows = _NEW_ROWS.get(key)
    if rows is None:
        mu = np.empty((k, 2))
        mu[:, 0], mu[:, 1] = keep_prob, 1.0 - keep_prob
        rows = (np.zeros(k, dtype=np.int32), np.ones(k, dtype=np.int32), np.zeros(k, dtype=bool),
                np.ones(k, dtype=np.uint32), np.zeros(k), np.full(k, ext_var), mu)
        for a in rows:
            a.flags.writeable = False
        if len(_NEW_ROWS) < 256:  # a few seed counts per configuration
            _NEW_ROWS[key] = rows
    return rows


@dataclass
class Measurements:
    """One frame's detections as the filter sees them (float64, ground plane)."""

    z: np.ndarray  # (M, n): x, y[, ground radial speed]
    snr_db: np.ndarray  # (M,)
    with_radial_speed: bool
    pair: np.ndarray | None = None  # (M,) int: detections split from one (edge.dsp.resolve) share a value >= 0
    unresolved: np.ndarray | None = None  # (M,) bool: two sources in the cell, not split (edge.dsp.resolve's hint)

    @classmethod
    def from_detections(cls, det: Detections, use_radial_speed: bool, kernel=None) -> "Measurements":
        """The frame's measurements; ``kernel``: the compiled ``edge.native._track``, used when the columns are
        float32 arrays of finite values and the extra columns plain arrays (the same values)."""
        cols = (det.x_m, det.y_m, det.snr_db, det.radial_speed_mps, det.range_m)
        if kernel is not None:
            extra = det.extra
            res = kernel.measurements(*cols, use_radial_speed, extra.get("resolved_pair"), extra.get("unresolved_pair"))
            if res is not None:
                return cls(res[0], res[1], use_radial_speed, res[2], res[3])
        # one float64 array of the five columns (a handful of detections: few calls, not few flops)
        cols = np.array(cols, dtype=np.float64)
        fin = np.isfinite(cols)
        every = bool(fin.all())  # the usual frame: no checks column by column
        ok = fin[0] & fin[1]
        all_ok = every or bool(ok.all())
        if not all_ok:
            cols, fin = cols[:, ok], fin[:, ok]
        x, y, snr, vr, rng = cols
        use = use_radial_speed and (every or bool(fin[3:5].all()))
        if use:
            rho = np.hypot(x, y)
            near = rho <= 1e-6
            if np.count_nonzero(near):
                ratio = np.divide(rng, rho, out=np.ones_like(rho), where=~near)
            else:
                ratio = rng / rho
            z = np.empty((x.size, 3))
            z[:, 2] = vr * ratio
        else:
            z = np.empty((x.size, 2))
        z[:, 0] = x
        z[:, 1] = y
        pair = det.extra.get("resolved_pair")
        if pair is not None and len(pair) == ok.size:
            pair = np.asarray(pair, dtype=np.int64)
            pair = pair if all_ok else pair[ok]
            if not np.count_nonzero(pair >= 0):
                pair = None
        else:
            pair = None
        if not every and not fin[2].all():
            snr = np.nan_to_num(snr, nan=0.0)
        unr = _extra_column(det, "unresolved_pair", bool, ok, all_ok, ok.size)
        return cls(z, snr, use, pair, unr)


def _pair_column(det: Detections, n: int) -> np.ndarray | None:
    """``det.extra["resolved_pair"]`` as int64 for the ``n`` detections, all kept; None if absent, mis-sized or
    without a pair."""
    pair = det.extra.get("resolved_pair")
    if pair is None or len(pair) != n:
        return None
    pair = np.asarray(pair, dtype=np.int64)
    return pair if np.count_nonzero(pair >= 0) else None


def _extra_column(det: Detections, key: str, dtype, ok: np.ndarray | None, all_ok: bool,
                  n: int) -> np.ndarray | None:
    """The per-detection column ``det.extra[key]`` of the ``n`` detections as ``dtype``, rows ``ok`` kept; None if
    absent, mis-sized or all false."""
    col = det.extra.get(key)
    if col is None or len(col) != n:
        return None
    col = np.asarray(col, dtype=dtype)
    col = col if all_ok else col[ok]
    return col if np.count_nonzero(col) else None
