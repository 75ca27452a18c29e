"""DBSCAN on the wrapped range-Doppler map (Tavanti §II-C), exact and vectorised for a Raspberry Pi.

The points to cluster are the bins of one map at or above ``th_RD``, placed on the cylinder of
eq. (6): ``[v', v'', r]`` with ``v``, ``v'`` in km/h and ``r`` in metres, Euclidean 3-D metric, radius
``eps`` and ``M`` minimum points (the point itself included, as in scikit-learn). Because the points
sit on a regular (range bin, Doppler bin) lattice whose Doppler axis is a circle, the distance
between two bins depends only on their offsets ``(di, dj)``::

    d^2 = (di * dr)^2 + (2 R sin(pi dj / N_D))^2,   R = v_max / pi

so the whole algorithm runs on arrays, with no per-point Python and no callback metric:

1. **Neighbour counts** (core points): one circular (Doppler) / linear (range) convolution of the
   threshold mask with the 0/1 kernel ``d <= eps``, by real FFT over the rows that hold points
   (kernel spectra cached per padded length).
2. **Core connectivity**: core bins that are 8-neighbours on the lattice are always within ``eps``
   (``eps`` is many bins wide), so ``scipy.ndimage.label`` groups them first. Two such groups belong
   to the same cluster iff some pair of their points is within ``eps``; the closest pair of two groups
   is always on their boundaries (a step towards the other group from an interior bin stays in the
   group and gets closer), so only boundary core bins (plus the Doppler seam columns, which the
   lattice labelling does not join) are compared: group pairs whose bounding boxes come within
   ``eps`` are tested with a KD-tree nearest-neighbour query (``scipy.spatial.cKDTree``) and joined
   by union-find over groups (a loop over groups, never over points).
3. **Border points**: a non-core point joins the cluster of its nearest core point if that point is
   within ``eps`` (the nearest core point is again a boundary bin: one KD-tree query); equally near
   core points of two clusters give the smaller cluster id.

Cluster ids follow the order of each cluster's first core point in row-major order. The compiled
kernel ``edge/native/_dbscan.pyx`` does the same in one call per map (:meth:`CylinderDbscan.fit`);
:meth:`CylinderDbscan.reference` is this numpy code, which the tests compare it against.

Optionally (``min_samples_far``, ``far_range_m``) the core-point threshold is lower from a range on
(a range-dependent ``M``; beyond the paper). With one ``M`` everywhere, the result equals
scikit-learn's ``DBSCAN(eps, min_samples=M)`` on the same 3-D points up to label permutation (border points within ``eps`` of two clusters may go to either; scikit-learn picks by
visiting order, this module by distance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.ndimage
import scipy.spatial

from edge import native

_EPS_TOL = 1e-9  # relative slack so that distances equal to eps count as neighbours (<= eps)


@dataclass(frozen=True, eq=False)
class Clusters:
    """DBSCAN result for one map, per thresholded point in row-major (range, Doppler) order."""

    range_bin: np.ndarray  # (N,) int
    doppler_bin: np.ndarray  # (N,) int
    labels: np.ndarray  # (N,) int32, -1 = noise, clusters 0..n_clusters-1
    core: np.ndarray  # (N,) bool
    n_clusters: int
    neighbour_counts: np.ndarray  # (N,) int32, points within eps (itself included)

    def __len__(self) -> int:
        return int(self.labels.size)


class CylinderDbscan(native.KernelUser):
    """DBSCAN with radius ``eps`` and ``min_samples`` on the wrapped lattice of a range-Doppler map.

    ``n_range`` x ``n_doppler`` bins, ``range_bin_m`` metres per range bin, cylinder radius
    ``radius_kmh = v_max / pi``; Doppler bin ``j`` sits at angle ``2 pi j / n_doppler``.
    """

    def __init__(
        self, n_range: int, n_doppler: int, range_bin_m: float, radius_kmh: float, eps: float, min_samples: int,
        min_samples_far: int | None = None, far_range_m: float = math.inf,
    ) -> None:
        if eps <= 0 or min_samples < 1 or (min_samples_far is not None and min_samples_far < 1):
            raise ValueError("DBSCAN needs eps > 0 and min_samples >= 1")
        self.n_range = int(n_range)
        self.n_doppler = int(n_doppler)
        self.range_bin_m = float(range_bin_m)
        self.radius_kmh = float(radius_kmh)
        self.eps = float(eps)
        self.min_samples = int(min_samples)
        # core-point threshold per range row: min_samples, or min_samples_far from far_range_m on (a weak
        # far target covers fewer cells above th_RD: its echo falls as r^-2 while its Doppler spread does not)
        self.min_samples_far = self.min_samples if min_samples_far is None else int(min_samples_far)
        self.far_range_m = float(far_range_m)
        rows_m = np.arange(self.n_range) * self.range_bin_m
        self._m_row = np.where(rows_m >= self.far_range_m, self.min_samples_far, self.min_samples).astype(np.int32)
        self._r = self.eps * (1.0 + _EPS_TOL)
        h = min(int(math.floor(self._r / self.range_bin_m)), self.n_range - 1)
        self._h = h
        di = np.arange(-h, h + 1) * self.range_bin_m
        dj = np.arange(self.n_doppler)
        chord = 2.0 * self.radius_kmh * np.sin(np.pi * dj / self.n_doppler)
        kern = (di[:, None] ** 2 + chord[None, :] ** 2) <= self._r**2  # (2h+1, n_doppler), offsets mod N_D
        self._kern = kern
        self.kernel_size = int(kern.sum())
        self._kf_cache: dict[int, np.ndarray] = {}
        th = 2.0 * np.pi * np.arange(self.n_doppler) / self.n_doppler
        self._cos = self.radius_kmh * np.cos(th)
        self._sin = self.radius_kmh * np.sin(th)
        self._struct = np.ones((3, 3), dtype=bool)
        # the kernel row of range offset di as a circular Doppler interval [-lo, hi] (chord grows with |dj|)
        self._lo, self._hi = _row_intervals(kern)
        #: the compiled kernel (edge/native/_dbscan.pyx), None: the numpy reference runs
        # the kernel joins 8-neighbour core bins across the Doppler seam too: only right when they are within eps
        eight = self._lo is not None and h >= 1 and bool(np.all(kern[:, [0, 1, -1]][h - 1 : h + 2]))
        self.kernel = native.load("_dbscan") if eight else None

    def coordinates(self, range_bin: np.ndarray, doppler_bin: np.ndarray) -> np.ndarray:
        """``(N, 3)`` float64 cylinder coordinates ``[v', v'', r]`` of lattice points."""
        return np.stack(
            [self._cos[doppler_bin], self._sin[doppler_bin], np.asarray(range_bin) * self.range_bin_m], axis=1
        )

    def _kernel_spectrum(self, lp: int) -> np.ndarray:
        kf = self._kf_cache.get(lp)
        if kf is None:
            h = self._h
            k = np.zeros((lp, self.n_doppler), dtype=np.float32)
            k[np.arange(-h, h + 1) % lp] = self._kern
            kf = self._kf_cache[lp] = scipy.fft.rfft2(k, workers=1)
        return kf

    def neighbour_counts(self, mask: np.ndarray) -> np.ndarray:
        """Points of ``mask`` within ``eps`` of every bin (itself included): int32 ``(n_range, n_doppler)``.

        Only the range rows from the first to the last row with points are transformed (zero-padded by
        ``h`` rows, the kernel's half height, so the circular convolution does not wrap); rows outside
        hold no point and their counts are not needed. Kernel spectra are cached per padded length.
        """
        rows = np.flatnonzero(mask.any(axis=1))
        out = np.zeros(mask.shape, dtype=np.int32)
        if rows.size == 0:
            return out
        r0, r1 = int(rows[0]), int(rows[-1]) + 1
        lp = scipy.fft.next_fast_len(r1 - r0 + self._h + 1, real=True)
        mf = scipy.fft.rfft2(mask[r0:r1].astype(np.float32), s=(lp, self.n_doppler), workers=1)
        c = scipy.fft.irfft2(mf * self._kernel_spectrum(lp), s=(lp, self.n_doppler), workers=1)[: r1 - r0]
        out[r0:r1] = np.rint(c)
        return out

    def fit(self, mask: np.ndarray) -> Clusters:
        """Cluster the ``True`` bins of ``mask`` (``(n_range, n_doppler)`` bool): the compiled kernel when built,
        else :meth:`reference`."""
        if self.kernel is None:
            return self.reference(mask)
        if mask.shape != (self.n_range, self.n_doppler):
            raise ValueError(f"mask shape {mask.shape} != {(self.n_range, self.n_doppler)}")
        ri, dj, labels, core, n_clu, counts = self.kernel.fit(
            np.ascontiguousarray(mask).view(np.uint8), np.count_nonzero(mask), self._m_row, self._lo, self._hi,
            self._cos, self._sin, self.range_bin_m)
        return Clusters(ri, dj, labels, core, int(n_clu), counts)

    def reference(self, mask: np.ndarray) -> Clusters:
        """The numpy implementation of :meth:`fit` (see the module docstring)."""
        if mask.shape != (self.n_range, self.n_doppler):
            raise ValueError(f"mask shape {mask.shape} != {(self.n_range, self.n_doppler)}")
        ri, dj = np.nonzero(mask)
        n = ri.size
        labels = np.full(n, -1, dtype=np.int32)
        if n == 0:
            z = np.zeros(0, dtype=np.int32)
            return Clusters(ri, dj, labels, np.zeros(0, dtype=bool), 0, z)
        counts_grid = self.neighbour_counts(mask)
        counts = counts_grid[ri, dj]
        core_grid = mask & (counts_grid >= self._m_row[:, None])
        core = core_grid[ri, dj]
        if not core.any():
            return Clusters(ri, dj, labels, core, 0, counts)
        lab_grid, n_lab = scipy.ndimage.label(core_grid, structure=self._struct)
        # boundary core bins: some 8-neighbour (Doppler wrapping) is not core; plus the seam columns
        # interior = all 8 neighbours core (Doppler wraps, range edges count as core): a 3x3 erosion
        # as two separable 3-wide ANDs on shifted views (8x faster than ndimage.binary_erosion here)
        padded = np.concatenate([core_grid[:, -1:], core_grid, core_grid[:, :1]], axis=1)
        padded = np.pad(padded, ((1, 1), (0, 0)), constant_values=True)
        rows3 = padded[:, :-2] & padded[:, 1:-1] & padded[:, 2:]
        interior = rows3[:-2] & rows3[1:-1] & rows3[2:]
        bnd = core_grid & ~interior
        bnd[:, 0] |= core_grid[:, 0]
        bnd[:, -1] |= core_grid[:, -1]
        bi, bj = np.nonzero(bnd)
        b_lab = lab_grid[bi, bj] - 1
        b_xyz = self.coordinates(bi, bj)
        tree = scipy.spatial.cKDTree(b_xyz)
        comp = self._merge_groups(b_xyz, b_lab, n_lab) if n_lab > 1 else np.zeros(1, dtype=np.int32)
        n_clu = int(comp.max()) + 1
        labels[core] = comp[lab_grid[ri[core], dj[core]] - 1]
        # border points: nearest core point within eps (squared distance summed as ((x^2 + y^2) + z^2), so the kernel
        # rounds alike), equally near ones -> the smallest cluster id; the tree's k nearest hold every tie
        nc = ~core
        if nc.any():
            q = self.coordinates(ri[nc], dj[nc])
            k = min(8, len(b_xyz))
            _, idx = tree.query(q, k=k, distance_upper_bound=self._r)
            idx = idx.reshape(len(q), k)
            ok = idx < len(b_xyz)
            safe = np.where(ok, idx, 0)
            t = q[:, None, :] - b_xyz[safe]
            d2 = np.where(ok, (t[..., 0] * t[..., 0] + t[..., 1] * t[..., 1]) + t[..., 2] * t[..., 2], np.inf)
            lab_k = np.where(ok, comp[b_lab[safe]], np.iinfo(np.int32).max)
            best = np.where(d2 == d2.min(axis=1, keepdims=True), lab_k, np.iinfo(np.int32).max).min(axis=1)
            labels[nc] = np.where(ok.any(axis=1), best, -1).astype(np.int32)
        return Clusters(ri, dj, labels, core, int(n_clu), counts)

    def _merge_groups(self, xyz: np.ndarray, lab: np.ndarray, n_lab: int) -> np.ndarray:
        """Join lattice-connected core groups that come within eps of each other -> dense cluster ids.

        ``xyz``/``lab``: boundary core points and their group (0..n_lab-1). Candidate group pairs are
        those whose 3-D bounding boxes, grown by eps, overlap (one vectorised test); for each, the
        smaller group's boundary points query a KD-tree of the larger one's (nearest neighbour within
        eps). The loop runs over group pairs (a handful of targets and sidelobe islands), never points.
        """
        order = np.argsort(lab, kind="stable")
        xyz, lab = xyz[order], lab[order]
        starts = np.searchsorted(lab, np.arange(n_lab + 1))
        lo = np.minimum.reduceat(xyz, starts[:-1], axis=0)
        hi = np.maximum.reduceat(xyz, starts[:-1], axis=0)
        gap = np.maximum(0.0, np.maximum(lo[:, None, :] - hi[None, :, :], lo[None, :, :] - hi[:, None, :]))
        near = np.einsum("ijk,ijk->ij", gap, gap) <= self._r**2
        ia, ib = np.nonzero(np.triu(near, 1))
        parent = np.arange(n_lab)

        def find(x: int) -> int:
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        trees: dict[int, scipy.spatial.cKDTree] = {}
        for a, b in zip(ia.tolist(), ib.tolist()):
            ra, rb = find(a), find(b)
            if ra == rb:
                continue
            na, nb = starts[a + 1] - starts[a], starts[b + 1] - starts[b]
            small, big = (a, b) if na <= nb else (b, a)
            t = trees.get(big)
            if t is None:
                t = trees[big] = scipy.spatial.cKDTree(xyz[starts[big] : starts[big + 1]])
            d, _ = t.query(xyz[starts[small] : starts[small + 1]], k=1, distance_upper_bound=self._r)
            if np.isfinite(d).any():
                parent[max(ra, rb)] = min(ra, rb)
        roots = np.array([find(i) for i in range(n_lab)])
        _, dense = np.unique(roots, return_inverse=True)
        return dense.astype(np.int32)


def _row_intervals(kern: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Each row of a neighbourhood kernel ``(2h+1, n_doppler)`` (offsets mod n_doppler) as a circular interval
    ``[-lo, hi]`` of Doppler offsets: int32 ``(lo, hi)``, or ``(None, None)`` when a row is not such an interval (the
    kernel then cannot run). A full row gives ``lo + hi + 1 >= n_doppler``."""
    nd = kern.shape[1]
    lo = np.zeros(kern.shape[0], dtype=np.int32)
    hi = np.zeros(kern.shape[0], dtype=np.int32)
    for k, row in enumerate(kern):
        if row.all():
            lo[k], hi[k] = 0, nd - 1
            continue
        if not row[0]:
            return None, None
        hi[k] = int(np.argmin(row)) - 1  # offsets 0..hi
        lo[k] = int(np.argmin(row[::-1][: nd - 1]) if not row[::-1][: nd - 1].all() else nd - 1)
        want = np.zeros(nd, dtype=bool)
        want[np.arange(-lo[k], hi[k] + 1) % nd] = True
        if not np.array_equal(want, row):
            return None, None
    return lo, hi


def centroids(points: np.ndarray, labels: np.ndarray, n_clusters: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-cluster centroid of cylinder points, projected back on the cylinder.

    ``points`` ``(N, 3)`` ``[v', v'', r]``; returns ``(n_clusters, 3)`` float32 centroids (the mean's polar
    angle at ``radius``, mean range) and ``(n_clusters,)`` int32 point counts.
    """
    keep = labels >= 0
    lab = labels[keep]
    cnt = np.bincount(lab, minlength=n_clusters).astype(np.int32)
    out = np.zeros((n_clusters, 3), dtype=np.float32)
    if n_clusters == 0:
        return out, cnt
    sums = np.stack([np.bincount(lab, weights=points[keep, k], minlength=n_clusters) for k in range(3)], axis=1)
    mean = sums / np.maximum(cnt, 1)[:, None]
    ang = np.arctan2(mean[:, 1], mean[:, 0])
    out[:, 0] = radius * np.cos(ang)
    out[:, 1] = radius * np.sin(ang)
    out[:, 2] = mean[:, 2]
    return out, cnt
