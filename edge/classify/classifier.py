"""The classifier of the surveillance pipeline, chosen by configuration.

``classify.onnx.backend = "onnx"`` (default): the ONNX model ``classify.onnx.model`` (empty = the
packaged ``edge/data/knn_default.onnx``) under onnxruntime -- k, metric, features and reference set are the
model's own; ``classify.knn`` is then not used (a differing explicit ``classify.knn.k``/``metric``/``features``
is logged as ignored). ``"numpy"``: the reference k-NN built from ``classify.knn`` (the oracle).

Both are fed the whole feature vector (``FEATURE_NAMES`` order) and take their features' columns
(:class:`edge.classify.knn.ColumnSelect`); both have ``classes``, ``predict_proba(x) -> (Q, C)`` and
``predict(x) -> (Q,)``. The default model is the default numpy classifier exported (same reference set, features,
k = 13, Euclidean, balanced), so the two backends give the same results out of the box.
"""

from __future__ import annotations

import logging
from typing import Any

from edge.classify.features import feature_setting_mismatches
from edge.classify.knn import ColumnSelect, KnnConfig, WeightedKNN, knn_for
from edge.classify.onnx_runtime import OnnxKnnClassifier
from edge.classify.reference import DEFAULT_CLASSES, load_reference_set

log = logging.getLogger(__name__)

__all__ = ["build_classifier"]


def build_classifier(config: Any, expected_classes: tuple[str, ...] | None = DEFAULT_CLASSES) -> Any:
    """The classifier for a resolved :class:`edge.config.Config` (loaded now: errors at start)."""
    oc = config.section("classify.onnx")
    kc: KnnConfig = config.section("classify.knn")
    if oc.backend == "numpy":
        ref = load_reference_set(kc.reference_set or None)
        log.info("classifier: numpy weighted k-NN, k=%d %s, %d reference vectors, features %s", kc.k, kc.metric,
                 len(ref), ",".join(kc.features))
        _warn_feature_settings(ref.meta.get("classify.features", {}), config, kc.reference_set or "packaged default")
        return knn_for(ref, kc)
    model = OnnxKnnClassifier(oc.model or None, threads=oc.threads, expected_classes=expected_classes)
    _warn_feature_settings(model.metadata.get("build", {}).get("classify.features", {}), config, str(model.path))
    origin = getattr(config, "origin", {})
    for key, mine in (("k", model.k), ("metric", model.metric), ("features", tuple(model.feature_names))):
        if f"classify.knn.{key}" in origin and getattr(kc, key) != mine:
            log.warning("classify.knn.%s = %r is ignored: the ONNX model %s has %s = %r (set classify.onnx.backend="
                        "numpy to use classify.knn, or re-export the model)", key, getattr(kc, key), model.path, key,
                        mine)
    return ColumnSelect(model, model.feature_names)


def _warn_feature_settings(recorded: dict, config: Any, source: str) -> None:
    bad = feature_setting_mismatches(recorded, config.section("classify.features"))
    if bad:
        log.warning("classify.features differ from the settings the classifier's reference set (%s) was built with: "
                    "%s; its classes will be off (rebuild the set and the model)", source, "; ".join(bad))


def classifier_latency(config: Any, *, queries: int = 2000, batch: int = 1, seed: int = 0) -> dict[str, Any]:
    """Per-call latency of the configured ONNX model and of the numpy k-NN on the same reference
    set and parameters (for ``radar-edge bench``): :func:`edge.classify.onnx_runtime.query_latency`
    plus the model's ``path``, ``k``, ``metric`` and ``reference_size``. The numpy side is rebuilt
    from ``classify.knn.reference_set`` when its hash matches the model's, else left out (``None``)."""
    from edge.classify.onnx_runtime import query_latency

    oc = config.section("classify.onnx")
    kc: KnnConfig = config.section("classify.knn")
    model = OnnxKnnClassifier(oc.model or None, threads=oc.threads, expected_classes=None)
    ref = load_reference_set(kc.reference_set or None).select(model.feature_names)
    knn = None
    from edge.classify.onnx_export import reference_set_hash  # numpy + hashlib only, no onnx import

    if reference_set_hash(ref.features, ref.labels, ref.classes, ref.feature_names) == model.reference_sha256:
        knn = WeightedKNN.from_reference_set(ref, k=model.k, metric=model.metric,
                                             weighting=model.metadata.get("weighting", "balanced"))
    out = query_latency(model, knn, queries=queries, batch=batch, seed=seed)
    out.update({"model": str(model.path), "k": model.k, "metric": model.metric,
                "reference_size": int(model.metadata.get("reference_size", 0)), "threads": oc.threads})
    return out
