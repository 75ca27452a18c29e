"""Doppler and RCS signatures of clusters and the feature vector of a track (Tavanti §II-F).

Per frame and cluster (:class:`SignatureExtractor`, vectorised over every point of the frame):

* circular variance of the cluster's Doppler (eq. 18): ``S = 1 - |sum_l exp(j theta_l)| / N`` with
  ``theta`` the polar angle of each point on the wrapped map (unweighted, as in the paper);
* the RCS-related quantity of eq. 17: for every Doppler column of the cluster, the local peaks of
  the range profile inside the cluster's cells contribute
  ``r^1.8 / N_s * (|M| sqrt(f_c^2 + f_b^2) / f_b)^2`` where ``r`` and ``f_b = 2 mu r / c`` are the
  peak's range and beat frequency and ``f_c`` is the lower corner frequency of the board's IF
  amplifier (``classify.features.if_corner_hz``; the factor undoes its first-order high-pass).
  ``f_b`` is floored at half an FFT bin (``fs / (2 N_s)``) so cells at zero range stay finite;
* the centroid of the cluster: the mean of its points on the cylinder, projected back onto the
  surface (the tracker's measurement), and its mean range (for the radial speed);
* beyond the paper, the cluster's *range extent*: the span in range of its cells within
  ``extent_level_db`` (20 dB) of its strongest cell and within ``extent_doppler_kmh`` of that cell's wrapped
  Doppler, the body's (a rotating wheel's micro-Doppler moves its cells in range through the range-Doppler
  coupling, by 0.54 m per 10.7 km/h on the Distance2Go, so the span of all its cells grows with speed; the span
  of all the cells still serves the tracker and the speed). Seen along the road, a body's scatterers spread
  over its length in range (motorcycle ~2 m, car ~4.5 m, truck/bus 7-12 m; the range resolution is
  0.75 m), which eq. 17's RCS quantity and eq. 18's Doppler spread do not tell apart: with the five
  features of eq. 19 alone, 3-fold CV of the k = 13 k-NN on the simulated reference set was 0.84
  (cars confused with motorcycles and trucks); with the extent 0.97 (refgen, 400 events).

Per track (:class:`TrackFeatureAccumulator`, bounded memory, fed one frame at a time): the feature
vector of eq. 19 plus the extent,

    x = [E(S), var(S), E(gamma), var(gamma), E(|v_r|), P90(extent)]

with unbiased variances over the frames where the track had a cluster. ``v_r`` is, in the paper
(``classify.features.speed_feature = "range_rate"``), the radial speed from the displacement of the
centroid's range between consecutive visible frames (km/h, divided by the real elapsed time, so a
missed frame does not double a speed). With ``"doppler"`` (beyond the paper) it is each
frame's wrapped Doppler of the cluster unaliased with the track's range rate
(:class:`RadialSpeedEstimator`, fed through ``TrackFeatureAccumulator(vmax_kmh=...)``): the range
displacement of a slow target is mostly centroid jitter (docs/decisions/0021). By default
(``"event"``) an ended track's value is the mean magnitude of the frames its event speed is taken from,
on the fitted alias (:meth:`RadialSpeedEstimator.event_speed_kmh`, docs/decisions/0032); live tracks
keep ``"doppler"``.
:meth:`TrackFeatureAccumulator.mean_radial_speed_kmh` is the least-squares slope of centroid range
against time (km/h, positive receding). Weighted standardisation (eq. 20) lives in
:func:`weighted_standardization`.

A "point" is one cell of the range-Doppler map at or above ``th_RD`` (:class:`MapPoints`); labels
are cluster indices ``0..L-1`` from DBSCAN (``-1`` = noise, ignored) or all ``0`` for the paper's
training signatures (thresholded, neither clustered nor tracked).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass, field, fields

import numpy as np

from edge import native
from edge.classify.calibration import DATASHEET_C_DB, DATASHEET_C_SD_DB, rcs_gain_factor
from edge.track.cylinder import Cylinder
from edge.types import FrontendInfo
from hal.waveform import SPEED_OF_LIGHT_MPS, characteristics

__all__ = [
    "FEATURE_NAMES",
    "ClusterSignatures",
    "distinct_among",
    "feature_setting_mismatches",
    "feature_settings",
    "FeatureConfig",
    "MapPoints",
    "RadialSpeedEstimator",
    "SignatureExtractor",
    "SignatureLog",
    "TrackFeatureAccumulator",
    "weighted_standardization",
]

#: event_speed_alias = "fit" judges an event's alias on its latest frames (51 s at 200 ms: longer than any passage
#: through the 24 m view; bounds the work of a track that held static clutter for minutes)
FIT_MAX_FRAMES = 256

#: the five features of eq. 19, in order, and the range extent (beyond the paper, see the module doc)
FEATURE_NAMES: tuple[str, ...] = (
    "circ_var_mean",
    "circ_var_var",
    "rcs_mean",
    "rcs_var",
    "abs_radial_speed_mean_kmh",
    "range_extent_m",
)


def feature_settings(config: "FeatureConfig") -> dict:
    """The ``classify.features`` settings that shape the feature vector (all but the board's RCS calibration, which
    refers a board to the reference set's), as a reference set records them."""
    return {f.name: getattr(config, f.name) for f in fields(config) if not f.name.startswith("rcs_calibration")}


def feature_setting_mismatches(recorded: dict, config: "FeatureConfig") -> list[str]:
    """``"key = configured (the reference set's: recorded)"`` for each setting a reference set recorded
    (:func:`feature_settings`) that the configuration sets otherwise; keys it did not record are not compared."""
    mine = feature_settings(config)
    return [f"{k} = {mine[k]!r} (the reference set's: {v!r})" for k, v in sorted(recorded.items())
            if k in mine and mine[k] != v]


def distinct_among(names, among=FEATURE_NAMES) -> bool:
    """Whether ``names`` are one or more distinct names of ``among`` (a classifier's features of the extracted ones)."""
    names = tuple(names)
    return bool(names) and len(set(names)) == len(names) and all(n in tuple(among) for n in names)


def _np_sum(x) -> float:
    """``float(np.add.reduce(np.array(x, dtype=np.float64)))`` of a short sequence of floats in plain Python, with
    the same bits: numpy adds to its identity 0.0 the pairwise sum of the values (one accumulator below 8 values,
    eight in blocks of up to 128, halves above)."""
    return 0.0 + _pairwise(x, 0, len(x))


def _pairwise(x, i: int, n: int) -> float:
    """numpy's float64 ``pairwise_sum`` of ``x[i:i + n]``."""
    if n < 8:
        s = 0.0
        for k in range(i, i + n):
            s += x[k]
        return s
    if n <= 128:
        r0, r1, r2, r3, r4, r5, r6, r7 = x[i:i + 8]
        k, end = i + 8, i + n - n % 8
        while k < end:
            r0 += x[k]
            r1 += x[k + 1]
            r2 += x[k + 2]
            r3 += x[k + 3]
            r4 += x[k + 4]
            r5 += x[k + 5]
            r6 += x[k + 6]
            r7 += x[k + 7]
            k += 8
        s = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
        while k < i + n:
            s += x[k]
            k += 1
        return s
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise(x, i, n2) + _pairwise(x, i + n2, n - n2)


def _rint(x: float) -> float:
    """``float(np.rint(x))`` of a finite float: half to even, a zero keeps the sign of ``x``."""
    q = float(round(x))
    return q if q else math.copysign(0.0, x)


def _slope_of(t: list, r: list) -> float:
    """:meth:`RadialSpeedEstimator._slope_kmh` of two lists of floats, with the same bits: the means as numpy
    sums them, the centred values element by element, numpy's (BLAS) dot products of the same arrays."""
    n = len(t)
    tm = _np_sum(t) / n
    rm = _np_sum(r) / n
    tc = np.array([v - tm for v in t])
    den = float(tc @ tc)
    if not den > 0:
        return math.nan
    return float(tc @ np.array([v - rm for v in r])) / den * 3.6


@dataclass(frozen=True)
class FeatureConfig:
    """Signature extraction (eqs. 17-19)."""

    if_corner_hz: float = field(
        default=1000.0,
        metadata={"unit": "Hz", "doc": "f_c of eq. 17: lower (high-pass) corner of the board's IF amplifier; the "
                  "paper does not give the Distance2Go's value, 1 kHz is an assumption (beat of a target at 1.1 m)",
                  "min": 0.0, "max": 1e6},
    )
    range_exponent: float = field(
        default=1.8,
        metadata={"doc": "exponent of r in eq. 17 (2 in free space; 1.8 empirically, Tavanti after [39])",
                  "min": 0.0, "max": 4.0},
    )
    rcs_calibration_db: float = field(
        default=DATASHEET_C_DB,
        metadata={"unit": "dB", "doc": "the board's RCS calibration constant C (edge.classify.calibration: a 1 m^2 "
                                       "target on boresight at 1 m reads 10^(C/20) counts); eq. 17 is referred to "
                                       "the reference set's board by 10^((C_datasheet - C) / 10)",
                  "min": 0.0, "max": 200.0},
    )
    rcs_calibration_sd_db: float = field(
        default=DATASHEET_C_SD_DB,
        metadata={"unit": "dB", "doc": "uncertainty (1 sd) of rcs_calibration_db: the datasheet's unit spread, or "
                  "what `radar-edge calibrate --rcs` measured", "min": 0.0, "max": 60.0},
    )
    rcs_calibration_source: str = field(
        default="datasheet",
        metadata={"doc": "where rcs_calibration_db comes from: datasheet (the default value) or measured (a corner "
                  "reflector, `radar-edge calibrate --rcs`)", "choices": ("datasheet", "measured")},
    )
    extent_level_db: float = field(
        default=20.0,
        metadata={"unit": "dB", "doc": "beyond the paper: a cluster's range extent spans its cells at most this far "
                  "below its strongest cell (power; relative, so it measures the body's length along the line of "
                  "sight, not its RCS)", "min": 0.0, "max": 60.0},
    )
    extent_doppler_kmh: float = field(
        default=1.0,
        metadata={"unit": "km/h", "doc": "beyond the paper: the range extent counts only the cells within this wrapped "
                  "Doppler of the cluster's strongest cell, the body's (a wheel's micro-Doppler moves its cells in "
                  "range through the range-Doppler coupling); 0 = every cell", "min": 0.0, "max": 100.0},
    )
    speed_feature: str = field(
        default="event",
        metadata={"doc": "E(|v_r|) of eq. 19 from: range_rate = the centroid's range displacement between frames "
                         "(paper), doppler = each frame's wrapped Doppler unaliased with the range rate, event = the "
                         "frames of the ended track's event speed, on its alias (event_speed_alias; live tracks: "
                         "doppler)", "choices": ("range_rate", "doppler", "event")},
    )
    event_speed: str = field(
        default="trimmed_mean",
        metadata={"doc": "mean radial speed published with an event: median of the per-frame unaliased speeds, or "
                         "trimmed_mean (default: their mean within v_max of the median)",
                  "choices": ("median", "trimmed_mean")},
    )
    event_speed_leading_edge_m: float = field(
        default=0.0,
        metadata={"unit": "m", "doc": "beyond the paper: for a track whose clusters' median range extent is at least"
                                      " this, each frame's alias comes from the range rate of the body's leading "
                                      "edge instead of the centroid's; 0 = the centroid always (default)", "min": 0.0, "max": 30.0},
    )
    event_speed_cap_range_m: float = field(
        default=10.0,
        metadata={"unit": "m", "doc": "beyond the paper: frames whose |speed| exceeds the largest |speed| of the "
                                      "frames at this range or farther by more than event_speed_cap_margin_kmh took "
                                      "a wrong alias and are left out (targets reaching event_speed_cap_min_kmh); 0 "
                                      "= off",
                  "min": 0.0, "max": 30.0},
    )
    event_speed_cap_margin_kmh: float = field(
        default=0.5,
        metadata={"unit": "km/h", "doc": "see event_speed_cap_range_m", "min": 0.0, "max": 100.0},
    )
    event_speed_cap_min_kmh: float = field(
        default=13.0,
        metadata={"unit": "km/h", "doc": "see event_speed_cap_range_m: the cap applies to targets whose far frames are at "
                  "least this fast (vehicles; faster than a jogger)", "min": 0.0, "max": 200.0},
    )
    event_speed_alias: str = field(
        default="fit",
        metadata={"doc": "beyond the paper: how the event speed's alias is chosen: fit (default) = one reference fitted"
                         " to the range history with the Doppler as slope (RadialSpeedEstimator.fit_alias), history = "
                         "against the whole history's range rate, frame = each frame's from the middle-half rate",
                  "choices": ("fit", "history", "frame")},
    )
    event_speed_alias_edge_m: float = field(
        default=3.0,
        metadata={"unit": "m", "doc": "fit and history alias: a track whose clusters' median range extent is at "
                                      "least this is also judged by its edges (history: the leading edge's range "
                                      "rate, and the faster of it and the centroid's); 0 = the centroid only",
                  "min": 0.0, "max": 30.0},
    )
    event_speed_alias_edge_clip_m: float = field(
        default=3.0,
        metadata={"unit": "m", "doc": "fit and history alias: a far edge within this of the board's largest range "
                                      "(where the beat leaves the sampled band) is left out; fit: that frame's "
                                      "centroid counts as a lower bound of the range", "min": 0.0, "max": 30.0},
    )
    event_speed_alias_tol_m: float = field(
        default=0.75,
        metadata={"unit": "m", "doc": "fit alias: a frame whose range lies farther than this (the range resolution) "
                                      "from the path its Doppler predicts is an outlier; the alias is certain when "
                                      "others miss the range history by one such frame more", "min": 0.05, "max": 10.0},
    )
    event_speed_alias_margin_kmh: float = field(
        default=3.2,
        metadata={"unit": "km/h", "doc": "history alias: the alias is certain when the trimmed mean of the unaliased"
                                         " speeds lies within this of the range rate and the track has three frames;"
                                         " otherwise the event's speed_uncertain is set", "min": 0.0, "max": 100.0},
    )
    extent_percentile: float = field(
        default=90.0,
        metadata={"unit": "%", "doc": "beyond the paper: the range_extent_m feature is this percentile of the "
                                      "track's per-frame range extents (a long body shows its full length only in "
                                      "some frames)", "min": 0.0, "max": 100.0},
    )


@dataclass(frozen=True, eq=False)
class MapPoints:
    """Cells of one range-Doppler map at or above ``th_RD``, columnar (P points).

    ``doppler_kmh`` is the wrapped radial speed of the cell in ``[-v_max, v_max)``, ``amplitude`` the
    map magnitude ``|M|``, ``range_bin``/``doppler_bin`` the cell indices (zero-padded grid), ``label``
    the cluster index (``-1`` = noise).
    """

    range_m: np.ndarray
    doppler_kmh: np.ndarray
    amplitude: np.ndarray
    range_bin: np.ndarray
    doppler_bin: np.ndarray
    label: np.ndarray

    def __post_init__(self) -> None:
        n = np.shape(self.range_m)
        for name in ("doppler_kmh", "amplitude", "range_bin", "doppler_bin", "label"):
            if np.shape(getattr(self, name)) != n:
                raise ValueError(f"MapPoints.{name} has shape {np.shape(getattr(self, name))}, expected {n}")

    @classmethod
    def empty(cls) -> "MapPoints":
        f = np.zeros(0, dtype=np.float32)
        i = np.zeros(0, dtype=np.int32)
        return cls(f, f, f, i, i, i)

    @classmethod
    def from_map(
        cls,
        magnitude: np.ndarray,
        threshold: float,
        range_m: np.ndarray,
        doppler_kmh: np.ndarray,
        label: np.ndarray | None = None,
    ) -> "MapPoints":
        """Cells of a magnitude map ``(n_range, n_doppler)`` at or above ``threshold``.

        ``range_m`` (n_range,) and ``doppler_kmh`` (n_doppler,) are the axes of the map (any bin
        order, e.g. after ``fftshift``); ``label`` defaults to 0 for every cell (the paper's training
        signatures: thresholded, not clustered).
        """
        mag = np.asarray(magnitude)
        rb, db = np.nonzero(mag >= threshold)
        lab = np.zeros(rb.size, dtype=np.int32) if label is None else np.asarray(label, dtype=np.int32)
        return cls(
            np.asarray(range_m, dtype=np.float32)[rb],
            np.asarray(doppler_kmh, dtype=np.float32)[db],
            mag[rb, db].astype(np.float32),
            rb.astype(np.int32),
            db.astype(np.int32),
            lab,
        )

    @property
    def n_clusters(self) -> int:
        return int(self.label.max()) + 1 if self.label.size else 0

    def __len__(self) -> int:
        return int(np.size(self.range_m))


@dataclass(frozen=True, eq=False)
class ClusterSignatures:
    """Per-cluster results of one frame, ``L`` rows (index = cluster label)."""

    centroid: np.ndarray  # (L, 3) (v', v'' km/h, r m) on the cylinder
    range_m: np.ndarray  # (L,) mean range of the cluster's points
    circular_variance: np.ndarray  # (L,) eq. 18
    rcs: np.ndarray  # (L,) eq. 17
    n_points: np.ndarray  # (L,) int
    doppler_kmh: np.ndarray  # (L,) amplitude-weighted circular mean of the wrapped radial speed
    # sums that make the signatures of several clusters of one frame combinable (union of their cells):
    cos_sum: np.ndarray | None = None  # (L,) sum of cos(theta) of the cells (eq. 18's zeta, real part)
    sin_sum: np.ndarray | None = None  # (L,) imaginary part
    # range span of the cells within ``extent_level_db`` of the cluster's strongest cell (m)
    range_lo_m: np.ndarray | None = None  # (L,)
    range_hi_m: np.ndarray | None = None  # (L,)
    # the same span of the cells also within ``extent_doppler_kmh`` of the strongest cell's Doppler: the body's (m)
    body_lo_m: np.ndarray | None = None  # (L,)
    body_hi_m: np.ndarray | None = None  # (L,)

    @property
    def extent_m(self) -> np.ndarray:
        """(L,) range extent of each cluster, the feature's (``body_hi_m - body_lo_m``, else ``range_hi_m -
        range_lo_m``; NaN if unknown)."""
        if self.body_lo_m is not None and self.body_hi_m is not None:
            return self.body_hi_m - self.body_lo_m
        if self.range_lo_m is None or self.range_hi_m is None:
            return np.full(len(self), np.nan)
        return self.range_hi_m - self.range_lo_m

    def __len__(self) -> int:
        return int(self.n_points.size)


class SignatureExtractor(native.KernelUser):
    """Eqs. 17-18 and cluster centroids for every cluster of a frame at once."""

    def __init__(self, config: FeatureConfig, frontend: FrontendInfo) -> None:
        self.config = config
        wf = frontend.waveform
        seg = wf.segments[0]
        self.cylinder = Cylinder(characteristics(frontend).max_radial_speed_mps * 3.6)
        self.n_samples = int(wf.n_samples)
        self.slope_hz_per_s = abs(seg.slope_hz_per_s)
        self.fb_floor_hz = seg.sample_rate_hz / (2.0 * self.n_samples)
        self.extent_ratio = float(10.0 ** (-config.extent_level_db / 20.0))  # amplitude ratio
        # cos of the largest angle on the cylinder between a cell counted in the extent and the strongest cell
        # (every cell when the Doppler gate is off or covers the whole circle)
        gate = math.pi * config.extent_doppler_kmh / self.cylinder.vmax_kmh
        self.extent_cos = np.float32(math.cos(gate) if 0.0 < gate < math.pi else -2.0)
        #: power factor referring eq. 17 to the reference set's board (rcs_calibration_db; 1 at the datasheet C)
        self.rcs_factor = rcs_gain_factor(config.rcs_calibration_db)
        # TrackFeatureAccumulator(vmax_kmh=...): E(|v_r|) from the unaliased Doppler (speed_feature = "doppler"; with
        # "event", the live tracks' value and an ended track's without event-speed frames)
        self.speed_vmax_kmh = self.cylinder.vmax_kmh if config.speed_feature in ("doppler", "event") else None
        #: the compiled cluster sums (edge/native/_survsig.pyx), None: the numpy reference (:meth:`_sums`) runs
        self.kernel = native.load("_survsig")
        self._scratch = np.empty(0, dtype=np.int32)  # the kernel's cell grid, grown to the largest bin box seen

    def beat_hz(self, range_m: np.ndarray) -> np.ndarray:
        """Beat frequency of a range (``f_b = 2 mu r / c``), floored at half an FFT bin."""
        fb = 2.0 * self.slope_hz_per_s * np.asarray(range_m, dtype=np.float64) / SPEED_OF_LIGHT_MPS
        return np.maximum(fb, self.fb_floor_hz)

    def __call__(self, points: MapPoints, n_clusters: int | None = None) -> ClusterSignatures:
        L = points.n_clusters if n_clusters is None else int(n_clusters)
        if self.kernel is not None and L > 0:
            sig = self._signatures_kernel(points, L)
            if sig is not None:
                return sig
        lab = np.asarray(points.label)
        rng = np.asarray(points.range_m, dtype=np.float32)
        amp = np.asarray(points.amplitude, dtype=np.float32)
        rb = np.asarray(points.range_bin)
        db = np.asarray(points.doppler_bin)
        dop = np.asarray(points.doppler_kmh, dtype=np.float32)
        keep = (lab >= 0) & (lab < L)
        if not keep.all():
            lab, rng, amp, rb, db, dop = lab[keep], rng[keep], amp[keep], rb[keep], db[keep], dop[keep]
        lab = lab.astype(np.intp, copy=False)
        th = self.cylinder.angle_of_speed(dop).astype(np.float32, copy=False)
        cos, sin = np.cos(th), np.sin(th)
        n, c, s, r_sum, ca, sa, lo, hi, blo, bhi = self._sums(lab, rng, amp, cos, sin, L)
        rcs = self._rcs(lab, rng, amp, rb, db, L)
        return self._finish(n, c, s, r_sum, ca, sa, lo, hi, rcs, blo, bhi)

    def _finish(self, n, c, s, r_sum, ca, sa, lo, hi, rcs, blo, bhi) -> ClusterSignatures:
        """The signatures from the per-cluster sums and eq. 17's sums ``rcs`` (modified in place)."""
        nz = np.maximum(n, 1)
        rbar = np.hypot(c, s) / nz
        circ = np.where(n > 0, 1.0 - rbar, np.nan)
        mean_r = np.where(n > 0, r_sum / nz, np.nan)
        ang = np.arctan2(s, c)
        centroid = np.stack(
            [self.cylinder.radius_kmh * np.cos(ang), self.cylinder.radius_kmh * np.sin(ang), mean_r], axis=1
        )
        if self.rcs_factor != 1.0:
            rcs *= self.rcs_factor
        rcs[n == 0] = np.nan
        dop_mean = np.where(n > 0, self.cylinder.speed_of_angle(np.arctan2(sa, ca)), np.nan)
        return ClusterSignatures(centroid, mean_r, circ, rcs, n, dop_mean, c, s, lo, hi, blo, bhi)

    def _signatures_kernel(self, points: MapPoints, L: int) -> ClusterSignatures | None:
        """:meth:`__call__` with the kernel's one pass over all points (sums and eq. 17's cells, the points outside
        ``0..L-1`` skipped there); None when no point has such a label or a bin is negative (the reference runs)."""
        rng = np.ascontiguousarray(points.range_m, dtype=np.float32)
        amp = np.ascontiguousarray(points.amplitude, dtype=np.float32)
        th = self.cylinder.angle_of_speed(np.asarray(points.doppler_kmh, dtype=np.float32)).astype(np.float32,
                                                                                                  copy=False)
        cos, sin = np.cos(th), np.sin(th)
        lab = np.ascontiguousarray(points.label, dtype=np.int32)
        rb = np.ascontiguousarray(points.range_bin, dtype=np.int32)
        db = np.ascontiguousarray(points.doppler_bin, dtype=np.int32)
        sums = np.empty((10, L))
        sel = np.empty(lab.size, dtype=np.uint8)
        args = (lab, rng, amp, cos, sin, rb, db, np.float32(self.extent_ratio), self.extent_cos, sums,
                np.empty(3 * L, dtype=np.float32), sel)
        kept = self.kernel.signature_pass(*args, self._scratch)
        if kept < -1:  # a larger bin box than any before
            self._scratch = np.empty(-2 - kept, dtype=np.int32)
            kept = self.kernel.signature_pass(*args, self._scratch)
        if kept <= 0:
            return None
        n_f, c, s, r_sum, ca, sa, lo, hi, blo, bhi = sums
        peak = sel.view(bool)
        rcs = self._rcs_sums(lab[peak].astype(np.intp), rng[peak], amp[peak], L)
        return self._finish(n_f.astype(np.intp), c, s, r_sum, ca, sa, lo, hi, rcs, blo, bhi)

    def _sums(self, lab, rng, amp, cos, sin, L) -> tuple[np.ndarray, ...]:
        """The numpy reference of the kernel's per-cluster sums: cells (int), sums of cos, sin, range (m),
        amplitude times cos and sin, and the ends of the range span and of the body's (:meth:`_extent`)."""
        n = np.bincount(lab, minlength=L)
        c = np.bincount(lab, cos, minlength=L)
        s = np.bincount(lab, sin, minlength=L)
        r_sum = np.bincount(lab, rng, minlength=L)
        ca = np.bincount(lab, amp * cos, minlength=L)
        sa = np.bincount(lab, amp * sin, minlength=L)
        peak = np.zeros(L, dtype=np.float32)
        np.maximum.at(peak, lab, amp)
        lo, hi = self._extent(lab, rng, amp, peak)
        if self.extent_cos > -1.0:
            blo, bhi = self._extent(lab, rng, amp, peak, self._near_peak_doppler(lab, amp, cos, sin, peak))
        else:
            blo, bhi = lo.copy(), hi.copy()
        return n, c, s, r_sum, ca, sa, lo, hi, blo, bhi

    def _near_peak_doppler(self, lab, amp, cos, sin, peak) -> np.ndarray:
        """Cells within ``extent_doppler_kmh`` of their cluster's strongest cell (the first of equals) on the
        cylinder (float32 cos and sin of the cells' angles; ``peak`` (L,) the clusters' largest amplitudes); every
        cell of a cluster without a positive amplitude."""
        L = peak.size
        at_peak = np.flatnonzero((amp == peak[lab]) & (amp > 0))
        ks, first = np.unique(lab[at_peak], return_index=True)
        pk = np.zeros(L, dtype=np.intp)
        pk[ks] = at_peak[first]
        return ((cos * cos[pk[lab]] + sin * sin[pk[lab]]) >= self.extent_cos) | (peak[lab] <= 0)

    def _extent(self, lab, rng, amp, peak, cells=None) -> tuple[np.ndarray, np.ndarray]:
        """Range span of each cluster's cells within ``extent_level_db`` of its strongest cell (``peak`` (L,) the
        clusters' largest amplitudes; of the cells where ``cells`` is true, when given)."""
        L = peak.size
        lo = np.full(L, np.nan)
        hi = np.full(L, np.nan)
        if lab.size == 0:
            return lo, hi
        strong = amp >= peak[lab] * np.float32(self.extent_ratio)
        if cells is not None:
            strong &= cells
        ls, rs = lab[strong], rng[strong].astype(np.float64)
        lo[:] = np.inf
        hi[:] = -np.inf
        np.minimum.at(lo, ls, rs)
        np.maximum.at(hi, ls, rs)
        empty = ~np.isfinite(lo)
        lo[empty] = np.nan
        hi[empty] = np.nan
        return lo, hi

    def _rcs(self, lab, rng, amp, rb, db, L) -> np.ndarray:
        """Eq. 17: sum over the local range peaks of every Doppler column of each cluster.

        The range neighbours of a cell are looked up on a dense (range bin, Doppler bin) grid of the
        frame's cells (no sort): a neighbour counts only if it is a cell of the same cluster.
        """
        if lab.size == 0:
            return np.zeros(L)
        rb = rb.astype(np.int64, copy=False)
        db = db.astype(np.int64, copy=False)
        nd = int(db.max()) + 1
        size = (int(rb.max()) + 2) * nd
        key = rb * nd + db
        amp_g = np.full(size, -np.inf, dtype=np.float32)
        lab_g = np.full(size, -1, dtype=np.intp)
        amp_g[key] = amp
        lab_g[key] = lab
        lo_k = np.maximum(key - nd, 0)
        hi_k = key + nd
        has_lo = (rb > 0) & (lab_g[lo_k] == lab)
        has_hi = lab_g[hi_k] == lab
        # a peak is above its lower neighbour and not below its upper one (one peak per plateau)
        peak = (~has_lo | (amp > amp_g[lo_k])) & (~has_hi | (amp >= amp_g[hi_k]))
        return self._rcs_sums(lab[peak], rng[peak], amp[peak], L)

    def _rcs_sums(self, lab, rng, amp, L) -> np.ndarray:
        """Eq. 17's per-cluster sums over the selected cells (labels, ranges and amplitudes of those cells)."""
        r = rng.astype(np.float64)
        fb = self.beat_hz(r)
        fc = self.config.if_corner_hz
        comp = np.sqrt(fc * fc + fb * fb) / fb
        val = np.power(np.maximum(r, 0.0), self.config.range_exponent) / self.n_samples * (amp * comp) ** 2
        return np.bincount(lab, val, minlength=L)


class SignatureLog:
    """Per-frame cluster sums of a track (bounded), so that the signatures of several tracks of one
    target can be united frame by frame: the eqs. 17-19 features of the union of their cells.

    ``add(frame, t_s, n, cos_sum, sin_sum, rcs, range_sum, range_lo_m, range_hi_m, doppler_kmh)`` (the span the extent
    feature measures, the body's: :attr:`ClusterSignatures.body_lo_m`) once
    per frame where the track has a cluster; :meth:`extend` appends another track's rows (a fragment of
    the same target); :meth:`accumulator` sums the rows of each frame (cells, eq. 18's resultant, eq.
    17's quantity, ranges: the union of the clusters; the range extent spans the lowest ``range_lo_m``
    to the highest ``range_hi_m`` of the frame's rows, each relative to its own cluster's peak; the
    Doppler is that of the frame's largest cluster) and feeds them, in time order, to a
    :class:`TrackFeatureAccumulator`. With one row per frame it gives exactly the track's own features.
    """

    __slots__ = ("_rows", "max_rows")

    def __init__(self, max_rows: int = 4096) -> None:
        self._rows: deque[tuple[float, ...]] = deque(maxlen=max_rows)
        self.max_rows = int(max_rows)

    def __len__(self) -> int:
        return len(self._rows)

    def add(self, frame: int, t_s: float, n: float, cos_sum: float, sin_sum: float, rcs: float, range_sum: float,
            range_lo_m: float = math.nan, range_hi_m: float = math.nan, doppler_kmh: float = math.nan) -> None:
        self._rows.append((int(frame), float(t_s), float(n), float(cos_sum), float(sin_sum), float(rcs),
                           float(range_sum), float(range_lo_m), float(range_hi_m), float(doppler_kmh)))

    def extend(self, other: "SignatureLog") -> None:
        self._rows.extend(other._rows)

    def frames(self) -> int:
        """Distinct frames with rows."""
        return len({r[0] for r in self._rows})

    def accumulator(self, extent_percentile: float = 90.0, vmax_kmh: float | None = None) -> "TrackFeatureAccumulator":
        acc = TrackFeatureAccumulator(extent_percentile, vmax_kmh=vmax_kmh)
        if not self._rows:
            return acc
        a = np.array(self._rows, dtype=np.float64)
        a = a[np.lexsort((a[:, 2], a[:, 0]))]  # by frame, then cell count: a frame's largest cluster last
        key = a[:, 0]
        start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        t = a[start, 1]
        sums = np.add.reduceat(a[:, 2:7], start, axis=0)  # n, cos, sin, rcs, range per frame
        lo = np.fmin.reduceat(a[:, 7], start)
        hi = np.fmax.reduceat(a[:, 8], start)
        dop = a[np.r_[start[1:] - 1, len(a) - 1], 9]
        n = sums[:, 0]
        circ = 1.0 - np.hypot(sums[:, 1], sums[:, 2]) / n
        r = sums[:, 4] / n
        for k in range(t.size):
            acc.add(t[k], circ[k], sums[k, 3], r[k], hi[k] - lo[k], dop[k])
        return acc


class TrackFeatureAccumulator:
    """Running statistics of one track's per-frame signatures -> the feature vector (eq. 19 + extent).

    ``add(t_s, circular_variance, rcs, range_m, extent_m)`` once per frame where the track has a
    cluster (``extent_m`` NaN = not measured). Memory is bounded: Welford means/variances and
    least-squares sums, plus the last ``max_frames`` extents for their ``extent_percentile``.
    """

    __slots__ = ("n", "_s_mean", "_s_m2", "_g_mean", "_g_m2", "_t0", "_last_t", "_last_r",
                 "_abs_v_sum", "_n_v", "_st", "_sr", "_stt", "_str", "first_t_s", "last_t_s", "_ext",
                 "extent_percentile", "_doppler", "_features")

    def __init__(self, extent_percentile: float = 90.0, max_frames: int = 4096, vmax_kmh: float | None = None) -> None:
        self.n = 0
        self._s_mean = self._s_m2 = self._g_mean = self._g_m2 = 0.0
        self._t0 = self._last_t = self._last_r = 0.0
        self._abs_v_sum = 0.0
        self._n_v = 0
        self._st = self._sr = self._stt = self._str = 0.0
        self.first_t_s = self.last_t_s = math.nan
        self._ext: deque[float] = deque(maxlen=int(max_frames))
        self.extent_percentile = float(extent_percentile)
        # with vmax_kmh: E(|v_r|) from the unaliased Doppler of the frames given one (see FeatureConfig)
        self._doppler = RadialSpeedEstimator(vmax_kmh, max_frames=max_frames) if vmax_kmh else None
        self._features: np.ndarray | None = None  # features() of the frames as they are (None: not computed)

    def add(self, t_s: float, circular_variance: float, rcs: float, range_m: float,
            extent_m: float = math.nan, doppler_kmh: float = math.nan) -> None:
        t_s, s, g, r = float(t_s), float(circular_variance), float(rcs), float(range_m)
        self._features = None
        if math.isfinite(extent_m):
            self._ext.append(float(extent_m))
        if self._doppler is not None:
            self._doppler.add(t_s, r, float(doppler_kmh))
        if self.n == 0:
            self._t0 = t_s
            self.first_t_s = t_s
        elif t_s > self._last_t:
            v_kmh = (r - self._last_r) / (t_s - self._last_t) * 3.6
            self._abs_v_sum += abs(v_kmh)
            self._n_v += 1
        self.n += 1
        d = s - self._s_mean
        self._s_mean += d / self.n
        self._s_m2 += d * (s - self._s_mean)
        d = g - self._g_mean
        self._g_mean += d / self.n
        self._g_m2 += d * (g - self._g_mean)
        tr = t_s - self._t0
        self._st += tr
        self._sr += r
        self._stt += tr * tr
        self._str += tr * r
        self._last_t, self._last_r = t_s, r
        self.last_t_s = t_s

    def extent_m(self) -> float:
        """``extent_percentile`` of the per-frame range extents (linear interpolation between order
        statistics, as ``np.percentile``'s default; a sort of a track's few hundred values in plain
        Python: called every frame for the provisional class of each live track); NaN if none."""
        if not self._ext:
            return math.nan
        e = sorted(self._ext)
        pos = (len(e) - 1) * self.extent_percentile / 100.0
        lo = int(pos)
        hi = min(lo + 1, len(e) - 1)
        return e[lo] + (e[hi] - e[lo]) * (pos - lo)

    def features(self) -> np.ndarray:
        """``(6,)`` float64 in :data:`FEATURE_NAMES` order; NaN where fewer than two frames (the
        variances and the speed) or no extent was measured. Kept until the next :meth:`add` (the
        pipeline asks every frame for each live track's provisional class, also of tracks that had no
        cluster); a new array each call."""
        if self._features is None:
            self._features = self._compute_features()
        return self._features.copy()

    def _compute_features(self) -> np.ndarray:
        n = self.n
        var_s = self._s_m2 / (n - 1) if n > 1 else math.nan
        var_g = self._g_m2 / (n - 1) if n > 1 else math.nan
        v = self._abs_v_sum / self._n_v if self._n_v else math.nan
        if self._doppler is not None and len(self._doppler) >= 2:
            v = self._doppler.mean_abs_speed_kmh()
        return np.array([self._s_mean if n else math.nan, var_s, self._g_mean if n else math.nan, var_g, v,
                         self.extent_m()])

    def mean_radial_speed_kmh(self) -> float:
        """Least-squares slope of centroid range vs time (km/h, positive receding); NaN below 2 frames."""
        n = self.n
        den = n * self._stt - self._st * self._st
        if n < 2 or den <= 0:
            return math.nan
        return (n * self._str - self._st * self._sr) / den * 3.6


def plain_median(values) -> float:
    """``float(np.median(values))`` of a short non-empty sequence of finite numbers in plain Python, with the same
    bits: the middle value, or the middle two summed from 0.0 (as numpy's mean does) and halved."""
    s = sorted(values)
    m = len(s) // 2
    if len(s) % 2:
        return float(s[m])
    return (0.0 + s[m - 1] + s[m]) / 2


def fit_candidates_reference(t: np.ndarray, vw: np.ndarray, refs: np.ndarray, obs: list[np.ndarray], period: float,
                             static_kmh: float, tol2: float, vmax_kmh: float,
                             margin2: float, lower: np.ndarray | None = None) -> tuple[int, bool, np.ndarray]:
    """The candidate search of :meth:`RadialSpeedEstimator.fit_alias` (numpy reference of the ``_aliasfit`` kernel):
    ``(best, rivals_clear, on_path)``, the index of the least-cost candidate of ``refs``, whether every rival costs
    at least ``margin2`` more, and the best candidate's frames on its path. ``lower`` (observables, frames) bool:
    where an observable is only a lower bound of the body's range, a frame nearer than the path costs nothing."""
    n = t.size
    # every candidate at once: (candidates, frames)
    speeds = vw[None, :] + period * np.round((refs[:, None] - vw[None, :]) / period)
    path = np.zeros_like(speeds)
    np.cumsum(0.5 * (speeds[:, 1:] + speeds[:, :-1]) * np.diff(t)[None, :], axis=1, out=path[:, 1:])
    path /= 3.6
    # a candidate's frames at zero Doppler do not vote (static clutter a track held says nothing of a mover's
    # alias), unless fewer than three of its frames move (a target crossing the beam at zero radial speed)
    moving = np.abs(speeds) >= static_kmh
    moving |= (moving.sum(axis=1) < 3)[:, None]
    costs = np.zeros(refs.size)
    frame_e2 = np.full(speeds.shape, tol2)  # per frame: the best fit of the observables (on the path below tol2)
    for k, x in enumerate(obs):
        ok = np.isfinite(x)[None, :] & moving
        res = np.where(ok, x[None, :] - path, np.nan)
        m_ok = ok.sum(axis=1)
        # the offset: one of the usable frames' residuals (at most 48 of them, spread over their range)
        if n <= 48:
            off = res
        else:
            off = np.nanquantile(np.where(m_ok[:, None] > 0, res, 0.0), np.linspace(0.0, 1.0, 48), axis=1).T
        d = res[:, None, :] - off[:, :, None]  # (candidates, offsets, frames)
        if lower is not None and lower[k].any():
            d = np.where(lower[k][None, None, :], np.maximum(d, 0.0), d)
        e2 = np.minimum(d ** 2, tol2)
        e2 = np.where(ok[:, None, :], e2, tol2)
        c = np.where(np.isfinite(off), e2.sum(axis=2), np.inf)  # frames not usable cost an outlier's
        b = np.argmin(c, axis=1)
        e2b = e2[np.arange(refs.size), b]
        costs += np.where(m_ok > 0, e2b.sum(axis=1), tol2 * n)
        frame_e2 = np.minimum(frame_e2, e2b)
    on_path = frame_e2 < tol2
    best = int(np.argmin(costs))
    # rivals: the candidates that give the best one's frames on its path another alias (most of them)
    mine = on_path[best] if on_path[best].any() else np.ones(n, dtype=bool)
    rivals = np.abs(np.median(speeds[:, mine] - speeds[best, mine], axis=1)) >= vmax_kmh
    gap = float(np.min(costs[rivals]) - costs[best]) if rivals.any() else math.inf
    return best, gap >= margin2, on_path[best]


class RadialSpeedEstimator:
    """Unaliased radial speed of a track from its wrapped Doppler and its range history.

    The Doppler of a cluster (amplitude-weighted circular mean; 0.04 km/h bins) is precise but
    aliased modulo ``2 v_max`` (10.7 km/h on the Distance2Go); the range rate of the centroid is
    unambiguous but noisy, and biased low while an extended target enters the beam (more of the body
    comes into view behind its front) and while it passes beside the radar (the radial speed falls to
    zero and changes sign). The reference rate ``rho`` is therefore the least-squares slope of the
    centroid range over the *middle half* of the track's frames (all frames below eight), and each
    frame's speed is its wrapped Doppler moved by the multiple of ``2 v_max`` nearest to ``rho``:
    ``v = v_w + 2 v_max round((rho - v_w) / (2 v_max))``, right while the truth is within ``v_max``
    (about 5 km/h) of ``rho``.

    * :meth:`mean_radial_speed_kmh`: the median of the per-frame speeds (robust to the frames of a
      target passing beside the radar and to a wrong alias in a frame or two);
    * :meth:`current_radial_speed_kmh`: the latest frame's speed with ``rho`` from the last
      ``window_s`` seconds (at least three frames).

    History is bounded (``max_frames``, oldest dropped).
    """

    def __init__(self, vmax_kmh: float, window_s: float = 1.2, max_frames: int = 1024) -> None:
        self.vmax_kmh = float(vmax_kmh)
        self.window_s = float(window_s)
        self._t: deque[float] = deque(maxlen=max_frames)
        self._r: deque[float] = deque(maxlen=max_frames)
        self._v: deque[float] = deque(maxlen=max_frames)
        self._lo: deque[float] = deque(maxlen=max_frames)
        self._hi: deque[float] = deque(maxlen=max_frames)
        self._current: float | None = None  # current_radial_speed_kmh of the frames as they are (None: not known)

    def add(self, t_s: float, range_m: float, doppler_wrapped_kmh: float, range_lo_m: float = math.nan,
            range_hi_m: float = math.nan) -> None:
        """One frame: the cluster's centroid range, wrapped Doppler and (optional) range extent."""
        if math.isfinite(range_m) and math.isfinite(doppler_wrapped_kmh) and (not self._t or t_s > self._t[-1]):
            self._t.append(float(t_s))
            self._r.append(float(range_m))
            self._v.append(float(doppler_wrapped_kmh))
            self._lo.append(float(range_lo_m))
            self._hi.append(float(range_hi_m))
            self._current = None

    def __len__(self) -> int:
        return len(self._t)

    def prepend(self, earlier: "RadialSpeedEstimator") -> None:
        """Put the frames of ``earlier`` (another track of the same target, ended before this one
        started) before this one's; frames not earlier than this one's first are ignored."""
        t0 = self._t[0] if self._t else math.inf
        self._current = None
        rows = [row for row in zip(earlier._t, earlier._r, earlier._v, earlier._lo, earlier._hi) if row[0] < t0]
        rows += list(zip(self._t, self._r, self._v, self._lo, self._hi))
        rows = rows[-self._t.maxlen:] if self._t.maxlen else rows
        cols = (self._t, self._r, self._v, self._lo, self._hi)
        for c in cols:
            c.clear()
        for row in rows:
            for c, x in zip(cols, row):
                c.append(x)

    def merge(self, other: "RadialSpeedEstimator") -> None:
        """Add the frames of ``other`` (another part of the same body) at times this one has no frame of; where both
        have one, this one's centroid and Doppler stay and the range extent becomes the union of the two parts'."""
        self._current = None
        theirs = {t: (lo, hi) for t, lo, hi in zip(other._t, other._lo, other._hi)}
        own = []
        for t, r, v, lo, hi in zip(self._t, self._r, self._v, self._lo, self._hi):
            if t in theirs:
                lo, hi = float(np.fmin(lo, theirs[t][0])), float(np.fmax(hi, theirs[t][1]))
            own.append((t, r, v, lo, hi))
        have = set(self._t)
        rows = [row for row in zip(other._t, other._r, other._v, other._lo, other._hi) if row[0] not in have]
        rows = sorted(rows + own)
        rows = rows[-self._t.maxlen:] if self._t.maxlen else rows
        cols = (self._t, self._r, self._v, self._lo, self._hi)
        for c in cols:
            c.clear()
        for row in rows:
            for c, x in zip(cols, row):
                c.append(x)

    def extents(self) -> tuple[np.ndarray, np.ndarray]:
        """``(range_lo_m, range_hi_m)`` of every frame kept (NaN where not given)."""
        return np.array(self._lo, dtype=np.float64), np.array(self._hi, dtype=np.float64)

    def wrapped(self) -> np.ndarray:
        """The wrapped Doppler of every frame kept (km/h, oldest first)."""
        return np.array(self._v, dtype=np.float64)

    def range_rate_kmh(self) -> float:
        """Theil-Sen slope of the centroid range over the whole history (km/h); NaN below two frames."""
        t, r = self.history()
        return self._theil_sen_kmh(t, r)

    def history(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t_s, range_m)`` of every frame kept (float64 arrays, oldest first)."""
        return np.array(self._t, dtype=np.float64), np.array(self._r, dtype=np.float64)

    def first(self) -> tuple[float, float, float]:
        """``(t_s, range_m, doppler_wrapped_kmh)`` of the first frame (NaNs when empty)."""
        return (self._t[0], self._r[0], self._v[0]) if self._t else (math.nan, math.nan, math.nan)

    def last(self) -> tuple[float, float, float]:
        """``(t_s, range_m, doppler_wrapped_kmh)`` of the last frame (NaNs when empty)."""
        return (self._t[-1], self._r[-1], self._v[-1]) if self._t else (math.nan, math.nan, math.nan)

    @staticmethod
    def _slope_kmh(t: np.ndarray, r: np.ndarray) -> float:
        tc = t - t.mean()
        den = float(tc @ tc)
        return float(tc @ (r - r.mean())) / den * 3.6 if den > 0 else math.nan

    @classmethod
    def _middle_slope_kmh(cls, t: np.ndarray, r: np.ndarray) -> float:
        n = t.size
        if n < 2:
            return math.nan
        if n >= 8:
            lo, hi = n // 4, n - n // 4
            t, r = t[lo:hi], r[lo:hi]
        return cls._slope_kmh(t, r)

    def reference_rate_kmh(self, leading_edge_m: float = 0.0) -> float:
        """Least-squares range rate over the middle half of the frames (km/h); NaN below two.

        With ``leading_edge_m`` > 0 and a median range extent of the frames at least that long, the
        rate is that of the leading edge (the far edge when the centroid recedes, the near edge when
        it approaches) over the frames where the extent is known: a long body seen from one end
        shows more of itself every frame, so its centroid lags its front."""
        t, r = np.array(self._t), np.array(self._r)
        rho = self._middle_slope_kmh(t, r)
        if leading_edge_m > 0 and math.isfinite(rho):
            lo, hi = np.array(self._lo), np.array(self._hi)
            ext = hi - lo
            known = np.isfinite(ext)
            if np.count_nonzero(known) >= 2 and float(np.median(ext[known])) >= leading_edge_m:
                edge = hi if rho > 0 else lo
                lead = self._middle_slope_kmh(t[known], edge[known])
                if math.isfinite(lead):
                    return lead
        return rho

    def dealias(self, doppler_wrapped_kmh, reference_kmh: float) -> np.ndarray:
        period = 2.0 * self.vmax_kmh
        vw = np.asarray(doppler_wrapped_kmh, dtype=np.float64)
        return vw + period * np.round((reference_kmh - vw) / period)

    def dealias_one(self, doppler_wrapped_kmh: float, reference_kmh: float) -> float:
        """:meth:`dealias` of one frame in plain Python (the same rounding, half to even, and the same value)."""
        period = 2.0 * self.vmax_kmh
        vw = float(doppler_wrapped_kmh)
        q = (reference_kmh - vw) / period
        return vw + period * (round(q) if math.isfinite(q) else q)

    def speeds_kmh(self, leading_edge_m: float = 0.0) -> np.ndarray:
        """Per-frame unaliased radial speeds (km/h, positive receding); empty below two frames
        (``leading_edge_m``: see :meth:`reference_rate_kmh`)."""
        rho = self.reference_rate_kmh(leading_edge_m)
        if not math.isfinite(rho):
            return np.zeros(0)
        return self.dealias(np.array(self._v), rho)

    def capped_speeds_kmh(self, leading_edge_m: float = 0.0, cap_range_m: float = 0.0, cap_margin_kmh: float = 0.5,
                          cap_min_kmh: float = 13.0) -> np.ndarray:
        """:meth:`speeds_kmh` without the frames faster than the target can be: with ``cap_range_m`` > 0
        and at least two frames at that range or farther whose largest |speed| ``c`` is at least
        ``cap_min_kmh``, the frames with |speed| above ``c + cap_margin_kmh`` (a straight-moving target's
        radial speed never exceeds its speed, which the far frames show: such a frame took a wrong
        alias) are left out (all kept if none would remain)."""
        return self._capped(self.speeds_kmh(leading_edge_m), cap_range_m, cap_margin_kmh, cap_min_kmh)

    def _capped(self, v: np.ndarray, cap_range_m: float, cap_margin_kmh: float, cap_min_kmh: float,
                ranges: np.ndarray | None = None) -> np.ndarray:
        if cap_range_m <= 0 or v.size == 0:
            return v
        far = (np.array(self._r) if ranges is None else ranges) >= cap_range_m  # the centroid ranges of v's frames
        if np.count_nonzero(far) < 2:
            return v
        cap = float(np.max(np.abs(v[far])))
        if not cap >= cap_min_kmh:
            return v
        keep = np.abs(v) <= cap + cap_margin_kmh
        return v[keep] if keep.any() else v

    def mean_radial_speed_kmh(self, leading_edge_m: float = 0.0, **cap) -> float:
        """Median of the per-frame speeds (``cap``: the keywords of :meth:`capped_speeds_kmh`)."""
        v = self.capped_speeds_kmh(leading_edge_m, **cap)
        return float(np.median(v)) if v.size else math.nan

    def trimmed_mean_radial_speed_kmh(self, leading_edge_m: float = 0.0, **cap) -> float:
        """Mean of the per-frame speeds (:meth:`speeds_kmh`) within ``vmax_kmh`` of their median.
        Unlike the median it is not pulled towards the far frames of a target whose radial speed
        grows with range (a car receding past the radar), so it estimates the mean radial speed over
        the frames seen; the trim drops frames far from the bulk when the reference rate lies off it.
        ``leading_edge_m``: :meth:`reference_rate_kmh`; ``cap``: :meth:`capped_speeds_kmh`."""
        v = self.capped_speeds_kmh(leading_edge_m, **cap)
        if not v.size:
            return math.nan
        keep = np.abs(v - np.median(v)) <= self.vmax_kmh
        return float(np.mean(v[keep]))

    @staticmethod
    def _theil_sen_kmh(t: np.ndarray, r: np.ndarray) -> float:
        """Median of the pairwise slopes of ``r`` against ``t`` (km/h; robust to a frame or two whose cluster
        lost or gained part of the body); NaN below two frames."""
        if t.size < 2:
            return math.nan
        i, j = np.triu_indices(t.size, 1)
        dt = t[j] - t[i]
        ok = dt > 0
        return float(np.median((r[j] - r[i])[ok] / dt[ok])) * 3.6 if ok.any() else math.nan

    def history_alias(self, leading_edge_m: float = 3.0, margin_kmh: float = 3.2, edge_limit_m: float = math.inf
                      ) -> tuple[np.ndarray, float, bool]:
        """Per-frame unaliased speeds against one reference for the whole history: ``(speeds_kmh,
        range_rate_kmh, certain)``.

        The reference is the track's range rate over its whole life, re-decided from all frames kept: the
        least-squares slope over the middle half of the frames (:meth:`reference_rate_kmh`; the ends are where the
        radial speed of a target passing beside the radar turns) of the centroid range and, for a body whose
        median range extent is at least ``leading_edge_m``, of its leading edge (the far edge receding, the near
        edge approaching; a far edge beyond ``edge_limit_m`` is left out: near the board's largest range the body's
        far end is cut off, and the edge stops moving). While a long vehicle enters or leaves the 24 m
        view its centroid lags its front, so of the two the faster one in the centroid's direction is taken.
        Each frame's Doppler takes the alias nearest to it (``v = v_w + 2 v_max round((rho - v_w) / 2 v_max)``).
        The alias is *certain* when the trimmed mean of those speeds lies within ``margin_kmh`` of the range
        rate (an offset of ``v_max``, half an alias step, would be a coin toss) and the history has at least
        three frames; otherwise the event flags its speed as uncertain. Empty speeds and NaN below two frames."""
        n = len(self._t)
        if n < 2:
            return np.zeros(0), math.nan, False
        t, r = np.array(self._t), np.array(self._r)
        rho_c = self._middle_slope_kmh(t, r)
        rho = rho_c
        if leading_edge_m > 0 and math.isfinite(rho_c):
            lo, hi = np.array(self._lo), np.array(self._hi)
            known = np.isfinite(hi - lo)
            if np.count_nonzero(known) >= 3 and float(np.median((hi - lo)[known])) >= leading_edge_m:
                edge = hi if rho_c > 0 else lo
                use = known & (edge <= edge_limit_m) if rho_c > 0 else known
                rho_e = self._middle_slope_kmh(t[use], edge[use]) if np.count_nonzero(use) >= 3 else math.nan
                if math.isfinite(rho_e) and rho_e * rho_c > 0 and abs(rho_e) > abs(rho_c):
                    rho = rho_e
        if not math.isfinite(rho):
            return np.zeros(0), math.nan, False
        v = self.dealias(np.array(self._v), rho)
        keep = np.abs(v - np.median(v)) <= self.vmax_kmh
        certain = n >= 3 and abs(float(np.mean(v[keep])) - rho) <= margin_kmh
        return v, rho, certain

    def fit_alias(self, edge_m: float = 3.0, tol_m: float = 0.75, edge_limit_m: float = math.inf,
                  static_kmh: float = 1.5, margin_frames: float = 1.0, window_steps: float = 1.0,
                  last_frames: int = 0, around_kmh: float = math.nan) -> tuple[np.ndarray, float, bool, np.ndarray]:
        """Per-frame unaliased speeds from one reference fitted jointly to the range history, with the wrapped
        Doppler as the slope: ``(speeds_kmh, reference_kmh, certain, on_path)``.

        Each candidate reference ``V`` (a grid of a quarter alias step through the circular mean of the wrapped
        Doppler, within ``window_steps`` alias steps of the Theil-Sen range rate of one of the observables below over
        all frames or over those whose wrapped Doppler is not below ``static_kmh``)
        unaliases each frame (``u_i``, the alias nearest ``V``) and predicts the range path by integrating ``u``
        over the frames' times (trapezoids). The path is laid on each observable of the body at the offset that
        fits it best, and each frame costs ``min(e^2, tol_m^2)``: a frame off the path by more than the range
        resolution is an outlier (a merge with clutter, a fragment), whatever its size. The observables are the
        centroid and, for a body whose median range extent is at least ``edge_m``, also its near and far edges:
        while a long body enters or leaves the view one of its ends moves at its speed and its centroid lags
        (more of it comes into view every frame). A far edge beyond ``edge_limit_m`` (cut off at the board's
        largest range) is left out, and in such a frame the centroid is only a lower bound of the body's range: a
        path beyond it costs nothing there (the body's far part is not in the map). A frame whose ``|u|`` is below
        ``static_kmh`` does not vote for that candidate when at least three others move under it: static clutter a
        track held has zero Doppler and no range rate, and says nothing of a mover's alias (a target crossing the
        beam at zero radial speed keeps its frames). The candidate of least total cost wins; it is *certain* when
        at least three frames lie on its path and every candidate that gives most of those frames another alias
        costs at least ``margin_frames`` outlier frames more. ``on_path`` marks the frames on the winner's path
        (the target's; the others are outliers). ``last_frames`` > 0: the latest frames only; ``around_kmh``: the
        window around this speed instead of the range rates (a live track's current speed). Empty speeds and NaN
        below two frames."""
        n = len(self._t)
        if n < 2:
            return np.zeros(0), math.nan, False, np.zeros(0, dtype=bool)
        k0 = max(0, n - last_frames) if last_frames > 0 else 0
        cols = (self._t, self._v, self._r, self._lo, self._hi)
        if k0 == 0:
            t, vw, r, lo, hi = (np.array(c, dtype=np.float64) for c in cols)
        else:  # the latest frames only, without copying a long history
            t, vw, r, lo, hi = (np.fromiter(itertools.islice(c, k0, n), dtype=np.float64, count=n - k0) for c in cols)
        n = t.size
        period = 2.0 * self.vmax_kmh
        ang = vw * (2.0 * math.pi / period)
        # np.mean's sum and division, without its wrapper
        m = math.atan2(float(np.add.reduce(np.sin(ang))) / n,
                       float(np.add.reduce(np.cos(ang))) / n) * (period / (2.0 * math.pi))
        extent = hi - lo
        known = np.isfinite(extent)
        obs = [r]
        if edge_m > 0 and np.count_nonzero(known) >= 3 and plain_median(extent[known].tolist()) >= edge_m:
            obs += [np.where(known, lo, np.nan), np.where(known & (hi <= edge_limit_m), hi, np.nan)]
        # a cluster whose far edge lies beyond edge_limit_m is cut off at the board's largest range: its centroid
        # is nearer than the body's, a lower bound only
        lower = np.zeros((len(obs), n), dtype=np.uint8)
        lower[0] = known & (hi > edge_limit_m)
        rates = [float(around_kmh)] if math.isfinite(around_kmh) else []
        doppler = np.abs(vw) >= static_kmh  # frames not at zero Doppler (of a track that held clutter a while)
        for x in obs if not rates else ():
            for part in (np.isfinite(x), np.isfinite(x) & doppler):
                rates.append(self._theil_sen_kmh(t[part], x[part]))
        rates = [q for q in rates if math.isfinite(q)]
        if not rates:
            return np.zeros(0), math.nan, False, np.zeros(0, dtype=bool)
        grid = period / 4.0
        span = min(window_steps * period, 200.0)  # km/h; a wider window is all road speeds
        j_lo = math.floor((min(rates) - span - m) / grid)
        j_hi = math.ceil((max(rates) + span - m) / grid)
        refs = m + grid * np.arange(j_lo, j_hi + 1)
        near = np.zeros(refs.size, dtype=bool)
        for q in rates:
            near |= np.abs(refs - q) <= span
        refs = refs[near]
        tol2 = tol_m * tol_m
        kernel = native.load("_aliasfit") if n <= 48 else None
        if kernel is not None:
            on = np.empty(n, dtype=np.uint8)
            best, clear = kernel.fit_candidates(t, vw, refs, np.array(obs), lower, period, static_kmh, tol2,
                                                self.vmax_kmh, margin_frames * tol2, on)
            on_path = on.view(np.bool_)
        else:
            best, clear, on_path = fit_candidates_reference(t, vw, refs, obs, period, static_kmh, tol2, self.vmax_kmh,
                                                            margin_frames * tol2, lower.view(np.bool_))
        rho = float(refs[best])
        certain = n >= 3 and int(np.count_nonzero(on_path)) >= 3 and clear
        return self.dealias(vw, rho), rho, certain, on_path

    def event_speed_kmh(self, alias: str = "history", statistic: str = "trimmed_mean", leading_edge_m: float = 0.0,
                        alias_edge_m: float = 3.0, alias_margin_kmh: float = 3.2, edge_limit_m: float = math.inf,
                        alias_tol_m: float = 0.75, abs_mean: bool = False, **cap) -> tuple:
        """The mean radial speed of the passage (km/h) and whether its alias is certain.

        ``alias = "history"``: one alias for the whole history (:meth:`history_alias` with ``alias_edge_m`` and
        ``alias_margin_kmh``, ``edge_limit_m``); ``"fit"``: one reference fitted to the range history with the
        Doppler as its slope (:meth:`fit_alias` with ``alias_edge_m``, ``alias_tol_m`` and ``edge_limit_m`` over the
        latest :data:`FIT_MAX_FRAMES` frames; the speeds of the frames on its path, from three on); ``"frame"``: each frame's alias from the
        middle-half range rate (:meth:`speeds_kmh` with ``leading_edge_m``; certain from three frames on). ``statistic``: ``median`` or
        ``trimmed_mean`` (within ``v_max`` of the median) of the per-frame speeds left by the cap (``cap``: the
        keywords of :meth:`capped_speeds_kmh`). With ``abs_mean``, a third value: the mean of those speeds'
        magnitudes (the ``event`` speed feature; NaN when none)."""
        if alias == "history":
            v, _, certain = self.history_alias(alias_edge_m, alias_margin_kmh, edge_limit_m)
        elif alias == "fit":
            v, _, certain, on_path = self.fit_alias(alias_edge_m, alias_tol_m, edge_limit_m,
                                                    last_frames=FIT_MAX_FRAMES)
            ranges = np.array(self._r)[len(self._r) - v.size:]
            if np.count_nonzero(on_path) >= 3:  # the target's frames (off the path: clutter, fragments)
                v, ranges = v[on_path], ranges[on_path]
        else:
            v, certain = self.speeds_kmh(leading_edge_m), len(self) >= 3
        v = self._capped(v, cap.get("cap_range_m", 0.0), cap.get("cap_margin_kmh", 0.5), cap.get("cap_min_kmh", 13.0),
                         ranges if alias == "fit" else None)
        if not v.size:
            return (math.nan, False, math.nan) if abs_mean else (math.nan, False)
        if statistic == "median":
            out = float(np.median(v))
        else:
            keep = np.abs(v - np.median(v)) <= self.vmax_kmh
            out = float(np.mean(v[keep]))
        return (out, certain, float(np.mean(np.abs(v)))) if abs_mean else (out, certain)

    def mean_abs_speed_kmh(self) -> float:
        """``float(np.mean(np.abs(self.speeds_kmh())))`` (the tracks' ``E(|v_r|)`` feature) with fewer numpy
        calls and the same bits (the reference rate by :func:`_slope_of`); NaN below two frames."""
        n = len(self._t)
        t, r = list(self._t), list(self._r)
        if n >= 8:
            lo, hi = n // 4, n - n // 4
            t, r = t[lo:hi], r[lo:hi]
        rho = _slope_of(t, r) if n >= 2 else math.nan
        if not math.isfinite(rho):
            return math.nan
        period = 2.0 * self.vmax_kmh
        vw = np.array(list(self._v))
        v = vw + period * np.rint((rho - vw) / period)  # dealias (np.round with no decimals is rint)
        return float(np.add.reduce(np.abs(v, out=v))) / n

    def current_radial_speed_kmh(self) -> float:
        """The latest frame's unaliased radial speed (km/h): its wrapped Doppler with the alias nearest the least-squares
        range rate of the last ``window_s`` seconds (at least three frames); NaN below two frames. Kept until the
        frames change (the tracker asks several times per frame)."""
        if self._current is None:
            self._current = self._current_radial_speed_kmh()
        return self._current

    def _current_radial_speed_kmh(self) -> float:
        """:meth:`current_radial_speed_kmh` in plain Python over the window's frames, the last ones (the times
        increase); the same bits as :meth:`_current_radial_speed_kmh_numpy`."""
        n = len(self._t)
        if n < 2:
            return math.nan
        ts = self._t
        lim = ts[-1] - self.window_s
        c = 0
        for x in reversed(ts):
            if not x >= lim:
                break
            c += 1
        k = min(max(3, c), n)
        rho = _slope_of([ts[i] for i in range(n - k, n)], [self._r[i] for i in range(n - k, n)])
        if not math.isfinite(rho):
            return math.nan
        v = self._v[-1]
        period = 2.0 * self.vmax_kmh
        return v + period * _rint((rho - v) / period)

    def _current_radial_speed_kmh_numpy(self) -> float:
        """The numpy form of :meth:`_current_radial_speed_kmh` (the tests compare the two)."""
        n = len(self._t)
        if n < 2:
            return math.nan
        t, r = np.array(self._t), np.array(self._r)
        k = max(3, int(np.count_nonzero(t >= t[-1] - self.window_s)))
        rho = self._slope_kmh(t[-k:], r[-k:])
        return self.dealias_one(self._v[-1], rho) if math.isfinite(rho) else math.nan


def weighted_standardization(x: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 20: weighted mean and unbiased (reliability-weights) standard deviation per feature.

    ``x`` (N, F), ``weights`` (N,) non-negative (normalised here to sum 1). Returns ``(mean, scale)``
    so that ``z = (x - mean) / scale``; the scale is
    ``sqrt(sum_l w_l (x_l - mean)^2 / (1 - sum_l w_l^2))`` and 1 where a feature is constant.

    The sums are exactly rounded (:func:`math.fsum` of the elementwise products) rather than BLAS dot
    products, whose summation order depends on the CPU's kernel: the fitted mean and scale, and so the
    exported ONNX model, are the same bits on every machine (this runs once per fit, on N x F values).
    """
    x = np.asarray(x, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if x.ndim != 2 or x.shape[0] != w.size:
        raise ValueError(f"x must be (N, F) with N = len(weights); got {x.shape} and {w.shape}")
    total = math.fsum(w.tolist())
    if np.any(w < 0) or not total > 0:
        raise ValueError("weights must be non-negative with a positive sum")
    w = w / total
    mean = _column_fsum(w[:, None] * x)
    denom = 1.0 - math.fsum((w * w).tolist())
    if denom <= 0:
        raise ValueError("weighted standardisation needs at least two observations with weight")
    var = _column_fsum(w[:, None] * (x - mean) ** 2) / denom
    scale = np.sqrt(var)
    scale[~(scale > 0)] = 1.0
    return mean, scale


def _column_fsum(a: np.ndarray) -> np.ndarray:
    """(N, F) -> (F,) exactly rounded column sums (:func:`math.fsum`)."""
    return np.array([math.fsum(col) for col in a.T.tolist()], dtype=np.float64).reshape(a.shape[1])
