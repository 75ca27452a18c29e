"""Recorded outputs of the lane pipeline, to check that a speed-up changes nothing it computes.

The pipeline is built as ``radar-edge evaluate`` builds it (installer configuration from the scenario)
with a short statistics interval so lane statistics close within a few hundred frames, and run on a
seeded scenario. Everything a consumer sees is flattened into arrays (one row per detection / track /
lane-statistics record / event, with its frame number): detections with their extras, tracks (ids,
state, lane, age, hits, length), presence, lane statistics, events, and the intermediates (peak
frequencies, CFAR noise at the evaluated cells, pairing counts, angle spectra).

Record (before a change) and check (after it)::

    PYTHONPATH=. python -m tests.edge.lane_golden record OUT.npz --scenario highway4-traffic --seed 31 --frames 400
    PYTHONPATH=. python -m tests.edge.lane_golden check OUT.npz

``check`` compares integers, booleans, counts and ids exactly and floats within float32 round-off
(positions 1e-4 m; see :data:`TOLERANCE`). ``tests/edge/test_lane_golden.py`` runs the check on the small
fixtures of :data:`FIXTURES`; a deliberate change of what the pipeline computes (tracker or pairing logic)
re-records them with ``record-all`` (each fixture's arguments are in :data:`FIXTURES` and its ``meta``).

Fixtures are kept per machine kind (:func:`machine`): the BLAS kernel OpenBLAS picks for the CPU and the
SIMD targets numpy dispatches to round differently in the last bits (the tracker's small matrix products
go through BLAS), a detection at the threshold then comes or goes and the runs diverge within a few dozen
frames (so does the BLAS thread count: :func:`run` holds BLAS to one thread, as on the device). A fixture
can only vouch for "nothing changed" on a machine whose floating point is the one it was recorded with, so each lives in ``data/golden/<machine>/`` and the test skips, saying so, where none was
recorded::

    PYTHONPATH=. python -m tests.edge.lane_golden record-all       # this machine's fixtures, from FIXTURES
    PYTHONPATH=. python -m tests.edge.lane_golden machine          # its folder name

Record on the code before a change (``git stash``), then check after it.

A newer machine can also stand in for an older kind by holding numpy and OpenBLAS to its instruction set; on an
AVX-512 machine (``openblas-haswell_x86_v3+x86_v4+avx512_icl``) this reproduced the ``openblas-haswell_x86_v3``
fixtures exactly, so it records and checks them too::

    export NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX"
    export NPY_DISABLE_CPU_FEATURES="$NPY_DISABLE_CPU_FEATURES AVX512_CNL AVX512_ICL AVX512_SPR"
    OPENBLAS_CORETYPE=Haswell PYTHONPATH=. python -m tests.edge.lane_golden record-all
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

DATA_DIR = Path(__file__).parent / "data" / "golden"

#: the fixtures the test checks: file stem -> recording arguments
FIXTURES = {
    "lane_golden_misaimed_s31": {"scenario": "highway4-misaimed", "seed": 31, "frames": 200},
    "lane_golden_side_by_side_s31": {"scenario": "side-by-side", "seed": 31, "frames": 300},
    "lane_golden_wrong_way_s6": {"scenario": "wrong-way", "seed": 6, "frames": 240},
}


def machine() -> str:
    """The floating-point kind of this machine, as a folder name: the BLAS library and the kernel it picked
    for the CPU (threadpoolctl), and the SIMD targets numpy dispatches to (``numpy.show_runtime``'s 'found'),
    e.g. ``openblas-haswell_x86_v3``."""
    import numpy._core._multiarray_umath as um
    from threadpoolctl import threadpool_info

    blas = [i for i in threadpool_info() if i.get("user_api") == "blas"]
    kind = (f"{blas[0].get('internal_api', 'blas')}-{blas[0].get('architecture') or 'unknown'}" if blas
            else "noblas")
    simd = [t for t in getattr(um, "__cpu_dispatch__", []) if um.__cpu_features__.get(t)]
    return f"{kind}_{'+'.join(simd) or 'baseline'}".lower().replace(" ", "")


#: the machine kind a newer x86-64 CPU (AVX2 and FMA, with or without AVX-512) can stand in for, and the
#: environment that holds numpy and OpenBLAS to its instruction set (see the module docstring)
STAND_IN_KIND = "openblas-haswell_x86_v3"
STAND_IN_ENV = {
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL "
                                "AVX512_ICL AVX512_SPR",
    "OPENBLAS_CORETYPE": "Haswell",
}


def fixture_path(stem: str, kind: str | None = None) -> Path:
    return DATA_DIR / (kind or machine()) / f"{stem}.npz"


def recorded_kinds() -> list[str]:
    return sorted(d.name for d in DATA_DIR.iterdir() if d.is_dir()) if DATA_DIR.is_dir() else []


def record(path: str | Path, scenario: str, seed: int, frames: int, interval_s: float = 5.0,
           spectra: bool = True) -> dict[str, np.ndarray]:
    import scipy

    meta = {"scenario": scenario, "seed": seed, "frames": frames, "interval_s": interval_s, "spectra": spectra,
            "machine": machine(), "numpy": np.__version__, "scipy": scipy.__version__}
    data = run(scenario, seed, frames, interval_s, spectra)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save(path, data, meta)
    return data


#: absolute tolerance per float column (name prefix match); everything else compares exactly
TOLERANCE = {
    "det_range_m": 1e-4, "det_radial_speed_mps": 1e-4, "det_az_rad": 1e-6, "det_snr_db": 1e-3,
    "det_x_m": 1e-4, "det_y_m": 1e-4, "det_pair_residual_hz": 1e-2,
    "trk_x_m": 1e-4, "trk_y_m": 1e-4, "trk_vx_mps": 1e-4, "trk_vy_mps": 1e-4, "trk_range_m": 1e-4,
    "trk_radial_speed_mps": 1e-4, "trk_az_rad": 1e-6, "trk_length_m": 1e-4,
    "peak_freq_hz": 1e-2, "noise": 1e-6, "angle_spectrum": 1e-4,
    "ls_occupancy_pct": 1e-6, "ls_mean_speed_kmh": 1e-4, "ls_speed_p85_kmh": 1e-4, "ls_headway_s": 1e-6,
    "ls_gap_s": 1e-6,
}
#: relative part of the tolerance (CFAR noise and Bartlett spectra span decades)
REL_TOLERANCE = {"noise": 1e-5, "angle_spectrum": 1e-5, "peak_freq_hz": 1e-9}

_TRACK_FIELDS = ("track_id", "x_m", "y_m", "vx_mps", "vy_mps", "range_m", "radial_speed_mps", "az_rad",
                 "age_frames", "hits", "confirmed", "length_m", "lane")
_STAT_FIELDS = ("lane", "interval_start_ns", "sequence", "volume", "occupancy_pct", "mean_speed_kmh",
                "speed_p85_kmh", "headway_s", "gap_s")


def build(scenario: str, seed: int, interval_s: float):
    """(pipeline, frame iterator) as ``radar-edge evaluate`` builds them."""
    from edge.config import load_config
    from edge.evaluation.lane import _installer_config
    from edge.pipelines.lane import LanePipeline
    from hal.frame import RawFrame
    from hw_sim.boards import SIMO_BOARD
    from hw_sim.scenario import load_scenario_for_eval
    from hw_sim.simulator import FrameSimulator

    # figures measured on the v1 instrument; the corpus reports the physical defaults
    sc = load_scenario_for_eval(scenario, patch={"physics": {"preset": "v1"}})
    config = load_config(env={})
    lane_cfg, track_cfg, traffic_cfg = _installer_config(config, sc)
    traffic_cfg = dataclasses.replace(traffic_cfg, interval_s=interval_s)
    fe = SIMO_BOARD.frontend
    pipe = LanePipeline(fe, lane_cfg, track_cfg, traffic_cfg)
    sim = FrameSimulator(SIMO_BOARD, sc.build_scene(seed), seed)

    def frames(n: int):
        for k in range(n):
            f = sim.frame(k)
            yield RawFrame(k, int(round(f.t_s * 1e9)), f.i, f.q, fe, f.truth)

    return pipe, frames


def flatten(results, spectra: bool = True) -> dict[str, np.ndarray]:
    """``FrameResult`` list -> dict of flat arrays (see the module docstring); ``spectra=False`` leaves
    out the angle spectra, the CFAR noise and the peak frequencies (most of the bytes of a fixture)."""
    cols: dict[str, list] = {}

    def put(name, values):
        cols.setdefault(name, []).extend(values)

    for k, res in enumerate(results):
        d = res.detections
        n = len(d)
        put("det_frame", [k] * n)
        for name in ("range_m", "radial_speed_mps", "az_rad", "snr_db", "x_m", "y_m"):
            put(f"det_{name}", getattr(d, name).tolist())
        put("det_pair_residual_hz", d.extra["pair_residual_hz"].tolist())
        put("det_resolved_pair", d.extra["resolved_pair"].tolist())
        put("trk_frame", [k] * len(res.tracks))
        for name in _TRACK_FIELDS:
            vals = [getattr(t, name) for t in res.tracks]
            if name == "length_m":
                vals = [np.nan if v is None else v for v in vals]
            elif name == "lane":
                vals = [-2 if v is None else v for v in vals]
            put(f"trk_{name}", vals)
        put("presence", [int(p) for p in res.presence] + [-1])  # -1 ends a frame
        put("ls_frame", [k] * len(res.lane_stats))
        for name in _STAT_FIELDS:
            put(f"ls_{name}", [getattr(s, name) for s in res.lane_stats])
        put("ls_class_counts", [json.dumps(s.class_counts, sort_keys=True) for s in res.lane_stats])
        put("ev_frame", [k] * len(res.events))
        put("ev_kind", [e.kind for e in res.events])
        put("ev_track_id", [e.track_id for e in res.events])
        put("ev_lane", [-1 if e.lane is None else e.lane for e in res.events])
        it = res.intermediates
        pf = it["peak_freqs_hz"]
        put("peak_count", [len(f) for f in pf])
        if spectra:
            put("peak_freq_hz", np.concatenate(pf).tolist())
        if spectra:
            noise = it["noise"]
            r, c = np.nonzero(np.isfinite(noise))
            put("noise_frame", [k] * r.size)
            put("noise_row", r.tolist())
            put("noise_col", c.tolist())
            put("noise", noise[r, c].tolist())
        put("counts", [it["n_pair_candidates"], it["n_ghosts_rejected"], it["n_aided_pairs"]])
        if spectra:
            sp = it["angle_spectrum"]
            put("angle_spectrum_rows", [sp.shape[0]])
            put("angle_spectrum", sp.ravel().tolist())
    out = {}
    for name, v in cols.items():
        if name == "ls_class_counts" or name == "ev_kind":
            out[name] = np.asarray(v, dtype=str)
        else:
            out[name] = np.asarray(v)
    return out


def run(scenario: str, seed: int, frames: int, interval_s: float = 5.0, spectra: bool = True) -> dict[str, np.ndarray]:
    """The pipeline's outputs, with BLAS on one thread as on the device (the service unit sets
    OPENBLAS_NUM_THREADS=1): a threaded BLAS splits sums differently, and the runs diverge."""
    from threadpoolctl import threadpool_limits

    from edge.pipeline import StageTimer

    with threadpool_limits(limits=1):
        pipe, it = build(scenario, seed, interval_s)
        timer = StageTimer(16)
        return flatten([pipe.process(f, timer) for f in it(frames)], spectra)


def check(path: str | Path) -> list[str]:
    """Re-run the recording's scenario and compare (empty list: equivalent)."""
    import scipy

    ref, meta = load(path)
    errs = compare(ref, run(meta["scenario"], meta["seed"], meta["frames"], meta["interval_s"],
                            meta.get("spectra", True)))
    now = {"machine": machine(), "numpy": np.__version__, "scipy": scipy.__version__}
    moved = [f"{k} {meta[k]} -> {v}" for k, v in now.items() if k in meta and meta[k] != v]
    if errs and moved:  # say what else differs from the recording (round-off of another library or kernel)
        errs.append("recorded with another environment: " + ", ".join(moved))
    return errs


def compare(ref: dict[str, np.ndarray], new: dict[str, np.ndarray]) -> list[str]:
    """Differences (empty list: equivalent)."""
    errs = []
    for name in sorted(set(ref) | set(new)):
        if name == "meta":
            continue
        if name not in ref or name not in new:
            errs.append(f"{name}: only in {'new' if name in new else 'reference'}")
            continue
        a, b = ref[name], new[name]
        if a.shape != b.shape:
            errs.append(f"{name}: shape {a.shape} != {b.shape}")
            continue
        if name in TOLERANCE:
            a = a.astype(np.float64)
            b = b.astype(np.float64)
            tol = TOLERANCE[name] + REL_TOLERANCE.get(name, 0.0) * np.abs(a)
            nan_same = np.isnan(a) == np.isnan(b)
            diff = np.where(np.isnan(a) | np.isnan(b), 0.0, np.abs(a - b))
            bad = ~nan_same | (diff > tol)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                errs.append(f"{name}: {int(bad.sum())} of {a.size} differ, first at {i}: {a[i]!r} vs {b[i]!r} "
                            f"(max |diff| {diff.max():.3g})")
        else:
            if a.dtype.kind == "f":
                eq = (a == b) | (np.isnan(a) & np.isnan(b))
            else:
                eq = a == b
            if not np.all(eq):
                i = int(np.flatnonzero(~eq)[0])
                errs.append(f"{name}: {int((~eq).sum())} of {a.size} differ, first at {i}: {a[i]!r} vs {b[i]!r}")
    return errs


def save(path: str | Path, data: dict[str, np.ndarray], meta: dict) -> None:
    np.savez_compressed(path, meta=np.asarray(json.dumps(meta)), **data)


def load(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    with np.load(path) as z:
        data = {k: z[k] for k in z.files if k != "meta"}
        meta = json.loads(str(z["meta"]))
    return data, meta


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=("record", "check", "record-all", "machine"))
    p.add_argument("path", nargs="?", help="fixture file (record, check)")
    p.add_argument("--scenario", default="highway4-traffic")
    p.add_argument("--seed", type=int, default=31)
    p.add_argument("--frames", type=int, default=400)
    p.add_argument("--interval-s", type=float, default=5.0)
    p.add_argument("--no-spectra", action="store_true", help="leave the angle spectra, CFAR noise and peak frequencies out (small fixtures)")
    a = p.parse_args(argv)
    if a.action == "machine":
        print(machine())
        return 0
    if a.action in ("record", "check") and not a.path:
        p.error(f"{a.action} needs a fixture path")
    if a.action in ("record", "record-all"):
        jobs = ([(a.path, {"scenario": a.scenario, "seed": a.seed, "frames": a.frames})] if a.action == "record"
                else [(fixture_path(stem), args) for stem, args in FIXTURES.items()])
        for path, args in jobs:
            data = record(path, **args, interval_s=a.interval_s,
                          spectra=not a.no_spectra and a.action == "record")
            print(f"recorded {path}: {len(data['det_frame'])} detections, {len(data['trk_frame'])} track rows, "
                  f"{len(data['ls_frame'])} lane statistics, {len(data['ev_frame'])} events, "
                  f"confirmed ids {sorted(set(data['trk_track_id'].tolist()))}")
        return 0
    errs = check(a.path)
    print("\n".join(errs) if errs else f"equivalent: {a.path} ({load(a.path)[1]})")
    return 1 if errs else 0


if __name__ == "__main__":
    sys.exit(main())
