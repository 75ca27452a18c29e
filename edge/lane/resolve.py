"""Two vehicles in one range-speed cell, resolved in angle over several frames (the lane profile's angles stage keeps
one :class:`CellResolver`: its memory of the cells lives across frames, which is why it is not in the stateless
:mod:`edge.dsp`).

Two vehicles side by side in adjacent lanes at the same range and speed give the same beat
frequency in all four chirp segments: one peak per segment, one pairing, and a Bartlett angle that
lands somewhere between them (a 4-element array with d = 1.5 lambda has a 9.6 deg Rayleigh width;
adjacent lanes are 1.7 deg apart at 120 m). Within a frame the two echoes are coherent (the same
relative phase in every segment), so one frame cannot separate them. From frame to frame, however,
their relative phase is random (each vehicle's glint decorrelates between 33 ms frames), so the
spatial covariance accumulated over a few frames,

    R = E[x x^H]  ~  p1 a(th1) a(th1)^H + p2 a(th2) a(th2)^H + s2 I,

has rank two and a two-source deterministic maximum-likelihood fit,
``max_{th1 < th2} tr(P_[a(th1) a(th2)] R)``, finds both angles (measured on ``side-by-side``: two cars
3.5 m apart resolved from about 100 m in, angles within a few tenths of a degree).

:class:`CellResolver` follows every detection from frame to frame in range and radial speed (a
nearest-neighbour "cell track": ``range + v T``, within a range and speed gate), keeps an
exponentially weighted covariance of its normalised snapshots (the four segments are four looks),
and splits a detection in two when its cell's covariance is surely rank two (second eigenvalue above
``min_eig_ratio`` of the first and well above the noise eigenvalues), the two fitted sources carry
comparable power (``min_power_ratio``), the cell moves (``min_speed_mps``), the two angles lie
at least ``min_lateral_m`` apart on the ground and all this held for ``min_split_frames`` frames in a row (more than the width of one vehicle, whose own
scatterers spread a little in angle). The covariance work is batched over detections and cells; the
association and each cell's counters are plain Python (a handful of cells: array calls would cost more).

A cell that is not split but whose second eigenvalue is above ``pair_hint_eig_ratio`` of the first (and
``min_noise_ratio`` above the noise) marks its detection in :attr:`CellResolver.two_sources`: two sources too close
in angle to be split yet (two cars side by side at 100-120 m: 0.026-0.05, while one point-like vehicle stays near
0.01), whose one Bartlett angle lies between them. The tracker's straight-line lateral filter does not average
such detections (``track.pdaf.lateral_smoother_hold_unresolved``).

A vehicle keeps its lateral position while its range changes, so its direction cosine ``x / R`` moves:
near the radar by degrees within the memory. With ``follow_direction`` every cell's covariance is steered
by that shift (``sin(az) (1 - R_new / R_old)``, a diagonal phase ramp over the elements) before a frame is
added; otherwise the memory of a receding car leaving the overpass holds its direction of half a second
earlier as a second source, and the fit splits the car into itself and a phantom 3 m further out.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from dataclasses import dataclass, field

import numpy as np

from edge import native


_NEIGHBOURS = np.array([-1, 0, 1])  # the fine search around the best coarse pair
_NO_AZ = np.zeros(0, np.float32)  # the kernel's azimuths when the memory is not steered


@dataclass(frozen=True)
class ResolverConfig:
    """Options of :class:`CellResolver` (filled from ``pipeline.lane``)."""

    range_gate_m: float = 2.0
    speed_gate_mps: float = 1.0
    memory_frames: float = 8.0
    min_frames: int = 6
    min_split_frames: int = 4
    max_misses: int = 6
    min_eig_ratio: float = 0.05
    min_noise_ratio: float = 8.0
    min_lateral_m: float = 2.5
    min_power_ratio: float = 0.1
    min_speed_mps: float = 1.0
    max_cells: int = 256
    follow_direction: bool = True
    pair_hint_eig_ratio: float = 0.02


@dataclass
class _Cells:
    """The cells: per-cell numbers as Python lists (a handful of cells; their bookkeeping one by one costs less
    than array calls), the covariances as one array (they are updated in batches)."""

    range_m: list = field(default_factory=list)  # float (float64), last range
    v_mps: list = field(default_factory=list)  # float, last radial speed
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4), np.complex64))
    n: list = field(default_factory=list)  # int, frames followed
    misses: list = field(default_factory=list)  # int, frames in a row without a detection
    streak: list = field(default_factory=list)  # int, frames in a row found split


def _cmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a * b`` for complex64 arrays of one shape with one rounding per real operation (numpy's complex product may
    fuse a multiply and an add, machine by machine): ``(ar br - ai bi, ar bi + ai br)``."""
    fa, fb = a.view(np.float32), b.view(np.float32)
    ar, ai, br, bi = fa[..., 0::2], fa[..., 1::2], fb[..., 0::2], fb[..., 1::2]
    out = np.empty_like(fa)
    out[..., 0::2] = ar * br - ai * bi
    out[..., 1::2] = ar * bi + ai * br
    return out.view(np.complex64)


class CellResolver(native.KernelUser):
    """Per-cell covariance memory and the two-source split (see the module docstring)."""

    def __init__(self, cfg: ResolverConfig, steering: np.ndarray, grid_rad: np.ndarray, frame_period_s: float,
                 spacing_wavelengths: float, kernel=None) -> None:
        """``steering`` (grid, rx) over ``grid_rad``; ``spacing_wavelengths``: the array's element spacing d / lambda
        (the phase ramp of :meth:`_steer_memory`). ``kernel``: the compiled step (edge/native/_resolve.pyx, from
        ``edge.native.load("_resolve")``), None: the numpy reference (:meth:`reference_step`) runs."""
        self.cfg = cfg
        self.kernel = kernel
        self.period_s = frame_period_s
        self._min_speed32 = float(np.float32(cfg.min_speed_mps))  # compared with float32 speeds, as array code does
        self.grid = grid_rad
        n_rx = steering.shape[1]
        self.n_rx = n_rx
        # projection matrices of every angle pair on the grid (i < j), flattened for one matrix product
        i, j = np.triu_indices(grid_rad.size, 1)
        b = np.stack([steering[i], steering[j]], axis=2).astype(np.complex128)  # (P, rx, 2)
        bh = b.conj().transpose(0, 2, 1)
        proj = b @ np.linalg.inv(bh @ b) @ bh  # (P, rx, rx)
        self._pair_i, self._pair_j = i, j
        self._pair_ij = np.stack([i, j], axis=1)  # (P, 2): both grid indices of a pair in one gather
        self._pair_th = grid_rad[self._pair_ij]  # (P, 2) their angles
        sin_th = np.sin(self._pair_th)
        self._pair_dsin = np.abs(sin_th[:, 1] - sin_th[:, 0])  # (P,) the spread of their direction cosines
        # tr(P R) for Hermitian P and R as a real dot product of their upper triangles:
        # sum_k P_kk R_kk + 2 sum_{k<l} (Re P_kl Re R_kl + Im P_kl Im R_kl)
        self._iu = np.triu_indices(n_rx, 1)
        # the features of a complex64 covariance as columns of its (k, 2 rx^2) float view: Re of the diagonal, then
        # Re and Im of the upper triangle, weighted 1 and 2 (:meth:`_features`)
        diag = np.arange(n_rx) * (n_rx + 1)
        upper = self._iu[0] * n_rx + self._iu[1]
        self._feat_cols = np.concatenate([2 * diag, 2 * upper, 2 * upper + 1])
        self._feat_w = np.concatenate([np.ones(n_rx), np.full(2 * upper.size, 2.0)]).astype(np.float32)
        self._pair_feat = self._features(proj, scale_offdiag=1.0)  # (P, n_rx^2) float32
        self._pinv = (np.linalg.inv(bh @ b) @ bh).astype(np.complex64)  # (P, 2, rx): source amplitudes
        n_grid = grid_rad.size
        self._pair_index = np.full((n_grid, n_grid), -1, np.int64)
        self._pair_index[i, j] = np.arange(i.size)
        # coarse search on every other grid angle, then the 3 x 3 fine neighbours of the best coarse pair
        self._coarse = np.flatnonzero((i % 2 == 0) & (j % 2 == 0))
        # their features gathered once, not every frame;
        # used as the same transposed view as before (BLAS picks its kernel by the layout)
        self._coarse_feat = self._pair_feat[self._coarse]
        self._coarse_feat64 = self._coarse_feat.astype(np.float64)
        self._pair_feat64 = self._pair_feat.astype(np.float64)
        # the fine search's 3 x 3 neighbour pairs (i + di, j + dj, clipped to the grid) of every coarse pair, the
        # coarse pair itself where a neighbour is not a pair (i >= j): (n_coarse, 9) pair rows
        top = n_grid - 1
        ci, cj = i[self._coarse], j[self._coarse]
        fi = np.minimum(np.maximum(ci[:, None, None] + _NEIGHBOURS[None, :, None], 0), top)  # (c, 3, 1)
        fj = np.minimum(np.maximum(cj[:, None, None] + _NEIGHBOURS[None, None, :], 0), top)  # (c, 1, 3)
        rows = self._pair_index[fi, fj].reshape(self._coarse.size, -1)  # -1 where i >= j
        self._fine_rows = np.where(rows >= 0, rows, self._coarse[:, None])
        self._d_over_lam = float(spacing_wavelengths)
        m = np.arange(n_rx)  # the element lag a - b of every covariance entry, as an index into the lags
        self._lags = np.arange(-(n_rx - 1), n_rx).astype(np.float32)  # (2 rx - 1,)
        self._lag_index = (m[:, None] - m[None, :]) + (n_rx - 1)  # (rx, rx)
        # the kernel's tables (float32 views of the complex ones)
        self._k_pair_th = np.ascontiguousarray(self._pair_th, np.float32)
        self._k_pair_dsin = np.ascontiguousarray(self._pair_dsin, np.float32)
        self._k_pinv = np.ascontiguousarray(self._pinv).view(np.float32)  # (P, 2, 2 rx)
        self._k_fine_rows = np.ascontiguousarray(self._fine_rows, np.int64)
        self._k_coarse_t = np.ascontiguousarray(self._coarse_feat64.T)  # (rx^2, coarse pairs)
        self._k_phase = float(np.float32(-2.0 * np.pi * self._d_over_lam))
        self.reset()

    def reset(self) -> None:
        self.cells = _Cells(cov=np.zeros((0, self.n_rx, self.n_rx), np.complex64))
        if self.kernel is not None:  # the kernel's table: arrays
            self.cells = _Cells(np.zeros(0), np.zeros(0), self.cells.cov, *(np.zeros(0, np.int64) for _ in range(3)))
        self.two_sources = np.zeros(0, bool)

    def step(self, range_m: np.ndarray, v_mps: np.ndarray, snapshots: np.ndarray,
             az_rad: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Update the cells with this frame's detections; return ``(split (n,) bool, angles (n, 2) rad)``.

        ``snapshots``: complex64 ``(n, n_looks, n_rx)`` (calibrated; a look of zeros is left out). ``angles``
        is NaN where not split. ``az_rad`` (n,): the detections' angles; with ``follow_direction`` a cell's
        memory is steered along with its vehicle's direction (see :meth:`_steer_memory`). The compiled kernel
        when built (one call), else :meth:`reference_step`.
        """
        if self.kernel is None:
            return self.reference_step(range_m, v_mps, snapshots, az_rad)
        cfg = self.cfg
        c = self.cells
        follow = cfg.follow_direction and az_rad is not None
        n = range_m.shape[0]
        out = self.kernel.step(  # (float32 and complex64 C-contiguous arrays; the kernel converts others)
            c.range_m, c.v_mps, c.cov, c.n, c.misses, c.streak, range_m, v_mps, snapshots, az_rad if follow else _NO_AZ,
            follow, self.period_s, cfg.range_gate_m, cfg.speed_gate_mps, cfg.memory_frames, cfg.min_frames,
            cfg.min_split_frames, cfg.max_misses, cfg.min_eig_ratio, cfg.min_noise_ratio, cfg.pair_hint_eig_ratio,
            cfg.min_lateral_m, cfg.min_power_ratio, self._min_speed32, cfg.max_cells, self._k_phase,
            self._k_coarse_t, self._k_fine_rows, self._pair_feat, self._k_pair_th, self._k_pair_dsin, self._k_pinv)
        self.cells = _Cells(out[3], out[4], out[5], out[6], out[7], out[8])
        self.two_sources = out[2].view(bool)
        return out[0].view(bool), out[1]

    def reference_step(self, range_m: np.ndarray, v_mps: np.ndarray, snapshots: np.ndarray,
                       az_rad: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`step` in numpy and plain Python (the kernel's reference and fallback)."""
        cfg = self.cfg
        c = self.cells
        n_det = range_m.size
        angles = np.full((n_det, 2), np.nan, np.float32)
        split = np.zeros(n_det, bool)
        self.two_sources = two_sources = np.zeros(n_det, bool)
        # association: predicted cell range against detections, nearest first, one-to-one
        match = self._associate(range_m, v_mps) if len(c.range_m) and n_det else [-1] * n_det
        r_new, norm = self._outer(snapshots)
        # the detections that followed a cell and their cells (distinct: one-to-one)
        hi_l = [d for d, m in enumerate(match) if m >= 0]
        k_l = [match[d] for d in hi_l]
        if hi_l:
            hi, k = np.array(hi_l), np.array(k_l)
            rh, vh = range_m[hi], v_mps[hi]
            cov = c.cov[k]  # gathered once, updated, written back once
            if cfg.follow_direction and az_rad is not None:
                cov = _cmul(cov, self._steer_memory(rh, np.array([c.range_m[j] for j in k_l]), az_rad[hi]))
            # the weight of this frame: max(1 / n, 1 / memory) in float64, rounded to float32 (as astype)
            a_l = []
            for j in k_l:
                c.n[j] += 1
                a_l.append(max(1.0 / c.n[j], 1.0 / cfg.memory_frames))
            a = np.array(a_l, dtype=np.float32)
            cf = cov.view(np.float32)  # (real weights: the same rounding as the complex form)
            cf += a[:, None, None] * (r_new[hi].view(np.float32) - cf)
            c.cov[k] = cov
            ready_pos = []  # positions in hi_l of the cells followed long enough, moving
            for p, (j, r, v) in enumerate(zip(k_l, rh.tolist(), vh.tolist())):
                c.range_m[j], c.v_mps[j], c.misses[j] = r, v, 0
                if c.n[j] >= cfg.min_frames and abs(v) >= self._min_speed32:
                    ready_pos.append(p)
            now_l = [False] * len(hi_l)
            if ready_pos:
                sel = np.array(ready_pos)
                ready = hi[sel]
                split_idx, ang, two = self._split(cov[sel], range_m[ready])
                two_sources[ready] = two
                if split_idx.size:
                    angles[ready[split_idx]] = ang
                    for p in sel[split_idx].tolist():
                        now_l[p] = True
            # a cell split in a few frames in a row only (a passing vehicle's echo in one look is brief)
            for p, j in enumerate(k_l):
                c.streak[j] = c.streak[j] + 1 if now_l[p] else 0
            if any(now_l):  # (otherwise nothing is split and the angles stay NaN)
                split[hi] = [f and c.streak[j] >= cfg.min_split_frames for f, j in zip(now_l, k_l)]
                angles[~split] = np.nan
        # age, drop, create
        seen = set(k_l)
        misses = c.misses
        for j in range(len(misses)):
            if j not in seen:
                misses[j] += 1
        keep = [j for j, m in enumerate(misses) if m <= cfg.max_misses]
        new = [d for d, m in enumerate(match) if m < 0]
        if not new and len(keep) == len(misses):
            return split, angles  # every detection followed a cell, no cell dropped: the table is updated in place
        n_new = len(new)
        self.cells = _Cells(
            range_m=[c.range_m[j] for j in keep] + range_m[new].astype(np.float64).tolist(),
            v_mps=[c.v_mps[j] for j in keep] + v_mps[new].astype(np.float64).tolist(),
            cov=np.concatenate([c.cov[keep], r_new[new]]),
            n=[c.n[j] for j in keep] + [1] * n_new,
            misses=[misses[j] for j in keep] + [0] * n_new,
            streak=[c.streak[j] for j in keep] + [0] * n_new,
        )
        if len(self.cells.range_m) > cfg.max_cells:  # keep the most recently seen (a stable sort, as argsort's)
            cc = self.cells
            o = sorted(range(len(cc.misses)), key=cc.misses.__getitem__)[: cfg.max_cells]
            self.cells = _Cells([cc.range_m[j] for j in o], [cc.v_mps[j] for j in o], cc.cov[o],
                                [cc.n[j] for j in o], [cc.misses[j] for j in o], [cc.streak[j] for j in o])
        return split, angles

    def _outer(self, snapshots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(r_new (n, rx, rx) complex64, norm (n, looks, 1) float32)``: each look normalised to unit length (an
        all-zero look left out), the outer products ``x x^H`` averaged over the looks. Written on the float32 parts
        with one rounding per operation (no fused multiply-add), so that compiled code gives the same bits on
        every machine: ``|x|^2`` summed over the elements in order, ``x = s * (1 / |s|)``, the products summed over
        the looks in order, times ``1 / looks``."""
        n, n_looks_all, n_rx = snapshots.shape
        s = np.ascontiguousarray(snapshots, np.complex64).view(np.float32).reshape(n, n_looks_all, n_rx, 2)
        sr, si = s[..., 0], s[..., 1]
        p = sr * sr + si * si  # (n, looks, rx)
        acc = p[:, :, 0].copy()
        for a in range(1, n_rx):
            acc += p[:, :, a]
        norm = np.sqrt(acc)[:, :, None]
        inv = np.float32(1.0) / np.maximum(norm, np.float32(1e-30))
        xr, xi = sr * inv, si * inv
        re = xr[:, :, :, None] * xr[:, :, None, :] + xi[:, :, :, None] * xi[:, :, None, :]  # (n, looks, rx, rx)
        im = xi[:, :, :, None] * xr[:, :, None, :] - xr[:, :, :, None] * xi[:, :, None, :]
        r = np.empty((n, n_rx, n_rx, 2), np.float32)
        r[..., 0] = re[:, 0]
        r[..., 1] = im[:, 0]
        for k in range(1, n_looks_all):
            r[..., 0] += re[:, k]
            r[..., 1] += im[:, k]
        n_looks = np.maximum(np.add.reduce(norm[:, :, 0] > 0, axis=1), 1).astype(np.float32)  # all-zero looks out
        r *= (np.float32(1.0) / n_looks)[:, None, None, None]
        return r.view(np.complex64)[..., 0], norm

    def _associate(self, range_m: np.ndarray, v_mps: np.ndarray) -> list[int]:
        """The cell of each detection (-1: none): pairs inside the range and speed gates (the cell's range
        predicted with its speed), cheapest first (``|dr| / range gate + |dv| / speed gate``; ties in detection,
        then cell order), one-to-one. Plain Python floats (float64, the same operations as array code): a
        handful of detections and cells, and only the cells within the range gate's window of each detection
        (a binary search over the predicted ranges) are looked at."""
        cfg = self.cfg
        c = self.cells
        rg, sg = cfg.range_gate_m, cfg.speed_gate_mps
        period = self.period_s
        cv = c.v_mps
        pr = [r + v * period for r, v in zip(c.range_m, cv)]  # (r + v T, as array code computes it)
        by_range = sorted(range(len(pr)), key=pr.__getitem__)
        pr_sorted = [pr[k] for k in by_range]
        ordered = math.isfinite(sum(pr))  # (a NaN would leave the order undefined: then every cell is looked at)
        cand = []
        for d, (r, v) in enumerate(zip(range_m.tolist(), v_mps.tolist())):
            # a window twice the gate (rounding cannot move a cell across it), then the gate itself
            window = (by_range[bisect_left(pr_sorted, r - 2.0 * rg):bisect_right(pr_sorted, r + 2.0 * rg)]
                      if ordered else by_range)
            for k in window:
                dr, dv = abs(r - pr[k]), abs(v - cv[k])
                if dr <= rg and dv <= sg:
                    cand.append((dr / rg + dv / sg, d, k))
        match = [-1] * range_m.size
        if cand:
            cand.sort()
            taken_c = set()
            for _, d, k in cand:
                if match[d] < 0 and k not in taken_c:
                    taken_c.add(k)
                    match[d] = k
        return match

    def _steer_memory(self, range_m: np.ndarray, old_range_m: np.ndarray, az_rad: np.ndarray) -> np.ndarray:
        """``(k, rx, rx)`` complex64 factors that steer the memory of cells last seen at ``old_range_m`` to their
        vehicles' new direction before this frame's looks are added (multiplied into their covariances).

        A vehicle keeps its lateral position while its range changes, so its direction cosine along the array
        ``sin(az) = x / R`` scales with ``R_old / R_new``: near the radar it sweeps quickly (a receding car in
        lane 2: 0.12 at 15 m, 0.054 at 33 m). A memory that averages looks taken at those directions holds the
        vehicle's earlier direction as a second source: the two-source fit found one at the vehicle and a phantom
        at its direction of half a second earlier, 3 m further out at the present range (highway4-traffic seed
        57: a track in lane 3 beside a receding car of lane 2, counted there). The shift ``sin(az) (1 - R_new /
        R_old)`` is applied as the diagonal steering ``R_ab <- R_ab exp(-j 2 pi d/lambda (a - b) shift)`` that
        moves every source of the memory by it (two vehicles side by side shift alike to within their
        separation times the relative range change). The phase depends on the element lag ``a - b`` only: it is
        evaluated for the ``2 rx - 1`` lags and gathered into the ``rx x rx`` layout (the same values)."""
        shift = np.sin(az_rad.astype(np.float64)) * (1.0 - range_m / np.maximum(old_range_m, 1e-3))
        ph = (-2.0 * np.pi * self._d_over_lam) * shift.astype(np.float32)[:, None] * self._lags  # (k, 2 rx - 1)
        ph = ph.astype(np.float64)  # cos and sin in float64 (the C library's), rounded to float32
        f = np.empty(ph.shape + (2,), np.float32)
        f[..., 0] = np.cos(ph)
        f[..., 1] = np.sin(ph)
        return f.view(np.complex64)[..., 0].take(self._lag_index, axis=1)  # (k, rx, rx)

    def _features(self, m: np.ndarray, scale_offdiag: float) -> np.ndarray:
        """``(k, rx, rx)`` Hermitian -> ``(k, rx^2)`` float32: diagonal, then Re and Im of the upper triangle."""
        if m.dtype == np.complex64 and scale_offdiag == 2.0:
            # one gather of the diagonal and the upper triangle as float pairs, one product with the column
            # weights (1 on the diagonal, 2 off it: exact), the same values as the general form below
            return m.reshape(m.shape[0], -1).view(np.float32).take(self._feat_cols, axis=1) * self._feat_w
        d = np.real(np.diagonal(m, axis1=1, axis2=2))
        u = m[:, self._iu[0], self._iu[1]]
        return np.concatenate([d, scale_offdiag * u.real, scale_offdiag * u.imag], axis=1).astype(np.float32)

    def _split(self, cov: np.ndarray, range_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Which of the covariances ``(k, rx, rx)`` hold two resolved vehicles, and their angles; and which hold two
        sources, resolved or not (``pair_hint_eig_ratio``, :attr:`CellResolver.two_sources`)."""
        cfg = self.cfg
        w = np.linalg.eigvalsh(cov.astype(np.complex128))  # ascending, in float64 (decisions away from rounding)
        noise = np.maximum(np.add.reduce(w[:, : self.n_rx - 2], axis=1) / (self.n_rx - 2), 1e-12)  # np.mean
        above_noise = w[:, -2] >= cfg.min_noise_ratio * noise
        hint = above_noise & (w[:, -2] >= cfg.pair_hint_eig_ratio * w[:, -1])
        two = (w[:, -2] >= cfg.min_eig_ratio * w[:, -1]) & above_noise
        idx = two.nonzero()[0]
        if idx.size == 0:
            return idx, np.zeros((0, 2), np.float32), hint
        cov = cov[idx]
        fr = self._features(cov, scale_offdiag=2.0)  # (k, 16)
        fr = fr.astype(np.float64)  # products of float32 numbers are exact in float64: sums differ by 1e-16 at most
        best_coarse = np.argmax(fr @ self._coarse_feat64.T, axis=1)  # (k,) positions in the coarse list
        rows = self._fine_rows[best_coarse]  # (k, 9): the neighbours of the best coarse pair
        fine = np.einsum("kf,kpf->kp", fr, self._pair_feat64[rows])
        best = rows[np.arange(idx.size), np.argmax(fine, axis=1)]
        th = self._pair_th[best]  # (k, 2)
        lateral = range_m[idx] * self._pair_dsin[best]  # |sin th_j - sin th_i| x range
        # powers of the two fitted sources, diag(B+ R B+^H): a vehicle with a brief visitor in one of its
        # looks (another vehicle's beat in one segment) has a strong and a faint source, not two vehicles
        bp = self._pinv[best].astype(np.complex128)  # (k, 2, rx)
        pw = np.einsum("kar,krs,kas->ka", bp, cov.astype(np.complex128), bp.conj()).real
        ratio = np.minimum.reduce(pw, axis=1) / np.maximum(np.maximum.reduce(pw, axis=1), 1e-30)  # min / max
        ok = (lateral >= cfg.min_lateral_m) & (ratio >= cfg.min_power_ratio)
        return idx[ok], th[ok].astype(np.float32), hint
