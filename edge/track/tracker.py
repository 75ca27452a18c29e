"""The lane profile's multi-target tracker: a thin orchestrator over role objects (after Stone Soup
``tracker/simple.py``): predict, associate (gate + weights), update, delete, initiate.

Public API (stable; used by ``edge.pipelines.lane``)::

    from edge.track import PdafConfig, PdafTracker
    tracker = PdafTracker(PdafConfig())            # or cfg.section("track.pdaf")
    tracks = tracker.step(detections, t_ns)        # tuple[TrackState, ...], confirmed tracks
    tracker.intermediates                          # arrays of the last step, for plots
    tracker.reset()

``detections`` is an :class:`edge.types.Detections` (ground-plane ``x_m``, ``y_m``; ``range_m`` and
``radial_speed_mps`` as measured), ``t_ns`` the frame time (monotonic). Published tracks carry a small
recycled integer ``track_id`` in ``1..max_track_id`` given at confirmation; ``lane`` and ``cls`` are
left ``None`` for later stages (:mod:`edge.traffic` fills ``lane``). ``range_m`` of a track is the
ground range ``hypot(x, y)`` and ``radial_speed_mps`` the ground-plane radial speed.

The measured radial speed is slant (the radar is above the road); it is projected to the ground
plane with the detection's own range: ``v_ground = v_r * range_m / hypot(x_m, y_m)``. Frames whose
radial speeds are not all finite fall back to position-only updates.

Tracks are held as a struct of arrays (:class:`TrackTable`): the per-frame work is a handful of
batched numpy operations over tracks x detections; there is no Python object per detection.

Motion model (``motion_model``): ``"cv"`` is Lim's constant-velocity Kalman filter; ``"imm"`` (default)
runs two models per track, lane keeping (velocity across the road decaying to zero, tiny lateral
process noise; the road direction is ``road_yaw_rad``, which the lane pipeline sets from the traffic
layer's mounting-yaw estimate) and the cv model for manoeuvres, mixed by an IMM (:mod:`edge.track.imm`).
The association (gate, clutter density, PDAF/JPDA weights) is computed once on the IMM's moment-matched
prediction, as for the cv model; both modes are updated with those weights and weighed by their PDAF
likelihoods. ``tracks.x``/``tracks.p`` are always the (combined) state every other stage reads; a seed's
velocity points along the road (speed from the radial speed, ``init_lateral_speed_sigma_mps`` across).

Published lateral position (``lateral_smoother``, on by default): a straight-line filter per track across the
boresight (``tracks.lat``: ``[x, vx]``, :func:`edge.track.kalman.lateral_pda_update`), outside the IMM's mixing,
updated with the association's weights and each detection's own lateral noise; it restarts from the motion
model's estimate when a Hausman test or a CUSUM of the likelihood ratio of the two says the vehicle left the line
(a lane change), and is held there (with the lane-keeping mode's lateral speed) while the IMM's manoeuvring mode
has more than ``lateral_smoother_hold_manoeuvre_prob``, or while the detection that carries the track is an
unresolved pair (``lateral_smoother_hold_unresolved``: ``Measurements.unresolved``, the resolver's two sources too
close in angle to split, whose one angle lies between the lanes); the published ``x_m`` moves towards the motion
model's as the CUSUM's evidence grows. The IMM's lane-keeping mode alone cannot average a far vehicle's lateral
position: mixed with the manoeuvring mode every frame, it takes in ~20x its own lateral process noise (highway4
motorcycle, 0.15-0.38 m RMSE on the dev seeds). Association, gates, ids and ``tracks.x`` (what every other stage
reads) are the motion model's, and so are the positions the traffic layer's yaw estimator takes
(``published_motion_x_m``: a line starts along the road direction in use, and its tracks would vote for the yaw it
assumed; highway4-misaimed seed 1, 120 frames, lane accuracy 0.542 with the published positions, 0.683 with the
motion model's, 0.680 without the filter). Side-by-side (90 frames) tracked fractions without the unresolved-pair
hold: seed 3 0.88/0.54, seed 8 0.89/0.59, seed 21 0.70/0.83 (the one track of the unresolved pair lies between the
lanes, the evaluation gives each frame to the nearer car, and the straight line stays on one side of the middle);
with it 0.77/0.66, 0.74/0.73, 0.77/0.77, as with the filter off. Left as they are: a lane change's largest lateral
error 0.64 m either way, and highway4 seed 44 car 3 (seeded at 260 m, its first detections 1.3 m off on average)
0.22 m with the filter, 0.24 m without.

Measurement noise (``measurement_noise``): ``"constant"`` is one ``R`` per track from fixed range and azimuth sds
at its prediction (Lim); ``"snr"`` (default) is one ``R`` per detection from its SNR, ``sigma^2 = sigma0^2 / SNR +
floor^2`` for azimuth and range (the Cramer-Rao form, fitted on the simulated board: 0.88 deg and 0.165 m at 0 dB)
plus the across-vehicle scatter of an extended vehicle (0.47 m), so strong far detections are trusted and weak ones
are not. The innovation covariance then differs per (track, detection): the gate, the likelihoods and the update
use each detection's own ``S``, the PDAF posterior is the moment-matched mixture of one Kalman update per
hypothesis with its own gain (:func:`edge.track.pdaf.combined_update_each`; equal to Lim's single-gain update when
all ``R`` are equal), and the IMM modes are updated over the validated pairs only. Which detections may seed stays
decided with the constant model's (wider) exclusion gate (``seed_exclusion_noise``). Cost (thread CPU time per
frame, p50, shared development machine): highway4 seed 1 (4.7 detections) 0.34 ms constant, 0.57 ms snr; 73 synthetic
tracks x 99 detections 2.35 ms constant, 2.50 ms snr.

Beyond Lim's single-point PDAF, what a roadside radar needs (all parameters in ``track.pdaf``):

- extended vehicles: a car or truck gives several detections spread over its length; each track
  learns the along-heading spread of its detections (``ext_var``) and adds it to ``R`` along its
  heading, so the gate holds the whole vehicle and PDAF averages its points; ``length_m`` is
  published as ``sqrt(12 ext_var)`` (the lane profile's traffic layer replaces it with the length
  measured from the body's range extent, :mod:`edge.traffic.monitor`);
- seniority: confirmed tracks share detections (PDAF, or cheap JPDA by default); a tentative track
  only uses detections no more senior track validated;
- seeding: detections inside a wide exclusion gate or the same-vehicle box of a track never seed;
  seeds of one frame within the same-vehicle box (lateral extent growing with range x azimuth sd,
  same radial speed) give one seed;
- duplicates: two tracks with the same velocity whose positions fall within the same-vehicle box, or
  whose states are statistically indistinguishable, are one vehicle: the junior is dropped (before
  confirmation, so no id is spent on it);
- confirmation needs M of N hits, or (``confirmation = "either"``, default) a sequential log-likelihood-ratio
  track score above Wald's threshold (:mod:`edge.track.score`: a strong, consistent vehicle in two or three
  frames), and a speed surely above ``confirm_min_speed_mps`` (static clutter
  stays in unpublished tentative tracks that absorb its detections), and waits while a confirmed track
  moving the same way lies within a truck length along (``confirm_block_*``: a long vehicle's second
  seed, or its body's glint a lane beside it);
- near the radar: the measured ground radial speed of an extended vehicle is blurred by the mast geometry (a
  scatterer farther along the body sees another elevation), so its sd grows as ``|v| h^2 / g^3`` times
  ``near_speed_spread_m`` at ground range ``g`` under a radar ``h`` above the targets (``sensor_height_m``, set by
  the lane pipeline), in ``R`` and in a seed's speed: a car coming out from under the radar is not seeded with
  its first detections' speed and then gated out;
- re-anchoring: a confirmed track that misses moves to an unclaimed detection up to ``reanchor_m``
  nearer at its radial speed (it sat on a truck's body; the near face is the reference point).

Measured on seeded synthetic scenes (tests/edge/trackscene.py): crossing vehicles that swap lanes
side by side keep their ids with the cheap JPDA down to 1.5 m/s speed difference (PDAF: 6 of 10
seeds at 1.5 m/s, all at 3 m/s and more); 56 tracks with 117 detections per frame take about
1.4 ms per frame (p50, one core of the development machine, thread CPU time).

Cost: with tens of tracks the arrays are tiny and the time is the number and kind of numpy calls, not
flops (issue 9). Measured on this machine: a same-shape 1-D operation costs about 0.4 us, one that
broadcasts ((T, 1) against (T, M)) 2-3 us, fancy indexing of a 2-D array 2 us against 0.3 us for
``take``/``compress``, ``np.linalg.inv``/``det`` of a stack of 3x3 matrices 50-80 us against about
20 us for the cofactor formulas (:mod:`edge.track.smallmat`), a Python float operand about 0.5 us more
than an array. So: rows by ``take``/``compress``, closed-form small inverses, work skipped when there is
nothing to do (no tentative track, one seed candidate, no detection at a missed track's radial speed),
columns rather than broadcast forms where the count of calls is the same. Recorded highway4-traffic
frames (15-20 tracks, 12 detections) take 0.59 ms p50, 0.80 ms p99 per frame, 20 % less than before
these changes (thread CPU time, per-frame minimum of 5 runs, shared machine).
A second pass with the same outputs (the keep mode's F and Q in closed form, rebuilt alone when only the yaw
moves; one measurement prediction for the combined prediction and both IMM modes; the per-pair sums of the
per-detection PDAF update as one product with the row-membership matrix instead of np.add.at; the gate volume
and sqrt|S| shared by the weights and the IMM update; the seed exclusion's d2 from the innovations already
computed; smallmat's cofactors for the per-pair inverses): ``step`` on recorded highway4 detections 0.58 ->
0.44 ms p50, highway4-traffic 0.75 -> 0.63 ms (thread CPU time, per-frame minimum of 7 runs).
A third pass for the slow frames, seeding and the first frames (same outputs, bit for bit on recorded highway4 and
highway4-traffic): the seeds' noise for the seeds only (or taken from the frame's per-detection noise), the merge of
up to 8 seed candidates in plain Python, one along-road speed variance as a scalar, the new tracks' constant columns
from a cache, the deleter's pair indices cut from a larger table's instead of ``np.triu_indices`` each time the
track count changes (~60 us). ``initiate`` on a seeding frame 118 -> 83 us (highway4), 156 -> 107 us (p99,
highway4-traffic); ``step`` p99 586 -> 553 us (highway4, 300 frames), 902 -> 836 us (highway4-traffic, 600 frames);
p50 unchanged (per-function thread CPU time, per-frame minimum of 15 runs alternating with the previous code).

Known limit: two vehicles side by side at the same range and speed are separated only where the
azimuth noise is well below the lane spacing (tested at 25-60 m with 0.5 deg); far away the seeds
of the second vehicle fall inside the first track's same-vehicle box and the track sits between
them until they are resolved (a 4-element array cannot resolve them in angle there anyway).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from edge.track import imm, kalman, score
from edge.track.config import PdafConfig
from edge.track.smallmat import inv_quad2
from edge.track.pdaf import (Innovations, InnovationsEach, PairInnovations, association_weights,
                              association_weights_each, combined_update, combined_update_each, combined_update_pairs,
                              gate_threshold, gate_volume_each, innovations, innovations_each, mahalanobis_d2,
                              pair_innovations, unit_ball_volume)
from edge.types import Detections, TrackState

log = logging.getLogger(__name__)

__all__ = ["PdafTracker", "TrackTable", "IdPool"]


class IdPool:
    """Small integer ids ``1..max_id``, handed out lowest-first at start, then oldest-released first
    (a released id waits as long as possible before it is reused, so consumers do not confuse vehicles)."""

    def __init__(self, max_id: int) -> None:
        self._free: deque[int] = deque(range(1, max_id + 1))
        self._used: set[int] = set()

    def acquire(self) -> int | None:
        if not self._free:
            return None
        i = self._free.popleft()
        self._used.add(i)
        return i

    def release(self, track_id: int) -> None:
        if track_id in self._used:
            self._used.remove(track_id)
            self._free.append(track_id)

    @property
    def in_use(self) -> int:
        return len(self._used)


@dataclass
class TrackTable:
    """All tracks as columns (row = track). ``track_id`` is 0 until a track is confirmed."""

    x: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    p: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    track_id: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    age: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    hits: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    misses: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    history: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint32))  # bit 0 = this frame hit
    confirmed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    moved: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # was ever surely moving
    ext_var: np.ndarray = field(default_factory=lambda: np.zeros(0))  # along-heading detection spread, m^2
    close_run: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int32))  # frames next to a twin
    score: np.ndarray = field(default_factory=lambda: np.zeros(0))  # log-likelihood-ratio track score (edge.track.score)
    # IMM (motion_model = "imm"): per-mode states and mode probabilities; x, p are their moment-matched mixture
    xm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 4)))
    pm: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 4, 4)))
    mu: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    # lateral_smoother: the straight-line filter across the boresight, [x, vx] and its covariance
    lat: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    lat_p: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    lat_cusum: np.ndarray = field(default_factory=lambda: np.zeros(0))  # CUSUM of the IMM-vs-line likelihood ratio

    _COLUMNS = ("x", "p", "track_id", "age", "hits", "misses", "history", "confirmed", "moved", "ext_var",
                "close_run", "score", "xm", "pm", "mu", "lat", "lat_p",
                "lat_cusum")

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def keep(self, mask: np.ndarray) -> None:
        for c in self._COLUMNS:  # compress: a boolean row mask without the fancy-indexing machinery (3x cheaper)
            setattr(self, c, getattr(self, c).compress(mask, axis=0))

    def append(self, x: np.ndarray, p: np.ndarray, ext_var: float, keep_prob: float = 0.5) -> None:
        k = x.shape[0]
        cat = np.concatenate
        zeros, ones, no, ones_u32, zeros_f, ext, mu = _new_rows(k, ext_var, keep_prob)
        self.xm = cat([self.xm, x[:, None].repeat(2, axis=1)])
        self.pm = cat([self.pm, p[:, None].repeat(2, axis=1)])
        self.mu = cat([self.mu, mu])
        self.lat = cat([self.lat, x[:, 0::2]])
        self.lat_p = cat([self.lat_p, p[:, 0::2, 0::2]])
        self.lat_cusum = cat([self.lat_cusum, zeros_f])
        self.x = cat([self.x, x])
        self.p = cat([self.p, p])
        self.track_id = cat([self.track_id, zeros])
        self.age = cat([self.age, ones])
        self.hits = cat([self.hits, ones])
        self.misses = cat([self.misses, zeros])
        self.history = cat([self.history, ones_u32])
        self.confirmed = cat([self.confirmed, no])
        self.moved = cat([self.moved, no])
        self.ext_var = cat([self.ext_var, ext])
        self.close_run = cat([self.close_run, zeros])
        self.score = cat([self.score, zeros_f])


_SEED_MERGE_PLAIN_MAX = 8  # seed candidates up to which MofNInitiator merges them in plain Python
_NEW_ROWS: dict[tuple[int, float, float], tuple[np.ndarray, ...]] = {}


def _new_rows(k: int, ext_var: float, keep_prob: float) -> tuple[np.ndarray, ...]:
    """The constant columns of ``k`` new tracks (read-only, cached: ``TrackTable.append`` copies them): int32 zeros
    and ones, bool zeros, uint32 ones, float zeros, ``ext_var`` and the mode probabilities ``(keep, 1 - keep)``."""
    key = (k, ext_var, keep_prob)
    rows = _NEW_ROWS.get(key)
    if rows is None:
        mu = np.empty((k, 2))
        mu[:, 0], mu[:, 1] = keep_prob, 1.0 - keep_prob
        rows = (np.zeros(k, dtype=np.int32), np.ones(k, dtype=np.int32), np.zeros(k, dtype=bool),
                np.ones(k, dtype=np.uint32), np.zeros(k), np.full(k, ext_var), mu)
        for a in rows:
            a.flags.writeable = False
        if len(_NEW_ROWS) < 256:  # a few seed counts per configuration
            _NEW_ROWS[key] = rows
    return rows


@dataclass
class Measurements:
    """One frame's detections as the filter sees them (float64, ground plane)."""

    z: np.ndarray  # (M, n): x, y[, ground radial speed]
    snr_db: np.ndarray  # (M,)
    with_radial_speed: bool
    pair: np.ndarray | None = None  # (M,) int: detections split from one (edge.dsp.resolve) share a value >= 0
    coherence: np.ndarray | None = None  # (M,) the Bartlett peak's share of the looks' energy (if measured)
    unresolved: np.ndarray | None = None  # (M,) bool: two sources in the cell, not split (edge.dsp.resolve's hint)

    @classmethod
    def from_detections(cls, det: Detections, use_radial_speed: bool) -> "Measurements":
        # one float64 array of the five columns (a handful of detections: few calls, not few flops)
        cols = np.array([det.x_m, det.y_m, det.snr_db, det.radial_speed_mps, det.range_m], dtype=np.float64)
        fin = np.isfinite(cols)
        every = bool(fin.all())  # the usual frame: no checks column by column
        ok = fin[0] & fin[1]
        all_ok = every or bool(ok.all())
        if not all_ok:
            cols, fin = cols[:, ok], fin[:, ok]
        x, y, snr, vr, rng = cols
        use = use_radial_speed and (every or bool(fin[3:5].all()))
        if use:
            rho = np.hypot(x, y)
            near = rho <= 1e-6
            if near.any():
                ratio = np.divide(rng, rho, out=np.ones_like(rho), where=~near)
            else:
                ratio = rng / rho
            z = np.empty((x.size, 3))
            z[:, 2] = vr * ratio
        else:
            z = np.empty((x.size, 2))
        z[:, 0] = x
        z[:, 1] = y
        pair = det.extra.get("resolved_pair")
        if pair is not None and len(pair) == ok.size:
            pair = np.asarray(pair, dtype=np.int64)
            pair = pair if all_ok else pair[ok]
            if not (pair >= 0).any():
                pair = None
        else:
            pair = None
        if not every and not fin[2].all():
            snr = np.nan_to_num(snr, nan=0.0)
        coh = _extra_column(det, "angle_coherence", np.float64, ok, all_ok)
        unr = _extra_column(det, "unresolved_pair", bool, ok, all_ok)
        if unr is not None and not unr.any():
            unr = None
        return cls(z, snr, use, pair, coh, unr)


def _extra_column(det: Detections, key: str, dtype, ok: np.ndarray, all_ok: bool) -> np.ndarray | None:
    """The per-detection column ``det.extra[key]`` as ``dtype``, rows ``ok`` kept (None if absent or mis-sized)."""
    col = det.extra.get(key)
    if col is None or len(col) != ok.size:
        return None
    col = np.asarray(col, dtype=dtype)
    return col if all_ok else col[ok]


def _carrying_detection(beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per track, the detection of largest association weight and whether it carries the track (weight > 0.5)."""
    best = np.argmax(beta, axis=1)
    return best, beta[np.arange(beta.shape[0]), best] > 0.5


class CvPredictor:
    """Constant-velocity prediction of every track to the frame time."""

    def __init__(self, cfg: PdafConfig) -> None:
        self.cfg = cfg
        self._cached: tuple[float, np.ndarray, np.ndarray] | None = None  # (dt, F, Q) of the last frame

    def predict(self, tracks: TrackTable, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        if self._cached is None or self._cached[0] != dt_s:  # frames come at a fixed period
            self._cached = (dt_s, kalman.cv_transition(dt_s),
                            kalman.cv_process_noise(dt_s, self.cfg.q_lateral_m2ps3, self.cfg.q_along_m2ps3))
        _, f, q = self._cached
        return kalman.predict(tracks.x, tracks.p, f, q)


class ImmPredictor:
    """IMM mixing and mode-matched prediction (:mod:`edge.track.imm`): lane keeping along the road at
    ``road_yaw_rad`` and the constant-velocity model of :class:`CvPredictor` for manoeuvres."""

    def __init__(self, cfg: PdafConfig) -> None:
        self.cfg = cfg
        self.pi = imm.switch_matrix(cfg.imm_p_keep_to_manoeuvre, cfg.imm_p_manoeuvre_to_keep)
        self._cached: tuple[float, float, np.ndarray, np.ndarray] | None = None  # (dt, yaw, F (2,4,4), Q (2,4,4))

    def _far_switch(self, rho: np.ndarray) -> np.ndarray:
        """(T, 2, 2) switching matrices: ``imm_p_keep_to_manoeuvre`` up to ``imm_far_from_m``, then falling
        log-linearly to ``imm_far_p_keep_to_manoeuvre`` at ``imm_far_to_m`` and beyond."""
        c = self.cfg
        u = np.minimum(np.maximum((rho - c.imm_far_from_m) / max(c.imm_far_to_m - c.imm_far_from_m, 1e-9), 0.0), 1.0)
        p = np.exp((1.0 - u) * math.log(c.imm_p_keep_to_manoeuvre) + u * math.log(c.imm_far_p_keep_to_manoeuvre))
        pi = np.empty((rho.size, 2, 2))
        pi[:, 0, 0], pi[:, 0, 1] = 1.0 - p, p
        pi[:, 1] = self.pi[1]
        return pi

    def predict(self, tracks: TrackTable, dt_s: float, yaw_rad: float):
        """-> combined (xp, pp), per mode (xpm, ppm) and predicted mode probabilities ``c`` (T, 2)."""
        c = self.cfg
        if self._cached is None or self._cached[0] != dt_s:
            fm = kalman.cv_transition(dt_s)
            qm = kalman.cv_process_noise(dt_s, c.imm_manoeuvre_q_lateral_m2ps3, c.q_along_m2ps3)
            self._cached = (dt_s, None, np.stack([fm, fm]), np.stack([qm, qm]))
        _, cached_yaw, f, q = self._cached
        if cached_yaw != yaw_rad:  # the yaw estimate moves nearly every frame: only the keep mode is rebuilt
            f[0], q[0] = imm.keep_model(dt_s, yaw_rad, c.imm_keep_tau_s, c.imm_keep_q_across_m2ps3, c.q_along_m2ps3)
            self._cached = (dt_s, yaw_rad, f, q)
        pi = self.pi
        if c.imm_far_p_keep_to_manoeuvre < c.imm_p_keep_to_manoeuvre and len(tracks):
            pi = self._far_switch(np.hypot(tracks.x[:, 0], tracks.x[:, 1]))
        x0, p0, cj = imm.mix(tracks.xm, tracks.pm, tracks.mu, pi)
        xpm, ppm = imm.predict_modes(x0, p0, f, q)
        xp, pp = imm.moment_match(xpm, ppm, cj)
        return xp, pp, xpm, ppm, cj


def heading(xp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit heading (T, 2) and weight (T,) in [0, 1] (0 when standing, 1 from 1 m/s)."""
    sp = np.hypot(xp[:, 2], xp[:, 3])
    u = xp[:, 2:4] / np.maximum(sp, 1e-9)[:, None]
    return u, np.minimum(np.maximum(sp, 0.0), 1.0)  # np.clip, without its wrapper


_EYE2 = np.eye(2)[None]  # (1, 2, 2)


def extent_cov(xp: np.ndarray, ext_var: np.ndarray, head: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(T, 2, 2) spread of an extended vehicle's detections: ``ext_var`` along the heading
    (isotropic while the heading is unknown). ``head``: ``heading(xp)`` if already computed."""
    u, w = heading(xp) if head is None else head
    uu = u[:, :, None] * u[:, None, :]
    iso = _EYE2 * (1.0 - w)[:, None, None]
    return ext_var[:, None, None] * (w[:, None, None] * uu + iso)


class MeasurementModel:
    """``z_hat``, ``H`` and ``R`` per track at its prediction.

    ``R`` of the position is the converted polar noise plus the spread of an extended vehicle's
    detections: ``extent_sigma_m`` across, and the track's learned variance ``ext_var`` along its
    heading (isotropic while the track is slower than 1 m/s and the heading is unknown).
    """

    def __init__(self, cfg: PdafConfig) -> None:
        self.cfg = cfg
        self._az_sigma_rad = math.radians(cfg.azimuth_sigma_deg)
        self.height_m = 0.0  # radar above the targets (PdafTracker.sensor_height_m): near_speed_spread_m's geometry
        self._head: tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None = None  # (xp, heading(xp))

    @property
    def per_detection(self) -> bool:
        """``measurement_noise = "snr"``: the sensor noise is one ``R`` per detection (:meth:`of_detections`)."""
        return self.cfg.measurement_noise == "snr"

    def of_detections(self, meas: "Measurements", n: int | None = None, rows: np.ndarray | None = None) -> np.ndarray:
        """(M, n, n) sensor noise of each detection from its SNR (``measurement_noise = "snr"``); the radial-speed
        row stays in the track's part (:meth:`at`). ``rows``: only those detections (the same values: the noise of
        a detection is computed from its own row alone)."""
        c = self.cfg
        n = meas.z.shape[1] if n is None else n
        z, snr_db = (meas.z, meas.snr_db) if rows is None else (meas.z.take(rows, axis=0), meas.snr_db.take(rows))
        rp = kalman.snr_polar_noise(z[:, :2], snr_db, c.snr_range_sigma_m, c.snr_range_floor_m,
                                    math.radians(c.snr_azimuth_sigma_deg), math.radians(c.snr_azimuth_floor_deg),
                                    c.snr_extent_sigma_m, (c.snr_min_db, c.snr_max_db))
        if n == 2:
            return rp
        r = np.zeros((rp.shape[0], n, n))
        r[:, :2, :2] = rp
        return r

    def at(self, xp: np.ndarray, with_radial_speed: bool, ext_var: np.ndarray | None = None, sensor: bool = True,
           pred: tuple[np.ndarray, np.ndarray] | None = None):
        """``sensor=False``: without the converted polar noise (it comes per detection, :meth:`of_detections`).
        ``pred``: ``kalman.measurement_prediction(xp, with_radial_speed)`` if already computed."""
        c = self.cfg
        zh, h = kalman.measurement_prediction(xp, with_radial_speed) if pred is None else pred
        if sensor:
            rp = kalman.polar_position_noise(xp[:, :2], c.range_sigma_m, self._az_sigma_rad, c.extent_sigma_m)
        else:
            rp = np.zeros((xp.shape[0], 2, 2))
        if ext_var is not None:
            self._head = (xp, heading(xp))  # update_extent reuses it for the same prediction
            rp += extent_cov(xp, ext_var, self._head[1])
        n = zh.shape[1]
        r = np.zeros((xp.shape[0], n, n))
        r[:, :2, :2] = rp
        if n == 3:
            r[:, 2, 2] = c.radial_speed_sigma_mps**2
            if self.near_speed_on:
                r[:, 2, 2] += self.near_speed_sd(xp[:, :2], zh[:, 2]) ** 2
        return zh, h, r

    @property
    def near_speed_on(self) -> bool:
        """The near-radar radial-speed term applies: a height is known and ``near_speed_spread_m`` is not 0."""
        return self.height_m > 0.0 and self.cfg.near_speed_spread_m > 0.0

    def near_speed_sd(self, xy: np.ndarray, v_mps: np.ndarray) -> np.ndarray:
        """(T,) sd of a measured ground radial speed ``v_mps`` at ground positions ``xy`` that comes from the
        spread of the vehicle's scatterers along the line of sight (``near_speed_spread_m``): ``|v| h^2 / g^3 d``,
        capped at |v| + 1 m/s (right under the radar the radial speed says nothing)."""
        h2 = self.height_m * self.height_m
        g = np.maximum(np.hypot(xy[:, 0], xy[:, 1]), 1.0)
        av = np.abs(v_mps)
        return np.minimum(av * (h2 * self.cfg.near_speed_spread_m) / (g * g * g), av + 1.0)

    def with_sensor(self, xp: np.ndarray, r: np.ndarray) -> np.ndarray:
        """``r`` of :meth:`at` with ``sensor=False`` plus the constant converted polar noise: what :meth:`at`
        with ``sensor=True`` returns, without computing the prediction and extent again."""
        c = self.cfg
        out = r.copy()
        out[:, :2, :2] += kalman.polar_position_noise(xp[:, :2], c.range_sigma_m, self._az_sigma_rad, c.extent_sigma_m)
        return out

    def update_extent(self, xp, ext_var, inn: Innovations, beta: np.ndarray) -> np.ndarray:
        """Learn the along-heading spread from the weighted along-heading innovations of this frame:
        ``E[a^2] - u' (H P H' + R_sensor) u``, ``R_sensor`` = ``S`` without the extent term."""
        c = self.cfg
        u, w = self._head[1] if self._head is not None and self._head[0] is xp else heading(xp)
        a = inn.v[:, :, 0] * u[:, None, 0] + inn.v[:, :, 1] * u[:, None, 1]  # (T, M) along-heading innovation
        wsum = beta.sum(axis=1)
        ok = (wsum > 0.5) & (w >= 1.0)
        m2 = (beta * a * a).sum(axis=1) / np.maximum(wsum, 1e-12)
        s2 = inn.s[..., :2, :2]
        if s2.ndim == 4:  # one S per (track, detection): its weighted mean over this frame's detections
            s2 = (s2 * beta[:, :, None, None]).sum(axis=1) / np.maximum(wsum, 1e-12)[:, None, None]
        along_s = u[:, 0] * (s2[:, 0, 0] * u[:, 0] + s2[:, 0, 1] * u[:, 1]) + u[:, 1] * (
            s2[:, 1, 0] * u[:, 0] + s2[:, 1, 1] * u[:, 1])
        other = along_s - ext_var  # for moving tracks (w = 1) the extent adds exactly ext_var along u
        sample = np.minimum(np.maximum(m2 - other, 0.0), c.extent_max_sigma_m**2)
        return np.where(ok, (1.0 - c.extent_alpha) * ext_var + c.extent_alpha * sample, ext_var)


class PdaAssociator:
    """Gate (eq. 17) and association probabilities (eqs. 18-19, or cheap JPDA)."""

    def __init__(self, cfg: PdafConfig) -> None:
        self.cfg = cfg
        self._gamma = {n: gate_threshold(cfg.prob_gate, n) for n in (2, 3)}
        self.gamma = self._gamma.__getitem__  # gamma(n): the validation gate threshold of eq. 17
        self.exclusion_gamma = {n: gate_threshold(max(cfg.init_exclusion_prob, cfg.prob_gate), n) for n in (2, 3)}

    def associate(self, meas: Measurements, zh, h, pp, r, confirmed: np.ndarray, seniority: np.ndarray,
                  inn: Innovations | None = None):
        """``inn``: the innovations of ``zh``, ``h``, ``pp``, ``r`` if already computed. Confirmed tracks share detections (PDAF/JPDA); a tentative track only sees detections that no
        more senior track validated (confirmed first, then more hits): a tentative track born from clutter
        next to a vehicle, or a second seed on the same vehicle, must not live off its points."""
        if inn is None:
            inn = innovations(meas.z, zh, h, pp, r)
        n = meas.z.shape[1]
        gamma = self._gamma[n]
        if confirmed.all():  # no tentative track: every track may use every detection
            allowed = None
        else:
            rank = np.where(confirmed, np.inf, seniority.astype(float))
            owner = np.where(inn.d2 <= gamma, rank[:, None], -np.inf).max(axis=0)
            allowed = confirmed[:, None] | (rank[:, None] >= owner[None, :])
            if meas.pair is not None:  # one of two vehicles resolved in angle: the junior track may be the other one
                allowed |= (meas.pair >= 0)[None, :]
        weights = association_weights_each if isinstance(inn, InnovationsEach) else association_weights
        beta, beta0, gated = weights(inn, gamma, self.cfg.prob_detect, self.cfg.prob_gate, self.cfg.association, allowed)
        return inn, beta, beta0, gated


def _rows(inn: Innovations, rows: slice) -> Innovations:
    if isinstance(inn, InnovationsEach):
        return InnovationsEach(inn.v[rows], inn.d2[rows], inn.s[rows], inn.s_inv[rows], inn.det_s[rows],
                               inn.s_track[rows])
    return Innovations(inn.v[rows], inn.d2[rows], inn.s[rows], inn.s_inv[rows], inn.det_s[rows])


class PdaUpdater:
    def update(self, xp, pp, h, inn: Innovations, beta, beta0):
        if isinstance(inn, InnovationsEach):  # one gain per detection (its own R)
            return combined_update_each(xp, pp, h, inn, beta, beta0)
        return combined_update(xp, pp, h, inn, beta, beta0)


def _box_close(a_xy: np.ndarray, b_xy: np.ndarray, lat_m, along_m) -> np.ndarray:
    """(A, B) bool: points closer than the box half-sizes in x and y (scalars or (A,) per row)."""
    d = a_xy[:, None, :] - b_xy[None, :, :]
    lat = np.asarray(lat_m, dtype=float)
    lat = lat[:, None] if lat.ndim == 1 else lat
    along = np.asarray(along_m, dtype=float)
    along = along[:, None] if along.ndim == 1 else along
    return (np.abs(d[..., 0]) < lat) & (np.abs(d[..., 1]) < along)


def same_vehicle_lateral_m(cfg: PdafConfig, xy: np.ndarray) -> np.ndarray:
    """(N,) lateral distance within which points at ``xy`` may be one vehicle (grows with range)."""
    r = np.hypot(xy[:, 0], xy[:, 1])
    lat = cfg.merge_lateral_sigmas * r * math.radians(cfg.azimuth_sigma_deg)
    return np.minimum(np.maximum(lat, cfg.merge_lateral_m), max(cfg.merge_lateral_m, cfg.merge_lateral_max_m))


def same_vehicle_along_m(cfg: PdafConfig, tracks: "TrackTable") -> np.ndarray:
    """(T,) along-boresight distance within which a point still belongs to the track's vehicle."""
    sp = np.hypot(tracks.x[:, 2], tracks.x[:, 3])
    return np.maximum(np.maximum(cfg.merge_along_m, cfg.merge_headway_s * sp),
                      cfg.merge_extent_factor * np.sqrt(tracks.ext_var))


class MofNInitiator:
    """Tentative tracks from detections no track explains; confirmation after M hits in N frames, or by the
    track score (``confirmation``: :mod:`edge.track.score`)."""

    def __init__(self, cfg: PdafConfig, meas_model: MeasurementModel) -> None:
        self.cfg = cfg
        self.meas_model = meas_model
        self._mask_n = np.uint32((1 << cfg.confirm_n) - 1)
        self.uses_score = cfg.confirmation in ("score", "either")
        self._score_confirm = score.confirm_threshold(cfg.score_false_confirm_prob, cfg.score_true_reject_prob)
        self._score_drop = -score.confirm_threshold(cfg.score_true_reject_prob, cfg.score_false_confirm_prob)
        self._density = {n: score.false_density(cfg.score_false_density_m2, cfg.score_speed_span_mps, n) for n in (2, 3)}

    def score_increment(self, inn: Innovations, gated: np.ndarray, n: int) -> np.ndarray:
        """(T,) this frame's log-likelihood ratio of every track (:func:`edge.track.score.score_increment`)."""
        c = self.cfg
        return score.score_increment(inn.d2, inn.det_s, gated, n, c.score_prob_detect, c.prob_gate, self._density[n])

    def _ready(self, tracks: TrackTable) -> np.ndarray:
        """Tentative tracks that pass the confirmation test (``confirmation``), before the moving and block rules."""
        c = self.cfg
        out = ~tracks.confirmed
        if c.confirmation == "score":
            return out & (tracks.score >= self._score_confirm)
        mofn = np.bitwise_count(tracks.history & self._mask_n) >= c.confirm_m
        if c.confirmation == "either":
            mofn |= tracks.score >= self._score_confirm
        return out & mofn

    def initiate(self, tracks: TrackTable, meas: Measurements, used: np.ndarray, road_yaw_rad: float = 0.0,
                 r_det: np.ndarray | None = None) -> int:
        """Seed tentative tracks; with a radial speed the seed moves along the road (``road_yaw_rad`` off the
        boresight): its speed along the road from the radial speed, ``init_lateral_speed_sigma_mps`` across it.
        ``r_det``: ``meas_model.of_detections(meas)`` if already computed this frame (``measurement_noise = "snr"``)."""
        c = self.cfg
        z = meas.z
        rho = np.hypot(z[:, 0], z[:, 1])
        # a detection split from a merged one (two vehicles side by side) lies inside the gate of the track
        # that followed the merged detection: it may seed unless a track sits right on it
        resolved = meas.pair >= 0 if meas.pair is not None else np.zeros(z.shape[0], bool)
        cand = (~used | resolved) & (rho >= c.min_range_m) & (rho <= c.max_range_m)
        if meas.with_radial_speed:
            cand &= np.abs(z[:, 2]) >= c.seed_min_radial_speed_mps
        if meas.coherence is not None and c.seed_min_coherence > 0:
            cand &= (meas.coherence >= c.seed_min_coherence) | (meas.snr_db < c.seed_coherence_min_snr_db)
        if len(tracks) and cand.any():
            xt = tracks.x
            lat = same_vehicle_lateral_m(c, xt[:, :2])[:, None]
            if meas.pair is not None:
                lat = np.where(resolved[None, :], c.merge_lateral_m, lat)
            d = xt[:, None, :2] - z[None, :, :2]  # (T, M, 2)
            near = (np.abs(d[..., 0]) < lat) & (np.abs(d[..., 1]) < same_vehicle_along_m(c, tracks)[:, None])
            if meas.with_radial_speed:  # ... and moving like the track
                rho_t = np.maximum(np.hypot(xt[:, 0], xt[:, 1]), 1e-3)
                vr_t = (xt[:, 0] * xt[:, 2] + xt[:, 1] * xt[:, 3]) / rho_t
                near &= np.abs(vr_t[:, None] - z[None, :, 2]) < c.seed_merge_speed_mps
            cand &= ~near.any(axis=0)
        idx = cand.nonzero()[0]
        if idx.size == 0:
            return 0
        # one seed per vehicle: drop a candidate when a stronger one lies in its merge box
        zc = z.take(idx, axis=0)
        if idx.size == 1:  # one candidate: nothing to merge
            seed_idx = idx
        elif idx.size <= _SEED_MERGE_PLAIN_MAX:  # a handful: the same comparisons on Python floats, pair by pair
            seed_idx = self._merge_seeds_plain(idx, zc, meas.snr_db.take(idx), resolved.take(idx),
                                               meas.with_radial_speed)
        else:
            snr = meas.snr_db[idx]
            lat_c = np.where(resolved[idx][None, :] & resolved[idx][:, None], c.merge_lateral_m,
                             same_vehicle_lateral_m(c, zc[:, :2])[:, None])
            close = _box_close(zc[:, :2], zc[:, :2], lat_c, c.init_merge_along_m)
            if meas.with_radial_speed:  # detections of one vehicle share its radial speed
                close &= np.abs(zc[:, None, 2] - zc[None, :, 2]) < c.seed_merge_speed_mps
            order = np.arange(idx.size)
            stronger = (snr[None, :] > snr[:, None]) | ((snr[None, :] == snr[:, None]) & (order[None, :] < order[:, None]))
            seed_idx = idx.compress(~(close & stronger).any(axis=1))
        seeds = z.take(seed_idx, axis=0)
        room = c.max_tracks - len(tracks)
        if room <= 0:
            log.debug("track table full (%d): %d seeds dropped", c.max_tracks, seeds.shape[0])
            return 0
        seeds, seed_idx = seeds[:room], seed_idx[:room]
        k = seeds.shape[0]
        x0 = np.zeros((k, 4))
        x0[:, :2] = seeds[:, :2]
        p0 = np.zeros((k, 4, 4))
        if self.meas_model.per_detection:  # the seed's own noise (its SNR)
            # computed for the seeds only, or taken from this frame's (the same values)
            r = (self.meas_model.of_detections(meas, 2, rows=seed_idx) if r_det is None
                 else r_det.take(seed_idx, axis=0)[:, :2, :2])
        else:
            _, _, r = self.meas_model.at(x0, False)
        p0[:, :2, :2] = r
        if meas.with_radial_speed:
            # road direction e_s = (-sin yaw, cos yaw), across it e_u = (cos yaw, sin yaw): v = v_s e_s with
            # v_r = v_s (e_s . p) / |p|
            cy, sy = math.cos(road_yaw_rad), math.sin(road_yaw_rad)
            proj = cy * seeds[:, 1] - sy * seeds[:, 0]  # e_s . p
            rho_s = np.hypot(seeds[:, 0], seeds[:, 1])
            ok = np.abs(proj) > 1.0
            if ok.all():  # the usual case: no seed right beside the radar across the road
                v_s = seeds[:, 2] * rho_s / proj
                var_s = c.init_along_speed_sigma_mps**2  # one value for all seeds: the covariances below once
            else:
                v_s = np.where(ok, seeds[:, 2] * rho_s / np.where(ok, proj, 1.0), 0.0)
                var_s = np.where(ok, c.init_along_speed_sigma_mps**2, c.init_speed_sigma_mps**2)
            if self.meas_model.near_speed_on:
                # near the radar the seed's speed is blurred by its body's spread (MeasurementModel.near_speed_sd)
                var_s = var_s + self.meas_model.near_speed_sd(seeds[:, :2], v_s) ** 2
            x0[:, 2], x0[:, 3] = -sy * v_s, cy * v_s
            var_u = c.init_lateral_speed_sigma_mps**2
            p0[:, 2, 2] = cy * cy * var_u + sy * sy * var_s
            p0[:, 3, 3] = sy * sy * var_u + cy * cy * var_s
            p0[:, 2, 3] = p0[:, 3, 2] = cy * sy * (var_u - var_s)
        else:
            p0[:, 2, 2] = p0[:, 3, 3] = c.init_speed_sigma_mps**2
        tracks.append(x0, p0, c.extent_along_sigma_m**2, c.imm_init_keep_prob)
        if c.motion_model == "imm" and meas.with_radial_speed and c.imm_keep_init_lateral_speed_sigma_mps > 0:
            # the lane-keeping mode starts with little speed across the road (the manoeuvring mode keeps
            # init_lateral_speed_sigma_mps): a far seed's noisy first detections must not set it drifting
            pk = p0.copy()
            var_k = c.imm_keep_init_lateral_speed_sigma_mps**2
            pk[:, 2, 2] = cy * cy * var_k + sy * sy * var_s
            pk[:, 3, 3] = sy * sy * var_k + cy * cy * var_s
            pk[:, 2, 3] = pk[:, 3, 2] = cy * sy * (var_k - var_s)
            w = c.imm_init_keep_prob
            tracks.pm[-k:, 0] = pk
            tracks.p[-k:] = w * pk + (1.0 - w) * p0  # the modes share the mean: no spread term
        return k

    def _merge_seeds_plain(self, idx: np.ndarray, zc: np.ndarray, snr: np.ndarray, resolved: np.ndarray,
                           with_radial_speed: bool) -> np.ndarray:
        """The merge of :meth:`initiate`'s candidates (one seed per vehicle: a candidate goes when a stronger one,
        or an equally strong earlier one, lies in its merge box at its radial speed) for a handful of them, in
        plain Python: the same float64 differences and comparisons as the (A, A) array form, a few calls fewer."""
        c = self.cfg
        rows = zc.tolist()
        sl = snr.tolist()
        res = resolved.tolist()
        lat_i = same_vehicle_lateral_m(c, zc[:, :2]).tolist()
        lat_pair, along, dv = c.merge_lateral_m, c.init_merge_along_m, c.seed_merge_speed_mps
        keep = []
        for i, zi in enumerate(rows):
            si, ri, li = sl[i], res[i], lat_i[i]
            for j, zj in enumerate(rows):
                sj = sl[j]
                if not (sj > si or (sj == si and j < i)):  # j is not stronger (never itself)
                    continue
                if (abs(zi[0] - zj[0]) < (lat_pair if ri and res[j] else li) and abs(zi[1] - zj[1]) < along
                        and (not with_radial_speed or abs(zi[2] - zj[2]) < dv)):
                    break
            else:
                keep.append(i)
        return idx.take(np.array(keep, dtype=np.intp))

    def confirm(self, tracks: TrackTable, ids: IdPool) -> None:
        c = self.cfg
        ready = self._ready(tracks) & tracks.moved
        if c.confirm_block_along_m > 0 and ready.any() and tracks.confirmed.any():
            # a second track on a long vehicle (its front and its rear half) waits for the duplicate check
            r, k = np.flatnonzero(ready), np.flatnonzero(tracks.confirmed)
            xk = tracks.x.take(k, axis=0)
            d = tracks.x.take(r, axis=0)[:, None, :] - xk[None, :, :]
            u, _ = heading(xk)  # speed compared along the confirmed track's heading (a young track's
            dv = d[..., 2] * u[None, :, 0] + d[..., 3] * u[None, :, 1]  # lateral speed is still noise)
            along = np.abs(d[..., 1]) < c.confirm_block_along_m
            blocked = (along & (((np.abs(d[..., 0]) < c.merge_lateral_m) & (np.abs(dv) < c.merge_speed_mps))
                                | ((np.abs(d[..., 0]) < c.confirm_block_lateral_m) & (d[..., 1] > c.confirm_block_behind_m)
                                   & (np.abs(dv) < c.confirm_block_speed_mps)
                                   & (np.hypot(xk[:, 0], xk[:, 1]) < c.confirm_block_max_range_m)[None, :])
                                )).any(axis=1)
            ready[r[blocked]] = False
        for i in ready.nonzero()[0]:
            tid = ids.acquire()
            if tid is None:
                log.warning("no free track id (max %d): track stays tentative", c.max_track_id)
                break
            tracks.track_id[i] = tid
            tracks.confirmed[i] = True

    def tentative_expired(self, tracks: TrackTable) -> np.ndarray:
        """Tentative tracks that can no longer reach M hits in their last N frames."""
        c = self.cfg
        if c.confirmation == "score":  # Wald's lower threshold
            return ~tracks.confirmed & (tracks.score <= self._score_drop)
        recent = tracks.history & self._mask_n
        counts = np.bitwise_count(recent)
        out = ~tracks.confirmed & (tracks.age >= c.confirm_n) & (counts < c.confirm_m) & (tracks.misses > 0)
        if c.tentative_keep_from_m > 0 and out.any():  # far tracks: only once hardly anything hits any more
            far = np.hypot(tracks.x[:, 0], tracks.x[:, 1]) > c.tentative_keep_from_m
            out &= ~far | (counts < c.tentative_keep_min_hits)
        return out


class TrackDeleter:
    """Deletion: misses in a row, diverged covariance, out of the field, duplicates of an older track."""

    def __init__(self, cfg: PdafConfig) -> None:
        self.cfg = cfg
        self._state_gamma = gate_threshold(cfg.merge_state_prob, 4)
        self._pairs: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # track count -> np.triu_indices(t, 1)
        self._pairs_all: tuple[np.ndarray, np.ndarray] = np.triu_indices(32, 1)  # for up to 32 tracks (grows)

    def pairs(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """``np.triu_indices(t, 1)`` (row-major pairs ``a < b``), cached per track count; a new count takes the
        pairs ``b < t`` of a larger table in their order (the same arrays, 3 calls instead of ~60 us)."""
        pairs = self._pairs.get(t)
        if pairs is None:
            ia, ib = self._pairs_all
            n_all = int(ib[-1]) + 1 if ib.size else 1
            if t > n_all:
                ia, ib = self._pairs_all = np.triu_indices(max(t, 2 * n_all), 1)
            m = ib < t
            pairs = self._pairs[t] = (ia.compress(m), ib.compress(m))
        return pairs

    def delete(self, tracks: TrackTable, resolved: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """``resolved``: per track the resolved pair (or -1) and the detection it followed this frame."""
        c = self.cfg
        rho = np.hypot(tracks.x[:, 0], tracks.x[:, 1])
        sig = np.sqrt(np.maximum(tracks.p[:, 0, 0], tracks.p[:, 1, 1]))
        dead = (tracks.misses >= c.delete_after_misses) | (sig > c.max_position_sigma_m)
        dead |= (rho < c.min_range_m) | (rho > c.max_range_m)
        dead |= np.abs(np.arctan2(tracks.x[:, 0], tracks.x[:, 1])) > math.radians(c.max_azimuth_deg)
        return dead | self.duplicates(tracks, resolved)

    def duplicates(self, tracks: TrackTable, resolved: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Of two tracks on one vehicle, drop the junior (unconfirmed first, then fewer hits, then younger).

        Two tracks are one vehicle when their velocities agree within ``merge_speed_mps`` along their common
        heading and ``merge_lateral_speed_mps`` across it (or they stayed in the same-vehicle box for
        ``merge_persist_frames``, whatever their lateral speeds) and either their
        positions are within the same-vehicle box or their states are statistically indistinguishable
        (position covariances widened by the vehicles' along-heading spread)."""
        c = self.cfg
        t = len(tracks)
        out = np.zeros(t, dtype=bool)
        if t < 2:
            return out
        x = tracks.x
        ia, ib = self.pairs(t)
        # speed difference along the pair's common heading, and across it: a duplicate born with a wrong
        # lateral velocity (a far, noisy seed) drifts onto its vehicle with metres per second across
        xa, xb = x.take(ia, axis=0), x.take(ib, axis=0)  # take: rows without the fancy-indexing machinery
        dx = xa - xb  # (pairs, 4): position and velocity differences
        vsum = xa[:, 2:4] + xb[:, 2:4]
        nrm = np.maximum(np.hypot(vsum[:, 0], vsum[:, 1]), 1e-9)
        ux, uy = vsum[:, 0] / nrm, vsum[:, 1] / nrm
        dvx, dvy = dx[:, 2], dx[:, 3]
        keep = np.abs(dvx * ux + dvy * uy) < c.merge_speed_mps
        if resolved is not None:  # tracks on the two members of a resolved pair are two vehicles
            pair, det = resolved
            keep &= ~((pair[ia] >= 0) & (pair[ia] == pair[ib]) & (det[ia] != det[ib]))
        sel = keep.nonzero()[0]
        if sel.size == 0:  # no two tracks move alike: nothing is boxed, no duplicate
            tracks.close_run = np.zeros(t, np.int32)
            return out
        ia, ib, dx, ux, uy = ia[sel], ib[sel], dx.take(sel, axis=0), ux[sel], uy[sel]
        dv_across = np.abs(dx[:, 2] * uy - dx[:, 3] * ux)
        reach = same_vehicle_along_m(c, tracks)
        boxed = (np.abs(dx[:, 0]) < c.merge_lateral_m) & (np.abs(dx[:, 1]) < np.maximum(reach[ia], reach[ib]))
        # same place, same speed along, but moving apart or together across: two vehicles crossing each
        # other's path pass through the box within a second; a duplicate stays in it
        keep = dv_across < c.merge_lateral_speed_mps
        if boxed.any():
            run = np.zeros(t, bool)
            run[ia[boxed]] = run[ib[boxed]] = True
            tracks.close_run = np.where(run, tracks.close_run + 1, 0).astype(np.int32, copy=False)
            keep |= boxed & (np.minimum(tracks.close_run[ia], tracks.close_run[ib]) >= c.merge_persist_frames)
        else:  # nothing boxed: every run ends, and no pair lasted (merge_persist_frames >= 1)
            tracks.close_run = np.zeros(t, np.int32)
        sel = keep.nonzero()[0]
        if sel.size == 0:
            return out
        ia, ib, close, dx = ia[sel], ib[sel], boxed[sel], dx.take(sel, axis=0)
        # the diagonal of extent_cov(x, ext_var) (the whole matrices only for the pairs that need a solve),
        # column by column: heading() without its two-column forms
        sp = np.hypot(x[:, 2], x[:, 3])
        nrm_t = np.maximum(sp, 1e-9)
        ux_t, uy_t = x[:, 2] / nrm_t, x[:, 3] / nrm_t
        w = np.minimum(np.maximum(sp, 0.0), 1.0)
        iso = 1.0 - w
        pdx = tracks.p[:, 0, 0] + tracks.ext_var * (w * (ux_t * ux_t) + iso)
        pdy = tracks.p[:, 1, 1] + tracks.ext_var * (w * (uy_t * uy_t) + iso)
        # a marginal Mahalanobis distance never exceeds the joint one: prune before the 4x4 solves
        dxx, dxy = dx[:, 0], dx[:, 1]
        marg = dxx * dxx < self._state_gamma * (pdx[ia] + pdx[ib])
        marg &= dxy * dxy < self._state_gamma * (pdy[ia] + pdy[ib])
        rest = (marg & ~close).nonzero()[0]
        if rest.size:
            ext = extent_cov(x, tracks.ext_var)
            ja, jb = ia[rest], ib[rest]
            psum = tracks.p.take(ja, axis=0) + tracks.p.take(jb, axis=0)
            psum[:, :2, :2] += ext.take(ja, axis=0) + ext.take(jb, axis=0)
            d = dx.take(rest, axis=0)
            d2 = (d[:, None, :] @ np.linalg.solve(psum, d[:, :, None]))[:, 0, 0]
            close[rest] = d2 < self._state_gamma
        ia, ib = ia[close], ib[close]
        if ia.size == 0:
            return out
        rank = tracks.confirmed.astype(np.int64) * (1 << 40) + tracks.hits.astype(np.int64) * (1 << 20) + tracks.age
        b_senior = (rank[ib] > rank[ia]) | ((rank[ib] == rank[ia]) & (ib < ia))
        out[np.where(b_senior, ia, ib)] = True
        return out


class PdafTracker:
    """Multi-target PDAF (or cheap JPDA) tracker with a constant-velocity Kalman filter.

    One :meth:`step` per frame::

        predict -> associate (gate, beta) -> update -> delete -> confirm -> initiate -> publish
    """

    def __init__(self, config: PdafConfig | None = None) -> None:
        self.config = config or PdafConfig()
        self.predictor = CvPredictor(self.config)
        self.imm_predictor = ImmPredictor(self.config) if self.config.motion_model == "imm" else None
        self.road_yaw_rad = 0.0  # direction of the road off the boresight (the lane pipeline sets its estimate)
        # lateral_smoother: the motion model's x_m of the last published tracks (the published x_m is the line's)
        self.published_motion_x_m: np.ndarray | None = None
        self.measurement_model = MeasurementModel(self.config)
        self.associator = PdaAssociator(self.config)
        self.updater = PdaUpdater()
        self.initiator = MofNInitiator(self.config, self.measurement_model)
        self.deleter = TrackDeleter(self.config)
        self._moving_gamma = gate_threshold(self.config.moving_prob, 2)
        self._lateral_gamma = gate_threshold(self.config.lateral_smoother_reset_prob, 1)
        self.reset()

    @property
    def sensor_height_m(self) -> float:
        """Height of the radar above the targets' scatterers (m): the geometry of ``near_speed_spread_m`` (the lane
        pipeline sets it from its mounting and target heights; 0 = unknown, the term off)."""
        return self.measurement_model.height_m

    @sensor_height_m.setter
    def sensor_height_m(self, value: float) -> None:
        self.measurement_model.height_m = max(float(value), 0.0)

    def reset(self) -> None:
        self.tracks = TrackTable()
        self.ids = IdPool(self.config.max_track_id)
        self.last_t_ns: int | None = None
        self.intermediates: dict[str, np.ndarray] = {}
        self.published_motion_x_m = None

    def step(self, detections: Detections, t_ns: int) -> tuple[TrackState, ...]:
        """Advance all tracks to ``t_ns`` with this frame's detections; return the published tracks."""
        cfg = self.config
        meas = Measurements.from_detections(detections, cfg.use_radial_speed)
        dt_s = 0.0 if self.last_t_ns is None else max((t_ns - self.last_t_ns) * 1e-9, 0.0)
        self.last_t_ns = t_ns
        tr = self.tracks
        m = meas.z.shape[0]
        used = np.zeros(m, dtype=bool)
        rm = None
        if len(tr):
            if self.imm_predictor is not None:
                xp, pp, xpm, ppm, cj = self.imm_predictor.predict(tr, dt_s, self.road_yaw_rad)
            else:
                xp, pp = self.predictor.predict(tr, dt_s)
            # measurement_noise = "snr": the sensor noise comes per detection, r holds the track's part only
            rm = self.measurement_model.of_detections(meas) if self.measurement_model.per_detection else None
            pred = None
            if self.imm_predictor is not None:  # the combined prediction's and both modes' in one (elementwise) call
                t = len(tr)
                zh_all, h_all = kalman.measurement_prediction(np.concatenate([xp, xpm.reshape(2 * t, 4)]),
                                                              meas.with_radial_speed)
                pred, zhm, hm = (zh_all[:t], h_all[:t]), zh_all[t:], h_all[t:]
            zh, h, r = self.measurement_model.at(xp, meas.with_radial_speed, tr.ext_var, sensor=rm is None, pred=pred)
            if self.imm_predictor is not None:
                # one innovation computation for the combined prediction (association) and both modes
                if rm is None:
                    args = (meas.z, np.concatenate([zh, zhm]), np.concatenate([h, hm]),
                            np.concatenate([pp, ppm.reshape(2 * t, 4, 4)]), np.concatenate([r, r.repeat(2, axis=0)]))
                    inn_all = innovations(*args)
                    inn, inn_m = _rows(inn_all, slice(0, t)), _rows(inn_all, slice(t, None))
                else:  # per-detection noise: the modes' innovations only for the validated pairs (in _imm_update)
                    inn, inn_m = innovations_each(meas.z, zh, h, pp, r, rm), None
                inn, beta, beta0, gated = self.associator.associate(meas, zh, h, pp, r, tr.confirmed, tr.hits, inn)
                self._imm_update(meas, xpm, ppm, cj, hm, inn, inn_m, beta, beta0, gated, zhm, r, rm)
            else:
                inn = None if rm is None else innovations_each(meas.z, zh, h, pp, r, rm)
                inn, beta, beta0, gated = self.associator.associate(meas, zh, h, pp, r, tr.confirmed, tr.hits, inn)
                tr.x, tr.p = self.updater.update(xp, pp, h, inn, beta, beta0)
            if cfg.lateral_smoother:
                self._lateral_step(meas, dt_s, beta, r, rm, xp, pp)
            if cfg.extent_alpha > 0 and m:
                tr.ext_var = self.measurement_model.update_extent(xp, tr.ext_var, inn, beta)
            hit = gated.any(axis=1)
            if self.initiator.uses_score:
                tr.score += self.initiator.score_increment(inn, gated, meas.z.shape[1])
            d2_seed = inn.d2
            if rm is not None and cfg.seed_exclusion_noise == "constant":
                # which detections may seed: the exclusion gate of the constant noise model (wider than the SNR
                # noise for strong detections of unresolved vehicle pairs, whose angle lies between the two)
                # (S of the constant model = the track's part of S plus the constant sensor noise; the same innovations)
                d2_seed = mahalanobis_d2(inn.v, self.measurement_model.with_sensor(xp, inn.s_track))
            used = (d2_seed <= self.associator.exclusion_gamma[meas.z.shape[1]]).any(axis=0)
            tr.age += 1
            tr.hits += hit
            tr.misses = (tr.misses + 1) * ~hit  # int32: 0 on a hit
            tr.history = (tr.history << np.uint32(1)) | hit  # uint32, bit 0 = this frame
            if cfg.reanchor_m > 0 and m and meas.with_radial_speed:
                self._reanchor(meas, gated, hit, used)
            # moving for sure: the velocity is significantly non-zero (v' P_v^-1 v) and fast enough
            v = tr.x[:, 2:4]
            d2v = inv_quad2(tr.p[:, 2:4, 2:4], v)
            tr.moved |= (d2v > self._moving_gamma) & (np.hypot(v[:, 0], v[:, 1]) >= cfg.confirm_min_speed_mps)
            resolved = None
            if meas.pair is not None and m:
                best, strong = _carrying_detection(beta)
                resolved = (np.where(strong, meas.pair[best], -1), best)
            dead = self.deleter.delete(tr, resolved) | self.initiator.tentative_expired(tr)
            for tid in tr.track_id[dead & tr.confirmed]:
                self.ids.release(int(tid))
            if dead.any():
                tr.keep(~dead)
            self.initiator.confirm(tr, self.ids)  # after duplicates are gone: no id is spent on one
            self.intermediates = {"gated": gated, "beta0": beta0, "d2": inn.d2}
        else:
            self.intermediates = {}
        self.initiator.initiate(tr, meas, used, self.road_yaw_rad, rm)
        self.intermediates["used"] = used
        return self.published()

    def _imm_update(self, meas: Measurements, xpm, ppm, cj, hm, inn: Innovations, inn_m: Innovations | None, beta,
                    beta0, gated, zhm=None, r=None, rm=None) -> None:
        """PDAF update of both modes (rows (track, mode) of ``hm``, ``inn_m``) with the association weights of the
        combined prediction, mode probabilities from each mode's likelihood of the validated detections,
        moment-matched output."""
        cfg = self.config
        tr = self.tracks
        t = xpm.shape[0]
        n = meas.z.shape[1]
        xs, ps = xpm.reshape(2 * t, 4), ppm.reshape(2 * t, 4, 4)  # rows (track, mode)
        gamma = self.associator.gamma(n)
        if isinstance(inn, InnovationsEach):  # one S per (track, detection): a gain per detection, validated pairs
            ti, mi = np.nonzero(gated)
            rows = np.concatenate([2 * ti, 2 * ti + 1])  # rows (track, mode)
            cols = np.concatenate([mi, mi])
            scale = None
            if cfg.extent_near_side_factor != 1.0:
                # a detection nearer the radar than the track's (near-face) prediction: the face is nearer, not a
                # scatterer further along the body -- the extent's spread shrinks for it
                zp = zhm[rows, :2]
                nearer = ((meas.z[cols, :2] - zp) * zp).sum(axis=1) < 0.0
                scale = np.where(nearer, cfg.extent_near_side_factor, 1.0)
            pin = pair_innovations(meas.z, zhm, hm, ps, np.repeat(r, 2, axis=0), rm, rows, cols, scale)
            wg = beta[ti, mi]
            w = np.concatenate([wg, wg])
            if (wg > 0).all():  # the usual case (a validated pair has a positive weight unless it underflows)
                xu, pu = combined_update_pairs(xs, ps, hm, pin, w)
            else:
                pos = w > 0
                xu, pu = combined_update_pairs(xs, ps, hm, PairInnovations(rows[pos], cols[pos], pin.v[pos],
                                                                            pin.d2[pos], pin.s_inv[pos],
                                                                            pin.det_s[pos]), w[pos])
            vol = inn.gate_volume if inn.gate_volume is not None else gate_volume_each(inn, gated, gamma)
            lik = imm.mode_likelihood_pairs(pin, 2 * t, np.repeat(vol, 2), np.repeat(gated.sum(axis=1), 2),
                                            cfg.prob_detect, cfg.prob_gate).reshape(t, 2)
            tr.mu = imm.update_mode_probabilities(cj, lik, cfg.imm_min_mode_prob)
            tr.xm, tr.pm = xu.reshape(t, 2, 4), pu.reshape(t, 2, 4, 4)
            tr.x, tr.p = imm.moment_match(tr.xm, tr.pm, tr.mu)
            return
        m = inn_m.d2.shape[1]
        # (track, mode) axes: the common weights, gate and gate volume broadcast over the modes
        by_mode = Innovations(inn_m.v.reshape(t, 2, m, n), inn_m.d2.reshape(t, 2, m), inn_m.s.reshape(t, 2, n, n),
                              inn_m.s_inv.reshape(t, 2, n, n), inn_m.det_s.reshape(t, 2))
        tr.xm, tr.pm = combined_update(xpm, ppm, hm.reshape(t, 2, n, 4), by_mode, beta[:, None, :], beta0[:, None])
        vol = unit_ball_volume(n) * gamma ** (n / 2.0) * np.sqrt(inn.det_s)
        lik = imm.mode_likelihood(by_mode, gated[:, None, :], vol[:, None], cfg.prob_detect, cfg.prob_gate)
        tr.mu = imm.update_mode_probabilities(cj, lik, cfg.imm_min_mode_prob)
        tr.x, tr.p = imm.moment_match(tr.xm, tr.pm, tr.mu)

    def _lateral_step(self, meas: Measurements, dt_s: float, beta: np.ndarray, r: np.ndarray,
                      rm: np.ndarray | None, xp: np.ndarray, pp: np.ndarray) -> None:
        """The straight-line filter across the boresight (``lateral_smoother``, :mod:`edge.track.kalman`): predict,
        PDAF update with the association's weights and each detection's own lateral variance (the track's part
        of ``R`` plus, with ``measurement_noise = "snr"``, the detection's), restart from the motion model's
        estimate where the two disagree (``xp``, ``pp``: the motion model's prediction, for the CUSUM)."""
        cfg = self.config
        tr = self.tracks
        new = tr.age == 1  # seeded last frame: its lateral speed is the road direction's, give or take a little
        if new.any():
            tr.lat_p[new, 1, 1] = np.minimum(tr.lat_p[new, 1, 1], cfg.lateral_smoother_init_speed_sigma_mps**2)
            tr.lat_p[new, 0, 1] = tr.lat_p[new, 1, 0] = 0.0
        lat, lat_p = kalman.lateral_predict(tr.lat, tr.lat_p, dt_s, cfg.lateral_smoother_q_m2ps3)
        ti, mi = np.nonzero(beta > 0)
        cusum = tr.lat_cusum
        if ti.size:
            var = r[ti, 0, 0] if rm is None else r[ti, 0, 0] + rm[mi, 0, 0]
            z, w = meas.z[mi, 0], beta[ti, mi]
            llr = kalman.lateral_log_likelihood_ratio(len(tr), ti, w, z, var, lat[:, 0], lat_p[:, 0, 0], xp[:, 0],
                                                      pp[:, 0, 0])
            cusum = np.maximum(cusum + llr, 0.0)
            lat, lat_p = kalman.lateral_pda_update(lat, lat_p, z, var, ti, w)
        ref, ref_p = tr.x[:, 0::2], tr.p[:, 0::2, 0::2]
        off = kalman.lateral_inconsistent(lat, lat_p, ref, ref_p, self._lateral_gamma,
                                          cfg.lateral_smoother_min_var_fraction)
        off |= cusum > cfg.lateral_smoother_cusum_nats
        hold = None
        if cfg.lateral_smoother_hold_manoeuvre_prob < 1.0 and cfg.motion_model == "imm":
            hold = tr.mu[:, 1] > cfg.lateral_smoother_hold_manoeuvre_prob  # the IMM says: manoeuvring
            off |= hold
        if cfg.lateral_smoother_hold_unresolved and meas.unresolved is not None and ti.size:
            # a detection of two vehicles too close in angle to split (its angle lies between them) carries the track
            # (its largest weight): no straight line through it, the motion model's position until the pair splits
            best, strong = _carrying_detection(beta)
            pair = meas.unresolved[best] & strong
            off |= pair  # (with the motion model's own lateral speed: the pair may be crossing)
        if off.any():
            lat[off], lat_p[off] = ref[off], ref_p[off]
            cusum = np.where(off, 0.0, cusum)
            if hold is not None and hold.any():
                # held during a manoeuvre: the lateral speed of the lane-keeping mode (decaying to the road's), so a
                # line that starts again as the manoeuvre ends does not keep the manoeuvre's speed across
                lat[hold, 1] = tr.xm[hold, 0, 2]
                lat_p[hold, 1, 1] = tr.pm[hold, 0, 2, 2]
                lat_p[hold, 0, 1] = lat_p[hold, 1, 0] = tr.pm[hold, 0, 0, 2]
        tr.lat, tr.lat_p, tr.lat_cusum = lat, lat_p, cusum

    def _reanchor(self, meas: Measurements, gated: np.ndarray, hit: np.ndarray, used: np.ndarray) -> None:
        """A confirmed track that missed moves to the nearest unclaimed detection up to ``reanchor_m`` nearer
        than it, in line with it and at its radial speed (``PdafConfig.reanchor_m``): the near face of the
        vehicle whose body the track sat on. Marks the detection used (no seed)."""
        c = self.config
        tr = self.tracks
        miss = (tr.confirmed & ~hit).nonzero()[0]
        if miss.size == 0:
            return
        free = (~gated.any(axis=0)).nonzero()[0]
        if free.size == 0:
            return
        st, z = tr.x.take(miss, axis=0), meas.z.take(free, axis=0)
        rho_t = np.maximum(np.hypot(st[:, 0], st[:, 1]), 1e-3)
        vr_t = (st[:, 0] * st[:, 2] + st[:, 1] * st[:, 3]) / rho_t
        ok = np.abs(vr_t[:, None] - z[None, :, 2]) < c.reanchor_speed_mps
        if c.reanchor_receding_only:  # an approaching track started on its near face far away (config doc)
            ok &= (vr_t > 0.0)[:, None]
        if not ok.any():  # the usual frame: no unclaimed detection at a missed track's radial speed
            return
        nearer = rho_t[:, None] - np.hypot(z[:, 0], z[:, 1])[None, :]  # (k, f) > 0: the detection is nearer
        ok &= (nearer > c.reanchor_min_m) & (nearer <= c.reanchor_m) & (np.abs(st[:, 0, None] - z[None, :, 0]) < c.merge_lateral_m)
        has = ok.any(axis=1)
        if not has.any():
            return
        i = miss[has]
        j = free[np.argmax(np.where(ok, nearer, -np.inf), axis=1)[has]]  # the nearest: the near face
        tr.x[i, :2] = meas.z[j, :2]
        _, _, r = self.measurement_model.at(tr.x[i], False)  # a jump: the constant model's (wider) noise
        tr.p[i, :2, :2] = r
        tr.p[i, :2, 2:] = 0.0
        tr.p[i, 2:, :2] = 0.0
        tr.hits[i] += 1
        tr.misses[i] = 0
        tr.history[i] |= np.uint32(1)
        tr.xm[i] = tr.x[i, None, :]  # both IMM modes restart from the new position
        tr.pm[i] = tr.p[i, None, :, :]
        tr.lat[i] = tr.x[i, 0::2]  # and the straight-line filter
        tr.lat_p[i] = tr.p[i, 0::2, 0::2]
        tr.lat_cusum[i] = 0.0
        used[j] = True

    def published(self) -> tuple[TrackState, ...]:
        tr = self.tracks
        if self.config.publish_tentative:
            sel = tr.misses <= self.config.publish_max_misses
        else:
            sel = tr.confirmed & (tr.misses <= self.config.publish_max_misses)
        idx = sel.nonzero()[0]
        if idx.size == 0:
            if self.config.lateral_smoother:
                self.published_motion_x_m = None
            return ()
        st = tr.x.take(idx, axis=0)
        if self.config.lateral_smoother:  # the lateral position of the straight-line filter ...
            self.published_motion_x_m = st[:, 0].copy()
            c = tr.lat_cusum.take(idx)
            lat = tr.lat[:, 0].take(idx)
            # ... moved towards the motion model's by the evidence that the vehicle left its line (none: itself)
            st[:, 0] = kalman.lateral_blend(lat, st[:, 0], c, self.config.lateral_smoother_cusum_nats) if c.any() else lat
        x, y, vx, vy = st[:, 0], st[:, 1], st[:, 2], st[:, 3]
        rho = np.hypot(x, y)
        num = x * vx + y * vy
        if (rho > 0).all():  # always, unless a track sits on the radar (min_range_m = 0)
            vr = num / rho
        else:
            vr = np.divide(num, rho, out=np.zeros_like(rho), where=rho > 0)
        az = np.arctan2(x, y)
        if self.config.publish_length:  # moving (the weight of heading() is 1 from 1 m/s): the length is known
            length = [v if ok else None
                      for v, ok in zip(np.sqrt(12.0 * tr.ext_var[idx]).tolist(), (np.hypot(vx, vy) >= 1.0).tolist())]
        else:
            length = [None] * idx.size
        rows = zip(tr.track_id[idx].tolist(), st.tolist(), rho.tolist(), vr.tolist(), az.tolist(),
                   tr.age[idx].tolist(), tr.hits[idx].tolist(), tr.confirmed[idx].tolist(), length)
        quality = self._published_quality(idx)
        if not _TRACK_STATE_PLAIN:
            return tuple(TrackState(tid, x, y, vx, vy, r, v, a, age, hits, conf, length_m=ln, x_sd_m=xs, y_sd_m=ys,
                                    vx_sd_mps=vxs, vy_sd_mps=vys, existence_probability=pe)
                         for (tid, (x, y, vx, vy), r, v, a, age, hits, conf, ln), (xs, ys, vxs, vys, pe)
                         in zip(rows, quality))
        # TrackState(...) without the frozen dataclass's per-field object.__setattr__ (tens of tracks per
        # frame on the hot path): the same __dict__
        new, set_dict, cls = _new_object, _set_dict, TrackState
        out = []
        for (tid, (x, y, vx, vy), r, v, a, age, hits, conf, ln), (xs, ys, vxs, vys, pe) in zip(rows, quality):
            o = new(cls)
            set_dict(o, "__dict__", {
                "track_id": tid, "x_m": x, "y_m": y, "vx_mps": vx, "vy_mps": vy, "range_m": r,
                "radial_speed_mps": v, "az_rad": a, "age_frames": age, "hits": hits, "confirmed": conf, "lane": None,
                "cls": None, "class_probability": None, "rcs_dbsm": None, "length_m": ln, "x_sd_m": xs, "y_sd_m": ys,
                "vx_sd_mps": vxs, "vy_sd_mps": vys, "existence_probability": pe})
            out.append(o)
        return tuple(out)

    def _published_quality(self, idx: np.ndarray) -> zip:
        """Per published track (rows ``idx``): the standard deviations of the published x, y, vx, vy and the
        existence probability, as TrackState's quality fields.

        The deviations are the roots of the state covariance's diagonal (the published frame is the state's);
        with the lateral smoother the lateral one is the straight-line filter's, or the larger of the two while
        the published position moves towards the motion model's. The existence probability is the posterior
        ``1 / (1 + exp(-L))`` of the track score ``L`` (:mod:`edge.track.score`, prior odds 1; ``L`` stays 0 when
        confirmation = m_of_n keeps no score), and a confirmed track's ``L`` counts as at least Wald's
        threshold ``ln((1 - score_true_reject_prob) / score_false_confirm_prob)``, the evidence a confirmation
        stands for (an M-of-N confirmation is taken as equally strong): 0.9999 with the defaults."""
        tr, cfg = self.tracks, self.config
        sd = np.sqrt(np.maximum(np.diagonal(tr.p.take(idx, axis=0), axis1=1, axis2=2), 0.0))  # (n, 4): x, y, vx, vy
        if cfg.lateral_smoother:
            lat_sd = np.sqrt(np.maximum(tr.lat_p[:, 0, 0].take(idx), 0.0))
            sd[:, 0] = np.where(tr.lat_cusum.take(idx) > 0.0, np.maximum(lat_sd, sd[:, 0]), lat_sd)
        log_odds = tr.score.take(idx)
        floor = score.confirm_threshold(cfg.score_false_confirm_prob, cfg.score_true_reject_prob)
        log_odds = np.where(tr.confirmed.take(idx), np.maximum(log_odds, floor), log_odds)
        p_exist = 1.0 / (1.0 + np.exp(-np.clip(log_odds, -700.0, 700.0)))
        return zip(*sd.T.tolist(), p_exist.tolist())


_TRACK_STATE_FIELDS = ("track_id", "x_m", "y_m", "vx_mps", "vy_mps", "range_m", "radial_speed_mps", "az_rad",
                       "age_frames", "hits", "confirmed", "lane", "cls", "class_probability", "rcs_dbsm", "length_m",
                       "x_sd_m", "y_sd_m", "vx_sd_mps", "vy_sd_mps", "existence_probability")
# the fast path of PdafTracker.published knows TrackState's fields; if they change (or it gains a __post_init__
# or a factory default), the plain constructor is used
_TRACK_STATE_PLAIN = (tuple(f.name for f in dataclasses.fields(TrackState)) == _TRACK_STATE_FIELDS
                      and not hasattr(TrackState, "__post_init__")
                      and all(f.default is None for f in dataclasses.fields(TrackState)[11:]))
_new_object = object.__new__
_set_dict = object.__setattr__


def _track_state(tid, x, y, vx, vy, r, v, a, age, hits, conf, length_m) -> TrackState:
    """``TrackState(tid, x, ..., conf, length_m=length_m)`` without the frozen dataclass's per-field
    ``object.__setattr__``; the same ``__dict__`` (PdafTracker.published builds it inline)."""
    if not _TRACK_STATE_PLAIN:
        return TrackState(tid, x, y, vx, vy, r, v, a, age, hits, conf, length_m=length_m)
    out = _new_object(TrackState)
    _set_dict(out, "__dict__", {
        "track_id": tid, "x_m": x, "y_m": y, "vx_mps": vx, "vy_mps": vy, "range_m": r, "radial_speed_mps": v,
        "az_rad": a, "age_frames": age, "hits": hits, "confirmed": conf, "lane": None, "cls": None,
        "class_probability": None, "rcs_dbsm": None, "length_m": length_m, "x_sd_m": None, "y_sd_m": None,
        "vx_sd_mps": None, "vy_sd_mps": None, "existence_probability": None})
    return out
