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

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from edge.lane.angles import AngleStage, ResolveStage
from edge.lane.clutter import ClutterMap
from edge.lane.detections import DetectionStage
from edge.lane.pairs import PairStage
from edge.lane.peaks import PeakStage
from edge.lane.records import Feedback
from edge.lane.road import RoadFrame
from edge.lane.spectra import SpectraStage
from edge.pipeline import Pipeline, PipelineError, StageTimer
from edge.types import Detections, FrameResult, FrontendInfo, RawFrame


@dataclass(frozen=True)
class LaneConfig:
    """Signal processing of the lane profile (Lim §III-A); defaults follow the paper where it gives values."""

    window: str = field(default="hann", metadata={
        "doc": "range window applied before every FFT", "choices": ("hann", "hamming", "blackman", "kaiser", "boxcar")})
    clutter_map_time_s: float = field(default=20.0, metadata={
        "unit": "s", "doc": "time constant of the static-clutter map: an exponential average of each channel's "
               "complex spectrum subtracted before detection (guard rails, gantries, poles and the TX leakage "
               "vanish; a vehicle standing much longer than this fades too); 0 = off",
        "min": 0.0, "max": 3600.0})
    clutter_map_hold_speed_mps: float = field(default=1.0, metadata={
        "unit": "m/s", "doc": "the clutter map is not updated in the range bins of a confirmed track that once moved "
               "and is now slower than this (from 3 m before its near face to clutter_map_hold_length_m behind): a "
               "stopped vehicle (a breakdown, engine off: a static echo) would otherwise fade into the map within "
               "about clutter_map_time_s and its track be lost while it stands. Measured, off -> on, stopped-vehicle "
               "seeds 1-3 (a car standing a minute, a van 40 s): the car tracked in 0.43/0.45/0.72 -> 0.99/1.0/1.0 "
               "of its frames, the van 1.0/0.84/0.93 -> 1.0, id switches 2/4/5 -> 3/0/2, confirmed false tracks "
               "0/1/2 -> 5/0/1 (seed 1: ghosts at 4 m/s beside the two standing vehicles); 0 = off",
        "min": 0.0, "max": 10.0})
    clutter_map_hold_length_m: float = field(default=20.0, metadata={
        "unit": "m", "doc": "... range held behind a stopped track's near face (its body: a truck and more)",
        "min": 0.0, "max": 100.0})
    clutter_map_warmup_frames: int = field(default=60, metadata={
        "doc": "the clutter map starts as a running mean, frame n weighted max(1/(n + this), 1 - exp(-T/time "
               "constant)): static clutter is learned in seconds, a vehicle of the first frames stays in it at "
               "1/this of its amplitude (-36 dB) only", "min": 1, "max": 1_000_000})
    cfar_pfa: float = field(default=1e-3, metadata={
        "doc": "design false-alarm probability per cell of the OS-CFAR (sets the threshold scale). Lim gives no "
               "value; 1e-3 (about 4 noise peaks per frame over 4 x 1024 cells) is affordable because a target "
               "needs peaks in all four segments that agree in range, speed and angle: measured on highway4 and "
               "highway4-traffic, 1e-3 gives no false track and 15 points more detection probability than 1e-6",
        "min": 1e-12, "max": 0.1})
    cfar_train_cells: int = field(default=16, metadata={
        "doc": "OS-CFAR reference cells on each side of the cell under test", "min": 2, "max": 128})
    cfar_guard_cells: int = field(default=2, metadata={
        "doc": "guard cells on each side (a Hann-windowed peak spreads over +-2 bins)", "min": 0, "max": 32})
    cfar_rank_fraction: float = field(default=0.75, metadata={
        "doc": "rank of the ordered statistic as a fraction of the reference cells (Rohling: 3/4)",
        "min": 0.05, "max": 1.0})
    cfar_cap_db: float = field(default=9.0, metadata={
        "unit": "dB", "doc": "the OS-CFAR noise estimate is capped at the segment's median power plus this: "
               "an extended vehicle (or several) filling the reference window cannot mask itself. Where the beats "
               "of several vehicles crowd (a receding car 10-25 m away shares the fast-up bins of approaching "
               "vehicles 35 m farther) more than a quarter of the window holds echoes and the cap sets the "
               "threshold; measured on highway4-traffic seeds 5, 6, 7 (3000 frames each) against 12 dB: car Pd "
               "+0.2 points, summed count error 4 -> 2, false tracks 7 -> 8, 0.03 ms more per frame",
        "min": 0.0, "max": 100.0})
    cfar_full_threshold: bool = field(default=False, metadata={
        "doc": "compute the OS-CFAR threshold at every bin (for plots); off: only at local maxima, the only cells "
               "that can become peaks (same detections, a fifth of the work); other bins read NaN"})
    min_range_m: float = field(default=5.0, metadata={
        "unit": "m", "doc": "nearest slant range reported (TX->RX leakage and the overpass itself are closer)",
        "min": 0.0, "max": 100.0})
    max_range_m: float = field(default=375.0, metadata={
        "unit": "m", "doc": "farthest slant range reported (design range 300 m; a car fades out at 350-390 m and an "
               "approaching one is tracked from there, so its track is confirmed when it reaches 300 m: on "
               "highway4-traffic seed 1 (2 min) car Pd at 250-300 m 0.92 with 330 m, 0.94 with 375 m; 384 m is the "
               "unambiguous range at standstill)", "min": 10.0, "max": 400.0})
    max_speed_kmh: float = field(default=250.0, metadata={
        "unit": "km/h", "doc": "largest radial speed a pairing may have", "min": 10.0, "max": 400.0})
    max_peaks_per_segment: int = field(default=128, metadata={
        "doc": "strongest CFAR peaks kept per segment (bounds the pairing work)", "min": 1, "max": 1024})
    pair_tolerance_bins: float = field(default=1.0, metadata={
        "doc": "a fast pairing is confirmed when slow-segment peaks lie within this many slow-segment bins "
               "of both predictions (ghost rejection); an extended vehicle's unresolved scatterers shift its peaks "
               "by up to about a bin", "min": 0.05, "max": 5.0})
    pair_near_tolerance_bins: float = field(default=1.5, metadata={
        "doc": "pair_tolerance_bins for candidates nearer than pair_near_range_m. Near the overpass a vehicle's "
               "radial speed changes within the 33 ms frame (radial acceleration v^2 h^2 / R^3 with h the lateral "
               "and height offset: 30 m/s^2 at 12 m, 100 km/h, an outer lane, i.e. a slow bin between the segments) "
               "and its body spans many bins and degrees seen from the radar's height, so the four segments' peaks "
               "agree less well; measured on highway4-traffic seeds 5 and 6 (3000 frames): receding cars at 10-25 "
               "m were paired in about half their frames with 1.0 (a slow segment 1.0-1.5 bins off the fast pair's "
               "prediction)", "min": 0.05, "max": 5.0})
    pair_near_range_m: float = field(default=40.0, metadata={
        "unit": "m", "doc": "slant range up to which pair_near_tolerance_bins applies (the radial acceleration "
               "falls with R^3: 1 m/s^2 beyond about 40 m); 0 = off", "min": 0.0, "max": 400.0})
    pair_max_shared_peaks: int = field(default=1, metadata={
        "doc": "a pairing may share this many of its four peaks with better pairings (vehicles whose beats "
               "coincide in one segment); 0 = every peak belongs to one pairing", "min": 0, "max": 3})
    angle_step_deg: float = field(default=0.25, metadata={
        "unit": "deg", "doc": "Bartlett grid step (refined by a parabola)", "min": 0.01, "max": 2.0})
    angle_max_deg: float = field(default=19.0, metadata={
        "unit": "deg", "doc": "Bartlett grid half-width (unambiguous sector of d = 1.5 lambda: 19.47 deg)",
        "min": 1.0, "max": 90.0})
    angle_outlier_deg: float = field(default=2.0, metadata={
        "unit": "deg", "doc": "a segment whose own Bartlett maximum is farther than this from the median of the four "
               "is left out of the angle estimate (another vehicle shares its bin); 90 = keep all",
        "min": 0.1, "max": 90.0})
    angle_outlier_lateral_m: float = field(default=1.0, metadata={
        "unit": "m", "doc": "... widened near the radar to this lateral distance at the detection's range "
               "(max(angle_outlier_deg, this / range)): a car 12 m away spans 9 deg and each segment's maximum "
               "lands on another part of its body (1.0 m: 4.8 deg at 12 m, the 2 deg floor from 29 m on; less than "
               "half the 3.5 m lane spacing, so the peaks of two vehicles in adjacent lanes still disagree)",
        "min": 0.0, "max": 10.0})
    angle_skip_shared_looks: bool = field(default=True, metadata={
        "doc": "leave a segment out of a detection's angle (and of the side-by-side resolver's looks) when its peak "
               "bin is also the peak of another accepted pairing (within angle_shared_bins): two vehicles whose beats "
               "coincide in that segment, the weaker or nearer-in-angle visitor passing angle_outlier_deg; kept where "
               "fewer than two agreeing segments would remain. In busy traffic 15 % of detections have such a "
               "segment (highway4-traffic seed 7012, 1000 frames). Measured, off -> on: highway4 seeds 7001-7040, "
               "per-seed mean position RMSE lower on 37 of 40 (summed 2.642 -> 2.502 m), seeds with a vehicle over "
               "0.15 m 5 -> 4, no false track either way; highway4-traffic ten minutes, seeds 5, 7007, 7012, 7015, "
               "7016, 7018, 7019, 7020: position RMSE mean 0.251-0.274 -> 0.221-0.246 m (every seed), counted "
               "crossings matching no vehicle 7 -> 1, vehicles not counted 5 -> 8 (two of the new ones crossed "
               "untracked in both runs and had been counted late by chance; the third, a coasting truck track "
               "drifting sideways in both runs, crossed the line 0.1 m beyond the lane boundary), id switches 283 -> "
               "264, confirmed false tracks 134 -> 116, car detection probability within 0.001; the phantom that the "
               "resolver split off car 120 of seed 7012 (another vehicle in two of its segments) is gone"})
    angle_shared_bins: int = field(default=1, metadata={
        "doc": "peaks this many FFT bins apart or closer in one segment count as shared (a Hann window's main lobe "
               "spans +-2 bins: two beats a bin apart merge into one peak)", "min": 0, "max": 4})
    angle_shared_speed_mps: float = field(default=1.0, metadata={
        "unit": "m/s", "doc": "... only with a pairing whose radial speed differs by more than this (another "
               "vehicle; one vehicle's scatterers pair into several detections of its speed a bin or two apart)",
        "min": 0.0, "max": 20.0})
    angle_min_agreeing: int = field(default=3, metadata={
        "doc": "a pairing is kept only if at least this many of the four segments agree on its angle: the peaks "
               "of a ghost pairing come from different vehicles and point in different directions",
        "min": 1, "max": 4})
    aided_pairing: bool = field(default=True, metadata={
        "doc": "confirmed tracks (and far approaching tentative ones: aided_tentative_min_range_m) that got no "
               "pairing look for their own peaks near their predicted beat frequencies (near vehicles smear over "
               "several bins and the four segments stop agreeing within pair_tolerance_bins)"})
    aided_window_bins: float = field(default=3.0, metadata={
        "doc": "search half-width around a track's predicted beat frequency, in bins of each segment",
        "min": 0.5, "max": 20.0})
    aided_min_segments: int = field(default=4, metadata={
        "doc": "segments that must hold a peak near the prediction (range and speed are fitted to them). Measured "
               "on highway4-misaimed seed 11 (90 s): 4 raises the detection probability 0.933 -> 0.934 with "
               "id switches 13 -> 12; 3 gives 0.936 but 22 id switches (tracks live on other vehicles' peaks)",
        "min": 2, "max": 4})
    aided_pfa: float = field(default=1e-2, metadata={
        "doc": "false-alarm probability of the lower OS-CFAR threshold at which a confirmed track's search also takes "
               "local maxima that missed cfar_pfa (the track says where to look: four segments within "
               "aided_window_bins of their predictions and a range/speed fit inside the aided gates make a noise "
               "coincidence rare); 0 = only the cfar_pfa peaks. A car near 300 m or under the overpass crosses "
               "the cfar_pfa threshold in all four segments in about 60 % of its frames only",
        "min": 0.0, "max": 0.1})
    aided_gate_m: float = field(default=2.5, metadata={
        "unit": "m", "doc": "fitted range within this of the track's predicted slant range (and an existing "
               "pairing this close means the track needs no help)", "min": 0.1, "max": 20.0})
    aided_gate_mps: float = field(default=1.5, metadata={
        "unit": "m/s", "doc": "... and fitted radial speed within this of the prediction", "min": 0.1, "max": 20.0})
    aided_tentative_min_range_m: float = field(default=200.0, metadata={
        "unit": "m", "doc": "tentative tracks at least this far (ground range), surely moving (the tracker's "
               "moving test), approaching and with aided_tentative_min_hits hits, search for their own peaks as confirmed tracks do (0 = confirmed "
               "tracks only). Far cars cross the cfar_pfa threshold in all four segments in a third to a half of "
               "their frames (glint; the outer lane's weaker; a car beside another at a few metres' range and m/s "
               "also loses its slow-segment peak in the neighbour's stronger one), so their tentative tracks missed "
               "5 of 10 and expired while the neighbour's confirmed track was the only one (the evaluator's 'confirmed "
               "track nearby, assigned to the adjacent-lane neighbour'). highway4-traffic dev seeds 5/6/7 (6000 frames), "
               "car Pd 0.984/0.982/0.981 -> 0.989/0.989/0.987 (250-300 m: 0.955/0.947/0.943 -> 0.972/0.981/0.973), "
               "false tracks 8/7/4 and per-lane counts unchanged, id switches 13/18/9 -> 12/18/10; seed 31: 0.981 -> "
               "0.986, id switches 18 -> 20; 10 min, seeds 5/6: 0.985/0.984 -> 0.990/0.989 (250-300 m: 0.959/0.963 -> "
               "0.978/0.986), false tracks 15/12, counts and lane accuracy unchanged, id switches 38/48 -> 34/48. "
               "What is left there: frames in which the car's peaks miss the lower threshold as well. Without the "
               "approaching rule seed 5 got a false track at 250 m in a receding lane, from 150 m one more",
        "min": 0.0, "max": 1000.0})
    aided_tentative_min_hits: int = field(default=2, metadata={
        "doc": "... once they have this many hits (1, every far seed: car Pd 0.001 higher on seeds 5/6/7, lane "
               "accuracy 0.0004 lower on seed 7)", "min": 1, "max": 32})
    aided_tentative_approaching: bool = field(default=True, metadata={
        "doc": "... and only while they approach (the far edge is where approaching vehicles come into view; a "
               "receding vehicle there has had its track for 250 m)"})
    resolve_pairs: bool = field(default=True, metadata={
        "doc": "split a detection in two when its range-speed cell's spatial covariance, accumulated over frames, "
               "holds two vehicles at different angles (side by side at the same range and speed; "
               "edge.lane.resolve)"})
    resolve_memory_frames: float = field(default=8.0, metadata={
        "doc": "memory (frames) of the per-cell covariance: longer resolves farther, shorter lags less",
        "min": 1.0, "max": 100.0})
    resolve_min_frames: int = field(default=6, metadata={
        "doc": "frames a cell must have been followed before it may be split", "min": 2, "max": 100})
    resolve_min_split_frames: int = field(default=4, metadata={
        "doc": "a cell is split only after it was found to hold two vehicles in this many frames in a row (a "
               "passing vehicle's echo in one look, or one noisy frame, is brief)", "min": 1, "max": 100})
    resolve_min_eig_ratio: float = field(default=0.05, metadata={
        "doc": "second eigenvalue of the cell covariance relative to the first above which two sources are "
               "considered (one vehicle's spread scatterers stay below)", "min": 1e-4, "max": 1.0})
    resolve_min_noise_ratio: float = field(default=8.0, metadata={
        "doc": "... and relative to the mean of the noise eigenvalues", "min": 1.0, "max": 1e4})
    resolve_pair_hint_eig_ratio: float = field(default=0.02, metadata={
        "doc": "a cell not split whose second eigenvalue is above this fraction of the first (and resolve_min_noise_ratio "
               "above the noise) marks its detection extra['unresolved_pair']: two sources too close in angle to be "
               "split (two cars side by side at 100-120 m: 0.026-0.05 while their two-source fit already finds both "
               "lanes; one point-like vehicle about 0.01), whose one angle lies between them. The tracker's lateral "
               "filter does not draw a straight line through such detections (track.pdaf.lateral_smoother)",
        "min": 1e-4, "max": 1.0})
    resolve_min_power_ratio: float = field(default=0.1, metadata={
        "doc": "... and the weaker of the two fitted sources carries at least this fraction of the stronger one's "
               "power (a vehicle with a brief visitor in one of its looks has a strong and a faint source)",
        "min": 0.0, "max": 1.0})
    resolve_min_lateral_m: float = field(default=2.5, metadata={
        "unit": "m", "doc": "the two fitted directions must lie at least this far apart across at the cell's range "
               "(more than one vehicle's width; adjacent lanes are 3.5 m apart)", "min": 0.5, "max": 20.0})
    resolve_boundary_fraction: float = field(default=0.25, metadata={
        "doc": "when lanes are known (configured or learned), a split is kept only if its two directions lie in "
               "adjacent lanes and their midpoint within this fraction of the lane spacing from the boundary "
               "between them (a truck's two sides straddle one lane's centre instead)", "min": 0.0, "max": 1.0})
    resolve_follow_direction: bool = field(default=True, metadata={
        "doc": "steer a cell's covariance memory along with its vehicle's direction (sin(az) scales with 1/range at a "
               "fixed lateral position) before adding a frame: without it the memory of a vehicle near the radar, "
               "whose direction sweeps by degrees within resolve_memory_frames, held its earlier direction as a "
               "second source and the cell was split into the vehicle and a phantom 3 m further out, in the next "
               "lane (highway4-traffic seeds 31 and 57: tracks beside receding cars at 30-40 m counted in lane 3). "
               "Measured with resolve_skip_bodies and resolve_same_direction on highway4-traffic seeds 5, 6, 7 "
               "(6000 frames each) against all three off: summed |count error| 3 -> 2 (the three tracks counted "
               "beside receding vehicles gone; a car hidden beside another in the next lane at its speed, counted "
               "through a split before, missed on seed 7), false tracks 19 -> 19, id switches 43 -> 40, detection "
               "probability within 0.001; side-by-side seeds 3, 5, 6, 8, 21 (300 frames) tracked fractions within "
               "0.1 per car"})
    resolve_skip_bodies: bool = field(default=True, metadata={
        "doc": "no split of a cell that lies behind a nearer detection of the same vehicle (up to cluster_length_m "
               "nearer, within cluster_speed_mps and cluster_lateral_m of the cell's unsplit position): a vehicle's "
               "body puts its two sides (or a side and its far face) in one range bin, a rank-two covariance the "
               "4-element array cannot resolve, and the two-source fit pushed one direction into the next lane, 3-4 m "
               "beside the vehicle, where it seeded tracks that were counted (highway4-traffic seed 31: beside a "
               "receding van and an approaching truck); two vehicles side by side are the nearest detections of "
               "both"})
    resolve_same_direction: bool = field(default=True, metadata={
        "doc": "when lanes are known, a split is kept only if both its lanes carry the cell's direction of travel "
               "(the sign of its radial speed): two vehicles in one range-speed cell move the same way, and a body "
               "split across the median put a track against its lane's direction (a wrong-way alarm)"})
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
        "unit": "m", "doc": "detections at most this much farther than another one with the same radial speed and "
               "lateral position are the same vehicle's body and dropped (0 = keep every detection); 17 m holds the "
               "longest truck (16.5 m): with 7 m, the rear half of a truck seeded a second track that lived for "
               "seconds (a false track, an id switch when it took over, a track on the body instead of the near face). "
               "A follower this close at the same speed is hidden meanwhile (0.6 s headway at 100 km/h)",
        "min": 0.0, "max": 30.0})
    cluster_speed_mps: float = field(default=0.6, metadata={
        "unit": "m/s", "doc": "radial speed difference within which detections can be one vehicle (the body's own "
               "scatterers share its speed)",
        "min": 0.0, "max": 10.0})
    cluster_lateral_m: float = field(default=1.5, metadata={
        "unit": "m", "doc": "lateral difference within which detections can be one vehicle (half a lane)",
        "min": 0.0, "max": 10.0})
    tracking: bool = field(default=True, metadata={
        "doc": "run the PDAF tracker and the traffic layer (off: detections only)"})
    unalias_by_lane: bool = field(default=True, metadata={
        "doc": "when lanes are known, a moving detection that lands in a lane of the other direction of travel is "
               "moved to its grating-lobe alias (sin(az) +- lambda/d) if that lies in a lane of its own direction: "
               "near vehicles in outer lanes lie beyond the +-19.5 deg unambiguous sector and appeared mirrored "
               "across the road as receding vehicles in approaching lanes (8 of 12 false tracks on highway4-traffic "
               "seed 2, first 2 min)"})
    unalias_min_speed_mps: float = field(default=1.0, metadata={
        "unit": "m/s", "doc": "radial speed below which a detection's direction of travel is unknown (not unaliased)",
        "min": 0.0, "max": 50.0})
    cluster_ghost_speed_mps: float = field(default=6.0, metadata={
        "unit": "m/s", "doc": "wrong pairings among a body's scatterers: a long vehicle's equally spaced scatterers "
               "(near face, side scatterers every L/5, far face) at R'-2u, R'-u, R'+u, R'+2u fit a target at R' with "
               "speed v +- u a/b exactly in all four segments (a/b = 1.66 m/s per m of the fast segments; pair "
               "residual ~1 Hz), so ghosts at v +- 5 m/s appear 6-10 m behind a truck's near face. Detections behind "
               "a nearer one are dropped up to this speed difference, but at most cluster_ghost_speed_per_m x their "
               "distance behind and at most cluster_ghost_length_m behind; 0 = off. Measured on highway4-traffic "
               "seeds 5, 6, 7 (3000 frames each): the ghosts of receding trucks seeded tracks running ahead of them "
               "across the detection line (false tracks 12 -> 7, summed count error 6 -> 4; 0.83 and 0.9 m/s per m "
               "alike); crossing keeps both ids",
        "min": 0.0, "max": 20.0})
    cluster_ghost_speed_per_m: float = field(default=0.9, metadata={
        "unit": "m/s per m", "doc": "... the ghost law: a ghost lies at least 2u behind the near face and is off by "
               "u a/b, i.e. at most a / (2 b) = 0.83 m/s per metre behind; 0.9 leaves room for the least-squares fit "
               "over the four segments (a ghost exactly 2u behind came out at 0.834) and still keeps a car 3 m behind "
               "a van at 2.8 m/s more (crossing; 1.7 dropped it)",
        "min": 0.0, "max": 10.0})
    cluster_ghost_length_m: float = field(default=12.0, metadata={
        "unit": "m", "doc": "... and only up to this far behind (a ghost at R' needs a scatterer 2u beyond it on the "
               "body: R' <= 16.5 m - 2u; seen up to 9 m behind trucks)", "min": 0.0, "max": 30.0})
    cluster_against_lane_speed_mps: float = field(default=0.3, metadata={
        "unit": "m/s", "doc": "angle glint of a vehicle's body: a detection in a lane of the other direction of "
               "travel (moving against it) that lies up to cluster_length_m behind a nearer detection within this "
               "radial speed of it, and within the array's beamwidth in angle, is dropped (when lanes are known). Two "
               "scatterers of one range cell in antiphase pull the 4-element Bartlett peak aside by up to a "
               "beamwidth: an approaching truck's body at 45-60 m showed up 5-6 m beside it, in the receding lane, "
               "at the truck's speed (within 0.15 m/s) in a third of the frames, and seeded a track that raised a "
               "false wrong_way alarm (highway4-traffic seeds 5, 7015, 7016). A wrong-way driver pacing a vehicle of "
               "the other carriageway this closely is dropped while it does. Measured, off -> on (with "
               "traffic.wrong_way_azimuth_sigma_deg), highway4-traffic ten minutes, seeds 5, 7007, 7012, 7015, 7016, "
               "7018, 7019, 7020: confirmed false tracks 116 -> 73, id switches 264 -> 238, false wrong_way alarms "
               "5 -> 0, per-lane counts the same, car detection probability the same or 1e-4 lower (3 seeds); "
               "highway4 seeds 7001-7040, side-by-side and crossing 1-8 unchanged; 0 = off",
        "min": 0.0, "max": 10.0})
    cluster_against_lane_margin_m: float = field(default=1.0, metadata={
        "unit": "m", "doc": "... only where the lanes this far to either side (plus the traffic layer's wrong-way "
               "lane uncertainty: traffic.wrong_way_lane_sigmas x range x the yaw's and the tracks' azimuth "
               "uncertainty) run the same way: a receding car by the median can show up just across it, beside a "
               "vehicle of its speed in the next lane (the glints lay 3 m and more inside)",
        "min": 0.0, "max": 10.0})
    cluster_ghost_from_near_face: bool = field(default=True, metadata={
        "doc": "... measured from a near face only (a detection with no nearer one of its speed within "
               "cluster_length_m): a ghost lies within its body, while a detection behind another vehicle's far end "
               "is the next vehicle (highway4-traffic seed 7018: a truck 17 m behind a 6 m van, 2.5 m/s faster, lay "
               "11 m behind the van's rear face and was dropped in every frame; its track coasted and drifted a "
               "lane over). Measured, off -> on, highway4-traffic ten minutes, seeds 5, 7007, 7012, 7015, 7016, "
               "7018, 7019, 7020: vehicles not counted 8 -> 6, counted crossings matching no vehicle 1 -> 0, summed "
               "|count error| per lane 9 -> 6, id switches 264 -> 256, confirmed false tracks 116 -> 120; highway4 "
               "seeds 7001-7040 unchanged"})
    clutter_map_init_frames: int = field(default=16, metadata={
        "doc": "after this many frames the clutter map is replaced by the per-bin median (real and imaginary parts) "
               "of those frames: static returns, above all the TX->RX leakage 80 dB over the noise at DC, are then "
               "removed exactly, while the running mean alone leaves (warm-up - 1)/(n + warm-up) of them for minutes "
               "and masks every beat near zero frequency (vehicles 10-35 m from the radar); a vehicle moves through "
               "a bin in a frame or two and stays out of the median; 0 = running mean only",
        "min": 0, "max": 256})


#: a detection within this range and radial speed of a track is the one it follows (its near face), for its length
_TRACK_DET_RANGE_M = 1.5
_TRACK_DET_SPEED_MPS = 1.0


class LanePipeline(Pipeline):
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
        self.spectra = SpectraStage(frontend, cfg, self.clutter, self.peaks.pad)
        self.angles = AngleStage(frontend, cfg, want_looks=cfg.resolve_pairs)
        self.resolve = (ResolveStage(frontend, cfg, self.angles.steer, self.angles.grid, road)
                        if cfg.resolve_pairs else None)
        self.detections = DetectionStage(frontend, cfg, road)
        self.tracker = self.traffic = None
        if cfg.tracking:
            from edge.track import PdafConfig, PdafTracker
            from edge.traffic import TrafficConfig, TrafficMonitor

            self.tracker = PdafTracker(track_config or PdafConfig())
            # the radial-speed noise near the radar (track.pdaf.near_speed_spread_m) needs the radar's height
            self.tracker.sensor_height_m = cfg.mounting_height_m - cfg.target_height_m
            self.traffic = TrafficMonitor(traffic_config or TrafficConfig())
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
        tcfg = traffic.config
        return Feedback(self.tracker.last_t_ns, tr.x, tr.confirmed, tr.moved, tr.hits, traffic.lanes, traffic.yaw_rad,
                        math.hypot(traffic.yaw_sigma_rad, math.radians(tcfg.wrong_way_azimuth_sigma_deg)),
                        tcfg.wrong_way_lane_sigmas)

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
            peaks = self.peaks(spectra, self.peaks.aided_scale32 is not None and bool(fb.confirmed.any()))
        with timer.stage("pairing"):
            pairs = self.pairs(peaks, frame.t_ns, fb)
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
        out = np.full(len(tracks), np.nan)
        if not len(det) or not len(tracks):
            return out
        tr = np.array([(t.range_m, t.radial_speed_mps) for t in tracks], dtype=np.float64).reshape(-1, 2)
        dr = np.abs(det.range_m[None, :].astype(np.float64) - tr[:, :1])
        near = (dr <= _TRACK_DET_RANGE_M) & (np.abs(det.radial_speed_mps[None, :] - tr[:, 1:]) <= _TRACK_DET_SPEED_MPS)
        hit = near.any(axis=1)
        if hit.any():
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
