"""Labelled feature vectors for training (Tavanti §III-C) from recordings or from the simulator.

The paper builds its reference set from recordings of single-target events whose range-Doppler
maps are *only thresholded* with ``th_RD`` (neither clustered nor tracked), "to make the learning
process independent from the clustering and tracking parameters". :class:`EventFeatureExtractor` does
exactly that for one event: every frame goes through the surveillance front end
(:class:`edge.dsp.range_doppler.RangeDopplerProcessor` with ``pipeline.surveillance``'s K_c, K_sf,
N_R, N_D), the cells at or above ``th_RD`` form one cluster whose eq. 17/18 signatures feed a
:class:`~edge.classify.features.TrackFeatureAccumulator`; the eq. 19 vector is the result.

* :func:`recordings_reference_set`: one vector per recording (a site's own data). The class comes
  from ``label=``, else the parent directory's name (``site/car/*.npz``), else the recording's ground
  truth when it holds exactly one class.
* :func:`synthetic_reference_set`: N simulated single-target events (see there).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from edge.classify.features import FEATURE_NAMES, MapPoints, SignatureExtractor
from edge.classify.reference import DEFAULT_CLASSES, ReferenceSet

log = logging.getLogger(__name__)

__all__ = ["EventFeatureExtractor", "recordings_reference_set", "synthetic_reference_set"]


class EventFeatureExtractor:
    """Thresholded-map features of one single-target event (frames in, eq. 19 vector out); the
    accumulation is :func:`edge.classify.refgen.event_signatures`, as for the synthetic set."""

    def __init__(self, frontend: Any, config: Any, min_frames: int = 3, min_range_m: float | None = None) -> None:
        from edge.dsp.range_doppler import RangeDopplerProcessor
        from hal.waveform import characteristics

        sc = config.section("pipeline.surveillance")
        self.th_rd = float(sc.th_rd)
        self.min_frames = int(min_frames)
        # as refgen: cells nearer than one range resolution (leakage residue) are not the target
        self.min_range_m = characteristics(frontend).range_resolution_m if min_range_m is None else float(min_range_m)
        self.rd = RangeDopplerProcessor(frontend, k_c=sc.k_c, k_sf=sc.k_sf, n_range_fft=sc.n_range_fft,
                                        n_doppler_fft=sc.n_doppler_fft)
        self.extractor = SignatureExtractor(config.section("classify.features"), frontend)

    def __call__(self, frames: Iterable[Any]) -> np.ndarray:
        """``(F,)`` (eq. 19 and the range extent); NaN when the target was above ``th_RD`` in fewer
        than ``min_frames`` frames."""
        from edge.classify.refgen import event_signatures

        def points():
            for fr in frames:
                amp = self.rd.process(fr.iq()).amplitude
                yield fr.t_ns * 1e-9, MapPoints.from_map(amp, self.th_rd, self.rd.range_m, self.rd.radial_speed_kmh)

        acc = event_signatures(points(), self.extractor, self.min_range_m)
        return acc.features() if acc.n >= self.min_frames else np.full(len(FEATURE_NAMES), np.nan)


def _expand(paths: Sequence[str | Path]) -> list[Path]:
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out.extend(sorted(p.rglob("*.npz")))
        elif p.is_file():
            out.append(p)
        else:
            raise FileNotFoundError(f"recording {str(p)!r} not found")
    if not out:
        raise ValueError(f"no .npz recordings in {', '.join(map(str, paths))}")
    return out


def _label_of(path: Path, truth_classes: set[str], label: str | None, classes: Sequence[str]) -> str:
    if label:
        return label
    if path.parent.name in classes:
        return path.parent.name
    if len(truth_classes) == 1:
        return next(iter(truth_classes))
    if truth_classes:
        raise ValueError(f"{path}: ground truth holds classes {sorted(truth_classes)}; training needs single-target "
                         "events")
    raise ValueError(f"{path}: no class: put it in a directory named after its class ({', '.join(classes)}) "
                     "or pass --label")


def recordings_reference_set(
    paths: Sequence[str | Path],
    config: Any,
    *,
    label: str | None = None,
    classes: Sequence[str] = DEFAULT_CLASSES,
    progress: bool = False,
) -> ReferenceSet:
    """One feature vector per recording (single-target events; the recorded timestamps are used, so
    speeds do not depend on how fast the file is read); recordings whose target was above ``th_RD``
    in fewer than three frames are skipped with a warning."""
    from hal.frame import RawFrame
    from hal.recording import Recording

    files = _expand(paths)
    if label is not None and label not in classes:
        raise ValueError(f"unknown class {label!r}; classes: {', '.join(classes)}")
    it: Iterable[Path] = files
    if progress:
        from tqdm import tqdm

        it = tqdm(files, unit="recording", desc="features")
    feats, labels, names = [], [], []
    extractor: EventFeatureExtractor | None = None
    for path in it:
        rec = Recording(path)
        truth_classes = {c for k in range(len(rec)) for c in (getattr(rec.truth(k), "cls", None) or ())}
        truth_classes.discard("clutter")  # the site's swaying foliage (hw_sim.events.Foliage) is no target
        if extractor is None or extractor.rd.frontend != rec.frontend:
            extractor = EventFeatureExtractor(rec.frontend, config)
        frames = (RawFrame(seq=int(rec.seq[k]), t_ns=int(rec.t_ns[k]), i=rec.i[k], q=rec.q[k], frontend=rec.frontend)
                  for k in range(len(rec)))
        x = extractor(frames)
        cls = _label_of(path, truth_classes, label, classes)
        if cls not in classes:
            raise ValueError(f"{path}: class {cls!r} is not one of {', '.join(classes)}")
        if not np.all(np.isfinite(x)):
            log.warning("%s: target seen in fewer than two frames above th_RD, skipped", path)
            continue
        feats.append(x)
        labels.append(list(classes).index(cls))
        names.append(str(path))
    if not feats:
        raise ValueError("no recording gave a feature vector")
    return ReferenceSet(np.array(feats), np.array(labels), tuple(classes), FEATURE_NAMES,
                        meta={"generator": "recordings", "files": names})


def synthetic_reference_set(n: int, seed: int, config: Any, *, progress: bool = False) -> ReferenceSet:
    """``n`` simulated single-target events (rounded up to a multiple of the four classes, balanced),
    seeded: :func:`edge.classify.refgen.build_reference_set` with ``events_per_class = ceil(n / 4)``."""
    from edge.classify import refgen

    per_class = max(1, -(-int(n) // len(DEFAULT_CLASSES)))
    bar = None
    cb = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=per_class * len(DEFAULT_CLASSES), unit="event", desc=f"synthetic events (seed {seed})")

        def cb(done: int, total: int) -> None:
            bar.update(done - bar.n)

    try:
        return refgen.build_reference_set(events_per_class=per_class, seed=seed, config=config, progress=cb)
    finally:
        if bar is not None:
            bar.close()
