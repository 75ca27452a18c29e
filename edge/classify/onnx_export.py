"""Export the weighted k-NN of Tavanti eqs. 20-21 to one hand-built ONNX graph.

Build-time only: this module imports ``onnx`` (extras ``train``/``test``); the device runs the
result with onnxruntime (:mod:`edge.classify.onnx_runtime`) and never imports ``onnx``.

The graph (opset 17, no custom ops, no Scan/Loop)::

    features  float32 [Q, F]
      Cast(double) -> Sub(mean) -> Div(scale)                       eq. 20, the fitted mean/scale
      Unsqueeze(1) -> Sub(Cast(Z_ref float32 [N, F])) -> Abs        |z - z_l| per feature [Q, N, F]
      euclidean: Mul(a, a) -> ReduceSum(2) -> Sqrt
      manhattan: ReduceSum(2)            chebyshev: ReduceMax(2)     distances [Q, N]
      TopK(K = min(k, N), largest=0, sorted=1)                       neighbours [Q, K]
      Gather(w [N]) -> nb_w [Q, K];  Gather(y int32 [N]) == classes -> Cast -> * nb_w -> ReduceSum(1)
      / ReduceSum(nb_w)                                                  eq. 21
    probabilities double [Q, C], label int64 [Q] (ArgMax, first maximum), neighbors int64 [Q, K],
    distances double [Q, K]

The vote of neighbour ``l`` for class ``c`` is ``w_l * I(y_l = c)``. The standardised reference
vectors are *stored* in float32 (20 bytes a vector instead of 40; with int32 labels and float64
weights a reference costs 32 bytes, so about 1900 of them fit the 64 KiB model budget) and cast to
double once; the oracle rounds its ``z_`` to float32 the same way when it is fitted, so both use
identical reference values. Everything after the input cast is computed in double, with the same
element-wise operations in the same order as the numpy oracle (:class:`edge.classify.knn.WeightedKNN`),
so the standardised queries are bit-identical and distances differ at most by the summation order of
six terms: the two implementations pick the same neighbours except for distances within a few ulp
(about 1e-16 relative), which float32 arithmetic would make about 1e9 times more likely.

Ties. ONNX TopK (opset 11 and later) specifies that among equal values the lower index comes first;
with ``sorted=1`` and ``largest=0`` that is exactly ``argsort(kind="stable")[:K]``, the oracle's rule
(the lower reference index wins, also at the K-th/K+1-th boundary). The tests check it on
reference sets built with many exact ties (integer grids, duplicated vectors) for each metric. Ties
between class probabilities go to the lower class index in both: probabilities within
``PROBABILITY_TIE_TOL`` (1e-9) of the maximum count as tied, because eq. 21 sums weights in an
implementation-defined order and two mathematically equal sums can differ in the last bit (seen in
the tests with unequal integer weights); the first such class wins (ArgMax ``select_last_index=0``
over the indicator, as ``WeightedKNN.predict``).

Metadata (``metadata_props``, all strings, keys prefixed ``radar_edge.``): ``schema`` (format
version), ``classes``, ``feature_names``, ``feature_units`` (JSON lists), ``k`` (the configured k;
the graph uses ``min(k, N)``), ``metric``, ``weighting``, ``reference_sha256``
(:func:`reference_set_hash`), ``reference_size``, ``version`` (the project version) and ``build``
(JSON: how it was made).
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from edge.classify.features import FEATURE_NAMES
from edge.classify.knn import METRICS, PROBABILITY_TIE_TOL, WeightedKNN
from edge.classify.onnx_runtime import META_PREFIX, SCHEMA_VERSION

log = logging.getLogger(__name__)

__all__ = [
    "FEATURE_UNITS",
    "KnnDefinition",
    "META_PREFIX",
    "OPSET",
    "SCHEMA_VERSION",
    "build_model",
    "export_model",
    "project_version",
    "reference_set_hash",
]

OPSET = 17
INPUT_NAME = "features"

#: units of the eq. 19 features, in :data:`FEATURE_NAMES` order ("1" = dimensionless; the RCS-related
#: quantity of eq. 17 is in ADC-count^2 m^1.8, "a.u.", as the paper uses it only relatively)
FEATURE_UNITS: tuple[str, ...] = ("1", "1", "a.u.", "a.u.^2", "km/h", "m")
#: the unit of each feature by name
FEATURE_UNIT_OF: dict[str, str] = dict(zip(FEATURE_NAMES, FEATURE_UNITS))


def project_version() -> str:
    """The radar-edge version: installed metadata, else ``pyproject.toml`` of a source tree."""
    from importlib import metadata

    try:
        return metadata.version("radar-edge")
    except metadata.PackageNotFoundError:
        pass
    import tomllib

    py = Path(__file__).resolve().parents[2] / "pyproject.toml"
    try:
        return str(tomllib.loads(py.read_text(encoding="utf-8"))["project"]["version"])
    except (OSError, KeyError, tomllib.TOMLDecodeError):
        return "unknown"


def reference_set_hash(features: np.ndarray, labels: np.ndarray, classes: Sequence[str],
                       feature_names: Sequence[str] = FEATURE_NAMES) -> str:
    """SHA-256 of a reference set: features as little-endian float64 (C order), labels as int64,
    then the class and feature names as JSON. Independent of the file format it came from."""
    h = hashlib.sha256()
    f = np.ascontiguousarray(np.asarray(features, dtype="<f8"))
    y = np.ascontiguousarray(np.asarray(labels, dtype="<i8"))
    h.update(f"{f.shape[0]}x{f.shape[1]};".encode())
    h.update(f.tobytes())
    h.update(y.tobytes())
    h.update(json.dumps([list(classes), list(feature_names)]).encode())
    return h.hexdigest()


@dataclass(frozen=True, eq=False)
class KnnDefinition:
    """Everything the graph needs: a plain, fitted definition of eqs. 20-21.

    ``reference_z`` (N, F) standardised reference vectors, ``labels`` (N,) class indices,
    ``weights`` (N,) the ``w_l`` (summing to 1), ``mean``/``scale`` (F,) of eq. 20.
    """

    reference_z: np.ndarray
    labels: np.ndarray
    weights: np.ndarray
    mean: np.ndarray
    scale: np.ndarray
    classes: tuple[str, ...]
    k: int
    metric: str
    feature_names: tuple[str, ...] = FEATURE_NAMES
    feature_units: tuple[str, ...] = FEATURE_UNITS
    weighting: str = "balanced"
    reference_sha256: str = ""
    build: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        z = np.asarray(self.reference_z)
        n_f = len(self.feature_names)
        if z.ndim != 2 or z.shape[1] != n_f or z.shape[0] < 1:
            raise ValueError(f"reference_z must be (N >= 1, {n_f}); got {z.shape}")
        n = z.shape[0]
        for name in ("labels", "weights"):
            if np.shape(getattr(self, name)) != (n,):
                raise ValueError(f"{name} must be ({n},); got {np.shape(getattr(self, name))}")
        for name in ("mean", "scale"):
            if np.shape(getattr(self, name)) != (n_f,):
                raise ValueError(f"{name} must be ({n_f},); got {np.shape(getattr(self, name))}")
        if len(self.feature_units) != n_f:
            raise ValueError("one unit per feature")
        y = np.asarray(self.labels)
        if y.min() < 0 or y.max() >= len(self.classes):
            raise ValueError(f"labels must index the {len(self.classes)} classes")
        if self.metric not in METRICS:
            raise ValueError(f"unknown metric {self.metric!r}; choose one of {', '.join(METRICS)}")
        if self.k < 1:
            raise ValueError(f"k must be at least 1, got {self.k}")
        if not np.all(np.isfinite(z)) or not np.all(np.asarray(self.scale) > 0):
            raise ValueError("reference vectors must be finite and scales positive")
        if not np.array_equal(z.astype(np.float32).astype(np.float64), z):
            raise ValueError("reference_z must be exactly representable in float32 (the model stores it so; "
                             "WeightedKNN.fit rounds it)")
        if np.any(np.asarray(self.weights) < 0) or not np.sum(self.weights) > 0:
            raise ValueError("weights must be non-negative with a positive sum")

    @classmethod
    def from_knn(cls, knn: WeightedKNN, *, reference_sha256: str = "", weighting: str = "balanced",
                 feature_names: Sequence[str] = FEATURE_NAMES, feature_units: Sequence[str] | None = None,
                 build: dict[str, Any] | None = None) -> "KnnDefinition":
        """The definition of a fitted :class:`WeightedKNN` (the oracle's own arrays, not copies of
        a re-computation, so both standardise identically)."""
        if knn.z_ is None:
            raise ValueError("WeightedKNN is not fitted")
        return cls(
            reference_z=knn.z_, labels=knn.y_, weights=knn.w_, mean=knn.mean_, scale=knn.scale_,
            classes=tuple(knn.classes), k=knn.k, metric=knn.metric, feature_names=tuple(feature_names),
            feature_units=tuple(feature_units if feature_units is not None
                                else (FEATURE_UNIT_OF.get(n, "") for n in feature_names)),
            weighting=weighting, reference_sha256=reference_sha256,
            build=dict(build or {}),
        )

    @property
    def n_reference(self) -> int:
        return int(np.shape(self.reference_z)[0])

    @property
    def effective_k(self) -> int:
        return min(int(self.k), self.n_reference)

    def metadata(self) -> dict[str, str]:
        m = {
            "schema": SCHEMA_VERSION,
            "classes": json.dumps(list(self.classes)),
            "feature_names": json.dumps(list(self.feature_names)),
            "feature_units": json.dumps(list(self.feature_units)),
            "k": str(int(self.k)),
            "metric": self.metric,
            "weighting": self.weighting,
            "reference_sha256": self.reference_sha256,
            "reference_size": str(self.n_reference),
            "version": project_version(),
            "build": json.dumps(self.build, sort_keys=True),
        }
        return {META_PREFIX + k: v for k, v in m.items()}


def build_model(defn: KnnDefinition):
    """The ``onnx.ModelProto`` of ``defn`` (deterministic: the same definition gives the same bytes)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    n, n_f = np.shape(defn.reference_z)
    n_c = len(defn.classes)
    kk = defn.effective_k
    w = np.asarray(defn.weights, dtype=np.float64)
    y = np.asarray(defn.labels, dtype=np.int32)

    def const(name: str, arr: np.ndarray):
        return numpy_helper.from_array(np.ascontiguousarray(arr), name)

    inits = [
        const("mean", np.asarray(defn.mean, dtype=np.float64)),
        const("scale", np.asarray(defn.scale, dtype=np.float64)),
        const("reference_z32", np.asarray(defn.reference_z, dtype=np.float32)),
        const("ref_labels", y),
        const("class_ids", np.arange(n_c, dtype=np.int32)),
        const("ref_weights", w),
        const("k", np.array([kk], dtype=np.int64)),
        const("axis_1", np.array([1], dtype=np.int64)),
        const("axis_2", np.array([2], dtype=np.int64)),
        const("tie_tol", np.array(PROBABILITY_TIE_TOL, dtype=np.float64)),
    ]
    nodes = [
        helper.make_node("Cast", [INPUT_NAME], ["x64"], to=TensorProto.DOUBLE, name="to_double"),
        helper.make_node("Sub", ["x64", "mean"], ["centred"], name="eq20_centre"),
        helper.make_node("Div", ["centred", "scale"], ["z"], name="eq20_scale"),
        helper.make_node("Unsqueeze", ["z", "axis_1"], ["z_q1f"], name="query_axis"),
        helper.make_node("Cast", ["reference_z32"], ["reference_z"], to=TensorProto.DOUBLE, name="reference_to_double"),
        helper.make_node("Sub", ["z_q1f", "reference_z"], ["diff"], name="diff"),
        helper.make_node("Abs", ["diff"], ["absdiff"], name="absdiff"),
    ]
    if defn.metric == "euclidean":
        nodes += [
            helper.make_node("Mul", ["absdiff", "absdiff"], ["sq"], name="square"),
            helper.make_node("ReduceSum", ["sq", "axis_2"], ["sqsum"], keepdims=0, name="sum_sq"),
            helper.make_node("Sqrt", ["sqsum"], ["dist"], name="euclidean"),
        ]
    elif defn.metric == "manhattan":
        nodes.append(helper.make_node("ReduceSum", ["absdiff", "axis_2"], ["dist"], keepdims=0, name="manhattan"))
    else:  # chebyshev (validated in KnnDefinition)
        nodes.append(helper.make_node("ReduceMax", ["absdiff"], ["dist"], axes=[2], keepdims=0, name="chebyshev"))
    nodes += [
        helper.make_node("TopK", ["dist", "k"], ["distances", "neighbors"], axis=1, largest=0, sorted=1,
                         name="k_nearest"),
        helper.make_node("Gather", ["ref_weights", "neighbors"], ["nb_w"], axis=0, name="gather_weights"),
        helper.make_node("Gather", ["ref_labels", "neighbors"], ["nb_y"], axis=0, name="gather_labels"),
        helper.make_node("Unsqueeze", ["nb_y", "axis_2"], ["nb_y_qk1"], name="label_axis"),
        helper.make_node("Equal", ["nb_y_qk1", "class_ids"], ["is_class"], name="one_hot"),
        helper.make_node("Cast", ["is_class"], ["one_hot64"], to=TensorProto.DOUBLE, name="one_hot_double"),
        helper.make_node("Unsqueeze", ["nb_w", "axis_2"], ["nb_w_qk1"], name="weight_axis"),
        helper.make_node("Mul", ["one_hot64", "nb_w_qk1"], ["nb_votes"], name="votes"),
        helper.make_node("ReduceSum", ["nb_votes", "axis_1"], ["num"], keepdims=0, name="eq21_numerator"),
        helper.make_node("ReduceSum", ["nb_w", "axis_1"], ["den"], keepdims=1, name="eq21_denominator"),
        helper.make_node("Div", ["num", "den"], ["probabilities"], name="eq21"),
        # label: the lowest class within PROBABILITY_TIE_TOL of the maximum (as WeightedKNN.predict)
        helper.make_node("ReduceMax", ["probabilities"], ["p_max"], axes=[1], keepdims=1, name="p_max"),
        helper.make_node("Sub", ["p_max", "tie_tol"], ["p_thr"], name="p_thr"),
        helper.make_node("GreaterOrEqual", ["probabilities", "p_thr"], ["is_top"], name="is_top"),
        helper.make_node("Cast", ["is_top"], ["is_top_i"], to=TensorProto.INT32, name="is_top_int"),
        helper.make_node("ArgMax", ["is_top_i"], ["label"], axis=1, keepdims=0, select_last_index=0,
                         name="label"),
    ]
    graph = helper.make_graph(
        nodes,
        "radar_edge_weighted_knn",
        [helper.make_tensor_value_info(INPUT_NAME, TensorProto.FLOAT, ["N", n_f])],
        [
            helper.make_tensor_value_info("label", TensorProto.INT64, ["N"]),
            helper.make_tensor_value_info("probabilities", TensorProto.DOUBLE, ["N", n_c]),
            helper.make_tensor_value_info("neighbors", TensorProto.INT64, ["N", kk]),
            helper.make_tensor_value_info("distances", TensorProto.DOUBLE, ["N", kk]),
        ],
        initializer=inits,
        doc_string=f"Weighted k-NN (Tavanti et al. 2022, eqs. 20-21): k={defn.k}, metric={defn.metric}, "
        f"{n} reference vectors, classes {', '.join(defn.classes)}",
    )
    model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="radar-edge",
        producer_version=project_version(),
        doc_string="radar-edge surveillance classifier; see edge/classify/onnx_export.py",
    )
    model.ir_version = 8  # opset 17 needs IR >= 8; pinned so older onnxruntime builds load it
    helper.set_model_props(model, defn.metadata())
    onnx.checker.check_model(model, full_check=True)
    return model


def export_model(defn: KnnDefinition, path: str | Path) -> Path:
    """Write the model of ``defn`` to ``path``; returns the path."""
    model = build_model(defn)
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    data = model.SerializeToString(deterministic=True)
    p.write_bytes(data)
    log.info("wrote %s (%d bytes): k=%d %s, %d reference vectors, reference sha256 %s", p, len(data), defn.k,
             defn.metric, defn.n_reference, defn.reference_sha256[:12])
    return p
