"""The DBSCAN kernel (edge/native/_dbscan.pyx) against its numpy reference (CylinderDbscan.reference): the same points,
neighbour counts, core flags, cluster count and labels exactly, on random masks (blobs across the Doppler seam,
speckle, symmetric border-point ties, full-circle windows, a range-dependent M) and on hw_sim frames."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.dsp.dbscan import Clusters, CylinderDbscan
from edge.dsp.range_doppler import RangeDopplerProcessor
from hal.waveform import d2g_frontend
from tests.native.conftest import require_kernel

RDP = RangeDopplerProcessor(d2g_frontend())


def _db(eps=1.9, m=80, m_far=None, far_m=np.inf, n_range=None, n_doppler=None) -> CylinderDbscan:
    return CylinderDbscan(n_range or RDP.n_range, n_doppler or RDP.n_doppler_fft, RDP.range_bin_m,
                          RDP.cylinder_radius_kmh, eps, m, m_far, far_m)


def assert_same(a: Clusters, b: Clusters) -> None:
    for name in ("range_bin", "doppler_bin", "labels", "core", "neighbour_counts"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)
    assert a.n_clusters == b.n_clusters


def _blobs(rng: np.random.Generator, shape: tuple[int, int], n_blobs: int, noise: float) -> np.ndarray:
    nr, nd = shape
    i = np.arange(nr)[:, None]
    j = np.arange(nd)[None, :]
    mask = rng.random(shape) < noise
    for k in range(n_blobs):
        ci, cj = rng.integers(0, nr), (0 if k == 0 else rng.integers(0, nd))  # the first one across the seam
        a, b = rng.uniform(2, 25), rng.uniform(3, 40)
        dj = (j - cj + nd // 2) % nd - nd // 2
        mask |= ((i - ci) / a) ** 2 + (dj / b) ** 2 <= 1.0
        mask &= ~(rng.random(shape) < rng.uniform(0, 0.2))  # ragged interiors and borders
    return mask


def _check(db: CylinderDbscan, mask: np.ndarray) -> Clusters:
    assert db.kernel is not None
    got, ref = db.fit(mask), db.reference(mask)
    assert_same(got, ref)
    return ref


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("eps,m", [(1.9, 80), (0.7, 12), (3.0, 200), (1.2, 5)])
def test_kernel_equals_reference_on_random_masks(seed, eps, m):
    require_kernel("_dbscan")
    rng = np.random.default_rng(seed)
    ref = _check(_db(eps, m), _blobs(rng, (RDP.n_range, RDP.n_doppler_fft), int(rng.integers(1, 9)),
                                     float(rng.uniform(0, 0.02))))
    assert len(ref) > 0


def test_kernel_equals_reference_with_several_clusters_and_borders():
    """Seeds whose reference has clusters that come near each other (merged groups) and border points."""
    require_kernel("_dbscan")
    n_multi = n_border = 0
    for seed in range(40):
        rng = np.random.default_rng(1000 + seed)
        ref = _check(_db(1.2, 30), _blobs(rng, (RDP.n_range, RDP.n_doppler_fft), 8, 0.01))
        n_multi += ref.n_clusters > 1
        n_border += int(np.count_nonzero(~ref.core & (ref.labels >= 0)))
    assert n_multi >= 10 and n_border >= 100


def test_kernel_equals_reference_with_far_min_points():
    require_kernel("_dbscan")
    for seed in range(6):
        rng = np.random.default_rng(50 + seed)
        _check(_db(1.9, 80, 40, 12.0), _blobs(rng, (RDP.n_range, RDP.n_doppler_fft), 6, 0.005))


def test_full_circle_windows():
    """eps wider than the cylinder's diameter: the nearest rows' windows hold the whole Doppler circle."""
    require_kernel("_dbscan")
    db = _db(4.0, 60)
    assert db._lo is not None and np.any(db._lo + db._hi + 1 >= db.n_doppler)
    for seed in range(4):
        _check(db, _blobs(np.random.default_rng(seed), (RDP.n_range, RDP.n_doppler_fft), 4, 0.01))


def test_equidistant_border_point_goes_to_the_smaller_cluster_id():
    """A non-core bin halfway between two separate core blocks (same distance to both): the smaller id, both ways."""
    require_kernel("_dbscan")
    db = _db(0.4, 9, n_range=40, n_doppler=64)  # eps ~ 4.3 range bins
    mask = np.zeros((40, 64), dtype=bool)
    mask[5:10, 10:13] = True  # block A, rows 5..9
    mask[17:22, 10:13] = True  # block B, rows 17..21: 8 bins from A
    mask[13, 11] = True  # halfway: 4 range bins from each block's nearest row
    ref = _check(db, mask)
    k = int(np.flatnonzero((ref.range_bin == 13) & (ref.doppler_bin == 11))[0])
    assert ref.n_clusters == 2 and not ref.core[k] and ref.labels[k] == 0
    _check(db, mask[::-1].copy())


@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1), density=st.floats(0.02, 0.6), eps=st.floats(0.7, 2.5), m=st.integers(1, 40))
def test_kernel_equals_reference_hypothesis(seed, density, eps, m):
    """Small maps of dense random speckle: many groups, seams, ties and border points."""
    require_kernel("_dbscan")
    rng = np.random.default_rng(seed)
    nr, nd = int(rng.integers(8, 40)), int(rng.choice([16, 32, 64]))
    _check(_db(eps, m, n_range=nr, n_doppler=nd), rng.random((nr, nd)) < density)


def test_eps_narrower_than_a_lattice_diagonal_runs_the_reference():
    """The kernel joins 8-neighbour core bins (across the seam too), so it runs only when they are within eps."""
    db = _db(0.25, 1, n_range=35, n_doppler=32)  # one Doppler bin is 0.33 km/h on the cylinder
    assert db.kernel is None
    mask = np.random.default_rng(0).random((35, 32)) < 0.5
    assert_same(db.fit(mask), db.reference(mask))


def test_empty_and_all_noise():
    require_kernel("_dbscan")
    db = _db()
    _check(db, np.zeros((RDP.n_range, RDP.n_doppler_fft), dtype=bool))
    mask = np.zeros((RDP.n_range, RDP.n_doppler_fft), dtype=bool)
    mask[::17, ::13] = True
    ref = _check(db, mask)
    assert ref.n_clusters == 0


def test_kernel_equals_reference_on_simulated_frames():
    """Recorded input: hw_sim frames of Tavanti's test 1 through the surveillance pipeline's front end."""
    require_kernel("_dbscan")
    from edge.bench import board_of, synth_frames
    from edge.config import load_config
    from edge.dsp.range_doppler import detection_mask
    from edge.pipelines.surveillance import SurveillancePipeline
    from edge.dsp.range_fft import to_complex64

    frames = synth_frames(board_of("surveillance"), "tavanti-test1", 1, 60)
    cfg = load_config(env={})
    pipe = SurveillancePipeline.from_config(frames[0].frontend, cfg)
    sc = cfg.section("pipeline.surveillance")
    n_pts = n_clu = 0
    for f in frames[20:60:2]:
        m = pipe.rd.process(to_complex64(f)).amplitude
        ref = _check(pipe.dbscan, detection_mask(m, sc.th_rd, sc.sidelobe_guard_db))
        n_pts += len(ref)
        n_clu += ref.n_clusters
    assert n_pts > 1000 and n_clu > 5


def test_stage_with_kernel_deep_copies_and_pickles():
    import copy
    import pickle

    require_kernel("_dbscan")
    db = _db()
    mask = _blobs(np.random.default_rng(3), (RDP.n_range, RDP.n_doppler_fft), 3, 0.005)
    for other in (copy.deepcopy(db), pickle.loads(pickle.dumps(db))):
        assert other.kernel is db.kernel
        assert_same(other.fit(mask), db.fit(mask))
