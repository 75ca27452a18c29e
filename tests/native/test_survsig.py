"""The surveillance signature kernel (edge/native/_survsig.pyx) against the numpy reference
(SignatureExtractor with ``kernel = None``): every field of the ClusterSignatures bit for bit, on random points
(hypothesis, seeded) and on the points of recorded tavanti-test1 frames."""

from __future__ import annotations

import copy
import pickle

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.classify.features import FeatureConfig, MapPoints, SignatureExtractor
from hal.waveform import d2g_frontend
from tests.native.conftest import require_kernel

FIELDS = ("centroid", "range_m", "circular_variance", "rcs", "n_points", "doppler_kmh", "cos_sum", "sin_sum",
          "range_lo_m", "range_hi_m", "body_lo_m", "body_hi_m")


def _pair(gate_kmh: float = 1.0):
    fast = SignatureExtractor(FeatureConfig(extent_doppler_kmh=gate_kmh), d2g_frontend())
    slow = copy.copy(fast)
    slow.kernel = None
    return fast, slow


def assert_same(fast: SignatureExtractor, slow: SignatureExtractor, pts: MapPoints, n_clusters=None) -> None:
    assert fast.kernel is not None
    a, b = fast(pts, n_clusters), slow(pts, n_clusters)
    for name in FIELDS:
        x, y = np.asarray(getattr(a, name)), np.asarray(getattr(b, name))
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name, strict=True)


def _random_points(rng: np.random.Generator, n: int, n_clusters: int) -> MapPoints:
    nd = 256
    rb = rng.integers(0, 256, n).astype(np.int32)
    db = rng.integers(0, nd, n).astype(np.int32)
    # unique cells, as on a map
    key = np.unique(rb.astype(np.int64) * nd + db)
    rng.shuffle(key)
    rb, db = (key // nd).astype(np.int32), (key % nd).astype(np.int32)
    lab = rng.integers(-1, max(n_clusters, 1), key.size).astype(np.int32)
    amp = rng.choice(np.array([1.0, 2.0, 4.0, 8.5], dtype=np.float32), key.size) if rng.random() < 0.3 else \
        rng.uniform(2.0, 300.0, key.size).astype(np.float32)  # ties in the first case
    vmax = 5.35
    dop = ((db - nd // 2) * (2 * vmax / nd)).astype(np.float32)
    return MapPoints((rb * 0.0938).astype(np.float32), dop, amp, rb, db, lab)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.integers(0, 3000), st.integers(0, 12), st.sampled_from([0.0, 0.3, 1.0, 3.0]))
def test_kernel_equals_reference_on_random_points(seed, n, n_clusters, gate_kmh):
    require_kernel("_survsig")
    fast, slow = _pair(gate_kmh)
    pts = _random_points(np.random.default_rng(seed), n, n_clusters)
    assert_same(fast, slow, pts)
    assert_same(fast, slow, pts, n_clusters + 2)  # clusters without cells: NaN rows, as the reference


def test_kernel_equals_reference_on_recorded_frames():
    require_kernel("_survsig")
    from edge.bench import build_pipeline, synth_frames
    from edge.config import load_config
    from edge.pipeline import StageTimer

    frames = synth_frames("d2g", "tavanti-test1", 1, 120)
    pipe = build_pipeline("surveillance", frames[0].frontend, load_config(env={}))
    fast, slow = _pair()
    seen = []
    update = pipe.tracker.update

    def record(t_ns, pts, **kw):
        seen.append(pts)
        return update(t_ns, pts, **kw)

    pipe.tracker.update = record
    timer = StageTimer(16)
    for f in frames:
        pipe.process(f, timer)
    assert sum(p.n_clusters for p in seen) > 80
    for pts in seen:
        assert_same(fast, slow, pts)


def test_extractor_with_kernel_copies_and_pickles():
    require_kernel("_survsig")
    fast, _ = _pair()
    for other in (copy.deepcopy(fast), pickle.loads(pickle.dumps(fast))):
        assert other.kernel is fast.kernel


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.integers(0, 2**31 - 1), st.integers(1, 400), st.integers(1, 6), st.booleans())
def test_kernel_equals_reference_on_dense_boxes(seed, n, n_clusters, offset):
    """Cells packed in a small (range, Doppler) box, some given twice, amplitude ties, labels beyond ``n_clusters``
    and noise: the selection of eq. 17's cells (range neighbours of the same cluster) is exercised everywhere."""
    require_kernel("_survsig")
    fast, slow = _pair()
    rng = np.random.default_rng(seed)
    rb = (rng.integers(0, 12, n) + (40 if offset else 0)).astype(np.int32)
    db = rng.integers(0, 9, n).astype(np.int32)
    lab = rng.integers(-1, n_clusters + 2, n).astype(np.int32)
    amp = rng.choice(np.array([1.0, 2.0, 4.0], dtype=np.float32), n)
    dop = ((db - 128) * (2 * 5.35 / 256)).astype(np.float32)
    pts = MapPoints((rb * 0.0938).astype(np.float32), dop, amp, rb, db, lab)
    assert_same(fast, slow, pts)
    assert_same(fast, slow, pts, n_clusters)  # labels n_clusters and above are not clusters here


def test_kernel_negative_bins_and_all_noise_fall_back():
    require_kernel("_survsig")
    fast, slow = _pair()
    f = np.array([1.0, 1.1, 1.2], dtype=np.float32)
    for rb, lab in (([-1, 0, 1], [0, 0, 1]), ([3, 4, 5], [-1, -1, -1])):
        pts = MapPoints(f, f, f, np.array(rb, dtype=np.int32), np.array([0, 0, 0], dtype=np.int32),
                        np.array(lab, dtype=np.int32))
        assert_same(fast, slow, pts, 2)
