"""Run the exported weighted k-NN with onnxruntime on the device.

:class:`OnnxKnnClassifier` has the call signature of the numpy oracle
(:class:`edge.classify.knn.WeightedKNN`): ``classes``, ``k``, ``metric``, ``predict_proba(x)``,
``predict(x)``, ``kneighbors(x)`` with the same shapes and dtypes (float64 probabilities and
distances, integer indices), so the surveillance pipeline can use either.

The model is loaded once, in the constructor (the pipeline builds it at start): a missing or
corrupt file, a graph without the expected inputs/outputs, a model without radar-edge metadata, or
one whose feature schema or class list differs from what the pipeline expects raises
:class:`ModelError` there, never mid-run. onnxruntime runs single-threaded by default
(``classify.onnx.threads``), sequential execution, CPU provider. ``onnx`` is not imported here.

With no model configured, :func:`default_model_path` (the packaged ``edge/data/knn_default.onnx``)
is used; it is rebuilt by ``radar-edge export-onnx --out edge/data/knn_default.onnx``.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from edge.classify.features import FEATURE_NAMES, distinct_among

log = logging.getLogger(__name__)

__all__ = ["ModelError", "OnnxConfig", "OnnxKnnClassifier", "default_model_path", "query_latency"]

META_PREFIX = "radar_edge."
SCHEMA_VERSION = "1"
_REQUIRED_META = ("schema", "classes", "feature_names", "feature_units", "k", "metric", "reference_sha256",
                  "version")
_OUTPUTS = ("label", "probabilities", "neighbors", "distances")


class ModelError(ValueError):
    """The classifier model is missing, corrupt or does not fit the pipeline; the message says why."""


@dataclass(frozen=True)
class OnnxConfig:
    """The classifier model run by onnxruntime (section ``classify.onnx``)."""

    backend: str = field(
        default="onnx",
        metadata={"doc": "classifier implementation: onnx = the exported model under onnxruntime (the device), "
                  "numpy = the reference k-NN of classify.knn (the test oracle)", "choices": ("onnx", "numpy")},
    )
    model: str = field(
        default="",
        metadata={"doc": "ONNX model file from radar-edge train / export-onnx; empty = the packaged default "
                  "edge/data/knn_default.onnx"},
    )
    threads: int = field(
        default=1, metadata={"doc": "onnxruntime intra-op threads (1 leaves the other core to the frame loop)",
                             "min": 1, "max": 64},
    )


def default_model_path() -> Path:
    return Path(str(resources.files("edge").joinpath("data", "knn_default.onnx")))


def _ort_errors() -> tuple[type[BaseException], ...]:
    from onnxruntime.capi import onnxruntime_pybind11_state as st

    names = ("Fail", "InvalidArgument", "NoSuchFile", "NoModel", "InvalidProtobuf", "InvalidGraph",
             "ModelLoaded", "NotImplemented", "RuntimeException", "EngineError")
    return tuple(getattr(st, n) for n in names if isinstance(getattr(st, n, None), type))


class OnnxKnnClassifier:
    """The exported weighted k-NN under onnxruntime, a drop-in for :class:`WeightedKNN`.

    ``expected_features``/``expected_classes``: the features the caller extracts (the model's must be among them;
    it is fed its own, :class:`edge.classify.knn.ColumnSelect`) and the classes it reads; ``None`` accepts what the
    model declares -- the metadata and graph schema are always checked.
    """

    def __init__(
        self,
        path: str | Path | None = None,
        *,
        threads: int = 1,
        expected_features: Sequence[str] | None = FEATURE_NAMES,
        expected_classes: Sequence[str] | None = None,
    ) -> None:
        p = default_model_path() if not path else Path(path)
        self.path = p
        if not p.is_file():
            raise ModelError(f"classifier model {str(p)!r} not found")
        if threads < 1:
            raise ModelError(f"threads must be at least 1, got {threads}")
        try:
            import onnxruntime as ort
        except ImportError as exc:  # pragma: no cover - a runtime dependency
            raise ModelError("onnxruntime is not installed (it is a runtime dependency of radar-edge)") from exc
        so = ort.SessionOptions()
        so.intra_op_num_threads = int(threads)
        so.inter_op_num_threads = 1
        so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        so.log_severity_level = 3
        try:
            data = p.read_bytes()
            self._session = ort.InferenceSession(data, sess_options=so, providers=["CPUExecutionProvider"])
        except OSError as exc:
            raise ModelError(f"classifier model {str(p)!r} cannot be read: {exc}") from exc
        except _ort_errors() as exc:
            raise ModelError(f"classifier model {str(p)!r} is not a valid ONNX model: {exc}") from exc
        self.metadata = self._check_metadata(p)
        self._check_graph(p)
        self.classes: tuple[str, ...] = tuple(self.metadata["classes"])
        self.feature_names: tuple[str, ...] = tuple(self.metadata["feature_names"])
        self.feature_units: tuple[str, ...] = tuple(self.metadata["feature_units"])
        self.k: int = int(self.metadata["k"])
        self.metric: str = str(self.metadata["metric"])
        self.reference_sha256: str = str(self.metadata["reference_sha256"])
        if expected_features is not None and not distinct_among(self.feature_names, expected_features):
            raise ModelError(
                f"classifier model {str(p)!r} expects features {list(self.feature_names)}, not distinct features of "
                f"those the pipeline extracts {list(expected_features)}: retrain or re-export it with this version")
        if expected_classes is not None and tuple(expected_classes) != self.classes:
            raise ModelError(
                f"classifier model {str(p)!r} has classes {list(self.classes)}, the pipeline expects "
                f"{list(expected_classes)}")
        log.info("classifier %s: k=%d %s, %s reference vectors, classes %s, reference sha256 %s, %d thread(s)",
                 p, self.k, self.metric, self.metadata.get("reference_size", "?"), ",".join(self.classes),
                 self.reference_sha256[:12], threads)

    def _check_metadata(self, p: Path) -> dict[str, Any]:
        raw = self._session.get_modelmeta().custom_metadata_map
        meta = {k[len(META_PREFIX):]: v for k, v in raw.items() if k.startswith(META_PREFIX)}
        missing = [k for k in _REQUIRED_META if k not in meta]
        if missing:
            raise ModelError(f"classifier model {str(p)!r} lacks radar-edge metadata {missing}: "
                             "export it with radar-edge export-onnx")
        if meta["schema"] != SCHEMA_VERSION:
            raise ModelError(f"classifier model {str(p)!r} has metadata schema {meta['schema']!r}, "
                             f"this version reads {SCHEMA_VERSION!r}")
        out: dict[str, Any] = dict(meta)
        try:
            for key in ("classes", "feature_names", "feature_units"):
                val = json.loads(meta[key])
                if not isinstance(val, list) or not all(isinstance(s, str) for s in val):
                    raise ValueError(f"{key} is not a list of strings")
                out[key] = val
            out["k"] = int(meta["k"])
            out["build"] = json.loads(meta.get("build", "{}"))
        except ValueError as exc:
            raise ModelError(f"classifier model {str(p)!r}: malformed metadata: {exc}") from exc
        return out

    def _check_graph(self, p: Path) -> None:
        ins = self._session.get_inputs()
        outs = {o.name: o for o in self._session.get_outputs()}
        n_f = len(self.metadata["feature_names"])
        n_c = len(self.metadata["classes"])
        if len(ins) != 1 or ins[0].type != "tensor(float)" or len(ins[0].shape) != 2 or ins[0].shape[1] != n_f:
            got = [(i.name, i.type, i.shape) for i in ins]
            raise ModelError(f"classifier model {str(p)!r}: input must be one float32 [N, {n_f}] tensor, got {got}")
        missing = [o for o in _OUTPUTS if o not in outs]
        if missing:
            raise ModelError(f"classifier model {str(p)!r}: outputs {missing} missing")
        if outs["probabilities"].shape[-1] != n_c:
            raise ModelError(f"classifier model {str(p)!r}: probabilities have {outs['probabilities'].shape[-1]} "
                             f"columns for {n_c} classes")
        self._input = ins[0].name

    # -- the WeightedKNN call signature -------------------------------------------------------------

    def _run(self, x: np.ndarray, names: Sequence[str]) -> list[np.ndarray]:
        q = np.atleast_2d(np.asarray(x, dtype=np.float32))
        if q.ndim != 2 or q.shape[1] != len(self.feature_names):
            raise ValueError(f"features must be (Q, {len(self.feature_names)}); got {np.shape(x)}")
        if not np.all(np.isfinite(q)):
            raise ValueError("features must be finite (a track seen in fewer than two frames has NaN variances)")
        return self._session.run(list(names), {self._input: np.ascontiguousarray(q)})

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        """``(Q, C)`` float64 class probabilities of eq. 21."""
        return self._run(x, ("probabilities",))[0]

    def predict(self, x: np.ndarray) -> np.ndarray:
        """``(Q,)`` class indices (first maximum of the probabilities)."""
        return self._run(x, ("label",))[0].astype(np.intp)

    def predict_with_proba(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Labels and probabilities from one run."""
        lab, prob = self._run(x, ("label", "probabilities"))
        return lab.astype(np.intp), prob

    def kneighbors(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(distances, indices)`` ``(Q, min(k, N))``, nearest first, ties to the lower index."""
        d, i = self._run(x, ("distances", "neighbors"))
        return d, i.astype(np.intp)


def _percentiles_us(samples_ns: np.ndarray) -> dict[str, float]:
    us = np.asarray(samples_ns, dtype=np.float64) / 1e3
    return {"p50_us": float(np.percentile(us, 50)), "p99_us": float(np.percentile(us, 99)),
            "mean_us": float(us.mean())}


def query_latency(
    onnx_model: OnnxKnnClassifier,
    numpy_knn: Any | None = None,
    *,
    queries: int = 1000,
    batch: int = 1,
    seed: int = 0,
    warmup: int = 20,
) -> dict[str, Any]:
    """Per-call latency of ``predict_proba`` on ``batch``-row batches of random standard-normal
    feature vectors mapped into the model's raw feature space (for ``radar-edge bench``).

    Returns ``{"queries", "batch", "onnxruntime": {p50_us, p99_us, mean_us}, "numpy": {...} | None}``.
    Wall time, one thread, this process; compare figures from the same machine only.
    """
    if queries < 1 or batch < 1:
        raise ValueError("queries and batch must be at least 1")
    rng = np.random.default_rng(seed)
    n_calls = max(1, queries // batch)
    mean = np.zeros(len(onnx_model.feature_names))
    scale = np.ones(len(onnx_model.feature_names))
    if numpy_knn is not None and getattr(numpy_knn, "mean_", None) is not None:
        mean, scale = numpy_knn.mean_, numpy_knn.scale_
    x = (rng.standard_normal((n_calls, batch, mean.size)) * scale + mean).astype(np.float32)
    out: dict[str, Any] = {"queries": n_calls * batch, "batch": batch}
    for name, fn in (("onnxruntime", onnx_model.predict_proba),
                     ("numpy", None if numpy_knn is None else numpy_knn.predict_proba)):
        if fn is None:
            out[name] = None
            continue
        for j in range(min(warmup, n_calls)):
            fn(x[j])
        t = np.empty(n_calls, dtype=np.int64)
        for j in range(n_calls):
            t0 = time.perf_counter_ns()
            fn(x[j])
            t[j] = time.perf_counter_ns() - t0
        out[name] = _percentiles_us(t)
    return out
