"""Training of the surveillance classifier (Tavanti §III-C): reference set -> tuned k-NN -> report.

:func:`train` takes a :class:`~edge.classify.reference.ReferenceSet` (a site's own labelled
recordings turned into feature vectors, or a synthetic one), runs the full grid search with
stratified 3-fold cross-validation of :func:`edge.classify.train.grid_search` (``k`` in [1, 50] x
{Euclidean, Manhattan, Chebyshev}, class-balancing weights, numpy only), fits the weighted k-NN of
eqs. 20-21 on the whole set with the chosen ``(k, metric)`` and returns it with a
:class:`TrainingReport`: the CV score table, the out-of-fold confusion matrix at the chosen
parameters, and -- when a separate test set is given -- the test confusion matrix (Tavanti
Tables IV/V; a class absent from the reference set shows up as a true-class row predicted as the
nearest remaining classes).

:func:`plot_reference_pca` draws the standardised reference set on its first three principal
components (Tavanti Fig. 7). Confusion matrices are ``rows = true class, columns = predicted``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from edge.classify.knn import METRICS, WeightedKNN
from edge.classify.reference import ReferenceSet
from edge.classify.train import GridSearchResult, grid_search, stratified_folds

log = logging.getLogger(__name__)

__all__ = ["TrainingReport", "confusion_matrix", "drop_classes", "format_report", "plot_reference_pca",
           "reference_pca", "train"]


def confusion_matrix(truth: np.ndarray, pred: np.ndarray, n_classes: int) -> np.ndarray:
    """``(C, C)`` counts, rows = true class, columns = predicted class."""
    t = np.asarray(truth, dtype=np.intp)
    p = np.asarray(pred, dtype=np.intp)
    return np.bincount(t * n_classes + p, minlength=n_classes * n_classes).reshape(n_classes, n_classes)


def drop_classes(ref: ReferenceSet, names: Sequence[str]) -> ReferenceSet:
    """The reference set without the vectors of ``names`` (the class list is kept, so a model trained
    on it still reports those classes, with probability 0: Tavanti Table V)."""
    unknown = [n for n in names if n not in ref.classes]
    if unknown:
        raise ValueError(f"unknown class(es) {unknown}; the reference set has {list(ref.classes)}")
    drop = [ref.classes.index(n) for n in names]
    keep = ~np.isin(ref.labels, drop)
    meta = dict(ref.meta, dropped_classes=list(names))
    return ReferenceSet(ref.features[keep], ref.labels[keep], ref.classes, ref.feature_names, meta)


@dataclass
class TrainingReport:
    classes: tuple[str, ...]
    class_counts: dict[str, int]
    k: int
    metric: str
    weighting: str
    score_name: str
    cv_score: float
    n_folds: int
    cv_seed: int
    ks: list[int]
    cv_table: dict[str, list[float]]  # metric -> mean CV score per k in ``ks``
    cv_confusion: list[list[int]]  # out-of-fold predictions at (k, metric)
    cv_accuracy: float
    reference_sha256: str
    test_confusion: list[list[int]] | None = None
    test_accuracy: float | None = None
    test_class_counts: dict[str, int] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        from dataclasses import asdict

        d = asdict(self)
        d["confusion_orientation"] = "rows = true class, columns = predicted class"
        return d


def _out_of_fold_predictions(x, y, classes, k, metric, n_folds, seed, weighting) -> np.ndarray:
    pred = np.empty(y.size, dtype=np.intp)
    for test in stratified_folds(y, n_folds, seed):
        train_idx = np.setdiff1d(np.arange(y.size), test)
        knn = WeightedKNN(classes, k=k, metric=metric).fit(x[train_idx], y[train_idx], weighting)
        pred[test] = knn.predict(x[test])
    return pred


def train(
    ref: ReferenceSet,
    *,
    ks: Sequence[int] = range(1, 51),
    metrics: Sequence[str] = METRICS,
    n_folds: int = 3,
    cv_seed: int = 0,
    weighting: str = "balanced",
    score: str = "balanced_accuracy",
    test: ReferenceSet | None = None,
    reference_sha256: str = "",
) -> tuple[WeightedKNN, TrainingReport]:
    """Grid search with stratified ``n_folds``-fold CV, then the k-NN fitted on all of ``ref``."""
    x = np.asarray(ref.features, dtype=np.float64)
    y = np.asarray(ref.labels, dtype=np.intp)
    classes = tuple(ref.classes)
    counts = np.bincount(y, minlength=len(classes))
    present = counts > 0
    if present.sum() < 2:
        raise ValueError("training needs at least two classes in the reference set")
    if counts[present].min() < n_folds:
        small = [c for c, n in zip(classes, counts) if 0 < n < n_folds]
        raise ValueError(f"{n_folds}-fold stratified cross-validation needs at least {n_folds} vectors per class; "
                         f"too few for {small}")
    if not np.all(np.isfinite(x)):
        raise ValueError("reference features must be finite (drop tracks seen in fewer than two frames)")
    ks = [int(k) for k in ks]
    res: GridSearchResult = grid_search(x, y, classes, ks=ks, metrics=tuple(metrics), n_folds=n_folds,
                                        seed=cv_seed, weighting=weighting, score=score)
    log.info("grid search: k=%d %s, mean CV %s %.3f", res.k, res.metric, res.score_name, res.score)
    oof = _out_of_fold_predictions(x, y, classes, res.k, res.metric, n_folds, cv_seed, weighting)
    knn = WeightedKNN(classes, k=res.k, metric=res.metric).fit(x, y, weighting)
    rep = TrainingReport(
        classes=classes,
        class_counts=ref.class_counts(),
        k=res.k,
        metric=res.metric,
        weighting=weighting,
        score_name=res.score_name,
        cv_score=float(res.score),
        n_folds=n_folds,
        cv_seed=cv_seed,
        ks=[int(k) for k in res.ks],
        cv_table={m: [float(v) for v in res.scores[m]] for m in metrics},
        cv_confusion=confusion_matrix(y, oof, len(classes)).tolist(),
        cv_accuracy=float(np.mean(oof == y)),
        reference_sha256=reference_sha256,
    )
    if test is not None:
        if tuple(test.classes) != classes:
            raise ValueError(f"test set classes {list(test.classes)} differ from the reference set's {list(classes)}")
        tp = knn.predict(test.features)
        rep.test_confusion = confusion_matrix(test.labels, tp, len(classes)).tolist()
        rep.test_accuracy = float(np.mean(tp == test.labels))
        rep.test_class_counts = test.class_counts()
    return knn, rep


def _matrix_lines(title: str, classes: Sequence[str], m: Sequence[Sequence[int]]) -> list[str]:
    w = max(10, max(len(c) for c in classes) + 1)
    corner = "true \\ pred"
    lines = [title, f"{corner:<{w}}" + "".join(f"{c:>{w}}" for c in classes)]
    for c, row in zip(classes, m):
        lines.append(f"{c:<{w}}" + "".join(f"{v:>{w}d}" for v in row))
    return lines


def format_report(rep: TrainingReport, top: int = 10) -> str:
    """Human-readable report: counts, chosen parameters, CV table (best ``top`` k per metric and every
    5th k), confusion matrices."""
    sha = f" (sha256 {rep.reference_sha256[:16]})" if rep.reference_sha256 else ""
    lines = ["reference set: " + ", ".join(f"{c} {n}" for c, n in rep.class_counts.items()) + sha]
    lines.append(f"chosen: k = {rep.k}, {rep.metric} distance, {rep.weighting} weights; mean {rep.n_folds}-fold CV "
                 f"{rep.score_name} {rep.cv_score:.3f} (out-of-fold accuracy {rep.cv_accuracy:.3f}, fold seed "
                 f"{rep.cv_seed})")
    ms = list(rep.cv_table)
    lines.append(f"CV {rep.score_name} by k (every 5th k, the best and the chosen):")
    lines.append(f"{'k':>4}" + "".join(f"{m:>12}" for m in ms))
    best_rows = set()
    for m in ms:
        best_rows.update(np.argsort(-np.asarray(rep.cv_table[m]), kind="stable")[:1].tolist())
    rows = sorted({i for i, k in enumerate(rep.ks) if k % 5 == 0 or k == 1} | best_rows
                  | {rep.ks.index(rep.k)})
    for i in rows:
        mark = "  <- chosen" if rep.ks[i] == rep.k else ""
        lines.append(f"{rep.ks[i]:>4}" + "".join(f"{rep.cv_table[m][i]:12.3f}" for m in ms) + mark)
    lines += _matrix_lines("out-of-fold confusion matrix at the chosen k and metric:", rep.classes, rep.cv_confusion)
    if rep.test_confusion is not None:
        lines += _matrix_lines(f"test set confusion matrix (accuracy {rep.test_accuracy:.3f}):", rep.classes,
                               rep.test_confusion)
    return "\n".join(lines)


def reference_pca(z: np.ndarray, n_components: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Projection ``(N, n)`` of standardised vectors on their first principal components and the
    fraction of variance each explains (SVD of the centred data)."""
    z = np.asarray(z, dtype=np.float64)
    zc = z - z.mean(axis=0)
    _, s, vt = np.linalg.svd(zc, full_matrices=False)
    # fix the sign of each component (largest loading positive) so plots are reproducible
    signs = np.sign(vt[np.arange(vt.shape[0]), np.argmax(np.abs(vt), axis=1)])
    vt = vt * signs[:, None]
    var = s**2 / max(float(np.sum(s**2)), 1e-300)
    n = min(n_components, vt.shape[0])
    return zc @ vt[:n].T, var[:n]


def plot_reference_pca(knn: WeightedKNN, path: str | Path, title: str = "") -> Path:
    """Tavanti Fig. 7: the standardised reference set on the planes (c1, c2), (c1, c3), (c2, c3)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    proj, var = reference_pca(knn.z_, 3)
    pairs = [(0, 1), (0, 2), (1, 2)]
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), constrained_layout=True)
    markers = ("o", "s", "^", "D", "v", "P")
    for ax, (a, b) in zip(axes, pairs):
        for c, name in enumerate(knn.classes):
            sel = knn.y_ == c
            if np.any(sel):
                ax.scatter(proj[sel, a], proj[sel, b], s=14, marker=markers[c % len(markers)], alpha=0.75,
                           label=f"{name} ({int(sel.sum())})")
        ax.set_xlabel(f"c{a + 1} ({var[a]:.0%} of variance)")
        ax.set_ylabel(f"c{b + 1} ({var[b]:.0%} of variance)")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    fig.suptitle(title or f"reference set on its first principal components ({var.sum():.0%} of the variance)")
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p
