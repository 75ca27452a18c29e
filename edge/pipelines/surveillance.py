"""The surveillance profile (Tavanti et al. 2022, Fig. 2) on the Distance2Go, streaming frame by frame.

Stages, each timed:

``to_complex``    int16 I/Q -> complex64
``range_doppler`` IIR clutter/leakage canceller (step initialised, first chirp dropped), Kaiser
                  windows, zero-padded 2-D FFT, positive range half (:mod:`edge.dsp.range_doppler`)
``threshold``     bins at or above ``th_RD``
``dbscan``        DBSCAN in the wrapped 3-D (cylinder) metric (:mod:`edge.dsp.dbscan`)
``track``         signatures, Benedict-Bordner alpha-beta tracking with the cylinder constraint, event
                  segmentation, features and weighted k-NN when a track ends
                  (:class:`edge.track.surveillance.SurveillanceTracker`)

Unlike the paper, which records a whole event before processing it, every frame is processed as
it arrives: every confirmed track carries a provisional class and probability from its features so
far (``TrackState.cls``, ``class_probability``), and its final class, probabilities, mean radial
speed and direction are published as a :class:`~edge.types.ClassifiedEvent` on the frame it ends (``N_u`` misses, or the end of the
event). Detections are one row per cluster: centroid range, ``radial_speed_mps`` NaN (the Doppler
axis is aliased beyond ±5.4 km/h) with the wrapped Doppler in ``extra["doppler_wrapped_kmh"]``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from edge.classify.features import MapPoints
from edge.dsp.dbscan import CylinderDbscan
from edge.dsp.range_doppler import RangeDopplerProcessor, detection_mask
from edge.dsp.range_fft import to_complex64
from edge.pipeline import Pipeline, PipelineError, StageTimer
from edge.types import ClassifiedEvent, Detections, FrameResult, FrontendInfo, RawFrame, TrackState

log = logging.getLogger(__name__)

# a provisional class is set on a TrackState by copying its __dict__ (what dataclasses.replace's constructor call
# gives, without the frozen dataclass's per-field __setattr__) while TrackState has no __post_init__ and every
# field is an __init__ argument
_CLASS_PLAIN = (not hasattr(TrackState, "__post_init__") and all(f.init for f in fields(TrackState))
                and {"cls", "class_probability"} <= {f.name for f in fields(TrackState)})


def _with_class(ts: TrackState, cls: str, probability: float) -> TrackState:
    """``dataclasses.replace(ts, cls=cls, class_probability=probability)``, the same object built cheaper."""
    if not _CLASS_PLAIN:
        return replace(ts, cls=cls, class_probability=probability)
    d = dict(ts.__dict__)
    d["cls"] = cls
    d["class_probability"] = probability
    out = object.__new__(TrackState)
    object.__setattr__(out, "__dict__", d)
    return out


@dataclass(frozen=True)
class SurveillanceConfig:
    """Front end and clustering of the surveillance profile (Tavanti Table III)."""

    k_c: float = field(
        default=0.5, metadata={"doc": "IIR canceller feedback K_c (0 = single delay-line canceller); Table III",
                               "min": 0.0, "max": 0.99}
    )
    k_sf: float = field(
        default=3.0, metadata={"doc": "Kaiser shape factor K_sf (scipy's beta) of the range and Doppler windows; Table III",
                               "min": 0.0, "max": 20.0}
    )
    th_rd: float = field(
        default=2.0,
        metadata={"unit": "counts", "doc": "th_RD: map bins at or above this are points (map amplitude: a tone of A ADC "
                  "counts reads A); Table III's value, which `radar-edge calibrate` reproduces on the simulated "
                  "site (mean of empty-scene maxima + 3 std)", "min": 1e-6, "max": 1e6},
    )
    sidelobe_guard_db: float = field(
        default=0.0,
        metadata={"unit": "dB", "doc": "beyond the paper: a cell is a point only if it is at most this far below the"
                                       " strongest cell of its range row and of its Doppler column (drops strong "
                                       "echoes' sidelobes, edge.dsp.range_doppler.detection_mask); 0 = off (paper)", "min": 0.0, "max": 120.0},
    )
    eps: float = field(
        default=1.9,
        metadata={"unit": "m | km/h", "doc": "DBSCAN radius in the wrapped map (range in m, wrapped Doppler in km/h; "
                  "DESIGN §5); Table III", "min": 0.01, "max": 100.0},
    )
    min_points: int = field(
        default=80, metadata={"doc": "DBSCAN M: points within eps (itself included) that make a core point, nearer "
                                     "than far_range_m; Table III",
                              "min": 1, "max": 100000}
    )
    min_points_far: int = field(
        default=40, metadata={"doc": "beyond the paper: DBSCAN M at far_range_m and beyond, where a weak walker's "
                                     "echo (falling as r^-2) covers fewer cells above th_RD; = min_points: the paper",
                              "min": 1, "max": 100000}
    )
    far_range_m: float = field(
        default=12.0, metadata={"unit": "m", "doc": "range from which min_points_far applies", "min": 0.0, "max": 1000.0}
    )
    n_range_fft: int = field(
        default=512, metadata={"doc": "N_R: zero-padded range FFT length (positive half kept); Table III",
                               "choices": (64, 128, 256, 512, 1024, 2048)}
    )
    n_doppler_fft: int = field(
        default=256, metadata={"doc": "N_D: zero-padded Doppler FFT length; Table III",
                               "choices": (32, 64, 128, 256, 512, 1024)}
    )
    keep_map: bool = field(
        default=True, metadata={"doc": "return the range-Doppler map and point labels in FrameResult.intermediates"}
    )


class SurveillancePipeline(Pipeline):
    profile = "surveillance"
    stages = ("to_complex", "range_doppler", "threshold", "dbscan", "track")

    def __init__(self, frontend: FrontendInfo, config: SurveillanceConfig, full_config: Any = None,
                 tracker: Any = None) -> None:
        super().__init__(frontend, config)
        try:
            self.rd = RangeDopplerProcessor(
                frontend, k_c=config.k_c, k_sf=config.k_sf, n_range_fft=config.n_range_fft,
                n_doppler_fft=config.n_doppler_fft,
            )
        except ValueError as exc:
            raise PipelineError(f"surveillance profile needs a Distance2Go-like front end: {exc}") from None
        self.dbscan = CylinderDbscan(
            self.rd.n_range, self.rd.n_doppler_fft, self.rd.range_bin_m, self.rd.cylinder_radius_kmh,
            config.eps, config.min_points, config.min_points_far, config.far_range_m,
        )
        if tracker is None:
            from edge.config import load_config
            from edge.track.surveillance import SurveillanceTracker

            cfg = full_config if full_config is not None else load_config(env={})
            tracker = SurveillanceTracker.from_config(frontend, cfg, threshold=config.th_rd)
        self.tracker = tracker
        self._iq = np.empty(frontend.frame_shape, dtype=np.complex64)
        self._last_t_ns = 0
        self._period_ns = int(round(frontend.waveform.frame_period_s * 1e9))
        self._offset_ns = 0
        self._last_query: tuple[Any, bytes, np.ndarray] | None = None  # provisional classes: classifier, features, answer

    @classmethod
    def from_config(cls, frontend: FrontendInfo, config: Any) -> "SurveillancePipeline":
        """From a resolved :class:`edge.config.Config` (all sections)."""
        return cls(frontend, config.section("pipeline.surveillance"), full_config=config)

    def process(self, frame: RawFrame, timer: StageTimer) -> FrameResult:
        cfg = self.config
        rd = self.rd
        with timer.stage("to_complex"):
            iq = to_complex64(frame, self._iq)
        with timer.stage("range_doppler"):
            m = rd.process(iq).amplitude
        with timer.stage("threshold"):
            mask = detection_mask(m, cfg.th_rd, cfg.sidelobe_guard_db)
        with timer.stage("dbscan"):
            clu = self.dbscan.fit(mask)
        with timer.stage("track"):
            rb, db = clu.range_bin, clu.doppler_bin
            pts = MapPoints(
                rd.range_m[rb], rd.radial_speed_kmh[db], m[rb, db], rb.astype(np.int32), db.astype(np.int32),
                clu.labels,
            )
            level = float(m.max())
            # the tracker's clock is the board's frame counter times the frame period: host receive
            # times jitter (USB) and mean nothing when a recording is replayed unpaced
            t_seq = frame.seq * self._period_ns
            self._offset_ns = frame.t_ns - t_seq
            step = self.tracker.update(t_seq, pts, level=level)
            lab = step.intermediates.get("cluster_labels")
            assoc = {
                int(tid): float(step.signatures.range_m[lab[j]]) for tid, j in step.tracker.assigned.items()
            } if lab is not None else {}
            det = self._detections(step, clu.n_clusters)
            tracks = self._provisional_classes(step.tracks)
        self._last_t_ns = frame.t_ns
        inter: dict[str, Any] = {"th_rd": cfg.th_rd, "level": level, "n_points": len(clu), "n_clusters": clu.n_clusters,
                                 "track_cluster_range_m": assoc,
                                 "tracks_ended_without_event": step.intermediates.get("ended_without_event", [])}
        if cfg.keep_map:
            inter.update({"rd_map": m, "range_m": rd.range_m, "radial_speed_kmh": rd.radial_speed_kmh,
                          "range_bin": rb, "doppler_bin": db, "labels": clu.labels})
        return FrameResult(
            profile=self.profile, seq=frame.seq, t_ns=frame.t_ns, detections=det, tracks=tracks,
            classifications=self._host_times(step.classifications), intermediates=inter,
        )

    def _detections(self, step: Any, n_clusters: int) -> Detections:
        """One detection per cluster with cells: what ``Detections.from_polar(range, nan, nan, nan, extra)`` gives
        (azimuth unknown: on boresight, ``x = range * sin(0)``, ``y = range * cos(0)``), built directly."""
        sig = step.signatures
        n_pts = np.asarray(sig.n_points)
        ok = n_pts > 0
        if ok.all():  # DBSCAN's clusters always have cells: no selection
            if not ok.size:
                return Detections.empty()
            c, rng = np.asarray(sig.centroid), np.asarray(sig.range_m)
        else:
            if not ok.any():
                return Detections.empty()
            c, rng, n_pts = np.asarray(sig.centroid)[ok], np.asarray(sig.range_m)[ok], n_pts[ok]
        _, v_wrapped = self.rd.unwrap(c)
        r = np.array(rng, dtype=np.float32)
        nan = np.full(r.size, np.nan, dtype=np.float32)
        return Detections(r, nan, nan, nan, r * np.float32(0.0), r * np.float32(1.0),
                          {"doppler_wrapped_kmh": v_wrapped, "n_points": n_pts.astype(np.int32)})

    def _provisional_classes(self, tracks: tuple) -> tuple:
        """Class and probability of each live track from its features so far (eq. 21), so outputs can
        show a class while the target is in view; the final answer is the track's ClassifiedEvent.

        Uses the tracker's per-track feature accumulators (``SurveillanceTracker._acc``); tracks
        with fewer than two frames of signatures keep ``cls = None``. When every row is the same as in
        the previous frame's query (no track got a cluster, none started or ended), the classifier is
        not asked again: its answer is a function of its input.
        """
        acc = getattr(self.tracker, "_acc", None)
        clf = getattr(self.tracker, "classifier", None)
        if not tracks or acc is None or clf is None:
            return tuple(tracks)
        rows, feats = [], []
        isfinite = math.isfinite
        for k, ts in enumerate(tracks):
            a = acc.get(ts.track_id)
            if a is not None and a.n >= 2:
                x = a.features()
                if all(isfinite(v) for v in x.tolist()):
                    rows.append(k)
                    feats.append(x)
        if not rows:
            return tuple(tracks)
        x = np.array(feats)
        key = x.tobytes()
        last = self._last_query
        if last is not None and last[0] is clf and last[1] == key:  # same rows, same order: the same answer
            p = last[2]
        else:
            p = clf.predict_proba(x)
            self._last_query = (clf, key, p)
        out = list(tracks)
        for k, b, pk in zip(rows, p.argmax(axis=1).tolist(), p):
            out[k] = _with_class(out[k], clf.classes[b], float(pk[b]))
        return tuple(out)

    def _host_times(self, events: tuple) -> tuple:
        """Event times from frame-counter time back to host monotonic time (offset of the last frame)."""
        off = self._offset_ns
        return tuple(replace(e, start_ns=e.start_ns + off, end_ns=e.end_ns + off) for e in events)

    def flush(self) -> tuple[ClassifiedEvent, ...]:
        """End and classify every open track (end of a recording or a scenario)."""
        return self._host_times(tuple(self.tracker.close(self._last_t_ns - self._offset_ns)))

    def close(self) -> None:
        out = self.flush()
        if out:
            log.info("surveillance: %d track(s) classified at stop", len(out))
