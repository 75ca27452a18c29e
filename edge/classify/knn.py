"""Weighted k-nearest-neighbour classification (Tavanti §II-G, eqs. 20-21), numpy only.

:class:`WeightedKNN` is the reference implementation and the test oracle of the exported ONNX
model:

1. standardise the reference features with the weighted mean and unbiased weighted standard
   deviation of eq. 20 (weights ``w_l`` summing to 1; class-balancing by default:
   ``w_l = 1 / (C * n_{y_l})`` with ``C`` the classes present, so every class weighs the same); the
   standardised reference vectors are stored rounded to float32 (relative 6e-8, far below any
   feature's noise), as the exported ONNX model stores them, and used in float64;
2. distances from a query to all ``N`` reference vectors (Euclidean, Manhattan or Chebyshev);
3. the ``k`` nearest: ``argsort(kind="stable")``, so among equal distances the lower reference index
   wins;
4. ``p(c | z) = sum_{l in D} w_l I(y_l = c) / sum_{l in D} w_l`` (eq. 21); the predicted class is the
   most probable one, ties going to the lower class index.

Paper defaults (Table III): ``k = 13``, Euclidean. Reference sets are loaded by
:func:`edge.classify.reference.load_reference_set`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Sequence

import numpy as np

from edge.classify.features import FEATURE_NAMES, distinct_among, weighted_standardization

if TYPE_CHECKING:  # pragma: no cover
    from edge.classify.reference import ReferenceSet

__all__ = ["ColumnSelect", "DEFAULT_FEATURES", "KnnConfig", "METRICS", "PROBABILITY_TIE_TOL", "WeightedKNN",
           "class_balanced_weights", "knn_for", "pairwise_distances"]

#: the features the k-NN compares by default: eq. 18's circular variance left out (on the Distance2Go it follows the
#: echo's strength, docs/decisions/0026)
DEFAULT_FEATURES: tuple[str, ...] = ("rcs_mean", "rcs_var", "abs_radial_speed_mean_kmh", "range_extent_m")

METRICS: tuple[str, ...] = ("euclidean", "manhattan", "chebyshev")

#: class probabilities closer than this are a tie (-> the lower class index). Eq. 21 sums weights
#: in an implementation-defined order, so equal sums can differ by a few ulp (~1e-16 each); distinct
#: probabilities of any realistic reference set differ by far more (>= 1/(k * N^2) ~ 1e-7).
PROBABILITY_TIE_TOL = 1e-9


@dataclass(frozen=True)
class KnnConfig:
    """The classifier of the surveillance profile (Tavanti Table III)."""

    k: int = field(default=13, metadata={"doc": "number of neighbours (3-fold CV grid search: 13)", "min": 1, "max": 1000})
    metric: str = field(default="euclidean", metadata={"doc": "distance between standardised features",
                                                         "choices": METRICS})
    weighting: str = field(
        default="balanced",
        metadata={"doc": "reference weights w_l of eqs. 20-21: balanced = every class weighs the same, uniform = 1/N",
                  "choices": ("balanced", "uniform")},
    )
    reference_set: str = field(
        default="",
        metadata={"doc": "reference set .npz (edge.classify.reference format); empty = the packaged default "
                  "edge/data/reference_set.npz"},
    )
    features: tuple[str, ...] = field(
        default=DEFAULT_FEATURES,
        metadata={"doc": "the features of the track's vector that the k-NN compares (names of edge.classify.features."
                         "FEATURE_NAMES); the default leaves out eq. 18's circular variance, which on the Distance2Go "
                         "follows the echo's strength (docs/decisions/0026)"},
    )

    def __post_init__(self) -> None:
        if not distinct_among(self.features):
            raise ValueError(f"features must be distinct names of {list(FEATURE_NAMES)}, got {list(self.features)}")


def class_balanced_weights(labels: np.ndarray, n_classes: int | None = None) -> np.ndarray:
    """``w_l = 1 / (C * n_{y_l})``: each of the ``C`` classes present sums to ``1/C``; total 1."""
    y = np.asarray(labels, dtype=np.intp).reshape(-1)
    if y.size == 0:
        raise ValueError("no labels")
    counts = np.bincount(y, minlength=n_classes or 0)
    present = int(np.count_nonzero(counts))
    return 1.0 / (present * counts[y].astype(np.float64))


def pairwise_distances(queries: np.ndarray, refs: np.ndarray, metric: str = "euclidean") -> np.ndarray:
    """``(Q, F)`` x ``(N, F)`` -> ``(Q, N)`` distances (float64)."""
    q = np.asarray(queries, dtype=np.float64)
    r = np.asarray(refs, dtype=np.float64)
    d = np.abs(q[:, None, :] - r[None, :, :])
    if metric == "euclidean":
        return np.sqrt(np.einsum("qnf,qnf->qn", d, d))
    if metric == "manhattan":
        return d.sum(axis=-1)
    if metric == "chebyshev":
        return d.max(axis=-1)
    raise ValueError(f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")


class WeightedKNN:
    """Eqs. 20-21. ``classes`` are names; labels passed to :meth:`fit` are indices into them."""

    def __init__(self, classes: Sequence[str], k: int = 13, metric: str = "euclidean") -> None:
        if k < 1:
            raise ValueError(f"k must be at least 1, got {k!r}")
        if metric not in METRICS:
            raise ValueError(f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")
        self.classes = tuple(classes)
        self.k = int(k)
        self.metric = metric
        self.mean_: np.ndarray | None = None
        self.scale_: np.ndarray | None = None
        self.z_: np.ndarray | None = None
        self.y_: np.ndarray | None = None
        self.w_: np.ndarray | None = None

    def fit(self, x: np.ndarray, y: np.ndarray, weights: np.ndarray | str = "balanced") -> "WeightedKNN":
        """Reference features ``x`` (N, F), labels ``y`` (N,), weights (N,) or "balanced"/"uniform"."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.intp).reshape(-1)
        if x.ndim != 2 or x.shape[0] != y.size:
            raise ValueError(f"x must be (N, F) with N = len(y); got {x.shape} and {y.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError("reference features must be finite")
        if y.size and (y.min() < 0 or y.max() >= len(self.classes)):
            raise ValueError(f"labels must be indices into {len(self.classes)} classes")
        if isinstance(weights, str):
            if weights == "balanced":
                w = class_balanced_weights(y, len(self.classes))
            elif weights == "uniform":
                w = np.full(y.size, 1.0 / y.size)
            else:
                raise ValueError(f"weights must be an array, 'balanced' or 'uniform', got {weights!r}")
        else:
            w = np.asarray(weights, dtype=np.float64).reshape(-1)
            if w.size != y.size or np.any(w < 0) or not w.sum() > 0:
                raise ValueError("weights must be (N,), non-negative, with a positive sum")
            w = w / w.sum()
        self.mean_, self.scale_ = weighted_standardization(x, w)
        # the reference store is float32 (the exported ONNX model keeps it so, to stay small); queries,
        # standardisation and distances stay float64, so both implementations compute the same numbers
        self.z_ = ((x - self.mean_) / self.scale_).astype(np.float32).astype(np.float64)
        self.y_ = y
        self.w_ = w
        return self

    @classmethod
    def from_reference_set(cls, ref: "ReferenceSet", k: int = 13, metric: str = "euclidean",
                           weighting: str = "balanced") -> "WeightedKNN":
        return cls(ref.classes, k=k, metric=metric).fit(ref.features, ref.labels, weighting)

    def _check(self) -> None:
        if self.z_ is None:
            raise RuntimeError("WeightedKNN is not fitted")

    def standardize(self, x: np.ndarray) -> np.ndarray:
        self._check()
        return (np.atleast_2d(np.asarray(x, dtype=np.float64)) - self.mean_) / self.scale_

    def kneighbors(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(distances, indices)``, both ``(Q, k')`` with ``k' = min(k, N)``; ties -> lower index."""
        z = self.standardize(x)
        d = pairwise_distances(z, self.z_, self.metric)
        kk = min(self.k, d.shape[1])
        idx = np.argsort(d, axis=1, kind="stable")[:, :kk]
        return np.take_along_axis(d, idx, axis=1), idx

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        """``(Q, C)`` class probabilities of eq. 21."""
        _, idx = self.kneighbors(x)
        w = self.w_[idx]  # (Q, k)
        onehot = self.y_[idx][..., None] == np.arange(len(self.classes))  # (Q, k, C)
        num = np.einsum("qk,qkc->qc", w, onehot)
        return num / w.sum(axis=1, keepdims=True)

    def predict(self, x: np.ndarray) -> np.ndarray:
        """``(Q,)`` class indices: the lowest class whose probability is within
        :data:`PROBABILITY_TIE_TOL` of the maximum (ties -> lower class index, also when rounding made
        two mathematically equal sums of weights differ in the last bit)."""
        p = self.predict_proba(x)
        return np.argmax(p >= p.max(axis=1, keepdims=True) - PROBABILITY_TIE_TOL, axis=1)


class ColumnSelect:
    """A classifier of a subset of the features, fed the whole feature vector (:data:`FEATURE_NAMES` order): it
    takes the columns ``names`` and forwards the call (``predict``, ``predict_proba``, ``predict_with_proba``,
    ``kneighbors``); other attributes are the classifier's."""

    def __init__(self, classifier, names) -> None:
        self.classifier = classifier
        self.feature_names = tuple(names)
        self.columns = np.array([FEATURE_NAMES.index(n) for n in self.feature_names], dtype=np.intp)

    def __getattr__(self, name):
        return getattr(self.classifier, name)

    def _x(self, x: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(np.asarray(x))
        if q.shape[-1] != len(FEATURE_NAMES):
            raise ValueError(f"features must be (Q, {len(FEATURE_NAMES)}) in FEATURE_NAMES order; got {q.shape}")
        return q[:, self.columns]

    def predict(self, x: np.ndarray) -> np.ndarray:
        return self.classifier.predict(self._x(x))

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        return self.classifier.predict_proba(self._x(x))

    def predict_with_proba(self, x: np.ndarray):
        return self.classifier.predict_with_proba(self._x(x))

    def kneighbors(self, x: np.ndarray):
        return self.classifier.kneighbors(self._x(x))


def knn_for(ref: "ReferenceSet", config: KnnConfig) -> ColumnSelect:
    """The numpy k-NN of ``config`` (k, metric, weighting, features) on ``ref``, fed whole feature vectors."""
    sub = ref.select(config.features)
    knn = WeightedKNN.from_reference_set(sub, k=config.k, metric=config.metric, weighting=config.weighting)
    return ColumnSelect(knn, sub.feature_names)
