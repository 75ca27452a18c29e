"""The lane profile's fast paths against the plain implementations they replace (same results)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from hw_sim import SIMO_BOARD

from edge.dsp.angle import bartlett_consensus, steering_matrix
from edge.lane.resolve import CellResolver, ResolverConfig, _cmul
from edge.dsp.pairing import Pairs, PairingModel, pair_beats
from edge.dsp.cfar import circular_pad, os_cfar, os_cfar_at, os_cfar_at_padded, reference_index


@pytest.mark.parametrize("n_train,n_guard,rank", [(16, 2, 24), (4, 0, 3), (8, 1, 16), (3, 5, 1)])
def test_os_cfar_at_padded_equals_os_cfar(n_train, n_guard, rank):
    rng = np.random.default_rng(7)
    power = rng.gamma(4.0, size=(4, 256)).astype(np.float32)
    power[1, 40:60] *= 100.0  # an extended target
    power[2, :5] = 0.0  # exact zeros sort like any other value
    ref = reference_index(256, n_train, n_guard)
    _, _, full = os_cfar(power, ref, rank, 3.0)
    rows, cols = np.nonzero(rng.random(power.shape) < 0.3)
    rows = np.concatenate([rows, [0, 3, 3]])
    cols = np.concatenate([cols, [0, 255, 1]])  # both ends (circular windows)
    noise, cells = os_cfar_at_padded(circular_pad(power, n_train + n_guard), rows, cols, n_train, n_guard, rank)
    assert noise.dtype == np.float32 and cells.dtype == np.float32
    np.testing.assert_array_equal(noise, full[rows, cols])
    np.testing.assert_array_equal(noise, os_cfar_at(power, rows, cols, ref, rank))
    np.testing.assert_array_equal(cells, np.stack([power[rows, (cols + o) % 256] for o in (-1, 0, 1)], axis=1))
    empty = os_cfar_at_padded(circular_pad(power, n_train + n_guard), rows[:0], cols[:0], n_train, n_guard, rank)
    assert empty[0].shape == (0,) and empty[1].shape == (0, 3)


# --- pairing: the plain implementation it replaced (binary-search nearest peak, np.linalg.lstsq) -----------

def _nearest_reference(sorted_f: np.ndarray, order: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def pair_beats_reference(
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
    j2, d2 = _nearest_reference(f2[o2], o2, pred[:, 2])
    j3, d3 = _nearest_reference(f3[o3], o3, pred[:, 3])
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




MODEL = PairingModel.from_waveform(SIMO_BOARD.frontend.waveform)


def _scene_peaks(seed: int) -> tuple[np.ndarray, ...]:
    """Peaks of a busy frame: vehicles of several scatterers (ghost pairings between them), beats that
    coincide in one segment, jitter and noise peaks."""
    rng = np.random.default_rng(seed)
    n_veh = rng.integers(1, 12)
    r0 = rng.uniform(10.0, 320.0, n_veh)
    v0 = rng.choice([-1.0, 1.0], n_veh) * rng.uniform(5.0, 40.0, n_veh)
    r = np.concatenate([r0 + off for off in (0.0, 2.5, 6.0)][: rng.integers(1, 4)])
    v = np.resize(v0, r.size)
    if n_veh > 2:  # a second vehicle at the first one's beat in segment 0
        r = np.append(r, r0[0] + 3.0)
        v = np.append(v, (MODEL.predict(np.array([r0[0]]), np.array([v0[0]]))[0, 0] - MODEL.a[0] * r[-1]) / MODEL.b[0])
    f = MODEL.predict(r, v) + rng.normal(0.0, 15.0, (r.size, 4))
    out = []
    for k in range(4):
        noise = rng.uniform(-4e5, 4e5, rng.integers(0, 8))
        fk = np.concatenate([f[:, k], noise])
        out.append(fk[rng.permutation(fk.size)])
    return tuple(out)


@pytest.mark.parametrize("max_shared", [0, 1, 2])
def test_pair_beats_equals_the_plain_implementation(max_shared):
    kw = dict(min_range_m=5.0, max_range_m=330.0, max_speed_mps=70.0, tolerance_hz=(520.0, 520.0),
              max_shared=max_shared)
    n_pairs = n_ghost_dropped = 0
    for seed in range(300):
        freqs = _scene_peaks(seed)
        new, old = pair_beats(freqs, MODEL, **kw), pair_beats_reference(freqs, MODEL, **kw)
        assert isinstance(new, Pairs)
        np.testing.assert_array_equal(new.peak_index, old.peak_index)
        assert (new.n_candidates, new.n_ghosts) == (old.n_candidates, old.n_ghosts)
        np.testing.assert_allclose(new.range_m, old.range_m, rtol=0, atol=1e-4)
        np.testing.assert_allclose(new.radial_speed_mps, old.radial_speed_mps, rtol=0, atol=1e-5)
        np.testing.assert_allclose(new.residual_hz, old.residual_hz, rtol=1e-4, atol=1e-3)
        for a in (new.range_m, new.radial_speed_mps, new.residual_hz):
            assert a.dtype == np.float32
        n_pairs += new.range_m.size
        no_ghost = pair_beats_reference(freqs, MODEL, **kw, ghost_speed_mps=0.0)
        n_ghost_dropped += no_ghost.range_m.size - old.range_m.size
    assert n_pairs > 500
    if max_shared > 0:
        assert n_ghost_dropped > 0  # the extended-vehicle ghost rule was exercised


@pytest.mark.parametrize("near", [False, True])
def test_pair_beats_plain_python_path_is_bit_identical_to_the_array_path(monkeypatch, near):
    import edge.dsp.pairing as pairing

    kw = dict(min_range_m=5.0, max_range_m=330.0, max_speed_mps=70.0, tolerance_hz=(520.0, 520.0), max_shared=1)
    if near:  # the wider window near the radar (lane profile: 1.5 bins up to 40 m)
        kw.update(near_tolerance_hz=(780.0, 780.0), near_range_m=120.0)
    n_small = n_pairs = 0
    for seed in range(300):
        freqs = _scene_peaks(seed)
        monkeypatch.setattr(pairing, "_SMALL_FAST", 10**9)
        monkeypatch.setattr(pairing, "_SMALL_SLOW", 10**9)
        small = pair_beats(freqs, MODEL, **kw)
        monkeypatch.setattr(pairing, "_SMALL_FAST", -1)
        arrays = pair_beats(freqs, MODEL, **kw)
        for f in ("peak_index", "range_m", "radial_speed_mps", "residual_hz"):
            a, b = getattr(small, f), getattr(arrays, f)
            assert a.dtype == b.dtype and a.shape == b.shape
            np.testing.assert_array_equal(a, b)  # bit for bit, not within a tolerance
        assert (small.n_candidates, small.n_ghosts) == (arrays.n_candidates, arrays.n_ghosts)
        n_small += freqs[0].size * freqs[1].size <= 64
        n_pairs += small.range_m.size
    assert n_small > 50 and n_pairs > 300


def test_nearest_peak_small_and_dense_paths_agree():
    from edge.dsp.pairing import _nearest

    rng = np.random.default_rng(2)
    peaks = np.round(rng.uniform(-1e5, 1e5, 200))
    peaks[5] = peaks[6] + 100.0
    o = np.argsort(peaks)
    tie = peaks[6] + 50.0  # exactly between two peaks: the lower one
    for n_queries in (3, 500):  # 3 x 200 distances take the table, 500 x 200 the binary search
        f = np.concatenate([np.round(rng.uniform(-1.2e5, 1.2e5, n_queries - 1)), [tie]])
        j, d = _nearest(peaks[o], o, f)
        np.testing.assert_array_equal(d, np.abs(f[:, None] - peaks[None, :]).min(axis=1))
        np.testing.assert_array_equal(np.abs(f - peaks[j]), d)
        assert j[-1] == 6


# --- angle: the plain Bartlett consensus it replaced (np.median, np.errstate, copies) ----------------------

def bartlett_consensus_reference(snapshots: np.ndarray, steering: np.ndarray, grid_rad: np.ndarray,
                       outlier_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bartlett with per-snapshot normalisation and outlier rejection.

    In a busy scene one segment's peak bin can also hold another vehicle (the beats of two vehicles
    coincide in one segment only, because the four slopes map range and speed differently). Each
    snapshot's spectrum is normalised to unit power so every segment votes equally; snapshots whose own
    maximum lies more than ``outlier_rad`` from the median of the per-snapshot maxima are dropped, and
    the rest are summed and refined as in :func:`bartlett`.

    Returns ``(az_rad (n_det,), spectrum (n_det, n_grid), kept (n_det, n_snap) bool)``.
    """
    n_det, n_snap, _ = snapshots.shape
    if n_det == 0:
        return np.zeros(0, np.float32), np.zeros((0, grid_rad.size), np.float32), np.zeros((0, n_snap), bool)
    y = snapshots @ steering.conj().T  # (n_det, n_snap, n_grid)
    p = (y.real * y.real + y.imag * y.imag).astype(np.float32)
    p /= np.maximum(p.max(axis=2, keepdims=True), np.float32(1e-30))
    each = grid_rad[np.argmax(p, axis=2)]  # (n_det, n_snap)
    med = np.median(each, axis=1, keepdims=True)
    kept = np.abs(each - med) <= outlier_rad
    spec = (p * kept[..., None]).sum(axis=1)
    k = np.argmax(spec, axis=1)
    kk = np.clip(k, 1, grid_rad.size - 2)
    rows = np.arange(n_det)
    pm, p0, pp = spec[rows, kk - 1], spec[rows, kk], spec[rows, kk + 1]
    den = pm - 2.0 * p0 + pp
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where((den < 0) & (k == kk), 0.5 * (pm - pp) / den, 0.0)
    step = grid_rad[1] - grid_rad[0]
    az = np.where(k == kk, grid_rad[kk] + np.clip(d, -0.5, 0.5) * step, grid_rad[k])
    return az.astype(np.float32), spec.astype(np.float32), kept


@pytest.mark.parametrize("n_snap", [4, 3, 1])
def test_bartlett_consensus_equals_the_plain_implementation(n_snap):
    rng = np.random.default_rng(11)
    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    steer = steering_matrix(4, 0.0186, 0.01244, grid)
    n = 400
    az = rng.uniform(-0.4, 0.4, (n, 1))
    a = np.exp(-2j * np.pi * np.arange(4)[None, :] * 1.5 * np.sin(az))  # (n, rx)
    x = a[:, None, :] * rng.normal(1.0, 0.3, (n, n_snap, 1)) + 0.3 * (
        rng.normal(size=(n, n_snap, 4)) + 1j * rng.normal(size=(n, n_snap, 4)))
    x[: n // 4, 0] = np.exp(-2j * np.pi * np.arange(4) * 1.5 * np.sin(0.3))  # another vehicle in one look
    x[-3:, :] = 0.0  # all-zero looks
    x = x.astype(np.complex64)
    new, old = bartlett_consensus(x, steer, grid, np.radians(2.0)), bartlett_consensus_reference(x, steer, grid, np.radians(2.0))
    np.testing.assert_array_equal(new[2], old[2])
    np.testing.assert_array_equal(new[3], old[2])  # without peak bins every agreeing look is used
    np.testing.assert_array_equal(new[0], old[0])
    np.testing.assert_array_equal(new[1], old[1])
    assert new[0].dtype == np.float32 and new[1].dtype == np.float32
    assert old[2].any() and ((~old[2]).any() or n_snap < 3)


def test_bartlett_consensus_scalar_refinement_equals_the_plain_implementation():
    """A handful of detections (<= angle._SMALL) are refined one by one with NumPy scalars: the same values, at the
    edges too (angles beyond +-19 deg), and with a float64 grid."""
    from edge.dsp import angle

    rng = np.random.default_rng(12)
    grid32 = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    for grid in (grid32, grid32.astype(np.float64)):
        steer = steering_matrix(4, 0.0186, 0.01244, grid)
        n = 300
        az = rng.uniform(-0.45, 0.45, (n, 1))
        a = np.exp(-2j * np.pi * np.arange(4)[None, :] * 1.5 * np.sin(az))
        x = (a[:, None, :] * rng.normal(1.0, 0.3, (n, 4, 1)) + 0.3 * (
            rng.normal(size=(n, 4, 4)) + 1j * rng.normal(size=(n, 4, 4)))).astype(np.complex64)
        x[-2:] = 0.0
        start, n_small = 0, 0
        for size in itertools.cycle(range(1, angle._SMALL + 1)):
            if start >= n:
                break
            xs = x[start:start + size]
            start += size
            new, old = bartlett_consensus(xs, steer, grid, np.radians(2.0)), bartlett_consensus_reference(
                xs, steer, grid, np.radians(2.0))
            n_small += xs.shape[0] if xs.shape[0] <= angle._SMALL else 0
            np.testing.assert_array_equal(new[0], old[0])
            np.testing.assert_array_equal(new[1], old[1])
            np.testing.assert_array_equal(new[2], old[2])
            assert new[0].dtype == np.float32
        assert n_small == n


# --- resolve: the two-source test as it was (np.mean) --------------------------------------------------------

def split_reference(self, cov: np.ndarray, range_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which of the covariances ``(k, rx, rx)`` hold two resolved vehicles, and their angles."""
    cfg = self.cfg
    w = np.linalg.eigvalsh(cov.astype(np.complex128))  # ascending (float64, as CellResolver since kernel _resolve)
    noise = np.maximum(w[:, : self.n_rx - 2].mean(axis=1), 1e-12)
    two = (w[:, -2] >= cfg.min_eig_ratio * w[:, -1]) & (w[:, -2] >= cfg.min_noise_ratio * noise)
    idx = np.flatnonzero(two)
    if idx.size == 0:
        return idx, np.zeros((0, 2), np.float32)
    fr = self._features(cov[idx], scale_offdiag=2.0).astype(np.float64)  # (k, 16)
    pf = self._pair_feat.astype(np.float64)
    coarse = self._coarse[np.argmax(fr @ pf[self._coarse].T, axis=1)]  # (k,) pair rows
    ci, cj = self._pair_i[coarse], self._pair_j[coarse]
    d = np.array([-1, 0, 1])
    fi = np.clip(ci[:, None, None] + d[None, :, None], 0, self.grid.size - 1)  # (k, 3, 1)
    fj = np.clip(cj[:, None, None] + d[None, None, :], 0, self.grid.size - 1)  # (k, 1, 3)
    rows = self._pair_index[fi, fj].reshape(idx.size, -1)  # (k, 9), -1 where i >= j
    rows = np.where(rows >= 0, rows, coarse[:, None])
    fine = np.einsum("kf,kpf->kp", fr, pf[rows])
    best = rows[np.arange(idx.size), np.argmax(fine, axis=1)]
    th = np.stack([self.grid[self._pair_i[best]], self.grid[self._pair_j[best]]], axis=1)
    lateral = range_m[idx] * np.abs(np.sin(th[:, 1]) - np.sin(th[:, 0]))
    # powers of the two fitted sources, diag(B+ R B+^H): a vehicle with a brief visitor in one of its
    # looks (another vehicle's beat in one segment) has a strong and a faint source, not two vehicles
    bp = self._pinv[best].astype(np.complex128)  # (k, 2, rx)
    pw = np.einsum("kar,krs,kas->ka", bp, cov[idx].astype(np.complex128), bp.conj()).real
    ratio = pw.min(axis=1) / np.maximum(pw.max(axis=1), 1e-30)
    ok = (lateral >= cfg.min_lateral_m) & (ratio >= cfg.min_power_ratio)
    return idx[ok], th[ok].astype(np.float32)


def test_cell_split_equals_the_plain_implementation():
    rng = np.random.default_rng(3)
    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    steer = steering_matrix(4, 0.0186, 0.01244, grid)
    res = CellResolver(ResolverConfig(), steer, grid, 0.033, 0.0186 / 0.01244)
    covs = []
    for k in range(600):
        i, j = rng.integers(0, grid.size, 2)
        p2 = rng.choice([0.0, 1e-3, 0.02, 0.05, 0.2, 0.5, 1.0])
        noise = rng.choice([1e-4, 1e-3, 1e-2, 0.05])
        a, b = steer[i][:, None], steer[j][:, None]
        c = a @ a.conj().T + p2 * (b @ b.conj().T) + noise * np.eye(4)
        w = rng.normal(size=(4, 4)) + 1j * rng.normal(size=(4, 4))
        c = c + 0.01 * noise * (w @ w.conj().T)
        covs.append(c / np.trace(c).real)
    cov = np.array(covs).astype(np.complex64)
    cov[:5] = 0.0  # empty cells
    r = rng.uniform(20.0, 300.0, cov.shape[0])
    new, old = res._split(cov, r), split_reference(res, cov, r)
    np.testing.assert_array_equal(new[0], old[0])
    np.testing.assert_array_equal(new[1], old[1])
    assert old[0].size > 20  # splits happen
    w = np.linalg.eigvalsh(cov)
    assert ((w[:, -2] >= 0.05 * w[:, -1]) & (w[:, -2] < 0.2 * w[:, -1])).sum() > 20  # cells near the ratio test


def test_published_track_states_equal_the_dataclass_constructor():
    from edge.traffic.monitor import _with
    from edge.types import TrackState
    from edge.types import track_state as _track_state

    for ln in (None, 4.5):
        fast = _track_state(7, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.1, 3, 2, True, ln)
        plain = TrackState(7, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.1, 3, 2, True, length_m=ln)
        assert fast == plain and list(vars(fast).items()) == list(vars(plain).items()) and hash(fast) == hash(plain)
        laned = _with(fast, 2, "car", ln)
        assert laned == TrackState(7, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.1, 3, 2, True, lane=2, cls="car", length_m=ln)
        assert fast.lane is None  # the original is untouched
    with pytest.raises(AttributeError):  # still frozen
        fast.x_m = 0.0


def test_start_up_yaw_weighted_median_equals_the_numpy_one():
    from edge.traffic import TrafficConfig
    from edge.traffic.lanes import YawEstimator

    rng = np.random.default_rng(5)
    est = YawEstimator(TrafficConfig())
    n_checked = 0
    for frame in range(120):
        ids = np.arange(1, 9)
        x = np.array([-5.25, -1.75, 1.75, 5.25] * 2) + 0.03 * frame * rng.normal(0.05, 0.02, 8) + rng.normal(0, 0.1, 8)
        y = 40.0 + np.arange(8) * 20.0 + 0.8 * frame
        est.add(ids, np.full(8, frame + 1), x, y)
        got = est.estimate_rad()
        votes = np.fromiter(est._votes, dtype=float)
        live, w = est.live_votes_weighted()
        if votes.size + live.size < TrafficConfig().yaw_min_tracks:
            assert got is None
            continue
        allv = np.concatenate([votes, live])
        allw = np.concatenate([np.full(votes.size, w.max() if w.size else 1.0), w])
        o = np.argsort(allv)
        cw = np.cumsum(allw[o])
        assert got == float(allv[o][np.searchsorted(cw, 0.5 * cw[-1])])
        n_checked += 1
    assert n_checked > 50


def test_start_up_live_votes_plain_python_path_is_bit_identical_to_the_array_path(monkeypatch):
    """A handful of running tracks take the plain-Python path; it must give the same votes and
    weights, bit for bit, as the array path (including tracks that do not qualify yet)."""
    import edge.traffic.lanes as lanes_mod
    from edge.traffic import TrafficConfig

    rng = np.random.default_rng(11)
    est = lanes_mod.YawEstimator(TrafficConfig(), kernels=False)  # (the kernel path has no _SMALL switch)
    n_votes = 0
    for frame in range(80):
        ids = np.arange(1, 11)
        x = rng.normal(0.0, 3.0, 10) * (frame < 3) + np.linspace(-6, 6, 10) + rng.normal(0, 0.2, 10)
        y = 10.0 + np.arange(10) * 15.0 + 0.9 * frame * (1 + 0.1 * np.arange(10))
        est.add(ids, np.full(10, frame + 1), x, y)
        monkeypatch.setattr(lanes_mod, "_SMALL", 10**6)
        small = est.live_votes_weighted()
        monkeypatch.setattr(lanes_mod, "_SMALL", -1)
        arrays = est.live_votes_weighted()
        assert small[0].dtype == arrays[0].dtype == np.float64
        assert np.array_equal(small[0], arrays[0]) and np.array_equal(small[1], arrays[1])
        n_votes += small[0].size
    assert 0 < n_votes < 80 * 10  # some tracks qualify, not all (early frames are too short)


def _associate_reference(res: CellResolver, range_m: np.ndarray, v_mps: np.ndarray) -> np.ndarray:
    """The cell association as array code (gate table, stable sort of the costs, greedy one-to-one)."""
    cfg, c, n_det = res.cfg, res.cells, range_m.size
    c_range, c_v = np.array(c.range_m), np.array(c.v_mps)
    match = np.full(n_det, -1)
    pr = c_range + c_v * res.period_s
    dr = np.abs(range_m[:, None] - pr[None, :])
    dv = np.abs(v_mps[:, None] - c_v[None, :])
    cost = np.where((dr <= cfg.range_gate_m) & (dv <= cfg.speed_gate_mps),
                    dr / cfg.range_gate_m + dv / cfg.speed_gate_mps, np.inf)
    di, ci = np.nonzero(np.isfinite(cost))
    order = np.argsort(cost[di, ci], kind="stable")
    taken_d, taken_c = np.zeros(n_det, bool), np.zeros(c_range.size, bool)
    for d, k in zip(di[order].tolist(), ci[order].tolist()):
        if not taken_d[d] and not taken_c[k]:
            taken_d[d] = taken_c[k] = True
            match[d] = k
    return match


def test_cell_association_equals_the_array_form():
    from edge.lane.resolve import _Cells

    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    res = CellResolver(ResolverConfig(), steering_matrix(4, 0.0186, 0.01244, grid), grid, 0.033, 1.5)
    rng = np.random.default_rng(21)
    n_matched = 0
    for t in range(2000):
        nc, nd = int(rng.integers(1, 30)), int(rng.integers(1, 30))
        cr = rng.uniform(5.0, 60.0, nc)
        cv = rng.choice([-20.0, -10.0, 10.0, 25.0], nc) + rng.normal(0.0, 0.5, nc)
        if t % 5 == 0:  # equal costs: ties broken in detection, then cell order
            cr, cv = np.round(cr), np.round(cv)
        k = rng.integers(0, nc, nd)
        r = (cr[k] + cv[k] * 0.033 + rng.normal(0.0, 1.2, nd)).astype(np.float32)
        v = (cv[k] + rng.normal(0.0, 0.6, nd)).astype(np.float32)
        if t % 5 == 0:
            r = np.round(r).astype(np.float32)
        if t % 11 == 0:
            r[0] = np.nan
        if t % 13 == 0:
            cr[0] = np.nan  # a cell without a range: the binary search is not used
        res.cells = _Cells(cr.tolist(), cv.tolist(), np.zeros((nc, 4, 4), np.complex64), [1] * nc, [0] * nc, [0] * nc)
        new = res._associate(r, v)
        np.testing.assert_array_equal(np.array(new), _associate_reference(res, r, v))
        n_matched += sum(m >= 0 for m in new)
    assert n_matched > 10_000


@pytest.mark.parametrize("k", [2, 3, 16])
def test_clutter_map_start_median_equals_np_median(k):
    from edge.lane.clutter import _median_of_frames

    rng = np.random.default_rng(k)
    z = ((rng.standard_normal((k, 4, 4, 64)) + 1j * rng.standard_normal((k, 4, 4, 64))) * 1000).astype(np.complex64)
    z[:, 0, 0, :3] = 0.0  # exact zeros (and ties)
    z[1, 1, 1, 5] = np.nan
    z[0, 2, 2, 7] = complex(np.nan, 1.0)
    ref = np.median(z.real, axis=0) + 1j * np.median(z.imag, axis=0)
    out = _median_of_frames(z.copy())
    assert out.dtype == ref.dtype == np.complex64
    np.testing.assert_array_equal(out, ref)  # NaN where np.median gives NaN
    assert np.isnan(out[1, 1, 5]) and np.isnan(out[2, 2, 7])


class _ArrayCells:
    def __init__(self, n_rx):
        self.range_m, self.v_mps = np.zeros(0), np.zeros(0)
        self.cov = np.zeros((0, n_rx, n_rx), np.complex64)
        self.n, self.misses, self.streak = (np.zeros(0, np.int32) for _ in range(3))


def _step_reference(res: CellResolver, c: _ArrayCells, range_m, v_mps, snapshots, az_rad):
    """CellResolver.step as array code (the form before the per-cell numbers became lists); returns the new cells."""
    cfg = res.cfg
    n_det = range_m.size
    angles = np.full((n_det, 2), np.nan, np.float32)
    split = np.zeros(n_det, bool)
    match = np.full(n_det, -1)
    if len(c.range_m) and n_det:
        pr = c.range_m + c.v_mps * res.period_s
        dr = np.abs(range_m[:, None] - pr[None, :])
        dv = np.abs(v_mps[:, None] - c.v_mps[None, :])
        cost = np.where((dr <= cfg.range_gate_m) & (dv <= cfg.speed_gate_mps),
                        dr / cfg.range_gate_m + dv / cfg.speed_gate_mps, np.inf)
        di, ci = np.nonzero(np.isfinite(cost))
        order = np.argsort(cost[di, ci], kind="stable")
        taken_d, taken_c = np.zeros(n_det, bool), np.zeros(len(c.range_m), bool)
        for d, k in zip(di[order].tolist(), ci[order].tolist()):
            if not taken_d[d] and not taken_c[k]:
                taken_d[d] = taken_c[k] = True
                match[d] = k
    r_new, _ = res._outer(snapshots)  # (the products with one rounding each, shared with the list form)
    hit = match >= 0
    seen = np.zeros(len(c.range_m), bool)
    if hit.any():
        k = match[hit]
        seen[k] = True
        c.n[k] += 1
        if cfg.follow_direction:
            shift = np.sin(az_rad[hit].astype(np.float64)) * (1.0 - range_m[hit] / np.maximum(c.range_m[k], 1e-3))
            m = np.arange(res.n_rx)
            lag = (m[:, None] - m[None, :]).astype(np.float32)
            ph = (-2.0 * np.pi * res._d_over_lam) * shift.astype(np.float32)[:, None, None] * lag
            ph = ph.astype(np.float64)
            f = np.empty(ph.shape + (2,), np.float32)
            f[..., 0], f[..., 1] = np.cos(ph), np.sin(ph)
            c.cov[k] = _cmul(c.cov[k], f.view(np.complex64)[..., 0])
        a = np.maximum(1.0 / c.n[k], 1.0 / cfg.memory_frames).astype(np.float32)
        c.cov[k] += a[:, None, None] * (r_new[hit] - c.cov[k])
        c.range_m[k] = range_m[hit]
        c.v_mps[k] = v_mps[hit]
        c.misses[k] = 0
        ready = hit.nonzero()[0][(c.n[k] >= cfg.min_frames) & (np.abs(v_mps[hit]) >= cfg.min_speed_mps)]
        now = np.zeros(n_det, bool)
        if ready.size:
            split_idx, ang = split_reference(res, c.cov[match[ready]], range_m[ready])
            now[ready[split_idx]] = True
            angles[ready[split_idx]] = ang
        c.streak[k] = np.where(now[hit], c.streak[k] + 1, 0)
        split[hit.nonzero()[0]] = now[hit] & (c.streak[k] >= cfg.min_split_frames)
        angles[~split] = np.nan
    c.misses[~seen] += 1
    keep = c.misses <= cfg.max_misses
    new = ~hit
    if new.any() or not keep.all():
        nn = int(new.sum())
        c.range_m = np.concatenate([c.range_m[keep], range_m[new].astype(np.float64)])
        c.v_mps = np.concatenate([c.v_mps[keep], v_mps[new].astype(np.float64)])
        c.cov = np.concatenate([c.cov[keep], r_new[new]])
        c.n = np.concatenate([c.n[keep], np.ones(nn, np.int32)])
        c.misses = np.concatenate([c.misses[keep], np.zeros(nn, np.int32)])
        c.streak = np.concatenate([c.streak[keep], np.zeros(nn, np.int32)])
        if len(c.range_m) > cfg.max_cells:
            o = np.argsort(c.misses, kind="stable")[: cfg.max_cells]
            c.range_m, c.v_mps, c.cov, c.n, c.misses, c.streak = (
                c.range_m[o], c.v_mps[o], c.cov[o], c.n[o], c.misses[o], c.streak[o])
    return split, angles


@pytest.mark.parametrize("max_cells", [256, 6])
def test_cell_resolver_step_equals_the_array_form(max_cells):
    """Several vehicles (two side by side) followed over frames, cells created, dropped and (max_cells=6) cut:
    the splits, angles and every cell's state equal the array form's."""
    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    steer = steering_matrix(4, 0.0186, 0.01244, grid)
    res = CellResolver(ResolverConfig(max_cells=max_cells, min_frames=3, min_split_frames=2, min_lateral_m=1.0),
                       steer, grid, 0.033, 0.0186 / 0.01244)
    ref = _ArrayCells(4)
    rng = np.random.default_rng(5)
    d_lam = 0.0186 / 0.01244
    n_split = 0
    for t in range(150):
        n = int(rng.integers(0, 9))
        r0 = np.array([30.0, 30.0, 55.0, 80.0, 12.0, 100.0, 140.0, 60.0])[:n] - 0.9 * t * 0.033 * 25.0 % 60.0
        rng_m = (np.abs(r0) + 5.0 + rng.normal(0.0, 0.2, n)).astype(np.float32)
        v = np.array([-25.0, -25.0, 20.0, -30.0, 0.5, 22.0, -10.0, 15.0])[:n].astype(np.float32)
        th = np.array([-0.06, 0.06, 0.1, -0.2, 0.0, 0.05, 0.15, -0.1])[:n]
        a = np.exp(-2j * np.pi * d_lam * np.arange(4)[None, :] * np.sin(th)[:, None])
        b = np.exp(-2j * np.pi * d_lam * np.arange(4)[None, :] * np.sin(-th)[:, None])
        ph = np.exp(2j * np.pi * rng.random((n, 4, 1)))
        snaps = (a[:, None, :] + ph * b[:, None, :] * (np.arange(n) < 2)[:, None, None]
                 + 0.05 * (rng.normal(size=(n, 4, 4)) + 1j * rng.normal(size=(n, 4, 4)))).astype(np.complex64)
        if n:
            snaps[0, 3] = 0.0  # a look left out
        az = th.astype(np.float32)
        new_split, new_ang = res.step(rng_m, v, snaps, az)
        old_split, old_ang = _step_reference(res, ref, rng_m, v, snaps, az)
        np.testing.assert_array_equal(new_split, old_split)
        np.testing.assert_array_equal(new_ang, old_ang)
        c = res.cells
        np.testing.assert_array_equal(np.array(c.range_m, np.float64).reshape(-1), ref.range_m)
        np.testing.assert_array_equal(np.array(c.v_mps, np.float64).reshape(-1), ref.v_mps)
        np.testing.assert_array_equal(c.cov, ref.cov)
        for name in ("n", "misses", "streak"):
            np.testing.assert_array_equal(np.array(getattr(c, name), np.int64).reshape(-1), getattr(ref, name))
        n_split += int(new_split.sum())
    assert n_split > 0
    assert max_cells > 6 or len(res.cells.range_m) <= 6


def test_split_features_one_gather_equals_the_general_form():
    """The complex64 covariance features (diagonal, 2 Re and 2 Im of the upper triangle) from one gather of the
    float view and one product equal the general form's."""
    grid = np.radians(np.arange(-19.0, 19.0 + 1e-9, 0.25)).astype(np.float32)
    res = CellResolver(ResolverConfig(), steering_matrix(4, 0.0186, 0.01244, grid), grid, 0.033, 1.5)
    rng = np.random.default_rng(8)
    x = (rng.normal(size=(50, 4, 4)) + 1j * rng.normal(size=(50, 4, 4))).astype(np.complex64)
    cov = np.einsum("nsa,nsb->nab", x, x.conj())
    fast = res._features(cov, scale_offdiag=2.0)
    d = np.real(np.diagonal(cov, axis1=1, axis2=2))
    u = cov[:, res._iu[0], res._iu[1]]
    general = np.concatenate([d, 2.0 * u.real, 2.0 * u.imag], axis=1).astype(np.float32)
    assert fast.dtype == np.float32 and fast.flags.c_contiguous
    np.testing.assert_array_equal(fast, general)


def test_track_aided_predictions_small_and_array_paths_agree(monkeypatch):
    """The confirmed tracks' predicted range, speed and beats, and which of them already have a pairing within the
    aided gates: the plain-Python path (a handful of tracks) and the array path give the same values."""
    from edge.lane import pairs as lane
    from edge.pipelines.lane import LaneConfig, LanePipeline

    pipe = LanePipeline(SIMO_BOARD.frontend, LaneConfig())
    rng = np.random.default_rng(3)
    n_kept = 0
    for t in range(60):
        n = int(rng.integers(1, 25))
        x = np.stack([rng.uniform(-8.0, 8.0, n), rng.uniform(-20.0, 380.0, n), rng.normal(0.0, 0.5, n),
                      rng.choice([-30.0, -0.5, 25.0], n)], axis=1)
        pipe.tracker.tracks.append(x, np.tile(np.eye(4), (n, 1, 1)), 1.0)
        tr = pipe.tracker.tracks
        tr.confirmed[:] = True
        dt = 0.033
        xp, yp = x[:, 0] + x[:, 2] * dt, x[:, 1] + x[:, 3] * dt
        r = np.sqrt(xp * xp + yp * yp + 6.5 ** 2)
        v = (xp * x[:, 2] + yp * x[:, 3]) / r
        k = rng.random(n) < 0.4  # some tracks already paired (within the gates), some just outside
        pr = (r[k] + rng.choice([0.0, 2.4, 2.6, -2.6], k.sum())).astype(np.float32)
        pv = (v[k] + rng.choice([0.0, 1.4, 1.6], k.sum())).astype(np.float32)
        pairs = Pairs(np.zeros((pr.size, 4), np.int64), pr, pv, np.zeros(pr.size, np.float32), 0, 0)
        sel = np.arange(len(tr))
        monkeypatch.setattr(lane, "_AIDED_SMALL", 10_000)
        small = pipe.pairs.reference_predictions(tr.x, sel, dt, pairs)
        monkeypatch.setattr(lane, "_AIDED_SMALL", -1)
        full = pipe.pairs.reference_predictions(tr.x, sel, dt, pairs)
        assert (small is None) == (full is None)
        if small is not None:
            for a, b in zip(small, full):
                np.testing.assert_array_equal(a, b)
            n_kept += small[0].size
        pipe.tracker.reset()
    assert n_kept > 100
