"""Lane geometry, the road frame, the mounting-yaw estimate and lane learning.

Road frame: the radar is yawed by ``yaw`` (clockwise from the road axis, as ``hw_sim``'s
``RadarPose.yaw_deg``), so a point ``(x, y)`` of the radar's ground plane lies at

    u = x cos(yaw) + y sin(yaw)      across the road (right +, from the radar's foot)
    s = -x sin(yaw) + y cos(yaw)     along the road (away from the radar +)

and the road axis points along ``(-sin(yaw), cos(yaw))`` in radar coordinates.

Yaw estimate: every confirmed track accumulates running sums of its positions (O(1) memory per
track); when it ends, the principal axis of its position scatter is the direction it drove. Tracks
that covered at least ``yaw_min_track_length_m`` with a small spread across that axis (no lane change)
vote; the yaw is the median vote of the last ``yaw_window_tracks``. Until ``yaw_min_tracks`` tracks have
ended, running tracks that already qualify vote too (otherwise a mis-aimed radar assigns lanes wrongly
for the first tens of seconds). With configured lanes the start-up estimate is instead the yaw that puts the
frame's confirmed tracks into the lanes of their direction of travel (:func:`align_yaw`): one frame of tracks
fixes it to hundredths of a degree, where a direction needs tens of metres of each track. It holds until the
ended tracks' median direction has a standard error no larger than the alignment's sigma.

Lane learning: positions of confirmed tracks (between ``learn_min_range_m`` and ``learn_max_range_m``)
go into a bounded ring buffer; a lateral histogram in the road frame, smoothed, gives one peak per
lane (centre refined as the mean of the samples around the peak); the width is the median spacing of
neighbouring centres; the direction is the sign of the median along-road speed in that lane. Lanes are
numbered 0, 1, ... from the most negative offset (left) to the right, like ``[[lane]]`` of a scenario.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from edge import native

__all__ = ["Lane", "to_road", "assign_lanes", "assign_lanes_with_margin", "align_yaw", "YawEstimator", "LaneLearner", "configured_lanes"]


@dataclass(frozen=True)
class Lane:
    center_m: float
    width_m: float
    direction: int  # +1 away from the radar, -1 toward it

    @property
    def direction_name(self) -> str:
        return "away" if self.direction > 0 else "toward"


def configured_lanes(cfg) -> tuple[Lane, ...]:
    n = len(cfg.lane_centers_m)
    widths = cfg.lane_widths_m * n if len(cfg.lane_widths_m) == 1 else cfg.lane_widths_m
    dirs = cfg.lane_directions * n if len(cfg.lane_directions) == 1 else cfg.lane_directions
    return tuple(Lane(float(c), float(w), 1 if d == "away" else -1) for c, w, d in zip(cfg.lane_centers_m, widths, dirs))


def to_road(x: np.ndarray, y: np.ndarray, yaw_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Radar ground-plane coordinates -> road frame ``(u across, s along)``; also for velocities."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return x * c + y * s, -x * s + y * c


def assign_lanes(u: np.ndarray, lanes: tuple[Lane, ...]) -> np.ndarray:
    """Lane index per lateral offset ``u`` (N,), -1 outside every lane (nearest centre wins on overlaps)."""
    return assign_lanes_with_margin(u, lanes)[0]


def assign_lanes_with_margin(u: np.ndarray, lanes: tuple[Lane, ...]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`assign_lanes` and, per offset, its distance inside the nearest lane's nearer edge (m; negative
    outside every lane)."""
    if not lanes:
        return np.full(u.shape, -1, dtype=np.int32), np.full(u.shape, -np.inf)
    global _lane_arrays
    if _lane_arrays[0] is not lanes:  # the lanes (a tuple of frozen Lanes) change rarely: their arrays once
        _lane_arrays = (lanes, np.array([ln.center_m for ln in lanes]), 0.5 * np.array([ln.width_m for ln in lanes]))
    _, c, half_w = _lane_arrays
    d = np.abs(u[:, None] - c)
    k = d.argmin(axis=1)
    margin = half_w[k] - np.minimum.reduce(d, axis=1)  # the minimum is the distance at k (same value)
    k[~(margin >= 0.0)] = -1  # NaN too, as np.where(margin >= 0, k, -1)
    return k.astype(np.int32), margin


#: (lanes, their centres, their half widths) of the last call of :func:`assign_lanes_with_margin`
_lane_arrays: tuple = (None, None, None)


def align_yaw(x: np.ndarray, y: np.ndarray, heading: np.ndarray, lanes: tuple[Lane, ...], yaw0_rad: float,
              half_window_rad: float, min_points: int) -> tuple[float, float] | None:
    """The mounting yaw that puts the points ``(x, y)`` (m, the radar's ground plane) into configured lanes: within
    ``yaw0_rad`` +- ``half_window_rad``, the yaw minimising the squared distance of each point to the nearest centre of
    a lane of its direction of travel (``heading`` +1 away, -1 toward, 0 any), capped at that lane's half width
    squared (a point off every lane costs the same wherever it is). Returns ``(yaw, sigma)`` (rad), sigma being the
    points' rms distance inside their lanes over the root sum of their squared along-road distances; None when fewer
    than ``min_points`` points lie inside a lane at that yaw."""
    x, y, heading = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64), np.asarray(heading)
    c = np.array([ln.center_m for ln in lanes], dtype=np.float64)
    hw2 = (0.5 * np.array([ln.width_m for ln in lanes], dtype=np.float64)) ** 2
    allowed = (heading[:, None] == 0) | (heading[:, None] == np.array([ln.direction for ln in lanes])[None, :])
    keep = allowed.any(axis=1)
    x, y, allowed = x[keep], y[keep], allowed[keep]
    if x.size < min_points:
        return None
    # per lane: its centre, its half width squared (the cap) and per point 0, or inf where not of its direction
    per_lane = [(float(c[k]), float(hw2[k]), np.where(allowed[:, k], 0.0, np.inf)) for k in range(c.size)]

    def cost(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = np.multiply.outer(np.cos(g), x)
        u += np.multiply.outer(np.sin(g), y)  # (G, N) across the road
        best = np.full(u.shape, np.inf)
        d2 = np.empty_like(u)
        for ck, cap_k, off_k in per_lane:
            np.subtract(u, ck, out=d2)
            d2 *= d2
            np.minimum(d2, cap_k, out=d2)
            d2 += off_k
            np.minimum(best, d2, out=best)
        return best.sum(axis=1), best

    # grids whose neighbours move the farthest point by 0.5, 0.05 and 0.005 m, each about the best of the one before;
    # equal costs go to the yaw nearest the configured one
    step = 0.5 / max(float(np.abs(y).max()), 1.0)
    n = int(math.ceil(half_window_rad / step))
    offs = np.arange(-n, n + 1) * step
    for _ in range(3):
        tot, d2 = cost(yaw0_rad + offs)
        k = int(np.argmin(tot + 1e-9 * np.abs(offs)))
        best = offs[k]
        offs = best + np.arange(-10, 11) * (0.1 * step)
        step *= 0.1
    inside = d2[k] < np.where(allowed, hw2, np.inf).min(axis=1)  # under the cap of its nearest lane
    m = int(inside.sum())
    if m < min_points:
        return None
    yaw = yaw0_rad + float(best)
    s = -x[inside] * math.sin(yaw) + y[inside] * math.cos(yaw)  # along the road: d(across)/d(yaw)
    rms = math.sqrt(float(d2[k][inside].sum()) / max(m - 1, 1))
    return yaw, rms / max(math.sqrt(float(np.dot(s, s))), 1e-9)


#: up to this many running tracks the start-up votes are computed in plain Python
_SMALL = 24


class YawEstimator(native.KernelUser):
    """Mounting yaw from the directions of straight tracks (see the module docstring)."""

    def __init__(self, cfg, kernels: bool = True) -> None:
        """``kernels``: use the compiled kernel ``edge.native._traffic`` when it is built (False: the Python
        reference on a dict of sums)."""
        self.cfg = cfg
        self._sums: dict[int, list[float]] = {}  # track_id -> [n, sx, sy, sxx, syy, sxy, age]
        #: the kernel's table of the same sums, indexed by track id (edge.native._traffic): rows, running flags,
        #: insertion order
        self._k = native.load("_traffic") if kernels else None
        self._acc = np.zeros((0, 7))
        self._live = np.zeros(0, dtype=np.uint8)
        self._seq = np.zeros(0, dtype=np.int64)
        self._next_seq = 0
        self._n_live = 0
        self._votes: deque[float] = deque(maxlen=cfg.yaw_window_tracks)
        self._n_voted = 0  # votes ever cast (the median of the window changes only with a new one)
        self._median: tuple[int, float, float] | None = None  # (_n_voted, median of the window, its stderr)
        self._stderr: float | None = None  # standard error of the last estimate

    def _grow(self, cap: int) -> None:
        """Make the kernel's table hold track ids below ``cap``."""
        old = self._live.shape[0]
        cap = max(cap, 2 * old, 64)
        acc, live, seq = np.zeros((cap, 7)), np.zeros(cap, dtype=np.uint8), np.zeros(cap, dtype=np.int64)
        acc[:old], live[:old], seq[:old] = self._acc, self._live, self._seq
        self._acc, self._live, self._seq = acc, live, seq

    def add(self, ids: np.ndarray, age: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
        """Accumulate this frame's confirmed tracks; tracks that ended (or whose id was recycled) vote."""
        if self._k is not None:
            ids, age = np.asarray(ids, dtype=np.int64), np.asarray(age, dtype=np.int64)
            x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
            while (res := self._k.yaw_add(self._acc, self._live, self._seq, self._next_seq, ids, age, x, y)) is None:
                if int(ids.min()) < 0:
                    raise ValueError("track ids are >= 0")
                self._grow(int(ids.max()) + 1)  # an id beyond the table
            ended, self._next_seq = res
            for row in ended:
                self._vote(row)
            self._n_live = ids.size  # (the running tracks are this frame's: the others ended)
            return
        self.add_reference(ids, age, x, y)

    def add_table(self, kin: np.ndarray, x: np.ndarray | None = None) -> None:
        """:meth:`add` of the traffic monitor's table ``kin`` (n, 6) float64 (track id, age, x, y, vx, vy;
        ``edge.native._traffic.track_kin``); ``x``: the positions across the boresight to take instead of its x
        column."""
        if self._k is None:
            self.add(kin[:, 0].astype(np.int64), kin[:, 1].astype(np.int64), kin[:, 2] if x is None else x, kin[:, 3])
            return
        while (res := self._k.yaw_add_kin(self._acc, self._live, self._seq, self._next_seq, kin, x)) is None:
            ids = kin[:, 0]
            if float(ids.min()) < 0:
                raise ValueError("track ids are >= 0")
            self._grow(int(ids.max()) + 1)  # an id beyond the table
        ended, self._next_seq = res
        for row in ended:
            self._vote(row)
        self._n_live = kin.shape[0]

    def add_reference(self, ids: np.ndarray, age: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
        """:meth:`add` in Python on the dict of sums (the kernel's reference)."""
        seen = set()
        for i, a, xi, yi in zip(ids.tolist(), age.tolist(), x.tolist(), y.tolist()):
            acc = self._sums.get(i)
            if acc is not None and a < acc[6]:  # id recycled: the old track ended
                self._vote(acc)
                acc = None
            if acc is None:
                acc = self._sums[i] = [0.0] * 7
            acc[0] += 1.0
            acc[1] += xi
            acc[2] += yi
            acc[3] += xi * xi
            acc[4] += yi * yi
            acc[5] += xi * yi
            acc[6] = a
            seen.add(i)
        for i in [k for k in self._sums if k not in seen]:
            self._vote(self._sums.pop(i))

    def _vote(self, acc: list[float]) -> None:
        n = acc[0]
        if n < 3:
            return
        mx, my = acc[1] / n, acc[2] / n
        cxx = acc[3] / n - mx * mx
        cyy = acc[4] / n - my * my
        cxy = acc[5] / n - mx * my
        ev, evec = np.linalg.eigh(np.array([[cxx, cxy], [cxy, cyy]]))
        major_sd, minor_sd = math.sqrt(max(ev[1], 0.0)), math.sqrt(max(ev[0], 0.0))
        # a uniform run over length L has sd L / sqrt(12)
        if major_sd * math.sqrt(12.0) < self.cfg.yaw_min_track_length_m or minor_sd > self.cfg.yaw_max_lateral_sd_m:
            return
        ex, ey = evec[:, 1]
        if ey < 0:
            ex, ey = -ex, -ey
        self._votes.append(-math.atan2(ex, ey))  # road axis (-sin yaw, cos yaw)
        self._n_voted += 1

    @property
    def n_votes(self) -> int:
        return len(self._votes)

    def live_votes(self) -> np.ndarray:
        """Angles of :meth:`live_votes_weighted`."""
        return self.live_votes_weighted()[0]

    def live_votes_weighted(self) -> tuple[np.ndarray, np.ndarray]:
        """Votes of the tracks still running that already qualify (covered ``yaw_live_min_length_m``,
        straight so far): at start-up they give the estimate long before enough tracks have ended.
        Weights: the inverse variance of a line's angle fitted to ``n`` points spread ``sd_along`` along
        and ``sd_across`` across it, ``n sd_along^2 / sd_across^2`` (long, dense, straight tracks count most)."""
        if self._k is not None:
            if not self._n_live:
                return np.zeros(0), np.zeros(0)
            num, den, w = self._k.yaw_live_terms(self._acc, self._live, self._seq, self.cfg.yaw_live_min_length_m,
                                                 self.cfg.yaw_max_lateral_sd_m)
            return -(0.5 * np.arctan2(num, den)), w
        if not self._sums:
            return np.zeros(0), np.zeros(0)
        if len(self._sums) <= _SMALL:
            return self._live_votes_small()
        a = np.array(list(self._sums.values()), dtype=np.float64)
        n = np.maximum(a[:, 0], 1.0)
        mx, my = a[:, 1] / n, a[:, 2] / n
        cxx, cyy, cxy = a[:, 3] / n - mx * mx, a[:, 4] / n - my * my, a[:, 5] / n - mx * my
        # eigenvalues of the 2x2 scatter and the angle of its major axis from +y, in closed form
        half_tr, det = 0.5 * (cxx + cyy), cxx * cyy - cxy * cxy
        disc = np.sqrt(np.maximum(half_tr * half_tr - det, 0.0))
        major, minor = half_tr + disc, np.maximum(half_tr - disc, 0.0)
        ok = (a[:, 0] >= 3) & (np.sqrt(major * 12.0) >= self.cfg.yaw_live_min_length_m) & (
            np.sqrt(minor) <= self.cfg.yaw_max_lateral_sd_m)
        phi = 0.5 * np.arctan2(2.0 * cxy, cyy - cxx)  # major axis angle from +y towards +x
        w = a[:, 0] * major / np.maximum(minor, 0.01)
        return -phi[ok], w[ok]

    def _live_votes_small(self) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`live_votes_weighted` in plain Python floats, the same operations in the same order
        (a handful of running tracks: numpy's per-call overhead would dominate); the angles with one
        ``numpy.arctan2`` call, so the votes are bit-identical to the array path."""
        min_len, max_sd = self.cfg.yaw_live_min_length_m, self.cfg.yaw_max_lateral_sd_m
        sqrt = math.sqrt
        num: list[float] = []
        den: list[float] = []
        ws: list[float] = []
        for a0, a1, a2, a3, a4, a5, _ in self._sums.values():
            n = a0 if a0 > 1.0 else 1.0
            mx, my = a1 / n, a2 / n
            cxx, cyy, cxy = a3 / n - mx * mx, a4 / n - my * my, a5 / n - mx * my
            half_tr, det = 0.5 * (cxx + cyy), cxx * cyy - cxy * cxy
            disc = sqrt(max(half_tr * half_tr - det, 0.0))
            major, minor = half_tr + disc, max(half_tr - disc, 0.0)
            if a0 >= 3 and sqrt(max(major, 0.0) * 12.0) >= min_len and sqrt(minor) <= max_sd:
                num.append(2.0 * cxy)
                den.append(cyy - cxx)
                ws.append(a0 * major / max(minor, 0.01))
        phi = 0.5 * np.arctan2(np.array(num, dtype=np.float64), np.array(den, dtype=np.float64))
        return -phi, np.array(ws, dtype=np.float64)

    def estimate_rad(self) -> float | None:
        if len(self._votes) >= self.cfg.yaw_min_tracks:
            if self._median is None or self._median[0] != self._n_voted:
                v = np.fromiter(self._votes, dtype=float)
                self._median = (self._n_voted, float(np.median(v)), _median_stderr(v, None))
            self._stderr = self._median[2]
            return self._median[1]
        # start-up: the tracks that still run vote too; weighted median (ended tracks count as the best one)
        if self._k is not None:  # live_votes_weighted and weighted_median in one call
            code, a, b = self._k.yaw_startup(self._acc, self._live, self._seq, self._n_live, self._votes,
                                             self.cfg.yaw_live_min_length_m, self.cfg.yaw_max_lateral_sd_m,
                                             self.cfg.yaw_min_tracks, np.arctan2)
            if code == 1:
                self._stderr = b
                return a
            if code == 0:
                self._stderr = None
                return None
            return self._estimate_startup(list(self._votes), a, b)  # (more than 64 votes or a NaN: numpy)
        votes_l = list(self._votes)  # (Python floats)
        live, w = self.live_votes_weighted()
        if len(votes_l) + live.size < self.cfg.yaw_min_tracks:
            self._stderr = None
            return None
        return self._estimate_startup(votes_l, live, w)

    def _estimate_startup(self, votes_l: list[float], live: np.ndarray, w: np.ndarray) -> float:
        """The start-up estimate's weighted median of the ended tracks' votes ``votes_l`` and the running tracks'
        ``live`` with weights ``w`` (at least ``yaw_min_tracks`` votes)."""
        if self._k is not None and (res := self._k.weighted_median(self._votes, live, w)) is not None:
            self._stderr = res[1]
            return res[0]
        top = float(np.maximum.reduce(w)) if w.size else 1.0  # (w.max() without its wrapper)
        if len(votes_l) + live.size <= 64:  # a handful of tracks: the same weighted median in plain Python
            vals, wts = votes_l + live.tolist(), [top] * len(votes_l) + w.tolist()
            self._stderr = _median_stderr(np.array(vals), np.array(wts))
            pairs = sorted(zip(vals, wts), key=lambda p: p[0])
            cw = list(itertools.accumulate(p[1] for p in pairs))
            return pairs[bisect.bisect_left(cw, 0.5 * cw[-1])][0]
        votes = np.array(votes_l, dtype=float)
        allv = np.concatenate([votes, live])
        allw = np.concatenate([np.full(votes.size, top), w])
        self._stderr = _median_stderr(allv, allw)
        o = np.argsort(allv)
        cw = np.cumsum(allw[o])
        return float(allv[o][np.searchsorted(cw, 0.5 * cw[-1])])

    @property
    def stderr_rad(self) -> float | None:
        """Standard error of the last :meth:`estimate_rad` (None before the first estimate): the spread of
        the votes over the square root of their (effective) number, times 1.2533 for a median. It says
        how far off the yaw may still be -- a lateral uncertainty of ``range x stderr`` in the road frame."""
        return self._stderr


def _median_stderr(v: np.ndarray, w: np.ndarray | None) -> float:
    """Standard error of the (weighted) median of the votes ``v``: ``1.2533 sd / sqrt(n_eff)`` with the
    weighted sd and Kish's effective number ``(sum w)^2 / sum w^2`` (``n`` when unweighted); one vote
    gives no spread, so its error is taken as unknown (``inf``)."""
    n = v.size
    if n < 2:
        return math.inf
    if w is None:
        return 1.2533 * float(np.std(v, ddof=1)) / math.sqrt(n)
    add = np.add.reduce  # what ndarray.sum calls, without its wrapper (a handful of votes: the cost is per call)
    sw = float(add(w))
    if sw <= 0.0:
        return math.inf
    mean = float(add(w * v)) / sw
    n_eff = sw * sw / float(add(w * w))
    if n_eff <= 1.0:
        return math.inf
    d = v - mean
    var = float(add(w * (d * d))) / sw * n_eff / (n_eff - 1.0)  # numpy's x ** 2 is x * x
    return 1.2533 * math.sqrt(var / n_eff)


class LaneLearner:
    """Lanes from the lateral distribution of confirmed tracks (see the module docstring)."""

    def __init__(self, cfg) -> None:
        self.cfg = cfg
        n = cfg.learn_buffer_samples
        self._buf = np.zeros((n, 4), dtype=np.float32)  # x, y, vx, vy (radar frame)
        self._n = 0
        self._head = 0

    @property
    def n_samples(self) -> int:
        return self._n

    def add(self, x: np.ndarray, y: np.ndarray, vx: np.ndarray, vy: np.ndarray) -> None:
        rho = np.hypot(x, y)
        keep = (rho >= self.cfg.learn_min_range_m) & (rho <= self.cfg.learn_max_range_m)
        rows = np.stack([x[keep], y[keep], vx[keep], vy[keep]], axis=1).astype(np.float32)
        k = rows.shape[0]
        if k == 0:
            return
        cap = self._buf.shape[0]
        if k >= cap:
            rows, k = rows[-cap:], cap
        idx = (self._head + np.arange(k)) % cap
        self._buf[idx] = rows
        self._head = (self._head + k) % cap
        self._n = min(self._n + k, cap)

    def learn(self, yaw_rad: float) -> tuple[Lane, ...]:
        c = self.cfg
        if self._n < c.learn_min_samples:
            return ()
        d = self._buf[: self._n].astype(np.float64)
        u, _ = to_road(d[:, 0], d[:, 1], yaw_rad)
        _, vs = to_road(d[:, 2], d[:, 3], yaw_rad)
        ext = c.learn_lateral_extent_m
        edges = np.arange(-ext, ext + c.learn_bin_m, c.learn_bin_m)
        hist, _ = np.histogram(u, bins=edges)
        centres = 0.5 * (edges[:-1] + edges[1:])
        hist = hist.astype(np.float64)
        if c.learn_smooth_m > 0:
            half = int(math.ceil(3 * c.learn_smooth_m / c.learn_bin_m))
            k = np.exp(-0.5 * (np.arange(-half, half + 1) * c.learn_bin_m / c.learn_smooth_m) ** 2)
            hist = np.convolve(hist, k / k.sum(), mode="same")
        if hist.max() <= 0:
            return ()
        left = np.r_[-np.inf, hist[:-1]]
        right = np.r_[hist[1:], -np.inf]
        peaks = np.flatnonzero((hist > left) & (hist >= right) & (hist >= c.learn_peak_fraction * hist.max()))
        chosen: list[float] = []
        for i in peaks[np.argsort(-hist[peaks])]:  # strongest first; few peaks
            if all(abs(centres[i] - p) >= c.learn_min_separation_m for p in chosen):
                chosen.append(float(centres[i]))
        chosen.sort()
        refined = []
        for p in chosen:
            sel = np.abs(u - p) <= 0.5 * c.learn_min_separation_m
            refined.append(float(u[sel].mean()) if sel.any() else p)
        if len(refined) >= 2:
            width = float(np.median(np.diff(refined)))
        else:
            width = c.default_lane_width_m
        lanes = []
        for p in refined:
            sel = np.abs(u - p) <= 0.5 * width
            med = float(np.median(vs[sel])) if sel.any() else 1.0
            lanes.append(Lane(p, width, 1 if med >= 0 else -1))
        return tuple(lanes)
