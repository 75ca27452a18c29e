"""The pairing kernel (edge/native/_pairs.pyx, steps 1-4 of the pairing; step 5 stays numpy) against its numpy
reference (edge.dsp.pairing.pair_beats): the same accepted pairs, ranges, speeds, residuals and counts bit for bit,
on random peak lists (vehicles of several scatterers, whose cross-pairings are ghosts; ties; empty segments) and on
the peak frequencies recorded in the lane stage fixtures (hw_sim frames)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge.dsp.pairing import PairingModel, pair_beats
from edge.lane.pairs import _GHOST_SPEED_MPS, PairStage
from edge.pipelines.lane import LaneConfig
from hw_sim.boards import SIMO_BOARD
from tests.native.conftest import require_kernel

FE = SIMO_BOARD.frontend
BIN_HZ = np.array([s.sample_rate_hz / FE.waveform.n_samples for s in FE.waveform.segments])


def _stage(**overrides) -> PairStage:
    return PairStage(FE, dataclasses.replace(LaneConfig(), **overrides), BIN_HZ)


def assert_same_pairs(a, b) -> None:
    assert (a.n_candidates, a.n_ghosts) == (b.n_candidates, b.n_ghosts)
    assert a.peak_index.dtype == b.peak_index.dtype
    np.testing.assert_array_equal(a.peak_index.reshape(-1, 4), b.peak_index.reshape(-1, 4))
    for name in ("range_m", "radial_speed_mps", "residual_hz"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)


def _random_freqs(rng, model: PairingModel, n_veh: int, drop: float, targets: list | None = None):
    """Peaks of ``n_veh`` vehicles of 1-6 scatterers (3 m apart, the body's ghost pairings among them) plus noise
    peaks; each peak missed with probability ``drop`` in each segment; frequency jitter of a tenth of a bin.
    ``targets``: if given, each vehicle's (near-face range, speed) is appended."""
    rs, vs = [], []
    for _ in range(n_veh):
        r0, v = rng.uniform(3.0, 380.0), rng.uniform(-45.0, 45.0)
        if targets is not None:
            targets.append((r0, v))
        k = rng.integers(1, 7)
        rs.extend(r0 + 3.0 * np.arange(k))
        vs.extend([v] * k)
    f = model.predict(np.array(rs, dtype=np.float64), np.array(vs, dtype=np.float64)) if rs else np.zeros((0, 4))
    out = []
    for s in range(4):
        fs = f[:, s] + rng.normal(0.0, 0.1 * BIN_HZ[s], f.shape[0])
        fs = fs[rng.random(fs.size) >= drop]
        noise = rng.uniform(-0.5, 0.5, rng.integers(0, 4)) * BIN_HZ[s] * FE.waveform.n_samples
        out.append(np.concatenate([fs, noise]).astype(np.float64))
    return tuple(out)


@pytest.mark.parametrize("seed", range(40))
def test_kernel_equals_reference_on_random_peaks(seed):
    require_kernel("_pairs")
    rng = np.random.default_rng(seed)
    overrides = [{}, {"pair_max_shared_peaks": 0}, {"pair_near_range_m": 0.0}, {"pair_max_shared_peaks": 2}]
    stage = _stage(**overrides[seed % len(overrides)])
    assert stage.kernel is not None
    n_pairs = 0
    for n_veh in (0, 1, 3, 8, 20):
        for drop in (0.0, 0.2):
            freqs = _random_freqs(rng, stage.model, n_veh, drop)
            ref = stage.reference(freqs)
            assert_same_pairs(stage.pair(freqs), ref)
            n_pairs += ref.range_m.size
    assert n_pairs > 10


def test_kernel_equals_reference_with_ties_and_empty_segments():
    """Two peaks at the same distance from a prediction (the lower frequency wins) and a segment without peaks."""
    stage = _stage()
    require_kernel("_pairs")
    f = stage.model.predict(np.array([50.0, 120.0]), np.array([-20.0, 25.0]))  # (2, 4)
    tie = (f[:, 0], f[:, 1], np.concatenate([f[:, 2] - 0.3 * BIN_HZ[2], f[:, 2] + 0.3 * BIN_HZ[2]]), f[:, 3])
    ref = stage.reference(tie)
    assert ref.range_m.size == 2
    assert_same_pairs(stage.pair(tie), ref)
    for s in range(4):
        empty = tuple(np.zeros(0) if k == s else f[:, k] for k in range(4))
        assert_same_pairs(stage.pair(empty), stage.reference(empty))


@pytest.mark.parametrize("stem", ["lane_stages_misaimed_s31", "lane_stages_side_by_side_s31",
                                  "lane_stages_wrong_way_s6"])
def test_kernel_equals_reference_on_recorded_peaks(stem):
    """The peak frequencies of every recorded frame of the stage fixtures (seeded hw_sim runs), paired with the
    fixture's own arguments."""
    kern = require_kernel("_pairs")
    from edge.dsp.pairing import refine_pairs
    from tests.edge import lane_golden as g

    data, meta = g.load(g.fixture_path(stem))
    fr = g.Frames(data)
    kw = dict(meta["pair_kw"])
    model = PairingModel(np.array(kw.pop("model_a")), np.array(kw.pop("model_b")))
    tol, near_tol = tuple(kw["tolerance_hz"]), kw.get("near_tolerance_hz")
    near_r = kw.get("near_range_m", 0.0) if near_tol is not None else 0.0
    near_tol = tuple(near_tol) if near_tol is not None else tol
    ghost = kw.get("ghost_speed_mps", _GHOST_SPEED_MPS)
    coef = np.array(model.coefficients)
    n_frames = n_pairs = 0
    for k in range(meta["frames"]):
        if not fr.has("pair_counts", k):
            continue
        freqs = tuple(np.ascontiguousarray(fr.get(f"pair_in_f{s}", k), np.float64) for s in range(4))
        ref = pair_beats(freqs, model, **{**kw, "tolerance_hz": tol,
                                          "near_tolerance_hz": near_tol if near_r > 0 else None})
        rows, n_cand, n_ghost = kern.pair(*freqs, coef, kw["min_range_m"], kw["max_range_m"], kw["max_speed_mps"],
                                          tol[0], tol[1], near_tol[0], near_tol[1], near_r,
                                          kw.get("max_shared", 1), ghost)
        assert_same_pairs(refine_pairs(rows, freqs, model, n_cand, n_ghost), ref)
        n_frames += 1
        n_pairs += ref.range_m.size
    assert n_frames > 100 and n_pairs > 200


def _aided_both(stage: PairStage, *args):
    """track_aided with the kernel and with its numpy reference (the stage's kernel switched off)."""
    out = stage.track_aided(*args)
    k, stage.kernel = stage.kernel, None
    try:
        ref = stage.track_aided(*args)
    finally:
        stage.kernel = k
    return out, ref


def _assert_same_aided(out, ref) -> None:
    assert len(out) == len(ref) == 4
    for x, y in zip(out, ref):
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("seed", range(20))
def test_aided_search_equals_reference_on_random_tracks(seed):
    """Tracks at random positions (a third near a vehicle whose peaks are present, some of them paired), peaks of
    other vehicles and noise, weak peaks in half the cases: the same track-aided pairs from the kernel's search."""
    require_kernel("_pairs")
    from edge.lane.records import Feedback

    rng = np.random.default_rng(100 + seed)
    stage = _stage(aided_min_segments=(2, 3, 4)[seed % 3])
    cfg = stage.config
    dz = cfg.mounting_height_m - cfg.target_height_m
    n_out = 0
    for trial in range(10):
        n_veh = int(rng.integers(1, 12))
        targets: list = []
        freqs = _random_freqs(rng, stage.model, n_veh, 0.3, targets)
        bins = tuple(np.rint(f / BIN_HZ[s]).astype(np.int64) % FE.waveform.n_samples for s, f in enumerate(freqs))
        weak = None
        if trial % 2:
            wf = _random_freqs(rng, stage.model, 3, 0.5)
            weak = (wf, tuple(np.rint(f / BIN_HZ[s]).astype(np.int64) % FE.waveform.n_samples
                              for s, f in enumerate(wf)))
        pairs = stage.reference(freqs)
        # tracks on the vehicles (on the boresight, a little off their range and speed) and elsewhere
        rows = []
        for r0, v in targets:
            r = r0 + rng.normal(0.0, 0.3)
            y = np.sqrt(max(r * r - dz * dz, 1.0))
            rows.append((0.0, y, 0.0, (v + rng.normal(0.0, 0.2)) * r / y))
        for _ in range(int(rng.integers(0, 5))):
            rows.append((rng.uniform(-8.0, 8.0), rng.uniform(5.0, 350.0), 0.0, rng.uniform(-40.0, 40.0)))
        state = np.array(rows, dtype=np.float64)
        n_tr = state.shape[0]
        fb = Feedback(t_ns=0, track_state=state, confirmed=rng.random(n_tr) < 0.8, moved=np.ones(n_tr, bool),
                      hits=rng.integers(0, 10, n_tr))
        out, ref = _aided_both(stage, freqs, bins, pairs, 0, fb, weak)
        _assert_same_aided(out, ref)
        n_out += ref[1].size
    assert n_out > 0  # the search found peaks and the fits passed their gates


def test_aided_search_equals_reference_in_the_pipeline(monkeypatch):
    """Every track-aided search of a seeded highway4-traffic run (120 frames): the kernel's picks and the fits
    equal the reference's."""
    require_kernel("_pairs")
    from tests.edge import lane_golden as g

    pipe, frames = g.build("highway4-traffic", 1, 5.0)
    stage = pipe.pairs
    real = stage.track_aided
    n = {"calls": 0, "pairs": 0}

    def spy(*args):
        out = real(*args)
        k, stage.kernel = stage.kernel, None
        try:
            ref = real(*args)
        finally:
            stage.kernel = k
        _assert_same_aided(out, ref)
        n["calls"] += 1
        n["pairs"] += ref[1].size
        return out

    monkeypatch.setattr(stage, "track_aided", spy)
    from edge.pipeline import StageTimer
    t = StageTimer(16)
    for f in frames(120):
        pipe.process(f, t)
    assert n["calls"] > 50 and n["pairs"] > 5


@pytest.mark.parametrize("seed", range(10))
def test_pair_frame_equals_pair_and_the_frequency_rows(seed):
    """pair_frame (the stage's call) against pair on float64 arrays and refine_pairs' frequency rows
    (``np.concatenate(f)[rows + offsets]``), for peak lists given as float64, float32, strided or list forms."""
    k = require_kernel("_pairs")
    rng = np.random.default_rng(300 + seed)
    stage = _stage()
    cfg = stage.config
    args = (stage._coef, cfg.min_range_m, cfg.max_range_m, cfg.max_speed_kmh / 3.6, stage.tol[0], stage.tol[1],
            stage._near_tol[0], stage._near_tol[1], cfg.pair_near_range_m, cfg.pair_max_shared_peaks,
            _GHOST_SPEED_MPS)
    n_rows = 0
    for trial in range(6):
        freqs = _random_freqs(rng, stage.model, int(rng.integers(0, 12)), 0.2)
        f64 = tuple(np.ascontiguousarray(f, np.float64) for f in freqs)
        rows, n_cand, n_ghost = k.pair(*f64, *args)
        forms = [freqs, tuple(np.repeat(f, 2)[::2] for f in freqs), tuple(list(f) for f in freqs)]
        if trial % 2:
            forms.append(tuple(f.astype(np.float32) for f in freqs))
            rows, n_cand, n_ghost = k.pair(*(np.ascontiguousarray(f, np.float32).astype(np.float64)
                                             for f in freqs), *args)
            forms = forms[3:]
        bins = tuple(rng.integers(0, 1024, len(f)).astype(np.int64) for f in freqs)
        for form in forms:
            r2, c2, g2, fm, pk = k.pair_frame(tuple(form), *args)
            assert pk is None
            r3, c3, g3, fm3, pk = k.pair_frame(tuple(form), *args, bins)
            assert (c3, g3) == (c2, g2)
            np.testing.assert_array_equal(r3, r2)
            np.testing.assert_array_equal(fm3.view(np.int64), fm.view(np.int64))
            want_pk = np.concatenate(bins)[rows + PairingModel.offsets(tuple(b.size for b in bins[:3]))]
            assert pk.dtype == np.int64 and pk.shape == rows.shape
            np.testing.assert_array_equal(pk, want_pk)
            for bad in (tuple(b.astype(np.int32) for b in bins), bins[:3] + (np.zeros(bins[3].size + 1, np.int64),)):
                assert k.pair_frame(tuple(form), *args, bad)[4] is None
            assert (c2, g2) == (n_cand, n_ghost) and r2.dtype == rows.dtype == np.int64
            np.testing.assert_array_equal(r2, rows)
            f_ref = tuple(np.ascontiguousarray(f, np.float64) for f in form)
            want = np.concatenate(f_ref)[rows + PairingModel.offsets(tuple(f.size for f in f_ref[:3]))]
            assert fm.dtype == np.float64 and fm.shape == (rows.shape[0], 4)
            np.testing.assert_array_equal(fm.view(np.int64), want.view(np.int64))
        n_rows += rows.shape[0]
    assert n_rows > 0
    with pytest.raises(ValueError):
        k.pair_frame(freqs[:3], *args)


@pytest.mark.parametrize("seed", range(6))
def test_aided_search_converts_other_arrays(seed):
    """aided_search on strided, float32 and int32 peak lists and a (4 n,) used array gives what it gives on their
    float64 / int64 C-contiguous conversions (the stage's former arguments); a used index out of range raises."""
    k = require_kernel("_pairs")
    rng = np.random.default_rng(400 + seed)
    stage = _stage()
    targets: list = []
    freqs = _random_freqs(rng, stage.model, 8, 0.2, targets)
    bins = tuple(np.rint(f / BIN_HZ[s]).astype(np.int64) % FE.waveform.n_samples for s, f in enumerate(freqs))
    wf32 = tuple(f.astype(np.float32) for f in _random_freqs(rng, stage.model, 3, 0.3))
    wf = tuple(f.astype(np.float64) for f in wf32)
    wb = tuple(np.rint(f / BIN_HZ[s]).astype(np.int64) % FE.waveform.n_samples for s, f in enumerate(wf))
    used = stage.reference(freqs).peak_index
    t = np.array(targets + [(rng.uniform(10.0, 300.0), rng.uniform(-30.0, 30.0)) for _ in range(3)])
    f_hat = stage.model.predict(t[:, 0] + rng.normal(0.0, 0.3, len(t)), t[:, 1])
    base = k.aided_search(tuple(np.ascontiguousarray(f, np.float64) for f in freqs), bins, wf, wb,
                          np.ascontiguousarray(used, np.int64).reshape(-1, 4), np.ascontiguousarray(f_hat),
                          stage._aided_window_hz, 2)
    other = k.aided_search(tuple(np.repeat(f, 2)[::2] for f in freqs), tuple(b.astype(np.int32) for b in bins),
                           wf32, tuple(list(b) for b in wb),
                           used.reshape(-1), np.asfortranarray(f_hat), list(stage._aided_window_hz), 2)
    for a, b in zip(base, other):
        assert a.dtype == b.dtype and a.shape == b.shape
        np.testing.assert_array_equal(a, b)
    assert base[0].sum() > 0
    bad = np.ascontiguousarray(used, np.int64).reshape(-1, 4).copy()
    if bad.size:
        bad[0, 1] = freqs[1].size
        with pytest.raises(IndexError):
            k.aided_search(freqs, bins, wf, wb, bad, f_hat, stage._aided_window_hz, 2)


def test_aided_search_window_edge():
    """A peak exactly one window from the prediction is found (the reference's ``<=``), one just beyond is not."""
    k = require_kernel("_pairs")
    freqs = tuple(np.array([1024.0, 4096.0]) for _ in range(4))
    bins = tuple(np.array([3, 9], np.int64) for _ in range(4))
    window = np.array([8.0, 8.0, 8.0, 8.0])
    f_hat = np.array([[1032.0, 4088.0, np.nextafter(1032.0, 2e3), 4087.0]])
    found, fsel, bsel, good = k.aided_search(freqs, bins, None, None, np.zeros((0, 4), np.int64), f_hat, window, 2)
    np.testing.assert_array_equal(found, [[1, 1, 0, 0]])
    np.testing.assert_array_equal(fsel, [[1024.0, 4096.0, 0.0, 0.0]])
    np.testing.assert_array_equal(bsel, [[3, 9, -1, -1]])
    assert good.tolist() == [1]


@pytest.mark.parametrize("seed", range(6))
def test_refine_finish_equals_refine(seed):
    """Step 5 with the kernel's tail (refine_rows with the kernel) against numpy's _refine: ranges, speeds and
    residuals bit for bit, for pairs on the model and off it by up to a hundred bins."""
    from edge.dsp import pairing

    k = require_kernel("_pairs")
    stage = _stage()
    rng = np.random.default_rng(300 + seed)
    n_pairs = 0
    for n in (0, 1, 2, 3, 8, 50, 200):
        idx = rng.integers(0, 10, (n, 4))
        fm = stage.model.predict(rng.uniform(1.0, 400.0, n), rng.uniform(-50.0, 50.0, n))
        fm = fm + rng.normal(0.0, 1.0, (n, 4)) * BIN_HZ * rng.choice([0.0, 0.01, 1.0, 100.0], (n, 1))
        ref = pairing._refine(idx, fm, stage.model, 5, 2)
        assert_same_pairs(pairing.refine_rows(idx, fm, stage.model, 5, 2, k), ref)
        n_pairs += n
    assert n_pairs > 200


def test_refine_finish_checks_its_arrays():
    k = require_kernel("_pairs")
    fm = np.ones((3, 4))
    sol = np.ones((3, 2))
    k.refine_finish(fm, sol, fm)
    for args in ((np.asfortranarray(fm), sol, fm), (fm, sol[:2], fm), (fm, sol, fm.astype(np.float32)),
                 (fm, np.ones((3, 3)), fm)):
        with pytest.raises(ValueError):
            k.refine_finish(*args)


@pytest.mark.parametrize("seed", range(6))
def test_drop_rows_equals_boolean_indexing(seed):
    """The kept rows of drop_static's five arrays in one call, against numpy's ``a[~static]``: the same dtypes,
    shapes and bytes; None when nothing is static; False for arrays it does not take."""
    k = require_kernel("_pairs")
    rng = np.random.default_rng(400 + seed)
    for n in (1, 2, 5, 30):
        cols = (rng.integers(0, 50, (n, 4)), rng.normal(0, 100, n).astype(np.float32),
                rng.normal(0, 10, n).astype(np.float32), rng.random(n).astype(np.float32),
                rng.integers(0, 256, (n, 4)))
        for static in (rng.random(n) < 0.4, np.zeros(n, bool), np.ones(n, bool)):
            for s_in in (static, static.view(np.uint8)):
                out = k.drop_rows(s_in, cols)
                if not static.any():
                    assert out is None
                    continue
                assert len(out) == len(cols)
                for a, c in zip(out, cols):
                    want = c[~static]
                    assert a.dtype == want.dtype and a.shape == want.shape and a.flags.c_contiguous
                    assert a.tobytes() == want.tobytes()
                    assert not np.shares_memory(a, c)
        if n < 2:  # (one row is contiguous in any layout)
            continue
        static = np.arange(n) % 2 == 0
        for bad in ((np.asfortranarray(np.ones((n, 4))),), (np.ones(n + 1),), (np.ones(2 * n)[::2],),
                    (np.array(["x"] * n, object),), (np.ones(n, ">f4"),), ([1.0] * n,)):
            assert k.drop_rows(static, cols + bad) is False
        assert k.drop_rows(static.astype(np.int64), cols) is False


def test_drop_static_with_the_kernel_equals_numpy(monkeypatch):
    """drop_static of every frame of a seeded highway4-traffic run (150 frames; static residue dropped in most):
    the kernel's rows are numpy's."""
    require_kernel("_pairs")
    from edge.pipeline import StageTimer
    from tests.edge import lane_golden as g

    pipe, frames = g.build("highway4-traffic", 1, 5.0)
    stage = pipe.pairs
    real = stage.drop_static
    n = {"calls": 0, "dropped": 0}

    def spy(pairs, pk, spectra, floor):
        out = real(pairs, pk, spectra, floor)
        k, stage.kernel = stage.kernel, None
        try:
            ref = real(pairs, pk, spectra, floor)
        finally:
            stage.kernel = k
        assert_same_pairs(out[0], ref[0])
        assert out[1].dtype == ref[1].dtype and out[1].tobytes() == ref[1].tobytes()
        n["calls"] += 1
        n["dropped"] += pk.shape[0] - ref[1].shape[0]
        return out

    monkeypatch.setattr(stage, "drop_static", spy)
    t = StageTimer(16)
    for f in frames(150):
        pipe.process(f, t)
    assert n["calls"] > 50 and n["dropped"] > 50, n
