"""Hyper-parameter search for the weighted k-NN (Tavanti §III-C), numpy only.

The paper selects ``k`` in ``[1, 50]`` and the metric in {Euclidean, Manhattan, Chebyshev} by a full
grid search with 3-fold cross-validation on its reference set (result: ``k = 13``, Euclidean).
:func:`grid_search` does the same with stratified, seeded folds. Within a fold the standardisation
(eq. 20) and the weights (eq. 21) are fitted on the training part only. All ``k`` of a metric are
scored from one stable sort of the distances (cumulative weighted votes), so the full grid costs a
few milliseconds for a few hundred observations.

The score is the balanced accuracy (mean per-class recall) by default, consistent with the
class-balancing weights; plain accuracy is available. Ties go to the smaller ``k``, then to the
metric listed first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge.classify.knn import METRICS, WeightedKNN, pairwise_distances

__all__ = ["GridSearchResult", "grid_search", "stratified_folds"]


def stratified_folds(labels: np.ndarray, n_folds: int = 3, seed: int = 0) -> list[np.ndarray]:
    """Test-index arrays of ``n_folds`` folds; each class is shuffled (seeded) and dealt round-robin."""
    y = np.asarray(labels, dtype=np.intp)
    rng = np.random.default_rng(seed)
    fold_of = np.empty(y.size, dtype=np.intp)
    offset = 0
    for c in np.unique(y):
        idx = np.flatnonzero(y == c)
        rng.shuffle(idx)
        fold_of[idx] = (np.arange(idx.size) + offset) % n_folds
        offset += idx.size  # continue dealing where the previous class stopped: balanced fold sizes
    return [np.flatnonzero(fold_of == f) for f in range(n_folds)]


@dataclass(frozen=True)
class GridSearchResult:
    k: int
    metric: str
    score: float
    scores: dict[str, np.ndarray]  # metric -> (len(ks),) mean CV score
    ks: np.ndarray
    score_name: str


def _score(pred: np.ndarray, truth: np.ndarray, n_classes: int, balanced: bool) -> np.ndarray:
    """``pred`` (K, Q) vs ``truth`` (Q,) -> (K,) scores."""
    ok = pred == truth[None, :]
    if not balanced:
        return ok.mean(axis=1)
    rec = [ok[:, truth == c].mean(axis=1) for c in range(n_classes) if np.any(truth == c)]
    return np.mean(rec, axis=0)


def grid_search(
    features: np.ndarray,
    labels: np.ndarray,
    classes: tuple[str, ...],
    *,
    ks=range(1, 51),
    metrics: tuple[str, ...] = METRICS,
    n_folds: int = 3,
    seed: int = 0,
    weighting: str = "balanced",
    score: str = "balanced_accuracy",
) -> GridSearchResult:
    """Mean ``n_folds``-fold CV score for every ``(k, metric)``; returns the best and the table."""
    if score not in ("balanced_accuracy", "accuracy"):
        raise ValueError(f"score must be 'balanced_accuracy' or 'accuracy', got {score!r}")
    x = np.asarray(features, dtype=np.float64)
    y = np.asarray(labels, dtype=np.intp)
    ks = np.asarray(list(ks), dtype=np.intp)
    C = len(classes)
    folds = stratified_folds(y, n_folds, seed)
    table = {m: np.zeros(ks.size) for m in metrics}
    for test in folds:
        train = np.setdiff1d(np.arange(y.size), test)
        knn = WeightedKNN(classes, k=1).fit(x[train], y[train], weighting)
        zq = knn.standardize(x[test])
        for m in metrics:
            d = pairwise_distances(zq, knn.z_, m)
            order = np.argsort(d, axis=1, kind="stable")  # (Q, Ntrain)
            w = knn.w_[order]
            onehot = (knn.y_[order][..., None] == np.arange(C)).astype(np.float64)
            votes = np.cumsum(w[..., None] * onehot, axis=1)  # (Q, Ntrain, C): vote of the first j+1
            kk = np.minimum(ks, order.shape[1]) - 1
            pred = np.argmax(votes[:, kk, :], axis=2).T  # (K, Q); normalisation does not change argmax
            table[m] += _score(pred, y[test], C, score == "balanced_accuracy") / len(folds)
    best = None
    for m in metrics:
        j = int(np.argmax(table[m]))  # first maximum = smallest k
        if best is None or table[m][j] > best[2]:
            best = (int(ks[j]), m, float(table[m][j]))
    return GridSearchResult(best[0], best[1], best[2], table, ks, score)
