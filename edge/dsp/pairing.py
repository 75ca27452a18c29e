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

from dataclasses import dataclass

import numpy as np

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
    """Index (into the unsorted list) and distance of the nearest peak to each ``f``."""
    if sorted_f.size == 0:
        return np.full(f.shape, -1), np.full(f.shape, np.inf)
    j = np.clip(np.searchsorted(sorted_f, f), 1, max(sorted_f.size - 1, 1))
    lo = np.clip(j - 1, 0, sorted_f.size - 1)
    hi = np.clip(j, 0, sorted_f.size - 1)
    d_lo = np.abs(f - sorted_f[lo])
    d_hi = np.abs(f - sorted_f[hi])
    pick = np.where(d_hi < d_lo, hi, lo)
    return order[pick], np.minimum(d_lo, d_hi)


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
) -> Pairs:
    """Pair the peaks of the four segments.

    ``freqs``: signed beat frequencies (Hz, float64) of the peaks of segments 0..3 (fast up, fast
    down, slow up, slow down). ``tolerance_hz``: allowed mismatch in the slow up / slow down segment.
    """
    f0, f1, f2, f3 = (np.asarray(f, dtype=np.float64) for f in freqs)
    a, b = model.a, model.b
    det = a[0] * b[1] - a[1] * b[0]
    # solve [a0 b0; a1 b1] [R; v] = [f0; f1] for every (up, down) combination
    F0, F1 = np.meshgrid(f0, f1, indexing="ij")  # (n0, n1)
    rng = (F0 * b[1] - F1 * b[0]) / det
    vel = (a[0] * F1 - a[1] * F0) / det
    ok = (rng >= min_range_m) & (rng <= max_range_m) & (np.abs(vel) <= max_speed_mps)
    i0, i1 = np.nonzero(ok)
    n_cand = int(i0.size)
    rng, vel = rng[i0, i1], vel[i0, i1]
    pred = model.predict(rng, vel)  # (n, 4)
    o2, o3 = np.argsort(f2), np.argsort(f3)
    j2, d2 = _nearest(f2[o2], o2, pred[:, 2])
    j3, d3 = _nearest(f3[o3], o3, pred[:, 3])
    conf = (d2 <= tolerance_hz[0]) & (d3 <= tolerance_hz[1])
    n_ghost = int(n_cand - conf.sum())
    i0, i1, j2, j3, vel = i0[conf], i1[conf], j2[conf], j3[conf], vel[conf]
    cost = (d2[conf] / tolerance_hz[0]) ** 2 + (d3[conf] / tolerance_hz[1]) ** 2
    # greedy, best slow agreement first (a handful of candidates): a candidate may share at most
    # ``max_shared`` of its four peaks with pairs already accepted (two vehicles whose beats coincide in
    # one segment are both kept; the cross-pairings of one vehicle's scatterers share two or more)
    # A candidate none of whose peaks any other candidate uses can neither be blocked nor block: accepted
    # up front; the loop runs over the rest only (same result as the plain greedy, a fraction of the work)
    cand = np.stack([i0, i1, j2, j3], axis=1)  # (n, 4)
    alone = np.ones(cand.shape[0], bool)
    for s, sz in enumerate((f0.size, f1.size, f2.size, f3.size)):
        alone &= np.bincount(cand[:, s], minlength=sz)[cand[:, s]] == 1
    used: list[set[int]] = [set(), set(), set(), set()]
    keep = np.flatnonzero(alone).tolist()
    rest = np.flatnonzero(~alone)
    for n, pk in zip(rest[np.argsort(cost[rest], kind="stable")].tolist(),
                     cand[rest[np.argsort(cost[rest], kind="stable")]].tolist()):
        if sum(k in u for u, k in zip(used, pk)) <= max_shared:
            for u, k in zip(used, pk):
                u.add(k)
            keep.append(n)
    keep = np.sort(np.asarray(keep, dtype=np.int64)) if keep else np.zeros(0, np.int64)
    keep = keep[np.argsort(cost[keep], kind="stable")]  # acceptance order, as the plain greedy
    if keep.size > 2 and max_shared > 0 and ghost_speed_mps > 0:
        # a wrong pairing on an extended vehicle (the up peak of one scatterer with the down peak of another,
        # confirmed by other scatterers' slow peaks) may be accepted first; once the true pairs of those
        # scatterers are in, it shares two or more of its peaks with them, and its speed is off theirs by
        # 0.8 m/s per metre between the scatterers, while the two true pairs agree with each other: drop
        # it (the true pair of a near vehicle whose smeared peaks give ghosts on both sides stays)
        pk = np.stack([i0[keep], i1[keep], j2[keep], j3[keep]], axis=1)  # (k, 4)
        share = (pk[:, None, :] == pk[None, :, :]).sum(axis=2)  # (k, k) peaks in common
        np.fill_diagonal(share, 0)
        vk = vel[keep]
        dv = np.abs(vk[:, None] - vk[None, :])
        m = ((share > 0) & (dv > ghost_speed_mps)).astype(np.int64)  # partners at another speed
        agree = (dv <= ghost_speed_mps).astype(np.int64)  # ... which agree with each other
        np.fill_diagonal(agree, 0)
        ghost = (share.sum(axis=1) > max_shared) & ((m @ agree) * m).any(axis=1)
        keep = keep[~ghost]
    idx = np.stack([i0[keep], i1[keep], j2[keep], j3[keep]], axis=1) if keep.size else np.zeros((0, 4), np.int64)
    if keep.size:
        fm = np.stack([f0[idx[:, 0]], f1[idx[:, 1]], f2[idx[:, 2]], f3[idx[:, 3]]], axis=1)  # (n, 4)
        A = np.stack([a, b], axis=1)  # (4, 2)
        sol, *_ = np.linalg.lstsq(A, fm.T, rcond=None)  # (2, n)
        res = np.sqrt(np.mean((A @ sol - fm.T) ** 2, axis=0))
        r_out, v_out = sol[0], sol[1]
    else:
        r_out = v_out = res = np.zeros(0)
    return Pairs(idx, r_out.astype(np.float32), v_out.astype(np.float32), res.astype(np.float32), n_cand, n_ghost)


def nearest_of_clusters(range_m: np.ndarray, v_mps: np.ndarray, x_m: np.ndarray, *, length_m: float,
                        speed_mps: float, lateral_m: float, ghost_speed_per_m: float = 0.0,
                        ghost_speed_mps: float = 0.0, ghost_length_m: float = 0.0) -> np.ndarray:
    """Keep mask ``(n,)``: drop a detection when another one lies at most ``length_m`` nearer in range,
    within ``speed_mps`` in radial speed and ``lateral_m`` across -- the same vehicle seen further
    along its body. An extended vehicle then yields its nearest face, the point that stays visible and
    that the tracker follows (several detections of one body would pull a track between its faces).
    ``ghost_speed_mps`` > 0 also drops wrong pairings among the body's scatterers: up to ``ghost_length_m``
    behind and ``ghost_speed_mps`` off in speed, but no more than ``ghost_speed_per_m`` per metre behind.
    """
    r = range_m[:, None] - range_m[None, :]  # r[i, j] > 0: j nearer than i
    dv = np.abs(v_mps[:, None] - v_mps[None, :])
    # a wrong pairing between two of the body's scatterers lies between them (within half the body behind
    # its near face), off their speed by ghost_speed_per_m / 2 per metre of their spacing
    tol = speed_mps
    if ghost_speed_mps > 0 and ghost_length_m > 0:
        tol = np.where(r <= ghost_length_m, np.maximum(speed_mps, np.minimum(ghost_speed_mps, ghost_speed_per_m * r)),
                       speed_mps)
    same = (r > 0) & (r <= length_m) & (dv <= tol) & (np.abs(x_m[:, None] - x_m[None, :]) <= lateral_m)
    return ~same.any(axis=1)
