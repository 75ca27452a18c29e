"""Beat-frequency pairing over Lim's four chirp segments (eqs. 5, 8, 13, 14; 9-10 with the typo fixed).

Signed beat frequencies as the complex FFT sees them (hal.waveform conventions: radial speed ``v``
positive receding, IF ``exp(+j 2 pi (S tau - f_D) t)``, ``f_D = -2 v / lambda``)::

    f_k = S_k * 2 R(t_k) / c + 2 v / lambda,      R(t_k) = R0 + v * t_k

with ``S_k`` the *signed* slope of segment ``k`` (down-chirps put targets at negative frequencies) and
``t_k`` the middle of segment ``k``'s sampling window measured from the frame start, so ``R0`` is the
range at the frame start (the time the ground truth refers to). Lim writes the same model per segment
with ``|S|`` and the sign of the Doppler term flipped for up and down chirps: eq. (9)
``R = (f1 + f2) c dT / (4 dB)`` and, with the typo of eq. (10) fixed (DESIGN §5),
``v = (f2 - f1) c / (4 fc)`` in his convention (approach positive); our ``v`` is its negative.

Pairing (vectorised over all candidate pairs):

1. every up peak of the fast up-chirp x every peak of the fast down-chirp gives ``(R0, v)`` by solving
   the two linear equations (the exact generalisation of eqs. 9-10 that includes the range change
   between the segments);
2. candidates outside the configured range and speed limits are dropped;
3. each candidate predicts where it must appear in the slow up and slow down segments (eqs. 13-14);
   it is confirmed only if a slow peak lies within ``tolerance_hz`` of both predictions -- a ghost
   (a wrong fast pairing) predicts slow beats where no target is;
4. confirmed candidates are accepted greedily by smallest slow mismatch; a candidate sharing more than
   ``max_shared`` of its four peaks with already accepted pairs is dropped (with 0, every peak is used
   once; with 1, two vehicles whose beats coincide in one segment both survive); an accepted pair that
   ends up sharing more than ``max_shared`` peaks with the pairs accepted after it is dropped too (a
   wrong pairing between two scatterers of one long truck, accepted before their true pairs, whose speed
   differs from theirs by more than ``ghost_speed_mps``);
5. ``(R0, v)`` is refined by least squares over the four measured frequencies.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from edge.fastinit import one_dict_init
from hal.waveform import SPEED_OF_LIGHT_MPS


@dataclass(frozen=True)
class PairingModel:
    """Per-segment coefficients of ``f_k = a_k R0 + b_k v`` (float64, 4 segments in frame order)."""

    a: np.ndarray  # (4,) Hz per metre
    b: np.ndarray  # (4,) Hz per m/s

    @classmethod
    def from_waveform(cls, waveform) -> "PairingModel":
        c = SPEED_OF_LIGHT_MPS
        lam = waveform.wavelength_m
        a, b = [], []
        for s in waveform.segments:
            t_mid = s.t_start_s + s.sample_offset_s + 0.5 * s.n_samples / s.sample_rate_hz
            a.append(2.0 * s.slope_hz_per_s / c)
            b.append(2.0 * s.slope_hz_per_s * t_mid / c + 2.0 / lam)
        return cls(np.array(a), np.array(b))

    def predict(self, range_m: np.ndarray, v_mps: np.ndarray) -> np.ndarray:
        """``(..., 4)`` beat frequencies of targets at ``range_m`` with radial speed ``v_mps``."""
        return range_m[..., None] * self.a + v_mps[..., None] * self.b

    @cached_property
    def coefficients(self) -> tuple[float, ...]:
        """``(a0, a1, a2, a3, b0, b1, b2, b3)`` as Python floats."""
        return tuple(self.a.tolist() + self.b.tolist())

    @cached_property
    def matrix_t(self) -> np.ndarray:
        """``(2, 4)``: ``[R0, v] @ matrix_t`` are the four beat frequencies."""
        return np.stack([self.a, self.b])

    @cached_property
    def pinv_t(self) -> np.ndarray:
        """``(4, 2)``: ``f @ pinv_t`` is the least-squares ``[R0, v]`` of four beat frequencies ``f``."""
        return np.ascontiguousarray(np.linalg.pinv(self.matrix_t.T).T)

    @staticmethod
    def offsets(sizes: tuple[int, int, int]) -> np.ndarray:
        """``(4,)`` start of each segment's peaks in the concatenation of the four lists."""
        s0, s1, s2 = sizes
        return np.array([0, s0, s0 + s1, s0 + s1 + s2])


@one_dict_init
@dataclass(frozen=True)
class Pairs:
    """Accepted pairings: indices into each segment's peak list and the refined range/speed."""

    peak_index: np.ndarray  # (n, 4) int: peak of segment k used by pair n
    range_m: np.ndarray  # (n,) float32, at the frame start
    radial_speed_mps: np.ndarray  # (n,) float32, positive receding
    residual_hz: np.ndarray  # (n,) float32, RMS of the 4-frequency least-squares fit
    n_candidates: int  # fast pairs inside the limits (for plots/diagnostics)
    n_ghosts: int  # candidates rejected by the slow segments


def _nearest(sorted_f: np.ndarray, order: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index (into the unsorted list) and distance of the nearest peak to each ``f`` (of two at the same
    distance, the lower frequency)."""
    n = sorted_f.size
    if n == 0:
        return np.full(f.shape, -1), np.full(f.shape, np.inf)
    if f.size * n <= _TABLE_MAX or n == 1:
        # a handful of peaks: one broadcast distance table beats a binary search and its clipping
        d = np.abs(np.subtract.outer(f, sorted_f))
        j = d.argmin(axis=1)  # the first minimum in frequency order: the lower of two equidistant peaks
        return order[j], np.minimum.reduce(d, axis=1)  # the minimum is d at j (the same value)
    # more: binary search between the two neighbours (the same pick: the lower one on a tie; a segment's peaks
    # are distinct local maxima, so the nearest is one of the two)
    j = np.searchsorted(sorted_f, f)
    np.clip(j, 1, n - 1, out=j)
    lo = j - 1
    d_lo = np.abs(f - sorted_f[lo])
    d_hi = np.abs(f - sorted_f[j])
    pick = np.where(d_hi < d_lo, j, lo)
    return order[pick], np.minimum(d_lo, d_hi)


#: largest distance table (candidates x peaks) of :func:`_nearest`; beyond, a binary search is cheaper
#: (measured: 2600 cells 18 us against 14 us, 600 cells 9 us against 14 us)
_TABLE_MAX = 2048

#: up to this many fast candidates (up x down peaks) and slow peaks per segment :func:`pair_beats` runs
#: in plain Python (measured on recorded highway4 calls: 16-36 candidates 45 us against 78 us with arrays, 64-100
#: candidates 86 against 83)
_SMALL_FAST = 64

#: candidates x slow-down peaks beyond which only the candidates confirmed by the slow up segment are searched in
#: the slow down one
_SUBSET_MIN = 512
_SMALL_SLOW = 16


def _no_pairs(n_cand: int, n_ghost: int) -> Pairs:
    e = np.zeros(0, np.float32)
    return Pairs(np.zeros((0, 4), np.int64), e, e, e, n_cand, n_ghost)


def pair_beats(
    freqs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    model: PairingModel,
    *,
    min_range_m: float,
    max_range_m: float,
    max_speed_mps: float,
    tolerance_hz: tuple[float, float],
    max_shared: int = 1,
    ghost_speed_mps: float = 1.5,
    near_tolerance_hz: tuple[float, float] | None = None,
    near_range_m: float = 0.0,
) -> Pairs:
    """Pair the peaks of the four segments.

    ``freqs``: signed beat frequencies (Hz, float64) of the peaks of segments 0..3 (fast up, fast
    down, slow up, slow down). ``tolerance_hz``: allowed mismatch in the slow up / slow down segment;
    ``near_tolerance_hz`` (if given) replaces it for candidates at most ``near_range_m`` away.
    """
    f0, f1, f2, f3 = (np.asarray(f, dtype=np.float64) for f in freqs)
    a0, a1, a2, a3, b0, b1, b2, b3 = model.coefficients
    det = a0 * b1 - a1 * b0
    if f0.size * f1.size <= _SMALL_FAST and f2.size <= _SMALL_SLOW and f3.size <= _SMALL_SLOW:
        # a handful of peaks: the candidates in plain Python floats (the same IEEE operations in the same
        # order as the array path below, so the same values; numpy's per-call cost would dominate)
        fl = (f0.tolist(), f1.tolist(), f2.tolist(), f3.tolist())
        n_cand, rows_c, vel_c, cost_c = _candidates_small(
            *fl, model.coefficients, det, min_range_m, max_range_m,
            max_speed_mps, tolerance_hz,
            near_tolerance_hz if near_tolerance_hz is not None and near_range_m > 0 else None, near_range_m)
        n_ghost = n_cand - len(rows_c)
        if not rows_c:
            return _no_pairs(n_cand, n_ghost)
        order_l = sorted(range(len(cost_c)), key=cost_c.__getitem__)  # stable, as argsort(kind="stable")
        return _accept(order_l, [rows_c[n] for n in order_l], vel_c, (f0, f1, f2, f3), model, max_shared,
                       ghost_speed_mps, n_cand, n_ghost, fl)
    # solve [a0 b0; a1 b1] [R; v] = [f0; f1] for every (up, down) combination
    rng = (f0[:, None] * b1 - f1[None, :] * b0) / det  # (n0, n1)
    vel = (a0 * f1[None, :] - a1 * f0[:, None]) / det
    ok = (rng >= min_range_m) & (rng <= max_range_m) & (np.abs(vel) <= max_speed_mps)
    flat = ok.reshape(-1).nonzero()[0]  # candidate n is up peak flat[n] // n1, down peak flat[n] % n1
    n_cand = int(flat.size)
    if n_cand == 0 or f2.size == 0 or f3.size == 0:  # nothing can be confirmed: all candidates are ghosts
        return _no_pairs(n_cand, n_cand)
    rng, vel = rng.reshape(-1)[flat], vel.reshape(-1)[flat]
    near = None
    if near_tolerance_hz is not None and near_range_m > 0:
        near = rng <= near_range_m
    # eqs. 13-14: where the slow segments must see it; a candidate must agree with both, so the slow down
    # segment is searched only for the candidates the slow up segment confirmed (most are ghosts)
    o2 = np.argsort(f2)
    j2, d2 = _nearest(f2[o2], o2, rng * a2 + vel * b2)
    tol2 = tolerance_hz[0] if near is None else np.where(near, near_tolerance_hz[0], tolerance_hz[0])
    c2 = d2 <= tol2
    if n_cand * f3.size > _SUBSET_MIN:  # a large table: subsetting costs less than the distances it saves
        s2 = c2.nonzero()[0]
        if s2.size == 0:
            return _no_pairs(n_cand, n_cand)
        rng, vel, flat, j2, d2 = rng[s2], vel[s2], flat[s2], j2[s2], d2[s2]
        if near is not None:
            near = near[s2]
        c2 = None
    o3 = np.argsort(f3)
    j3, d3 = _nearest(f3[o3], o3, rng * a3 + vel * b3)
    tol3 = tolerance_hz[1] if near is None else np.where(near, near_tolerance_hz[1], tolerance_hz[1])
    c3 = d3 <= tol3
    if c2 is not None:
        c3 &= c2
    conf = c3.nonzero()[0]
    n_conf = int(conf.size)
    n_ghost = n_cand - n_conf
    if n_conf == 0:
        return _no_pairs(n_cand, n_ghost)
    if n_conf < d3.size:
        vel, flat, j2, j3, d2, d3 = vel[conf], flat[conf], j2[conf], j3[conf], d2[conf], d3[conf]
    i0, i1 = np.divmod(flat, f1.size)
    cand = np.stack([i0, i1, j2, j3], axis=1)  # (n, 4)
    # normalised by the base tolerance everywhere: a near candidate's wider window does not make it rank better
    cost = (d2 / tolerance_hz[0]) ** 2 + (d3 / tolerance_hz[1]) ** 2
    # greedy, best slow agreement first (a handful of candidates): a candidate may share at most
    # ``max_shared`` of its four peaks with pairs already accepted (two vehicles whose beats coincide in
    # one segment are both kept; the cross-pairings of one vehicle's scatterers share two or more)
    order = np.argsort(cost, kind="stable")
    return _accept(order.tolist(), cand[order].tolist(), vel, (f0, f1, f2, f3), model, max_shared, ghost_speed_mps,
                   n_cand, n_ghost)


def _candidates_small(f0: list, f1: list, f2: list, f3: list, coef: tuple, det: float, min_range_m: float,
                      max_range_m: float, max_speed_mps: float, tolerance_hz: tuple, near_tolerance_hz,
                      near_range_m: float) -> tuple[int, list, list, list]:
    """The confirmed candidates of :func:`pair_beats` from Python lists: ``(n_candidates, rows [i0, i1, j2,
    j3], speeds, costs)`` in the array path's order (up peak, then down peak)."""
    a0, a1, a2, a3, b0, b1, b2, b3 = coef
    # each slow segment by frequency (of two equidistant peaks the lower one wins): the nearest peak to a
    # prediction is one of its two neighbours in that order (a binary search instead of a scan; the same pick,
    # as in :func:`_nearest`: a segment's peaks are distinct local maxima, so no third one is as near)
    s2 = sorted(zip(f2, range(len(f2))))
    s3 = sorted(zip(f3, range(len(f3))))
    g2, k2 = [fk for fk, _ in s2], [k for _, k in s2]
    g3, k3 = [fk for fk, _ in s3], [k for _, k in s3]
    n2, n3 = len(g2), len(g3)
    t2, t3 = tolerance_hz
    n_cand = 0
    rows, vels, costs = [], [], []
    for i0, x0 in enumerate(f0):
        x0b1, a1x0 = x0 * b1, a1 * x0
        for i1, x1 in enumerate(f1):
            r = (x0b1 - x1 * b0) / det
            v = (a0 * x1 - a1x0) / det
            if not (r >= min_range_m and r <= max_range_m and abs(v) <= max_speed_mps):
                continue
            n_cand += 1
            if near_tolerance_hz is not None and r <= near_range_m:
                tol2, tol3 = near_tolerance_hz
            else:
                tol2, tol3 = t2, t3
            if not n2:
                continue
            p = r * a2 + v * b2
            j = bisect_left(g2, p)
            if j == 0:
                d2, j2 = abs(p - g2[0]), k2[0]
            elif j == n2:
                d2, j2 = abs(p - g2[j - 1]), k2[j - 1]
            else:
                d2, d = abs(p - g2[j - 1]), abs(p - g2[j])
                j2 = k2[j - 1]
                if d < d2:
                    d2, j2 = d, k2[j]
            if not d2 <= tol2:
                continue
            if not n3:
                continue
            p = r * a3 + v * b3
            j = bisect_left(g3, p)
            if j == 0:
                d3, j3 = abs(p - g3[0]), k3[0]
            elif j == n3:
                d3, j3 = abs(p - g3[j - 1]), k3[j - 1]
            else:
                d3, d = abs(p - g3[j - 1]), abs(p - g3[j])
                j3 = k3[j - 1]
                if d < d3:
                    d3, j3 = d, k3[j]
            if not d3 <= tol3:
                continue
            rows.append([i0, i1, j2, j3])
            vels.append(v)
            e2, e3 = d2 / t2, d3 / t3
            costs.append(e2 * e2 + e3 * e3)  # numpy's x ** 2 is x * x
    return n_cand, rows, vels, costs


def _accept(order: list, cand_rows: list, vel, f: tuple, model: PairingModel, max_shared: int,
            ghost_speed_mps: float, n_cand: int, n_ghost: int, f_lists: tuple | None = None) -> Pairs:
    """Steps 4 and 5 of :func:`pair_beats`: ``order`` of the confirmed candidates (best first), their rows
    ``[i0, i1, j2, j3]`` in that order, the speeds ``vel`` of all candidates and the four segments' peak
    frequencies ``f`` (float64 arrays; ``f_lists``: the same as lists of floats, when at hand)."""
    u0: dict[int, int] = {}
    u1: dict[int, int] = {}
    u2: dict[int, int] = {}
    u3: dict[int, int] = {}
    keep: list[int] = []
    rows: list[list[int]] = []
    for n, (p0, p1, p2, p3) in zip(order, cand_rows):
        if (p0 in u0) + (p1 in u1) + (p2 in u2) + (p3 in u3) <= max_shared:
            u0[p0] = u0.get(p0, 0) + 1
            u1[p1] = u1.get(p1, 0) + 1
            u2[p2] = u2.get(p2, 0) + 1
            u3[p3] = u3.get(p3, 0) + 1
            keep.append(n)  # acceptance order
            rows.append([p0, p1, p2, p3])
    # peaks each accepted pair shares with the other accepted pairs
    shared = [u0[p0] + u1[p1] + u2[p2] + u3[p3] - 4 for p0, p1, p2, p3 in rows]
    if len(keep) > 2 and max_shared > 0 and ghost_speed_mps > 0 and max(shared) > max_shared:
        # a wrong pairing on an extended vehicle (the up peak of one scatterer with the down peak of another,
        # confirmed by other scatterers' slow peaks) may be accepted first; once the true pairs of those
        # scatterers are in, it shares two or more of its peaks with them, and its speed is off theirs by
        # 0.8 m/s per metre between the scatterers, while the two true pairs agree with each other: drop
        # it (the true pair of a near vehicle whose smeared peaks give ghosts on both sides stays)
        # (ufunc reductions and flat diagonal writes: the values of ndarray.sum/.any and np.fill_diagonal without
        # their wrappers, a few us a call at this size)
        k = len(rows)
        pk = np.array(rows, dtype=np.int64)  # (k, 4)
        share = np.add.reduce(pk[:, None, :] == pk[None, :, :], axis=2)  # (k, k) peaks in common
        share.reshape(-1)[::k + 1] = 0
        vk = np.asarray(vel, dtype=np.float64)[np.array(keep, dtype=np.int64)]
        dv = np.abs(vk[:, None] - vk[None, :])
        m = ((share > 0) & (dv > ghost_speed_mps)).astype(np.int64)  # partners at another speed
        agree = (dv <= ghost_speed_mps).astype(np.int64)  # ... which agree with each other
        agree.reshape(-1)[::k + 1] = 0
        ghost = (np.add.reduce(share, axis=1) > max_shared) & np.logical_or.reduce((m @ agree) * m, axis=1)
        rows = [r for r, g in zip(rows, ghost.tolist()) if not g]
    if not rows:
        return _no_pairs(n_cand, n_ghost)
    idx = np.array(rows, dtype=np.int64)
    if f_lists is not None:  # a handful of pairs: their four frequencies picked from the lists
        f0, f1, f2, f3 = f_lists
        fm = np.array([[f0[p0], f1[p1], f2[p2], f3[p3]] for p0, p1, p2, p3 in rows])  # (n, 4) float64
    else:  # more: one gather from the concatenated peak lists
        fm = np.concatenate(f)[idx + model.offsets((f[0].size, f[1].size, f[2].size))]
    return _refine(idx, fm, model, n_cand, n_ghost)


def refine_pairs(idx: np.ndarray, f: tuple, model: PairingModel, n_cand: int, n_ghost: int) -> Pairs:
    """Step 5 of :func:`pair_beats` for accepted pairs ``idx`` ``(n, 4)`` (peak index per segment) of the four
    segments' peak frequencies ``f`` (Hz, float64): range and speed by least squares over the four frequencies (used
    by the compiled pairing kernel, edge/native/_pairs.pyx, which does steps 1-4)."""
    if idx.shape[0] == 0:
        return _no_pairs(n_cand, n_ghost)
    fm = np.concatenate(f)[idx + model.offsets((f[0].size, f[1].size, f[2].size))]
    return _refine(idx, fm, model, n_cand, n_ghost)


def refine_rows(idx: np.ndarray, fm: np.ndarray, model: PairingModel, n_cand: int, n_ghost: int,
                kernel=None) -> Pairs:
    """:func:`refine_pairs` given the accepted pairs' frequencies ``fm`` (n, 4) float64 (segment k's peak
    ``idx[:, k]``), as the compiled pairing kernel returns them. With ``kernel`` (edge/native/_pairs.pyx; ``fm`` then a
    C-contiguous float64 array), the two BLAS products stay here and the kernel's ``refine_finish`` does the rest
    (:func:`_refine`'s values)."""
    if idx.shape[0] == 0:
        return _no_pairs(n_cand, n_ghost)
    if kernel is not None:
        sol = fm @ model.pinv_t
        r, v, res = kernel.refine_finish(fm, sol, sol @ model.matrix_t)
        return Pairs(idx, r, v, res, n_cand, n_ghost)
    return _refine(idx, fm, model, n_cand, n_ghost)


def _refine(idx: np.ndarray, fm: np.ndarray, model: PairingModel, n_cand: int, n_ghost: int) -> Pairs:
    sol = fm @ model.pinv_t  # (n, 2): the least-squares (R0, v) over the four frequencies
    res = np.sqrt(np.add.reduce((sol @ model.matrix_t - fm) ** 2, axis=1) / 4.0)  # RMS (np.mean)
    return Pairs(idx, sol[:, 0].astype(np.float32), sol[:, 1].astype(np.float32), res.astype(np.float32),
                 n_cand, n_ghost)


def nearest_of_clusters(range_m: np.ndarray, v_mps: np.ndarray, x_m: np.ndarray, *, length_m: float,
                        speed_mps: float, lateral_m: float,
                        with_extent: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Keep mask ``(n,)``: drop a detection when another one lies at most ``length_m`` nearer in range,
    within ``speed_mps`` in radial speed and ``lateral_m`` across -- the same vehicle seen further
    along its body. An extended vehicle then yields its nearest face, the point that stays visible and
    that the tracker follows (several detections of one body would pull a track between its faces).
    With ``with_extent`` also returns each detection's body extent ``(n,)`` (m, slant): the farthest detection
    the rule drops behind it, 0 where none (what :func:`body_extent` computes for the kept ones).
    """
    r = range_m[:, None] - range_m[None, :]  # r[i, j] > 0: j nearer than i
    dv = np.abs(v_mps[:, None] - v_mps[None, :])
    beside = np.abs(x_m[:, None] - x_m[None, :]) <= lateral_m
    same = (r > 0) & (r <= length_m) & beside & (dv <= speed_mps)  # same[i, j]: i is j's body
    keep = ~same.any(axis=1)
    if not with_extent:
        return keep
    return keep, (np.where(same, r, 0.0).max(axis=0) if r.size else np.zeros(range_m.size, range_m.dtype))


def body_extent(range_m: np.ndarray, v_mps: np.ndarray, x_m: np.ndarray, keep: np.ndarray, *, length_m: float,
                speed_mps: float, lateral_m: float) -> np.ndarray:
    """Range extent ``(n,)`` (m, slant) of each kept detection's body: the farthest detection at most ``length_m``
    behind it in range, within ``speed_mps`` in radial speed and ``lateral_m`` across (the rule by which
    :func:`nearest_of_clusters` drops it as the same vehicle's body); 0 where none, NaN for detections not kept.
    A vehicle's scatterers span its length, so over its passage the largest extents are its length. The reference
    for ``nearest_of_clusters(..., with_extent=True)``, which the pipeline uses (one pairwise pass for both)."""
    n = range_m.size
    out = np.full(n, np.nan, np.float32)
    k = keep.nonzero()[0]
    if not k.size:
        return out
    r = range_m[None, :] - range_m[k, None]  # (kept, all): > 0 behind the kept detection
    same = (r > 0) & (r <= length_m) & (np.abs(v_mps[None, :] - v_mps[k, None]) <= speed_mps) & (
        np.abs(x_m[None, :] - x_m[k, None]) <= lateral_m)
    out[k] = np.where(same, r, 0.0).max(axis=1) if n else 0.0
    return out
