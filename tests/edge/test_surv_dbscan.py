"""Cylinder DBSCAN: same labels as scikit-learn's DBSCAN on the same 3-D points (up to permutation)."""

from __future__ import annotations

import numpy as np
import pytest

sklearn_cluster = pytest.importorskip("sklearn.cluster")
from scipy.spatial import cKDTree  # noqa: E402

from edge.dsp.dbscan import CylinderDbscan, centroids  # noqa: E402
from edge.dsp.range_doppler import RangeDopplerProcessor  # noqa: E402
from hal.waveform import d2g_frontend  # noqa: E402

RDP = RangeDopplerProcessor(d2g_frontend())


def _db(eps=1.9, m=80) -> CylinderDbscan:
    return CylinderDbscan(RDP.n_range, RDP.n_doppler_fft, RDP.range_bin_m, RDP.cylinder_radius_kmh, eps, m)


def _blob_mask(seed: int, n_blobs: int = 6, noise: float = 0.004) -> np.ndarray:
    """Elliptic blobs of random size (one across the Doppler seam), plus speckle."""
    rng = np.random.default_rng(seed)
    i = np.arange(RDP.n_range)[:, None]
    j = np.arange(RDP.n_doppler_fft)[None, :]
    mask = rng.random((RDP.n_range, RDP.n_doppler_fft)) < noise
    centres = [(rng.integers(0, 256), 0)] + [(rng.integers(0, 256), rng.integers(0, 256)) for _ in range(n_blobs - 1)]
    for ci, cj in centres:
        a, b = rng.uniform(3, 25), rng.uniform(5, 40)
        dj = (j - cj + 128) % 256 - 128
        mask |= ((i - ci) / a) ** 2 + (dj / b) ** 2 <= 1.0
        mask &= ~(rng.random(mask.shape) < 0.05)  # ragged interiors and borders
    return mask


def _compare(db: CylinderDbscan, mask: np.ndarray) -> tuple[int, int]:
    res = db.fit(mask)
    x = db.coordinates(res.range_bin, res.doppler_bin)
    sk = sklearn_cluster.DBSCAN(eps=db.eps, min_samples=db.min_samples).fit(x)
    core_sk = np.zeros(len(x), dtype=bool)
    core_sk[sk.core_sample_indices_] = True
    np.testing.assert_array_equal(res.core, core_sk)
    np.testing.assert_array_equal(res.labels == -1, sk.labels_ == -1)
    # core points: a bijection between the two labellings
    a, b = res.labels[res.core], sk.labels_[res.core]
    pairs = set(zip(a.tolist(), b.tolist()))
    assert len(pairs) == len(set(a.tolist())) == len(set(b.tolist())) == res.n_clusters
    mapping = dict(pairs)
    # border points: identical unless they are within eps of cores of two clusters (then either is right)
    border = (~res.core) & (res.labels >= 0)
    tree = cKDTree(x[res.core])
    ambiguous = 0
    for k in np.flatnonzero(border):
        near = set(res.labels[res.core][tree.query_ball_point(x[k], db.eps)].tolist())
        assert res.labels[k] in near
        if len(near) == 1:
            assert mapping[res.labels[k]] == sk.labels_[k]
        else:
            ambiguous += 1
    return res.n_clusters, ambiguous


def _no_ties(db: CylinderDbscan) -> None:
    """The lattice has no pair distance within 1e-6 of eps (float rounding could flip <= eps)."""
    di = np.arange(0, 60)[:, None] * db.range_bin_m
    dj = 2 * db.radius_kmh * np.sin(np.pi * np.arange(256)[None, :] / 256)
    assert np.min(np.abs(np.hypot(di, dj) - db.eps)) > 1e-6


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("eps,m", [(1.9, 80), (0.7, 12), (3.0, 200)])
def test_labels_equal_sklearn(seed, eps, m):
    db = _db(eps, m)
    _no_ties(db)
    n, _ = _compare(db, _blob_mask(seed))
    assert n >= 1


def test_seam_split_cluster_is_rejoined():
    mask = np.zeros((256, 256), dtype=bool)
    mask[100:120, :30] = True
    mask[100:120, -30:] = True  # the same target split at +-v_max
    res = _db().fit(mask)
    assert res.n_clusters == 1 and (res.labels == 0).all()


def test_two_separate_targets_two_clusters_and_centroids():
    mask = np.zeros((256, 256), dtype=bool)
    mask[40:60, 20:60] = True
    mask[150:170, 150:190] = True
    db = _db()
    res = db.fit(mask)
    assert res.n_clusters == 2
    c, cnt = centroids(db.coordinates(res.range_bin, res.doppler_bin), res.labels, res.n_clusters, db.radius_kmh)
    assert sorted(cnt.tolist()) == [800, 800]
    assert sorted((c[:, 2] / RDP.range_bin_m).tolist()) == pytest.approx([49.5, 159.5], abs=1e-3)


def test_neighbour_counts_brute_force():
    db = _db(1.2, 5)
    mask = _blob_mask(5, n_blobs=3)
    counts = db.neighbour_counts(mask)
    ri, dj = np.nonzero(mask)
    x = db.coordinates(ri, dj)
    brute = np.array([len(v) for v in cKDTree(x).query_ball_point(x, db.eps)])
    np.testing.assert_array_equal(counts[ri, dj], brute)


def test_empty_and_all_noise():
    db = _db()
    assert db.fit(np.zeros((256, 256), dtype=bool)).n_clusters == 0
    sparse = np.zeros((256, 256), dtype=bool)
    sparse[::40, ::40] = True
    res = db.fit(sparse)
    assert res.n_clusters == 0 and (res.labels == -1).all()


def test_simulated_frame_equals_sklearn():
    from hw_sim.boards import D2G_BOARD
    from hw_sim.scenario import load_scenario
    from hw_sim.simulator import FrameSimulator

    sc = load_scenario("tavanti-test3")
    sim = FrameSimulator(D2G_BOARD, sc.build_scene(1), 1)
    f = sim.frame(20)  # jogger and motorcycle both in view
    m = RDP.process((f.i + 1j * f.q).astype(np.complex64)).amplitude
    n, _ = _compare(_db(), m >= 2.0)
    assert n >= 1


def test_range_dependent_min_points_is_dbscan_with_each_m_on_its_side():
    """``min_samples_far`` from ``far_range_m`` on: points all nearer are clustered as DBSCAN with M,
    points all beyond as DBSCAN with M_far (scikit-learn), and a weak far blob that M = 80 leaves as
    noise is a cluster with M_far = 40."""
    far_bin = 128  # 12 m
    db2 = CylinderDbscan(RDP.n_range, RDP.n_doppler_fft, RDP.range_bin_m, RDP.cylinder_radius_kmh, 1.9, 80,
                         min_samples_far=40, far_range_m=far_bin * RDP.range_bin_m)
    for seed in (3, 4):
        mask = _blob_mask(seed, n_blobs=10)
        near, far = mask.copy(), mask.copy()
        near[far_bin - 25:] = False  # eps (1.9 m) is 20 range bins: no neighbour across the boundary
        far[: far_bin + 25] = False
        _compare(db2, near)  # db2.min_samples = 80
        _compare(_db(m=40), far)
        np.testing.assert_array_equal(db2.fit(far).labels, _db(m=40).fit(far).labels)
    weak = np.zeros((RDP.n_range, RDP.n_doppler_fft), dtype=bool)
    weak[200:206, 100:110] = True  # 60 cells at 19 m
    assert _db(m=80).fit(weak).n_clusters == 0
    assert db2.fit(weak).n_clusters == 1
