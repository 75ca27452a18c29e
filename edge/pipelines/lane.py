"""The ``lane`` profile: Lim et al. (IEEE Access 2021) §III on the 1 TX x 4 RX SIMO board (Fig. 10).

One frame is four chirp segments (fast up, fast down, slow up, slow down) on 4 receive channels. Its stages, one
module each under :mod:`edge.lane`, each passing a typed record (:mod:`edge.lane.records`) to the next::

    spectra     edge.lane.spectra     RawFrame -> Spectra      windowed range FFT, static-clutter map (§III-A)
    peaks       edge.lane.peaks       Spectra  -> Peaks        OS-CFAR, local maxima, interpolation (§III-A)
    pairs       edge.lane.pairs       Peaks    -> PairList     four-segment pairing, track-aided pairing (§III-A)
    angles      edge.lane.angles      PairList -> Angles       Bartlett over the channels, side-by-side resolver (§III-A)
    detections  edge.lane.detections  Angles   -> Detections   ground plane (eq. 16), road-geometry filters
    tracks      edge.track            Detections -> tracks     PDAF tracker (§III-B, eqs. 17-19)
    lanes       edge.traffic          tracks -> lanes, statistics, events

What detection takes from earlier frames -- the tracks, the lanes, the road's direction -- is one record,
:class:`edge.lane.records.Feedback`, built by :meth:`LanePipeline.feedback` before each frame. The table with the
stages' inputs and outputs is in ``docs/lane-stages.md``.

All parameters are in :class:`LaneConfig` (section ``pipeline.lane``); the tracker and the traffic layer read
``track.pdaf`` and ``traffic``. Intermediates for plots: ``power`` (segments x bins, linear), ``threshold`` and
``noise`` (linear; NaN away from local maxima unless ``cfar_full_threshold``), ``peak_freqs_hz`` (per segment),
pairing counts (``n_aided_pairs`` from tracks), ``angle_spectrum``. Detections carry ``extra["body_extent_m"]``
(along-road length of the body behind the detection: the vehicle length the traffic layer measures),
``extra["resolved_pair"]`` (>= 0: the two detections split from one share the value) and
``extra["unresolved_pair"]`` (bool: the resolver found two sources in the cell but could not split them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from edge import native
from edge.lane.angles import AngleStage, ResolveStage
from edge.lane.clutter import ClutterMap
from edge.lane.detections import DetectionStage
from edge.lane.pairs import PairStage
from edge.lane.peaks import PeakStage
from edge.lane.records import Feedback
from edge.lane.road import RoadFrame
from edge.lane.spectra import SpectraStage
from edge.npc import count_nonzero
from edge.pipeline import Pipeline, PipelineError, StageTimer
from edge.types import Detections, FrameResult, FrontendInfo, RawFrame


@dataclass(frozen=True)
class LaneConfig:
    """Signal processing of the lane profile (Lim §III-A); defaults follow the paper where it gives values. Why the
    values beyond the paper are what they are: docs/decisions/0003-lane-stages.md."""

    window: str = field(default="hann", metadata={
        "doc": "range window applied before every FFT", "choices": ("hann", "hamming", "blackman", "kaiser", "boxcar")})
    clutter_map_time_s: float = field(default=20.0, metadata={
        "unit": "s", "doc": "time constant of the static-clutter map, an exponential average of each channel's complex "
               "spectrum subtracted before detection (guard rails, gantries, poles, TX leakage; each chirp segment "
               "learns in turn, one a frame); 0 = off",
        "min": 0.0, "max": 3600.0})
    clutter_map_hold_speed_mps: float = field(default=1.0, metadata={
        "unit": "m/s", "doc": "the clutter map is not updated in the range bins of a confirmed track that once moved and "
               "is now slower than this, so a stopped vehicle does not fade into the map; 0 = off",
        "min": 0.0, "max": 10.0})
    clutter_map_hold_length_m: float = field(default=20.0, metadata={
        "unit": "m", "doc": "range held behind a stopped track's near face (its body)", "min": 0.0, "max": 100.0})
    clutter_map_warmup_frames: int = field(default=60, metadata={
        "doc": "the clutter map starts as a running mean: frame n is weighted max(1/(n + this), 1 - exp(-T/time "
               "constant))", "min": 1, "max": 1_000_000})
    clutter_map_static_factor: float = field(default=8.0, metadata={
        "doc": "the clutter map learns a bin only while it stands still: its frame-to-frame change, summed over the "
               "channels, at most this many times the segment's median change (a moving echo's phase and beat change "
               "between frames); 0 = every bin learns", "min": 0.0, "max": 1e6})
    clutter_map_static_rel: float = field(default=0.05, metadata={
        "doc": "... plus this fraction of the bin's own amplitude (a strong standing echo under phase noise)",
        "min": 0.0, "max": 1.0})
    cfar_pfa: float = field(default=1e-3, metadata={
        "doc": "design false-alarm probability per cell of the OS-CFAR (sets its threshold scale); a target also "
               "needs agreeing peaks in all four segments", "min": 1e-12, "max": 0.1})
    cfar_train_cells: int = field(default=16, metadata={
        "doc": "OS-CFAR reference cells on each side of the cell under test", "min": 2, "max": 128})
    cfar_guard_cells: int = field(default=2, metadata={
        "doc": "guard cells on each side (a Hann-windowed peak spreads over +-2 bins)", "min": 0, "max": 32})
    cfar_rank_fraction: float = field(default=0.75, metadata={
        "doc": "rank of the ordered statistic as a fraction of the reference cells (Rohling: 3/4)",
        "min": 0.05, "max": 1.0})
    cfar_full_threshold: bool = field(default=False, metadata={
        "doc": "compute the OS-CFAR threshold at every bin (for plots); off: only at local maxima (the same "
               "detections), other bins read NaN"})
    min_range_m: float = field(default=5.0, metadata={
        "unit": "m", "doc": "nearest slant range reported (TX->RX leakage and the overpass itself are closer)",
        "min": 0.0, "max": 100.0})
    max_range_m: float = field(default=375.0, metadata={
        "unit": "m", "doc": "farthest slant range reported: beyond the 300 m design range, so an approaching car's "
               "track is confirmed by 300 m (384 m is the unambiguous range at standstill)", "min": 10.0, "max": 400.0})
    max_speed_kmh: float = field(default=250.0, metadata={
        "unit": "km/h", "doc": "largest radial speed a pairing may have", "min": 10.0, "max": 400.0})
    max_peaks_per_segment: int = field(default=128, metadata={
        "doc": "strongest CFAR peaks kept per segment (bounds the pairing work)", "min": 1, "max": 1024})
    pair_tolerance_bins: float = field(default=1.0, metadata={
        "doc": "a fast-segment pairing is confirmed when slow-segment peaks lie within this many slow-segment bins "
               "of both predictions (ghost rejection)", "min": 0.05, "max": 5.0})
    pair_near_tolerance_bins: float = field(default=1.5, metadata={
        "doc": "pair_tolerance_bins nearer than pair_near_range_m, where a vehicle's radial speed changes within "
               "the frame (radial acceleration v^2 h^2 / R^3) and its body spans many bins", "min": 0.05, "max": 5.0})
    pair_near_range_m: float = field(default=40.0, metadata={
        "unit": "m", "doc": "slant range up to which pair_near_tolerance_bins applies; 0 = off", "min": 0.0, "max": 400.0})
    pair_max_shared_peaks: int = field(default=1, metadata={
        "doc": "a pairing may share this many of its four peaks with better pairings (vehicles whose beats "
               "coincide in one segment)", "min": 0, "max": 3})
    pair_static_residue_db: float = field(default=3.0, metadata={
        "unit": "dB", "doc": "a four-segment pairing whose peak in every segment is no stronger than this over the "
               "static-clutter map's echo in its bin, noise allowed for, is the residue of static echoes (posts a "
               "vehicle shadows) and is dropped; 0 = off", "min": 0.0, "max": 20.0})
    angle_step_deg: float = field(default=0.5, metadata={
        "unit": "deg", "doc": "angle grid step: the Bartlett maximum is refined by a parabola between grid angles, "
               "the resolver's two angles lie on the grid", "min": 0.01, "max": 2.0})
    angle_max_deg: float = field(default=19.0, metadata={
        "unit": "deg", "doc": "Bartlett grid half-width (unambiguous sector of d = 1.5 lambda: 19.47 deg)",
        "min": 1.0, "max": 90.0})
    angle_outlier_deg: float = field(default=2.0, metadata={
        "unit": "deg", "doc": "a segment whose own Bartlett maximum is farther than this from the median of the four "
               "is left out of the angle; 90 = keep all", "min": 0.1, "max": 90.0})
    angle_outlier_lateral_m: float = field(default=1.0, metadata={
        "unit": "m", "doc": "... widened near the radar to this lateral distance at the detection's range, "
               "max(angle_outlier_deg, this / range): a near vehicle spans degrees", "min": 0.0, "max": 10.0})
    angle_skip_shared_looks: bool = field(default=True, metadata={
        "doc": "leave a segment out of a detection's angle (and of the resolver's looks) when its peak is also the "
               "peak of another accepted pairing of another speed, unless fewer than two agreeing segments remain"})
    angle_shared_bins: int = field(default=1, metadata={
        "doc": "peaks this many FFT bins apart or closer in one segment count as shared", "min": 0, "max": 4})
    angle_shared_speed_mps: float = field(default=1.0, metadata={
        "unit": "m/s", "doc": "... only with a pairing whose radial speed differs by more than this (another vehicle)",
        "min": 0.0, "max": 20.0})
    angle_min_agreeing: int = field(default=3, metadata={
        "doc": "a pairing is kept only if at least this many of the four segments agree on its angle (a ghost "
               "pairing's peaks point in different directions)", "min": 1, "max": 4})
    aided_pairing: bool = field(default=True, metadata={
        "doc": "confirmed tracks (and far approaching tentative ones) that got no pairing look for their own peaks "
               "near their predicted beat frequencies"})
    aided_window_bins: float = field(default=3.0, metadata={
        "doc": "search half-width around a track's predicted beat frequency, in bins of each segment",
        "min": 0.5, "max": 20.0})
    aided_min_segments: int = field(default=4, metadata={
        "doc": "segments that must hold a peak near the prediction (range and speed are fitted to them)",
        "min": 2, "max": 4})
    aided_pfa: float = field(default=1e-2, metadata={
        "doc": "false-alarm probability of the lower OS-CFAR threshold whose local maxima a track's search also "
               "takes; 0 = only the cfar_pfa peaks", "min": 0.0, "max": 0.1})
    aided_gate_m: float = field(default=2.5, metadata={
        "unit": "m", "doc": "fitted range within this of the track's predicted slant range (and an existing "
               "pairing this close means the track needs no help)", "min": 0.1, "max": 20.0})
    aided_gate_mps: float = field(default=1.5, metadata={
        "unit": "m/s", "doc": "... and fitted radial speed within this of the prediction", "min": 0.1, "max": 20.0})
    aided_tentative_min_range_m: float = field(default=200.0, metadata={
        "unit": "m", "doc": "tentative tracks at least this far (ground range) that once moved and have "
               "aided_tentative_min_hits hits search for their own peaks too; 0 = confirmed tracks only",
        "min": 0.0, "max": 1000.0})
    aided_tentative_min_hits: int = field(default=2, metadata={
        "doc": "... once they have this many hits", "min": 1, "max": 32})
    aided_tentative_approaching: bool = field(default=True, metadata={
        "doc": "... and only while they approach (the far edge is where approaching vehicles come into view)"})
    resolve_pairs: bool = field(default=True, metadata={
        "doc": "split a detection in two when its range-speed cell's spatial covariance over frames holds two "
               "vehicles at different angles (edge.lane.resolve)"})
    resolve_memory_frames: float = field(default=8.0, metadata={
        "doc": "memory (frames) of the per-cell covariance: longer resolves farther, shorter lags less",
        "min": 1.0, "max": 100.0})
    resolve_min_frames: int = field(default=6, metadata={
        "doc": "frames a cell must have been followed before it may be split", "min": 2, "max": 100})
    resolve_min_split_frames: int = field(default=4, metadata={
        "doc": "a cell is split only after it was found to hold two vehicles in this many frames in a row",
        "min": 1, "max": 100})
    resolve_min_eig_ratio: float = field(default=0.05, metadata={
        "doc": "second eigenvalue of the cell covariance relative to the first above which two sources are "
               "considered", "min": 1e-4, "max": 1.0})
    resolve_min_noise_ratio: float = field(default=8.0, metadata={
        "doc": "... and relative to the mean of the noise eigenvalues", "min": 1.0, "max": 1e4})
    resolve_pair_hint_eig_ratio: float = field(default=0.02, metadata={
        "doc": "a cell not split whose second eigenvalue is above this fraction of the first marks its detection "
               "extra['unresolved_pair']: two sources too close in angle to split", "min": 1e-4, "max": 1.0})
    resolve_min_power_ratio: float = field(default=0.1, metadata={
        "doc": "... and the weaker of the two fitted sources carries at least this fraction of the stronger one's "
               "power", "min": 0.0, "max": 1.0})
    resolve_min_lateral_m: float = field(default=2.5, metadata={
        "unit": "m", "doc": "the two fitted directions must lie at least this far apart across at the cell's range "
               "(more than a vehicle's width)", "min": 0.5, "max": 20.0})
    resolve_boundary_fraction: float = field(default=0.25, metadata={
        "doc": "with lanes, a split is kept only if its two directions lie in adjacent lanes and their midpoint "
               "within this fraction of the lane spacing from the boundary between them", "min": 0.0, "max": 1.0})
    resolve_follow_direction: bool = field(default=True, metadata={
        "doc": "steer a cell's covariance memory along with its vehicle's direction (sin(az) scales with 1/range) "
               "before adding a frame"})
    calibration_gain: tuple[float, ...] = field(default=(1.0, 1.0, 1.0, 1.0), metadata={
        "doc": "per-channel amplitude of the receive paths (divided out before the angle estimate)",
        "min": 1e-3, "max": 1e3})
    calibration_phase_deg: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0), metadata={
        "unit": "deg", "doc": "per-channel phase of the receive paths (removed before the angle estimate)",
        "min": -360.0, "max": 360.0})
    mounting_height_m: float = field(default=7.0, metadata={
        "unit": "m", "doc": "radar height above the road (overpass)", "min": 0.0, "max": 50.0})
    target_height_m: float = field(default=0.5, metadata={
        "unit": "m", "doc": "height of the dominant vehicle scatterers (bumper) for the ground projection",
        "min": 0.0, "max": 5.0})
    cluster_length_m: float = field(default=17.0, metadata={
        "unit": "m", "doc": "detections at most this much farther than another with the same radial speed and "
               "lateral position are that vehicle's body and dropped (the longest truck: 16.5 m); 0 = keep all",
        "min": 0.0, "max": 30.0})
    cluster_speed_mps: float = field(default=0.6, metadata={
        "unit": "m/s", "doc": "radial speed difference within which detections can be one vehicle",
        "min": 0.0, "max": 10.0})
    cluster_lateral_m: float = field(default=1.5, metadata={
        "unit": "m", "doc": "lateral difference within which detections can be one vehicle (half a lane)",
        "min": 0.0, "max": 10.0})
    tracking: bool = field(default=True, metadata={
        "doc": "run the PDAF tracker and the traffic layer (off: detections only)"})
    unalias_by_lane: bool = field(default=True, metadata={
        "doc": "with lanes, a moving detection in a lane of the other direction is moved to its grating-lobe alias "
               "(sin(az) +- lambda/d) if that lies in a lane of its own direction"})
    unalias_min_speed_mps: float = field(default=1.0, metadata={
        "unit": "m/s", "doc": "radial speed below which a detection's direction of travel is unknown",
        "min": 0.0, "max": 50.0})
    clutter_map_init_frames: int = field(default=16, metadata={
        "doc": "after this many frames the clutter map is replaced by the per-bin median of those frames (static "
               "returns removed exactly, vehicles passing through a bin left out); 0 = running mean only",
        "min": 0, "max": 256})


#: a detection within this range and radial speed of a track is the one it follows (its near face), for its length
_TRACK_DET_RANGE_M = 1.5
_TRACK_DET_SPEED_MPS = 1.0


class LanePipeline(native.KernelUser, Pipeline):
    profile = "lane"
    stages = ("to_complex", "range_fft", "cfar", "pairing", "angle", "resolve", "geometry", "track", "traffic")

    def __init__(self, frontend: FrontendInfo, config: LaneConfig, track_config: Any = None,
                 traffic_config: Any = None) -> None:
        super().__init__(frontend, config)
        wf = frontend.waveform
        if len(wf.segments) != 4 or any(s.n_chirps != 1 for s in wf.segments):
            raise PipelineError("the lane pipeline needs Lim's four single-chirp segments (up/down fast, up/down slow)")
        if [s.direction for s in wf.segments] != [1, -1, 1, -1]:
            raise PipelineError("the lane pipeline expects segments up, down, up, down")
        cfg = config
        n_rx = frontend.n_rx
        if len(cfg.calibration_gain) != n_rx or len(cfg.calibration_phase_deg) != n_rx:
            raise PipelineError(f"pipeline.lane.calibration_* need {n_rx} values (one per receive channel)")
        self.n_bins = wf.n_samples
        road = RoadFrame()
        self.peaks = PeakStage(frontend, cfg)
        self.cfar_scale = self.peaks.cfar_scale
        self.pairs = PairStage(frontend, cfg, self.peaks.bin_hz)
        # a static echo's FFT bins per metre of range in each segment (negative on a down-chirp)
        self.clutter = ClutterMap(cfg, tuple(frontend.frame_shape), wf.frame_period_s,
                                  (self.pairs.model.a / self.peaks.bin_hz).tolist())
        self.pairs.clutter = self.clutter
        self.spectra = SpectraStage(frontend, cfg, self.clutter, self.peaks.pad)
        self.angles = AngleStage(frontend, cfg, want_looks=cfg.resolve_pairs)
        self.resolve = (ResolveStage(frontend, cfg, self.angles.steer, self.angles.grid, road)
                        if cfg.resolve_pairs else None)
        self.detections = DetectionStage(frontend, cfg, road)
        self.tracker = self.traffic = None
        if cfg.tracking:
            from edge.track import PdafConfig, PdafTracker
            from edge.traffic import TrafficConfig, TrafficMonitor

            self.tracker = PdafTracker(track_config or PdafConfig(), cfg.mounting_height_m - cfg.target_height_m,
                                       cfg.target_height_m)
            self.traffic = TrafficMonitor(traffic_config or TrafficConfig())
        #: the compiled ``edge.native._faces`` for :meth:`track_extents` (None: its numpy form)
        self._k_faces = native.load("_faces")
        #: called with (tracks, t_ns, motion model's x per track or None) before the traffic layer's update
        self.traffic_tap: Callable[[tuple, int, np.ndarray | None], None] | None = None

    def close(self) -> None:
        if self.traffic is not None:
            self.traffic.close()  # saves the traffic self-calibration when configured

    @property
    def n_lanes(self) -> int:  # type: ignore[override]
        return self.traffic.n_lanes if self.traffic is not None else 0

    @classmethod
    def from_config(cls, frontend: FrontendInfo, config: Any) -> "LanePipeline":
        """Build from the whole configuration (sections ``pipeline.lane``, ``track.pdaf``, ``traffic``)."""
        return cls(frontend, config.section("pipeline.lane"), config.section("track.pdaf"), config.section("traffic"))

    # --- stages ------------------------------------------------------------------------------------

    def feedback(self) -> Feedback:
        """What detection takes from earlier frames (:class:`edge.lane.records.Feedback`): the tracks as the tracker
        left them, the lanes and yaw as the traffic layer left them."""
        if self.tracker is None:
            return Feedback.none()
        tr, traffic = self.tracker.tracks, self.traffic
        return Feedback(self.tracker.last_t_ns, tr.x, tr.confirmed, tr.moved, tr.hits, traffic.lanes, traffic.yaw_rad)

    def detect(self, frame: RawFrame, timer: StageTimer,
               feedback: Feedback | None = None) -> tuple[Detections, dict[str, Any]]:
        """Detections of one frame (everything before the tracker) and the intermediates; ``feedback`` from
        :meth:`feedback` when not given."""
        fb = self.feedback() if feedback is None else feedback
        with timer.stage("to_complex"):
            iq = self.spectra.to_complex(frame)
        with timer.stage("range_fft"):
            spectra = self.spectra(iq, fb)
        with timer.stage("cfar"):  # weak peaks only when a confirmed track may use them
            peaks = self.peaks(spectra, self.peaks.aided_scale32 is not None and bool(count_nonzero(fb.confirmed)))
        with timer.stage("pairing"):
            pairs = self.pairs(peaks, frame.t_ns, fb, spectra)
        with timer.stage("angle"):
            angles = self.angles(spectra, peaks.noise, peaks.floor, pairs)
        if self.resolve is not None:
            with timer.stage("resolve"):
                angles = self.resolve(angles, fb)
        with timer.stage("geometry"):
            det = self.detections(angles, fb)
        inter = {
            "power": spectra.power, "threshold": peaks.threshold, "noise": peaks.noise,
            "peak_freqs_hz": list(peaks.freqs_hz), "n_pair_candidates": pairs.n_candidates,
            "n_ghosts_rejected": pairs.n_ghosts, "n_aided_pairs": pairs.n_aided,
            "angle_grid_rad": self.angles.grid, "angle_spectrum": angles.spectrum,
        }
        return det, inter

    def track_extents(self, tracks, det: Detections) -> np.ndarray | None:
        """Per published track the body extent (m) of the detection it follows this frame: the nearest in range
        within 1.5 m of its range and 1 m/s of its radial speed; NaN without one (None without extents)."""
        body = det.extra.get("body_extent_m")
        if body is None:
            return None
        cols = (det.range_m, det.radial_speed_mps, body)
        if self._k_faces is not None:
            for c in cols:  # (a loop in this frame: no generator)
                if not (isinstance(c, np.ndarray) and c.dtype == np.float32 and c.ndim == 1 and c.flags.c_contiguous):
                    break
            else:
                return self._k_faces.track_extents(tracks, *cols, _TRACK_DET_RANGE_M, _TRACK_DET_SPEED_MPS)
        out = np.full(len(tracks), np.nan)
        if not len(det) or not len(tracks):
            return out
        tr = np.array([(t.range_m, t.radial_speed_mps) for t in tracks], dtype=np.float64).reshape(-1, 2)
        dr = np.abs(det.range_m[None, :].astype(np.float64) - tr[:, :1])
        near = (dr <= _TRACK_DET_RANGE_M) & (np.abs(det.radial_speed_mps[None, :] - tr[:, 1:]) <= _TRACK_DET_SPEED_MPS)
        hit = near.any(axis=1)
        if count_nonzero(hit):
            j = np.where(near, dr, np.inf).argmin(axis=1)
            out[hit] = body[j[hit]]
        return out

    def process(self, frame: RawFrame, timer: StageTimer) -> FrameResult:
        det, inter = self.detect(frame, timer, self.feedback())
        if self.tracker is None:
            return FrameResult(profile=self.profile, seq=frame.seq, t_ns=frame.t_ns, detections=det, intermediates=inter)
        with timer.stage("track"):
            tracks = self.tracker.step(det, frame.t_ns)
        if self.traffic_tap is not None:  # (the traffic layer's input, e.g. for evaluate --record-tracks)
            self.traffic_tap(tracks, frame.t_ns, self.tracker.published_motion_x_m)
        with timer.stage("traffic"):
            upd = self.traffic.update(tracks, frame.t_ns, self.tracker.published_motion_x_m,
                                      self.track_extents(tracks, det))
        # the road's direction, the traffic layer's estimate, is the IMM's lane-keeping direction from the next
        # frame on (PdafTracker.road_yaw_rad, its declared input)
        self.tracker.road_yaw_rad = self.traffic.yaw_rad
        return FrameResult(
            profile=self.profile, seq=frame.seq, t_ns=frame.t_ns, detections=det, tracks=upd.tracks,
            presence=upd.presence, lane_stats=upd.lane_stats, events=upd.events, intermediates=inter,
        )
