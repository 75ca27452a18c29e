"""Reference sets of labelled feature vectors for the k-NN (Tavanti §III-C).

A reference set is an ``.npz`` file with

* ``features`` (N, F) float64 (F = 6: eq. 19 and the range extent) in
  :data:`edge.classify.features.FEATURE_NAMES` order,
* ``labels`` (N,) int16 indices into ``classes``,
* ``classes`` (C,) str, ``feature_names`` (F,) str,
* ``meta`` a JSON string (generator, seed, events per class, configuration, command).

The surveillance pipeline loads the one named by ``classify.knn.reference_set`` or, when that is
empty, the packaged default ``edge/data/reference_set.npz`` (see :mod:`edge.classify.refgen` for
how it is built and the exact command that regenerates it).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from edge.classify.features import FEATURE_NAMES, distinct_among

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_CLASSES", "ReferenceSet", "ReferenceSetError", "default_reference_path", "load_reference_set",
           "save_reference_set"]

#: the four classes of the surveillance profile, in label order
DEFAULT_CLASSES: tuple[str, ...] = ("pedestrian", "car", "motorcycle", "truck")

FORMAT_VERSION = 1


class ReferenceSetError(ValueError):
    """A reference set file is missing or malformed."""


@dataclass(frozen=True, eq=False)
class ReferenceSet:
    features: np.ndarray  # (N, F) float64
    labels: np.ndarray  # (N,) int
    classes: tuple[str, ...] = DEFAULT_CLASSES
    feature_names: tuple[str, ...] = FEATURE_NAMES
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        f = np.asarray(self.features)
        y = np.asarray(self.labels)
        if f.ndim != 2 or f.shape[1] != len(self.feature_names) or y.shape != (f.shape[0],):
            raise ReferenceSetError(f"features must be (N, {len(self.feature_names)}) and labels (N,); "
                                    f"got {f.shape} and {y.shape}")
        if y.size and (y.min() < 0 or y.max() >= len(self.classes)):
            raise ReferenceSetError("labels must index the classes")

    def __len__(self) -> int:
        return int(self.labels.size)

    def class_counts(self) -> dict[str, int]:
        c = np.bincount(self.labels, minlength=len(self.classes))
        return {name: int(n) for name, n in zip(self.classes, c)}

    def select(self, names) -> "ReferenceSet":
        """The set with only the features ``names`` (in that order); the same set when they are all of its own."""
        names = tuple(names)
        if names == self.feature_names:
            return self
        if not distinct_among(names, self.feature_names):
            raise ReferenceSetError(f"features {list(names)} must be distinct features of the set "
                                    f"{list(self.feature_names)}")
        cols = [self.feature_names.index(n) for n in names]
        return ReferenceSet(np.asarray(self.features)[:, cols], self.labels, self.classes, names, dict(self.meta))


def default_reference_path() -> Path:
    return Path(str(resources.files("edge").joinpath("data", "reference_set.npz")))


def save_reference_set(ref: ReferenceSet, path: str | Path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    meta = dict(ref.meta)
    meta.setdefault("format_version", FORMAT_VERSION)
    with p.open("wb") as fh:
        np.savez_compressed(
            fh,
            features=np.asarray(ref.features, dtype=np.float64),
            labels=np.asarray(ref.labels, dtype=np.int16),
            classes=np.array(ref.classes),
            feature_names=np.array(ref.feature_names),
            meta=np.array(json.dumps(meta, sort_keys=True)),
        )
    return p


def load_reference_set(path: str | Path | None = None) -> ReferenceSet:
    """Load ``path`` (``None`` or ``""`` = the packaged default)."""
    p = default_reference_path() if not path else Path(path)
    if not p.is_file():
        raise ReferenceSetError(f"reference set {str(p)!r} not found")
    try:
        with np.load(p, allow_pickle=False) as d:
            names = tuple(str(s) for s in d["feature_names"])
            if names != FEATURE_NAMES:
                raise ReferenceSetError(f"{p}: feature names {names} differ from {FEATURE_NAMES}")
            ref = ReferenceSet(
                features=d["features"].astype(np.float64),
                labels=d["labels"].astype(np.intp),
                classes=tuple(str(s) for s in d["classes"]),
                feature_names=names,
                meta=json.loads(str(d["meta"])),
            )
    except (KeyError, ValueError, OSError) as exc:
        if isinstance(exc, ReferenceSetError):
            raise
        raise ReferenceSetError(f"{p}: not a reference set: {exc}") from exc
    log.debug("reference set %s: %s", p, ref.class_counts())
    return ref
