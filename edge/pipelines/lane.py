"""The ``lane`` profile: Lim et al. (IEEE Access 2021) §III on the 1 TX x 4 RX SIMO board (Fig. 10).

Per frame (four chirp segments: fast up, fast down, slow up, slow down; 4 receive channels)::

    int16 I/Q -> complex64 -> windowed range FFT (every segment and channel)
      -> static-clutter map subtracted (exponential average of the complex spectra, initialised with the
         per-bin median of the first frames so the TX leakage at DC is gone within half a second)
      -> non-coherent integration over the channels -> OS-CFAR per segment -> local maxima,
         sub-bin interpolation -> signed beat frequencies
      -> four-segment pairing (edge.dsp.pairing): range at the frame start and radial speed,
         ghosts of wrong pairings rejected by the slow segments (and wrong pairings between two
         scatterers of one long truck dropped once their true pairs are in)
      -> track-aided pairing: a confirmed track that got no pairing takes the peaks nearest its predicted
         beats in all four segments (a near vehicle's body smears its echo over several bins), local maxima
         above a lower OS-CFAR threshold (``aided_pfa``) included; so does a far approaching tentative track
         (``aided_tentative_*``: a far car is detected in only part of its frames and must confirm before 300 m)
      -> Bartlett angle over the 4 channels (calibration vector divided out), the 4 segments as looks,
         each normalised, a segment that disagrees with the others left out (edge.dsp.angle; the agreement
         window widens near the radar, where a vehicle spans degrees), and so is a segment whose peak another
         accepted pairing of another speed also uses (two vehicles' beats coincide there: a weak or nearby
         visitor biases the angle without disagreeing, and held over frames it is a second source to the
         resolver)
      -> resolve (edge.dsp.resolve): a detection whose range-speed cell holds two vehicles side by side
         (rank-two spatial covariance over frames, its memory steered along with the vehicles' direction)
         becomes two detections, one per fitted angle -- not when the cell lies behind a nearer detection of
         the same vehicle (its body), nor across lanes of opposite directions
      -> grating-lobe aliases of near vehicles beyond +-19.5 deg moved back into a lane of their direction
      -> ground-plane x/y (edge.dsp.geometry, eq. 16 for a raised radar), nearest face of each body (a 17 m
         body's detections and the wrong pairings among its scatterers -- ghosts at v +- u a/b, within reach of
         its near face -- dropped)
      -> PDAF tracker (edge.track) -> lanes, statistics, events (edge.traffic)

All parameters are in :class:`LaneConfig` (section ``pipeline.lane``); the tracker and the traffic
layer read ``track.pdaf`` and ``traffic``. Intermediates for plots: ``power`` (segments x bins, linear),
``threshold`` and ``noise`` (linear; NaN away from local maxima unless ``cfar_full_threshold``),
``peak_freqs_hz`` (per segment), pairing counts (``n_aided_pairs`` from tracks), ``angle_spectrum``.
Detections carry ``extra["body_extent_m"]`` (along-road length of the body behind the detection, from the detections
dropped as its body: the vehicle length the traffic layer measures), ``extra["resolved_pair"]`` (>= 0: the two
detections split from one share the value) and
``extra["unresolved_pair"]`` (bool: the resolver found two sources in the cell but could not split them).
"""

from __future__ import annotations

import bisect
import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import scipy.fft

from edge.dsp.angle import bartlett_consensus, peak_coherence, steering_matrix
from edge.dsp.cfar import os_cfar, os_cfar_at_padded, os_cfar_scale, reference_index
from edge.dsp.geometry import polar_to_ground
from edge.dsp.pairing import PairingModel, nearest_of_clusters, pair_beats
from edge.dsp.peaks import interpolate_peak, local_maxima
from edge.dsp.resolve import CellResolver, ResolverConfig
from edge.dsp.range_fft import make_window
from edge.pipeline import Pipeline, PipelineError, StageTimer
from edge.traffic.lanes import assign_lanes
from edge.types import Detections, FrameResult, FrontendInfo, RawFrame
from hal.waveform import SPEED_OF_LIGHT_MPS


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
    clutter_map_static_factor: float = field(default=8.0, metadata={
        "doc": "the clutter map learns a bin only while it stands: where its frame-to-frame change, summed over the "
               "channels, is at most this many times the segment's median change (a moving echo's phase turns and "
               "its beat moves between frames; a standing one changes by noise alone); 0 = every bin learns",
        "min": 0.0, "max": 1e6})
    clutter_map_static_rel: float = field(default=0.05, metadata={
        "doc": "... plus this fraction of the bin's own amplitude (the frame-to-frame change of a strong standing "
               "echo under phase noise: 0.2 deg per chirp is 0.5 %)", "min": 0.0, "max": 1.0})
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
               "edge.dsp.resolve)"})
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


_SEG4 = np.arange(4)  # the four segments, as an index

#: a detection within this range and radial speed of a track is the one it follows (its near face), for its length
_TRACK_DET_RANGE_M = 1.5
_TRACK_DET_SPEED_MPS = 1.0

#: up to this many confirmed tracks the track-aided pairing predicts them in plain Python floats
_AIDED_SMALL = 10


def _median_of_frames(frames: np.ndarray) -> np.ndarray:
    """``np.median(z.real, axis=0) + 1j * np.median(z.imag, axis=0)`` of the complex64 spectra ``z`` (frames on the
    first axis) of the first frames: np.median's value (the middle element, or the mean of the middle two: their
    float32 sum halved; NaN where a NaN is among the values) from one sort of contiguous rows, each cell's real or
    imaginary part over the frames. np.median selects along the strided frame axis instead: 9 ms of CPU time for
    16 frames of 4 x 4 x 1024 bins on the development machine, in a single frame; the transpose and sort take
    1.5 ms. (Storing each frame straight into the transposed layout would spread the transpose over the first
    frames, but its strided writes cost more than the copy.)"""
    k = frames.shape[0]
    v = frames.view(np.float32).reshape(k, -1).T.copy()  # (cells x re/im, frames)
    v.sort(axis=1)
    h = k // 2
    if k % 2:
        m = v[:, h]
    else:
        m = v[:, h - 1] + v[:, h]
        m /= 2
    last = np.isnan(v[:, -1])  # NaN sorts last
    if last.any():
        m[last] = np.nan
    m = m.reshape(frames.shape[1:] + (2,))
    return m[..., 0] + 1j * m[..., 1]


def _segment_slopes(fe: FrontendInfo) -> np.ndarray:
    return np.array([s.slope_hz_per_s for s in fe.waveform.segments])


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
        n = wf.n_samples
        self.n_bins = n
        self.window = make_window(cfg.window, n)
        self._iq = np.empty(frontend.frame_shape, dtype=np.complex64)
        # the window times the FFT's 1/n scale when n is a power of two (scaling by 2^-k before the FFT
        # is exact, the same spectrum bit for bit as scaling after it); one multiply less per frame
        self._post_scale = n & (n - 1) != 0
        self._window_scaled = self.window if self._post_scale else self.window * np.float32(1.0 / n)
        self._sq = np.empty(frontend.frame_shape + (2,), dtype=np.float32)  # |re|^2, |im|^2 scratch
        self._sq_sum = np.empty(frontend.frame_shape, dtype=np.float32)
        self._diff = np.empty(frontend.frame_shape, dtype=np.complex64)  # clutter-map scratch
        fs = np.array([s.sample_rate_hz for s in wf.segments])
        self._bin_hz = fs / n  # (4,)
        self._freq = (np.fft.fftfreq(n)[None, :] * fs[:, None])  # (4, n) float64 signed Hz per bin
        # search region per segment: beats of targets in [min_range, max_range] at any allowed speed
        slope = _segment_slopes(frontend)
        c = SPEED_OF_LIGHT_MPS
        v_max = cfg.max_speed_kmh / 3.6
        fd = 2.0 * v_max / wf.wavelength_m
        lo = np.minimum(slope * 2 * cfg.min_range_m / c, slope * 2 * cfg.max_range_m / c) - fd
        hi = np.maximum(slope * 2 * cfg.min_range_m / c, slope * 2 * cfg.max_range_m / c) + fd
        self._valid = (self._freq >= lo[:, None]) & (self._freq <= hi[:, None])  # (4, n) bool
        self._n_ref = 2 * cfg.cfar_train_cells
        self._rank = max(1, min(self._n_ref, int(round(cfg.cfar_rank_fraction * self._n_ref))))
        self.cfar_scale = os_cfar_scale(cfg.cfar_pfa, self._n_ref, self._rank, n_looks=n_rx)
        period = wf.frame_period_s
        self._alpha = np.float32(1.0 - math.exp(-period / cfg.clutter_map_time_s)) if cfg.clutter_map_time_s > 0 else 0.0
        self._background = np.zeros(frontend.frame_shape, dtype=np.complex64)  # (rx, seg, bin) static-clutter map
        self._map_frames = 0
        self._prev_spec = None  # the last frame's raw spectrum (clutter_map_static_factor)
        k_init = cfg.clutter_map_init_frames if self._alpha > 0 else 0
        self._map_init = np.zeros((k_init,) + tuple(frontend.frame_shape), np.complex64) if k_init > 1 else None
        self._cap = np.float32(10.0 ** (cfg.cfar_cap_db / 10.0))
        self._ref_index = reference_index(n, cfg.cfar_train_cells, cfg.cfar_guard_cells)
        self._half = cfg.cfar_train_cells + cfg.cfar_guard_cells  # circular padding of the power rows
        self._freq_flat = self._freq.ravel()
        self._bin_shift = n.bit_length() - 1 if n & (n - 1) == 0 else None
        self._nan_rows = np.full((len(wf.segments), n), np.nan, np.float32)
        self._tiny = np.float32(1e-30)
        self._seg_ends = np.arange(1, len(wf.segments) + 1)
        self._aided_window_hz = cfg.aided_window_bins * self._bin_hz  # (4,)
        self._seg_bin0 = np.arange(len(wf.segments)) * n  # first bin of each segment in a (rx, seg * bin) view
        self._scale32 = np.float32(self.cfar_scale)
        self._aided_scale32 = None  # the lower threshold of track-aided pairing (weak peaks)
        if cfg.aided_pairing and 0 < cfg.aided_pfa and cfg.tracking:
            self._aided_scale32 = np.float32(min(os_cfar_scale(cfg.aided_pfa, self._n_ref, self._rank, n_looks=n_rx),
                                                 self.cfar_scale))
        self._alias_period = wf.wavelength_m / frontend.rx_spacing_m  # grating-lobe period in sin(az)
        self._alias_offsets = np.array([0.0, self._alias_period, -self._alias_period])[:, None]  # (3, 1)
        self._beamwidth_sin = self._alias_period / frontend.n_rx  # Rayleigh width lambda / (N d) in sin(az)
        self._lane_cache: tuple = (None, 0.0, None)  # (lanes, their span across, directions): see _lane_arrays
        self._centres_cache: tuple = (None, None)  # (lanes, their centres): see _lane_centres
        self._pad_inf, self._pad_zero = np.zeros(0), np.zeros(0, np.int64)  # padding rows of _track_aided_pairs
        self._aided_empty = (np.zeros((0, 4), np.int64), np.zeros(0, np.float32), np.zeros(0, np.float32),
                             np.zeros(0, np.float32))  # no track-aided pairs (read, never written)
        self._model = PairingModel.from_waveform(wf)
        self._model_ab = np.stack([self._model.a, self._model.b], axis=1)  # (4, 2): beat = a R + b v per segment
        # a static echo's FFT bins per metre of range in each segment (negative on a down-chirp): _hold_standing
        self._bins_per_m = (self._model.a / self._bin_hz).tolist()
        self._tol = (cfg.pair_tolerance_bins * self._bin_hz[2], cfg.pair_tolerance_bins * self._bin_hz[3])
        self._near_tol = (cfg.pair_near_tolerance_bins * self._bin_hz[2],
                          cfg.pair_near_tolerance_bins * self._bin_hz[3])
        self._outlier_rad = np.float32(math.radians(cfg.angle_outlier_deg))
        half = math.radians(cfg.angle_max_deg)
        self._grid = np.arange(-half, half + 1e-12, math.radians(cfg.angle_step_deg)).astype(np.float32)
        self._steer = steering_matrix(n_rx, frontend.rx_spacing_m, wf.wavelength_m, self._grid)
        cal = np.asarray(cfg.calibration_gain) * np.exp(1j * np.radians(cfg.calibration_phase_deg))
        self._inv_cal = (1.0 / cal).astype(np.complex64)
        self.resolver = None
        if cfg.resolve_pairs:
            self.resolver = CellResolver(
                ResolverConfig(memory_frames=cfg.resolve_memory_frames, min_frames=cfg.resolve_min_frames,
                               min_split_frames=cfg.resolve_min_split_frames,
                               min_eig_ratio=cfg.resolve_min_eig_ratio, min_noise_ratio=cfg.resolve_min_noise_ratio,
                               pair_hint_eig_ratio=cfg.resolve_pair_hint_eig_ratio,
                               min_lateral_m=cfg.resolve_min_lateral_m, min_power_ratio=cfg.resolve_min_power_ratio,
                               follow_direction=cfg.resolve_follow_direction),
                self._steer, self._grid, wf.frame_period_s, frontend.rx_spacing_m / wf.wavelength_m)
        self.tracker = self.traffic = None
        if cfg.tracking:
            from edge.track import PdafConfig, PdafTracker
            from edge.traffic import TrafficConfig, TrafficMonitor

            self.tracker = PdafTracker(track_config or PdafConfig())
            # the radial-speed noise near the radar (track.pdaf.near_speed_spread_m) needs the radar's height
            self.tracker.sensor_height_m = cfg.mounting_height_m - cfg.target_height_m
            self.traffic = TrafficMonitor(traffic_config or TrafficConfig())
        self._want_coherence = self.tracker is not None and self.tracker.config.seed_min_coherence > 0
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

    def detect(self, frame: RawFrame, timer: StageTimer) -> tuple[Detections, dict[str, Any]]:
        """Detections of one frame (everything before the tracker) and the intermediates."""
        cfg = self.config
        with timer.stage("to_complex"):  # int16 -> complex64, windowed on the way
            iq = self._iq
            np.multiply(frame.i, self._window_scaled, out=iq.real)
            np.multiply(frame.q, self._window_scaled, out=iq.imag)
        with timer.stage("range_fft"):
            spec = scipy.fft.fft(iq, axis=-1, overwrite_x=True, workers=1)  # (rx, seg, bin) complex64
            if self._post_scale:
                spec *= np.float32(1.0 / self.n_bins)
            if self._alpha > 0:
                # the map starts empty and learns as a running mean over the first frames (weight
                # 1/(n + warm-up)), then with the time constant: guard-rail posts are gone within seconds
                # of a start instead of a minute (their wrong pairings made tracks hop along the rail);
                # initialising it with the first frame alone would leave that frame's vehicles' images
                alpha = np.float32(max(self._alpha, 1.0 / (self._map_frames + cfg.clutter_map_warmup_frames)))
                d = np.subtract(spec, self._background, out=self._diff)
                d *= alpha
                if cfg.clutter_map_static_factor > 0:
                    self._hold_moving(spec, d)
                if cfg.clutter_map_hold_speed_mps > 0 and self.tracker is not None:
                    self._hold_standing(d)
                self._background += d
                if self._map_init is not None:  # the first frames are kept; then the map is their median
                    self._map_init[self._map_frames] = spec
                    if self._map_frames + 1 == self._map_init.shape[0]:
                        self._background[...] = _median_of_frames(self._map_init)
                        self._map_init = None
                self._map_frames += 1
                spec -= self._background
            # non-coherent sum over the channels, written into the middle of a circularly padded row per
            # segment (the OS-CFAR windows read across the ends); ``power`` is a view of it
            h, n = self._half, self.n_bins
            sq = np.multiply(spec.view(np.float32), spec.view(np.float32), out=self._sq.reshape(spec.shape[:-1] + (-1,)))
            sq = sq.reshape(self._sq.shape)
            np.add(sq[..., 0], sq[..., 1], out=self._sq_sum)
            ppad = np.empty((spec.shape[1], n + 2 * h), np.float32)
            power = ppad[:, h:h + n]
            np.add.reduce(self._sq_sum, axis=0, out=power)  # (seg, bin) float32 (ndarray.sum without its wrapper)
            ppad[:, :h] = ppad[:, n:n + h]
            ppad[:, n + h:] = ppad[:, h:2 * h]
        # weak peaks (above the aided threshold, below the detection one) only when a confirmed track may use them
        want_weak = (self._aided_scale32 is not None and self.tracker is not None
                     and bool(self.tracker.tracks.confirmed.any()))
        weak = None
        with timer.stage("cfar"):
            # median per segment; the power is non-negative, so its float32 bit patterns as int32 sort like the
            # values and numpy selects int32 faster (the same element)
            floor = np.partition(power.view(np.int32), n // 2, axis=-1)[:, n // 2].view(np.float32)
            cap = floor * self._cap  # (4,)
            if cfg.cfar_full_threshold:  # the whole threshold curve, for plots
                _, _, noise = os_cfar(power, self._ref_index, self._rank, self.cfar_scale)
                noise = np.minimum(noise, cap[:, None])
                thr = noise * self._scale32
                rows, cols = np.nonzero(local_maxima(power, (power > thr) & self._valid))
                cells = np.stack([ppad[rows, cols + h + o] for o in (-1, 0, 1)], axis=1)
                if want_weak:
                    wr, wc = np.nonzero(local_maxima(power, (power > noise * self._aided_scale32) & (power <= thr)
                                                     & self._valid))
                    weak = (wr, wc, np.stack([ppad[wr, wc + h + o] for o in (-1, 0, 1)], axis=1))
            else:  # only local maxima can be reported: evaluate the ordered statistic there
                is_max = power > ppad[:, h - 1:h - 1 + n]
                is_max &= power >= ppad[:, h + 1:h + 1 + n]
                is_max &= self._valid
                flat = is_max.reshape(-1).nonzero()[0]
                if self._bin_shift is not None:  # a power of two: np.divmod's values by a shift and a mask
                    rows, cols = flat >> self._bin_shift, flat & (n - 1)
                else:
                    rows, cols = np.divmod(flat, n)
                nz, cells = os_cfar_at_padded(ppad, rows, cols, cfg.cfar_train_cells, cfg.cfar_guard_cells,
                                              self._rank)
                np.minimum(nz, cap[rows], out=nz)
                hit = cells[:, 1] > nz * self._scale32
                noise = self._nan_rows.copy()  # (np.full's value; NaN away from local maxima)
                noise.reshape(-1)[flat] = nz
                thr = noise * self._scale32
                if want_weak:
                    wk = ~hit & (cells[:, 1] > nz * self._aided_scale32)
                    weak = (rows[wk], cols[wk], cells[wk])
                rows, cols, cells = rows[hit], cols[hit], cells[hit]
            # peaks in (segment, bin) order; sub-bin offsets by a parabola through the log-power
            # (edge.dsp.peaks.interpolate_peak, all segments at once)
            bounds = self._segment_bounds(rows)
            wf = None
            if max(e - b for b, e in bounds) > cfg.max_peaks_per_segment:
                freqs, bins = self._strongest_peaks(power, rows, cols)
            else:
                if weak is None:
                    f = self._peak_freqs(rows, cols, cells)
                else:  # the detected and the weak peaks in one interpolation (elementwise; the cost is per call)
                    f = self._peak_freqs(*(np.concatenate([a, b]) for a, b in zip((rows, cols, cells), weak)))
                    f, wf = f[:rows.size], f[rows.size:]
                freqs, bins = [f[b:e] for b, e in bounds], [cols[b:e] for b, e in bounds]
            if weak is not None:  # the same interpolation, grouped by segment
                wr, wc, wcells = weak
                wf = self._peak_freqs(wr, wc, wcells) if wf is None else wf
                bounds = self._segment_bounds(wr)
                weak = ([wf[b:e] for b, e in bounds], [wc[b:e] for b, e in bounds])
        with timer.stage("pairing"):
            pairs = pair_beats(tuple(freqs), self._model, min_range_m=cfg.min_range_m, max_range_m=cfg.max_range_m,
                               max_speed_mps=cfg.max_speed_kmh / 3.6, tolerance_hz=self._tol,
                               max_shared=cfg.pair_max_shared_peaks, near_tolerance_hz=self._near_tol,
                               near_range_m=cfg.pair_near_range_m)
            p_rng, p_vel, p_res = pairs.range_m, pairs.radial_speed_mps, pairs.residual_hz
            # (n, 4 seg) bins: the peaks of the four segments are consecutive in ``all_bins``
            all_bins = np.concatenate(bins)
            seg_start = np.array(list(itertools.accumulate((b.size for b in bins[:-1]), initial=0)))
            pk = all_bins[pairs.peak_index + seg_start] if p_rng.size else np.zeros((0, 4), np.int64)
            n_aided = 0
            if self.tracker is not None and cfg.aided_pairing and len(self.tracker.tracks):
                a_bins, a_rng, a_vel, a_res = self._track_aided_pairs(freqs, bins, pairs, frame.t_ns, weak)
                n_aided = a_rng.size
                if n_aided:
                    pk = np.concatenate([pk, a_bins])
                    p_rng, p_vel, p_res = (np.concatenate([u, w]) for u, w in ((p_rng, a_rng), (p_vel, a_vel),
                                                                              (p_res, a_res)))
        with timer.stage("angle"):
            n_det = p_rng.size
            if n_det:
                snaps = spec.reshape(spec.shape[0], -1).take(pk + self._seg_bin0, axis=1)  # (rx, n, seg)
                snaps = snaps.transpose(1, 2, 0) * self._inv_cal  # (n, seg, rx)
                outlier = self._outlier_rad
                if cfg.angle_outlier_lateral_m > 0:  # wider near the radar, where a vehicle spans degrees
                    outlier = np.maximum(outlier, np.float32(cfg.angle_outlier_lateral_m)
                                         / np.maximum(p_rng, np.float32(1.0)))
                az, aspec, kept, used = bartlett_consensus(
                    snaps, self._steer, self._grid, outlier, pk if cfg.angle_skip_shared_looks else None,
                    cfg.angle_shared_bins, cfg.angle_min_agreeing, speeds=p_vel,
                    min_speed_diff=cfg.angle_shared_speed_mps)
                p0 = power[0, pk[:, 0]]
                n0 = noise[0, pk[:, 0]]
                n0 = np.where(np.isfinite(n0), n0, floor[0])  # a track-aided pair may read a non-peak bin
                snr_db = (10.0 * np.log10(p0 / np.maximum(n0, np.float32(1e-30)))).astype(np.float32)
            else:
                az = snr_db = np.zeros(0, np.float32)
                aspec = np.zeros((0, self._grid.size), np.float32)
                kept = used = np.zeros((0, 4), bool)
            keep = ((np.add.reduce(kept, axis=1) >= cfg.angle_min_agreeing).nonzero()[0] if n_det
                    else np.zeros(0, np.int64))
            rng, vel, res = p_rng[keep], p_vel[keep], p_res[keep]
            az, snr_db = az[keep], snr_db[keep]
            pair_of = np.full(keep.size, -1, np.int32)
            unresolved = None  # two sources in the cell, not split (the resolver's hint)
            coh = None  # the Bartlett peak's share of the looks' energy, when the tracker's seeding asks for it
            if self._want_coherence:
                coh = (peak_coherence(snaps[keep], self._steer, np.argmax(aspec[keep], axis=1), used[keep])
                       if keep.size else np.zeros(0, np.float32))
        if self.resolver is not None:
            with timer.stage("resolve"):
                # only the looks that agreed on the angle and hold no other pairing's peak (another vehicle may
                # share one segment's bin)
                looks = snaps[keep] * used[keep][:, :, None] if n_det else np.zeros((0, 4, self.frontend.n_rx),
                                                                                    np.complex64)
                split, ang = self.resolver.step(rng, vel, looks, az)
                unresolved = self.resolver.two_sources
                any_split = split.any()  # (rare: asked once when nothing is split)
                if any_split and self.traffic is not None and self.traffic.lanes:
                    split &= self._split_straddles_lanes(rng, vel, ang)
                    any_split = split.any()
                if any_split and cfg.resolve_skip_bodies:
                    split &= ~self._split_is_body(rng, vel, az, split)
                    any_split = split.any()
                if any_split:  # each split detection becomes two, one per angle, half the power each
                    s_idx = split.nonzero()[0]
                    az = az.copy()
                    az[s_idx] = ang[s_idx, 0]
                    pair_of[s_idx] = s_idx
                    rng, vel, res = (np.concatenate([a, a[s_idx]]) for a in (rng, vel, res))
                    az = np.concatenate([az, ang[s_idx, 1]])
                    snr_db[s_idx] -= np.float32(3.0)
                    snr_db = np.concatenate([snr_db, snr_db[s_idx]])
                    pair_of = np.concatenate([pair_of, s_idx.astype(np.int32)])
                    unresolved = np.concatenate([unresolved & ~split, np.zeros(s_idx.size, bool)])
                    if coh is not None:  # two sources by construction: not judged by one direction's share
                        coh[s_idx] = 1.0
                        coh = np.concatenate([coh, coh[s_idx]])
        with timer.stage("geometry"):
            if cfg.unalias_by_lane and rng.size and self.traffic is not None and self.traffic.lanes:
                az = self._unalias_by_lane(rng, vel, az)
            x, y = polar_to_ground(rng, az, cfg.mounting_height_m, cfg.target_height_m)
            sel = None  # all kept
            body = None
            if cfg.cluster_length_m > 0 and rng.size > 1:
                keep, ext = nearest_of_clusters(rng, vel, x, length_m=cfg.cluster_length_m,
                                                speed_mps=cfg.cluster_speed_mps, lateral_m=cfg.cluster_lateral_m,
                                                ghost_speed_per_m=cfg.cluster_ghost_speed_per_m,
                                                ghost_speed_mps=cfg.cluster_ghost_speed_mps,
                                                ghost_length_m=cfg.cluster_ghost_length_m,
                                                ghost_from_near_faces=cfg.cluster_ghost_from_near_face,
                                                with_extent=True)
                if (cfg.cluster_against_lane_speed_mps > 0 and self.traffic is not None and self.traffic.lanes
                        and keep.sum() > 1):
                    keep &= ~self._against_lane_glint(rng, vel, az, x, y, keep)
                if not keep.all():
                    sel = keep.nonzero()[0]
                body = self._body_extent(rng, x, ext, keep)
            elif cfg.cluster_length_m > 0:  # one detection or none: no body behind it
                body = np.zeros(rng.size, np.float32)
            if sel is None:  # the arrays themselves (nothing reads or writes them after this)
                det = Detections(rng, vel, az, snr_db, x, y, {"pair_residual_hz": res, "resolved_pair": pair_of})
            else:
                det = Detections(rng[sel], vel[sel], az[sel], snr_db[sel], x[sel], y[sel],
                                 {"pair_residual_hz": res[sel], "resolved_pair": pair_of[sel]})
            if body is not None:
                det.extra["body_extent_m"] = body if sel is None else body[sel]
            if coh is not None:
                det.extra["angle_coherence"] = coh if sel is None else coh[sel]
            if unresolved is not None:
                det.extra["unresolved_pair"] = unresolved if sel is None else unresolved[sel]
        inter = {
            "power": power, "threshold": thr, "noise": noise, "peak_freqs_hz": freqs,
            "n_pair_candidates": pairs.n_candidates, "n_ghosts_rejected": pairs.n_ghosts, "n_aided_pairs": n_aided,
            "angle_grid_rad": self._grid, "angle_spectrum": aspec,
        }
        return det, inter

    def _body_extent(self, rng: np.ndarray, x: np.ndarray, ext: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """Per detection the along-road length of the body behind it (``ext``: its slant range extent, from
        ``nearest_of_clusters``), as ground distance along the road at its lateral offset; NaN for dropped ones."""
        cfg = self.config
        ext = np.where(keep, ext, np.float32(np.nan))
        dz2 = np.float32((cfg.mounting_height_m - cfg.target_height_m) ** 2)
        x2 = x * x
        near = np.sqrt(np.maximum(rng * rng - dz2 - x2, np.float32(0)))
        far_r = rng + ext
        far = np.sqrt(np.maximum(far_r * far_r - dz2 - x2, np.float32(0)))
        return far - near

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

    def _segment_bounds(self, rows: np.ndarray) -> list[tuple[int, int]]:
        """``(start, end)`` of each segment's run in ``rows`` (sorted segment numbers of peaks)."""
        ends = np.searchsorted(rows, self._seg_ends).tolist()
        return list(zip([0] + ends[:-1], ends))

    def _peak_freqs(self, rows: np.ndarray, cols: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """Signed beat frequencies (Hz) of peaks ``(segment rows, bin cols)`` with their power and its two
        neighbours ``cells (n, 3)``: a parabola through the log-power (edge.dsp.peaks.interpolate_peak)."""
        lg = np.log(np.maximum(cells, self._tiny))
        lm, l0, lp = lg[:, 0], lg[:, 1], lg[:, 2]
        den = lm - 2.0 * l0 + lp
        d = np.zeros(den.shape, np.float32)
        np.divide(0.5 * (lm - lp), den, out=d, where=den < 0)
        np.minimum(np.maximum(d, np.float32(-0.5), out=d), np.float32(0.5), out=d)  # np.clip
        return self._freq_flat[rows * self.n_bins + cols] + d * self._bin_hz[rows]

    def _strongest_peaks(self, power: np.ndarray, rows: np.ndarray, cols: np.ndarray):
        """Per segment the ``max_peaks_per_segment`` strongest peaks (a segment with more): their
        frequencies and bins, ordered by power (rare; the common case is done in :meth:`detect`)."""
        cfg = self.config
        freqs, bins = [], []
        for k in range(power.shape[0]):
            b = cols[rows == k]
            if b.size > cfg.max_peaks_per_segment:
                b = b[np.argsort(power[k, b])[-cfg.max_peaks_per_segment:]]
            d = interpolate_peak(np.ascontiguousarray(power[k]), b)
            freqs.append(self._freq[k, b] + d * self._bin_hz[k])
            bins.append(b)
        return freqs, bins

    def _track_aided_pairs(self, freqs, bins, pairs, t_ns: int, weak=None):
        """Pairings of confirmed tracks that the four-segment pairing missed (a near vehicle's echo is smeared
        over several bins by its body, and the peaks of the four segments no longer agree within a bin), and of
        tentative tracks that approach from at least ``aided_tentative_min_range_m`` with
        ``aided_tentative_min_hits`` hits (a far car's peaks cross the detection threshold in all four segments
        in only part of its frames, and its track must confirm before it gets to 300 m).

        Each such track without a pairing near it predicts its beat frequency in every segment (slant
        range and speed from its state at this frame's time); the nearest unused peak within
        ``aided_window_bins`` is taken in each segment, at least ``aided_min_segments`` must be found, and
        range and speed are fitted to them by least squares; the fit must lie within ``aided_gate_m`` and
        ``aided_gate_mps`` of the prediction. A segment without a peak is read at its predicted bin for
        the angle. ``weak``: per segment, the frequencies and bins of local maxima above the lower ``aided_pfa``
        threshold only (searched as well, after the detected peaks). Returns ``(bins (m, 4), range_m, v_mps,
        residual_hz)``."""
        cfg = self.config
        tr = self.tracker.tracks
        empty = self._aided_empty
        sel = tr.confirmed
        if cfg.aided_tentative_min_range_m > 0:  # far tentative tracks with a few hits search as well
            far = ~sel & tr.moved & (tr.hits >= cfg.aided_tentative_min_hits)  # moved: not static clutter
            if far.any():
                x = tr.x
                far &= np.hypot(x[:, 0], x[:, 1]) >= cfg.aided_tentative_min_range_m
                if cfg.aided_tentative_approaching:
                    far &= x[:, 0] * x[:, 2] + x[:, 1] * x[:, 3] < 0.0
                sel = sel | far
        sel = sel.nonzero()[0]
        if sel.size == 0 or self.tracker.last_t_ns is None:
            return empty
        dt = max((t_ns - self.tracker.last_t_ns) * 1e-9, 0.0)
        pred = self._aided_predictions(sel, dt, pairs)
        if pred is None:
            return empty
        r_hat, v_hat, f_hat = pred
        # all four segments at once: peaks in a (segment, peak) table padded with +inf, used peaks at +inf
        counts = [fk.size for fk in freqs]
        w_counts = [fk.size for fk in weak[0]] if weak is not None else [0, 0, 0, 0]
        width = max(c + w for c, w in zip(counts, w_counts))
        if width == 0:
            return empty
        # four segments; the weak peaks after the detected ones (pairs.peak_index stays valid); one concatenation
        # each (padding: views of cached +inf / 0 rows)
        if self._pad_inf.size < width:
            self._pad_inf, self._pad_zero = np.full(2 * width, np.inf), np.zeros(2 * width, np.int64)
        fp, bp = [], []
        for k in range(4):
            fp.append(freqs[k])
            bp.append(bins[k])
            if w_counts[k]:
                fp.append(weak[0][k])
                bp.append(weak[1][k])
            fp.append(self._pad_inf[:width - counts[k] - w_counts[k]])
            bp.append(self._pad_zero[:width - counts[k] - w_counts[k]])
        table = np.concatenate(fp, dtype=np.float64).reshape(4, width)
        btab = np.concatenate(bp, dtype=np.int64).reshape(4, width)
        seg = _SEG4
        if pairs.range_m.size:
            table[seg, pairs.peak_index] = np.inf
        d = np.abs(table - f_hat[:, :, None])  # (m, 4, peaks)
        j = d.argmin(axis=2)  # (m, 4): the first nearest in each segment's peak order
        found = np.minimum.reduce(d, axis=2) <= self._aided_window_hz  # the minimum is d at j
        fsel = np.where(found, table[seg, j], 0.0)
        good = np.add.reduce(found, axis=1) >= cfg.aided_min_segments
        if not good.any():
            return empty
        A = self._model_ab  # (4, 2)
        w = found[good].astype(np.float64)
        fs = fsel[good]
        nrm = np.einsum("mk,ki,kj->mij", w, A, A)
        rhs = np.einsum("mk,ki,mk->mi", w, A, fs)
        sol = np.linalg.solve(nrm, rhs[:, :, None])[:, :, 0]  # (g, 2): range, speed
        resid = np.sqrt((w * (fs - sol @ A.T) ** 2).sum(axis=1) / w.sum(axis=1))
        close = (np.abs(sol[:, 0] - r_hat[good]) < cfg.aided_gate_m) & (np.abs(sol[:, 1] - v_hat[good]) < cfg.aided_gate_mps)
        g = good.nonzero()[0][close]
        # a segment without a peak is read at its predicted bin (np.round's value)
        out_bins = np.where(found[g], btab[seg, j[g]], np.rint(f_hat[g] / self._bin_hz).astype(np.int64) % self.n_bins)
        return (out_bins, sol[close, 0].astype(np.float32), sol[close, 1].astype(np.float32),
                resid[close].astype(np.float32))

    def _aided_predictions(self, sel: np.ndarray, dt: float, pairs) -> tuple | None:
        """``(range_m (m,), v_mps (m,), beats (m, 4))`` predicted at this frame for the confirmed tracks ``sel`` that
        lie inside the range limits, move (|v| >= 1 m/s) and have no pairing within the aided gates; None if none.
        A handful of tracks in plain Python floats (the float64 operations of the array form in the same order; the
        pairings looked at only within twice the range gate, found by a binary search), more as arrays."""
        cfg = self.config
        tr = self.tracker.tracks
        dz = cfg.mounting_height_m - cfg.target_height_m
        r_lo, r_hi, gate_m, gate_mps = cfg.min_range_m, cfg.max_range_m, cfg.aided_gate_m, cfg.aided_gate_mps
        if sel.size > _AIDED_SMALL:
            st = tr.x[sel]
            x, y = st[:, 0] + st[:, 2] * dt, st[:, 1] + st[:, 3] * dt
            r_hat = np.sqrt(x * x + y * y + dz * dz)
            v_hat = (x * st[:, 2] + y * st[:, 3]) / r_hat
            ok = (r_hat >= r_lo) & (r_hat <= r_hi) & (np.abs(v_hat) >= 1.0)
            if pairs.range_m.size:  # already paired
                near = (np.abs(pairs.range_m[None, :] - r_hat[:, None]) < gate_m) & (
                    np.abs(pairs.radial_speed_mps[None, :] - v_hat[:, None]) < gate_mps)
                ok &= ~near.any(axis=1)
            idx = ok.nonzero()[0]
            if idx.size == 0:
                return None
            r_hat, v_hat = r_hat[idx], v_hat[idx]
            return r_hat, v_hat, self._model.predict(r_hat, v_hat)
        dz2 = dz * dz
        paired = sorted(zip(pairs.range_m.tolist(), pairs.radial_speed_mps.tolist()))
        paired_r = [pr for pr, _ in paired]
        ordered = math.isfinite(sum(paired_r))  # (a NaN would leave the order undefined: then all are looked at)
        r_l, v_l = [], []
        for x0, y0, vx, vy in tr.x.take(sel, axis=0)[:, :4].tolist():  # x, y, vx, vy
            x, y = x0 + vx * dt, y0 + vy * dt
            r = math.sqrt(x * x + y * y + dz2)
            v = (x * vx + y * vy) / r
            if not (r >= r_lo and r <= r_hi and abs(v) >= 1.0):
                continue
            near = paired
            if ordered:  # (rounding cannot move a pairing across a window twice the gate)
                lo = bisect.bisect_left(paired_r, r - 2.0 * gate_m)
                near = paired[lo:bisect.bisect_right(paired_r, r + 2.0 * gate_m, lo)]
            if any(abs(pr - r) < gate_m and abs(pv - v) < gate_mps for pr, pv in near):
                continue  # already paired
            r_l.append(r)
            v_l.append(v)
        if not r_l:
            return None
        a0, a1, a2, a3, b0, b1, b2, b3 = self._model.coefficients
        f_hat = np.array([(r * a0 + v * b0, r * a1 + v * b1, r * a2 + v * b2, r * a3 + v * b3)
                          for r, v in zip(r_l, v_l)])  # (m, 4): PairingModel.predict's values
        return np.array(r_l), np.array(v_l), f_hat

    def _unalias_by_lane(self, range_m: np.ndarray, v_mps: np.ndarray, az: np.ndarray) -> np.ndarray:
        """Grating lobes: with d = 1.5 lambda the array measures sin(az) only modulo lambda/d (+-19.5 deg). A
        vehicle close to the radar in an outer lane lies beyond that (25 deg at 12 m) and its echo, still strong
        through the sidelobes, shows up mirrored across the road. A moving detection that lands in a lane of the
        other direction of travel is moved to its alias (sin(az) +- lambda/d) if that lies in a lane of its own
        direction; otherwise it is left alone (a wrong-way driver keeps its position unless, within about 15 m,
        its alias falls in a lane of the matching direction)."""
        cfg = self.config
        lanes = self.traffic.lanes
        period = self._alias_period
        # an alias is sin(az) +- period away, i.e. about period x range across: only near detections can have
        # both themselves and their alias on the road (the rest is left alone at the cost of one comparison)
        span, dirs = self._lane_arrays(lanes)
        near = np.abs(v_mps) >= np.float32(cfg.unalias_min_speed_mps)
        near &= range_m <= np.float32(span / period + cfg.mounting_height_m)
        idx = near.nonzero()[0]
        if idx.size == 0:
            return az
        # itself and the two neighbouring grating lobes, (3, n)
        cand = np.sin(az[idx].astype(np.float64)) + self._alias_offsets
        # the lane direction of all three in one pass (the cost is per call, not per element); the road frame's
        # lateral offset as to_road computes it
        x, y = polar_to_ground(range_m[idx], np.arcsin(np.minimum(np.maximum(cand, -1.0), 1.0)),
                               cfg.mounting_height_m, cfg.target_height_m)
        u = self._across_road(x, y)
        d = dirs[assign_lanes(u.reshape(-1), lanes)].reshape(3, -1)  # direction, 0 outside every lane (-1 -> 0)
        sign = np.sign(v_mps[idx])  # +1 receding: lanes "away"
        bad = d[0] == -sign
        if not bad.any():
            return az
        az = az.copy()
        for j in (1, 2):
            alt = cand[j]
            ok = bad & (np.abs(alt) <= 1.0)
            ok &= d[j] == sign
            az[idx[ok]] = np.arcsin(alt[ok]).astype(np.float32)
            bad &= ~ok
        return az

    def _lane_arrays(self, lanes) -> tuple[float, np.ndarray]:
        """(span of the road across, (L + 1,) lane directions and a 0 after them, which lane index -1 -- outside
        every lane -- reads) of ``lanes``, cached: the lanes change only when the traffic layer learns them."""
        if self._lane_cache[0] is not lanes:
            self._lane_cache = (lanes, max(ln.center_m + 0.5 * ln.width_m for ln in lanes)
                                - min(ln.center_m - 0.5 * ln.width_m for ln in lanes),
                                np.array([ln.direction for ln in lanes] + [0]))
        return self._lane_cache[1], self._lane_cache[2]

    def _across_road(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Lateral offset (float64, m) of ground positions in the road frame of the traffic layer's yaw, as
        edge.traffic.lanes.to_road computes it (its operations only: the lanes' coordinate)."""
        yaw = self.traffic.yaw_rad
        return x.astype(np.float64) * math.cos(yaw) + y.astype(np.float64) * math.sin(yaw)

    def _hold_moving(self, spec: np.ndarray, d: np.ndarray) -> None:
        """Zero the clutter-map update ``d`` (rx, seg, bin) where the spectrum ``spec`` changed since the last
        frame by more than noise and phase noise explain (``clutter_map_static_factor``, ``clutter_map_static_rel``):
        what moves stays out of the map. Keeps this frame's spectrum for the next."""
        prev = self._prev_spec
        if prev is None:
            self._prev_spec = spec.copy()
            return
        cfg = self.config
        dv = np.subtract(spec, prev, out=prev).view(np.float32)
        sq = (dv * dv).reshape(spec.shape + (2,)).sum(axis=(0, 3))  # (seg, bin): sum over rx of |change|^2
        n = sq.shape[1]
        med = np.partition(sq, n // 2, axis=1)[:, n // 2]
        sv = spec.view(np.float32)
        own = (sv * sv).reshape(spec.shape + (2,)).sum(axis=(0, 3))
        moving = sq > med[:, None] * np.float32(cfg.clutter_map_static_factor) + own * np.float32(cfg.clutter_map_static_rel ** 2)
        d[:, moving] = 0
        np.copyto(prev, spec)

    def _hold_standing(self, d: np.ndarray) -> None:
        """Zero the clutter-map update ``d`` (rx, seg, bin) in the range bins of stopped confirmed tracks
        (``clutter_map_hold_speed_mps``): a static echo at zero Doppler, beat a_k R in segment k."""
        cfg = self.config
        tr = self.tracker.tracks
        if not tr.confirmed.any():
            return
        x = tr.x
        stop = tr.confirmed & tr.moved & (np.hypot(x[:, 2], x[:, 3]) < cfg.clutter_map_hold_speed_mps)
        if not stop.any():
            return
        h = cfg.mounting_height_m - cfg.target_height_m
        n = self.n_bins
        for g in np.hypot(x[stop, 0], x[stop, 1]).tolist():
            r0 = math.sqrt(max(g - 3.0, 0.0) ** 2 + h * h)
            r1 = math.sqrt((g + cfg.clutter_map_hold_length_m) ** 2 + h * h)
            for k, a in enumerate(self._bins_per_m):
                lo, hi = sorted((a * r0, a * r1))
                d[:, k, np.arange(math.floor(lo) - 1, math.ceil(hi) + 2) % n] = 0

    def _against_lane_glint(self, range_m: np.ndarray, v_mps: np.ndarray, az: np.ndarray, x: np.ndarray,
                            y: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """(n,) bool: kept detections moving against the lane they lie in (faster than unalias_min_speed_mps)
        with a kept detection not against its lane up to ``cluster_length_m`` nearer, within
        ``cluster_against_lane_speed_mps`` in radial speed and a beamwidth (lambda / (N d) in sin az) in angle:
        that vehicle's body seen at a glint angle (``cluster_against_lane_speed_mps``). Only where the direction
        is sure: the lanes ``cluster_against_lane_margin_m`` plus traffic.wrong_way_lane_sigmas x range x the
        yaw's and the tracks' azimuth uncertainty to either side run the same way (a receding car by the median
        can show up just across it; with the yaw still unknown a far vehicle of a mis-aimed radar lies in the
        neighbouring lane)."""
        cfg = self.config
        traffic = self.traffic
        lanes = traffic.lanes
        _, dirs = self._lane_arrays(lanes)
        u = self._across_road(x, y)
        against = keep & (dirs[assign_lanes(u, lanes)] * v_mps < -np.float32(cfg.unalias_min_speed_mps))
        out = np.zeros(range_m.shape, bool)
        if not against.any():
            return out
        sigma = math.hypot(traffic.yaw_sigma_rad, math.radians(traffic.config.wrong_way_azimuth_sigma_deg))
        idx = against.nonzero()[0]
        half = cfg.cluster_against_lane_margin_m + traffic.config.wrong_way_lane_sigmas * sigma * range_m[idx]
        for side in (-half, half):
            against[idx] &= dirs[assign_lanes(u[idx] + side, lanes)] * v_mps[idx] < -np.float32(
                cfg.unalias_min_speed_mps)
        if not against.any():
            return out
        idx = against.nonzero()[0]
        own = keep & ~against
        r = range_m[idx, None] - range_m[None, :]  # > 0: the other one nearer
        sin_az = np.sin(az.astype(np.float64))
        out[idx] = (own[None, :] & (r > 0) & (r <= cfg.cluster_length_m)
                    & (np.abs(v_mps[idx, None] - v_mps[None, :]) <= cfg.cluster_against_lane_speed_mps)
                    & (np.abs(sin_az[idx, None] - sin_az[None, :]) <= self._beamwidth_sin)).any(axis=1)
        return out

    def _lane_centres(self, lanes) -> np.ndarray:
        """(L,) lane centres across the road (m) of ``lanes``, cached like :meth:`_lane_arrays`."""
        if self._centres_cache[0] is not lanes:
            self._centres_cache = (lanes, np.array([ln.center_m for ln in lanes]))
        return self._centres_cache[1]

    def _split_is_body(self, range_m: np.ndarray, v_mps: np.ndarray, az: np.ndarray, split: np.ndarray) -> np.ndarray:
        """(n,) bool: split detections whose cell lies behind a nearer detection of the same vehicle -- up to
        ``cluster_length_m`` nearer, within ``cluster_speed_mps`` in radial speed and ``cluster_lateral_m`` across
        of the cell's own (unsplit) position, the nearest_of_clusters rule. Such a cell is the vehicle's body
        (its two sides, or a side and the far face, in one range bin) and not two vehicles side by side,
        whose near faces are the nearest detections of both. The array cannot resolve scatterers 1-2.5 m
        apart (a 4-element aperture: 9.6 deg Rayleigh width, 1.5 deg at 75 m), so the two-source fit pushes
        its angles apart and one of them lands in the next lane, 3-4 m beside the vehicle (highway4-traffic
        seed 31: tracks beside a receding van and an approaching truck were counted there)."""
        cfg = self.config
        x, _ = polar_to_ground(range_m, az, cfg.mounting_height_m, cfg.target_height_m)
        behind = ~nearest_of_clusters(range_m, v_mps, x, length_m=cfg.cluster_length_m,
                                      speed_mps=cfg.cluster_speed_mps, lateral_m=cfg.cluster_lateral_m)
        return split & behind

    def _split_straddles_lanes(self, range_m: np.ndarray, v_mps: np.ndarray, ang: np.ndarray) -> np.ndarray:
        """(n,) bool: the two directions of a split lie in adjacent lanes with their midpoint near the
        boundary between them -- two vehicles side by side. A truck's two sides (2.5 m apart) fit two
        sources as well as two cars do, but they straddle the centre of one lane. Both lanes must carry
        the cell's direction of travel (its radial speed's sign; two vehicles in one range-speed cell move
        the same way) when ``resolve_same_direction``."""
        cfg = self.config
        lanes = self.traffic.lanes
        centres = self._lane_centres(lanes)
        # both directions at once: the ground position and the road frame's lateral offset (to_road's operations)
        x, y = polar_to_ground(range_m[:, None], np.nan_to_num(ang), cfg.mounting_height_m, cfg.target_height_m)
        u = self._across_road(x, y)  # (n, 2)
        lane = np.argmin(np.abs(u[:, :, None] - centres[None, None, :]), axis=2)  # (n, 2) nearest lane
        lo, hi = np.minimum(lane[:, 0], lane[:, 1]), np.maximum(lane[:, 0], lane[:, 1])
        ok = (hi - lo) == 1
        boundary = 0.5 * (centres[lo] + centres[hi])
        spacing = np.abs(centres[hi] - centres[lo])
        mid = (u[:, 0] + u[:, 1]) / 2  # u.mean(axis=1): the sum of the two, halved
        ok &= np.abs(mid - boundary) <= cfg.resolve_boundary_fraction * spacing
        if cfg.resolve_same_direction:
            _, dirs = self._lane_arrays(lanes)
            sign = np.sign(v_mps)
            ok &= (dirs[lo] == sign) & (dirs[hi] == sign)
        return ok

    def process(self, frame: RawFrame, timer: StageTimer) -> FrameResult:
        det, inter = self.detect(frame, timer)
        if self.tracker is None:
            return FrameResult(profile=self.profile, seq=frame.seq, t_ns=frame.t_ns, detections=det, intermediates=inter)
        with timer.stage("track"):
            tracks = self.tracker.step(det, frame.t_ns)
        if self.traffic_tap is not None:  # (the traffic layer's input, e.g. for evaluate --record-tracks)
            self.traffic_tap(tracks, frame.t_ns, self.tracker.published_motion_x_m)
        with timer.stage("traffic"):
            upd = self.traffic.update(tracks, frame.t_ns, self.tracker.published_motion_x_m,
                                      self.track_extents(tracks, det))
            self.tracker.road_yaw_rad = self.traffic.yaw_rad  # the IMM's lane-keeping direction
        return FrameResult(
            profile=self.profile, seq=frame.seq, t_ns=frame.t_ns, detections=det, tracks=upd.tracks,
            presence=upd.presence, lane_stats=upd.lane_stats, events=upd.events, intermediates=inter,
        )
