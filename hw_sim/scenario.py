"""Scenario files (TOML): the documented way to describe a simulated world.

Schema (every key optional unless marked; units in names)::

    [scenario]
    name = "highway4"            # required
    board = "simo"               # required: "simo" (lane profile) or "d2g" (surveillance profile)
    description = "..."
    duration_s = 30.0            # how long the scenario lasts (frames = duration / frame period)
    seed = 1                     # default seed; a URL or CLI seed overrides it

    [radar]                      # pose, see hw_sim.scene.RadarPose
    x_m = 0.0
    y_m = 0.0
    height_m = 6.0
    yaw_deg = 0.0                # boresight heading, clockwise from +y
    tilt_deg = 1.0               # downward tilt of the boresight
    occluded_behind = false      # on an overpass's face: the deck hides everything behind it
    tx_power = 7                 # Distance2Go only: the board's TX power level 0..7 (7 = full power, the default)

    [[lane]]                     # road lanes (ground truth and lane statistics)
    center_x_m = -5.25
    width_m = 3.5
    direction = "toward"         # "toward" the radar or "away" from it

    [[target]]                   # explicit targets, constant velocity
    id = 1                       # required, small positive integer
    class = "car"                # pedestrian | car | motorcycle | truck | bicycle
    x_m = -1.75                  # reference point at t = start_s
    y_m = 120.0
    z_m = 0.0
    vx_mps = 0.0
    vy_mps = -25.0
    rcs_m2 = 10.0                # one point scatterer of this RCS (extended shapes: later issues)
    swerling = 1                 # 0, 1 or 3
    lane = 2                     # index into [[lane]], omit when not on a lane
    start_s = 0.0                # appears at this time
    end_s = 1e9                  # disappears at this time

    [[clutter]]                  # static scatterers
    x_m = 8.0
    y_m = 40.0
    z_m = 1.0
    rcs_m2 = 30.0

    [[d2g_target]]               # a realistic Distance2Go-site body (hw_sim.events): pedestrian with
    id = 1                       # swinging limbs, car, motorcycle with rider, truck; keys as [[target]]
    class = "pedestrian"         # (x_m, y_m, vx_mps, vy_mps, start_s, end_s), optional rcs_m2 (total)
    x_m = 1.0                    # and stride_hz; size and scatterers random per seed
    y_m = 14.0
    vy_mps = -1.0

    [[d2g_events]]               # random surveillance events (hw_sim.events), one slot of 24 s each
    mode = "single"              # "single" (one target, classes balanced) or "multi" (2-4 targets)
    events = 10

Road traffic on the SIMO board adds the tables ``[[vehicle]]`` (extended vehicles with lane changes and
stop-and-go), ``[[traffic]]`` (random traffic per lane), ``[[guardrail]]`` and ``[[multipath]]``;
their schema is in :mod:`hw_sim.traffic`.

Built-in scenarios live in ``hw_sim/scenarios/*.toml`` and are named by file stem; the event
generators of :data:`EVENT_SCENARIOS` (``single-random``, ``multi-random``) load by name too.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Callable

import numpy as np

from hw_sim.physics import Physics, PhysicsError, parse_physics
from hw_sim.scene import CLASSES, Clutter, LinearTrajectory, RadarPose, Scene, Target


class ScenarioError(ValueError):
    """A scenario file is missing or does not follow the schema; the message names the key."""


BOARDS = ("simo", "d2g")


@dataclass(frozen=True)
class Lane:
    center_x_m: float
    width_m: float = 3.5
    direction: str = "toward"


@dataclass
class Scenario:
    name: str
    board: str
    description: str = ""
    duration_s: float = 30.0
    seed: int = 1
    pose: RadarPose = field(default_factory=RadarPose)
    lanes: tuple[Lane, ...] = ()
    raw: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    physics: Physics = field(default_factory=Physics)
    #: the Distance2Go's TX power level (``[radar] tx_power``); None: the board's full power
    tx_power: int | None = None

    def sim_board(self):
        """The simulated board this scenario runs on, with its ``[physics]`` choices and TX power level applied."""
        from hw_sim.boards import board_for, with_tx_power

        board = board_for(self.board, self.physics)
        return board if self.tx_power is None else with_tx_power(board, self.tx_power)

    def build_scene(self, seed: int | None = None) -> Scene:
        """A fresh, deterministic :class:`Scene` for ``seed`` (defaults to the scenario's)."""
        s = self.seed if seed is None else seed
        scene = Scene(pose=self.pose, seed=s, physics=self.physics)
        for t in _targets(self.raw, self.source):
            scene.add_target(t)
        cl = self.raw.get("clutter", [])
        if cl:
            scene.clutter = Clutter(
                position_m=[[_num(c, "x_m", 0.0), _num(c, "y_m", 0.0), _num(c, "z_m", 0.0)] for c in cl],
                rcs_m2=[_num(c, "rcs_m2", 1.0) for c in cl],
            )
        for gen_name, builder in GENERATORS.items():
            for spec in self.raw.get(gen_name, []):
                builder(scene, self, spec, np.random.default_rng([s, len(scene.targets)]))
        return scene


#: name of a TOML array of tables -> function adding targets to a scene (later issues register
#: random traffic, pedestrian events, ...): builder(scene, scenario, spec, rng)
GENERATORS: dict[str, Callable[[Scene, Scenario, dict, np.random.Generator], None]] = {}


def _bool(d: dict, key: str, where: str = "") -> bool:
    v = d.get(key, False)
    if not isinstance(v, bool):
        raise ScenarioError(f"{where}{key} must be true or false, got {v!r}")
    return v


def _num(d: dict, key: str, default: float | None = None, where: str = "") -> float:
    if key not in d:
        if default is None:
            raise ScenarioError(f"{where}missing required key {key!r}")
        return float(default)
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ScenarioError(f"{where}{key} must be a number, got {v!r}")
    return float(v)


def _targets(raw: dict, src: str) -> list[Target]:
    out = []
    seen: set[int] = set()
    for n, t in enumerate(raw.get("target", [])):
        where = f"{src}: target[{n}]."
        tid = t.get("id")
        if not isinstance(tid, int) or tid <= 0 or tid in seen:
            raise ScenarioError(f"{where}id must be a unique positive integer, got {tid!r}")
        seen.add(tid)
        cls = t.get("class", "car")
        if cls not in CLASSES:
            raise ScenarioError(f"{where}class must be one of {CLASSES}, got {cls!r}")
        p0 = (_num(t, "x_m", where=where), _num(t, "y_m", where=where), _num(t, "z_m", 0.0, where))
        v = (_num(t, "vx_mps", 0.0, where), _num(t, "vy_mps", 0.0, where), _num(t, "vz_mps", 0.0, where))
        start = _num(t, "start_s", 0.0, where)
        out.append(
            Target(
                id=tid,
                cls=cls,
                trajectory=LinearTrajectory(p0, v, t0_s=start),
                offsets_m=np.zeros((1, 3)),
                rcs_m2=np.array([_num(t, "rcs_m2", 10.0, where)]),
                swerling=int(t.get("swerling", 0)),
                lane=t.get("lane"),
                t_start_s=start,
                t_end_s=_num(t, "end_s", 1e9, where),
            )
        )
    return out


def parse_scenario(raw: dict[str, Any], source: str = "<string>") -> Scenario:
    head = raw.get("scenario")
    if not isinstance(head, dict):
        raise ScenarioError(f"{source}: missing [scenario] table")
    name = head.get("name")
    if not isinstance(name, str) or not name:
        raise ScenarioError(f"{source}: scenario.name must be a non-empty string")
    board = head.get("board")
    if board not in BOARDS:
        raise ScenarioError(f"{source}: scenario.board must be one of {BOARDS}, got {board!r}")
    dur = _num(head, "duration_s", 30.0, f"{source}: scenario.")
    if dur <= 0:
        raise ScenarioError(f"{source}: scenario.duration_s must be > 0")
    seed = head.get("seed", 1)
    if not isinstance(seed, int) or seed < 0:
        raise ScenarioError(f"{source}: scenario.seed must be a non-negative integer")
    r = raw.get("radar", {})
    w = f"{source}: radar."
    pose = RadarPose(
        x_m=_num(r, "x_m", 0.0, w),
        y_m=_num(r, "y_m", 0.0, w),
        height_m=_num(r, "height_m", 6.0 if board == "simo" else 1.0, w),
        yaw_deg=_num(r, "yaw_deg", 0.0, w),
        tilt_deg=_num(r, "tilt_deg", 0.0, w),
        occluded_behind=_bool(r, "occluded_behind", w),
    )
    tx_power = r.get("tx_power")
    if tx_power is not None:
        from hw_sim.boards import D2G_MAX_TX_POWER

        if board != "d2g":
            raise ScenarioError(f"{source}: radar.tx_power is a Distance2Go setting (board {board!r} has none)")
        if isinstance(tx_power, bool) or not isinstance(tx_power, int) or not 0 <= tx_power <= D2G_MAX_TX_POWER:
            raise ScenarioError(f"{source}: radar.tx_power must be an integer 0..{D2G_MAX_TX_POWER}")
    lanes = []
    for n, ln in enumerate(raw.get("lane", [])):
        d = ln.get("direction", "toward")
        if d not in ("toward", "away"):
            raise ScenarioError(f"{source}: lane[{n}].direction must be 'toward' or 'away'")
        lanes.append(Lane(_num(ln, "center_x_m", where=f"{source}: lane[{n}]."), _num(ln, "width_m", 3.5), d))
    try:
        physics = parse_physics(raw.get("physics"), f"{source}: physics.")
    except PhysicsError as exc:
        raise ScenarioError(str(exc)) from None
    known = {"scenario", "radar", "lane", "target", "clutter", "physics", *GENERATORS}
    extra = sorted(set(raw) - known)
    if extra:
        raise ScenarioError(f"{source}: unknown table(s) {extra}; known: {sorted(known)}")
    sc = Scenario(
        name=name,
        board=board,
        description=str(head.get("description", "")),
        duration_s=dur,
        seed=seed,
        pose=pose,
        lanes=tuple(lanes),
        raw=raw,
        source=source,
        physics=physics,
        tx_power=tx_power,
    )
    sc.build_scene()  # validate targets and generators now, not mid-run
    return sc


def builtin_names() -> list[str]:
    files = resources.files("hw_sim").joinpath("scenarios")
    return sorted(p.name[: -len(".toml")] for p in files.iterdir() if p.name.endswith(".toml"))


def apply_patch(raw: dict[str, Any], patch: dict[str, Any] | None) -> dict[str, Any]:
    """A copy of a scenario's TOML document with ``patch`` applied (the corpus's variants).

    A table merges into the table of the same name, key by key (recursively); a table patched onto an
    array of tables (``traffic = { weave_sdlp_m = 0.2 }`` onto ``[[traffic]]``) merges into every element;
    an array of tables is appended to the array of the same name; any other value replaces.
    """
    import copy

    out = copy.deepcopy(raw)
    for key, val in (patch or {}).items():
        cur = out.get(key)
        if isinstance(val, dict) and isinstance(cur, dict):
            out[key] = apply_patch(cur, val)
        elif isinstance(val, dict) and isinstance(cur, list) and all(isinstance(e, dict) for e in cur):
            out[key] = [apply_patch(e, val) for e in cur]
        elif isinstance(val, list) and isinstance(cur, list) and all(isinstance(e, dict) for e in val + cur):
            out[key] = cur + copy.deepcopy(val)
        else:
            out[key] = copy.deepcopy(val)
    return out


def patch_from_assignments(items: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``["radar.height_m=10", "physics.preset='v1'"]`` -> a patch for :func:`apply_patch`.

    Values are TOML values; a bare word that is not one is taken as a string (``physics.preset=v1``).
    """
    patch: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ScenarioError(f"scenario override {item!r} must be KEY=VALUE, e.g. radar.height_m=10")
        try:
            val = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            val = text.strip()
        node = patch
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ScenarioError(f"scenario override {item!r} conflicts with an earlier one")
        node[parts[-1]] = val
    return patch


def patched(sc: Scenario, patch: dict[str, Any] | None) -> Scenario:
    """``sc`` re-parsed with ``patch`` applied to its TOML document (itself when there is none)."""
    if not patch:
        return sc
    return parse_scenario(apply_patch(sc.raw, patch), f"{sc.source} (patched)")


def load_scenario(name_or_path: str, patch: dict[str, Any] | None = None) -> Scenario:
    """Load a built-in scenario by name, or a TOML file by path; ``patch`` (:func:`apply_patch`) changes it."""
    return patched(_load_scenario(name_or_path), patch)


def _load_scenario(name_or_path: str) -> Scenario:
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise ScenarioError(f"scenario file {name_or_path!r} not found")
        text = p.read_text(encoding="utf-8")
        src = str(p)
    else:
        res = resources.files("hw_sim").joinpath("scenarios", f"{name_or_path}.toml")
        if not res.is_file() and name_or_path in EVENT_SCENARIOS:
            return EVENT_SCENARIOS[name_or_path](events=None)  # an event generator, default events
        if not res.is_file():
            raise ScenarioError(
                f"unknown scenario {name_or_path!r}; built-in: {', '.join(builtin_names())} (or a path to a .toml file)"
            )
        text = res.read_text(encoding="utf-8")
        src = f"builtin:{name_or_path}"
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{src}: not valid TOML: {exc}") from exc
    return parse_scenario(raw, src)


#: event-generator scenarios (``single-random``, ``multi-random``...): name -> builder(events, seed)
#: returning a :class:`Scenario`; registered by the modules that provide them.
EVENT_SCENARIOS: dict[str, Callable[..., Scenario]] = {}


def load_scenario_for_eval(name_or_path: str, events: int | None = None,
                           patch: dict[str, Any] | None = None) -> Scenario:
    """A scenario for ``radar-edge evaluate``: an event generator (takes ``events``) or a file/name."""
    if name_or_path in EVENT_SCENARIOS:
        return patched(EVENT_SCENARIOS[name_or_path](events=events), patch)
    return load_scenario(name_or_path, patch)


# the road-traffic generators ([[vehicle]], [[traffic]], [[guardrail]], [[multipath]]) register themselves
import hw_sim.traffic  # noqa: E402,F401  (import for its side effect, after GENERATORS exists)
