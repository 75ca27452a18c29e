"""Scenario generators for road traffic on the SIMO board (registered in ``hw_sim.scenario.GENERATORS``).

TOML tables (units in names; lanes are indices into the scenario's ``[[lane]]`` list)::

    [[vehicle]]                  # one extended vehicle (hw_sim.vehicles)
    id = 1                       # required, unique positive integer
    kind = "car"                 # car | van | truck | bus | motorcycle
    lane = 1                     # required
    y_m = 200.0                  # along-road position of the reference point at t = 0 (required)
    speed_kmh = 90.0             # travel speed; the lane's direction sets the sign
    x_offset_m = 0.0             # lateral offset from the lane centre
    wrong_way = false            # drive against the lane's direction (a wrong-way driver)
    lane_change_to = 2           # optional: target lane of a lane change ...
    lane_change_at_s = 2.0       # ... starting at this time
    lane_change_duration_s = 4.0
    stop_at_s = 3.0              # optional stop-and-go: start braking at this time ...
    decel_mps2 = 3.0             # ... with this deceleration, stand for ...
    stop_s = 4.0                 # ... this long, then accelerate back to speed_kmh at
    accel_mps2 = 1.5
    length_m = 4.5               # default: drawn from the body type's range
    rcs_m2 = 10.0                # default: the body type's
    swerling = 0                 # extra whole-body fluctuation (the glint already fluctuates per frame)
    start_s = 0.0                # active window (default: always)
    end_s = 1e9

    [[traffic]]                  # random traffic, per lane
    lanes = [0, 1, 2, 3]         # default: every lane
    flow_veh_h = 1200.0          # vehicles per hour and lane
    speed_kmh_mean = 100.0
    speed_kmh_sd = 10.0
    speed_kmh_min = 40.0
    min_headway_s = 1.2          # time headway is min_headway_s + exponential
    range_m = 320.0              # vehicles enter/leave this far from the radar
    mix = { car = 0.72, van = 0.1, truck = 0.12, bus = 0.02, motorcycle = 0.04 }
    lateral_offset_sd_m = 0.25   # each driver's own offset from the lane centre (normal, clipped at 2.5 sd)
    weave_sdlp_m = 0.2           # each driver's slow wander inside the lane (SDLP, a sinusoid of ...
    weave_period_s = [8.0, 20.0] # ... a period drawn uniformly from this range and a random phase)
                                 # (on-road driving tests at motorway speed measure SDLPs of about 0.2 m;
                                 # defaults: Physics.lateral_offset_sd_m and Physics.weave_sdlp_m, 0 in the v1 preset)

    [[guardrail]]                # static posts along the road (clutter)
    x_m = -7.5
    y_from_m = 5.0
    y_to_m = 250.0
    spacing_m = 4.0
    z_m = 0.75
    rcs_m2 = 0.5

    [[multipath]]                # optional ghosts: every vehicle mirrored in a vertical reflector
    plane_x_m = 8.0              # (noise barrier, guard rail) at this lateral position
    loss_db = 12.0               # the ghost's RCS is the vehicle's reduced by this

Random vehicles get ids after the largest explicit id. ``Physics.traffic_model`` chooses how they drive:

* ``"idm"`` (default): each driver's desired speed is drawn as above; the Intelligent Driver Model (Treiber, Hennecke
  & Helbing 2000) follows the vehicle ahead and MOBIL (Kesting, Treiber & Helbing 2007) changes to an adjacent lane
  of the same direction (of this table's lanes) when a safe gap offers a gain, so fast drivers overtake slow ones.
  The motion is integrated once at scene build (:func:`_idm_traffic`) and kept as sampled paths.
* ``"v1"``: constant speeds, and vehicles in one lane never overtake each other: a follower that would catch up
  inside the road section takes its leader's speed (so platoons form behind slow vehicles, as on a road without
  overtaking, and the mean speed on the road is below ``speed_kmh_mean``).

Either way the mean speed on the road is below ``speed_kmh_mean``. Traffic is generated from before ``t = 0`` so that
the road is already populated when the scenario starts. Explicit ``[[vehicle]]`` tables are not part of the car
following (they drive their own profiles). A ghost is a
:class:`hw_sim.scene.Target` of class ``clutter`` with no lane: a track on it is a false track.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from hw_sim.scenario import GENERATORS, Scenario, ScenarioError, _num
from hw_sim.scene import Clutter, Scene, Target
from hw_sim.vehicles import BODY_TYPES, RoadTrajectory, SampledTrajectory, Vehicle, make_vehicle

#: vehicles enter "away" lanes this far behind the radar's foot (under the overpass)
AWAY_ENTRY_Y_M = -20.0
DEFAULT_MIX = {"car": 0.72, "van": 0.10, "truck": 0.12, "bus": 0.02, "motorcycle": 0.04}


def _lane(sc: Scenario, spec: dict, key: str, where: str) -> int:
    ln = spec.get(key)
    if not isinstance(ln, int) or not 0 <= ln < len(sc.lanes):
        raise ScenarioError(f"{where}{key} must be a lane index 0..{len(sc.lanes) - 1}, got {ln!r}")
    return ln


def _direction(sc: Scenario, lane: int) -> int:
    return 1 if sc.lanes[lane].direction == "away" else -1


def _next_id(scene: Scene) -> int:
    return max((t.id for t in scene.targets), default=0) + 1


def build_vehicle(scene: Scene, sc: Scenario, spec: dict, rng: np.random.Generator) -> None:
    where = f"{sc.source}: vehicle."
    vid = spec.get("id")
    if not isinstance(vid, int) or vid <= 0:
        raise ScenarioError(f"{where}id must be a positive integer, got {vid!r}")
    kind = spec.get("kind", "car")
    if kind not in BODY_TYPES:
        raise ScenarioError(f"{where}kind must be one of {', '.join(BODY_TYPES)}, got {kind!r}")
    lane = _lane(sc, spec, "lane", where)
    d = _direction(sc, lane)
    wrong = spec.get("wrong_way", False)
    if not isinstance(wrong, bool):
        raise ScenarioError(f"{where}wrong_way must be true or false, got {wrong!r}")
    if wrong:
        d = -d
    v = _num(spec, "speed_kmh", 90.0, where) / 3.6
    x0 = sc.lanes[lane].center_x_m + _num(spec, "x_offset_m", 0.0, where)
    y0 = _num(spec, "y_m", where=where)
    knots_t, knots_v = [0.0], [v]
    if "stop_at_s" in spec:
        t0 = _num(spec, "stop_at_s", where=where)
        dec = _num(spec, "decel_mps2", 3.0, where)
        acc = _num(spec, "accel_mps2", 1.5, where)
        wait = _num(spec, "stop_s", 4.0, where)
        if dec <= 0 or acc <= 0 or wait < 0:
            raise ScenarioError(f"{where}decel_mps2 and accel_mps2 must be > 0, stop_s >= 0")
        t1 = t0 + v / dec
        t2 = t1 + wait
        knots_t, knots_v = [min(0.0, t0), t0, t1, t2, t2 + v / acc], [v, v, 0.0, 0.0, v]
    changes, switch = (), ()
    if "lane_change_to" in spec:
        to = _lane(sc, spec, "lane_change_to", where)
        t_lc = _num(spec, "lane_change_at_s", 0.0, where)
        dur = _num(spec, "lane_change_duration_s", 4.0, where)
        if dur <= 0:
            raise ScenarioError(f"{where}lane_change_duration_s must be > 0")
        changes = ((t_lc, dur, sc.lanes[to].center_x_m - sc.lanes[lane].center_x_m),)
        switch = ((t_lc + dur / 2.0, to),)
    # the trajectory's speed profile is anchored at t = 0 where the vehicle is at y0
    traj = RoadTrajectory(x0, 0.0, d, tuple(knots_t), tuple(knots_v), changes)
    traj = RoadTrajectory(x0, y0 - float(traj.position(0.0)[1]), d, tuple(knots_t), tuple(knots_v), changes)
    try:
        veh = make_vehicle(
            vid, kind, traj, lane=lane, rng=rng,
            t_start_s=_num(spec, "start_s", -math.inf, where) if "start_s" in spec else -math.inf,
            t_end_s=_num(spec, "end_s", math.inf, where) if "end_s" in spec else math.inf,
            length_m=spec.get("length_m"), rcs_m2=spec.get("rcs_m2"), swerling=int(spec.get("swerling", 0)),
            lane_switch=switch, physics=scene.physics,
        )
        scene.add_target(veh)
    except ValueError as exc:
        raise ScenarioError(f"{where}{exc}") from None


def build_traffic(scene: Scene, sc: Scenario, spec: dict, rng: np.random.Generator) -> None:
    where = f"{sc.source}: traffic."
    if not sc.lanes:
        raise ScenarioError(f"{where}random traffic needs [[lane]] tables")
    lanes = spec.get("lanes", list(range(len(sc.lanes))))
    if not isinstance(lanes, list) or any(not isinstance(x, int) or not 0 <= x < len(sc.lanes) for x in lanes):
        raise ScenarioError(f"{where}lanes must be a list of lane indices, got {lanes!r}")
    flow = _num(spec, "flow_veh_h", 1200.0, where)
    v_mean = _num(spec, "speed_kmh_mean", 100.0, where) / 3.6
    v_sd = _num(spec, "speed_kmh_sd", 10.0, where) / 3.6
    v_min = _num(spec, "speed_kmh_min", 40.0, where) / 3.6
    h_min = _num(spec, "min_headway_s", 1.2, where)
    r_max = _num(spec, "range_m", 320.0, where)
    mix = spec.get("mix", DEFAULT_MIX)
    if not isinstance(mix, dict) or not mix or any(k not in BODY_TYPES for k in mix):
        raise ScenarioError(f"{where}mix must map vehicle kinds ({', '.join(BODY_TYPES)}) to weights")
    kinds = list(mix)
    w = np.array([float(mix[k]) for k in kinds])
    if flow <= 0 or v_mean <= 0 or h_min <= 0 or (w < 0).any() or w.sum() <= 0:
        raise ScenarioError(f"{where}flow_veh_h, speed_kmh_mean, min_headway_s and mix weights must be positive")
    w = w / w.sum()
    off_sd = _num(spec, "lateral_offset_sd_m", scene.physics.lateral_offset_sd_m, where)
    sdlp = _num(spec, "weave_sdlp_m", scene.physics.weave_sdlp_m, where)
    period = spec.get("weave_period_s", [8.0, 20.0])
    if (off_sd < 0 or sdlp < 0 or not isinstance(period, list) or len(period) != 2
            or not all(isinstance(p, (int, float)) for p in period) or not 0 < period[0] <= period[1]):
        raise ScenarioError(f"{where}lateral_offset_sd_m and weave_sdlp_m must be >= 0 and weave_period_s a range "
                            f"[shortest, longest] of positive seconds")
    path_m = r_max - AWAY_ENTRY_Y_M
    t_fill = path_m / max(v_min, 1.0)
    mean_gap = 3600.0 / flow
    vid = _next_id(scene)
    made: list[Vehicle] = []
    if scene.physics.traffic_model == "idm":
        made = _idm_traffic(scene, sc, lanes, rng, vid=vid, kinds=kinds, weights=w, t_from=-t_fill, path_m=path_m,
                            r_max=r_max, mean_gap=mean_gap, h_min=h_min, v_mean=v_mean, v_sd=v_sd, v_min=v_min)
    for lane in (lanes if scene.physics.traffic_model == "v1" else ()):
        d = _direction(sc, lane)
        y_entry = r_max if d < 0 else AWAY_ENTRY_Y_M
        x0 = sc.lanes[lane].center_x_m
        t = -t_fill
        prev_t, prev_v = None, None
        while t < sc.duration_s:
            t += h_min + rng.exponential(max(mean_gap - h_min, 1e-3))
            v = max(v_min, rng.normal(v_mean, v_sd))
            if prev_v is not None and v > prev_v:
                d0 = (t - prev_t) * prev_v  # leader's lead when the follower enters
                if v * d0 / (v - prev_v) < path_m + 50.0:  # would catch up on the road section
                    v = prev_v
            kind = kinds[int(rng.choice(len(kinds), p=w))]
            traj = RoadTrajectory(x0, y_entry, d, (t,), (v,))
            made.append(make_vehicle(vid, kind, traj, lane=lane, rng=rng, t_start_s=t, t_end_s=t + path_m / v,
                                     physics=scene.physics))
            vid += 1
            prev_t, prev_v = t, v
    if off_sd > 0 or sdlp > 0:
        # drawn after the traffic itself, so that the same seed gives the same vehicles with or without them
        n = len(made)
        off = np.clip(rng.normal(0.0, 1.0, n), -2.5, 2.5) * off_sd
        per = rng.uniform(float(period[0]), float(period[1]), n)
        phase = rng.uniform(0.0, 2.0 * math.pi, n)
        for veh, o, p, ph in zip(made, off.tolist(), per.tolist(), phase.tolist()):
            tr = veh.trajectory
            veh.trajectory = dataclasses.replace(tr, x0_m=tr.x0_m + o,
                                                 weave=(sdlp * math.sqrt(2.0), p, ph) if sdlp > 0 else None)
            if veh.lane_switch:
                veh.lane_switch = _crossings(veh, sc)
    for veh in made:
        scene.add_target(veh)


#: Intelligent Driver Model, motorway parameters of Treiber, Hennecke & Helbing, Phys. Rev. E 62, 1805 (2000),
#: Table 1: safe time headway T (s), maximum acceleration a (m/s^2), comfortable deceleration b (m/s^2), jam
#: distance s0 (m), acceleration exponent delta. Each driver's desired speed v0 is drawn from the [[traffic]] table.
IDM_T_S, IDM_A_MPS2, IDM_B_MPS2, IDM_S0_M, IDM_DELTA = 1.6, 0.73, 1.67, 2.0, 4
#: integration step (s) of the precomputed traffic (ballistic update; Treiber & Kesting, Traffic Flow Dynamics,
#: Springer 2013, ch. 11: steps up to ~0.5 s are accurate for the IDM)
IDM_DT_S = 0.25
#: MOBIL lane-change rule (Kesting, Treiber & Helbing, Transp. Res. Rec. 1999, 86, 2007): a driver changes to an
#: adjacent lane of the same direction when the new follower need not brake harder than b_safe (m/s^2) and its own
#: acceleration gain plus politeness p times the followers' gains exceeds the threshold (m/s^2); p is drawn per driver
#: uniformly from [0, MOBIL_POLITENESS_MAX] (the paper's range 0-0.5)
MOBIL_B_SAFE_MPS2, MOBIL_THRESHOLD_MPS2, MOBIL_POLITENESS_MAX = 4.0, 0.1, 0.5
#: smallest time gap (s) a driver accepts to the new leader and leaves to the new follower (at the follower's
#: speed, plus s0); accepted merging gaps on motorways are rarely below ~1 s (e.g. Daamen, Loot & Hoogendoorn,
#: Transp. Res. Rec. 2188, 2010)
MOBIL_MIN_TIME_GAP_S = 0.8
#: how often (s) a driver considers a lane change, how long (s) the half-cosine lateral move takes (lane changes on
#: motorways last 3-6 s, mean ~4.6 s: Toledo & Zohar, Transp. Res. Rec. 1999, 2007), and the pause (s) after one
MOBIL_CHECK_S, LANE_CHANGE_S, LANE_CHANGE_PAUSE_S = 1.0, 4.0, 10.0


def _crossings(veh: Vehicle, sc: Scenario) -> tuple[tuple[float, int], ...]:
    """Truth lane switches of a lane-changing vehicle: when its reference point, with its own offset and weave,
    crosses the boundary to the new lane (sampled every 10 ms inside each lane change)."""
    centres = np.array([ln.center_x_m for ln in sc.lanes])
    out = []
    for (t0, dur, _dx), (_t_mid, new) in zip(veh.trajectory.lane_changes, veh.lane_switch):
        t = np.arange(t0, t0 + dur + 0.01, 0.01)
        x = veh.trajectory.position(t)[:, 0]
        inside = np.argmin(np.abs(x[:, None] - centres[None, :]), axis=1) == new
        out.append((float(t[np.argmax(inside)]) if inside.any() else t0 + dur / 2.0, new))
    return tuple(out)


def _idm_acc(v, v0, gap, dv):
    """IDM acceleration (m/s^2) at speed ``v`` with desired speed ``v0``, bumper-to-bumper ``gap`` (m; inf on a free
    road) and approach rate ``dv = v - v_leader``."""
    s_star = IDM_S0_M + np.maximum(0.0, v * IDM_T_S + v * dv / (2.0 * math.sqrt(IDM_A_MPS2 * IDM_B_MPS2)))
    return IDM_A_MPS2 * (1.0 - (v / v0) ** IDM_DELTA - (s_star / np.maximum(gap, 0.1)) ** 2)


def _idm_traffic(scene: Scene, sc: Scenario, lanes: list[int], rng: np.random.Generator, *, vid: int, kinds, weights,
                 t_from: float, path_m: float, r_max: float, mean_gap: float, h_min: float, v_mean: float,
                 v_sd: float, v_min: float) -> list[Vehicle]:
    """Random traffic driven by the IDM with MOBIL lane changes, integrated at scene build on a grid of
    :data:`IDM_DT_S` from ``t_from`` to the scenario's end and kept as :class:`SampledTrajectory` paths.

    Arrivals per lane as in the v1 model (time headway ``h_min`` + exponential, desired speed normal, at least
    ``v_min``); a vehicle enters once the gap to the last one in its lane is safe, at its desired speed or, when
    that would close in too fast, at its leader's. Lane changes only between adjacent lanes of this table of the
    same direction; the truth lane switches at the middle of the move."""
    n_steps = int(math.ceil((sc.duration_s + 1.0 - t_from) / IDM_DT_S)) + 1
    check_every = max(1, int(round(MOBIL_CHECK_S / IDM_DT_S)))
    made: list[Vehicle] = []
    groups: dict[int, list[int]] = {}
    for ln in lanes:
        groups.setdefault(_direction(sc, ln), []).append(ln)
    # arrivals of every lane, drawn lane by lane
    arr: list[tuple[int, float, float, str, float, float]] = []  # (lane, t, v0, kind, length, politeness)
    for lane in lanes:
        t = t_from
        while t < sc.duration_s:
            t += h_min + rng.exponential(max(mean_gap - h_min, 1e-3))
            v0 = max(v_min, rng.normal(v_mean, v_sd))
            kind = kinds[int(rng.choice(len(kinds), p=weights))]
            length = float(rng.uniform(*BODY_TYPES[kind].length_m))
            arr.append((lane, t, v0, kind, length, float(rng.uniform(0.0, MOBIL_POLITENESS_MAX))))
    for d, group in sorted(groups.items()):
        xs = {ln: sc.lanes[ln].center_x_m for ln in group}
        order_x = sorted(group, key=lambda ln: xs[ln])
        spacing = min((abs(xs[b] - xs[a]) for a, b in zip(order_x, order_x[1:])), default=0.0)
        adjacent = {ln: [m for m in order_x if m != ln and abs(xs[m] - xs[ln]) <= 1.5 * spacing] for ln in group}
        mine = [a for a in arr if a[0] in xs]
        n = len(mine)
        lane = np.array([a[0] for a in mine])
        t_arr = np.array([a[1] for a in mine])
        v0 = np.array([a[2] for a in mine])
        length = np.array([a[4] for a in mine])
        polite = np.array([a[5] for a in mine])
        s = np.zeros(n)
        v = np.zeros(n)
        state = np.zeros(n, dtype=np.int8)  # 0 waiting to enter, 1 on the road, 2 gone
        first = np.full(n, -1)
        last = np.full(n, -1)
        pause_until = np.full(n, -math.inf)
        changes: list[list[tuple[float, float, float]]] = [[] for _ in range(n)]
        switches: list[list[tuple[float, int]]] = [[] for _ in range(n)]
        entry_lane = lane.copy()
        S = np.full((n_steps, n), np.nan)
        V = np.full((n_steps, n), np.nan)
        waiting = {ln: [i for i in np.argsort(t_arr, kind="stable") if lane[i] == ln] for ln in group}

        def neighbours(on: np.ndarray):
            """Leader index (-1: none) of every vehicle on the road, per current lane."""
            lead = np.full(n, -1)
            for ln in group:
                idx = on[lane[on] == ln]
                if idx.size > 1:
                    o = idx[np.argsort(-s[idx], kind="stable")]
                    lead[o[1:]] = o[:-1]
            return lead

        def gap_to(i, j):
            return s[j] - s[i] - 0.5 * (length[i] + length[j])

        def acc_behind(i, j):
            """IDM acceleration of ``i`` behind ``j`` (-1: free road)."""
            if j < 0:
                return float(_idm_acc(v[i], v0[i], math.inf, 0.0))
            return float(_idm_acc(v[i], v0[i], gap_to(i, j), v[i] - v[j]))

        for k in range(n_steps):
            t = t_from + k * IDM_DT_S
            # entries
            for ln in group:
                q = waiting[ln]
                while q and t_arr[q[0]] <= t:
                    i = q[0]
                    in_lane = np.flatnonzero((state == 1) & (lane == ln))
                    ve = v0[i]
                    if in_lane.size:
                        j = in_lane[np.argmin(s[in_lane])]
                        g = s[j] - 0.5 * (length[i] + length[j])
                        if g < IDM_S0_M + v[j] * 0.6 * IDM_T_S:
                            break  # no safe gap yet: the vehicle waits at the entry
                        if g < IDM_S0_M + ve * IDM_T_S:
                            ve = min(ve, v[j])
                    q.pop(0)
                    state[i], s[i], v[i], first[i] = 1, 0.0, ve, k
            on = np.flatnonzero(state == 1)
            lead = neighbours(on)
            # lane changes (MOBIL), drivers in random order
            if k % check_every == 0 and on.size:
                for i in rng.permutation(on):
                    if t < pause_until[i] or not 20.0 < s[i] < path_m - 60.0:
                        continue
                    a_now = acc_behind(i, lead[i])
                    of = np.flatnonzero((lead == i) & (state == 1))
                    of = int(of[0]) if of.size else -1
                    best, best_gain = None, MOBIL_THRESHOLD_MPS2
                    for ln in adjacent[lane[i]]:
                        cand = on[(lane[on] == ln) & (on != i)]
                        ahead, behind = cand[s[cand] >= s[i]], cand[s[cand] < s[i]]
                        nl = int(ahead[np.argmin(s[ahead])]) if ahead.size else -1
                        nf = int(behind[np.argmax(s[behind])]) if behind.size else -1
                        if ((nl >= 0 and gap_to(i, nl) < IDM_S0_M + MOBIL_MIN_TIME_GAP_S * v[i])
                                or (nf >= 0 and gap_to(nf, i) < IDM_S0_M + MOBIL_MIN_TIME_GAP_S * v[nf])):
                            continue
                        nf_new = acc_behind(nf, i) if nf >= 0 else 0.0
                        if nf_new < -MOBIL_B_SAFE_MPS2:
                            continue
                        gain = acc_behind(i, nl) - a_now
                        if nf >= 0:
                            gain += polite[i] * (nf_new - acc_behind(nf, nl))
                        if of >= 0:
                            gain += polite[i] * (acc_behind(of, lead[i]) - acc_behind(of, i))
                        if gain > best_gain:
                            best, best_gain = ln, gain
                    if best is not None:
                        changes[i].append((t, LANE_CHANGE_S, xs[best] - xs[lane[i]]))
                        switches[i].append((t + LANE_CHANGE_S / 2.0, int(best)))
                        lane[i] = best
                        pause_until[i] = t + LANE_CHANGE_S + LANE_CHANGE_PAUSE_S
                        lead = neighbours(on)
            # car following: ballistic update
            if on.size:
                has = lead[on] >= 0
                gap = np.full(on.size, math.inf)
                dv = np.zeros(on.size)
                li = lead[on][has]
                gap[has] = s[li] - s[on][has] - 0.5 * (length[on][has] + length[li])
                dv[has] = v[on][has] - v[li]
                a = _idm_acc(v[on], v0[on], gap, dv)
                S[k, on], V[k, on] = s[on], v[on]
                v_new = v[on] + a * IDM_DT_S
                stop = v_new < 0.0
                ds = np.where(stop, -v[on] ** 2 / (2.0 * np.minimum(a, -1e-9)),  # comes to a stop inside the step
                              v[on] * IDM_DT_S + 0.5 * a * IDM_DT_S ** 2)
                s[on] += ds
                v[on] = np.maximum(v_new, 0.0)
                last[on] = k
                gone = on[s[on] - 0.5 * length[on] > path_m]
                state[gone] = 2
        y_entry = r_max if d < 0 else AWAY_ENTRY_Y_M
        for i in range(n):
            if first[i] < 0:
                continue
            a, b = first[i], last[i]
            t0 = t_from + a * IDM_DT_S
            traj = SampledTrajectory(
                xs[int(entry_lane[i])], y_entry, d, (t0,), (float(V[a, i]),), tuple(changes[i]),
                t0_s=t0, dt_s=IDM_DT_S, s_m=S[a:b + 1, i].copy(), v_mps=V[a:b + 1, i].copy())
            t_end = t_from + b * IDM_DT_S if state[i] == 2 else math.inf
            made.append(make_vehicle(vid + i, mine[i][3], traj, lane=int(entry_lane[i]), rng=rng, t_start_s=t0,
                                     t_end_s=t_end, length_m=float(length[i]), lane_switch=tuple(switches[i]),
                                     physics=scene.physics))
        vid += n
    made.sort(key=lambda veh: veh.id)
    return made


def build_guardrail(scene: Scene, sc: Scenario, spec: dict, rng: np.random.Generator) -> None:
    where = f"{sc.source}: guardrail."
    x = _num(spec, "x_m", where=where)
    y0, y1 = _num(spec, "y_from_m", 5.0, where), _num(spec, "y_to_m", 250.0, where)
    step = _num(spec, "spacing_m", 4.0, where)
    if step <= 0 or y1 < y0:
        raise ScenarioError(f"{where}spacing_m must be > 0 and y_to_m >= y_from_m")
    ys = np.arange(y0, y1 + 1e-9, step)
    pos = np.stack([np.full(ys.size, x), ys, np.full(ys.size, _num(spec, "z_m", 0.75, where))], axis=1)
    rcs = np.full(ys.size, _num(spec, "rcs_m2", 0.5, where))
    if scene.clutter is None:
        scene.clutter = Clutter(pos, rcs)
    else:
        scene.clutter = Clutter(np.concatenate([scene.clutter.position_m, pos]), np.concatenate([scene.clutter.rcs_m2, rcs]))


@dataclass(frozen=True)
class MirroredTrajectory:
    """The image of a trajectory in the vertical plane ``x = plane_x_m``."""

    inner: object
    plane_x_m: float

    def position(self, t_s):
        p = np.array(self.inner.position(t_s), dtype=np.float64)
        p[..., 0] = 2.0 * self.plane_x_m - p[..., 0]
        return p

    def velocity(self, t_s):
        v = np.array(self.inner.velocity(t_s), dtype=np.float64)
        v[..., 0] = -v[..., 0]
        return v


def build_multipath(scene: Scene, sc: Scenario, spec: dict, rng: np.random.Generator) -> None:
    where = f"{sc.source}: multipath."
    px = _num(spec, "plane_x_m", where=where)
    gain = 10.0 ** (-_num(spec, "loss_db", 12.0, where) / 10.0)
    vid = max(_next_id(scene), 1_000_000)
    for tg in [t for t in scene.targets if isinstance(t, Vehicle)]:
        scene.add_target(Target(
            id=vid, cls="clutter", trajectory=MirroredTrajectory(tg.trajectory, px),
            offsets_m=tg.offsets_m, rcs_m2=tg.rcs_m2 * gain, swerling=tg.swerling, lane=None,
            t_start_s=tg.t_start_s, t_end_s=tg.t_end_s,
        ))
        vid += 1


# order matters: explicit vehicles first, random traffic after them, ghosts of all vehicles last
GENERATORS["vehicle"] = build_vehicle
GENERATORS["traffic"] = build_traffic
GENERATORS["guardrail"] = build_guardrail
GENERATORS["multipath"] = build_multipath
