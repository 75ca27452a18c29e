"""Counts at the detection line scored against the truth: shared by the lane evaluation
(:mod:`edge.evaluation.lane`) and the replay of its recorded tracks (:mod:`edge.evaluation.track_log`).

* measured volume per lane: the volumes of the traffic layer's closed intervals plus the crossings of the open
  one (:meth:`CountTally.add_frame`, :meth:`CountTally.close`);
* counted crossings ``(lane, t_s, speed km/h)``: as the traffic layer appends them to each lane's recent ones;
* true crossings ``(lane, t_s, vehicle id, class[, either lane])``: of the vehicles' reference points, found by the
  caller; ``either lane`` (-1: none) is the neighbouring lane the vehicle's body straddles into at the line;
* ``count_mismatches``: per lane, the two lists matched one-to-one by time (at most ``COUNT_MATCH_S`` apart), the
  unmatched true ones ``missed`` and the unmatched counted ones ``extra``; ``straddling``: the missed crossings of
  straddling vehicles that were counted in the lane they straddle into (an extra there within ``COUNT_MATCH_S``);
* ``volume_measured_either_per_lane``: the measured volumes with those counts given back to the true lane (a
  loop detector under a straddling vehicle may count it in either lane), for ``count_abs_error_either``.
"""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np
from scipy.optimize import linear_sum_assignment

COUNT_MATCH_S = 2.0  # a counted crossing this close in time to a true one in the lane is that vehicle's


def count_mismatches(true_cross: list, meas_cross: list, n_lanes: int) -> dict:
    """``{"missed": [...], "extra": [...], "straddling": [...]}``: true crossings (lane, t_s, vehicle id, class[,
    either lane]) and counted ones (lane, t_s, speed km/h) left over when each lane's two lists are matched
    one-to-one minimising the time differences, pairs further apart than ``COUNT_MATCH_S`` not allowed. Then each
    missed crossing with an ``either lane``, earliest first, takes the extra of that lane nearest in time within
    ``COUNT_MATCH_S``: the two leave ``missed`` and ``extra`` for ``straddling`` (the true crossing with the lane and
    time it was counted at)."""
    missed, extra, alt = [], [], []
    for k in range(n_lanes):
        t_true = [c for c in true_cross if c[0] == k]
        t_meas = [c for c in meas_cross if c[0] == k]
        dt = np.abs(np.array([c[1] for c in t_true])[:, None] - np.array([c[1] for c in t_meas])[None, :]).reshape(
            len(t_true), len(t_meas))
        cost = np.where(dt <= COUNT_MATCH_S, dt, 1e6)
        r, c = linear_sum_assignment(cost) if cost.size else (np.zeros(0, int), np.zeros(0, int))
        ok = cost[r, c] < 1e6
        mt, mm = set(r[ok].tolist()), set(c[ok].tolist())
        for n, x in enumerate(t_true):
            if n not in mt:
                missed.append({"lane": k, "t_s": round(x[1], 3), "vehicle_id": x[2], "class": x[3]})
                alt.append((x[4] if len(x) > 4 else -1, x[1]))
        extra += [(x[1], {"lane": k, "t_s": round(x[1], 3), "speed_kmh": round(x[2], 1)})
                  for n, x in enumerate(t_meas) if n not in mm]
    straddling, still_missed = [], []
    for n in sorted(range(len(missed)), key=lambda n: alt[n][1]):
        lane_b, t = alt[n]
        cand = [j for j, (te, e) in enumerate(extra) if e["lane"] == lane_b != missed[n]["lane"]
                and abs(te - t) <= COUNT_MATCH_S]
        if cand:
            j = min(cand, key=lambda j: abs(extra[j][0] - t))
            straddling.append({**missed[n], "counted_lane": lane_b, "counted_t_s": extra.pop(j)[1]["t_s"]})
        else:
            still_missed.append(n)
    return {"missed": [missed[n] for n in sorted(still_missed)], "extra": [e for _, e in extra],
            "straddling": straddling}


class CountTally:
    """What the traffic layer counted at its detection line over a run, lane by lane (module docstring)."""

    def __init__(self, n_lanes: int) -> None:
        self.n_lanes = n_lanes
        self.measured = np.zeros(n_lanes, dtype=np.int64)
        self.counted: list[tuple[int, float, float]] = []  # (lane, t_s, speed km/h)
        self._seen_last: dict[int, Any] = {}

    def add_frame(self, lane_stats: Iterable, traffic: Any) -> None:
        """After a frame: the volumes of the intervals it closed (``lane_stats``) and the crossings the traffic
        layer (``traffic``, a :class:`edge.traffic.TrafficMonitor` or ``None``) counted in it."""
        for ls in lane_stats:
            if 0 <= ls.lane < self.n_lanes:
                self.measured[ls.lane] += ls.volume
        if traffic is None:
            return
        for k, la in traffic.stats.lanes.items():  # this frame's crossings were appended to each lane's recent ones
            rec = list(la.recent)
            last = self._seen_last.get(k)
            start = next((i + 1 for i in range(len(rec) - 1, -1, -1) if rec[i] is last), 0) if last is not None else 0
            self.counted.extend((k, c.t_ns * 1e-9, c.speed_mps * 3.6) for c in rec[start:])
            if rec:
                self._seen_last[k] = rec[-1]

    def close(self, traffic: Any) -> None:
        """At the end of the run: the crossings of the open interval."""
        if traffic is None:
            return
        for k, la in traffic.stats.lanes.items():
            if 0 <= k < self.n_lanes:
                self.measured[k] += len(la.crossings)

    def summary(self, true_cross: list) -> dict:
        """The count figures of the evaluation report against ``true_cross`` ``[(lane, t_s, vehicle id, class[,
        either lane])]`` (lanes outside ``0..n_lanes - 1`` already left out)."""
        true_volume = np.bincount(np.array([c[0] for c in true_cross], dtype=np.int64), minlength=self.n_lanes)
        mism = count_mismatches(true_cross, self.counted, self.n_lanes)
        either = self.measured.copy()
        for s in mism["straddling"]:  # counted in the lane the vehicle straddled into: given back to its own
            either[s["counted_lane"]] -= 1
            either[s["lane"]] += 1
        return {
            "count_error_per_lane": [int(m - t) for m, t in zip(self.measured, true_volume)],
            "volume_true_per_lane": [int(v) for v in true_volume[: self.n_lanes]],
            "volume_measured_per_lane": [int(v) for v in self.measured],
            "volume_measured_either_per_lane": [int(v) for v in either],
            "count_mismatches": mism,
        }
