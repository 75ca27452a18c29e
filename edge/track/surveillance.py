"""Surveillance back end, frame by frame: signatures -> alpha-beta tracks -> features -> k-NN.

:class:`SurveillanceTracker` is what the surveillance pipeline calls after thresholding and DBSCAN::

    st = SurveillanceTracker.from_config(frontend, cfg, threshold=th_rd)
    step = st.update(frame.t_ns, points, level=rd_map_max, seq=frame.seq)  # points: MapPoints, DBSCAN labels
    step.tracks            # TrackState of the confirmed tracks (seen in >= 3 frames)
    step.classifications   # ClassifiedEvent of every track that ended in this frame
    ...
    st.close(t_ns)         # at stop: end and classify every open track

Per frame it computes the clusters' signatures (:class:`~edge.classify.features.SignatureExtractor`),
steps the :class:`~edge.track.alphabeta.AlphaBetaTracker` with the cluster centroids, adds each
assigned cluster's signature to its track's :class:`~edge.classify.features.TrackFeatureAccumulator`,
and feeds the frame's level to the :class:`~edge.track.events.EventSegmenter`. A track ends when it
has missed ``N_u`` frames or when the event ends (hysteresis), and is classified there and then
(streaming, not after the whole event as in the paper): class, eq. 21 probabilities, mean radial
speed and direction. The speed is the trimmed mean (``event_speed``) of the track's per-frame radial
speeds, each the cluster's wrapped Doppler with its alias chosen by the range rate of the centroid
(of the body's leading edge for a long one, ``event_speed_leading_edge_m``), without the frames
faster than the target's far frames (``event_speed_cap_range_m``: wrong aliases beside the radar)
(:class:`~edge.classify.features.RadialSpeedEstimator`, km/h, positive receding); the least-squares
range rate when that is not available. With ``event_speed_alias = "history"`` the alias is chosen against
the range rate of the track's whole history (of a long body's leading edge too), and the event's
``speed_uncertain`` is set when that choice is not sure (:meth:`~edge.classify.features.RadialSpeedEstimator.history_alias`);
with ``"fit"`` one reference is fitted to the range history of the centroid (and of a long body's edges) with the
Doppler as its slope, and ``speed_uncertain`` is set when no alias fits clearly better than the others
(:meth:`~edge.classify.features.RadialSpeedEstimator.fit_alias`; the event's speed is that of the frames on the
fitted path).

Beyond the paper (``track.alphabeta`` options; 0 restores the paper): once a track has clusters in
``doppler_range_rate_frames`` frames, its alpha-beta range rate is replaced after every update by its
current unaliased radial speed, so fast vehicles are predicted where they will be; and a *merge
guard*: a cluster with more than ``merge_ratio`` times the median point count of the track's last
clusters and than its last own cluster is its target merged with another one (a car passing a pedestrian, Tavanti Fig. 9(d); a track
with fewer than ``merge_history_frames`` clusters only with another track predicted within ``gate_radius``) --
the track counts the frame as seen but keeps its predicted state and adds nothing to its features
or speed -- while a track left without a cluster whose prediction lies in such an enlarged cluster is
*occluded*: it coasts without counting misses or ageing (at most ``merge_max_frames`` frames), so it
picks its own cluster up again when the targets separate instead of ending and restarting.

One track per target (Tavanti §II-E, Figs. 9-11: merges and splits resolved in the tracker), each
measured on multi-random dev seeds (field docs):

* *co-range fragments* (``corange_fragment_m``, in :class:`~edge.track.alphabeta.AlphaBetaTracker`):
  a jogger's legs at twice the torso's speed wrap around the +-5.4 km/h interval and DBSCAN cuts them
  off at the same range; such a cluster starts no track (and a younger track assigned one loses it):
  its cells join the track's signature of the frame (:attr:`~edge.track.alphabeta.TrackerStep.absorbed`);
* *range gate* (``range_gate_m``): a slow track's coasting prediction does not jump 5 m to another
  walker (R_gate alone is 6 m | km/h);
* *shared clusters* (``shared_span_m``): two walkers crossing make one cluster for seconds, its
  centroid between them; an established track predicted inside the range span of the cluster
  another track took coasts hidden (no misses), and the other keeps its prediction too when the two
  are of comparable size, so neither is dragged onto the other's path and both pick their own
  clusters up when they separate;
* *continuation* (``continuation_speed_kmh``): a track that ends although a track started after its
  last cluster lies where its speed (or range rate) in its direction takes it hands its frames to that
  track -- one event, features and mean speed over the whole passage -- instead of being classified on
  its own (a motorcycle accelerating in radial speed past the radar outruns its prediction). With
  ``continuation_hold_frames``, a moving track that nothing continues yet waits that long, its id kept,
  and joins the one confirmed track in view if that track continues it while no other track waits (a
  walker fading below th_RD for longer than ``max_missed_frames``); its event comes after the wait, which the
  end of the passage's echo (the event segmenter) does not cut short;

* *rigid bodies* (``rigid_*``): a car passing 3 m beside the radar shows its front and rear as two
  clusters with one Doppler, each with a track; a younger track whose cluster stays within
  ``rigid_length_m`` of an older vehicle track (at least ``rigid_min_speed_kmh``, faster than any
  jogger, so walkers side by side are never merged) at its wrapped Doppler, with a steady separation
  for ``rigid_frames`` frames, is merged into it (signatures united, no event of its own), and a track
  started later where that part was joins at once;
* *passage beside the radar* (``passage_*``): a short track (at most ``passage_max_frames`` frames,
  near the radar, slow or at the vehicle's speed) next to a live vehicle track in place and time, its extents within
  ``body_gap_m`` of the vehicle's in most of the frames paired in time, is that vehicle seen while it passes beside
  the radar, its Doppler near zero: its signatures join the vehicle's (Tavanti Test 1's departing car); the vehicle
  is one at least ``rigid_min_speed_kmh`` fast or, with ``vehicle_by_class``, one the classifier reads as a vehicle;
* *body parts* (``body_length_m``, ``body_gap_m``, ``body_doppler_kmh``, ``body_rate_kmh``): a track that ends while
  a vehicle's track lives, whose clusters were near that track's (centres within ``body_length_m``) at its wrapped
  Doppler, adjacent (extents within ``body_gap_m``) or moving at its range rate, is a part of that body (a truck's
  front, body and rear split by DBSCAN): its frames join the living track, one event for the passage; a vehicle's
  track is one at least ``rigid_min_speed_kmh`` fast or, with ``vehicle_by_class``, one the classifier reads as a
  vehicle from its features so far (a truck at about an alias step of radial speed, whose Doppler reads near zero).
  With ``body_overlap_any_doppler``, a part whose extents overlap the vehicle's in most of the frames both were seen
  in joins at any wrapped Doppler (beside the radar a body's parts are seen at aspects whose radial speeds differ by
  up to its speed, and its wheels at 0-2 times it). The pairing covers at least half of the ending track's frames, or
  it is a *handover*: a younger vehicle track, seen beside it before its last cluster, that took the body over, paired
  in half of its frames since; a handover needs overlapping extents (a vehicle following another moves at its rate).
  A track held by ``continuation_hold_frames`` whose last cluster came after the ending track's first one is also
  a candidate; its extents must overlap the part's in most of the frames both were seen in (a vehicle's far end
  cut off at the board's largest range outlives the body's track);
* *merge guard needs another target* (``merge_other_required``): an enlarged cluster holds a track on
  its prediction only when another track is near it; an approaching car growing six-fold alone is
  itself, not a merge.
* *static zones* (``static_zone_*``, :mod:`edge.track.static_zones`): a slow cluster in a range cell that
  slow clusters keep covering (swaying foliage) is site clutter: it starts and feeds no track.

*Fragments* (``fragment_gap_m``, ``fragment_link_fraction``; off by default, see the field's doc for
the measurements): a truck passing beside the radar spans
several metres of range and a wide Doppler spread, and DBSCAN often splits it into two or three
clusters, each starting a track. Two tracks whose clusters of a frame come within ``fragment_gap_m``
of each other in range, with radial speeds within ``fragment_speed_kmh``, are *linked* in that frame. A track that ends (or is dropped) linked to a
track still alive, or ending later in the same batch, in at least ``fragment_link_fraction`` of its own
frames is a fragment: its per-frame cluster sums (:class:`~edge.classify.features.SignatureLog`) join
that track's, so the features of eqs. 17-19 are computed, frame by frame, on the union of the
target's cells -- what the reference set's thresholded signatures see -- and no event is published
for the fragment (its id disappears as a dropped one). A pedestrian passed by a car is linked to it
for a frame or two of its passage only, and keeps its own event.

Published :class:`~edge.types.TrackState`: tracks seen in at least ``min_seen_frames`` frames and
not coasting for more than ``publish_coasting_frames`` frames. The alpha-beta state lives on the
wrapped map and only serves the association (Tavanti §II-D: with ``alpha = 0.19`` it lags a 40 km/h
car by metres), so the published kinematics come from the measured clusters: ``radial_speed_mps``
is the unaliased radial speed of the latest frame (wrapped Doppler + alias from the range rate; the
filtered rate ``u_r`` until two frames exist) and ``range_m`` the last centroid's range less the range-Doppler
coupling of that speed (``v f_c / S``: 0.18 s on the Distance2Go's 1.5 ms up-chirp, 1.75 m at 35 km/h receding),
moved on by that speed over the time since it was seen (never below 0). With ``classify.features.event_speed_alias =
"history"`` (or ``"fit"``, fitted to the latest :data:`LIVE_FIT_FRAMES` frames and kept while certain for at most
:data:`LIVE_REFIT_FRAMES`) the published speed is NaN (n/a on Modbus and CAN) while the alias of the track's history
is not certain or the latest frame's speed is not on it. The Distance2Go has one
receive channel, so the azimuth is unknown (NaN) and, as in
:meth:`edge.types.Detections.from_polar`, the target is placed on boresight (``x = 0``, ``y = range``).
A published id that disappears from ``tracks`` without a :class:`~edge.types.ClassifiedEvent` was
dropped (``vis / age < th_v``); its id may be reused.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edge.classify.features import (
    FEATURE_NAMES,
    ClusterSignatures,
    FeatureConfig,
    MapPoints,
    RadialSpeedEstimator,
    SignatureExtractor,
    SignatureLog,
    TrackFeatureAccumulator,
    plain_median,
)
from edge.classify.classifier import build_classifier
from edge.classify.knn import KnnConfig, knn_for
from edge.classify.reference import load_reference_set
from edge.track.alphabeta import AlphaBetaConfig, AlphaBetaTrack, AlphaBetaTracker, TrackerStep
from edge.track.events import EventConfig, EventSegmenter, SegmentStep
from edge.track.static_zones import StaticZones
from edge.types import ClassifiedEvent, FrontendInfo, TrackState, track_state
from hal.waveform import characteristics

log = logging.getLogger(__name__)

__all__ = ["SurveillanceStep", "SurveillanceTracker", "UNKNOWN_CLASS"]

#: class reported when a track's features cannot be computed, or when classification is off
UNKNOWN_CLASS = "unknown"
#: event_speed_alias = "fit": the live speed's alias is judged on the latest frames (5 s; bounds the work per frame);
#: a certain fit is kept for LIVE_REFIT_FRAMES frames (2 s) while the latest frame's speed on it is the current speed
LIVE_FIT_FRAMES = 25
LIVE_REFIT_FRAMES = 10


@dataclass(frozen=True, eq=False)
class SurveillanceStep:
    """Result of one frame; ``signatures``, ``tracker`` and ``event`` are intermediates for plots."""

    tracks: tuple[TrackState, ...]
    classifications: tuple[ClassifiedEvent, ...]
    event: SegmentStep
    signatures: ClusterSignatures
    tracker: TrackerStep
    intermediates: dict[str, Any] = field(default_factory=dict)


def _finite_or_zero(x: float) -> float:
    return x if math.isfinite(x) else 0.0


def _extent_gaps(x: tuple[np.ndarray, np.ndarray, np.ndarray], y: tuple[np.ndarray, np.ndarray, np.ndarray],
                 k: np.ndarray) -> np.ndarray:
    """Range gap (m, 0 where they overlap) between the extents of each of a track's frames ``x`` = (centroid, near,
    far edge) and those of frame ``k`` of another track's ``y``; the centroids' distance where an extent is not
    known."""
    (r_x, lo_x, hi_x), (r_y, lo_y, hi_y) = x, y
    gap = np.maximum(0.0, np.maximum(lo_x - hi_y[k], lo_y[k] - hi_x))
    return np.where(np.isfinite(gap), gap, np.abs(r_x - r_y[k]))


def _within(d0: float, d1: float, d2: float, radius: float) -> bool | None:
    """Is ``float(np.linalg.norm([d0, d1, d2])) <= radius``? Decided in plain Python when the squared norm lies
    clearly on one side of ``radius**2`` (numpy's dot product may sum it in another order, a few units in the last
    place apart); None when it is too close to tell (or NaN): then numpy decides."""
    s = (d0 * d0 + d1 * d1) + d2 * d2
    r2 = radius * radius
    if s < r2 * (1.0 - 1e-9):
        return True
    if s > r2 * (1.0 + 1e-9):
        return False
    return None


class SurveillanceTracker:
    """See the module docstring. ``threshold`` is th_RD in the map's amplitude unit."""

    def __init__(
        self,
        frontend: FrontendInfo,
        threshold: float,
        *,
        tracking: AlphaBetaConfig | None = None,
        events: EventConfig | None = None,
        features: FeatureConfig | None = None,
        knn: Any = None,
        classify: bool = True,
    ) -> None:
        self.frontend = frontend
        self.frame_period_s = frontend.waveform.frame_period_s
        self.extractor = SignatureExtractor(features or FeatureConfig(), frontend)
        self.cylinder = self.extractor.cylinder
        # a receding body's far edge nearer the board's largest range than this is cut off (history alias)
        ch = characteristics(frontend)
        self._edge_limit_m = ch.max_unambiguous_range_m - self.extractor.config.event_speed_alias_edge_clip_m
        # range-Doppler coupling: a radial speed v moves a chirp's beat by 2 v / lambda, its range by v f_c / S
        seg = frontend.waveform.segments[0]
        self._coupling_s = seg.f_start_hz / seg.slope_hz_per_s
        self.tracker = AlphaBetaTracker(tracking or AlphaBetaConfig(), self.cylinder)
        self.tracker.keep_ended_ids = self.tracker.config.continuation_hold_frames > 0
        self._held: dict[int, tuple[AlphaBetaTrack, int]] = {}  # ended track id -> (track, last frame it waits)
        tc = self.tracker.config
        self.static_zones = (StaticZones(ch.range_resolution_m, ch.max_unambiguous_range_m, self.frame_period_s,
                                         tc.static_zone_time_s, tc.static_zone_speed_kmh, tc.static_zone_occupancy)
                             if tc.static_zone_time_s > 0 else None)
        if self.tracker.config.merge_ratio > 0:
            self.tracker.occlusion_test = self._hidden_in
        self._frame_sizes = np.zeros(0, dtype=np.int64)
        self._frame_lo = self._frame_hi = np.zeros(0)
        self._shared = {}
        self.absorbed = 0  # clusters that joined a track's frame as its co-range fragments
        self.segmenter = EventSegmenter(events or EventConfig(), threshold)
        self.classifier: Any  # WeightedKNN or OnnxKnnClassifier (same predict interface), or None
        if not classify:
            self.classifier = None  # features only (building reference sets): cls = "unknown"
        elif knn is not None and not isinstance(knn, KnnConfig):  # WeightedKNN or OnnxKnnClassifier
            self.classifier = knn
        else:
            kc = knn or KnnConfig()
            ref = load_reference_set(kc.reference_set or None)
            self.classifier = knn_for(ref, kc)
        self._acc: dict[int, TrackFeatureAccumulator] = {}
        self._speed: dict[int, RadialSpeedEstimator] = {}
        self._live_fit: dict[int, tuple[float, float, bool]] = {}  # track id -> last frame's time, reference, certain
        self.classified = 0
        self.dropped = 0
        self._seen_t: dict[int, float] = {}  # track id -> sensor time (s) of its last cluster
        self._size: dict[int, deque] = {}  # track id -> point counts of its last clusters (not merged)
        self._merged_run: dict[int, int] = {}  # track id -> merged frames in a row
        self.merged_frames = 0
        self._log: dict[int, SignatureLog] = {}  # track id -> per-frame cluster sums (its own and its fragments')
        self._links: dict[int, dict[int, int]] = {}  # track id -> {other track id: frames with adjacent clusters}
        self.fragments = 0  # tracks whose cells joined another track's signatures
        self.continued = 0  # ended tracks continued by a later track of the same target
        self.rigid_merges = 0  # younger tracks merged into an older one as parts of one rigid body
        self.rigid_parts = 0  # new tracks merged in their first frame into the body a part was merged into
        self.body_parts = 0  # ended tracks joined to a live track of the same vehicle body (body_length_m)
        self.passages = 0  # short tracks of a vehicle's passage beside the radar joined to its track
        self._rigid: dict[tuple[int, int], list[float]] = {}  # (older, younger) -> separations of the frames counted
        self._body: dict[int, tuple[float, float]] = {}  # track id -> range offsets of the parts merged into it
        self._start_ns: dict[int, int] = {}  # track id -> start of the earliest track it continues
        self._batch_created: dict[int, int] = {}  # track id -> creation time, of the tracks ending in this batch
        self._forgotten: list[int] = []  # ids forgotten in this frame (ended, dropped or joined to another track)

    @classmethod
    def from_config(cls, frontend: FrontendInfo, config: Any, threshold: float) -> "SurveillanceTracker":
        """Build from a resolved :class:`edge.config.Config` (sections ``track.alphabeta``,
        ``track.events``, ``classify.features``, and ``classify.onnx``/``classify.knn`` for the classifier:
        :func:`edge.classify.classifier.build_classifier`, the ONNX model by default)."""
        return cls(
            frontend,
            threshold,
            tracking=config.section("track.alphabeta"),
            events=config.section("track.events"),
            features=config.section("classify.features"),
            knn=build_classifier(config),
        )

    # ------------------------------------------------------------------------------------------
    def update(self, t_ns: int, points: MapPoints, level: float | None = None, seq: int | None = None) -> SurveillanceStep:
        """One frame. ``level`` defaults to the largest point amplitude (0 without points).

        Kinematics (radial speeds, the features' range rates) need the *sensor* clock: host arrival
        times jitter and mean nothing for a replay at full speed. Give either ``seq``, the board's
        frame counter (time = ``seq * frame_period``, gaps = dropped frames), or a ``t_ns`` that is
        already on the sensor clock, as :class:`~edge.pipelines.surveillance.SurveillancePipeline`
        does (``seq * period``, mapped back to host time for its outputs). ``t_ns`` also stamps the
        tracks' start/end in the :class:`~edge.types.ClassifiedEvent`.
        """
        if level is None:
            level = float(np.max(points.amplitude)) if len(points) else 0.0
        self._forgotten = []
        sig = self.extractor(points)
        valid = sig.n_points > 0
        if self.static_zones is not None:  # slow clusters where something stands: site clutter, no track
            k = np.flatnonzero(valid).tolist()
            standing = self.static_zones.update(np.asarray(sig.range_m)[k].tolist(),
                                                np.asarray(sig.doppler_kmh)[k].tolist(),
                                                np.asarray(sig.range_lo_m)[k].tolist(),
                                                np.asarray(sig.range_hi_m)[k].tolist())
            if standing:
                valid = valid.copy()
                valid[[k[i] for i in standing]] = False
        pred: dict[int, np.ndarray] = {}
        p = None
        if self.tracker.config.merge_ratio > 0 and self.tracker.tracks:
            p = self.tracker.filter.predict(np.stack([tr.state for tr in self.tracker.tracks]))
            pred = {tr.track_id: p[k] for k, tr in enumerate(self.tracker.tracks)}
        if valid.all():  # every cluster has cells (DBSCAN's always): the arrays as they are
            labels = np.arange(valid.size, dtype=np.intp)
            self._frame_sizes, self._frame_lo, self._frame_hi = sig.n_points, sig.range_lo_m, sig.range_hi_m
            centroids = sig.centroid
        else:
            labels = np.flatnonzero(valid)
            self._frame_sizes = np.asarray(sig.n_points)[valid]
            self._frame_lo = np.asarray(sig.range_lo_m)[valid]
            self._frame_hi = np.asarray(sig.range_hi_m)[valid]
            centroids = sig.centroid[valid]
        self._shared: dict[int, list[int]] = {}  # centroid index -> ids of the tracks hidden in it by its span
        tstep = self.tracker.step(t_ns, centroids, predicted=p)
        t_s = t_ns * 1e-9 if seq is None else int(seq) * self.frame_period_s
        frame_key = int(round(t_s / self.frame_period_s))
        out: list[ClassifiedEvent] = []
        alive = {tr.track_id for tr in self.tracker.tracks} - set(tstep.created)
        out.extend(self._end_tracks(tstep.ended, tstep.dropped, alive, frame_key))
        for tid in tstep.created:
            self._size[tid] = deque(maxlen=self.tracker.config.merge_history_frames)
            self._merged_run[tid] = 0
            self._acc[tid] = TrackFeatureAccumulator(self.extractor.config.extent_percentile,
                                                     vmax_kmh=self.extractor.speed_vmax_kmh)
            self._speed[tid] = RadialSpeedEstimator(self.cylinder.vmax_kmh)
            cfg_t = self.tracker.config
            if cfg_t.fragment_gap_m > 0 or cfg_t.continuation_speed_kmh > 0:  # united with a fragment's or
                self._log[tid] = SignatureLog()  # an earlier track's rows; else never read
            self._links[tid] = {}
        recorded: list[tuple[int, int]] = []
        n_aid = self.tracker.config.doppler_range_rate_frames
        by_id = {tr.track_id: tr for tr in self.tracker.tracks}
        merged: list[int] = []
        parts: dict[int, list[int]] = {}  # track id -> labels of its co-range fragments this frame
        for j, tid in tstep.absorbed.items():
            parts.setdefault(tid, []).append(int(labels[j]))
        self.absorbed += len(tstep.absorbed)
        for tid, j in tstep.assigned.items():
            lab = labels[j]
            shared = self._shares_with(tid, j)
            if shared or self._is_merged(
                    tid, int(sig.n_points[lab]), self._other_track_near(tid, sig.centroid[lab], pred),
                    lambda: self._any_track_near(tid, sig.centroid[lab], pred, sig.range_lo_m[lab], sig.range_hi_m[lab])):
                tr = by_id.get(tid)
                if tr is not None and tid in pred:  # keep the prediction: the centroid is not this target's
                    tr.state = pred[tid]
                    tr.last_measurement = pred[tid][[0, 2, 4]].copy()
                merged.append(tid)
                continue
            own = [int(lab)] + parts.get(tid, [])
            if len(own) == 1:  # the numpy reductions below of one value: the value (a sum adds it to 0.0)
                lo, hi = float(sig.range_lo_m[lab]), float(sig.range_hi_m[lab])
                blo, bhi = float(sig.body_lo_m[lab]), float(sig.body_hi_m[lab])
                n_lab = float(sig.n_points[lab])
                circ, rcs, r_mean = sig.circular_variance[lab], sig.rcs[lab], sig.range_m[lab]
                cos_sum, sin_sum = 0.0 + float(sig.cos_sum[lab]), 0.0 + float(sig.sin_sum[lab])
            else:  # the union of the track's cluster and its co-range fragments (eqs. 17, 18 on all cells)
                lo, hi = float(np.min(sig.range_lo_m[own])), float(np.max(sig.range_hi_m[own]))
                blo, bhi = float(np.min(sig.body_lo_m[own])), float(np.max(sig.body_hi_m[own]))
                n_lab = float(np.sum(sig.n_points[own]))
                cos_sum, sin_sum = float(np.sum(sig.cos_sum[own])), float(np.sum(sig.sin_sum[own]))
                res = math.hypot(cos_sum, sin_sum)
                circ = 1.0 - res / n_lab
                rcs = float(np.sum(sig.rcs[own]))
                r_mean = float(np.sum(sig.n_points[own] * sig.range_m[own])) / n_lab
            self._acc[tid].add(t_s, circ, rcs, r_mean, bhi - blo, sig.doppler_kmh[lab])  # the body's extent
            log_ = self._log.get(tid)
            if log_ is not None:
                log_.add(frame_key, t_s, n_lab, cos_sum, sin_sum, rcs, n_lab * float(r_mean), blo, bhi,
                         float(sig.doppler_kmh[lab]))
            recorded.append((tid, int(lab)))
            spd = self._speed[tid]
            spd.add(t_s, sig.range_m[lab], sig.doppler_kmh[lab], lo, hi)
            self._seen_t[tid] = t_s
            tr = by_id.get(tid)
            if n_aid > 0 and tr is not None and len(spd) >= n_aid:
                v_kmh = spd.current_radial_speed_kmh()
                if math.isfinite(v_kmh):  # Doppler-aided range rate (m per frame), see AlphaBetaConfig
                    tr.state[5] = v_kmh / 3.6 * self.frame_period_s
        self._link(recorded, points)
        if self.tracker.config.rigid_min_speed_kmh > 0:
            self._rigid_merge(recorded, sig)
        if self._held:
            out.extend(self._resolve_held(frame_key))
        seg = self.segmenter.step(t_ns, level)
        if seg.ended or seg.discarded:  # the echo's end closes the live tracks; held ones wait out their hold
            out.extend(self._close_tracks(keep_held=True))
        tracks = tuple(self._track_state(tr, t_s) for tr in self.tracker.confirmed())
        done_ids = {ev.track_id for ev in out}
        inter = {"centroids": centroids, "cluster_labels": labels, "level": level, "merged_tracks": merged,
                 "ended_without_event": [i for i in self._forgotten if i not in done_ids]}
        return SurveillanceStep(tracks, tuple(out), seg, sig, tstep, inter)

    def close(self, t_ns: int | None = None) -> tuple[ClassifiedEvent, ...]:
        """End every open track (stop, or end of a recording) and classify those seen often enough."""
        return tuple(self._close_tracks())

    # ------------------------------------------------------------------------------------------
    def _close_tracks(self, keep_held: bool = False) -> list[ClassifiedEvent]:
        """End every live track; also classify the held ones unless ``keep_held`` (a target that faded for longer than
        the segment's release may come back within their hold)."""
        held = []
        if not keep_held:
            held = [self._finish(tr) for tr, _ in self._held.values()]
            for tid in self._held:
                self.tracker.ids.release(tid)
            self._held = {}
        ended, dropped = self.tracker.close_all()
        return held + self._end_tracks(ended, dropped, set())

    def _resolve_held(self, frame: int) -> list[ClassifiedEvent]:
        """Held tracks (``continuation_hold_frames``): one whose wait is over is classified. While a single
        track waits and a single confirmed track lives, it joins that track if that track continues it
        (:meth:`_successor`): with other targets in view a target's successor is ambiguous (two walkers in step)."""
        tracks = self.tracker.tracks
        alone = (len(self._held) == 1 and len(tracks) == 1
                 and tracks[0].seen_frames >= self.tracker.config.min_seen_frames)
        out: list[ClassifiedEvent] = []
        for tid, (tr, last) in list(self._held.items()):
            succ = self._successor(tr, {tracks[0].track_id}) if alone else None
            if succ is not None:
                self._continue(tr, succ)
            elif frame >= last:
                out.append(self._finish(tr))
            else:
                continue
            del self._held[tid]
            self.tracker.ids.release(tid)
        return out

    def _moving(self, track_id: int) -> bool:
        """Is the track's mean radial speed above ``static_zone_speed_kmh``? A standing echo's successor
        would be any later track at its range."""
        spd = self._speed.get(track_id)
        v = spd.mean_radial_speed_kmh() if spd is not None and len(spd) else math.nan
        return abs(v) > self.tracker.config.static_zone_speed_kmh

    def _continue(self, tr: AlphaBetaTrack, succ: int) -> None:
        """The ended track ``tr`` is the target of the living track ``succ``: its rows and speeds join it."""
        tid = tr.track_id
        self._log[succ].extend(self._log[tid])
        self._speed[succ].prepend(self._speed[tid])
        self._start_ns[succ] = self._start_ns.get(tid, int(tr.created_ns))
        self.continued += 1
        self._forget(tid, counted=False)

    def _link(self, recorded: list[tuple[int, int]], points: MapPoints) -> None:
        """Count a link between every two tracks of this frame whose clusters' range extents come
        within ``fragment_gap_m`` of each other and whose radial speeds agree within
        ``fragment_speed_kmh``."""
        gap = self.tracker.config.fragment_gap_m
        if gap <= 0 or len(recorded) < 2:
            return
        ids = [tid for tid, _ in recorded]
        rng, lab = np.asarray(points.range_m), np.asarray(points.label)
        ext = [rng[lab == k] for _, k in recorded]  # a handful of clusters: one compare each
        lo = np.array([float(e.min()) for e in ext])
        hi = np.array([float(e.max()) for e in ext])
        sep = np.maximum(lo[:, None], lo[None, :]) - np.minimum(hi[:, None], hi[None, :])
        n_aid = max(2, self.tracker.config.doppler_range_rate_frames)
        v = np.array([self._speed[tid].current_radial_speed_kmh() if len(self._speed[tid]) >= n_aid else math.nan
                      for tid in ids])
        dv = np.abs(v[:, None] - v[None, :])
        same = ~(dv > self.tracker.config.fragment_speed_kmh)  # NaN (no speed yet) passes
        ia, ib = np.nonzero(np.triu((sep <= gap) & same, 1))
        for a, b in zip(ia.tolist(), ib.tolist()):
            la, lb = self._links[ids[a]], self._links[ids[b]]
            la[ids[b]] = la.get(ids[b], 0) + 1
            lb[ids[a]] = lb.get(ids[a], 0) + 1

    def _rigid_merge(self, recorded: list[tuple[int, int]], sig: ClusterSignatures) -> None:
        """Merge tracks that are parts of one rigid body (``rigid_*`` of :class:`AlphaBetaConfig`).

        For every pair of an older track ``a`` with an unaliased radial speed of at least
        ``rigid_min_speed_kmh`` and a younger track ``b`` that has its own cluster this frame: the
        frame counts when ``b``'s cluster is within ``rigid_length_m`` of ``a``'s (its cluster this
        frame, or its prediction while it coasts) and their wrapped Dopplers agree within
        ``rigid_doppler_kmh``; any other frame of ``b`` resets the count. After ``rigid_frames``
        frames in a row whose separations spread by at most ``rigid_separation_m``, ``b``'s signature
        rows join ``a``'s (the union of the body's cells frame by frame) and ``b`` ends without an
        event. ``a`` remembers the separations (widened by ``rigid_separation_m``): a track started
        there later with ``a``'s Doppler is the same part again and is merged in its first frame."""
        cfg = self.tracker.config
        n_aid = max(2, cfg.doppler_range_rate_frames)
        by_id = {tr.track_id: tr for tr in self.tracker.tracks}
        own = {tid: lab for tid, lab in recorded}
        period = 2.0 * self.cylinder.vmax_kmh
        older = []
        for tid, tr in by_id.items():
            spd = self._speed.get(tid)
            if spd is None or len(spd) < n_aid:
                continue
            v = spd.current_radial_speed_kmh()
            if not abs(v) >= cfg.rigid_min_speed_kmh:
                continue
            if tid in own:
                r, dw = float(sig.range_m[own[tid]]), float(sig.doppler_kmh[own[tid]])
            else:
                r, dw = float(tr.state[4]), spd.last()[2]
            older.append((tid, len(spd), r, dw))
        seen: set[tuple[int, int]] = set()
        for a, n_a, r_a, dw_a in older:
            for b, lab in own.items():
                spd_b = self._speed.get(b)
                if b == a or spd_b is None or len(spd_b) >= n_a or b not in by_id or a not in by_id:
                    continue
                key = (a, b)
                sep = float(sig.range_m[lab]) - r_a
                ddw = abs((float(sig.doppler_kmh[lab]) - dw_a + 0.5 * period) % period - 0.5 * period)
                if abs(sep) <= cfg.rigid_length_m and ddw <= cfg.rigid_doppler_kmh:
                    body = self._body.get(a)
                    if len(spd_b) == 1 and body is not None and body[0] <= sep <= body[1]:
                        # a new track where a part already merged into ``a`` was: that part again
                        self._merge_into(a, b)
                        self.rigid_parts += 1
                        by_id.pop(b, None)
                        continue
                    seps = self._rigid.setdefault(key, [])
                    seps.append(sep)
                    del seps[:-cfg.rigid_frames]
                    seen.add(key)
                    if len(seps) >= cfg.rigid_frames and max(seps) - min(seps) <= cfg.rigid_separation_m:
                        m = cfg.rigid_separation_m
                        lo, hi = min(seps) - m, max(seps) + m
                        if body is not None:
                            lo, hi = min(lo, body[0]), max(hi, body[1])
                        self._body[a] = (lo, hi)
                        self._merge_into(a, b)
                        self.rigid_merges += 1
                        by_id.pop(b, None)
        # a younger track's frame that did not move with the older one breaks the run
        for key in [k for k in self._rigid if k not in seen and (k[1] in own or k[0] not in by_id or k[1] not in by_id)]:
            del self._rigid[key]

    def _merge_into(self, keep: int, gone: int) -> None:
        """Track ``gone`` is a part of ``keep``'s target: its rows join ``keep``'s, it ends silently."""
        log_k, log_g = self._log.get(keep), self._log.get(gone)
        if log_k is not None and log_g is not None:
            log_k.extend(log_g)
        self.tracker.tracks = [t for t in self.tracker.tracks if t.track_id != gone]
        self.tracker.ids.release(gone)
        self._rigid = {k: v for k, v in self._rigid.items() if gone not in k}
        self._forget(gone, counted=False)
        log.debug("track %d merged into track %d (one rigid body)", gone, keep)

    def _end_tracks(self, ended, dropped, alive: set[int], frame: int | None = None) -> list[ClassifiedEvent]:
        """Classify the ``ended`` tracks and forget the ``dropped`` ones, except fragments: a track
        linked (:meth:`_link`) in at least ``fragment_link_fraction`` of its own frames to a track that
        is still ``alive``, or that ends in this batch with more frames, hands its signature rows to
        that track (the one it is linked to most) instead. With ``continuation_hold_frames`` and a
        ``frame``, an ended track that would be classified waits that long for a successor instead."""
        cfg = self.tracker.config
        batch = sorted([(tr, True) for tr in ended] + [(tr, False) for tr in dropped],
                       key=lambda e: (self._acc[e[0].track_id].n if e[0].track_id in self._acc else 0))
        later = {tr.track_id for tr, _ in batch}
        self._batch_created = {tr.track_id: int(tr.created_ns) for tr, _ in batch}  # ending now: out of the tracker
        out: list[ClassifiedEvent] = []
        for tr, is_ended in batch:
            tid = tr.track_id
            later.discard(tid)
            # a moving dropped track (coasting below th_v) that carries the rows of tracks that ended before it (a
            # continuation, a passage, a part) is classified as they would have been; its id is free already
            carries = not is_ended and tid in self._start_ns and self._moving(tid)
            held_id = is_ended and self.tracker.keep_ended_ids
            is_ended = is_ended or carries
            partner = None
            if cfg.fragment_gap_m > 0 and tid in self._links:
                own = max(1, self._acc[tid].n)
                best = [(n, p) for p, n in self._links[tid].items() if (p in alive or p in later)
                        and n >= cfg.fragment_link_fraction * own]
                if best:
                    partner = max(best)[1]
            if partner is not None:
                self._log[partner].extend(self._log[tid])
                self.fragments += 1
                self._forget(tid, counted=False)
            elif is_ended and (host := self._passage_host(tr, alive)) is not None:
                self._log[host].extend(self._log[tid])
                self._start_ns[host] = min(self._start_ns.get(host, int(self._created_ns(host))),
                                           self._start_ns.get(tid, int(tr.created_ns)))
                self.passages += 1
                self._forget(tid, counted=False)
            elif is_ended and (body := self._body_partner(tr, alive | later, self._held_beside(tid))) is not None:
                self._join(body, tid, int(tr.created_ns))
                self.body_parts += 1
                self._forget(tid, counted=False)
            elif is_ended and (succ := self._successor(tr, alive)) is not None:
                self._continue(tr, succ)
            elif is_ended and self._own_frames(tid) < 2:
                # seen often enough, but nearly every frame merged with or shared by another target's
                # cluster: no features to classify (eq. 19 needs two frames), dropped
                self._forget(tid)
            elif held_id and frame is not None and self._moving(tid):
                self._held[tid] = (tr, frame + cfg.continuation_hold_frames)
            elif is_ended:
                out.append(self._finish(tr))
            else:
                self._forget(tid)
            if held_id and tid not in self._held:
                self.tracker.ids.release(tid)
        return out

    def _held_beside(self, track_id: int) -> set[int]:
        """Held tracks (``continuation_hold_frames``) whose last cluster came after the first one of ``track_id``:
        seen beside it, they may be the body it is a part of."""
        spd = self._speed.get(track_id)
        if not self._held or spd is None or not len(spd):
            return set()
        t0 = spd.first()[0]
        return {h for h in self._held if h in self._speed and len(self._speed[h]) and self._speed[h].last()[0] >= t0}

    def _created_ns(self, track_id: int) -> int:
        for t in self.tracker.tracks:
            if t.track_id == track_id:
                return int(t.created_ns)
        return 0

    def _passage_host(self, tr: AlphaBetaTrack, alive: set[int]) -> int | None:
        """The vehicle track whose passage beside the radar the short ending track ``tr`` saw, or None
        (``passage_max_frames``, ``passage_range_m``, ``passage_gap_frames`` with ``rigid_min_speed_kmh``
        and ``rigid_length_m``): ``tr`` has at most ``passage_max_frames`` frames of its own, one of
        them within ``passage_range_m``; the host is alive, at least ``rigid_min_speed_kmh`` fast (or, with
        ``vehicle_by_class``, read as a vehicle), one of its clusters lies within ``rigid_length_m`` of one of
        ``tr``'s at most ``passage_gap_frames`` frames apart, and the median gap between their extents over ``tr``'s
        frames paired in time is at most ``body_gap_m``; ``tr``'s mean radial speed is within ``passage_speed_kmh``
        of zero (beside the radar) or within ``passage_same_speed_kmh`` of the host's. The closest such pair picks
        the host."""
        cfg = self.tracker.config
        if cfg.passage_max_frames <= 0 or cfg.rigid_min_speed_kmh <= 0 or not alive:
            return None
        spd = self._speed.get(tr.track_id)
        if spd is None or len(spd) == 0 or tr.track_id not in self._log or self._own_frames(tr.track_id) > cfg.passage_max_frames:
            return None
        t_x, r_x = spd.history()
        if not float(np.min(r_x)) <= cfg.passage_range_m:
            return None
        lo_x, hi_x = spd.extents()
        n_aid = max(2, cfg.doppler_range_rate_frames)
        dt_max = (cfg.passage_gap_frames + 0.5) * self.frame_period_s
        v_x = spd.mean_radial_speed_kmh()
        if not math.isfinite(v_x):
            v_x = 0.0  # a single frame: no speed, judged by place and time only
        best, best_d = None, math.inf
        for tid in alive:
            other = self._speed.get(tid)
            if other is None or tid not in self._log or len(other) < n_aid:
                continue
            v_y = other.current_radial_speed_kmh()
            if not (abs(v_y) >= cfg.rigid_min_speed_kmh or self._vehicle_by_class(tid)):
                continue
            # beside the radar the part's radial speed is small; otherwise it is the host's own (one body):
            # another vehicle passing the other way, or a fast one seen for a few frames, is neither
            if not (abs(v_x) <= cfg.passage_speed_kmh or abs(v_x - v_y) <= cfg.passage_same_speed_kmh):
                continue
            t_y, r_y = other.history()
            dt = np.abs(t_x[:, None] - t_y[None, :])
            near = dt <= dt_max
            if not near.any():
                continue
            d = float(np.min(np.where(near, np.abs(r_x[:, None] - r_y[None, :]), np.inf)))
            # a part of the host's body touches its extent in most of the frames paired in time; a walker the
            # vehicle passes comes near it for a frame or two only
            k = np.argmin(dt, axis=1)
            paired = near[np.arange(t_x.size), k]
            gap = _extent_gaps((r_x, lo_x, hi_x), (r_y, *other.extents()), k)[paired]
            if not float(np.median(gap)) <= cfg.body_gap_m:
                continue
            if d <= cfg.rigid_length_m and d < best_d:
                best, best_d = tid, d
        return best

    def _join(self, keep: int, gone: int, gone_created_ns: int) -> None:
        """Track ``gone`` (ending) saw the same body as ``keep``: its signature rows and its frames of radial speed
        join ``keep``'s, and ``keep``'s event starts where the earlier of the two did."""
        if keep in self._log and gone in self._log:
            self._log[keep].extend(self._log[gone])
        if keep in self._speed and gone in self._speed:
            self._speed[keep].merge(self._speed[gone])
        own = self._start_ns.get(keep)
        if own is None:
            held = self._held.get(keep)
            own = next((int(t.created_ns) for t in self.tracker.tracks if t.track_id == keep),
                       int(held[0].created_ns) if held is not None
                       else self._batch_created.get(keep, gone_created_ns))
        self._start_ns[keep] = min(own, self._start_ns.get(gone, gone_created_ns))

    def _body_partner(self, tr: AlphaBetaTrack, candidates: set[int],
                      held: frozenset[int] | set[int] = frozenset()) -> int | None:
        """The track of the vehicle whose body the ending track ``tr`` is a part of (``body_length_m``,
        ``body_doppler_kmh``, ``passage_gap_frames``, ``rigid_min_speed_kmh``), or None; the nearest in range wins.
        ``held``: ended tracks waiting for a successor, also candidates; their extents must touch ``tr``'s."""
        cfg = self.tracker.config
        candidates = candidates | held
        if cfg.body_length_m <= 0 or not candidates:
            return None
        spd = self._speed.get(tr.track_id)
        if spd is None or len(spd) < 2 or tr.track_id not in self._log:
            return None
        period = 2.0 * self.cylinder.vmax_kmh
        dt_max = (cfg.passage_gap_frames + 0.5) * self.frame_period_s
        t_x, r_x = spd.history()
        w_x = spd.wrapped()
        lo_x, hi_x = spd.extents()
        rate_x = _finite_or_zero(spd.range_rate_kmh())
        best, best_d = None, math.inf
        for tid in candidates:
            other = self._speed.get(tid)
            if tid == tr.track_id or other is None or len(other) < 2 or tid not in self._log:
                continue
            rate_y = _finite_or_zero(other.range_rate_kmh())
            if not (max(abs(rate_y), abs(_finite_or_zero(other.mean_radial_speed_kmh()))) >= cfg.rigid_min_speed_kmh
                    or self._vehicle_by_class(tid)):
                continue
            if rate_x * rate_y < 0 and min(abs(rate_x), abs(rate_y)) >= cfg.passage_speed_kmh:
                continue  # moving apart: two targets crossing each other
            t_y, r_y = other.history()
            dt = np.abs(t_x[:, None] - t_y[None, :])
            k = np.argmin(dt, axis=1)
            dt_k = dt[np.arange(t_x.size), k]
            near = dt_k <= dt_max
            n_near = np.count_nonzero(near)
            # paired in at least half of tr's frames; or a *handover*: a younger part, seen beside tr before tr's last
            # cluster, that took the body over, paired in at least half of tr's frames since it appeared
            handover = (n_near < max(1, t_x.size // 2) and t_y[0] < t_x[-1]
                        and n_near >= max(1, np.count_nonzero(t_x >= t_y[0] - dt_max) // 2))
            if n_near < max(1, t_x.size // 2) and not handover:
                continue
            d = float(np.median(np.abs(r_x[near] - r_y[k[near]])))
            gap_n = _extent_gaps((r_x, lo_x, hi_x), (r_y, *other.extents()), k)[near]
            gap = float(np.median(gap_n))
            # extents overlapping in most of the frames both were seen in (not paired across frames: a body moves)
            same = dt_k[near] <= 0.5 * self.frame_period_s
            overlap = bool(same.any()) and float(np.median(gap_n[same])) <= 0.0
            dw = (w_x[near] - other.wrapped()[k[near]] + 0.5 * period) % period - 0.5 * period
            # a younger part that took the body over must touch it (median gap 0): a vehicle following another moves
            # at its rate
            together = (overlap if tid in held else gap <= 0.0 if handover else
                        gap <= cfg.body_gap_m or abs(rate_x - rate_y) <= cfg.body_rate_kmh)
            # inside the body's range extent any Doppler is the body's: a vehicle's parts beside the radar are seen at
            # aspects whose radial speeds differ by up to its speed, its wheels at 0-2 v
            doppler_ok = abs(float(np.median(dw))) <= cfg.body_doppler_kmh or (cfg.body_overlap_any_doppler and overlap)
            if d <= cfg.body_length_m and doppler_ok and together and d < best_d:
                best, best_d = tid, d
        return best

    def _vehicle_by_class(self, track_id: int) -> bool:
        """``vehicle_by_class``: the classifier reads the track's features so far (at least
        ``doppler_range_rate_frames`` frames) as a vehicle."""
        cfg = self.tracker.config
        acc = self._acc.get(track_id)
        if (not cfg.vehicle_by_class or self.classifier is None or acc is None
                or acc.n < max(2, cfg.doppler_range_rate_frames)):
            return False
        x = acc.features()
        if not np.all(np.isfinite(x)):
            return False
        k = int(self.classifier.predict(x[None, :])[0])
        return self.classifier.classes[k] != "pedestrian"

    def _own_frames(self, track_id: int) -> int:
        """Frames with signatures of the track (its own clusters, and those of tracks it absorbed)."""
        acc = self._acc.get(track_id)
        log_ = self._log.get(track_id)
        return max(acc.n if acc is not None else 0, log_.frames() if log_ is not None else 0)

    def _successor(self, tr: AlphaBetaTrack, alive: set[int]) -> int | None:
        """The live track that continues the ending track ``tr`` (``continuation_speed_kmh``), or None.

        Candidates started after ``tr``'s last cluster, last seen at ``continuation_min_range_m`` or
        farther; the gap from ``tr``'s last cluster to the candidate's first one must be walked in the
        direction ``tr`` moved, at ``tr``'s mean radial speed (its unaliased Doppler) or at its range
        rate (the least-squares slope of its centroids: right when a track of a few frames got the
        wrong alias), within ``max(continuation_speed_kmh, |v| / 2)``. The smallest mismatch wins."""
        cfg = self.tracker.config
        if cfg.continuation_speed_kmh <= 0 or not alive:
            return None
        spd = self._speed.get(tr.track_id)
        if spd is None or tr.track_id not in self._log or len(spd) < 2:
            return None
        t_a, r_a, _ = spd.last()
        if r_a < cfg.continuation_min_range_m:
            return None
        speeds = [v for v in (spd.mean_radial_speed_kmh(), spd.reference_rate_kmh()) if math.isfinite(v)]
        if not speeds:
            return None
        best, best_err = None, math.inf
        for tid in alive:
            other = self._speed.get(tid)
            if other is None or len(other) == 0 or tid not in self._log:
                continue
            t_b, r_b, _ = other.first()
            if t_b == t_a and cfg.continuation_same_frame:
                # started in the frame of tr's last cluster (another part of the same target, a metre
                # away): judged at its latest cluster, the longest baseline
                t_b, r_b, _ = other.last()
            dt = t_b - t_a
            if not dt > 0:
                continue
            v_gap = (r_b - r_a) / dt * 3.6
            for v in speeds:
                err = abs(v_gap - v)
                if v_gap * v > 0 and err <= max(cfg.continuation_speed_kmh, 0.5 * abs(v)) and err < best_err:
                    best, best_err = tid, err
        return best

    def _shares_with(self, track_id: int, j: int) -> bool:
        """Is centroid ``j`` (assigned to ``track_id``) shared with an established track hidden in its
        range span (:meth:`_hidden_in`) whose size is at least 0.4 of this track's? Then the
        centroid lies between the two targets: the track keeps its prediction (as merged)."""
        others = self._shared.get(j)
        hist = self._size.get(track_id)
        if not others or not hist:
            return False
        own = plain_median(hist)
        return any(plain_median(self._size[o]) >= 0.4 * own for o in others if self._size.get(o))

    def _hidden_in(self, tr: AlphaBetaTrack, j: int) -> bool:
        """Occlusion test of the alpha-beta tracker: is cluster ``j`` (an assigned one) large enough,
        against ``tr``'s own size, to hold ``tr``'s target merged with another, or (``shared_span_m``)
        does its range span hold ``tr``'s predicted range?"""
        hist = self._size.get(tr.track_id)
        margin = self.tracker.config.shared_span_m
        if (margin > 0 and hist and len(hist) >= self.tracker.config.merge_history_frames
                and self._frame_lo[j] - margin <= float(tr.state[4]) <= self._frame_hi[j] + margin):
            self._shared.setdefault(j, []).append(tr.track_id)
            return True
        # a track with fewer than merge_history_frames own clusters has no known size: typically a
        # fragment split off a long vehicle's cluster for a frame or two, which, held as hidden in
        # that cluster, lived (and was published) through the whole passage beside the real track
        if not hist or len(hist) < self.tracker.config.merge_history_frames:
            return False
        return float(self._frame_sizes[j]) > self.tracker.config.merge_ratio * plain_median(hist)

    def _other_track_near(self, track_id: int, centroid: np.ndarray, pred: dict[int, np.ndarray]) -> bool:
        """Is another track (with at least ``merge_other_min_frames`` own clusters) predicted within
        ``gate_radius`` of this centroid (on the cylinder)?"""
        gate = self.tracker.config.gate_radius
        need = self.tracker.config.merge_other_min_frames
        c0, c1, c2 = centroid.tolist()
        for tid, p in pred.items():
            if tid != track_id and (need <= 0 or len(self._size.get(tid, ())) >= need):
                near = _within(float(p[0]) - c0, float(p[2]) - c1, float(p[4]) - c2, gate)
                if near is None:
                    near = float(np.linalg.norm(p[[0, 2, 4]] - centroid)) <= gate
                if near:
                    return True
        return False

    def _any_track_near(self, track_id: int, centroid: np.ndarray, pred: dict[int, np.ndarray], lo_m: float,
                        hi_m: float) -> bool:
        """Is any other track predicted within ``gate_radius`` of this centroid (on the cylinder) or, in
        range, inside the cluster's span (``lo_m``..``hi_m`` widened by ``shared_span_m``)? Always true
        when ``merge_other_required`` is ``young`` (the old rule: established tracks need no other)."""
        cfg = self.tracker.config
        if cfg.merge_other_required == "young":
            return True
        m = cfg.shared_span_m
        c0, c1, c2 = centroid.tolist()
        lo, hi = float(lo_m) - m, float(hi_m) + m
        for tid, p in pred.items():
            if tid == track_id:
                continue
            near = _within(float(p[0]) - c0, float(p[2]) - c1, float(p[4]) - c2, cfg.gate_radius)
            if near is None:
                near = float(np.linalg.norm(p[[0, 2, 4]] - centroid)) <= cfg.gate_radius
            if near or lo <= float(p[4]) <= hi:
                return True
        return False

    def _is_merged(self, track_id: int, n_points: int, other_near: bool = True,
                   any_near: Callable[[], bool] = lambda: True) -> bool:
        """Is this cluster the track's target merged with another one (``merge_ratio``)? Updates the
        track's size history.

        A young track (fewer than ``merge_history_frames`` clusters) is held only when another track
        is predicted near the cluster (``other_near``): a cluster grows several-fold on its own while
        a long vehicle enters the beam (a truck's point count goes from ~100 to ~1000 in one frame),
        and holding such a track on its prediction starved its features of the frames that make it a
        truck and let it run away from its target. With ``merge_other_required = "always"`` an
        established track is held only when some other track is near the cluster (``any_near()``, asked only then): a
        target growing on its own as it approaches is no merge."""
        cfg = self.tracker.config
        hist = self._size.get(track_id)
        if hist is None:
            return False
        established = other_near or (len(hist) >= cfg.merge_history_frames and any_near())
        if (established and cfg.merge_ratio > 0 and len(hist) >= 2
                and self._merged_run[track_id] < cfg.merge_max_frames):
            # against the median *and* the last own cluster: a merge is a sudden jump, while a long
            # vehicle coming closer grows a few tens of percent a frame (221 -> 1530 -> 1941 -> 3052
            # points) and was held for merge_max_frames, losing its closest, most telling frames
            if n_points > cfg.merge_ratio * max(plain_median(hist), float(hist[-1])):
                self._merged_run[track_id] += 1
                self.merged_frames += 1
                return True
        self._merged_run[track_id] = 0
        hist.append(n_points)
        return False

    def _forget(self, track_id: int, counted: bool = True) -> None:
        self._forgotten.append(track_id)
        self._log.pop(track_id, None)
        for other in self._links.pop(track_id, {}):
            self._links.get(other, {}).pop(track_id, None)
        self._acc.pop(track_id, None)
        self._speed.pop(track_id, None)
        self._live_fit.pop(track_id, None)
        self._seen_t.pop(track_id, None)
        self._size.pop(track_id, None)
        self._merged_run.pop(track_id, None)
        self._start_ns.pop(track_id, None)
        self._body.pop(track_id, None)
        self.dropped += int(counted)

    def _finish(self, tr: AlphaBetaTrack) -> ClassifiedEvent:
        pct = self.extractor.config.extent_percentile
        own = self._acc.get(tr.track_id) or TrackFeatureAccumulator(pct)
        log_ = self._log.get(tr.track_id)
        spd = self._speed.get(tr.track_id)
        start_ns = self._start_ns.get(tr.track_id, int(tr.created_ns))  # of the earliest track it continues
        self._forget(tr.track_id, counted=False)  # an ended track, classified below: not a dropped one
        # the union with absorbed fragments; a track without any has exactly its own running features
        acc = (log_.accumulator(pct, self.extractor.speed_vmax_kmh) if log_ is not None and len(log_) > own.n
               else own)
        x = acc.features()
        v, certain = math.nan, False
        if spd is not None:
            fc = self.extractor.config
            cap = {"cap_range_m": fc.event_speed_cap_range_m, "cap_margin_kmh": fc.event_speed_cap_margin_kmh,
                   "cap_min_kmh": fc.event_speed_cap_min_kmh}
            v, certain, v_abs = spd.event_speed_kmh(fc.event_speed_alias, fc.event_speed, fc.event_speed_leading_edge_m,
                                                    fc.event_speed_alias_edge_m, fc.event_speed_alias_margin_kmh,
                                                    self._edge_limit_m, fc.event_speed_alias_tol_m, abs_mean=True,
                                                    **cap)
            if fc.speed_feature == "event" and math.isfinite(v_abs):
                x[4] = v_abs  # E(|v_r|) of the event speed's frames, on its alias
        if not math.isfinite(v):
            v, certain = acc.mean_radial_speed_kmh(), False
        if self.classifier is not None and np.all(np.isfinite(x)):
            names = self.classifier.classes
            p = self.classifier.predict_proba(x[None, :])[0]
            k = int(self.classifier.predict(x[None, :])[0])  # ties -> lower class, as the ONNX model
            cls, probs = names[k], {n: float(pi) for n, pi in zip(names, p)}
        else:
            if self.classifier is not None:
                log.warning("track %d ended without finite features (%d frames)", tr.track_id, acc.n)
            cls, probs = UNKNOWN_CLASS, {}
        self.classified += 1
        feats = {n: float(xi) for n, xi in zip(FEATURE_NAMES, x)}
        feats["frames"] = float(acc.n)
        return ClassifiedEvent(
            track_id=tr.track_id,
            cls=cls,
            probabilities=probs,
            mean_radial_speed_kmh=float(v),
            direction="approaching" if v < 0 else "receding",
            start_ns=start_ns,
            end_ns=int(tr.last_seen_ns),
            features=feats,
            speed_uncertain=not certain,
        )

    def _track_state(self, tr: AlphaBetaTrack, t_s: float) -> TrackState:
        spd = self._speed.get(tr.track_id)
        v_kmh = spd.current_radial_speed_kmh() if spd is not None else math.nan
        v = v_kmh / 3.6 if math.isfinite(v_kmh) else float(tr.state[5]) / self.frame_period_s
        dt = t_s - self._seen_t.get(tr.track_id, t_s)
        r = max(0.0, float(tr.last_measurement[2]) - self._coupling_s * v + v * dt)
        fc = self.extractor.config
        if fc.event_speed_alias in ("history", "fit"):
            # published only when its alias is sure: the history's alias is certain and the latest frame's speed is
            # on it (else n/a: an alias step is 10.7 km/h); fit: LIVE_FIT_FRAMES, LIVE_REFIT_FRAMES
            latest, certain = math.nan, False
            if spd is not None and fc.event_speed_alias == "history":
                hv, _, certain = spd.history_alias(fc.event_speed_alias_edge_m, fc.event_speed_alias_margin_kmh,
                                                   self._edge_limit_m)
                latest = float(hv[-1]) if hv.size else math.nan
            elif spd is not None and len(spd) >= 3 and math.isfinite(v_kmh):
                # fitted again while not certain, every LIVE_REFIT_FRAMES frames, and when the latest frame's speed
                # on its alias is not the current speed's
                fit = self._live_fit.get(tr.track_id)
                t_last, _, vw_last = spd.last()
                fresh = (fit is not None and fit[2]
                         and 0 <= t_last - fit[0] < (LIVE_REFIT_FRAMES - 0.5) * self.frame_period_s)
                if not (fresh and abs(spd.dealias_one(vw_last, fit[1]) - v_kmh) <= self.cylinder.vmax_kmh):
                    _, ref, sure, _ = spd.fit_alias(fc.event_speed_alias_edge_m, fc.event_speed_alias_tol_m,
                                                    self._edge_limit_m, last_frames=LIVE_FIT_FRAMES, around_kmh=v_kmh)
                    fit = self._live_fit[tr.track_id] = (t_last, ref, sure)
                _, ref, certain = fit
                latest = spd.dealias_one(vw_last, ref) if certain else math.nan
            if not (certain and abs(latest - v_kmh) <= self.cylinder.vmax_kmh):
                v = math.nan
        return track_state(tr.track_id, 0.0, r, 0.0, v, r, v, math.nan, tr.age, tr.seen_frames, True, None)
