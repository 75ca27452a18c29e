"""Pictures of a recording (``radar-edge plot``): what the radar saw and what the pipeline made of it.

The recording is replayed through its profile's pipeline (offline, every frame); the figures use
whatever the results carry and degrade gracefully when a field is absent:

* ``range-time``: range profile of every frame (a waterfall, dB), detections, track ids over time,
  and the simulated ground truth when the recording has it -- works for every board and profile;
* ``frame-map``: one frame -- a range-Doppler map (single-segment boards: the Distance2Go, Tavanti
  Fig. 9) with detections coloured by cluster and track ids, or a range-azimuth map in road
  coordinates for an array board (the 1x4 SIMO, Lim Fig. 12). A map the pipeline returned in
  ``FrameResult.intermediates`` is used as is; otherwise the map is computed here;
* ``road``: detections and track trajectories in road coordinates with the lanes (Lim Figs. 12-14);
* ``lanes``: lane statistics over time (volume, mean speed, occupancy), or, when the profile does not
  produce them, detections/tracks/presence per frame.

matplotlib comes from the ``plot`` extra and is imported only here.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.fft
import scipy.signal

from edge.types import FrameResult
from hal.recording import Recording
from hal.waveform import SPEED_OF_LIGHT_MPS

log = logging.getLogger(__name__)

_DPI = 110
_TRACK_CMAP = "tab10"


class PlotError(RuntimeError):
    """The figures cannot be made (matplotlib missing, empty recording)."""


def require_matplotlib():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise PlotError("radar-edge plot needs matplotlib: pip install 'radar-edge[plot]' "
                        f"(or pip install matplotlib) -- {exc}") from exc
    return plt


@dataclass
class Lane:
    center_x_m: float
    width_m: float = 3.5
    direction: str = "toward"


@dataclass
class Replayed:
    """A recording and the pipeline's result for each of its frames."""

    path: Path
    recording: Recording
    profile: str
    results: list[FrameResult]
    lanes: list[Lane] = field(default_factory=list)

    @property
    def t_s(self) -> np.ndarray:
        return frame_times_s(self.recording)


def frame_times_s(rec: Recording) -> np.ndarray:
    """Frame times from the first frame: simulation time, else receive times, else the frame counter
    times the period (a recording made faster than real time has meaningless host times)."""
    period = rec.frontend.waveform.frame_period_s
    truth_t = getattr(rec, "_truth", {}).get("t_s")
    if truth_t is not None and len(truth_t) == len(rec):
        return np.asarray(truth_t, dtype=np.float64) - float(truth_t[0])
    t = rec.t_ns.astype(np.float64)
    if t.size > 1 and (t[-1] - t[0]) / 1e9 >= 0.5 * (t.size - 1) * period:
        return (t - t[0]) / 1e9
    seq = rec.seq.astype(np.float64)
    return (seq - seq[0]) * period


def replay(path: str | Path, config: Any, profile: str | None = None, max_frames: int | None = None) -> Replayed:
    """Run the recording through its pipeline (every frame, no deadlines)."""
    from edge.pipeline import StageTimer, build_pipeline, resolve_profile

    rec = Recording(path)
    if len(rec) == 0:
        raise PlotError(f"{path}: the recording has no frames")
    fe = rec.frontend
    prof = resolve_profile(profile or config["loop"].profile, fe.board)
    pipe = build_pipeline(prof, fe, config)
    timer = StageTimer(64)
    results = []
    n = len(rec) if max_frames is None else min(max_frames, len(rec))
    from hal.frame import RawFrame

    # the trackers integrate over frame times: give them the recording's time line, not the host's
    t0_ns = int(rec.t_ns[0]) if int(rec.t_ns[0]) > 0 else 1_000_000_000
    t_ns = t0_ns + np.round(frame_times_s(rec) * 1e9).astype(np.int64)
    try:
        for k in range(n):
            frame = RawFrame(seq=int(rec.seq[k]), t_ns=int(t_ns[k]), i=rec.i[k], q=rec.q[k], frontend=fe,
                             truth=rec.truth(k))
            results.append(pipe.process(frame, timer))
    finally:
        pipe.close()
    return Replayed(Path(path), rec, prof, results, _lanes(rec, pipe))


def _lanes(rec: Recording, pipe: Any) -> list[Lane]:
    """Lanes from the pipeline (``lanes`` with ``center_x_m``) or from the recording's scenario."""
    for obj in (pipe, getattr(pipe, "traffic", None), getattr(pipe, "lane_model", None)):
        lanes = getattr(obj, "lanes", None) if obj is not None else None
        if lanes:
            try:
                return [Lane(float(getattr(ln, "center_x_m")), float(getattr(ln, "width_m", 3.5)),
                             str(getattr(ln, "direction", "toward"))) for ln in lanes]
            except (AttributeError, TypeError, ValueError):
                break
    name = rec.meta.get("scenario")
    if name:
        try:
            from hw_sim.scenario import load_scenario

            sc = load_scenario(name)
            return [Lane(ln.center_x_m, ln.width_m, ln.direction) for ln in sc.lanes]
        except Exception as exc:  # noqa: BLE001 - lanes are decoration; any scenario problem just drops them
            log.debug("no lanes from scenario %s: %s", name, exc)
    return []


# --- maps computed here when the pipeline returns none --------------------------------------------
def _iq(rec: Recording, k: int) -> np.ndarray:
    return (rec.i[k].astype(np.float32) + 1j * rec.q[k].astype(np.float32)).astype(np.complex64)


def range_axis_m(rec: Recording, n_fft: int) -> np.ndarray:
    seg = rec.frontend.waveform.segments[0]
    return (np.arange(n_fft // 2) * seg.sample_rate_hz / n_fft * SPEED_OF_LIGHT_MPS / (2.0 * abs(seg.slope_hz_per_s))).astype(np.float32)


def range_profiles_db(rec: Recording, n_fft: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(frames, range bins) dB of the first chirp row's range spectrum, summed over channels; range axis."""
    fe = rec.frontend
    n = fe.waveform.n_samples
    n_fft = n_fft or max(256, int(2 ** np.ceil(np.log2(n))))
    w = scipy.signal.windows.hann(n, sym=False).astype(np.float32)
    iq = (rec.i[:, :, 0, :].astype(np.float32) + 1j * rec.q[:, :, 0, :].astype(np.float32)).astype(np.complex64)
    iq -= iq.mean(axis=-1, keepdims=True)
    spec = scipy.fft.fft(iq * w, n=n_fft, axis=-1, workers=1)
    slope = fe.waveform.segments[0].slope_hz_per_s
    half = spec[..., : n_fft // 2] if slope > 0 else spec[..., ::-1][..., : n_fft // 2]
    p = (np.abs(half) ** 2).sum(axis=1)
    return (10 * np.log10(p + 1e-3)).astype(np.float32), range_axis_m(rec, n_fft)


def range_doppler_db(rec: Recording, k: int, n_range: int = 256, n_doppler: int = 128):
    """Range-Doppler map of frame ``k`` (first channel, mean over chirps removed): dB, range m, speed m/s."""
    seg = rec.frontend.waveform.segments[0]
    x = _iq(rec, k)[0]  # (chirps, samples)
    x = x - x.mean(axis=0, keepdims=True)  # static clutter out (two-pulse-like canceller)
    n_c, n_s = x.shape
    w = (scipy.signal.windows.hann(n_c, sym=False)[:, None] * scipy.signal.windows.hann(n_s, sym=False)[None, :]).astype(np.float32)
    r = scipy.fft.fft(x * w, n=n_range, axis=1, workers=1)[:, : n_range // 2]
    rd = scipy.fft.fftshift(scipy.fft.fft(r, n=n_doppler, axis=0, workers=1), axes=0)
    lam = SPEED_OF_LIGHT_MPS / (seg.f_start_hz + seg.bandwidth_hz / 2)
    # slow-time frequency f -> radial speed -lambda f / 2 (positive receding)
    v = -(np.arange(n_doppler) - n_doppler // 2) / (n_doppler * seg.pri_s) * lam / 2
    db = 20 * np.log10(np.abs(rd).T + 1e-3)
    return db.astype(np.float32), range_axis_m(rec, n_range), v.astype(np.float32)


def range_azimuth(rec: Recording, k: int, n_range: int = 2048, n_az: int = 64):
    """Range-azimuth power (dB) of frame ``k`` for an array board: rows range, columns azimuth (rad)."""
    fe = rec.frontend
    x = _iq(rec, k)[:, 0, :]  # (rx, samples), first chirp
    x = x - x.mean(axis=-1, keepdims=True)
    w = scipy.signal.windows.hann(x.shape[-1], sym=False).astype(np.float32)
    r = scipy.fft.fft(x * w, n=n_range, axis=-1, workers=1)[:, : n_range // 2]
    a = scipy.fft.fftshift(scipy.fft.fft(r, n=n_az, axis=0, workers=1), axes=0)  # spatial frequency
    lam = fe.waveform.wavelength_m
    u = (np.arange(n_az) - n_az // 2) / n_az * lam / max(fe.rx_spacing_m, 1e-6)  # sin(az)
    ok = np.abs(u) < 1
    return (20 * np.log10(np.abs(a[ok]).T + 1e-3)).astype(np.float32), range_axis_m(rec, n_range), np.arcsin(u[ok])


def _intermediate_map(res: FrameResult):
    """A 2-D map the pipeline returned: (array, range axis or None, speed axis or None, name)."""
    im = res.intermediates or {}
    for key, val in im.items():
        arr = getattr(val, "amplitude", None)
        if arr is None and re.search(r"(^|_)(rd|range_doppler|map)(_|$)", key):
            arr = val  # a plain array named as a map
        if isinstance(arr, np.ndarray) and arr.ndim == 2 and min(arr.shape) >= 8:
            rng = im.get("range_m")
            spd = im.get("radial_speed_mps")
            if spd is None and im.get("radial_speed_kmh") is not None:
                spd = np.asarray(im["radial_speed_kmh"]) / 3.6
            return arr, rng, spd, key
    return None


def _default_rd_axes(fe, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray | None]:
    """Axes of a map laid out as in :mod:`edge.dsp.range_doppler`: rows = positive range half of an
    ``2 * rows``-point FFT, columns = fftshifted Doppler bins (m, m/s)."""
    seg = fe.waveform.segments[0]
    rows, cols = shape
    rng = np.arange(rows) * seg.sample_rate_hz / (2 * rows) * SPEED_OF_LIGHT_MPS / (2.0 * abs(seg.slope_hz_per_s))
    if len(fe.waveform.segments) != 1 or seg.pri_s <= 0:
        return rng.astype(np.float32), None  # no uniform chirp train: Doppler bins only
    lam = fe.waveform.wavelength_m
    spd = (np.arange(cols) - cols // 2) * lam / (2.0 * cols * seg.pri_s)
    return rng.astype(np.float32), spd.astype(np.float32)


def _track_colors(ids):
    import matplotlib

    cmap = matplotlib.colormaps[_TRACK_CMAP]
    return {tid: cmap(k % 10) for k, tid in enumerate(sorted(ids))}


def _busiest_frame(rep: Replayed) -> int:
    score = [len(r.tracks) * 100 + len(r.detections) for r in rep.results]
    return int(np.argmax(score)) if score else 0


# --- figures ------------------------------------------------------------------------------------------
def plot_range_time(rep: Replayed, out: Path) -> Path:
    plt = require_matplotlib()
    rec = rep.recording
    db, rng = range_profiles_db(rec)
    t = rep.t_s
    fig, ax = plt.subplots(figsize=(11, 6.5), constrained_layout=True)
    db = db - np.median(db, axis=1, keepdims=True)  # dB above each frame's noise floor
    vmax = max(20.0, float(np.percentile(db, 99.8)))
    im = ax.pcolormesh(t, rng, db.T, shading="nearest", cmap="viridis", vmin=0.0, vmax=vmax, rasterized=True)
    fig.colorbar(im, ax=ax, label="range spectrum, dB above the frame's median (noise floor)")
    # detections
    dt, dr = [], []
    for k, r in enumerate(rep.results):
        if len(r.detections):
            dr.append(r.detections.range_m)
            dt.append(np.full(len(r.detections), t[k]))
    if dr:
        ax.scatter(np.concatenate(dt), np.concatenate(dr), s=4, c="white", alpha=0.35, linewidths=0,
                   label="detections")
    # truth
    if rec.has_truth:
        truth = {}
        for k in range(len(rec)):
            g = rec.truth(k)
            for tid, r in zip(g.id, g.range_m):
                truth.setdefault(int(tid), ([], []))
                truth[int(tid)][0].append(t[k])
                truth[int(tid)][1].append(r)
        for n, (tid, (tt, rr)) in enumerate(truth.items()):
            ax.plot(tt, rr, ls=":", lw=1.0, color="orange",
                    label="ground truth (true range; a moving target's beat is shifted by its Doppler)" if n == 0 else None)
    _plot_tracks_over_time(ax, rep, t, lambda s: s.range_m, y_max=float(rng[-1]))
    ax.set_xlabel("time (s)")
    ax.set_ylabel("range (m)")
    ax.set_ylim(0, float(rng[-1]))
    ax.set_title(f"{rep.path.name}: range over time ({rep.profile} profile, {len(rec)} frames, "
                 f"{rec.frontend.board})")
    ax.legend(loc="best", fontsize=8, framealpha=0.7)
    return _save(fig, out)


def _plot_tracks_over_time(ax, rep: Replayed, t: np.ndarray, value, y_max: float = np.inf) -> None:
    tracks: dict[int, tuple[list, list]] = {}
    for k, r in enumerate(rep.results):
        for s in r.tracks:
            if s.confirmed:
                tracks.setdefault(s.track_id, ([], []))
                tracks[s.track_id][0].append(t[k])
                tracks[s.track_id][1].append(value(s))
    colors = _track_colors(tracks)
    for n, (tid, (tt, vv)) in enumerate(tracks.items()):
        ax.plot(tt, vv, lw=2, color=colors[tid], label="tracks" if n == 0 else None)
        inside = [j for j, v in enumerate(vv) if 0 <= v <= y_max]
        if inside:  # label the last point still inside the axes
            j = inside[-1]
            ax.annotate(f"#{tid}", (tt[j], vv[j]), xytext=(3, 3), textcoords="offset points", color=colors[tid],
                        fontsize=9, fontweight="bold", path_effects=[_outline()])


def plot_frame_map(rep: Replayed, out: Path, k: int | None = None) -> Path:
    plt = require_matplotlib()
    rec = rep.recording
    k = _busiest_frame(rep) if k is None else min(max(k, 0), len(rec) - 1)
    res = rep.results[k]
    fe = rec.frontend
    fig, ax = plt.subplots(figsize=(10, 7), constrained_layout=True)
    given = _intermediate_map(res)
    single = len(fe.waveform.segments) == 1 and fe.waveform.n_chirps >= 3
    speed_label = "radial speed (km/h, + receding)"
    det = res.detections
    if given is not None or single:
        if given is not None:
            arr, rng, spd, name = given
            db = 20 * np.log10(np.abs(arr) + 1e-6) if np.isrealobj(arr) and arr.min() >= 0 else np.asarray(arr)
            d_rng, d_spd = _default_rd_axes(fe, arr.shape)
            rng = np.asarray(rng) if rng is not None and len(rng) == arr.shape[0] else d_rng
            spd = np.asarray(spd) if spd is not None and len(spd) == arr.shape[1] else d_spd
            if spd is None:
                spd = (np.arange(arr.shape[1]) - arr.shape[1] // 2) / 3.6  # plotted x 3.6: Doppler bins
                speed_label = "Doppler bin"
            src = f"pipeline map '{name}'"
        else:
            db, rng, spd = range_doppler_db(rec, k)
            src = "range-Doppler map (computed for the plot)"
        db = db - float(np.median(db))
        clusters = _cluster_points(res, len(rng), len(spd)) if given is not None else None
        im = ax.pcolormesh(spd * 3.6, rng, db, shading="nearest", cmap="bone" if clusters is not None else "jet",
                           vmin=0.0, vmax=max(20.0, float(np.max(db))), rasterized=True)
        fig.colorbar(im, ax=ax, label="dB above the map's median")
        overlay = speed_label != "Doppler bin"  # detections/tracks are in km/h: not on a bin axis
        if clusters is not None:
            import matplotlib

            rb, dbin, lab = clusters
            noise = lab < 0
            cmap = matplotlib.colormaps["tab10"]
            if noise.any():
                ax.scatter(spd[dbin[noise]] * 3.6, rng[rb[noise]], s=2, c="0.75", alpha=0.5, linewidths=0,
                           label="thresholded cells, no cluster")
            for n, c in enumerate(np.unique(lab[~noise])):
                sel = lab == c
                ax.scatter(spd[dbin[sel]] * 3.6, rng[rb[sel]], s=3, color=cmap(n % 10), alpha=0.55, linewidths=0,
                           label="cluster cells (colour = cluster)" if n == 0 else None)
                cx, cy = float(np.median(spd[dbin[sel]] * 3.6)), float(np.median(rng[rb[sel]]))
                ax.annotate(f"C{c}", (cx, cy), xytext=(-16, -14), textcoords="offset points", fontsize=10,
                            color=cmap(n % 10), fontweight="bold", path_effects=[_outline()])
        if overlay and clusters is None and len(det) and np.isfinite(det.radial_speed_mps).any():
            lab = _cluster_labels(det)
            ax.scatter(det.radial_speed_mps * 3.6, det.range_m, c=lab, cmap="tab20", s=22, edgecolors="white",
                       linewidths=0.6, label="detections (colour = cluster)")
        for s in res.tracks if overlay else ():
            ax.scatter([s.radial_speed_mps * 3.6], [s.range_m], marker="s", s=90, facecolors="none",
                       edgecolors="yellow", linewidths=1.6, label="tracks" if s is res.tracks[0] else None)
            ax.annotate(f"#{s.track_id}" + (f" {s.cls}" if s.cls else ""), (s.radial_speed_mps * 3.6, s.range_m),
                        xytext=(7, 5), textcoords="offset points", color="yellow", fontsize=10, fontweight="bold")
        ax.set_xlabel(speed_label)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
        ax.set_ylabel("range (m)")
        ax.set_title(f"{rep.path.name} frame {k} (seq {res.seq}): {src}, {len(det)} detections, "
                     f"{len(res.tracks)} tracks")
    else:
        db, rng, az = range_azimuth(rec, k)
        az_deg = np.degrees(az)
        db = db - float(np.median(db))
        im = ax.pcolormesh(az_deg, rng, db, shading="nearest", cmap="jet", vmin=0.0,
                           vmax=max(20.0, float(np.max(db[rng > 5.0]))), rasterized=True)  # not the TX leakage
        fig.colorbar(im, ax=ax, label="dB above the map's median (noise floor)")
        # lane edges are curves az = asin(x / r) in this view
        r = np.linspace(max(float(rng[1]), 1.0), float(rng[-1]), 400)
        for n, ln in enumerate(rep.lanes):
            for edge in (ln.center_x_m - ln.width_m / 2, ln.center_x_m + ln.width_m / 2):
                ok_r = r > abs(edge)
                ax.plot(np.degrees(np.arcsin(edge / r[ok_r])), r[ok_r], color="white", lw=0.6, ls="--", alpha=0.6)
        ok = np.isfinite(det.az_rad)
        if ok.any():
            ax.scatter(np.degrees(det.az_rad[ok]), det.range_m[ok], s=18, c="white", edgecolors="black",
                       linewidths=0.5, label="detections")
        for s in res.tracks:
            ax.scatter([np.degrees(s.az_rad)], [s.range_m], marker="s", s=80, facecolors="none", edgecolors="white",
                       linewidths=1.5)
            ax.annotate(f"#{s.track_id}", (np.degrees(s.az_rad), s.range_m), xytext=(6, 4), textcoords="offset points",
                        color="white", fontsize=10, fontweight="bold")
        if rec.has_truth:
            g = rec.truth(k)
            ax.scatter(np.degrees(g.az_rad), g.range_m, marker="x", c="white", s=45, linewidths=1.5,
                       label="ground truth")
        half = fe.fov_deg / 2 if fe.fov_deg else 60.0
        ax.set_xlim(-half, half)
        ax.set_ylim(0, float(rng[-1]))
        ax.set_xlabel("azimuth (deg, right +)")
        ax.set_ylabel("range (m)")
        ax.set_title(f"{rep.path.name} frame {k} (seq {res.seq}): range-azimuth map of the {fe.n_rx} channels "
                     f"(computed for the plot; dashed: lane edges), {len(det)} detections", fontsize=10)
        if ok.any() or rec.has_truth:
            ax.legend(loc="upper right", fontsize=8, facecolor="0.3", labelcolor="white")
    return _save(fig, out)


def _outline():
    from matplotlib import patheffects

    return patheffects.withStroke(linewidth=2.5, foreground="black")


def _cluster_points(res: FrameResult, n_range: int, n_doppler: int):
    """Thresholded map cells and their cluster labels (``range_bin``, ``doppler_bin``, ``labels``), if given."""
    im = res.intermediates or {}
    try:
        rb = np.asarray(im["range_bin"], dtype=np.intp)
        dbin = np.asarray(im["doppler_bin"], dtype=np.intp)
        lab = np.asarray(im["labels"], dtype=np.intp)
    except (KeyError, TypeError, ValueError):
        return None
    if not (rb.shape == dbin.shape == lab.shape) or rb.ndim != 1 or rb.size == 0:
        return None
    if rb.min() < 0 or rb.max() >= n_range or dbin.min() < 0 or dbin.max() >= n_doppler:
        return None
    return rb, dbin, lab


def _cluster_labels(det) -> np.ndarray:
    for key in ("cluster", "cluster_id", "label", "labels"):
        if key in det.extra and len(det.extra[key]) == len(det):
            return np.asarray(det.extra[key], dtype=np.float64)
    return np.zeros(len(det))


def _draw_lanes(ax, lanes: list[Lane], y_max: float) -> None:
    for n, ln in enumerate(lanes):
        lo, hi = ln.center_x_m - ln.width_m / 2, ln.center_x_m + ln.width_m / 2
        ax.axvspan(lo, hi, color="0.5", alpha=0.10 if n % 2 else 0.16, lw=0)
        for edge in (lo, hi):
            ax.axvline(edge, color="0.6", lw=0.8, ls="--")
        arrow = "↓" if ln.direction == "toward" else "↑"
        ax.text(ln.center_x_m, y_max * 0.98, f"lane {n} {arrow}", ha="center", va="top", fontsize=8, color="0.25")


MIN_LABEL_FRAMES = 10


def _track_segments(rep: Replayed) -> dict[tuple[int, int], list]:
    """Confirmed track states by (id, segment): an id that reappears after a gap (recycled) starts a new segment."""
    segs: dict[tuple[int, int], list] = {}
    last: dict[int, tuple[int, int]] = {}  # id -> (frame index, segment number)
    for k, r in enumerate(rep.results):
        for s in r.tracks:
            if not s.confirmed:
                continue
            prev = last.get(s.track_id)
            seg = prev[1] if prev is not None and k - prev[0] <= 1 else (prev[1] + 1 if prev else 0)
            last[s.track_id] = (k, seg)
            segs.setdefault((s.track_id, seg), []).append((k, s.x_m, s.y_m, s.cls))
    return segs


def plot_road(rep: Replayed, out: Path) -> Path:
    plt = require_matplotlib()
    rec = rep.recording
    fig, ax = plt.subplots(figsize=(8, 10), constrained_layout=True)
    xs, ys = [], []
    for r in rep.results:
        d = r.detections
        ok = np.isfinite(d.az_rad)
        if ok.any():
            xs.append(d.x_m[ok])
            ys.append(d.y_m[ok])
    y_max = 10.0
    if xs:
        x, y = np.concatenate(xs), np.concatenate(ys)
        ax.scatter(x, y, s=3, c="0.55", alpha=0.5, linewidths=0, label="detections (all frames)")
        y_max = max(y_max, float(np.percentile(y, 99.5)) * 1.05)
    if rec.has_truth:
        paths: dict[int, list] = {}
        cls: dict[int, str] = {}
        for k in range(len(rec)):
            g = rec.truth(k)
            for tid, p, c in zip(g.id, g.position_m, g.cls):
                paths.setdefault(int(tid), []).append(p[:2])
                cls[int(tid)] = c
        for n, (tid, pts) in enumerate(paths.items()):
            p = np.array(pts)
            ax.plot(p[:, 0], p[:, 1], ls=":", color="black", lw=1.4,
                    label="ground truth (o start, triangle end)" if n == 0 else None)
            ax.plot(p[:1, 0], p[:1, 1], "o", color="black", ms=4)
            ax.plot(p[-1:, 0], p[-1:, 1], marker="^" if p[-1, 1] > p[0, 1] else "v", color="black", ms=6)
            ax.annotate(f"T{tid} {cls[tid]}", tuple(p[0]), xytext=(4, -10), textcoords="offset points", fontsize=7,
                        color="black")
            y_max = max(y_max, float(p[:, 1].max()) * 1.05)
    segs = _track_segments(rep)
    colors = _track_colors({tid for tid, _ in segs})
    labelled = 0
    for n, ((tid, _), pts) in enumerate(segs.items()):
        p = np.array([(q[1], q[2]) for q in pts], dtype=float)
        long_enough = len(pts) >= MIN_LABEL_FRAMES
        ax.plot(p[:, 0], p[:, 1], color=colors[tid], lw=2 if long_enough else 1, alpha=1.0 if long_enough else 0.5,
                label="tracks" if n == 0 else None)
        if long_enough:
            labelled += 1
            ax.scatter(p[-1:, 0], p[-1:, 1], color=colors[tid], s=30)
            cls = pts[-1][3]
            ax.annotate(f"#{tid}" + (f" {cls}" if cls else ""), tuple(p[-1]), xytext=(4, 4),
                        textcoords="offset points", color=colors[tid], fontsize=9, fontweight="bold")
        y_max = max(y_max, float(p[:, 1].max()) * 1.05)
    tracks = segs
    _draw_lanes(ax, rep.lanes, y_max)
    half = max(10.0, max((abs(ln.center_x_m) + ln.width_m for ln in rep.lanes), default=10.0) * 1.4)
    ax.set_xlim(-half, half)
    ax.set_ylim(0, y_max)
    ax.set_xlabel("lateral x (m, right +)")
    ax.set_ylabel("along the road y (m, from the radar)")
    notes = []
    if not xs:
        notes.append(f"no azimuth in the {rep.profile} profile: no detection positions")
        if tracks:
            notes.append("tracks drawn on the boresight at their range")
    if not tracks:
        notes.append("no confirmed tracks")
    else:
        notes.append(f"{len(tracks)} confirmed track segments, ids shown for the {labelled} of "
                     f"at least {MIN_LABEL_FRAMES} frames")
    ax.set_title(f"{rep.path.name}: road coordinates, {len(rec)} frames" + "".join("\n" + n for n in notes),
                 fontsize=10)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="lower right", fontsize=8)
    return _save(fig, out)


def plot_lane_stats(rep: Replayed, out: Path) -> Path:
    plt = require_matplotlib()
    stats = [s for r in rep.results for s in r.lane_stats]
    t = rep.t_s
    if stats:
        fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True, constrained_layout=True)
        t0 = min(s.interval_start_ns for s in stats)
        lanes = sorted({s.lane for s in stats})
        width = min(s.interval_s for s in stats) / (len(lanes) + 1)
        for n, ln in enumerate(lanes):
            ss = sorted((s for s in stats if s.lane == ln), key=lambda s: s.interval_start_ns)
            mid = np.array([(s.interval_start_ns - t0) / 1e9 + s.interval_s / 2 for s in ss])
            x = mid + (n - (len(lanes) - 1) / 2) * width
            col = f"C{n % 10}"
            axes[0].bar(x, [s.volume for s in ss], width=width, color=col, label=f"lane {ln}")
            spd = np.array([s.mean_speed_kmh for s in ss], dtype=float)
            p85 = np.array([s.speed_p85_kmh for s in ss], dtype=float)
            axes[1].plot(mid, spd, marker="o", color=col, label=f"lane {ln} mean")
            axes[1].plot(mid, p85, marker="^", ls="none", color=col, alpha=0.6)
            axes[2].bar(x, [s.occupancy_pct for s in ss], width=width, color=col)
        axes[1].plot([], [], marker="^", ls="none", color="0.4", label="85th percentile")
        axes[1].legend(fontsize=8, ncol=len(lanes) + 1)
        from matplotlib.ticker import MaxNLocator

        axes[0].yaxis.set_major_locator(MaxNLocator(integer=True))
        axes[0].set_ylabel("volume (veh/interval)")
        axes[1].set_ylabel("speed (km/h)")
        axes[2].set_ylabel("occupancy (%)")
        axes[2].set_xlabel("time (s), each interval centred on its middle")
        axes[0].legend(ncol=len(lanes), fontsize=8)
        axes[0].set_title(f"{rep.path.name}: lane statistics per interval ({rep.profile} profile)")
    else:
        n_pres = max((len(r.presence) for r in rep.results), default=0)
        rows = 2 + (1 if n_pres else 0)
        fig, axes = plt.subplots(rows, 1, figsize=(10, 2.6 * rows + 1), sharex=True, constrained_layout=True)
        axes[0].plot(t, [len(r.detections) for r in rep.results], lw=1, color="tab:blue")
        axes[0].set_ylabel("detections")
        axes[1].plot(t, [sum(s.confirmed for s in r.tracks) for r in rep.results], lw=1.5, color="tab:green")
        axes[1].set_ylabel("confirmed tracks")
        from matplotlib.ticker import MaxNLocator

        axes[1].yaxis.set_major_locator(MaxNLocator(integer=True))
        axes[1].set_ylim(bottom=0, top=max(1, max((sum(s.confirmed for s in r.tracks) for r in rep.results), default=0)) + 0.5)
        if n_pres:
            pres = np.array([list(r.presence) + [False] * (n_pres - len(r.presence)) for r in rep.results], dtype=float)
            axes[2].imshow(pres.T, aspect="auto", interpolation="nearest", cmap="Greens",
                           extent=(t[0], t[-1] if len(t) > 1 else 1.0, n_pres - 0.5, -0.5))
            axes[2].set_ylabel("presence by lane")
            axes[2].set_yticks(range(n_pres))
        axes[-1].set_xlabel("time (s)")
        axes[0].set_title(f"{rep.path.name}: per-frame activity ({rep.profile} profile: no lane statistics "
                          f"in {len(t) * rep.recording.frontend.waveform.frame_period_s:.0f} s)")
    return _save(fig, out)


def _save(fig, out: Path) -> Path:
    import matplotlib.pyplot as plt

    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=_DPI)
    plt.close(fig)
    return out


FIGURES = ("range-time", "frame-map", "road", "lanes")


def render(rep: Replayed, out_dir: str | Path, which: tuple[str, ...] = FIGURES, frame: int | None = None) -> list[Path]:
    require_matplotlib()
    out_dir = Path(out_dir)
    stem = rep.path.stem
    made = []
    for name in which:
        out = out_dir / f"{stem}-{name}.png"
        if name == "range-time":
            made.append(plot_range_time(rep, out))
        elif name == "frame-map":
            made.append(plot_frame_map(rep, out, frame))
        elif name == "road":
            made.append(plot_road(rep, out))
        elif name == "lanes":
            made.append(plot_lane_stats(rep, out))
        else:
            raise PlotError(f"unknown figure {name!r}; choose from {', '.join(FIGURES)}")
    return made
