"""Reference set -> fitted numpy k-NN -> ONNX file, and the parity check between the two.

Used by ``radar-edge export-onnx`` and ``radar-edge train`` (build time: needs ``onnx``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from edge.classify.knn import WeightedKNN
from edge.classify.reference import ReferenceSet, load_reference_set

log = logging.getLogger(__name__)

__all__ = ["ExportResult", "ParityError", "build_and_export", "export_knn", "parity_check"]


class ParityError(ValueError):
    """The exported model and the numpy k-NN disagree."""


@dataclass(frozen=True)
class ExportResult:
    path: Path
    knn: WeightedKNN
    reference: ReferenceSet
    reference_sha256: str


def export_knn(knn: WeightedKNN, ref: ReferenceSet, path: str | Path, *, weighting: str,
               build: dict[str, Any] | None = None) -> ExportResult:
    """Write the ONNX model of ``knn`` (fitted on ``ref``) to ``path``."""
    from edge.classify.onnx_export import KnnDefinition, export_model, reference_set_hash

    h = reference_set_hash(ref.features, ref.labels, ref.classes, ref.feature_names)
    defn = KnnDefinition.from_knn(knn, reference_sha256=h, weighting=weighting, feature_names=ref.feature_names,
                                  build=build)
    p = export_model(defn, path)
    return ExportResult(p, knn, ref, h)


def build_and_export(
    reference: str | Path | ReferenceSet | None,
    out: str | Path,
    *,
    k: int,
    metric: str,
    weighting: str = "balanced",
    drop: Sequence[str] = (),
    features: Sequence[str] | None = None,
    build: dict[str, Any] | None = None,
) -> ExportResult:
    """Load ``reference`` (path, set, or ``None``/``""`` = the packaged default), drop classes, keep the
    ``features`` (names; None = all of the set's), fit the weighted k-NN with ``k``/``metric``/``weighting`` and
    export it to ``out`` (its input: those features). ``build`` gains the set's recorded ``classify.features``."""
    from edge.classify.training import drop_classes

    ref = reference if isinstance(reference, ReferenceSet) else load_reference_set(reference or None)
    if drop:
        ref = drop_classes(ref, drop)
    if features is not None:
        ref = ref.select(features)
    knn = WeightedKNN(ref.classes, k=k, metric=metric).fit(ref.features, ref.labels, weighting)
    build = dict(build or {})
    if "classify.features" in ref.meta:  # the feature settings the set was built with, for the check at start
        build.setdefault("classify.features", ref.meta["classify.features"])
    return export_knn(knn, ref, out, weighting=weighting, build=build)


def parity_check(knn: WeightedKNN, model: Any, reference_features: np.ndarray, *, n_random: int = 10_000,
                 seed: int = 0, atol: float = 1e-6) -> dict[str, Any]:
    """Labels equal and probabilities within ``atol`` on every reference vector (as float32) and
    ``n_random`` random vectors (standard normal x 1.5 in the standardised space, mapped back).
    Raises :class:`ParityError` on a mismatch; returns ``{queries, max_abs_dp}``."""
    rng = np.random.default_rng(seed)
    z = rng.normal(0.0, 1.5, size=(n_random, knn.mean_.size))
    q = np.concatenate([np.asarray(reference_features, dtype=np.float64), z * knn.scale_ + knn.mean_])
    q = q.astype(np.float32)
    max_dp = 0.0
    for start in range(0, q.shape[0], 2048):
        qq = q[start:start + 2048]
        lab, prob = model.predict_with_proba(qq)
        want = knn.predict_proba(qq)
        bad = np.flatnonzero(lab != knn.predict(qq))
        if bad.size:
            raise ParityError(f"ONNX and numpy labels differ on {bad.size} of {qq.shape[0]} queries "
                              f"(first: query {start + int(bad[0])})")
        max_dp = max(max_dp, float(np.max(np.abs(prob - want))) if qq.size else 0.0)
    if max_dp > atol:
        raise ParityError(f"ONNX and numpy probabilities differ by {max_dp:.2e} > {atol:.0e}")
    return {"queries": int(q.shape[0]), "max_abs_dp": max_dp}
