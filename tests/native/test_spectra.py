"""The ``_spectra`` kernel (windowing, clutter-map update with its static test, subtraction, channel sum) equals
the numpy reference of edge/lane/spectra.py and edge/lane/clutter.py bit for bit: on random inputs, on a
recorded run of the spectra stage, and end to end (detections and confirmed tracks of the lane pipeline)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.fft
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.bench import synth_frames
from edge.config import load_config
from edge.native.check import agree, compare, outputs
from edge.pipeline import build_pipeline
from tests.native.conftest import require_kernel


@pytest.fixture(autouse=True)
def _kernel_built():
    """Fail (skip under RADAR_EDGE_KERNELS=0) before any fixture synthesises frames."""
    require_kernel("_spectra")


@pytest.fixture(scope="module")
def frames():
    return synth_frames("simo", "highway4-traffic", 1, 40)


def _lane(frames, kernel):
    pipe = build_pipeline("lane", frames[0].frontend, load_config(env={}))
    if not kernel:
        pipe.spectra.kernel = None
        pipe.clutter.kernel = None
    return pipe


def _cspec(rng, shape, scale=1.0):
    return (rng.normal(0, scale, shape) + 1j * rng.normal(0, scale, shape)).astype(np.complex64)


@settings(max_examples=25, deadline=None, derandomize=True)
@given(n_rx=st.integers(1, 4), n_seg=st.integers(1, 4), n=st.sampled_from([8, 64, 256, 7, 13]),
       seed=st.integers(0, 2**16))
def test_to_complex_equals_numpy(n_rx, n_seg, n, seed):
    k = require_kernel("_spectra")
    rng = np.random.default_rng(seed)
    i = rng.integers(-32768, 32768, (n_rx, n_seg, n), dtype=np.int16)
    q = rng.integers(-32768, 32768, (n_rx, n_seg, n), dtype=np.int16)
    w = rng.random(n).astype(np.float32) / np.float32(n)
    ref = np.empty(i.shape, np.complex64)
    np.multiply(i, w, out=ref.real)
    np.multiply(q, w, out=ref.imag)
    out = np.empty(i.shape, np.complex64)
    k.to_complex(i, q, w, out)
    assert np.array_equal(out, ref)



def test_to_complex_refuses_other_arrays():
    """The arrays are read through the numpy C API: other dtypes, shapes and layouts are refused."""
    k = require_kernel("_spectra")
    shape = (2, 3, 16)
    i16 = lambda: np.zeros(shape, np.int16)  # noqa: E731
    args = [i16(), i16(), np.ones(16, np.float32), np.empty(shape, np.complex64)]
    k.to_complex(*args)
    for j, bad in [(0, np.zeros(shape, np.int32)), (1, i16()[:, :, ::-1]), (2, np.ones(16, np.float64)),
                   (2, np.ones(15, np.float32)), (3, np.empty(shape, np.complex128)), (3, np.empty((2, 3, 15), np.complex64)),
                   (0, i16().tolist())]:
        a = list(args)
        a[j] = bad
        with pytest.raises((ValueError, TypeError)):
            k.to_complex(*a)

@settings(max_examples=25, deadline=None, derandomize=True)
@given(n_rx=st.integers(1, 4), n_seg=st.integers(1, 4), n=st.sampled_from([7, 64, 257]), seed=st.integers(0, 2**16),
       moving_share=st.floats(0.0, 0.5))
def test_update_hold_moving_equals_numpy(n_rx, n_seg, n, seed, moving_share):
    from edge.lane.clutter import ClutterMap

    k = require_kernel("_spectra")
    rng = np.random.default_rng(seed)
    shape = (n_rx, n_seg, n)
    prev = _cspec(rng, shape)
    spec = prev + _cspec(rng, shape, 0.05)  # static: small change ...
    hot = rng.random((n_seg, n)) < moving_share
    spec[:, hot] += _cspec(rng, (n_rx, int(hot.sum())), 3.0)  # ... and moving cells
    bg = _cspec(rng, shape)
    alpha, factor, rel = np.float32(0.02), 8.0, 0.05

    class Cfg:
        clutter_map_static_factor = factor
        clutter_map_static_rel = rel

    ref_map = ClutterMap.__new__(ClutterMap)
    ref_map.config, ref_map._prev = Cfg, prev.copy()
    d_ref = np.subtract(spec, bg) * alpha
    ref_map._hold_moving(spec, d_ref)
    prev_k, d_k = prev.copy(), np.empty(shape, np.complex64)
    k.update_hold_moving(spec, bg, prev_k, d_k, alpha, np.float32(factor), np.float32(rel ** 2),
                         np.empty((n_seg, n), np.float32), np.empty((n_seg, n), np.float32), np.empty(n, np.float32))
    assert np.array_equal(d_k, d_ref)
    assert np.array_equal(prev_k, ref_map._prev) and np.array_equal(prev_k, spec)


@pytest.mark.parametrize("n", [1, 7, 16, 17, 64, 257, 1024])
@pytest.mark.parametrize("seed", range(4))
def test_update_hold_moving_median_with_ties_and_zeros(n, seed):
    """The static test against the segment's median alone (factor 1, no own-energy term): a cell moves when its
    change exceeds the median, so the held cells show the median the kernel selected. Quantised spectra (ties in
    the change), cells unchanged since the last frame (change 0), some segments with half or all of them, and
    changes spread over many binades (every 8-bit digit of the float patterns in use)."""
    from edge.lane.clutter import ClutterMap

    k = require_kernel("_spectra")
    rng = np.random.default_rng(1000 + seed)
    n_rx, n_seg = 2, 4
    shape = (n_rx, n_seg, n)
    prev = np.round(_cspec(rng, shape) * 4) / 4
    step = np.round(_cspec(rng, shape) * 2) / 2 * (np.float32(10.0) ** rng.integers(-3, 4, shape)).astype(np.float32)
    spec = (prev + step).astype(np.complex64)
    still = rng.random((n_seg, n)) < [0.1, 0.5, 1.0, 0.0][seed % 4]
    spec[:, still] = prev[:, still]
    spec[:, 1, : n // 2] = prev[:, 1, : n // 2]  # segment 1: at least half of its cells unchanged
    bg = _cspec(rng, shape)
    alpha = np.float32(0.02)

    class Cfg:
        clutter_map_static_factor = 1.0
        clutter_map_static_rel = 0.0

    ref_map = ClutterMap.__new__(ClutterMap)
    ref_map.config, ref_map._prev = Cfg, prev.copy()
    d_ref = np.subtract(spec, bg) * alpha
    ref_map._hold_moving(spec, d_ref)
    prev_k, d_k = prev.copy(), np.empty(shape, np.complex64)
    change = np.empty((n_seg, n), np.float32)
    k.update_hold_moving(spec, bg, prev_k, d_k, alpha, np.float32(1.0), np.float32(0.0), change,
                         np.empty((n_seg, n), np.float32), np.empty(n, np.float32))
    assert np.array_equal(d_k.view(np.uint32), d_ref.view(np.uint32))
    med = np.partition(change, n // 2, axis=1)[:, n // 2]
    held = (d_k == 0).all(axis=0) & (spec != bg).any(axis=0)
    assert np.array_equal(held, (change > med[:, None]) & (spec != bg).any(axis=0))


def _channel_power(spec: np.ndarray) -> np.ndarray:
    """numpy reference of the channel sum: |spec|^2 summed over the receive channels, (seg, bin) float32."""
    sq = spec.view(np.float32).reshape(spec.shape + (2,)) ** 2
    return np.add.reduce(sq[..., 0] + sq[..., 1], axis=0)


def test_apply_map_and_channel_power_equal_numpy():
    k = require_kernel("_spectra")
    rng = np.random.default_rng(3)
    shape, h = (4, 4, 128), 10
    spec, bg, d = _cspec(rng, shape), _cspec(rng, shape), _cspec(rng, shape, 0.1)
    bg_ref = bg + d
    spec_ref = spec - bg_ref
    k.apply_map(spec, bg, d)
    assert np.array_equal(bg, bg_ref) and np.array_equal(spec, spec_ref)
    ref = _channel_power(spec)
    ppad = np.empty((4, 128 + 2 * h), np.float32)
    k.channel_power(spec, ppad, h)
    assert np.array_equal(ppad[:, h:-h], ref)
    assert np.array_equal(ppad[:, :h], ref[:, -h:]) and np.array_equal(ppad[:, -h:], ref[:, :h])


@pytest.mark.parametrize("shape", [(4, 4, 256), (1, 2, 7), (3, 1, 257), (2, 3, 66)])
def test_apply_map_power_equals_numpy(shape):
    """Four bins at a time and the remaining bins, one to four channels."""
    k = require_kernel("_spectra")
    rng = np.random.default_rng(4)
    h = min(12, shape[2] // 2)  # the circular padding needs h <= n
    spec, bg, d = _cspec(rng, shape), _cspec(rng, shape), _cspec(rng, shape, 0.1)
    bg_ref = bg + d
    spec_ref = spec - bg_ref
    ref = _channel_power(spec_ref)
    ppad = np.empty((shape[1], shape[2] + 2 * h), np.float32)
    k.apply_map_power(spec, bg, d, ppad, h)
    assert np.array_equal(bg, bg_ref) and np.array_equal(spec, spec_ref)
    assert np.array_equal(ppad, np.concatenate([ref[:, -h:], ref, ref[:, :h]], axis=1))


def test_spectra_stage_equals_numpy_on_recorded_frames(frames):
    """40 frames of highway4-traffic: the map's initial median, its warm-up and the static test, frame by frame."""
    require_kernel("_spectra")
    fast, ref = _lane(frames, True), _lane(frames, False)
    assert fast.spectra.kernel is not None and fast.clutter.kernel is not None
    fb = ref.feedback()
    for f in frames:
        a = fast.spectra(fast.spectra.to_complex(f), fb)
        b = ref.spectra(ref.spectra.to_complex(f), fb)
        assert np.array_equal(a.spec, b.spec)
        assert np.array_equal(a.power_padded, b.power_padded)
    assert np.array_equal(fast.clutter.background, ref.clutter.background)


def test_lane_pipeline_end_to_end_equal():
    """highway4-traffic, seed 1, 120 frames: identical detections, and the same confirmed tracks within 1e-9 (the
    tracker kernel rounds its small products differently from BLAS), with and without kernels."""
    require_kernel("_spectra")
    fr = synth_frames("simo", "highway4-traffic", 1, 120)
    cfg = load_config(env={})
    rep = compare(outputs("lane", fr, cfg, use_kernels=True), outputs("lane", fr, cfg, use_kernels=False))
    assert rep["detections"] > 500 and rep["confirmed_track_frames"] > 300
    assert agree(rep, atol=0.0), rep


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("n", [0, 1, 9, 40])
def test_static_residue_equals_numpy(seed, n):
    """``ClutterMap.static_residue`` with the kernel against its numpy form on random maps and pairings (peaks a
    little above, at and below the bound, echoes at and below the floor): bit for bit."""
    from edge.lane.clutter import ClutterMap
    from edge.pipelines.lane import LaneConfig

    rng = np.random.default_rng(seed)
    n_rx, n_seg, n_bin = 4, 4, 64
    cmap = ClutterMap(LaneConfig(), (n_rx, n_seg, n_bin), 0.03, [1.0, -1.0, 1.0, -1.0])
    cmap._background[...] = _cspec(rng, (n_rx, n_seg, n_bin), 3.0)
    cmap._background[:, :, ::5] = 0  # no echo
    bins = rng.integers(0, n_bin, (n, n_seg)).astype(np.int64)
    floor = rng.uniform(1.0, 20.0, n_seg).astype(np.float32)
    power = rng.uniform(0.0, 400.0, (n_seg, n_bin + 8)).astype(np.float32)[:, 4:-4]  # a view, as Spectra.power
    power[:, ::3] = 0.0
    k = cmap.kernel
    assert k is not None
    got = cmap.static_residue(bins, power, floor, 2.5)
    cmap.kernel = None
    want = cmap.static_residue(bins, power, floor, 2.5)
    cmap.kernel = k
    assert got.dtype == want.dtype == bool and got.shape == want.shape == (n,)
    np.testing.assert_array_equal(got, want)
    assert n < 40 or 0 < got.sum() < n  # both answers occur
    assert k.static_residue(cmap._background, bins - n_bin - 1, power, floor, 2.5, 4.0) is None or n == 0
    # the map of other strides (read through the numpy C API, as the memoryview did): the same answer
    wide = np.zeros((n_rx, n_seg, 2 * n_bin), np.complex64)
    wide[:, :, ::2] = cmap._background
    got2 = k.static_residue(wide[:, :, ::2], bins, power, floor, 2.5, 4.0)
    want2 = k.static_residue(cmap._background, bins, power, floor, 2.5, 4.0)
    assert got2.dtype == bool and got2.tobytes() == want2.tobytes()
    with pytest.raises(ValueError):
        k.static_residue(cmap._background.astype(np.complex128), bins, power, floor, 2.5, 4.0)


def _maps(shape, rng, init_frames):
    """A clutter map with the kernel and one without, in the same learnt state (previous frame, map, frame count)."""
    from edge.lane.clutter import ClutterMap
    from edge.pipelines.lane import LaneConfig

    cfg = LaneConfig(clutter_map_init_frames=init_frames)
    maps = [ClutterMap(cfg, shape, 0.033, [1.0, -1.0, 1.0, -1.0][: shape[1]]) for _ in range(2)]
    prev, bg = _cspec(rng, shape), _cspec(rng, shape)
    for m in maps:
        m._prev, m._background[...] = prev.copy(), bg
        m._map_init, m._map_frames = None, 200
    maps[1].kernel = None
    return maps


@settings(max_examples=30, deadline=None, derandomize=True)
@given(n_rx=st.integers(1, 5), n_seg=st.integers(1, 4), n=st.sampled_from([7, 16, 64, 257]),
       seed=st.integers(0, 2**16), moving_share=st.floats(0.0, 0.5), held=st.booleans())
def test_update_apply_power_equals_numpy(n_rx, n_seg, n, seed, moving_share, held):
    """``ClutterMap.subtract`` with the fused kernel (one segment's update in turn, its static test, cells held by
    standing tracks, subtraction, channel power) against its numpy form, bit for bit, frame by frame until every
    segment has learnt: the spectra, the map, the kept spectra and the padded power; one to five channels, bin counts
    with and without a remainder of four."""
    from edge.lane.records import Feedback

    rng = np.random.default_rng(seed)
    shape, h = (n_rx, n_seg, n), min(5, n)
    fast, ref = _maps(shape, rng, 16)
    cells = []
    if held:  # a standing track's bins, wrapping around the segment's end
        for k in range(n_seg):
            cells.append((k, np.arange(n - 2, n + rng.integers(1, 5)) % n))
    for m in (fast, ref):
        m._standing_cells = lambda fb: cells
    last = fast._prev.copy()
    for frame in range(n_seg + 1):
        turn = fast._turn
        assert turn == ref._turn == frame % n_seg
        spec = last + _cspec(rng, shape, 0.05)
        hot = rng.random((n_seg, n)) < moving_share
        spec[:, hot] += _cspec(rng, (n_rx, int(hot.sum())), 3.0)
        spec[:, :, ::6] = last[:, :, ::6]  # unchanged cells
        bg_before = ref.background.copy()
        ppad = np.full((n_seg, n + 2 * h), np.nan, np.float32)
        spec_k, spec_r = spec.copy(), spec.copy()
        assert fast.subtract(spec_k, Feedback.none(), ppad, h) is True
        assert ref.subtract(spec_r, Feedback.none(), None, h) is False
        assert np.array_equal(spec_k.view(np.uint32), spec_r.view(np.uint32))
        assert np.array_equal(fast.background.view(np.uint32), ref.background.view(np.uint32))
        others = np.arange(n_seg) != turn  # only the segment in turn learnt
        assert np.array_equal(ref.background[:, others], bg_before[:, others])
        for s in {turn, (turn + 1) % n_seg}:  # the kept spectra: this segment's and the next one's
            assert np.array_equal(fast._prev[:, s], spec[:, s]) and np.array_equal(ref._prev[:, s], spec[:, s])
        pw = _channel_power(spec_r)
        assert np.array_equal(ppad.view(np.uint32),
                              np.concatenate([pw[:, n - h:], pw, pw[:, :h]], axis=1).view(np.uint32))
        if held:  # the held cells kept the map as it was
            idx = cells[turn][1]
            assert np.array_equal(ref.background[:, turn, idx], bg_before[:, turn, idx])
        last = spec


def test_map_learns_one_segment_a_frame_with_their_weight():
    """Once started, each frame one segment learns, in turn, with the weight of as many frames as there are
    segments (the running mean's weight while it warms up): on a static scene, the numpy form and the kernel."""
    from edge.lane.clutter import ClutterMap
    from edge.lane.records import Feedback
    from edge.pipelines.lane import LaneConfig

    shape, h = (4, 4, 64), 3
    cfg = LaneConfig(clutter_map_init_frames=0)
    scene = _cspec(np.random.default_rng(3), shape, 2.0)
    for kernel in (True, False):
        m = ClutterMap(cfg, shape, 0.033, [1.0, -1.0, 1.0, -1.0])
        if not kernel:
            m.kernel = None
        m.subtract(scene.copy(), Feedback.none(), np.empty((4, 64 + 2 * h), np.float32) if kernel else None, h)
        assert m._map_frames == 1 and m._turn == 0  # the first frame: every segment, weight 1/warm-up
        w0 = 1.0 / cfg.clutter_map_warmup_frames
        np.testing.assert_allclose(m.background, scene * w0, rtol=1e-5)
        for frame in range(1, 9):
            before = m.background.copy()
            spec = scene.copy()
            m.subtract(spec, Feedback.none(), np.empty((4, 64 + 2 * h), np.float32) if kernel else None, h)
            s = (frame - 1) % 4
            w = min(1.0, 4.0 / (frame + cfg.clutter_map_warmup_frames))
            np.testing.assert_allclose(m.background[:, s], before[:, s] + w * (scene[:, s] - before[:, s]), rtol=1e-5)
            others = np.arange(4) != s
            assert np.array_equal(m.background[:, others], before[:, others])
            assert np.array_equal(spec, scene - m.background)


def test_update_apply_power_refuses_other_arrays():
    k = require_kernel("_spectra")
    shape = (4, 2, 16)
    c = lambda: np.zeros(shape, np.complex64)  # noqa: E731
    f = lambda *s: np.zeros(s, np.float32)  # noqa: E731
    args = [c(), c(), c(), 0.1, 8.0, 0.0025, None, f(2, 20), 2, f(2, 16), f(2, 16), f(16)]
    k.update_apply_power(*args)
    for i, bad in [(0, np.zeros(shape, np.complex128)), (1, c()[:, :, ::-1]), (2, c().T.copy().T),
                   (6, np.zeros((2, 16), bool)), (7, f(2, 19)), (11, f(15))]:
        a = list(args)
        a[i] = bad
        with pytest.raises((ValueError, TypeError)):
            k.update_apply_power(*a)
    for seg, keep in [(2, -1), (0, 2)]:  # segments outside the spectra
        with pytest.raises(ValueError):
            k.update_apply_power(*args, seg, keep)


@pytest.mark.parametrize("n", [255, 256, 257, 1024, 4099])
@pytest.mark.parametrize("pattern", ["random", "ties", "sample_large", "sample_small", "all_still"])
def test_update_apply_power_median_equals_numpy(n, pattern):
    """The fused kernel's segment median (a bracket from a sample of 64, Hoare's selection inside it, or on all the
    values when the bracket misses) against numpy's: the static test alone (factor 1, no own-energy term) on exact
    changes with ties and zeros, and with the sampled cells far above or below the others, so that the bracket
    misses."""
    from edge.lane.records import Feedback

    rng = np.random.default_rng(n)
    shape = (2, 3, n)
    fast, ref = _maps(shape, rng, 16)
    for m in (fast, ref):
        m.config = type(m.config)(**{**m.config.__dict__, "clutter_map_static_factor": 1.0,
                                     "clutter_map_static_rel": 0.0, "clutter_map_hold_speed_mps": 0.0})
    # quantised spectra: every sum of squares exact, whatever the order of summation
    prev = (np.round(_cspec(rng, shape) * 4) / 4).astype(np.complex64)
    fast._prev, ref._prev = prev.copy(), prev.copy()
    step = np.round(_cspec(rng, shape) * 2) / 2 if pattern == "ties" else np.round(_cspec(rng, shape) * 64) / 64
    if pattern == "all_still":
        step[:] = 0
    sampled = np.zeros(n, bool)
    if n >= 256:
        sampled[np.arange(64) * (n // 64) + n // 128] = True
    if pattern == "sample_large":  # the sampled cells change, the others stand still: the median is 0
        step[:, :, ~sampled] = 0
        step[:, :, sampled] *= 100
    elif pattern == "sample_small":  # the sampled cells stand still, the others change
        step[:, :, sampled] = 0
    spec = (prev + step).astype(np.complex64)
    h = 4
    ppad = np.empty((shape[1], n + 2 * h), np.float32)
    for seg in range(shape[1]):  # each segment in its turn, against the same last frame
        for m in (fast, ref):
            m._prev[:, seg] = prev[:, seg]
            m._turn = seg
        spec_k, spec_r = spec.copy(), spec.copy()
        prev_bg = fast.background.copy()
        assert fast.subtract(spec_k, Feedback.none(), ppad, h)
        ref.subtract(spec_r, Feedback.none(), None, h)
        assert np.array_equal(fast.background.view(np.uint32), ref.background.view(np.uint32))
        assert np.array_equal(spec_k.view(np.uint32), spec_r.view(np.uint32))
        # the held cells: those whose change exceeds the median (none when all stand still)
        held = np.all(fast.background[:, seg] == prev_bg[:, seg], axis=0) & np.any(spec[:, seg] != prev_bg[:, seg],
                                                                                    axis=0)
        assert (0 < np.count_nonzero(held) < held.size or pattern == "all_still"
                or (pattern.startswith("sample") and n < 256))


@settings(max_examples=25, deadline=None, derandomize=True)
@given(n_rx=st.integers(1, 4), n_seg=st.integers(1, 4), n=st.sampled_from([1, 2, 7, 48, 64, 1000, 1024]),
       seed=st.integers(0, 2**16))
def test_direct_fft_equals_scipy_fft(n_rx, n_seg, n, seed):
    """The transform the spectra stage calls without scipy.fft's dispatch gives scipy.fft.fft's spectrum bit for bit,
    in place."""
    from edge.lane.spectra import direct_fft

    c2c = direct_fft()
    assert c2c is not None
    x = _cspec(np.random.default_rng(seed), (n_rx, n_seg, n))
    want = scipy.fft.fft(x.copy(), axis=-1, overwrite_x=True, workers=1)
    y = x.copy()
    got = c2c(y, (-1,), True, 0, y, 1)
    assert got is y and got.dtype == want.dtype and got.shape == want.shape
    assert got.tobytes() == want.tobytes()


def test_direct_fft_declined_when_it_differs(monkeypatch):
    """scipy's pocketfft ``c2c`` is not called directly when scipy.fft.fft's spectrum of the probe differs from its own,
    or when the direct call fails."""
    from scipy.fft._pocketfft import pypocketfft

    from edge.lane.spectra import direct_fft

    fft = scipy.fft.fft
    monkeypatch.setattr(scipy.fft, "fft", lambda x, **kw: np.conj(fft(x, **kw)))  # another spectrum than c2c's
    assert direct_fft() is None
    monkeypatch.setattr(scipy.fft, "fft", fft)
    assert direct_fft() is not None
    real = pypocketfft.c2c

    def fails_in_place(a, axes, forward, inorm, out, nthreads):  # refuses the call without dispatch only
        if out is a:
            raise TypeError("no")
        return real(a, axes, forward, inorm, out, nthreads)

    monkeypatch.setattr(pypocketfft, "c2c", fails_in_place)
    assert direct_fft() is None


def test_spectra_stage_direct_fft_equals_scipy_fft(frames):
    """The stage's spectra with the direct transform and with scipy.fft.fft (``_c2c`` None, or an array other than the
    stage's buffer) are the same bits, frame by frame; without the kernels the stage calls scipy.fft.fft."""
    from edge.native.check import kernels

    fast, ref = _lane(frames, True), _lane(frames, True)
    ref.spectra._c2c = None
    assert fast.spectra._c2c is not None
    fb = ref.feedback()
    for k, f in enumerate(frames[:13]):
        iq = fast.spectra.to_complex(f)
        if k == 12:  # not the stage's buffer: scipy.fft.fft
            iq = iq.copy()
        a = fast.spectra(iq, fb)
        b = ref.spectra(ref.spectra.to_complex(f), fb)
        assert a.spec.tobytes() == b.spec.tobytes() and a.power_padded.tobytes() == b.power_padded.tobytes()
    with kernels(False):
        assert build_pipeline("lane", frames[0].frontend, load_config(env={})).spectra._c2c is None


def test_spectra_stage_calls_a_replaced_scipy_fft(frames, monkeypatch):
    """With scipy.fft.fft replaced in the stage's module (as tests/edge/lane_golden.py does to record the spectra),
    the stage calls the replacement, not the transform directly."""
    import types

    import edge.lane.spectra as spectra_mod

    pipe = _lane(frames, True)
    assert pipe.spectra._c2c is not None
    calls = []

    def fft(*a, **kw):
        calls.append(1)
        return scipy.fft.fft(*a, **kw)

    monkeypatch.setattr(spectra_mod, "scipy", types.SimpleNamespace(fft=types.SimpleNamespace(fft=fft)))
    pipe.spectra(pipe.spectra.to_complex(frames[0]), pipe.feedback())
    assert calls == [1]


@pytest.mark.parametrize("shape", [(4, 4, 64), (1, 1, 3), (3, 2, 7)])
def test_median_insert_equals_median_of_frames(shape):
    """The first frames' median a frame at a time (``median_insert``) against ``_median_of_frames`` on all the
    frames so far, bit for bit: odd and even counts, ties, NaN (the median NaN from then on), K values."""
    from edge.lane.clutter import _median_of_frames

    k = require_kernel("_spectra")
    rng = np.random.default_rng(shape[-1])
    n_frames = 16
    fr = _cspec(rng, (n_frames,) + shape, 2.0)
    fr[:, ..., 0] = np.floor(fr[:, ..., 0].real) + 0.5 + 1j * fr[:, ..., 0].imag  # ties among the frames, no zeros
    fr[5, 0, 0, -1] = np.nan + 1j
    buf = np.empty((2 * fr[0].size, n_frames), np.float32)
    out = np.empty(shape, np.complex64)
    for i in range(n_frames):
        k.median_insert(buf, i, fr[i], out)
        want = _median_of_frames(fr[:i + 1])
        assert out.tobytes() == want.tobytes(), i
        assert np.all(np.diff(buf[:, :i + 1], axis=1)[~np.isnan(buf[:, :i + 1]).any(axis=1)] >= 0)
    assert np.isnan(out[0, 0, -1].real) and not np.isnan(out[0, 0, -1].imag)
    k.median_insert(buf, 3, fr[0], None)  # without an output
    for bad in [(buf, n_frames, fr[0], out), (buf, -1, fr[0], out), (buf[:-1], 0, fr[0], out),
                (buf, 0, fr[0].astype(np.complex128), out), (buf, 0, fr[0], out[..., :-1]),
                (buf, 0, fr[0][..., ::-1], out)]:
        with pytest.raises(ValueError):
            k.median_insert(*bad)


@pytest.mark.parametrize("init_frames", [2, 3, 8])
def test_first_frames_median_from_the_kernel_equals_numpy(init_frames):
    """While the map keeps its first frames, ``static_residue`` reads their median from the third on and the map
    becomes their median at the last: kept sorted frame by frame by the kernel, the same bits as the numpy form's
    median of the kept frames (and the same spectra after the subtraction)."""
    from edge.lane.clutter import ClutterMap
    from edge.lane.records import Feedback
    from edge.pipelines.lane import LaneConfig

    shape = (4, 4, 64)
    cfg = LaneConfig(clutter_map_init_frames=init_frames)
    rng = np.random.default_rng(init_frames)
    scene = _cspec(rng, shape, 5.0)
    fast, ref = (ClutterMap(cfg, shape, 0.033, [1.0, -1.0, 1.0, -1.0]) for _ in range(2))
    ref.kernel = None
    bins = rng.integers(0, 64, (30, 4)).astype(np.int64)
    power = rng.uniform(0.0, 200.0, (4, 64)).astype(np.float32)
    floor = np.full(4, 2.0, np.float32)
    for i in range(init_frames + 2):
        spec = scene + _cspec(rng, shape, 0.5)
        a, b = spec.copy(), spec.copy()
        fast.subtract(a, Feedback.none(), None)
        ref.subtract(b, Feedback.none(), None)
        assert a.tobytes() == b.tobytes() and fast.background.tobytes() == ref.background.tobytes(), i
        if 3 <= i + 1 < init_frames:  # learning: the median so far
            assert fast._sorted is not None
            assert fast._init_median.tobytes() == _median_of_frames_of(ref).tobytes()
        got, want = fast.static_residue(bins, power, floor, 2.5), ref.static_residue(bins, power, floor, 2.5)
        assert np.array_equal(got, want), i
    assert fast._map_init is None and fast._sorted is None


def _median_of_frames_of(cmap):
    from edge.lane.clutter import _median_of_frames

    return _median_of_frames(cmap._map_init[:cmap._map_frames])
