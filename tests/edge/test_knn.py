"""Weighted k-NN (Tavanti eqs. 20-21) against scikit-learn, numpy and a brute-force oracle."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from edge.classify.features import weighted_standardization
from edge.classify.knn import METRICS, WeightedKNN, class_balanced_weights, pairwise_distances

sk_neighbors = pytest.importorskip("sklearn.neighbors")
sk_pre = pytest.importorskip("sklearn.preprocessing")

CLASSES = ("pedestrian", "car", "motorcycle", "truck")
SK_METRIC = {"euclidean": "euclidean", "manhattan": "manhattan", "chebyshev": "chebyshev"}


def blobs(rng, counts, f=5, spread=1.5):
    centers = rng.normal(0, 2.0, size=(len(counts), f))
    x = np.concatenate([centers[c] + spread * rng.normal(size=(n, f)) * rng.uniform(0.5, 2, f) for c, n in enumerate(counts)])
    y = np.concatenate([np.full(n, c) for c, n in enumerate(counts)])
    scale = np.array([1e-2, 1e-4, 1e3, 1e6, 10.0])[:f]  # wildly different feature units
    return x * scale + 5.0, y


@pytest.mark.parametrize("metric", METRICS)
def test_balanced_reference_equals_sklearn_pipeline(metric):
    """Equal class counts: the eq. 21 weights are equal, eq. 20 is StandardScaler up to one common
    factor (ddof), so the predictions equal StandardScaler + KNeighborsClassifier(k=13, uniform)."""
    rng = np.random.default_rng(11)
    x, y = blobs(rng, [40, 40, 40, 40])
    q, _ = blobs(np.random.default_rng(12), [25, 25, 25, 25])
    ours = WeightedKNN(CLASSES, k=13, metric=metric).fit(x, y)
    sc = sk_pre.StandardScaler().fit(x)
    sk = sk_neighbors.KNeighborsClassifier(n_neighbors=13, weights="uniform", algorithm="brute",
                                           metric=SK_METRIC[metric]).fit(sc.transform(x), y)
    p_ours = ours.predict_proba(q)
    p_sk = sk.predict_proba(sc.transform(q))
    np.testing.assert_allclose(p_ours, p_sk, atol=1e-12)
    np.testing.assert_array_equal(ours.predict(q), np.argmax(p_sk, axis=1))
    _, idx_sk = sk.kneighbors(sc.transform(q))
    _, idx = ours.kneighbors(q)
    np.testing.assert_array_equal(np.sort(idx, axis=1), np.sort(idx_sk, axis=1))


@pytest.mark.parametrize("metric", METRICS)
def test_unbalanced_reference_weighted_vote_over_sklearn_neighbours(metric):
    """Unbalanced classes (the paper's 88/31/7/56): eq. 21 with class-balancing weights equals the
    weighted vote over scikit-learn's neighbours in the eq.-20-standardised space."""
    rng = np.random.default_rng(5)
    x, y = blobs(rng, [31, 88, 56, 7])
    q, _ = blobs(np.random.default_rng(6), [10, 10, 10, 10])
    ours = WeightedKNN(CLASSES, k=13, metric=metric).fit(x, y)
    w = class_balanced_weights(y, 4)
    nn = sk_neighbors.NearestNeighbors(n_neighbors=13, algorithm="brute", metric=SK_METRIC[metric]).fit(ours.z_)
    _, idx = nn.kneighbors(ours.standardize(q))
    want = np.stack([np.bincount(y[i], weights=w[i], minlength=4) / w[i].sum() for i in idx])
    np.testing.assert_allclose(ours.predict_proba(q), want, atol=1e-12)
    # the weights really matter here: the 7 trucks weigh as much as the 88 cars
    unif = WeightedKNN(CLASSES, k=13, metric=metric).fit(x, y, "uniform")
    assert not np.allclose(unif.predict_proba(q), want)


def test_class_balanced_weights():
    y = np.array([0, 0, 0, 1, 2, 2])
    w = class_balanced_weights(y, 4)  # class 3 absent: three classes present
    np.testing.assert_allclose(w, [1 / 9, 1 / 9, 1 / 9, 1 / 3, 1 / 6, 1 / 6])
    assert w.sum() == pytest.approx(1.0)


def test_weighted_standardisation_equals_numpy_reliability_weights():
    """Eq. 20's scale is numpy's weighted covariance with aweights (unbiased, 1 - sum w^2)."""
    rng = np.random.default_rng(2)
    x = rng.normal(size=(30, 5)) * [1, 10, 100, 0.1, 3]
    w = rng.uniform(0.1, 3, 30)
    mean, scale = weighted_standardization(x, w)
    np.testing.assert_allclose(mean, np.average(x, axis=0, weights=w), rtol=1e-12)
    np.testing.assert_allclose(scale, np.sqrt(np.diag(np.cov(x.T, aweights=w))), rtol=1e-12)
    # a constant feature gets scale 1, not a division by zero
    x[:, 2] = 4.0
    _, scale = weighted_standardization(x, w)
    assert scale[2] == 1.0


def test_weighted_standardisation_does_not_depend_on_the_summation_order():
    """Exactly rounded sums: the rows in any order give the same bits (a BLAS dot product's order follows
    the CPU's kernel, and the shipped ONNX model differed in the last bit of its mean between machines)."""
    rng = np.random.default_rng(5)
    x = rng.lognormal(size=(990, 11)) * rng.uniform(0.01, 1e4, 11)
    w = rng.uniform(0.1, 3, 990)
    mean, scale = weighted_standardization(x, w)
    for seed in range(5):
        p = np.random.default_rng(seed).permutation(990)
        m2, s2 = weighted_standardization(x[p], w[p])
        assert mean.tobytes() == m2.tobytes() and scale.tobytes() == s2.tobytes()


@pytest.mark.parametrize("metric", METRICS)
def test_distances_match_scipy(metric):
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(7, 5)), rng.normal(size=(11, 5))
    name = {"manhattan": "cityblock"}.get(metric, metric)
    np.testing.assert_allclose(pairwise_distances(a, b, metric), cdist(a, b, name), rtol=1e-12)


def _oracle(z, y, w, q, k, n_classes):
    """Brute force in plain Python: sort by (distance, index), weighted vote, first maximum."""
    d = [float(np.sqrt(((q - zl) ** 2).sum())) for zl in z]
    nn = sorted(range(len(z)), key=lambda l: (d[l], l))[:k]
    num = [sum(w[l] for l in nn if y[l] == c) for c in range(n_classes)]
    den = sum(w[l] for l in nn)
    p = [n / den for n in num]
    return nn, p, max(range(n_classes), key=lambda c: (p[c], -c))


def test_distance_ties_go_to_the_lower_reference_index():
    # integer grid: many exactly equal distances; the k-th slot falls inside a tie
    z = np.array([[0, 0], [1, 0], [0, 1], [-1, 0], [0, -1], [1, 1], [2, 0]], dtype=float)
    y = np.array([0, 1, 2, 3, 0, 1, 2])
    knn = WeightedKNN(CLASSES, k=3).fit(z, y, "uniform")
    knn.mean_, knn.scale_ = np.zeros(2), np.ones(2)  # query directly in the standardised space
    knn.z_ = z
    q = np.array([[0.0, 0.0]])
    _, idx = knn.kneighbors(q)
    assert idx.tolist() == [[0, 1, 2]]  # 1, 2, 3, 4 tie at distance 1: the lower indices win
    nn, p, c = _oracle(z, y, knn.w_, q[0], 3, 4)
    assert idx[0].tolist() == nn
    np.testing.assert_allclose(knn.predict_proba(q)[0], p)
    assert knn.predict(q)[0] == c == 0  # 1/3 each for classes 0, 1, 2: the lower class wins


def test_random_ties_against_brute_force_oracle():
    rng = np.random.default_rng(9)
    for trial in range(60):
        n = int(rng.integers(5, 40))
        z = rng.integers(-2, 3, size=(n, 3)).astype(float)  # coarse grid: duplicates and ties
        y = rng.integers(0, 4, size=n)
        w = rng.integers(1, 4, size=n).astype(float)
        w /= w.sum()
        k = int(rng.integers(1, n + 1))
        knn = WeightedKNN(CLASSES, k=k).fit(z, y, w)
        knn.mean_, knn.scale_, knn.z_ = np.zeros(3), np.ones(3), z
        for q in rng.integers(-2, 3, size=(5, 3)).astype(float):
            nn, p, c = _oracle(z, y, knn.w_, q, k, 4)
            _, idx = knn.kneighbors(q[None])
            assert idx[0].tolist() == nn, trial
            np.testing.assert_allclose(knn.predict_proba(q[None])[0], p, atol=1e-12)
            assert knn.predict(q[None])[0] == c


def test_fit_validation():
    knn = WeightedKNN(CLASSES)
    with pytest.raises(ValueError):
        knn.fit(np.zeros((3, 5)), np.array([0, 1, 4]))
    with pytest.raises(ValueError):
        knn.fit(np.full((3, 5), np.nan), np.array([0, 1, 2]))
    with pytest.raises(ValueError):
        WeightedKNN(CLASSES, metric="cosine")
    with pytest.raises(RuntimeError):
        WeightedKNN(CLASSES).predict(np.zeros((1, 5)))


def test_grid_search_cv_scores_equal_sklearn_cross_validation():
    """Uniform weights: our 3-fold CV table equals scikit-learn's StandardScaler + k-NN on the same folds."""
    from sklearn.model_selection import cross_val_score
    from sklearn.pipeline import make_pipeline

    from edge.classify.train import grid_search, stratified_folds

    rng = np.random.default_rng(21)
    x, y = blobs(rng, [20, 30, 25, 12], spread=3.0)
    folds = stratified_folds(y, 3, seed=1)
    assert sorted(np.concatenate(folds).tolist()) == list(range(y.size))
    for f in folds:  # stratified: every class in every fold
        assert set(y[f].tolist()) == {0, 1, 2, 3}
    cv = [(np.setdiff1d(np.arange(y.size), f), f) for f in folds]
    res = grid_search(x, y, CLASSES, ks=range(1, 31), seed=1, weighting="uniform", score="accuracy")
    for metric in METRICS:
        for k in (1, 4, 13, 30):
            pipe = make_pipeline(sk_pre.StandardScaler(), sk_neighbors.KNeighborsClassifier(
                n_neighbors=k, algorithm="brute", metric=SK_METRIC[metric]))
            want = cross_val_score(pipe, x, y, cv=cv).mean()
            got = res.scores[metric][k - 1]
            # vote ties go to the lower class index in both (argmax / mode): scores equal exactly
            assert got == pytest.approx(want, abs=1e-12), (metric, k)
    best = max((res.scores[m].max(), m) for m in METRICS)
    assert res.score == pytest.approx(best[0])


def test_grid_search_finds_the_informative_k():
    """Two well-separated classes with 10 % label noise: k = 1 memorises the noise, larger k wins."""
    from edge.classify.train import grid_search

    rng = np.random.default_rng(8)
    x = np.concatenate([rng.normal(0, 1, (60, 5)), rng.normal(3, 1, (60, 5))])
    y = np.repeat([0, 1], 60)
    flip = rng.choice(120, 12, replace=False)
    y[flip] = 1 - y[flip]
    res = grid_search(x, y, CLASSES[:2], ks=range(1, 21), seed=0)
    assert res.k > 1 and res.score > 0.8
    assert res.scores["euclidean"][0] < res.score
