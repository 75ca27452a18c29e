"""The peak-stage kernel (edge/native/_peaks.pyx) against its numpy reference (edge.lane.peaks.PeakStage.reference):
the same peaks, weak peaks, noise and threshold bit for bit, on random spectra (with ties) and on hw_sim frames."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edge import native
from edge.dsp.cfar import circular_pad
from edge.lane.peaks import PeakStage
from edge.lane.records import Peaks, Spectra
from edge.pipeline import StageTimer
from edge.pipelines.lane import LaneConfig
from hw_sim.boards import SIMO_BOARD

FE = SIMO_BOARD.frontend


def _kernel_or_skip():
    if not native.enabled():
        pytest.skip("RADAR_EDGE_KERNELS=0: the numpy reference is in use")
    k = native.load("_peaks")
    assert k is not None, "edge.native._peaks is not built (pip install -e . with a C compiler)"
    return k


def assert_same_peaks(a: Peaks, b: Peaks) -> None:
    for name in ("freqs_hz", "bins", "weak_freqs_hz", "weak_bins"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert len(x) == len(y), name
            for u, v in zip(x, y):
                assert u.dtype == v.dtype, name
                np.testing.assert_array_equal(u, v, err_msg=name)
    for name in ("noise", "threshold", "floor"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x.view(np.int32), y.view(np.int32), err_msg=name)  # bits (NaN's included)


def _stage(**overrides) -> PeakStage:
    cfg = dataclasses.replace(LaneConfig(), **overrides)
    return PeakStage(FE, cfg)


def _spectra(power: np.ndarray, pad: int) -> Spectra:
    return Spectra(np.zeros((1,) + power.shape, np.complex64), circular_pad(power.astype(np.float32), pad), pad)


@pytest.mark.parametrize("seed", range(12))
def test_kernel_equals_reference_on_random_spectra(seed):
    """Gamma(4) noise with strong peaks of 1-3 bins; every third seed quantised to a few levels (ties between
    neighbours and in the OS-CFAR ranking), one with exact zeros; with and without weak peaks."""
    _kernel_or_skip()
    rng = np.random.default_rng(seed)
    overrides = [{}, {"cfar_train_cells": 8, "cfar_guard_cells": 1, "cfar_rank_fraction": 0.5},
                 {"max_peaks_per_segment": 8}, {"cfar_rank_fraction": 0.9}][seed % 4]
    st = _stage(**overrides)
    assert st.kernel is not None
    n = st.n_bins
    power = rng.gamma(4.0, 1.0, (4, n)).astype(np.float32)
    for _ in range(rng.integers(5, 60)):
        k, b = rng.integers(0, 4), rng.integers(0, n)
        power[k, b] *= np.float32(10 ** rng.uniform(0.3, 4))
        power[k, (b + 1) % n] *= np.float32(10 ** rng.uniform(0, 2))
    if seed % 3 == 0:
        power = np.round(power * 2) / 2  # ties
    if seed == 6:
        power[:, ::7] = 0.0
    sp = _spectra(power, st.pad)
    for want_weak in (False, True):
        ref, got = st.reference(sp, want_weak), st(sp, want_weak)
        assert_same_peaks(got, ref)
        assert sum(f.size for f in ref.freqs_hz) > 0
        if want_weak and seed % 4 != 2:
            assert sum(f.size for f in ref.weak_freqs_hz) > 0


def test_unrolled_default_network_is_the_rank_network():
    """The kernel's unrolled network for the default window (16 reference cells a side, rank 24) has the
    comparators of rank_network(32, 24), in order; the default configuration uses it."""
    k = _kernel_or_skip()
    comp, npad = k.rank_network(32, 24)
    assert npad == 32
    np.testing.assert_array_equal(k.fixed_network(), comp)
    st = _stage()
    assert (2 * st.config.cfar_train_cells, st._rank) == (32, 24)


@pytest.mark.parametrize("seed", range(4))
def test_unrolled_network_equals_the_generic_one(seed):
    """select's noise with the unrolled default network equals the comparator loop's on the same network (the
    comparators given with one repeated at the end, which changes no output: the generic path runs), for every
    batch size from 1 to 8 local maxima and with ties and zeros in the windows."""
    k = _kernel_or_skip()
    st = _stage()
    rng = np.random.default_rng(100 + seed)
    n, h = st.n_bins, st.pad
    comp, npad = k.rank_network(32, 24)
    comp_generic = np.ascontiguousarray(np.vstack([comp, comp[-1:]]))
    for n_peaks in list(range(1, 10)) + [40]:
        power = rng.gamma(4.0, 1.0, (4, n)).astype(np.float32)
        if seed % 2:
            power = np.round(power * 2) / 2
            power[:, ::5] = 0.0
        cells = 2 * rng.choice(n // 2, n_peaks, replace=False)  # even bins: never neighbours
        power[0, cells] = np.float32(100.0) + rng.integers(0, 3, n_peaks)  # local maxima, some of them tied
        ppad = circular_pad(power, h)
        valid = np.zeros((4, n), np.uint8)
        valid[0, cells] = 1  # the only local maxima searched: n_peaks of them, in one row
        out = []
        for c in (comp, comp_generic):
            m = 4 * (n // 2 + 1)
            noise = np.full((4, n), np.nan, np.float32)
            rows, cols = np.empty(m, np.int64), np.empty(m, np.int64)
            got = k.select(ppad, valid, 16, 2, 24, c, npad, st.scale32,
                           np.float32(0.0), False, noise, rows, cols, np.empty((m, 3), np.float32),
                           np.empty(m, np.uint8), np.empty(m, np.float32))
            out.append((got, noise))
        assert out[0][0] == out[1][0]
        np.testing.assert_array_equal(out[0][1].view(np.int32), out[1][1].view(np.int32))
        assert np.count_nonzero(~np.isnan(out[0][1])) == n_peaks


def test_kernel_equals_reference_on_hw_sim_frames():
    """Every frame of a short seeded highway4-traffic run: the stage's recorded input (spectra after the clutter
    map, the weak-peak switch as the pipeline set it) through kernel and reference."""
    _kernel_or_skip()
    from tests.edge import lane_golden as g

    pipe, frames = g.build("highway4-traffic", 3, 5.0)
    stage = pipe.peaks
    assert stage.kernel is not None
    seen = {"frames": 0, "weak": 0, "peaks": 0}

    def spy(spectra, want_weak):
        ref = stage.reference(spectra, want_weak)
        got = stage._compiled(spectra, want_weak)
        assert_same_peaks(got, ref)
        seen["frames"] += 1
        seen["weak"] += int(want_weak)
        seen["peaks"] += sum(f.size for f in ref.freqs_hz)
        return got

    pipe.peaks = spy
    pipe.peaks.aided_scale32 = stage.aided_scale32  # (read by detect())
    timer = StageTimer(16)
    for f in frames(60):
        pipe.process(f, timer)
    assert seen["frames"] == 60 and seen["weak"] > 10 and seen["peaks"] > 300


def test_stage_copies_and_pickles_with_its_kernel():
    """A pipeline is deep-copied (tests, replays) and may be pickled: the stage keeps using the kernel."""
    import copy
    import pickle

    _kernel_or_skip()
    st = _stage()
    for other in (copy.deepcopy(st), pickle.loads(pickle.dumps(st))):
        assert other.kernel is st.kernel is not None


@pytest.mark.parametrize("seed", range(8))
def test_select_frame_and_frame_peaks_equal_select_and_interpolate(seed):
    """The stage's two calls against the former ones (select with a NaN-filled noise, interpolate, the numpy split
    into detected and weak peaks by segment): the same noise, threshold, peaks and weak peaks bit for bit, with
    ties, zeros and segments over the peak cap."""
    k = _kernel_or_skip()
    rng = np.random.default_rng(200 + seed)
    st = _stage(**[{}, {"cfar_train_cells": 8, "cfar_guard_cells": 1, "cfar_rank_fraction": 0.5}][seed % 2])
    n, h = st.n_bins, st.pad
    power = rng.gamma(4.0, 1.0, (4, n)).astype(np.float32)
    for _ in range(rng.integers(5, 80)):
        power[rng.integers(0, 4), rng.integers(0, n)] *= np.float32(10 ** rng.uniform(0.2, 3))
    if seed % 3 == 0:
        power = np.round(power * 2) / 2
        power[:, ::9] = 0.0
    ppad = circular_pad(power, h)
    comp, npad = st._k_comp, st._k_npad
    cfg = st.config
    m_cap = 4 * (n // 2 + 1)
    for want_weak, max_peaks in ((False, 128), (True, 128), (True, 3), (False, 3)):
        noise_a = np.full((4, n), np.nan, np.float32)
        rows_a, cols_a = np.empty(m_cap, np.int64), np.empty(m_cap, np.int64)
        cells_a, hit_a = np.empty((m_cap, 3), np.float32), np.empty(m_cap, np.uint8)
        m = k.select(ppad, st._valid_u8, cfg.cfar_train_cells, cfg.cfar_guard_cells, st._rank, comp, npad,
                     st.scale32, st._k_aided, want_weak, noise_a, rows_a, cols_a, cells_a, hit_a,
                     np.empty(m_cap, np.float32))
        f_a = np.empty(m, np.float64)
        k.interpolate(np.log(cells_a[:m]), rows_a[:m].copy(), cols_a[:m].copy(), st._freq_flat, st._k_bin_hz, n, f_a)
        hit = hit_a[:m].view(bool)

        noise, thr = np.full((4, n), 7.0, np.float32), np.full((4, n), 7.0, np.float32)
        rows, cols = np.full(m_cap, -5, np.int64), np.full(m_cap, -5, np.int64)
        cells, counts = np.full((m_cap, 3), -1.0, np.float32), np.full(8, 99, np.int64)
        m_hit, m2 = k.select_frame(ppad, st._valid_u8, cfg.cfar_train_cells, cfg.cfar_guard_cells, st._rank, comp,
                                   npad, st.scale32, st._k_aided, want_weak, noise, thr, rows, cols,
                                   cells, counts, np.empty(m_cap, np.float32))
        assert (m_hit, m2) == (int(hit.sum()), m)
        np.testing.assert_array_equal(noise.view(np.int32), noise_a.view(np.int32))
        np.testing.assert_array_equal(thr.view(np.int32), (noise_a * st.scale32).view(np.int32))
        order = np.concatenate([hit.nonzero()[0], (~hit).nonzero()[0]])
        np.testing.assert_array_equal(rows[:m], rows_a[order])
        np.testing.assert_array_equal(cols[:m], cols_a[order])
        np.testing.assert_array_equal(cells[:m].view(np.int32), cells_a[order].view(np.int32))
        per_seg = [np.bincount(rows_a[:m][sel], minlength=4) for sel in (hit, ~hit)]
        np.testing.assert_array_equal(counts, np.concatenate(per_seg))
        freqs, bins, wf, wb = k.frame_peaks(np.log(cells[:m]), rows, cols, st._freq_flat, st._k_bin_hz, n, counts,
                                            m_hit, m, want_weak, max_peaks)
        for got, f_sel, c_sel in ((freqs, f_a[hit], cols_a[:m][hit]), (wf, f_a[~hit], cols_a[:m][~hit])):
            if got is wf and not want_weak:
                assert wf is None and wb is None
                continue
            if got is freqs and per_seg[0].max() > max_peaks:
                assert freqs is None and bins is None
                continue
            b_got = bins if got is freqs else wb
            ends = np.cumsum(per_seg[0] if got is freqs else per_seg[1])
            for s_, (fk, bk) in enumerate(zip(got, b_got)):
                lo = ends[s_ - 1] if s_ else 0
                assert fk.dtype == np.float64 and bk.dtype == np.int64
                np.testing.assert_array_equal(fk.view(np.int64), f_sel[lo:ends[s_]].view(np.int64))
                np.testing.assert_array_equal(bk, c_sel[lo:ends[s_]])


def test_select_frame_refuses_other_arrays():
    k = _kernel_or_skip()
    st = _stage()
    n, h = st.n_bins, st.pad
    ppad = np.zeros((4, n + 2 * h), np.float32)
    m_cap = 4 * (n // 2 + 1)
    cfg = st.config
    args = [ppad, st._valid_u8, cfg.cfar_train_cells, cfg.cfar_guard_cells, st._rank, st._k_comp, st._k_npad,
            st.scale32, st._k_aided, True, np.empty((4, n), np.float32),
            np.empty((4, n), np.float32), np.empty(m_cap, np.int64), np.empty(m_cap, np.int64),
            np.empty((m_cap, 3), np.float32), np.empty(8, np.int64), np.empty(m_cap, np.float32)]
    assert k.select_frame(*args) == (0, 0)
    ro = np.empty((4, n), np.float32)
    ro.flags.writeable = False
    for i, bad in [(0, ppad.astype(np.float64)), (0, ppad[:, 1:]), (10, ro),
                   (12, np.empty(m_cap - 1, np.int64)), (12, np.empty(m_cap, np.int32)), (15, np.empty(4, np.int64)),
                   (14, np.empty((m_cap, 3), np.float32).byteswap().view(np.dtype(">f4")))]:
        with pytest.raises((ValueError, TypeError)):
            k.select_frame(*args[:i], bad, *args[i + 1:])
