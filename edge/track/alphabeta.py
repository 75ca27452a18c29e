"""Benedict-Bordner alpha-beta tracking of cluster centroids on the wrapped map (Tavanti §II-D/E).

Measurements are DBSCAN cluster centroids ``m = (v', v'', r)`` on the cylinder of
:mod:`edge.track.cylinder` (km/h, km/h, m). Each track's state is
``s = (v', u_v', v'', u_v'', r, u_r)`` (eq. 9, positions and their per-frame rates, normalised time
step T = 1 frame). The tracker is a thin orchestrator over role objects, after Stone Soup:

* :class:`BenedictBordnerFilter` -- initiate, predict (eq. 12: ``N[A s]``) and update
  (eq. 13: ``N{s + G (m - C s)}``) with ``beta = alpha^2 / (2 - alpha)``; ``N`` is the cylinder
  projection of eq. 14.
* :class:`GreedyAssociator` -- the cost matrix of §II-E step 5 (Euclidean distance between a track's
  predicted position and a centroid; ``+inf`` when the centroid is farther than ``R_gate`` from the
  centroid last assigned to the track) and its greedy minimum-cost assignment (steps 5a-5d).
* :class:`IdPool` -- small integer ids, the smallest free one first, recycled when a track ends.
* :class:`AlphaBetaTracker` -- steps 2-9 frame by frame: update assigned tracks (``age`` and ``vis``
  + 1), coast the others (``age`` + 1), retire a track after ``N_u`` consecutive misses, delete it
  when ``vis / age < th_v``, start a track on every unassigned centroid (``age = vis = 0``).

Streaming instead of the paper's batch: a track that misses ``N_u`` frames in a row has left the
scene, so it *ends* there and then (it is handed back for classification) instead of staying in the
list with an infinite cost row until the event is over. As in step 7, departure is checked before
the ``th_v`` deletion: a departed track is frozen (its ``age`` no longer grows), so only tracks still
in the scene are deleted for ``vis / age < th_v``. The end-of-event rule of step 9 ("delete the
tracks visible in fewer than 3 frames") is applied to every ending track: a track is *seen* in the
frame that created it plus ``vis`` frames after it, and only tracks seen in at least
``min_seen_frames`` frames end as :attr:`TrackerStep.ended`; the others are
:attr:`TrackerStep.dropped`. :meth:`AlphaBetaTracker.close_all` ends every open track (end of an
event, or stop).

Options beyond the paper (the defaults depart from it where the paper's choice fails on fast
vehicles at 5 frames/s; ``gate_reference = "last_measurement"``, ``init_velocity = "zero"`` and
``doppler_range_rate_frames = 0`` restore it): ``gate_reference = "prediction"`` measures ``R_gate``
from the predicted position instead of the last centroid; ``init_velocity = "two_point"`` sets a new
track's rates from its first two centroids (the paper starts them at zero, which with
``alpha = 0.19`` lags a 40 km/h car by metres for its whole passage of 10-15 frames, so that crossing
targets swap tracks); ``doppler_range_rate_frames`` lets the surveillance tracker replace the range
rate by the track's unaliased radial speed (:class:`edge.track.surveillance.SurveillanceTracker`);
``publish_coasting_frames`` limits how long a confirmed track that misses frames is still
published (:meth:`AlphaBetaTracker.confirmed`); ``visibility_count = "with_creation"`` counts the
creation frame in ``vis`` and ``age`` for the ``th_v`` test (the paper's counters delete a new track
on its first miss, so a weak target detected in every other frame is never tracked);
``fragment_gap_m`` makes the surveillance tracker join the signatures of a track's fragments to it;
``corange_fragment_m`` keeps a cluster within that range of a tracked target's cluster from starting
a track (:attr:`TrackerStep.absorbed`; a younger track assigned one loses it to the most-seen track);
``range_gate_m`` and ``range_gate_rate_factor`` add a range gate that grows with a track's rate and
misses; ``shared_span_m``, ``continuation_speed_kmh`` and ``continuation_min_range_m`` are read by
:class:`edge.track.surveillance.SurveillanceTracker`.

Everything is vectorised over tracks and centroids; the only Python loop is the greedy assignment,
at most ``min(tracks, centroids)`` iterations of an ``argmin`` over the cost matrix.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from edge import native
from edge.track.cylinder import Cylinder

log = logging.getLogger(__name__)

__all__ = [
    "AlphaBetaConfig",
    "AlphaBetaTrack",
    "AlphaBetaTracker",
    "BenedictBordnerFilter",
    "GreedyAssociator",
    "IdPool",
    "TrackerStep",
    "benedict_bordner_beta",
    "greedy_assign",
]

#: indices of the positions (v', v'', r) and of their rates in a state vector (eq. 9)
POS = np.array([0, 2, 4])
VEL = np.array([1, 3, 5])


@dataclass(frozen=True)
class AlphaBetaConfig:
    """Tracking of cluster centroids on the wrapped map; defaults are Tavanti Table III."""

    alpha: float = field(
        default=0.19,
        metadata={"doc": "Benedict-Bordner alpha (beta = alpha^2 / (2 - alpha))", "min": 1e-6, "max": 1.0},
    )
    gate_radius: float = field(
        default=6.0,
        metadata={"unit": "m | km/h", "doc": "R_gate: largest distance on the wrapped map (range in m, "
                  "wrapped Doppler in km/h) between a track's last centroid and a new one", "min": 0.0, "max": 100.0},
    )
    gate_reference: str = field(
        default="prediction",
        metadata={"doc": "what R_gate is measured from: the centroid last assigned to the track (paper, step 5) or "
                         "the predicted position (default: a fast car moves metres per frame)",
                  "choices": ("last_measurement", "prediction")},
    )
    init_velocity: str = field(
        default="two_point",
        metadata={"doc": "rates of a new track: zero (paper, step 8) or two_point (default: from the first two "
                         "centroids on the first association, no alpha-beta start-up lag)",
                  "choices": ("zero", "two_point")},
    )
    max_missed_frames: int = field(
        default=7,
        metadata={"unit": "frames", "doc": "N_u: a track not assigned for this many consecutive frames has left "
                  "the scene and ends", "min": 1, "max": 1000},
    )
    visibility_threshold: float = field(
        default=0.25,
        metadata={"doc": "th_v: a track with vis / age below this is deleted (scintillation, multi-bounce)",
                  "min": 0.0, "max": 1.0},
    )
    visibility_count: str = field(
        default="with_creation",
        metadata={"doc": "what vis / age counts for th_v: paper = frames after creation; with_creation (default) = "
                         "the creation frame counted in both, (vis + 1) / (age + 1), so a track that misses its "
                         "second frame survives",
                  "choices": ("paper", "with_creation")},
    )
    min_seen_frames: int = field(
        default=3,
        metadata={"unit": "frames", "doc": "a track seen in fewer frames (creation frame + vis) is dropped when "
                  "it ends instead of being classified (step 9)", "min": 1, "max": 1000},
    )
    publish_coasting_frames: int = field(
        default=2,
        metadata={"unit": "frames", "doc": "a confirmed track is published while it has missed at most this many "
                  "consecutive frames (it stays alive for association until max_missed_frames)", "min": 0, "max": 1000},
    )
    doppler_range_rate_frames: int = field(
        default=4,
        metadata={"unit": "frames", "doc": "beyond the paper: once a track has clusters in this many frames, its "
                                           "range rate is its unaliased radial speed after every update (set by the "
                                           "surveillance tracker); 0 = the paper's alpha-beta rate",
                  "min": 0, "max": 1000},
    )
    merge_ratio: float = field(
        default=6.0,
        metadata={"doc": "beyond the paper: a cluster with more than this times the median point count of the "
                         "track's last merge_history_frames clusters is merged with another target: the track keeps "
                         "its prediction and the frame adds no features; 0 = off (paper)",
                  "min": 0.0, "max": 1000.0},
    )
    merge_history_frames: int = field(
        default=5,
        metadata={"unit": "frames", "doc": "clusters (not merged) whose median point count is a track's own size",
                  "min": 1, "max": 1000},
    )
    merge_other_min_frames: int = field(
        default=5,
        metadata={"unit": "frames", "doc": "beyond the paper: a young track's enlarged cluster counts as merged only"
                                           " when another track with at least this many own clusters is predicted "
                                           "within gate_radius (else both are fragments of one vehicle); 0 = any "
                                           "other track", "min": 0, "max": 1000},
    )
    shared_span_m: float = field(
        default=0.5,
        metadata={"unit": "m", "doc": "beyond the paper: a track left without a centroid whose prediction lies "
                                      "within this of the range span of another track's cluster is hidden in it and "
                                      "coasts without misses, for at most merge_max_frames; 0 = off", "min": 0.0, "max": 10.0},
    )
    merge_other_required: str = field(
        default="always",
        metadata={"doc": "beyond the paper: which tracks need another track near an enlarged cluster for the "
                         "merge_ratio test: young = tracks with fewer than merge_history_frames sizes, always "
                         "(default) = every track",
                  "choices": ("young", "always")},
    )
    merge_max_frames: int = field(
        default=10,
        metadata={"unit": "frames", "doc": "after this many merged frames in a row the larger cluster is accepted as "
                  "the track's own (a target that grew as it came closer)", "min": 1, "max": 1000},
    )
    fragment_gap_m: float = field(
        default=0.0,
        metadata={"unit": "m", "doc": "beyond the paper: a track that ends with its clusters within this range gap "
                                      "of a living track's in at least fragment_link_fraction of its frames is a "
                                      "fragment of that target: its cells join that track's signatures; 0 = off "
                                      "(paper, default)", "min": 0.0, "max": 30.0},
    )
    fragment_link_fraction: float = field(
        default=0.5,
        metadata={"doc": "share of a track's frames linked to another track that makes it a fragment of it "
                  "(see fragment_gap_m)", "min": 0.0, "max": 1.0},
    )
    fragment_speed_kmh: float = field(
        default=10.0,
        metadata={"unit": "km/h", "doc": "two tracks are linked (fragment_gap_m) only while their unaliased radial "
                                         "speeds differ by at most this; a track with clusters in fewer than "
                                         "doppler_range_rate_frames frames has no speed yet and passes",
                  "min": 0.0, "max": 1000.0},
    )
    range_gate_m: float = field(
        default=2.5,
        metadata={"unit": "m", "doc": "beyond the paper: besides R_gate, a track with a range rate takes only "
                                      "centroids within range_gate_m + range_gate_rate_factor * |u_r| * (missed + 1)"
                                      " of its predicted range (u_r in m per frame); 0 = off (paper)", "min": 0.0, "max": 100.0},
    )
    range_gate_rate_factor: float = field(
        default=3.0,
        metadata={"doc": "growth of the range gate with the track's range rate and its missed frames "
                  "(see range_gate_m)", "min": 0.0, "max": 100.0},
    )
    corange_fragment_m: float = field(
        default=0.5,
        metadata={"unit": "m", "doc": "beyond the paper: an unassigned cluster within this range of a cluster "
                                      "assigned to an older track starts no track; its cells join that track's "
                                      "signature (a walker's legs wrapped around the Doppler axis); 0 = off (paper)",
                  "min": 0.0, "max": 10.0},
    )
    static_zone_time_s: float = field(
        default=60.0,
        metadata={"unit": "s", "doc": "beyond the paper: time constant of the share of frames with a slow cluster "
                                      "over a range cell (edge.track.static_zones); a slow cluster in a cell whose "
                                      "share reaches static_zone_occupancy is site clutter and feeds no track; 0 = off",
                  "min": 0.0, "max": 3600.0},
    )
    static_zone_speed_kmh: float = field(
        default=2.0,
        metadata={"unit": "km/h", "doc": "a cluster is slow when its wrapped Doppler is at most this (swaying "
                                         "foliage: Billingsley's spectrum of wind-blown trees)", "min": 0.0, "max": 5.0},
    )
    static_zone_occupancy: float = field(
        default=0.1,
        metadata={"doc": "share of frames with a slow cluster that makes a range cell a static zone",
                  "min": 0.0, "max": 1.0},
    )
    continuation_speed_kmh: float = field(
        default=6.0,
        metadata={"unit": "km/h", "doc": "beyond the paper: a track that ends is the same target as a living track "
                                         "started after its last cluster when the gap between them is walked at its "
                                         "radial speed within this (or half that speed): its frames join the new "
                                         "track; 0 = off (paper)", "min": 0.0, "max": 1000.0},
    )
    continuation_min_range_m: float = field(
        default=3.0,
        metadata={"unit": "m", "doc": "see continuation_speed_kmh: a track last seen closer than this has left past "
                  "the radar and is never continued", "min": 0.0, "max": 100.0},
    )
    rigid_min_speed_kmh: float = field(
        default=13.0,
        metadata={"unit": "km/h", "doc": "beyond the paper: two live tracks are parts of one rigid body when the "
                                         "older is at least this fast and the younger's cluster stays within "
                                         "rigid_length_m in range, rigid_doppler_kmh in Doppler and "
                                         "rigid_separation_m in spread for rigid_frames frames; 0 = off", "min": 0.0, "max": 200.0},
    )
    rigid_length_m: float = field(
        default=6.0,
        metadata={"unit": "m", "doc": "see rigid_min_speed_kmh: largest range separation of two parts of one body "
                  "(a car's length, most of a truck's in range beside the radar)", "min": 0.0, "max": 30.0},
    )
    rigid_doppler_kmh: float = field(
        default=1.5,
        metadata={"unit": "km/h", "doc": "see rigid_min_speed_kmh: largest difference of the two tracks' wrapped "
                  "Doppler (circular, modulo 2 v_max) in a frame that counts as moving together (the older track's "
                  "last measured Doppler when it coasts)", "min": 0.0, "max": 20.0},
    )
    rigid_separation_m: float = field(
        default=1.5,
        metadata={"unit": "m", "doc": "see rigid_min_speed_kmh: largest spread of the two tracks' range separation "
                                      "over the frames counted (parts of one body keep their distance)", "min": 0.0, "max": 30.0},
    )
    rigid_frames: int = field(
        default=3,
        metadata={"unit": "frames", "doc": "see rigid_min_speed_kmh: consecutive frames of the younger track moving "
                  "with the older one before they are merged", "min": 1, "max": 1000},
    )
    passage_max_frames: int = field(
        default=8,
        metadata={"unit": "frames", "doc": "beyond the paper: a track that ends with at most this many frames, one "
                                           "within passage_range_m, joins a living vehicle track whose cluster was "
                                           "within rigid_length_m of its own within passage_gap_frames, their "
                                           "extents within body_gap_m in most of its frames (the vehicle beside "
                                           "the radar); 0 = off", "min": 0, "max": 1000},
    )
    passage_range_m: float = field(
        default=8.0,
        metadata={"unit": "m", "doc": "see passage_max_frames: the short track's nearest cluster is at most this "
                  "far from the radar (vehicles pass 2-6.5 m beside it at the simulated site)", "min": 0.0, "max": 30.0},
    )
    passage_gap_frames: int = field(
        default=2,
        metadata={"unit": "frames", "doc": "see passage_max_frames: largest time between a cluster of the short "
                  "track and one of the vehicle track that are within rigid_length_m", "min": 0, "max": 100},
    )
    passage_speed_kmh: float = field(
        default=8.0,
        metadata={"unit": "km/h", "doc": "see passage_max_frames: the short track's mean radial speed is within this"
                                         " of zero, or within passage_same_speed_kmh of the vehicle track's speed",
                  "min": 0.0, "max": 100.0},
    )
    passage_same_speed_kmh: float = field(
        default=2.5,
        metadata={"unit": "km/h", "doc": "see passage_speed_kmh", "min": 0.0, "max": 100.0},
    )
    continuation_hold_frames: int = field(
        default=10,
        metadata={"unit": "frames", "doc": "see continuation_speed_kmh: an ended track faster than "
                                           "static_zone_speed_kmh waits this long, its id kept, for the one track "
                                           "in view to continue it, when it is the only track waiting (a target "
                                           "fading for longer than max_missed_frames), and for its parts that end "
                                           "later; 0 = no wait",
                  "min": 0, "max": 1000},
    )
    continuation_same_frame: bool = field(
        default=True,
        metadata={"doc": "see continuation_speed_kmh: a track started in the very frame of the ended track's last "
                         "cluster is a candidate too, judged at its latest cluster; false = only tracks started "
                         "after it"},
    )
    vehicle_by_class: bool = field(
        default=True,
        metadata={"doc": "beyond the paper: the body and passage rules (body_length_m, passage_max_frames) also "
                         "take a track slower than rigid_min_speed_kmh for a vehicle when the classifier reads its "
                         "features so far as one (a truck at about an alias step of radial speed)"},
    )
    body_length_m: float = field(
        default=12.0,
        metadata={"unit": "m", "doc": "beyond the paper: a track that ends while a vehicle's track lives or waits "
                                      "(at least rigid_min_speed_kmh; see vehicle_by_class) joins it if their clusters' "
                                      "centres lie within this range at a wrapped Doppler within body_doppler_kmh, "
                                      "adjacent (body_gap_m) or at one range rate (body_rate_kmh); 0 = off",
                  "min": 0.0, "max": 30.0},
    )
    body_gap_m: float = field(
        default=2.5,
        metadata={"unit": "m", "doc": "see body_length_m: largest median range gap between the two tracks' cluster "
                                      "extents for parts joined without a common range rate", "min": 0.0, "max": 30.0},
    )
    body_doppler_kmh: float = field(
        default=4.0,
        metadata={"unit": "km/h", "doc": "see body_length_m: largest median difference of the two tracks' wrapped "
                  "Dopplers (on the +-v_max circle) of the frames paired (a car's front and rear passing beside the "
                  "radar are seen at aspects 3-4 km/h apart)", "min": 0.0, "max": 100.0},
    )
    body_overlap_any_doppler: bool = field(
        default=True,
        metadata={"doc": "see body_length_m: a part whose cluster extents overlap the vehicle's in most frames both were "
                         "seen in joins it at any wrapped Doppler (a vehicle beside the radar is seen at aspects whose radial "
                         "speeds differ by up to its speed; its wheels at 0-2 times it); false = body_doppler_kmh always"},
    )
    body_rate_kmh: float = field(
        default=6.0,
        metadata={"unit": "km/h", "doc": "see body_length_m: largest difference of the two tracks' Theil-Sen range "
                  "rates over their whole lives (parts of one body move together; a walker a car passes at the "
                  "walker's wrapped Doppler does not)", "min": 0.0, "max": 100.0},
    )
    max_track_id: int = field(
        default=255,
        metadata={"doc": "track ids are 1..max_track_id, smallest free first and recycled (fits CAN/Modbus)",
                  "min": 1, "max": 65535},
    )


def benedict_bordner_beta(alpha: float) -> float:
    """``beta = alpha^2 / (2 - alpha)`` (Benedict and Bordner 1962)."""
    return alpha * alpha / (2.0 - alpha)


class BenedictBordnerFilter(native.KernelUser):
    """Predictor and updater of eqs. 12-14 on stacked states ``(n, 6)`` (float64)."""

    def __init__(self, alpha: float, cylinder: Cylinder) -> None:
        if not 0.0 < alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {alpha!r}")
        self.alpha = float(alpha)
        self.beta = benedict_bordner_beta(self.alpha)
        self.cylinder = cylinder
        #: the compiled predict and update (edge/native/_alphabeta.pyx) for the plain cylinder, None: numpy
        self.kernel = native.load("_alphabeta") if type(cylinder) is Cylinder else None

    def initiate(self, measurements: np.ndarray) -> np.ndarray:
        """Centroids ``(n, 3)`` -> states ``(n, 6)`` = ``(v', 0, v'', 0, r, 0)`` on the cylinder (step 8)."""
        m = np.asarray(measurements, dtype=np.float64).reshape(-1, 3)
        s = np.zeros((m.shape[0], 6))
        s[:, POS] = m
        return self.cylinder.project_states(s)

    def predict(self, states: np.ndarray) -> np.ndarray:
        """``N[A s]`` with ``A = diag([[1, 1], [0, 1]])`` per coordinate (T = 1 frame), eq. 12."""
        s = np.array(states, dtype=np.float64, copy=True).reshape(-1, 6)
        if self.kernel is not None and s.flags.c_contiguous:
            self.kernel.predict(s, self.cylinder.radius_kmh)
            return s
        s[:, POS] += s[:, VEL]
        return self.cylinder.project_states(s)

    @staticmethod
    def measurement_of(states: np.ndarray) -> np.ndarray:
        """``C s``: the positions ``(n, 3)`` of states ``(n, 6)``."""
        return np.asarray(states).reshape(-1, 6)[:, POS]

    def two_point(self, first: np.ndarray, second: np.ndarray, frames: np.ndarray) -> np.ndarray:
        """States at ``second`` with rates ``(second - first) / frames`` (two-point initiation).

        The Doppler rates are taken along the shorter arc of the cylinder, so a centroid crossing the
        wrap does not get a rate of a whole turn.
        """
        a = np.asarray(first, dtype=np.float64).reshape(-1, 3)
        b = np.asarray(second, dtype=np.float64).reshape(-1, 3)
        n = np.asarray(frames, dtype=np.float64).reshape(-1, 1)
        s = np.zeros((a.shape[0], 6))
        s[:, POS] = b
        s[:, VEL] = (b - a) / n
        return self.cylinder.project_states(s)

    def update(self, predicted: np.ndarray, measurements: np.ndarray) -> np.ndarray:
        """``N{s + G (m - C s)}``: alpha on positions, beta on rates (eq. 13)."""
        s = np.array(predicted, dtype=np.float64, copy=True).reshape(-1, 6)
        if self.kernel is not None and s.flags.c_contiguous:
            m = np.ascontiguousarray(measurements, dtype=np.float64).reshape(-1, 3)
            if m.shape == (s.shape[0], 3):
                self.kernel.update(s, m, self.alpha, self.beta, self.cylinder.radius_kmh)
                return s
        resid = np.asarray(measurements, dtype=np.float64).reshape(-1, 3) - s[:, POS]
        s[:, POS] += self.alpha * resid
        s[:, VEL] += self.beta * resid
        return self.cylinder.project_states(s)


def greedy_assign(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Greedy minimum-cost assignment of §II-E step 5a-d.

    Repeatedly take the smallest finite entry ``(i, j)`` of ``cost`` (ties: the first in row-major
    order), pair row ``i`` with column ``j`` and set row ``i`` and column ``j`` to ``+inf``, until no
    finite entry is left. Returns the paired ``rows`` and ``cols`` (int arrays, in pairing order).
    """
    c = np.array(cost, dtype=np.float64, copy=True)
    if c.ndim != 2:
        raise ValueError(f"cost must be a 2-D matrix, got shape {c.shape}")
    rows: list[int] = []
    cols: list[int] = []
    if c.size:
        c[np.isnan(c)] = np.inf
        for _ in range(min(c.shape)):
            k = int(np.argmin(c))
            i, j = divmod(k, c.shape[1])
            if not np.isfinite(c[i, j]):
                break
            rows.append(i)
            cols.append(j)
            c[i, :] = np.inf
            c[:, j] = np.inf
    return np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp)


class GreedyAssociator(native.KernelUser):
    """Cost matrix with the ``R_gate`` gate (step 5) and :func:`greedy_assign`."""

    def __init__(self, gate_radius: float, gate_reference: str = "last_measurement") -> None:
        if gate_reference not in ("last_measurement", "prediction"):
            raise ValueError(f"gate_reference must be 'last_measurement' or 'prediction', got {gate_reference!r}")
        self.gate_radius = float(gate_radius)
        self.gate_reference = gate_reference
        #: the compiled cost matrix and greedy assignment (edge/native/_alphabeta.pyx), None: numpy
        self.kernel = native.load("_alphabeta")

    def cost_matrix(self, predicted_pos: np.ndarray, last_pos: np.ndarray, centroids: np.ndarray,
                    range_gate: np.ndarray | None = None) -> np.ndarray:
        """``(n_tracks, n_centroids)`` Euclidean distances from the predictions, ``+inf`` outside the gate
        (and, with ``range_gate`` (n_tracks,), where the range differs from the prediction by more)."""
        pred = np.asarray(predicted_pos, dtype=np.float64).reshape(-1, 3)
        cen = np.asarray(centroids, dtype=np.float64).reshape(-1, 3)
        cost = np.linalg.norm(pred[:, None, :] - cen[None, :, :], axis=-1)
        if self.gate_reference == "last_measurement":
            ref = np.asarray(last_pos, dtype=np.float64).reshape(-1, 3)
            gate_d = np.linalg.norm(ref[:, None, :] - cen[None, :, :], axis=-1)
        else:
            gate_d = cost
        cost[gate_d > self.gate_radius] = np.inf
        if range_gate is not None:
            dr = np.abs(pred[:, 2, None] - cen[None, :, 2])
            cost[dr > np.asarray(range_gate, dtype=np.float64)[:, None]] = np.inf
        return cost

    def associate(
        self, predicted_pos: np.ndarray, last_pos: np.ndarray, centroids: np.ndarray,
        range_gate: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """-> ``(track_rows, centroid_cols, cost)``."""
        if self.kernel is not None:
            out = self._associate_kernel(predicted_pos, last_pos, centroids, range_gate)
            if out is not None:
                return out
        cost = self.cost_matrix(predicted_pos, last_pos, centroids, range_gate)
        rows, cols = greedy_assign(cost)
        return rows, cols, cost

    def _associate_kernel(self, predicted_pos, last_pos, centroids, range_gate):
        """:meth:`associate` in one kernel call; None when the shapes are not the plain ``(n, 3)``, ``(m, 3)``,
        ``(n,)`` ones (the numpy code broadcasts or raises)."""
        pred = np.ascontiguousarray(predicted_pos, dtype=np.float64)
        cen = np.ascontiguousarray(centroids, dtype=np.float64)
        last = np.ascontiguousarray(last_pos, dtype=np.float64)
        rg = _NO_GATE if range_gate is None else np.ascontiguousarray(range_gate, dtype=np.float64)
        if (pred.ndim != 2 or pred.shape[1] != 3 or cen.ndim != 2 or cen.shape[1] != 3 or last.shape != pred.shape
                or (range_gate is not None and rg.shape != (pred.shape[0],))):
            return None
        n, m = pred.shape[0], cen.shape[0]
        cost = np.empty((n, m))
        pairs = np.empty((2, min(n, m)), dtype=np.intp)
        k = self.kernel.associate(pred, 1, last, cen, self.gate_radius, self.gate_reference == "last_measurement", rg,
                                  cost, np.empty((n, m)), pairs[0], pairs[1])
        return pairs[0, :k], pairs[1, :k], cost


_NO_GATE = np.zeros(0)  # the kernel's "no range gate"


class IdPool:
    """Integer ids ``1..max_id``; :meth:`acquire` returns the smallest free one (``None`` when exhausted)."""

    def __init__(self, max_id: int) -> None:
        if max_id < 1:
            raise ValueError("max_id must be at least 1")
        self.max_id = int(max_id)
        self._used: set[int] = set()

    def acquire(self) -> int | None:
        for i in range(1, self.max_id + 1):
            if i not in self._used:
                self._used.add(i)
                return i
        return None

    def release(self, track_id: int) -> None:
        self._used.discard(track_id)

    def __len__(self) -> int:
        return len(self._used)


@dataclass
class AlphaBetaTrack:
    """One track: filter state and the counters of §II-E (mutable; owned by the tracker)."""

    track_id: int
    state: np.ndarray  # (6,) float64, (v', u_v', v'', u_v'', r, u_r)
    last_measurement: np.ndarray  # (3,) the centroid last assigned (or the initiating one)
    created_ns: int
    last_seen_ns: int
    age: int = 0
    vis: int = 0
    missed: int = 0  # consecutive frames without a centroid
    occluded: int = 0  # consecutive frames hidden in another track's (merged) cluster

    @property
    def seen_frames(self) -> int:
        """Frames with a centroid: the creation frame plus ``vis``."""
        return self.vis + 1


@dataclass(frozen=True)
class TrackerStep:
    """What one :meth:`AlphaBetaTracker.step` did.

    ``assigned`` maps track id -> index of its centroid in this frame, for updated *and* newly
    created tracks (the creating centroid belongs to the new track). ``ended`` tracks left the scene
    after being seen often enough (classify them); ``dropped`` tracks were deleted (th_v, too few
    frames, or no free id). ``cost`` is the gated cost matrix (rows = ``track_ids_before``).
    """

    assigned: dict[int, int]
    created: tuple[int, ...]
    ended: tuple[AlphaBetaTrack, ...]
    dropped: tuple[AlphaBetaTrack, ...]
    cost: np.ndarray
    track_ids_before: tuple[int, ...]
    occluded: tuple[int, ...] = ()  # tracks hidden in another track's merged cluster (neither hit nor miss)
    absorbed: dict[int, int] = field(default_factory=dict)  # centroid index -> track id it is part of (no birth)


class AlphaBetaTracker:
    """Steps 2-9 of Tavanti §II-E, one call per frame (see the module docstring)."""

    def __init__(
        self,
        config: AlphaBetaConfig,
        cylinder: Cylinder,
        *,
        filter: BenedictBordnerFilter | None = None,
        associator: GreedyAssociator | None = None,
        ids: IdPool | None = None,
    ) -> None:
        self.config = config
        self.cylinder = cylinder
        self.filter = filter or BenedictBordnerFilter(config.alpha, cylinder)
        self.associator = associator or GreedyAssociator(config.gate_radius, config.gate_reference)
        self.ids = ids or IdPool(config.max_track_id)
        self.tracks: list[AlphaBetaTrack] = []
        self.ids_exhausted = 0
        #: optional ``(track, centroid_index) -> bool``: is this unassigned track hidden in that assigned
        #: centroid's cluster (merged with the track it went to)? Such a frame is neither a hit nor a miss:
        #: the track coasts on its prediction without counting towards N_u (at most merge_max_frames in a row)
        self.occlusion_test = None
        #: True: the ids of tracks that end (not of dropped ones) stay taken until the owner releases them
        self.keep_ended_ids = False

    def step(self, t_ns: int, centroids: np.ndarray, predicted: np.ndarray | None = None) -> TrackerStep:
        """Process the centroids ``(n, 3)`` of one frame (already on the cylinder, or projected here).
        ``predicted``: the tracks' predicted states when the caller has them (``filter.predict`` of the stacked
        states, unchanged since), else computed here."""
        cfg = self.config
        cen = np.asarray(centroids, dtype=np.float64).reshape(-1, 3)
        if cen.shape[0]:
            cen = self.cylinder.project_points(cen)
        before = tuple(t.track_id for t in self.tracks)
        assigned: dict[int, int] = {}
        occluded: list[int] = []
        ended: list[AlphaBetaTrack] = []
        dropped: list[AlphaBetaTrack] = []
        cost = np.zeros((len(self.tracks), cen.shape[0]))
        absorbed: dict[int, int] = {}
        used_cols: set[int] = set()
        if self.tracks:
            if predicted is None:
                pred = self.filter.predict(np.stack([t.state for t in self.tracks]))
            else:  # (updated in place below: the caller's array stays the prediction)
                pred = np.array(predicted, dtype=np.float64, copy=True).reshape(-1, 6)
            last = np.stack([t.last_measurement for t in self.tracks])
            rows, cols, cost = self.associator.associate(self.filter.measurement_of(pred), last, cen,
                                                         self._range_gate(pred))
            if cfg.corange_fragment_m > 0 and rows.size:
                rows, cols, absorbed = self._corange_fragments(rows, cols, cen)
            new_states = pred
            if rows.size:
                new_states[rows] = self.filter.update(pred[rows], cen[cols])
                used_cols.update(cols.tolist())
                if cfg.init_velocity == "two_point":
                    first = np.array([self.tracks[i].vis == 0 for i in rows.tolist()], dtype=bool)
                    if first.any():
                        r1 = rows[first]
                        new_states[r1] = self.filter.two_point(
                            np.stack([self.tracks[i].last_measurement for i in r1.tolist()]),
                            cen[cols[first]],
                            np.array([self.tracks[i].age + 1 for i in r1.tolist()], dtype=np.float64),
                        )
            col_of = dict(zip(rows.tolist(), cols.tolist()))
            keep: list[AlphaBetaTrack] = []
            for k, tr in enumerate(self.tracks):
                tr.state = new_states[k]
                tr.age += 1
                hit = k in col_of
                if hit:
                    tr.vis += 1
                    tr.missed = 0
                    tr.last_measurement = cen[col_of[k]]
                    tr.last_seen_ns = t_ns
                    assigned[tr.track_id] = col_of[k]
                elif self._occluded(tr, pred[k], cen, cols):
                    tr.age -= 1  # an occluded frame neither ages the track (th_v) nor counts as a miss
                    tr.occluded += 1
                    occluded.append(tr.track_id)
                else:
                    tr.missed += 1
                    tr.occluded = 0
                if hit:
                    tr.occluded = 0
                if tr.missed >= cfg.max_missed_frames:  # step 7: departed (checked before th_v)
                    (ended if tr.seen_frames >= cfg.min_seen_frames else dropped).append(tr)
                elif self._low_visibility(tr):  # vis / age < th_v
                    dropped.append(tr)
                else:
                    keep.append(tr)
            self.tracks = keep
            for tr in (dropped if self.keep_ended_ids else ended + dropped):
                self.ids.release(tr.track_id)
        created: list[int] = []
        free = [j for j in range(cen.shape[0]) if j not in used_cols and j not in absorbed]
        if free:
            states = self.filter.initiate(cen[free])
            for j, s in zip(free, states):
                tid = self.ids.acquire()
                if tid is None:
                    self.ids_exhausted += 1
                    log.warning("no free track id (max_track_id=%d): centroid %d not tracked", cfg.max_track_id, j)
                    continue
                self.tracks.append(AlphaBetaTrack(tid, s, cen[j].copy(), created_ns=t_ns, last_seen_ns=t_ns))
                assigned[tid] = j
                created.append(tid)
        return TrackerStep(assigned, tuple(created), tuple(ended), tuple(dropped), cost, before, tuple(occluded),
                           absorbed)

    def _range_gate(self, pred: np.ndarray) -> np.ndarray | None:
        """Per-track range gate (``range_gate_m``, ``range_gate_rate_factor``) or None when off: tracks
        with a rate (seen after their creation frame) ``r0 + k |u_r| (missed + 1)``, new ones inf."""
        cfg = self.config
        if cfg.range_gate_m <= 0:
            return None
        # per track, the float64 operations of r0 + k |u_r| (missed + 1) in numpy's order
        g0, k = cfg.range_gate_m, cfg.range_gate_rate_factor
        return np.array([g0 + k * abs(u) * (t.missed + 1.0) if t.vis > 0 else math.inf
                         for t, u in zip(self.tracks, pred[:, 5].tolist())], dtype=np.float64)

    def _corange_fragments(self, rows: np.ndarray, cols: np.ndarray, cen: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, dict[int, int]]:
        """Co-range fragments (``corange_fragment_m``): every centroid within that range of the centroid
        assigned to the track seen in the most frames among those near it belongs to that track. A
        younger track assigned such a centroid loses it (it coasts this frame), and the centroids no
        track got start no track. Returns the kept ``(rows, cols)`` and ``{centroid index: owner id}``
        of the centroids absorbed (the tracks' own centroids excluded)."""
        tol = self.config.corange_fragment_m
        r = cen[:, 2].tolist()
        rl, cl = rows.tolist(), cols.tolist()
        rc = [r[c] for c in cl]
        seen = [self.tracks[i].seen_frames for i in rl]
        # the owner of each assigned centroid: the most-seen track among the co-range ones (itself on ties); the
        # first of the largest scores, as np.argmax takes it (score: seen frames when within tol, else -1)
        owner = []
        for a, ra in enumerate(rc):
            best, arg = -2, 0
            for b, rb in enumerate(rc):
                sc = seen[b] if abs(ra - rb) <= tol else -1
                if sc > best:
                    best, arg = sc, b
            owner.append(arg if best > seen[a] else a)
        absorbed = {cl[a]: self.tracks[rl[o]].track_id for a, o in enumerate(owner) if o != a}
        if absorbed:
            rl = [i for a, i in enumerate(rl) if owner[a] == a]
            cl = [c for a, c in enumerate(cl) if owner[a] == a]
            rows, cols = np.array(rl, dtype=np.intp), np.array(cl, dtype=np.intp)
            rc = [r[c] for c in cl]
        taken = set(cl)
        if cl:
            for j in range(len(r)):
                if j in taken or j in absorbed:
                    continue
                # the nearest kept centroid in range (np.argmin: the first minimum, or the first NaN)
                d = [abs(r[j] - x) for x in rc]
                if any(x != x for x in d):
                    continue  # NaN: not within tol
                k = d.index(min(d))
                if d[k] <= tol:
                    absorbed[j] = self.tracks[rl[k]].track_id
        return rows, cols, absorbed

    def _low_visibility(self, tr: AlphaBetaTrack) -> bool:
        """``vis / age < th_v`` (age >= 1 here), counted as ``visibility_count`` says."""
        cfg = self.config
        if cfg.visibility_count == "with_creation":
            return tr.vis + 1 < cfg.visibility_threshold * (tr.age + 1)
        return tr.vis < cfg.visibility_threshold * tr.age

    def _occluded(self, tr: AlphaBetaTrack, pred: np.ndarray, cen: np.ndarray, cols: np.ndarray) -> bool:
        if self.occlusion_test is None or cols.size == 0 or tr.occluded >= self.config.merge_max_frames:
            return False
        # np.linalg.norm(cen[cols] - pred[POS], axis=1) row by row: sqrt((dx^2 + dy^2) + dz^2), numpy's sum order;
        # the nearest as np.argmin takes it (the first minimum, or the first NaN)
        p0, p2, p4 = float(pred[0]), float(pred[2]), float(pred[4])
        d = []
        for c in cols.tolist():
            c0, c1, c2 = cen[c].tolist()
            dx, dy, dz = c0 - p0, c1 - p2, c2 - p4
            d.append(math.sqrt((dx * dx + dy * dy) + dz * dz))
        nan = [k for k, x in enumerate(d) if x != x]
        j = nan[0] if nan else d.index(min(d))
        return bool(d[j] <= self.config.gate_radius) and bool(self.occlusion_test(tr, int(cols[j])))

    def close_all(self) -> tuple[tuple[AlphaBetaTrack, ...], tuple[AlphaBetaTrack, ...]]:
        """End every open track (end of the event, step 9): ``(ended, dropped)``."""
        ended = tuple(t for t in self.tracks if t.seen_frames >= self.config.min_seen_frames)
        dropped = tuple(t for t in self.tracks if t.seen_frames < self.config.min_seen_frames)
        for tr in self.tracks:
            self.ids.release(tr.track_id)
        self.tracks = []
        return ended, dropped

    def confirmed(self) -> list[AlphaBetaTrack]:
        """Open tracks seen in ``min_seen_frames`` frames and not coasting for more than
        ``publish_coasting_frames`` (the ones published per frame)."""
        c = self.config
        return [t for t in self.tracks if t.seen_frames >= c.min_seen_frames and t.missed <= c.publish_coasting_frames]
