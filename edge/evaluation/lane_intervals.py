"""Per-lane interval truth from the simulator, and the scoring of the traffic layer's interval records against it.

Truth per lane and interval (the traffic layer's intervals: from the first frame, ``interval_s`` long), from the
vehicles' true positions, lengths and speeds:

* a vehicle *crosses* when its near face (the point the tracks follow) passes the detection line in its lane's
  direction of travel, at the time interpolated between frames; ``volume`` counts them, ``mean_speed_kmh`` and
  ``speed_p85_kmh`` are the mean and 85th percentile (``numpy.percentile``) of their speeds then;
* ``headway_s``: mean time between a crossing and the one before it in the lane (which may lie in an earlier
  interval); ``gap_s``: mean of ``headway - L_leader / v_leader`` clipped at 0 (the leader's true length and speed);
* ``occupancy_pct``: share of the interval's frames (each counting its frame period; a frame at the end of an
  interval counts in it, as in the traffic layer) during which some part of a vehicle of the lane (its centre
  +- half its length along the road) lies in the presence zone;
* ``class_counts``: crossings per length class of the true length (the configured bins); ``mean_length_m``.

Scoring pairs each closed interval record (:class:`edge.types.LaneStats`) with the truth of its lane and interval
and reports the errors (measured - true; gap also in percent of the true gap) over the intervals where both are
defined, with the share within the acceptance tolerances (occupancy +-2 percentage points, mean speed +-1 km/h,
85th percentile +-3 km/h, gap +-10 %).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: acceptance tolerances (issue 27): occupancy in percentage points, speeds in km/h, gap in percent
TOLERANCES = {"occupancy_pct": 2.0, "mean_speed_kmh": 1.0, "speed_p85_kmh": 3.0, "gap_pct": 10.0}


def length_class(length_m: float, edges_m, names) -> str:
    return names[int(np.searchsorted(np.asarray(edges_m, dtype=np.float64), length_m, side="right"))]


@dataclass
class _Crossing:
    t_s: float
    speed_mps: float
    length_m: float
    vehicle_id: int


@dataclass
class LaneIntervalTruth:
    """Feed :meth:`add_frame` every frame; :meth:`intervals` gives the truth per ``(lane, interval index)``."""

    n_lanes: int
    line_m: float
    zone_m: float
    interval_s: float
    lane_dir: tuple[int, ...]  # +1 away from the radar, -1 towards it
    class_edges_m: tuple[float, ...]
    class_names: tuple[str, ...]
    t0_s: float | None = None
    crossings: dict[int, list[_Crossing]] = field(default_factory=dict)
    occupied_s: dict[tuple[int, int], float] = field(default_factory=dict)
    _prev: dict[int, tuple[float, float]] = field(default_factory=dict)  # vehicle -> (t, near-face s)
    _last_t: float | None = None

    def index(self, t_s: float, frame_end: bool = False) -> int:
        """Interval of a crossing at ``t_s`` (``[start, end)``), or of a frame's presence (``frame_end``: a frame at
        an interval's end closes it and counts in it)."""
        u = (t_s - self.t0_s) / self.interval_s
        return max(math.ceil(u - 1e-9) - 1, 0) if frame_end else int(math.floor(u + 1e-9))

    def add_frame(self, t_s: float, ids, lanes, s_near_m, s_centre_m, length_m, speed_mps) -> None:
        """Vehicles of one frame: id, lane (-1 off the lanes), near-face and centre along-road distance (from the
        radar's foot), true length and speed."""
        if self.t0_s is None:
            self.t0_s = t_s
        dt = 0.0 if self._last_t is None else t_s - self._last_t
        self._last_t = t_s
        lo, hi = self.line_m - 0.5 * self.zone_m, self.line_m + 0.5 * self.zone_m
        present = set()
        for i, k, sn, sc, ln, v in zip(ids, lanes, s_near_m, s_centre_m, length_m, speed_mps):
            i, k = int(i), int(k)
            prev = self._prev.get(i)
            self._prev[i] = (t_s, float(sn))
            if not 0 <= k < self.n_lanes:
                continue
            if sc - 0.5 * ln <= hi and sc + 0.5 * ln >= lo:
                present.add(k)
            if prev is None:
                continue
            t_p, s_p = prev
            crossed = (s_p - self.line_m) * (sn - self.line_m) < 0 or (sn == self.line_m and s_p != sn)
            if crossed and (sn - s_p) * self.lane_dir[k] > 0:
                tc = t_p + (self.line_m - s_p) / (sn - s_p) * (t_s - t_p)
                self.crossings.setdefault(k, []).append(_Crossing(tc, float(v), float(ln), i))
        if dt > 0:
            n = self.index(t_s, frame_end=True)
            for k in present:
                self.occupied_s[(k, n)] = self.occupied_s.get((k, n), 0.0) + dt

    def intervals(self) -> dict[tuple[int, int], dict]:
        """Truth per (lane, interval index) for every interval up to the last frame's."""
        if self.t0_s is None:
            return {}
        n_int = self.index(self._last_t, frame_end=True) + 1
        out = {}
        nan = float("nan")
        for k in range(self.n_lanes):
            cr = sorted(self.crossings.get(k, []), key=lambda c: c.t_s)
            per: dict[int, list[tuple[_Crossing, float, float]]] = {}
            for j, c in enumerate(cr):
                h = g = nan
                if j > 0:
                    lead = cr[j - 1]
                    h = c.t_s - lead.t_s
                    g = max(h - lead.length_m / lead.speed_mps, 0.0) if lead.speed_mps > 0 else nan
                per.setdefault(self.index(c.t_s), []).append((c, h, g))
            for n in range(n_int):
                done = per.get(n, [])
                speeds = np.array([c.speed_mps for c, _, _ in done]) * 3.6
                hs = [h for _, h, _ in done if math.isfinite(h)]
                gs = [g for _, _, g in done if math.isfinite(g)]
                counts = {name: 0 for name in self.class_names}
                for c, _, _ in done:
                    counts[length_class(c.length_m, self.class_edges_m, self.class_names)] += 1
                out[(k, n)] = {
                    "volume": len(done),
                    "occupancy_pct": 100.0 * self.occupied_s.get((k, n), 0.0) / self.interval_s,
                    "mean_speed_kmh": float(speeds.mean()) if speeds.size else nan,
                    "speed_p85_kmh": float(np.percentile(speeds, 85)) if speeds.size else nan,
                    "headway_s": float(np.mean(hs)) if hs else nan,
                    "gap_s": float(np.mean(gs)) if gs else nan,
                    "mean_length_m": float(np.mean([c.length_m for c, _, _ in done])) if done else nan,
                    "class_counts": counts,
                }
        return out


def _errors(values: list[float], tol: float | None) -> dict:
    """Summary of signed errors: n, mean, mean absolute, largest absolute, sd, share within ``tol``."""
    e = np.asarray([v for v in values if math.isfinite(v)], dtype=np.float64)
    if not e.size:
        return {"n": 0, "mean": None, "mean_abs": None, "max_abs": None, "sd": None,
                **({"within_tolerance": None, "tolerance": tol} if tol is not None else {})}
    out = {"n": int(e.size), "mean": float(e.mean()), "mean_abs": float(np.abs(e).mean()),
           "max_abs": float(np.abs(e).max()), "sd": float(e.std())}
    if tol is not None:
        out["within_tolerance"] = float(np.mean(np.abs(e) <= tol))
        out["tolerance"] = tol
    return out


def _f(x) -> float:
    return float("nan") if x is None else float(x)


def score_intervals(records, truth: dict[tuple[int, int], dict], t0_s: float, interval_s: float,
                    class_names: tuple[str, ...]) -> dict:
    """Errors of the traffic layer's closed interval records (``LaneStats``) against ``truth``
    (:meth:`LaneIntervalTruth.intervals`): over all lanes and per lane, plus every interval's pair."""
    rows = []
    for ls in records:
        n = int(round((ls.interval_start_ns * 1e-9 - t0_s) / interval_s))
        tr = truth.get((ls.lane, n))
        if tr is None:
            continue
        gap_t, gap_m = tr["gap_s"], _f(ls.gap_s)
        counts_m = dict(ls.class_counts)
        rows.append({
            "lane": int(ls.lane), "interval": n, "start_s": round(ls.interval_start_ns * 1e-9 - t0_s, 3),
            "volume": [int(ls.volume), tr["volume"]],
            "occupancy_pct": [_f(ls.occupancy_pct), tr["occupancy_pct"]],
            "mean_speed_kmh": [_f(ls.mean_speed_kmh), tr["mean_speed_kmh"]],
            "speed_p85_kmh": [_f(ls.speed_p85_kmh), tr["speed_p85_kmh"]],
            "headway_s": [_f(ls.headway_s), tr["headway_s"]],
            "gap_s": [gap_m, gap_t],
            "mean_length_m": [_f(getattr(ls, "mean_length_m", float("nan"))), tr["mean_length_m"]],
            "class_counts": {c: [int(counts_m.get(c, 0)), tr["class_counts"].get(c, 0)] for c in
                             list(class_names) + sorted(set(counts_m) - set(class_names))},
        })

    def summary(sel: list[dict]) -> dict:
        d = lambda key: [m - t for m, t in (r[key] for r in sel)]  # noqa: E731
        gap_pct = [100.0 * (m - t) / t for m, t in (r["gap_s"] for r in sel) if math.isfinite(t) and t > 0]
        gaps_m = [m for m, t in (r["gap_s"] for r in sel) if math.isfinite(m) and math.isfinite(t)]
        gaps_t = [t for m, t in (r["gap_s"] for r in sel) if math.isfinite(m) and math.isfinite(t)]
        classes = sorted({c for r in sel for c in r["class_counts"]}, key=lambda c: (c not in class_names, c))
        return {
            "intervals": len(sel),
            "volume_error": _errors(d("volume"), None),
            "occupancy_error_pp": _errors(d("occupancy_pct"), TOLERANCES["occupancy_pct"]),
            "mean_speed_error_kmh": _errors(d("mean_speed_kmh"), TOLERANCES["mean_speed_kmh"]),
            "speed_p85_error_kmh": _errors(d("speed_p85_kmh"), TOLERANCES["speed_p85_kmh"]),
            "headway_error_s": _errors(d("headway_s"), None),
            "gap_error_s": _errors(d("gap_s"), None),
            "gap_error_pct": _errors(gap_pct, TOLERANCES["gap_pct"]),
            # the gap over all intervals with both values: the run's mean gap, measured against true
            "gap_mean_s": [float(np.mean(gaps_m)) if gaps_m else None, float(np.mean(gaps_t)) if gaps_t else None],
            "gap_intervals_na": sum(1 for r in sel
                                    if not math.isfinite(r["gap_s"][0]) and math.isfinite(r["gap_s"][1])),
            "mean_length_error_m": _errors(d("mean_length_m"), None),
            "class_count_error": {c: _errors([r["class_counts"].get(c, [0, 0])[0] - r["class_counts"].get(c, [0, 0])[1]
                                              for r in sel], None) for c in classes},
        }

    lanes = sorted({r["lane"] for r in rows})
    return {"all_lanes": summary(rows),
            "per_lane": {str(k): summary([r for r in rows if r["lane"] == k]) for k in lanes},
            "records": rows}


def score_vehicles(vehicles: list[dict], class_names: tuple[str, ...]) -> dict:
    """Length and length class of each vehicle that crossed the line (``vehicles``: ``kind``, ``class`` (the
    simulator's body class), ``length_m_true``, ``length_m_est`` (None: n/a), ``length_class_true`` (of the true
    length), ``length_class_est`` (None: not measured)) by kind and by body class: the length error over the
    measured ones, the measured share, and the class accuracy against the true length's class and the body class
    (the n/a ones count as wrong)."""
    def group(sel: list[dict]) -> dict:
        err = [v["length_m_est"] - v["length_m_true"] for v in sel if v["length_m_est"] is not None]
        e = np.asarray(err, dtype=np.float64)
        n = len(sel)
        return {
            "vehicles": n,
            "length_measured_fraction": (len(err) / n) if n else None,
            "class_measured_fraction": (sum(v["length_class_est"] is not None for v in sel) / n) if n else None,
            "length_error_m": ({"mean": float(e.mean()), "sd": float(e.std()), "mean_abs": float(np.abs(e).mean()),
                                "p5": float(np.percentile(e, 5)), "p95": float(np.percentile(e, 95))}
                               if e.size else None),
            "length_class_accuracy": ((sum(v["length_class_est"] == v["length_class_true"] for v in sel) / n)
                                      if n else None),
            "body_class_accuracy": (sum(v["length_class_est"] == v["class"] for v in sel) / n) if n else None,
        }
    return {
        "by_kind": {k: group([v for v in vehicles if v["kind"] == k]) for k in sorted({v["kind"] for v in vehicles})},
        "by_class": {c: group([v for v in vehicles if v["class"] == c])
                     for c in sorted({v["class"] for v in vehicles})},
        "all": group(vehicles),
    }
