"""Stage-level fixtures of the lane pipeline: each stage's recorded input and output, to check on any machine that a
change (a speed-up, a refactor) leaves what a stage computes unchanged.

Whole runs of the pipeline cannot be compared across machines: the BLAS kernel and the SIMD targets numpy picks for
the CPU round differently in the last bits, a peak at the CFAR threshold then comes or goes, and the runs diverge
within a few dozen frames. Here every stage starts from its own recorded input instead, so a rounding difference
stays a rounding difference. A fixture (``data/golden/<stem>.npz``, one per entry of :data:`FIXTURES`) holds, for
every frame of a short seeded run of the scene (built as ``radar-edge evaluate`` builds it, the simulator pinned
to the v1 instrument, lane statistics every 5 s, BLAS on one thread as on the device)::

    spectra     raw int16 I/Q + clutter map and the last frame's -> complex spectra after clutter removal
                spectra before the frame
                (only the frames of ``fe_frames``: 330 kB each)
    detect      spectra + the replayed tracker/resolver/lanes  -> CFAR peaks (noise, margin), pairing counts,
                (only the frames of ``spec_frames``)              detections with their extras
    pairing     peak frequencies of the four segments          -> pairs (peak indices, range, speed, residual)
    angle       calibrated snapshots, peak bins, speeds         -> azimuth, agreeing and summed looks
    resolve     range, speed, looks, azimuth (stateful)         -> split, the two angles, two-source hint
    track       detections (stateful)                           -> published tracks, motion model's x
    traffic     tracks, motion x, body extents (stateful)       -> tracks with lanes, presence, lane statistics,
                                                                   events, yaw

Stateful stages (resolver, tracker, traffic layer) are replayed from frame 0 on recorded inputs only, and the
``detect`` frames run inside that replay (its tracker, resolver memory and lanes are the replayed ones). How each
output is compared, and why the tolerances are what they are, is in :data:`TOLERANCE` and
``tests/edge/test_lane_stages.py``. Discrete decisions compare exactly: the CFAR decision is exact float32
arithmetic on the recorded spectrum (its margin is recorded all the same, and a peak within :data:`CFAR_EPS` of
the threshold would be left out); the recorder checks that the other stages' decisions do not move when their float
inputs are perturbed by :data:`PERTURB_REL` (a thousand times float32 round-off) and leaves out the frames of the
stateless stages where one does (``meta["unstable"]``); the stateful replays must hold under it as a whole.

Re-record after a deliberate change of what a stage computes (each fixture's arguments are in :data:`FIXTURES`)::

    PYTHONPATH=. python -m tests.edge.lane_golden record-all
    PYTHONPATH=. python -m tests.edge.lane_golden check-all     # the same comparisons as the tests, printed

Then look at the diff of ``tests/edge/test_lane_stages.py``'s coverage assertions (resolved pairs, aided pairs,
events) and of the metric bands in ``tests/edge/test_lane_bands.py``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
import types
from pathlib import Path
from typing import Any

import numpy as np

DATA_DIR = Path(__file__).parent / "data" / "golden"

#: the simulator's physics the fixtures are recorded with (the hw_sim changes of issue 28 do not move them)
V1_PATCH = {"physics": {"preset": "v1"}}

#: the fixtures: file stem -> recording arguments (``fe_frames``: frames with the raw I/Q and clutter map kept for
#: the spectra stage; ``spec_frames``: frames whose spectra feed the detect stage, chosen with track-aided pairs
#: (misaimed 50, side-by-side 86, wrong-way 107) and a resolved side-by-side pair (104); all after the clutter
#: map's median start-up, 16 frames)
FIXTURES = {
    "lane_stages_misaimed_s31": {"scenario": "highway4-misaimed", "seed": 31, "frames": 200,
                                 "fe_frames": [150], "spec_frames": [50, 145]},
    "lane_stages_side_by_side_s31": {"scenario": "side-by-side", "seed": 31, "frames": 300,
                                     "fe_frames": [120], "spec_frames": [86, 104]},
    "lane_stages_wrong_way_s6": {"scenario": "wrong-way", "seed": 6, "frames": 240,
                                 "fe_frames": [100], "spec_frames": [107, 200]},
}

#: relative size of the perturbation of the float inputs under which every discrete decision must hold (float32
#: round-off is 6e-8; a different FFT or BLAS kernel moves results by a few of those)
PERTURB_REL = 1e-6
#: a CFAR peak whose power is within this relative margin of its threshold is not compared (the decision itself
#: is exact float32 arithmetic on the recorded spectrum, so none is expected to flip)
CFAR_EPS = 1e-5

#: comparison of float outputs: name -> (absolute, relative) tolerance, |a - b| <= abs + rel |a|; every other
#: output (ids, counts, lanes, flags, indices, classes, events) compares exactly. Why these values: see
#: ``tests/edge/test_lane_stages.py``.
TOLERANCE = {
    # spectra: float32 FFT of 1024 points; error ~ eps32 sqrt(log2 n) of the row's norm, and the clutter
    # subtraction leaves that of the (80 dB stronger) TX leakage: absolute, per row, relative to its largest bin
    "spec": (0.0, 2e-5),
    # detect from a recorded spectrum: power, CFAR and peak picking are exact; the peak interpolation's float32 log
    # (SIMD libm, 1-4 ulp) moves a frequency by < 1e-4 of a bin (bins are 2.0-3.9 kHz); the rest follows from it
    "peak_freq_hz": (1e-2, 1e-6), "noise": (0.0, 1e-6), "margin": (0.0, 1e-6),
    "range_m": (1e-4, 1e-6), "radial_speed_mps": (1e-4, 1e-6), "az_rad": (2e-5, 0.0), "snr_db": (1e-3, 0.0),
    "x_m": (2e-3, 0.0), "y_m": (2e-4, 1e-6), "pair_residual_hz": (0.5, 1e-3), "body_extent_m": (2e-3, 1e-5),
    "angle_coherence": (1e-4, 0.0),
    # resolver: float32 eigen-decomposition of 4x4 covariances (LAPACK), angles from a grid search refined by
    # a parabola
    "ang": (1e-4, 0.0),
    # tracker and traffic layer: float64 Kalman filters (BLAS small products) fed recorded detections; round-off
    # ~1e-12 relative, kept small by the filters' contraction over a few hundred frames
    "trk_x_m": (1e-6, 1e-9), "trk_y_m": (1e-6, 1e-9), "trk_vx_mps": (1e-6, 1e-9), "trk_vy_mps": (1e-6, 1e-9),
    "trk_range_m": (1e-6, 1e-9), "trk_radial_speed_mps": (1e-6, 1e-9), "trk_az_rad": (1e-8, 1e-9),
    "trk_length_m": (1e-6, 1e-9), "trk_rcs_dbsm": (1e-6, 1e-9), "trk_class_probability": (1e-8, 1e-9),
    "trk_x_sd_m": (1e-6, 1e-8), "trk_y_sd_m": (1e-6, 1e-8), "trk_vx_sd_mps": (1e-6, 1e-8),
    "trk_vy_sd_mps": (1e-6, 1e-8), "trk_existence_probability": (1e-8, 1e-8), "motion_x_m": (1e-6, 1e-9),
    "ls_interval_s": (0.0, 0.0), "ls_occupancy_pct": (1e-6, 1e-9), "ls_mean_speed_kmh": (1e-6, 1e-9),
    "ls_speed_p85_kmh": (1e-6, 1e-9), "ls_headway_s": (1e-6, 1e-9), "ls_gap_s": (1e-6, 1e-9),
    "ls_mean_length_m": (1e-6, 1e-9), "yaw_rad": (1e-9, 1e-9), "yaw_sigma_rad": (1e-9, 1e-9),
}


# --- building the pipeline ---------------------------------------------------------------------------------------


def build(scenario: str, seed: int, interval_s: float, patch: dict | None = None, lane_overrides: dict | None = None):
    """(pipeline, frame iterator) as ``radar-edge evaluate`` builds them, the lane statistics every ``interval_s``;
    ``patch``: a scenario patch (:func:`hw_sim.scenario.apply_patch`), ``lane_overrides``: fields of the lane
    configuration replaced."""
    from edge.config import load_config
    from edge.evaluation.lane import _installer_config
    from edge.pipelines.lane import LanePipeline
    from hal.frame import RawFrame
    from hw_sim.scenario import load_scenario_for_eval
    from hw_sim.simulator import FrameSimulator

    sc = load_scenario_for_eval(scenario, patch=patch)
    config = load_config(env={})
    lane_cfg, track_cfg, traffic_cfg = _installer_config(config, sc)
    traffic_cfg = dataclasses.replace(traffic_cfg, interval_s=interval_s)
    if lane_overrides:
        lane_cfg = dataclasses.replace(lane_cfg, **lane_overrides)
    board = sc.sim_board()
    fe = board.frontend
    pipe = LanePipeline(fe, lane_cfg, track_cfg, traffic_cfg)

    def frames(n: int):
        sim = FrameSimulator(board, sc.build_scene(seed), seed)
        for k in range(n):
            f = sim.frame(k)
            yield RawFrame(k, int(round(f.t_s * 1e9)), f.i, f.q, fe, f.truth)

    return pipe, frames


# --- a columnar store of per-frame rows --------------------------------------------------------------------------


class Rows:
    """Per-frame arrays under names, saved as one concatenation per name plus the per-frame row counts
    (``name@n``); a frame that did not record a name has 0 rows of it."""

    def __init__(self, n_frames: int) -> None:
        self.n = n_frames
        self.parts: dict[str, dict[int, np.ndarray]] = {}

    def put(self, name: str, frame: int, value) -> None:
        a = np.array(value)  # a copy: the pipeline changes some of its arrays in place afterwards
        self.parts.setdefault(name, {})[frame] = a.reshape((1,) + a.shape) if a.ndim == 0 else a

    def arrays(self) -> dict[str, np.ndarray]:
        out = {}
        for name, parts in self.parts.items():
            first = next(iter(parts.values()))
            empty = np.zeros((0,) + first.shape[1:], first.dtype)
            seq = [parts.get(k, empty) for k in range(self.n)]
            out[name] = np.concatenate(seq) if seq else empty
            out[name + "@n"] = np.array([s.shape[0] for s in seq], np.int32)
        return out


class Frames:
    """Read side of :class:`Rows`: ``get(name, frame)`` -> that frame's rows."""

    def __init__(self, data: dict[str, np.ndarray]) -> None:
        self.data = data
        self._ofs = {}

    def has(self, name: str, frame: int) -> bool:
        return name in self.data and self.data[name + "@n"][frame] > 0

    def get(self, name: str, frame: int) -> np.ndarray:
        if name not in self._ofs:
            self._ofs[name] = np.concatenate([[0], np.cumsum(self.data[name + "@n"])])
        o = self._ofs[name]
        return self.data[name][o[frame]:o[frame + 1]]


# TrackState <-> columns (every field; None kept apart from the values)

def _track_fields():
    from edge.types import TrackState

    return [f.name for f in dataclasses.fields(TrackState)]


def put_tracks(rows: Rows, prefix: str, frame: int, tracks) -> None:
    for name in _track_fields():
        vals = [getattr(t, name) for t in tracks]
        none = np.array([v is None for v in vals], bool)
        if name == "cls":
            rows.put(f"{prefix}_{name}", frame, np.array(["" if v is None else v for v in vals], dtype="U16"))
        elif name in ("track_id", "age_frames", "hits", "lane"):
            rows.put(f"{prefix}_{name}", frame, np.array([-99 if v is None else v for v in vals], np.int64))
        elif name == "confirmed":
            rows.put(f"{prefix}_{name}", frame, np.array(vals, bool))
        else:
            rows.put(f"{prefix}_{name}", frame, np.array([np.nan if v is None else v for v in vals], np.float64))
        rows.put(f"{prefix}_{name}!none", frame, none)


def get_tracks(fr: Frames, prefix: str, frame: int) -> tuple:
    from edge.types import TrackState

    cols = {}
    for name in _track_fields():
        vals = fr.get(f"{prefix}_{name}", frame).tolist()
        none = fr.get(f"{prefix}_{name}!none", frame).tolist()
        cols[name] = [None if nn else v for v, nn in zip(vals, none)]
    n = len(cols["track_id"])
    return tuple(TrackState(**{k: v[i] for k, v in cols.items()}) for i in range(n))


# --- recording ---------------------------------------------------------------------------------------------------


@contextlib.contextmanager
def patched(obj, name: str, value):
    old = getattr(obj, name)
    setattr(obj, name, value)
    try:
        yield
    finally:
        setattr(obj, name, old)


def _det_columns(det) -> dict[str, np.ndarray]:
    cols = {n: getattr(det, n) for n in ("range_m", "radial_speed_mps", "az_rad", "snr_db", "x_m", "y_m")}
    cols.update({f"extra.{k}": v for k, v in det.extra.items()})
    return cols


def _cfar_rows(pipe, inter) -> dict[str, np.ndarray]:
    """The CFAR stage's outputs of a frame: per local maximum (segment, bin) its noise estimate and the margin
    power / (noise x scale) of the detection threshold (above 1: a peak), and the peak frequencies."""
    noise = inter["noise"]
    r, c = np.nonzero(np.isfinite(noise))
    power = inter["power"]
    nz = noise[r, c]
    margin = power[r, c].astype(np.float64) / (nz.astype(np.float64) * float(pipe.peaks.scale32))
    pf = inter["peak_freqs_hz"]
    return {"cfar_row": r.astype(np.int16), "cfar_col": c.astype(np.int16), "noise": nz, "margin": margin,
            "peak_freq_hz": np.concatenate(pf), "peak_seg": np.concatenate([np.full(len(f), k, np.int8)
                                                                            for k, f in enumerate(pf)])}


def record_run(scenario: str, seed: int, frames: int, fe_frames=(), spec_frames=(), interval_s: float = 5.0):
    """Run the scene once through the pipeline with every stage boundary tapped; returns (arrays, meta)."""
    import edge.lane.angles as angle_mod
    import edge.lane.pairs as pair_mod
    import edge.lane.spectra as spectra_mod
    from edge.pipeline import StageTimer
    from threadpoolctl import threadpool_limits

    rows = Rows(frames)
    fe_frames, spec_frames = set(fe_frames), set(spec_frames)
    with threadpool_limits(limits=1):
        pipe, it = build(scenario, seed, interval_s, patch=V1_PATCH)
        cfg = pipe.config
        # the pairing and the angles are recorded from their numpy references (patched below)
        pipe.pairs.kernel = pipe.angles.kernel = None
        assert cfg.clutter_map_init_frames <= min(fe_frames | spec_frames, default=10**9)
        cur = {"k": -1, "spec": None}
        real_fft = spectra_mod.scipy.fft.fft
        real_pair, real_bartlett = pair_mod.pair_beats, angle_mod.bartlett_consensus

        def fft(*a, **kw):
            cur["spec"] = out = real_fft(*a, **kw)
            return out

        pair_kw = {}

        def pair(freqs, model, **kw):
            out = real_pair(freqs, model, **kw)
            k = cur["k"]
            pair_kw.update(kw, model_a=model.a.tolist(), model_b=model.b.tolist())
            for s in range(4):
                rows.put(f"pair_in_f{s}", k, np.asarray(freqs[s], np.float64))
            rows.put("pair_peak_index", k, out.peak_index.astype(np.int32).reshape(-1, 4))
            rows.put("pair_range_m", k, out.range_m)
            rows.put("pair_radial_speed_mps", k, out.radial_speed_mps)
            rows.put("pair_residual_hz", k, out.residual_hz)
            rows.put("pair_counts", k, np.array([[out.n_candidates, out.n_ghosts]], np.int32))
            return out

        angle_kw = {}
        angle_last = {"snaps": np.zeros((0, 4, pipe.frontend.n_rx), np.complex64),
                      "kept_used": (np.zeros((0, 4), bool), np.zeros((0, 4), bool))}

        def bartlett(snaps, steer, grid, outlier, pk, shared_bins, min_agreeing, **kw):
            out = real_bartlett(snaps, steer, grid, outlier, pk, shared_bins, min_agreeing, **kw)
            k = cur["k"]
            angle_kw.update(shared_bins=shared_bins, min_agreeing=min_agreeing,
                            min_speed_diff=kw.get("min_speed_diff", 0.0), peak_bins=pk is not None)
            rows.put("angle_in_snaps", k, snaps.astype(np.complex64))
            rows.put("angle_in_outlier", k, np.broadcast_to(np.asarray(outlier, np.float32), (snaps.shape[0],)))
            rows.put("angle_in_pk", k, (pk if pk is not None else np.zeros((snaps.shape[0], 4))).astype(np.int32))
            rows.put("angle_in_speeds", k, np.asarray(kw["speeds"], np.float32))
            az, _, kept, used = out
            angle_last.update(snaps=snaps.copy(), kept_used=(kept.copy(), used.copy()))
            rows.put("angle_az", k, az)
            rows.put("angle_kept", k, kept)
            rows.put("angle_used", k, used)
            return out

        resolver = pipe.resolve.resolver
        real_resolve = resolver.step

        def resolve(rng, vel, looks, az=None):
            split, ang = real_resolve(rng, vel, looks, az)
            k = cur["k"]
            # its looks are the angle stage's snapshots times its summed looks (of the detections kept): not stored
            snaps, kept_used = angle_last["snaps"], angle_last["kept_used"]
            assert np.array_equal(looks, _looks(snaps, *kept_used, angle_kw["min_agreeing"]))
            for name, v in (("rng", rng), ("vel", vel), ("az", az)):
                rows.put(f"res_in_{name}", k, v)
            rows.put("res_split", k, split)
            rows.put("res_ang", k, ang)
            rows.put("res_two", k, resolver.two_sources.copy())
            return split, ang

        real_track = pipe.tracker.step

        def track(det, t_ns):
            k = cur["k"]
            for name, v in _det_columns(det).items():
                rows.put(f"det_{name}", k, v)
            out = real_track(det, t_ns)
            put_tracks(rows, "trk", k, out)
            mx = pipe.tracker.published_motion_x_m
            rows.put("motion_x_m", k, np.zeros(0) if mx is None else mx)
            rows.put("motion_none", k, mx is None)
            return out

        real_traffic = pipe.traffic.update

        def traffic(tracks, t_ns, yaw_x_m=None, extent_m=None):
            k = cur["k"]
            rows.put("ext_m", k, np.zeros(0) if extent_m is None else extent_m)
            rows.put("ext_none", k, extent_m is None)
            upd = real_traffic(tracks, t_ns, yaw_x_m, extent_m)
            put_tracks(rows, "tfc", k, upd.tracks)
            rows.put("presence", k, np.array(upd.presence, bool))
            for f in dataclasses.fields(upd.lane_stats[0]) if upd.lane_stats else ():
                vals = [getattr(s, f.name) for s in upd.lane_stats]
                if f.name == "class_counts":
                    vals = [json.dumps(v, sort_keys=True) for v in vals]
                rows.put(f"ls_{f.name}", k, np.array(vals))
            rows.put("ev_kind", k, np.array([e.kind for e in upd.events], dtype="U24"))
            rows.put("ev_track_id", k, np.array([e.track_id for e in upd.events], np.int64))
            rows.put("ev_lane", k, np.array([-99 if e.lane is None else e.lane for e in upd.events], np.int64))
            rows.put("ev_t_ns", k, np.array([e.t_ns for e in upd.events], np.int64))
            rows.put("yaw", k, np.array([[pipe.traffic.yaw_rad, pipe.traffic.yaw_sigma_rad]]))
            return upd

        real_hold = pipe.clutter._hold_standing
        held = {"any": False}

        def hold(d, tracks):
            before = d.copy()
            real_hold(d, tracks)
            held["any"] = not np.array_equal(before, d, equal_nan=True)

        timer = StageTimer(16)
        ctx = contextlib.ExitStack()
        with ctx:
            ctx.enter_context(patched(spectra_mod, "scipy", types.SimpleNamespace(fft=types.SimpleNamespace(fft=fft))))
            ctx.enter_context(patched(pair_mod, "pair_beats", pair))
            ctx.enter_context(patched(angle_mod, "bartlett_consensus", bartlett))
            ctx.enter_context(patched(resolver, "step", resolve))
            ctx.enter_context(patched(pipe.tracker, "step", track))
            ctx.enter_context(patched(pipe.traffic, "update", traffic))
            ctx.enter_context(patched(pipe.clutter, "_hold_standing", hold))
            for f in it(frames):
                k = cur["k"] = f.seq
                angle_last.update(snaps=np.zeros((0, 4, pipe.frontend.n_rx), np.complex64),
                                  kept_used=(np.zeros((0, 4), bool), np.zeros((0, 4), bool)))
                rows.put("t_ns", k, np.array([f.t_ns], np.int64))
                if k in fe_frames:
                    assert pipe.clutter._map_init is None
                    rows.put("fe_i", k, f.i[None])
                    rows.put("fe_q", k, f.q[None])
                    rows.put("fe_background", k, pipe.clutter._background[None].copy())
                    rows.put("fe_map_frames", k, np.array([pipe.clutter._map_frames]))
                    rows.put("fe_prev", k, pipe.clutter._prev[None].copy())
                held["any"] = False
                res = pipe.process(f, timer)
                inter = res.intermediates
                rows.put("n_aided", k, np.array([inter["n_aided_pairs"]]))
                if k in fe_frames or k in spec_frames:
                    rows.put("spec", k, cur["spec"][None].copy())
                    rows.put("spec_held", k, np.array([held["any"]]))
                    for name, v in _cfar_rows(pipe, inter).items():
                        rows.put(f"cfar_{name}" if not name.startswith("cfar_") else name, k, v)
    meta = {"scenario": scenario, "seed": seed, "frames": frames, "interval_s": interval_s, "patch": V1_PATCH,
            "fe_frames": sorted(fe_frames), "spec_frames": sorted(spec_frames), "pair_kw": _jsonable(pair_kw),
            "angle_kw": angle_kw, "steer": [np.real(pipe.angles.steer).tolist(), np.imag(pipe.angles.steer).tolist()],
            "steer_dtype": str(pipe.angles.steer.dtype), "grid": pipe.angles.grid.tolist(),
            "cfar_scale": float(pipe.peaks.scale32),
            "versions": _versions()}
    return rows.arrays(), meta


def _looks(snaps: np.ndarray, kept: np.ndarray, used: np.ndarray, min_agreeing: int) -> np.ndarray:
    """The resolver's looks as the pipeline forms them: the snapshots of the detections with at least
    ``min_agreeing`` agreeing looks, the looks not summed into the angle zeroed."""
    keep = (np.add.reduce(kept, axis=1) >= min_agreeing).nonzero()[0]
    return snaps[keep] * used[keep][:, :, None]


def _jsonable(d: dict) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


def _versions() -> dict:
    import scipy

    return {"numpy": np.__version__, "scipy": scipy.__version__}


def save(path: str | Path, data: dict[str, np.ndarray], meta: dict) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, meta=np.asarray(json.dumps(meta)), **data)


def load(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    with np.load(path) as z:
        data = {k: z[k] for k in z.files if k != "meta"}
        meta = json.loads(str(z["meta"]))
    return data, meta


def fixture_path(stem: str) -> Path:
    return DATA_DIR / f"{stem}.npz"


# --- comparing ---------------------------------------------------------------------------------------------------


#: while set (:func:`discrete_only`), :func:`compare` leaves out the float outputs
_DISCRETE_ONLY = [False]


@contextlib.contextmanager
def discrete_only():
    """Compare only the discrete outputs (under a perturbation of the inputs the floats move with it)."""
    _DISCRETE_ONLY[0] = True
    try:
        yield
    finally:
        _DISCRETE_ONLY[0] = False


def compare(name: str, ref, new, tol_key: str | None = None, where: str = "") -> list[str]:
    """Differences between a recorded and a recomputed output (empty: equal within :data:`TOLERANCE`)."""
    a, b = np.asarray(ref), np.asarray(new)
    label = f"{where}{name}"
    if a.shape != b.shape:
        return [f"{label}: shape {a.shape} != {b.shape}"]
    if _DISCRETE_ONLY[0] and a.dtype.kind in "fc":
        return []
    key = tol_key or name
    if key in TOLERANCE and a.dtype.kind in "fc":
        atol, rtol = TOLERANCE[key]
        a64, b64 = a.astype(np.complex128 if a.dtype.kind == "c" else np.float64), b.astype(
            np.complex128 if b.dtype.kind == "c" else np.float64)
        nan_a, nan_b = np.isnan(a64), np.isnan(b64)
        diff = np.where(nan_a | nan_b, 0.0, np.abs(a64 - b64))
        bad = (nan_a != nan_b) | (diff > atol + rtol * np.abs(np.where(nan_a, 0, a64)))
        if bad.any():
            i = np.unravel_index(int(np.flatnonzero(bad)[0]), a.shape)
            return [f"{label}: {int(bad.sum())} of {a.size} differ, first at {i}: {a[i]!r} vs {b[i]!r} "
                    f"(max |diff| {diff.max():.3g}; tolerance {atol:g} + {rtol:g} x |value|)"]
        return []
    if a.dtype.kind == "f":
        eq = (a == b) | (np.isnan(a) & np.isnan(b))
    else:
        eq = a == b
    if not np.all(eq):
        i = np.unravel_index(int(np.flatnonzero(~eq)[0]), a.shape)
        return [f"{label}: {int((~eq).sum())} of {a.size} differ, first at {i}: {a[i]!r} vs {b[i]!r}"]
    return []


def _jitter(rng: np.random.Generator | None, a: np.ndarray) -> np.ndarray:
    """``a`` with every float multiplied by (1 + PERTURB_REL x N(0, 1)) (``rng`` None: ``a`` itself)."""
    if rng is None or a.dtype.kind not in "fc":
        return a
    if a.dtype.kind == "c":
        f = 1 + PERTURB_REL * (rng.standard_normal(a.shape) + 1j * rng.standard_normal(a.shape))
    else:
        f = 1 + PERTURB_REL * rng.standard_normal(a.shape)
    return (a * f).astype(a.dtype)


def check_pairing(data, meta, rng=None) -> dict[int, list[str]]:
    """Per frame: the pairing's outputs recomputed from its recorded peak frequencies (errors; empty lists too)."""
    from edge.dsp.pairing import PairingModel, pair_beats

    fr = Frames(data)
    kw = dict(meta["pair_kw"])
    model = PairingModel(np.array(kw.pop("model_a")), np.array(kw.pop("model_b")))
    for k in ("tolerance_hz", "near_tolerance_hz"):
        if kw.get(k) is not None:
            kw[k] = tuple(kw[k])
    out = {}
    for k in range(meta["frames"]):
        if not fr.has("pair_counts", k):
            continue
        freqs = tuple(_jitter(rng, fr.get(f"pair_in_f{s}", k)) for s in range(4))
        p = pair_beats(freqs, model, **kw)
        w = f"frame {k} pairing "
        errs = compare("peak_index", fr.get("pair_peak_index", k), p.peak_index.reshape(-1, 4), where=w)
        if not errs:
            errs += compare("range_m", fr.get("pair_range_m", k), p.range_m, where=w)
            errs += compare("radial_speed_mps", fr.get("pair_radial_speed_mps", k), p.radial_speed_mps, where=w)
            errs += compare("pair_residual_hz", fr.get("pair_residual_hz", k), p.residual_hz, where=w)
        errs += compare("counts", fr.get("pair_counts", k)[0], [p.n_candidates, p.n_ghosts], where=w)
        out[k] = errs
    return out


def check_angle(data, meta, rng=None) -> dict[int, list[str]]:
    """Per frame: the Bartlett consensus recomputed from its recorded snapshots, peak bins and speeds."""
    from edge.dsp.angle import bartlett_consensus

    fr = Frames(data)
    re, im = (np.array(v) for v in meta["steer"])
    steer = (re + 1j * im).astype(meta["steer_dtype"])
    grid = np.array(meta["grid"], np.float32)
    kw = meta["angle_kw"]
    out = {}
    for k in range(meta["frames"]):
        if not fr.has("angle_az", k):
            continue
        snaps = _jitter(rng, fr.get("angle_in_snaps", k))
        az, _, kept, used = bartlett_consensus(
            snaps, steer, grid, fr.get("angle_in_outlier", k), fr.get("angle_in_pk", k) if kw["peak_bins"] else None,
            kw["shared_bins"], kw["min_agreeing"], speeds=fr.get("angle_in_speeds", k),
            min_speed_diff=kw["min_speed_diff"])
        w = f"frame {k} angle "
        out[k] = (compare("kept", fr.get("angle_kept", k), kept, where=w)
                  + compare("used", fr.get("angle_used", k), used, where=w)
                  + compare("az_rad", fr.get("angle_az", k), az, where=w))
    return out


def check_spectra(data, meta) -> dict[int, list[str]]:
    """Per frame of ``fe_frames``: the front end (windowed FFT, clutter-map update and subtraction) from the recorded
    raw I/Q and clutter map; the spectrum compared per (channel, segment) row relative to its largest bin."""
    import edge.lane.spectra as spectra_mod
    from edge.pipeline import StageTimer
    from hal.frame import RawFrame

    fr = Frames(data)
    out = {}
    real_fft = spectra_mod.scipy.fft.fft
    for k in meta["fe_frames"]:
        pipe, _ = build(meta["scenario"], meta["seed"], meta["interval_s"], patch=meta["patch"])
        pipe.clutter._map_init = None
        pipe.clutter._background[...] = fr.get("fe_background", k)[0]
        pipe.clutter._map_frames = int(fr.get("fe_map_frames", k)[0])
        pipe.clutter._prev = fr.get("fe_prev", k)[0].copy()  # the last frame's spectra (what stands still)
        got = {}

        def fft(*a, **kw):
            got["spec"] = s = real_fft(*a, **kw)
            return s

        t_ns = int(fr.get("t_ns", k)[0])
        with patched(spectra_mod, "scipy", types.SimpleNamespace(fft=types.SimpleNamespace(fft=fft))):
            pipe.detect(RawFrame(k, t_ns, fr.get("fe_i", k)[0], fr.get("fe_q", k)[0], pipe.frontend, None),
                        StageTimer(16))
        ref = fr.get("spec", k)[0]
        new = got["spec"]
        # per row: relative to its largest raw bin (the TX leakage before clutter removal dominates the round-off)
        raw = np.abs(ref + pipe.clutter._background).max(axis=-1, keepdims=True).astype(np.float64)
        atol, rtol = TOLERANCE["spec"]
        diff = np.abs(ref.astype(np.complex128) - new)
        bad = diff > atol + rtol * raw
        errs = [f"frame {k} spectra: {int(bad.sum())} of {bad.size} bins differ (max |diff| / row max "
                f"{(diff / raw).max():.3g}; tolerance {rtol:g})"] if bad.any() else []
        if bool(fr.get("spec_held", k)[0]):
            errs.append(f"frame {k}: the clutter map was held under a stopped track (not reproducible here)")
        out[k] = errs
    return out


def replay(data, meta, rng=None) -> dict[str, dict[int, list[str]]]:
    """The stateful stages replayed from frame 0 on recorded inputs (see the module docstring); per stage, per frame,
    the differences. ``detect`` runs at ``spec_frames`` from the recorded spectrum; ``resolve`` is compared at the
    other frames (at the detect frames it runs inside detect)."""
    import edge.lane.spectra as spectra_mod
    from edge.pipeline import StageTimer
    from edge.types import Detections
    from hal.frame import RawFrame
    from threadpoolctl import threadpool_limits

    fr = Frames(data)
    out: dict[str, dict[int, list[str]]] = {"detect": {}, "resolve": {}, "track": {}, "traffic": {}}
    spec_frames = set(meta["spec_frames"])
    det_names = [n[4:] for n in data if n.startswith("det_") and not n.endswith("@n")]
    ls_names = [n[3:] for n in data if n.startswith("ls_") and not n.endswith("@n")]
    with threadpool_limits(limits=1):
        pipe, _ = build(meta["scenario"], meta["seed"], meta["interval_s"], patch=meta["patch"],
                        lane_overrides={"clutter_map_time_s": 0.0})
        zeros = np.zeros(pipe.frontend.frame_shape, np.int16)
        timer = StageTimer(16)
        for k in range(meta["frames"]):
            t_ns = int(fr.get("t_ns", k)[0])
            if k in spec_frames:
                spec = fr.get("spec", k)[0]  # (not perturbed: power and CFAR are exact float32 arithmetic on it)
                fake = types.SimpleNamespace(fft=types.SimpleNamespace(fft=lambda *a, **kw: spec.copy()))
                with patched(spectra_mod, "scipy", fake):
                    det, inter = pipe.detect(RawFrame(k, t_ns, zeros, zeros, pipe.frontend, None), timer)
                w = f"frame {k} detect "
                errs = []
                cf = _cfar_rows(pipe, inter)
                ref_margin = fr.get("cfar_margin", k)
                errs += compare("cfar_row", fr.get("cfar_row", k), cf["cfar_row"], where=w)
                errs += compare("cfar_col", fr.get("cfar_col", k), cf["cfar_col"], where=w)
                if not errs:
                    clear = np.abs(ref_margin - 1.0) > CFAR_EPS
                    errs += compare("noise", fr.get("cfar_noise", k)[clear], cf["noise"][clear], where=w)
                    errs += compare("margin", ref_margin[clear], cf["margin"][clear], where=w)
                    errs += compare("peak_seg", fr.get("cfar_peak_seg", k), cf["peak_seg"], where=w)
                    if not errs:
                        errs += compare("peak_freq_hz", fr.get("cfar_peak_freq_hz", k), cf["peak_freq_hz"], where=w)
                errs += compare("n_aided", fr.get("n_aided", k), [inter["n_aided_pairs"]], where=w)
                new = _det_columns(det)
                errs += compare("columns", sorted(det_names), sorted(new), where=w)
                for name in det_names:
                    if name in new:
                        errs += compare(name, fr.get(f"det_{name}", k), new[name], tol_key=name.split(".")[-1],
                                        where=w)
                out["detect"][k] = errs
            else:  # the resolver is stepped every frame (with no detections too)
                looks = _jitter(rng, _looks(fr.get("angle_in_snaps", k), fr.get("angle_kept", k),
                                            fr.get("angle_used", k), meta["angle_kw"]["min_agreeing"]))
                split, ang = pipe.resolve.resolver.step(fr.get("res_in_rng", k), fr.get("res_in_vel", k), looks,
                                                _jitter(rng, fr.get("res_in_az", k)))
                w = f"frame {k} resolve "
                out["resolve"][k] = (compare("split", fr.get("res_split", k), split, where=w)
                                     + compare("two_sources", fr.get("res_two", k), pipe.resolve.resolver.two_sources, where=w)
                                     + compare("ang", fr.get("res_ang", k), ang, where=w))
            # the tracker on the recorded detections
            cols = {n: _jitter(rng, fr.get(f"det_{n}", k)) for n in det_names}
            det = Detections(*(cols[n] for n in ("range_m", "radial_speed_mps", "az_rad", "snr_db", "x_m", "y_m")),
                             {n[6:]: v for n, v in cols.items() if n.startswith("extra.")})
            tracks = pipe.tracker.step(det, t_ns)
            w = f"frame {k} track "
            out["track"][k] = _compare_tracks(fr, "trk", k, tracks, w)
            mx = pipe.tracker.published_motion_x_m
            out["track"][k] += compare("motion_none", fr.get("motion_none", k), [mx is None], where=w)
            if mx is not None and not out["track"][k]:
                out["track"][k] += compare("motion_x_m", fr.get("motion_x_m", k), mx, where=w)
            # the traffic layer on the recorded tracks
            rec_tracks = get_tracks(fr, "trk", k)
            yaw_x = None if bool(fr.get("motion_none", k)[0]) else fr.get("motion_x_m", k)
            ext = None if bool(fr.get("ext_none", k)[0]) else fr.get("ext_m", k)
            upd = pipe.traffic.update(rec_tracks, t_ns, yaw_x, ext)
            w = f"frame {k} traffic "
            errs = _compare_tracks(fr, "tfc", k, upd.tracks, w)
            errs += compare("presence", fr.get("presence", k), np.array(upd.presence, bool), where=w)
            n_ls = fr.get("ls_lane", k).size if "ls_lane" in data else 0
            errs += compare("lane_stats", [n_ls], [len(upd.lane_stats)], where=w)
            if n_ls == len(upd.lane_stats) and n_ls:
                for name in ls_names:
                    vals = [getattr(s, name) for s in upd.lane_stats]
                    if name == "class_counts":
                        vals = [json.dumps(v, sort_keys=True) for v in vals]
                    errs += compare(name, fr.get(f"ls_{name}", k), np.array(vals), tol_key=f"ls_{name}", where=w)
            errs += compare("ev_kind", fr.get("ev_kind", k), np.array([e.kind for e in upd.events], dtype="U24"),
                            where=w)
            if not errs:
                errs += compare("ev_track_id", fr.get("ev_track_id", k), [e.track_id for e in upd.events], where=w)
                errs += compare("ev_lane", fr.get("ev_lane", k), [-99 if e.lane is None else e.lane
                                                                  for e in upd.events], where=w)
                errs += compare("ev_t_ns", fr.get("ev_t_ns", k), [e.t_ns for e in upd.events], where=w)
            yaw = fr.get("yaw", k)[0]
            errs += compare("yaw_rad", yaw[:1], [pipe.traffic.yaw_rad], where=w)
            errs += compare("yaw_sigma_rad", yaw[1:], [pipe.traffic.yaw_sigma_rad], where=w)
            out["traffic"][k] = errs
            pipe.tracker.road_yaw_rad = float(yaw[0])  # the tracker's input, as recorded (the pipeline's order)
    return out


def _compare_tracks(fr: Frames, prefix: str, k: int, tracks, where: str) -> list[str]:
    errs = compare(f"{prefix}_count", [fr.get(f"{prefix}_track_id", k).size], [len(tracks)], where=where)
    if errs:
        return errs
    for name in _track_fields():
        vals = [getattr(t, name) for t in tracks]
        errs += compare(f"{prefix}_{name}!none", fr.get(f"{prefix}_{name}!none", k),
                        np.array([v is None for v in vals], bool), where=where)
        ref = fr.get(f"{prefix}_{name}", k)
        if ref.dtype.kind == "U":
            new = np.array(["" if v is None else v for v in vals], dtype=ref.dtype)
        elif ref.dtype.kind == "f":
            new = np.array([np.nan if v is None else v for v in vals], np.float64)
        elif ref.dtype.kind == "b":
            new = np.array(vals, bool)
        else:
            new = np.array([-99 if v is None else v for v in vals], np.int64)
        errs += compare(f"{prefix}_{name}", ref, new, tol_key=f"trk_{name}", where=where)
    return errs


def unstable_frames(data, meta, seed: int = 0) -> dict[str, list[int]]:
    """Frames of the stateless stages where a discrete output (pairing: peak indices and counts; angle: agreeing
    and summed looks) moves under a :data:`PERTURB_REL` perturbation of the float inputs (a decision within that
    of its threshold), per stage: the tests leave them out."""
    rng = np.random.default_rng(seed)
    with discrete_only():
        return {"pairing": sorted(k for k, e in check_pairing(data, meta, rng).items() if e),
                "angle": sorted(k for k, e in check_angle(data, meta, rng).items() if e)}


def record(stem: str, scenario: str, seed: int, frames: int, fe_frames=(), spec_frames=()) -> tuple[dict, dict]:
    data, meta = record_run(scenario, seed, frames, fe_frames, spec_frames)
    meta["unstable"] = unstable = unstable_frames(data, meta)
    moved = sorted(set(spec_frames) & set(unstable["pairing"] + unstable["angle"]))
    assert not moved, f"detect frames {moved} hold decisions within {PERTURB_REL:g} of a threshold: pick others"
    with discrete_only():
        pert = replay(data, meta, np.random.default_rng(1))
    meta["replay_perturbed_errors"] = {s: sum(len(e) for e in v.values()) for s, v in pert.items()}
    meta["replay_perturbed_first"] = {s: next((e[0] for e in v.values() if e), None) for s, v in pert.items()}
    save(fixture_path(stem), data, meta)
    return data, meta


def check_all(stem: str) -> dict[str, list[str]]:
    data, meta = load(fixture_path(stem))
    st = meta["unstable"]
    errs = {"spectra": [e for v in check_spectra(data, meta).values() for e in v],
            "pairing": [e for k, v in check_pairing(data, meta).items() if k not in st["pairing"] for e in v],
            "angle": [e for k, v in check_angle(data, meta).items() if k not in st["angle"] for e in v]}
    errs.update({s: [e for v in r.values() for e in v] for s, r in replay(data, meta).items()})
    return errs


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=("record-all", "check-all"))
    a = p.parse_args(argv)
    bad = 0
    for stem, args in FIXTURES.items():
        if a.action == "record-all":
            data, meta = record(stem, **args)
            n = meta["unstable"]
            print(f"recorded {fixture_path(stem)} ({fixture_path(stem).stat().st_size // 1024} kB): "
                  f"{data['det_range_m'].size} detections, {data['trk_track_id'].size} track rows, "
                  f"{data['ev_kind'].size} events, frames left out (a decision within {PERTURB_REL:g} of its threshold) {n}, "
                  f"perturbed replay errors {meta['replay_perturbed_errors']}")
        else:
            for stage, errs in check_all(stem).items():
                bad += len(errs)
                print(f"{stem} {stage}: {'ok' if not errs else chr(10).join(errs[:5])}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
