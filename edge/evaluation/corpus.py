"""The evaluation corpus: scenarios x variants x seeds in two parts, run in parallel and pooled with confidence
intervals (issue 28).

A corpus file (TOML) declares what is evaluated. Schema (keys not listed are refused)::

    [corpus]
    name = "lane"                 # required
    profile = "lane"              # required: "lane" or "surveillance"; every run's scenario must run this profile
    description = "..."
    bootstrap_resamples = 2000    # cluster-bootstrap resamples per confidence interval
    bootstrap_seed = 0            # seed of the resampling (the figures are deterministic)

    [[variant]]                   # one way the world (or the installer) differs; names unique
    name = "v1"
    description = "..."
    patch = { physics = { preset = "v1" } }   # a scenario patch (hw_sim.scenario.apply_patch); default none
    set = ["traffic.interval_s=60"]           # pipeline configuration an installer would change for it
                                              # (as --set SECTION.KEY=VALUE); default none

    [[run]]                       # scenario runs of one part
    part = "dev"                  # required: "dev" (developed on) or "holdout" (reported, never tuned on)
    scenario = "highway4-traffic" # required: built-in name, event generator or .toml path
    seeds = [5, 7007]             # required, distinct
    variants = ["defaults", "v1"] # names; default every variant
    duration_s = 60.0             # or frames = 1800; default the scenario's duration
    events = 4                    # event generators (surveillance): events per run
    cold_start = true             # the pipeline starts with traffic already on the road (the only start the
                                  # lane evaluation has: the traffic generator populates the road before
                                  # t = 0 and no figure leaves the first seconds out); false is refused

A seed of a scenario may appear in one part only: a corpus whose ``dev`` and ``holdout`` runs share a
(scenario, seed) is refused, as is a (part, scenario, seed, variant) listed twice.

Every (run, seed, variant) is one *run*, evaluated by the profile's evaluation (:mod:`edge.evaluation.lane`,
:mod:`edge.evaluation.surveillance`) in a worker process. The result (:func:`corpus_document`) holds, per part:

* ``runs``: per run its key, the summary's scalar figures, its ``tallies`` (sums and counts) and its metrics;
* ``pooled``: per variant and over all runs, each metric of :data:`METRICS` pooled as a ratio of sums over the
  runs (proportions: sum of successes / sum of trials; rates: sum of events / sum of minutes; RMSE:
  sqrt(sum of squares / n); MAE: sum |e| / n; count error: sum |measured - true| / sum true) with a 95 %
  percentile confidence interval from a cluster bootstrap (Davison & Hinkley, *Bootstrap Methods and their
  Application*, 1997, §3.8): the independent units are the (scenario, seed) pairs, not the frames of a run, nor the
  variants of one seed, which share its traffic. With one run (or one seed) the interval is ``None`` and
  ``ci_note`` says why;
* ``confusion_by_variant`` (surveillance): per variant the per-class confusion matrices of its runs summed per
  scenario and over all of them (:func:`pooled_confusion`).

Results do not depend on the number of workers: each run is seeded and the resampling is seeded and ordered by
the corpus, not by completion.
"""

from __future__ import annotations

import math
import os
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

PARTS = ("dev", "holdout")
PROFILES = ("lane", "surveillance")
DEFAULT_RESAMPLES = 2000
#: environment of the worker processes: one BLAS/OpenMP thread each (the workers are the parallelism) and a fixed
#: string hash seed (set iteration order), so a run's figures do not depend on the process it ran in
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONHASHSEED": "0"}


class CorpusError(ValueError):
    """A corpus file does not follow the schema or reuses a seed across parts; the message names the key."""


@dataclass(frozen=True)
class Metric:
    """A pooled figure: ``num`` / ``den`` summed over runs (tally keys), its square root for an RMSE."""

    name: str
    num: str
    den: str
    unit: str
    doc: str
    sqrt: bool = False

    def of(self, num: np.ndarray | float, den: np.ndarray | float) -> np.ndarray | float:
        with np.errstate(divide="ignore", invalid="ignore"):
            v = np.divide(num, den)
        return np.sqrt(v) if self.sqrt else v


#: per profile, the pooled metrics (tally keys from the evaluations' ``summary.tallies``)
METRICS: dict[str, tuple[Metric, ...]] = {
    "lane": (
        Metric("detection_probability_separate", "separate_frames_tracked", "separate_frames_in_view", "",
               "tracked / in-view frames of vehicles sharing no range-Doppler cell and beam with another, 10-300 m"),
        Metric("detection_probability_visible", "visible_frames_tracked", "visible_frames_in_view", "",
               "the same over the frames where under half of the vehicle's echo is shadowed by another vehicle's body "
               "(the truth's shadowed_fraction; = separate where the simulator does not shadow)"),
        Metric("detection_probability", "vehicle_frames_tracked", "vehicle_frames_in_view", "",
               "tracked / in-view frames of all vehicles"),
        Metric("false_tracks_per_min", "false_tracks", "minutes", "1/min",
               "confirmed false tracks per minute, from the cold start on"),
        Metric("false_tracks_first_30s_per_min", "false_tracks_first_30s", "minutes_first_30s", "1/min",
               "false tracks begun in the first 30 s after the cold start, per minute of those 30 s"),
        Metric("false_tracks_near_per_min", "false_tracks_near", "minutes", "1/min",
               "false tracks begun within 25 m ground range of the radar, per minute"),
        Metric("count_error_per_lane", "count_abs_error", "count_true", "",
               "sum over lanes of |measured - true| volume / true volume"),
        Metric("count_error_either_lane", "count_abs_error_either", "count_true", "",
               "the same, a vehicle straddling two lanes at the detection line counted right in either"),
        Metric("position_rmse_m", "position_sq_error_sum_m2", "position_n", "m",
               "position error of assigned frames within 200 m (eq. 20 pooled over frames)", sqrt=True),
        Metric("position_rmse_road_m", "position_road_sq_error_sum_m2", "position_n", "m",
               "the same in the road frame of the traffic layer's yaw (a boresight error of the board cancels)",
               sqrt=True),
        Metric("position_rmse_vehicle_m", "position_vehicle_rmse_sum_m", "position_vehicles", "m",
               "each vehicle's own position RMSE within 200 m, mean over vehicles (10+ assigned frames)"),
        Metric("speed_mae_kmh", "speed_abs_error_sum_kmh", "speed_n", "km/h", "|track speed - speed|"),
        Metric("lane_accuracy", "lane_correct", "lane_assigned", "", "assigned frames in the true lane"),
        Metric("lane_accuracy_keeping", "lane_keeping_correct", "lane_keeping_assigned", "",
               "the same over the frames of vehicles outside a lane change"),
        Metric("id_switches_per_min", "id_switches", "minutes", "1/min", "track id changes along a vehicle"),
    ),
    "surveillance": (
        Metric("classification_accuracy_single", "single_correct", "single_targets", "",
               "targets of single-target events classified right (missed = wrong)"),
        Metric("classification_accuracy_multi", "multi_correct", "multi_targets", "",
               "targets of multi-target events classified right (missed = wrong)"),
        Metric("classification_accuracy", "correct", "targets", "", "all targets classified right"),
        Metric("detection_probability", "detected_frames", "visible_frames", "",
               "visible frames with a cluster within 2.5 m of the target, before tracking"),
        Metric("speed_mae_kmh", "speed_abs_error_sum_kmh", "speed_n", "km/h", "|estimated - true| mean radial speed"),
        Metric("range_rmse_m", "range_sq_error_sum_m2", "range_n", "m", "range error of matched tracks", sqrt=True),
        Metric("direction_accuracy", "direction_correct", "targets", "", "targets with the right direction"),
        Metric("false_tracks_per_min", "false_tracks", "minutes", "1/min", "classified tracks matching no target"),
        Metric("events_per_passage", "passage_events", "passages_tracked", "",
               "classified events per tracked target passage (1 = no split)"),
        Metric("one_event_fraction", "single_passages_one_event", "single_passages_tracked", "",
               "tracked single-target passages that ended as exactly one event (no split, no stray fragment)"),
        Metric("alias_step_fraction", "vehicles_alias_off", "vehicles_with_speed", "",
               "vehicles whose mean radial speed is off by more than half the Doppler alias step (2 v_max)"),
        Metric("speed_uncertain_fraction", "vehicles_speed_uncertain", "vehicles_with_speed", "",
               "vehicles whose event flags the speed as uncertain (alias not determined)"),
        Metric("alias_step_unflagged_fraction", "vehicles_alias_off_unflagged", "vehicles_with_speed", "",
               "vehicles off by an alias step whose event does not flag the speed as uncertain"),
        Metric("speed_mae_certain_kmh", "speed_abs_error_sum_certain_kmh", "speed_n_certain", "km/h",
               "|estimated - true| mean radial speed of the targets whose speed is not flagged uncertain"),
        Metric("live_class_accuracy", "live_class_correct", "live_class_frames", "",
               "published frames of matched tracks whose provisional class is the target's (frames with a class)"),
    ),
}


@dataclass(frozen=True)
class Variant:
    name: str
    patch: dict = field(default_factory=dict)
    set: tuple[str, ...] = ()
    description: str = ""


@dataclass(frozen=True)
class RunSpec:
    part: str
    scenario: str
    seeds: tuple[int, ...]
    variants: tuple[str, ...]
    duration_s: float | None = None
    frames: int | None = None
    events: int | None = None
    cold_start: bool = True


@dataclass(frozen=True)
class Corpus:
    name: str
    profile: str
    variants: tuple[Variant, ...]
    runs: tuple[RunSpec, ...]
    description: str = ""
    bootstrap_resamples: int = DEFAULT_RESAMPLES
    bootstrap_seed: int = 0
    source: str = ""

    def variant(self, name: str) -> Variant:
        return next(v for v in self.variants if v.name == name)

    def jobs(self, part: str) -> list[dict]:
        """The runs of ``part`` in corpus order: run table, then seed, then variant."""
        out = []
        for k, r in enumerate(self.runs):
            if r.part != part:
                continue
            for seed in r.seeds:
                for vn in r.variants:
                    v = self.variant(vn)
                    out.append({"run": k, "part": part, "scenario": r.scenario, "seed": seed, "variant": vn,
                                "duration_s": r.duration_s, "frames": r.frames, "events": r.events,
                                "cold_start": r.cold_start, "patch": v.patch, "set": list(v.set)})
        return out


def _check_keys(d: dict, allowed: set[str], where: str) -> None:
    bad = sorted(set(d) - allowed)
    if bad:
        raise CorpusError(f"{where}: unknown key(s) {bad}; known: {sorted(allowed)}")


def parse_corpus(raw: dict[str, Any], source: str = "<string>") -> Corpus:
    """A corpus document (the module doc's schema) checked and parsed; :class:`CorpusError` names the problem."""
    _check_keys(raw, {"corpus", "variant", "run"}, source)
    head = raw.get("corpus")
    if not isinstance(head, dict):
        raise CorpusError(f"{source}: a [corpus] table with name and profile is required")
    _check_keys(head, {"name", "profile", "description", "bootstrap_resamples", "bootstrap_seed"}, f"{source} [corpus]")
    name, profile = head.get("name"), head.get("profile")
    if not isinstance(name, str) or not name:
        raise CorpusError(f"{source}: corpus.name is required")
    if profile not in PROFILES:
        raise CorpusError(f"{source}: corpus.profile must be one of {list(PROFILES)}, got {profile!r}")
    resamples = head.get("bootstrap_resamples", DEFAULT_RESAMPLES)
    if not isinstance(resamples, int) or resamples < 100:
        raise CorpusError(f"{source}: corpus.bootstrap_resamples must be an integer >= 100")
    bseed = head.get("bootstrap_seed", 0)
    if not isinstance(bseed, int) or bseed < 0:
        raise CorpusError(f"{source}: corpus.bootstrap_seed must be a non-negative integer")

    variants: list[Variant] = []
    for i, v in enumerate(raw.get("variant", [{"name": "defaults"}])):
        where = f"{source} variant[{i}]"
        _check_keys(v, {"name", "patch", "set", "description"}, where)
        vn = v.get("name")
        if not isinstance(vn, str) or not vn:
            raise CorpusError(f"{where}: name is required")
        if any(x.name == vn for x in variants):
            raise CorpusError(f"{where}: variant name {vn!r} is used twice")
        patch = v.get("patch", {})
        sets = v.get("set", [])
        if not isinstance(patch, dict):
            raise CorpusError(f"{where} ({vn}): patch must be a table")
        if not isinstance(sets, list) or not all(isinstance(s, str) and "=" in s for s in sets):
            raise CorpusError(f"{where} ({vn}): set must be a list of \"section.key=value\" strings")
        variants.append(Variant(vn, patch, tuple(sets), str(v.get("description", ""))))

    runs: list[RunSpec] = []
    names = [v.name for v in variants]
    for i, r in enumerate(raw.get("run", [])):
        where = f"{source} run[{i}]"
        _check_keys(r, {"part", "scenario", "seeds", "variants", "duration_s", "frames", "events", "cold_start"}, where)
        if r.get("part") not in PARTS:
            raise CorpusError(f"{where}: part must be one of {list(PARTS)}, got {r.get('part')!r}")
        if not isinstance(r.get("scenario"), str):
            raise CorpusError(f"{where}: scenario is required")
        seeds = r.get("seeds")
        if not isinstance(seeds, list) or not seeds or not all(isinstance(s, int) and not isinstance(s, bool)
                                                              for s in seeds):
            raise CorpusError(f"{where}: seeds must be a non-empty list of integers")
        if len(set(seeds)) != len(seeds):
            raise CorpusError(f"{where}: seeds repeat: {seeds}")
        vs = r.get("variants", names)
        unknown = [x for x in vs if x not in names]
        if unknown:
            raise CorpusError(f"{where}: unknown variant(s) {unknown}; declared: {names}")
        if "duration_s" in r and "frames" in r:
            raise CorpusError(f"{where}: give duration_s or frames, not both")
        dur, frames, events = r.get("duration_s"), r.get("frames"), r.get("events")
        if dur is not None and (not isinstance(dur, (int, float)) or dur <= 0):
            raise CorpusError(f"{where}: duration_s must be a positive number")
        if frames is not None and (not isinstance(frames, int) or frames <= 0):
            raise CorpusError(f"{where}: frames must be a positive integer")
        if events is not None and (not isinstance(events, int) or events <= 0):
            raise CorpusError(f"{where}: events must be a positive integer")
        cold = r.get("cold_start", True)
        if not isinstance(cold, bool):
            raise CorpusError(f"{where}: cold_start must be true or false")
        if not cold:
            raise CorpusError(f"{where}: cold_start = false (a pipeline warmed up before scoring) is not implemented: "
                              "every run starts the pipeline with traffic already flowing")
        runs.append(RunSpec(r["part"], r["scenario"], tuple(seeds), tuple(vs),
                            float(dur) if dur is not None else None, frames, events, cold))
    if not runs:
        raise CorpusError(f"{source}: no [[run]] tables")
    # a seed of a scenario in one part only; each (part, scenario, seed, variant) once
    parts_of: dict[tuple[str, int], set[str]] = {}
    seen: set[tuple] = set()
    for r in runs:
        for s in r.seeds:
            parts_of.setdefault((r.scenario, s), set()).add(r.part)
            for v in r.variants:
                key = (r.part, r.scenario, s, v)
                if key in seen:
                    raise CorpusError(f"{source}: {r.part} lists scenario {r.scenario!r} seed {s} variant {v!r} twice")
                seen.add(key)
    shared = sorted(f"{sc} seed {s}" for (sc, s), p in parts_of.items() if len(p) > 1)
    if shared:
        raise CorpusError(f"{source}: dev and holdout must use disjoint seeds, but both use {', '.join(shared)}")
    return Corpus(name, profile, tuple(variants), tuple(runs), str(head.get("description", "")), resamples, bseed,
                  source)


def read_toml(path: str | Path, what: str) -> dict:
    """A TOML file's document; a missing file or bad TOML raises :class:`CorpusError` naming ``what`` it is."""
    p = Path(path)
    if not p.is_file():
        raise CorpusError(f"{what} {str(p)!r} not found")
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise CorpusError(f"{p}: not valid TOML: {exc}") from exc


def load_corpus(path: str | Path) -> Corpus:
    return parse_corpus(read_toml(path, "corpus file"), str(path))


def check_scenarios(corpus: Corpus, part: str | tuple[str, ...]) -> None:
    """Load every (scenario, variant) of ``part`` (one part or several) once with its patch, and every variant's
    settings: unknown scenarios, bad patches or settings and scenarios of the other profile stop the corpus before
    any worker starts."""
    from edge.pipeline import BOARD_PROFILE
    from hw_sim.physics import PhysicsError
    from hw_sim.scenario import ScenarioError, load_scenario_for_eval

    from edge.config import ConfigError, load_config, parse_set_option

    for v in corpus.variants:
        try:
            load_config(None, env={}, overrides=dict(parse_set_option(x) for x in v.set))
        except ConfigError as exc:
            raise CorpusError(f"{corpus.source}: variant {v.name!r}: {exc}") from exc
    done = set()
    for j in [j for p in ((part,) if isinstance(part, str) else part) for j in corpus.jobs(p)]:
        key = (j["scenario"], j["variant"])
        if key in done:
            continue
        done.add(key)
        try:
            sc = load_scenario_for_eval(j["scenario"], events=j["events"], patch=j["patch"] or None)
        except (ScenarioError, PhysicsError) as exc:
            raise CorpusError(f"{corpus.source}: scenario {j['scenario']!r} variant {j['variant']!r}: {exc}") from exc
        if BOARD_PROFILE[sc.board] != corpus.profile:
            raise CorpusError(f"{corpus.source}: scenario {j['scenario']!r} runs the {BOARD_PROFILE[sc.board]} profile, "
                              f"the corpus is {corpus.profile}")


# --- one run, in a worker -------------------------------------------------------------------------------------------


def _world_key(job: dict) -> tuple:
    """Jobs with equal keys simulate the same frames (the configuration does not change the simulated world)."""
    return (job["scenario"], job["seed"], job["events"], job["frames"], job["duration_s"], repr(job["patch"]))


def run_job_group(jobs: list[dict]) -> list[dict]:
    """:func:`run_job` for jobs of one simulated world (:func:`_world_key`), the frames made once and shared
    (lane profile; other profiles simulate per job)."""
    cache: dict = {}
    return [run_job(j, cache) for j in jobs]


def run_job(job: dict, cache: dict | None = None) -> dict:
    """Evaluate one (run, seed, variant): the record of :func:`corpus_document`'s ``runs`` without metrics.

    ``job``: a :meth:`Corpus.jobs` entry plus ``config`` (a configuration file or None) and ``extra_set`` (the
    command line's and an ablated rule's ``SECTION.KEY=VALUE``, applied after the variant's ``set``). ``cache``:
    a dict in which a lane run keeps its simulated frames for the next job of the same world."""
    import importlib

    from edge.config import load_config, parse_set_option
    from edge.pipeline import BOARD_PROFILE
    from hw_sim.scenario import load_scenario_for_eval

    overrides = dict(parse_set_option(s) for s in list(job["set"]) + list(job.get("extra_set", ())))
    config = load_config(job.get("config"), overrides=overrides)
    sc = load_scenario_for_eval(job["scenario"], events=job["events"], patch=job["patch"] or None)
    profile = BOARD_PROFILE[sc.board]
    mod = importlib.import_module(f"edge.evaluation.{profile}")
    frames = job["frames"]
    if frames is None and job["duration_s"] is not None:
        frames = max(1, int(round(job["duration_s"] / sc.sim_board().frontend.waveform.frame_period_s)))
    kw = {}
    if cache is not None and profile == "lane":
        from hw_sim.simulator import FrameCache, FrameSimulator

        if "world" not in cache:
            scene = sc.build_scene(job["seed"])
            cache["world"] = (scene, FrameCache(FrameSimulator(sc.sim_board(), scene, job["seed"])))
        kw["world"] = cache["world"]
    report = mod.evaluate(sc, seed=job["seed"], frames=frames, events=job["events"], config=config, progress=False,
                          **kw)
    s = report["summary"]
    figures = {k: v for k, v in s.items() if isinstance(v, (int, float, str, bool)) or v is None}
    for k in ("count_error_per_lane", "volume_true_per_lane", "volume_measured_per_lane",
              "volume_measured_either_per_lane"):
        if isinstance(s.get(k), list):
            figures[k] = s[k]
    rec = {"run": job["run"], "scenario": job["scenario"], "seed": job["seed"], "variant": job["variant"],
           "frames": report["frames"], "cold_start": job["cold_start"], "profile": profile,
           "figures": figures, "tallies": s["tallies"]}
    if isinstance(s.get("confusion_matrix"), dict):
        rec["confusion_matrix"] = s["confusion_matrix"]
    if job.get("targets"):  # the run's target rows, for a failure list (evaluate --targets)
        rec["targets"] = report["targets"]
    return rec


def _worker_init() -> None:  # pragma: no cover - runs in the workers
    os.environ.update(WORKER_ENV)


def run_jobs(jobs: list[dict], n_workers: int, progress: bool = True,
             label: Callable[[dict], str] | None = None, desc: str = "corpus", share_frames: bool = False) -> list[dict]:
    """Run ``jobs`` in ``n_workers`` spawned processes (one BLAS thread each); the results in ``jobs``' order.
    ``share_frames``: jobs of one simulated world run in one worker on frames made once (:func:`run_job_group`).

    Progress: a tqdm bar over runs on stderr when tqdm is installed, else one line per finished run."""
    import concurrent.futures as cf
    import multiprocessing as mp

    from edge.extras import available

    label = label or (lambda j: f"{j['scenario']} seed {j['seed']} {j['variant']}")
    saved = {k: os.environ.get(k) for k in WORKER_ENV}
    os.environ.update(WORKER_ENV)  # inherited by the spawned workers before they import numpy
    results: list[dict | None] = [None] * len(jobs)
    bar = None
    if progress and available("tqdm"):
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), unit="run", desc=desc, file=sys.stderr)
    try:
        with cf.ProcessPoolExecutor(max_workers=max(1, n_workers), mp_context=mp.get_context("spawn"),
                                    initializer=_worker_init) as ex:
            groups: dict[tuple, list[int]] = {}
            for k, j in enumerate(jobs):
                groups.setdefault(_world_key(j) if share_frames else (k,), []).append(k)
            futs = {ex.submit(run_job_group, [jobs[k] for k in ks]): ks for ks in groups.values()}
            done_n = 0
            for fut in cf.as_completed(futs):
                ks = futs[fut]
                for k, r in zip(ks, fut.result()):
                    results[k] = r
                done_n += len(ks)
                if bar is not None:
                    bar.set_postfix_str(label(jobs[ks[-1]]), refresh=False)
                    bar.update(len(ks))
                elif progress:
                    print(f"{desc} [{done_n}/{len(jobs)}] {label(jobs[ks[-1]])}", file=sys.stderr, flush=True)
    finally:
        if bar is not None:
            bar.close()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return results  # type: ignore[return-value]


# --- pooling --------------------------------------------------------------------------------------------------------


def resample_weights(clusters: list, resamples: int, seed: int, stream: int) -> np.ndarray | None:
    """(resamples, runs) multiplicities of a cluster bootstrap: ``clusters`` names each run's cluster (its
    (scenario, seed): the variants of one seed share its traffic, so they are not independent of each other); each
    row draws as many clusters as there are with replacement, and a run weighs as its cluster was drawn. From the seed
    and a stream number (one per pooled group); None for fewer than two clusters."""
    keys = list(dict.fromkeys(clusters))
    if len(keys) < 2:
        return None
    rng = np.random.default_rng([seed, stream])
    w = rng.multinomial(len(keys), np.full(len(keys), 1.0 / len(keys)), size=resamples).astype(np.float64)
    return w[:, [keys.index(c) for c in clusters]]


def _finite(v: float) -> float | None:
    return float(v) if v is not None and np.isfinite(v) else None


def pool(tallies: list[dict], metrics: Iterable[Metric], weights: np.ndarray | None) -> dict:
    """Each metric pooled over the runs' ``tallies`` as a ratio of sums, with a 95 % percentile interval from the
    bootstrap ``weights`` ((resamples, runs) multiplicities, :func:`resample_weights`; None: no interval, there
    being one run or one seed)."""
    out = {}
    n = len(tallies)
    for m in metrics:
        num = np.array([float(t.get(m.num, 0.0)) for t in tallies])
        den = np.array([float(t.get(m.den, 0.0)) for t in tallies])
        value = _finite(m.of(num.sum(), den.sum())) if den.sum() > 0 else None
        rec: dict[str, Any] = {"value": value, "ci95": None, "runs": n, "numerator": float(num.sum()),
                               "denominator": float(den.sum())}
        if weights is None:
            rec["ci_note"] = "n/a: one run" if n < 2 else "n/a: one seed"
        elif value is None:
            rec["ci_note"] = "n/a: no data"
        else:
            _percentile_ci(rec, m.of(weights @ num, weights @ den))
        out[m.name] = rec
    return out


def _percentile_ci(rec: dict, resampled: np.ndarray) -> None:
    """Set ``rec["ci95"]`` to the 2.5-97.5 % percentiles of a metric's bootstrap resamples, or ``rec["ci_note"]``
    when under 90 % of them have data."""
    b = resampled[np.isfinite(resampled)]
    if b.size < 0.9 * resampled.shape[0]:
        rec["ci_note"] = "n/a: too few resamples with data"
    else:
        lo, hi = np.percentile(b, [2.5, 97.5])
        rec["ci95"] = [float(lo), float(hi)]


def run_metrics(tallies: dict, metrics: Iterable[Metric]) -> dict:
    """One run's metrics from its own tallies (None where it has no data)."""
    return {m.name: (_finite(m.of(float(tallies.get(m.num, 0.0)), float(tallies[m.den])))
                     if float(tallies.get(m.den, 0.0)) > 0 else None) for m in metrics}


def _cluster(r: dict) -> tuple:
    """A run's bootstrap cluster: its scenario and seed (the variants of a seed share its traffic)."""
    return (r["scenario"], r["seed"])


def pooled_part(corpus: Corpus, results: list[dict], stream0: int = 0) -> dict:
    """Per variant and over all runs of one part, the pooled metrics (module doc)."""
    metrics = METRICS[corpus.profile]
    groups: dict[str, list[dict]] = {v.name: [] for v in corpus.variants}
    for r in results:
        groups[r["variant"]].append(r)
    by_variant = {}
    for k, (vn, rs) in enumerate(groups.items()):
        if not rs:
            continue
        w = resample_weights([_cluster(r) for r in rs], corpus.bootstrap_resamples, corpus.bootstrap_seed,
                             stream0 + k + 1)
        by_variant[vn] = _with_seeds(pool([r["tallies"] for r in rs], metrics, w), rs)
    w = resample_weights([_cluster(r) for r in results], corpus.bootstrap_resamples, corpus.bootstrap_seed, stream0)
    return {"by_variant": by_variant, "all": _with_seeds(pool([r["tallies"] for r in results], metrics, w), results)}


def pooled_confusion(results: list[dict]) -> dict:
    """Per variant, the runs' per-class confusion matrices (true class x predicted class or missed) summed per
    scenario and over all of them; runs without a matrix (the lane profile) are left out, and so is a variant
    without any."""
    out: dict[str, dict] = {}
    for r in results:
        cm = r.get("confusion_matrix")
        if not cm:
            continue
        v = out.setdefault(r["variant"], {"labels": list(cm["labels"]), "columns": list(cm["columns"]),
                                          "rows": cm.get("rows", "true class"), "by_scenario": {}, "all": None})
        if list(cm["labels"]) != v["labels"] or list(cm["columns"]) != v["columns"]:
            raise ValueError(f"run {r['scenario']} seed {r['seed']}: confusion-matrix classes differ within variant "
                             f"{r['variant']}")
        m = np.asarray(cm["matrix"], dtype=np.int64)
        prev = v["by_scenario"].get(r["scenario"])
        v["by_scenario"][r["scenario"]] = (m if prev is None else prev + m)
        v["all"] = m if v["all"] is None else v["all"] + m
    for v in out.values():
        v["by_scenario"] = {k: m.tolist() for k, m in v["by_scenario"].items()}
        v["all"] = v["all"].tolist()
    return out


def _with_seeds(pooled: dict, results: list[dict]) -> dict:
    n = len({_cluster(r) for r in results})
    for rec in pooled.values():
        rec["seeds"] = n
    return pooled


def corpus_document(corpus: Corpus, parts: dict[str, list[dict]], config_set: list[str] | None = None) -> dict:
    """The JSON document of ``radar-edge evaluate --corpus``: per part, the runs and the pooled metrics."""
    metrics = METRICS[corpus.profile]
    doc: dict[str, Any] = {
        "corpus": corpus.name, "profile": corpus.profile, "source": corpus.source,
        "description": corpus.description, "set": list(config_set or []),
        "method": {"pooling": "ratio of sums over runs", "ci": "95 % percentile, cluster (per-run) bootstrap",
                   "resamples": corpus.bootstrap_resamples, "seed": corpus.bootstrap_seed},
        "metrics": {m.name: {"unit": m.unit, "doc": m.doc, "numerator": m.num, "denominator": m.den,
                             "sqrt": m.sqrt} for m in metrics},
        "variants": {v.name: {"patch": v.patch, "set": list(v.set), "description": v.description}
                     for v in corpus.variants},
        "parts": {},
    }
    for i, (part, results) in enumerate(parts.items()):
        runs = [dict(r, metrics=run_metrics(r["tallies"], metrics)) for r in results]
        doc["parts"][part] = {"runs": runs,
                              "pooled": pooled_part(corpus, results, stream0=1000 * (PARTS.index(part) + 1))}
        confusion = pooled_confusion(results)
        if confusion:
            doc["parts"][part]["confusion_by_variant"] = confusion
    return doc


def _fmt(v: Any) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.1f}" if abs(v) >= 100 else f"{v:.4f}" if abs(v) < 1 else f"{v:.3f}"
    return str(v)


def _ci(rec: dict) -> str:
    return f"[{_fmt(rec['ci95'][0])}, {_fmt(rec['ci95'][1])}]" if rec.get("ci95") else "n/a"


def console_table(doc: dict) -> str:
    """Per part, per metric the pooled value and 95 % interval per variant and over all runs."""
    lines = []
    for part, p in doc["parts"].items():
        lines.append(f"{doc['corpus']} ({doc['profile']}), part {part}: {len(p['runs'])} runs; pooled value "
                     "[95 % cluster-bootstrap interval]")
        groups = list(p["pooled"]["by_variant"].items()) + [("all", p["pooled"]["all"])]
        rows = [["metric", "variant", "runs", "value", "95 % CI"]]
        for m in doc["metrics"]:
            for k, (g, rec) in enumerate(groups):
                rows.append([m if k == 0 else "", g, str(rec[m]["runs"]), _fmt(rec[m]["value"]), _ci(rec[m])])
        w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        lines += ["  " + "  ".join(c.ljust(w[i]) for i, c in enumerate(r)).rstrip() for r in rows]
        lines += _confusion_lines(p.get("confusion_by_variant") or {})
    return "\n".join(lines)


def _confusion_lines(confusion: dict) -> list[str]:
    """Per variant, its summed confusion matrix as text: one row per true class, columns predicted and missed."""
    lines = []
    for v, cm in confusion.items():
        cols = cm["columns"]
        rows = [["true \\ predicted"] + list(cols)] + [[lab] + [str(x) for x in row]
                                                        for lab, row in zip(cm["labels"], cm["all"])]
        w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        lines.append(f"  confusion matrix, {v} (all runs):")
        lines += ["    " + "  ".join(c.rjust(w[i]) if i else c.ljust(w[i]) for i, c in enumerate(r)).rstrip()
                  for r in rows]
    return lines
