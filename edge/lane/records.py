"""Typed records passed between the lane profile's stages (units in the field names, as in :mod:`edge.types`).

Arrays are numpy; a record holds references, not copies (a stage must not write into another stage's output).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from edge.fastinit import one_dict_init

_NO_TRACKS = (np.zeros((0, 4)), np.zeros(0, bool), np.zeros(0, bool), np.zeros(0, np.int32))
for _a in _NO_TRACKS:
    _a.flags.writeable = False


@one_dict_init
@dataclass(frozen=True, eq=False)
class Feedback:
    """What detection takes from earlier frames: the tracks as the tracker left them, the lanes and the road's
    direction as the traffic layer left them. Built once per frame by :meth:`LanePipeline.feedback` before
    detection; the only way detection learns about tracks and lanes."""

    #: time of the tracks' state (ns): the tracker's last frame; None before its first
    t_ns: int | None
    #: (n, 4) float64 per track: x_m, y_m, vx_mps, vy_mps (ground plane, the radar's frame) at ``t_ns``
    track_state: np.ndarray
    #: (n,) bool: confirmed tracks
    confirmed: np.ndarray
    #: (n,) bool: tracks that were ever surely moving (not static clutter)
    moved: np.ndarray
    #: (n,) int: frames with a detection
    hits: np.ndarray
    #: the lanes (edge.traffic.lanes.Lane), () while unknown
    lanes: tuple[Any, ...] = ()
    #: the road's direction off the boresight (rad), the traffic layer's estimate
    yaw_rad: float = 0.0

    @property
    def n_tracks(self) -> int:
        return int(self.track_state.shape[0])

    @classmethod
    def none(cls) -> "Feedback":
        """No tracker and no traffic layer: no tracks, no lanes."""
        return cls(None, *_NO_TRACKS)


@one_dict_init
@dataclass(frozen=True, eq=False)
class Spectra:
    """Range spectra of one frame after the static-clutter map (Lim §III-A)."""

    #: (rx, seg, bin) complex64, windowed range FFT (scaled 1/n) minus the clutter map
    spec: np.ndarray
    #: (seg, bin + 2 h) float32: power summed over the channels, each row padded circularly by h bins per side
    power_padded: np.ndarray
    #: h of ``power_padded``
    pad: int

    @cached_property
    def power(self) -> np.ndarray:
        """(seg, bin) float32: non-coherent power over the channels (a view of ``power_padded``, made once)."""
        return self.power_padded[:, self.pad:self.power_padded.shape[1] - self.pad]


@one_dict_init
@dataclass(frozen=True, eq=False)
class Peaks:
    """OS-CFAR peaks of the four segments (Lim §III-A), each segment's in bin order (or by power when capped)."""

    #: per segment (4): signed beat frequencies (Hz) of the detected peaks, sub-bin interpolated
    freqs_hz: tuple[np.ndarray, ...]
    #: per segment: their FFT bins
    bins: tuple[np.ndarray, ...]
    #: (seg, bin) float32 OS-CFAR noise estimate (NaN away from local maxima unless computed in full)
    noise: np.ndarray
    #: (seg, bin) float32 detection threshold, noise x scale
    threshold: np.ndarray
    #: (seg,) float32 median power per segment (the noise floor)
    floor: np.ndarray
    #: per segment: frequencies (Hz) of local maxima above the lower track-aided threshold only; None if not searched
    weak_freqs_hz: tuple[np.ndarray, ...] | None = None
    #: per segment: their bins
    weak_bins: tuple[np.ndarray, ...] | None = None


@one_dict_init
@dataclass(frozen=True, eq=False)
class PairList:
    """Four-segment pairings (Lim §III-A) and track-aided ones, one row each."""

    #: (n, 4) int64 FFT bin of each segment's peak
    bins: np.ndarray
    #: (n,) slant range at the frame start (m)
    range_m: np.ndarray
    #: (n,) radial speed (m/s, positive receding)
    radial_speed_mps: np.ndarray
    #: (n,) RMS residual of the least-squares fit over the four segments (Hz)
    residual_hz: np.ndarray
    n_candidates: int = 0
    n_ghosts: int = 0
    #: pairings from tracks (the last ``n_aided`` rows)
    n_aided: int = 0


@one_dict_init
@dataclass(frozen=True, eq=False)
class Angles:
    """Pairings with their angle (Lim §III-A), those whose segments agreed; after the resolver, a split one twice."""

    range_m: np.ndarray
    radial_speed_mps: np.ndarray
    residual_hz: np.ndarray
    #: (n,) float32 azimuth (rad, right +), Bartlett over the channels with the segments as looks
    az_rad: np.ndarray
    #: (n,) float32 power over the CFAR noise in the first segment (dB)
    snr_db: np.ndarray
    #: (n,) int32 >= 0: the two detections split from one cell share the value; -1 otherwise
    resolved_pair: np.ndarray
    #: (n,) bool: two sources in the cell, not split (the resolver's hint); None without the resolver
    unresolved_pair: np.ndarray | None
    #: (pairings, grid) float32 Bartlett spectrum of every pairing (for plots)
    spectrum: np.ndarray
    #: (n, seg, rx) complex64 calibrated snapshots of the kept pairings, the looks not summed into the angle zeroed
    looks: np.ndarray | None = None


@one_dict_init
@dataclass(frozen=True, eq=False)
class Candidates:
    """Detections on their way through the road-geometry filters (:mod:`edge.lane.detections`)."""

    range_m: np.ndarray
    radial_speed_mps: np.ndarray
    az_rad: np.ndarray
    #: (n,) ground-plane position (m); None before the projection
    x_m: np.ndarray | None
    y_m: np.ndarray | None
    #: (n,) bool: still kept
    keep: np.ndarray
    #: (n,) float32 along-road length of the body behind each (m, NaN for dropped ones); None if not measured
    body_extent_m: np.ndarray | None = None
