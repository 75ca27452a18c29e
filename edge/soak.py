"""Soak run: hours of frames through the pipeline and the outputs in accelerated replay.

A seeded scenario is synthesised once (``record_frames`` frames) and replayed in a loop as fast as
the pipeline goes (frame counters keep counting across loops), through the whole frame loop with the
output sinks attached. Resident memory is sampled along the way. The report answers what a radar
engineer asks before leaving a box on a pole for years: does memory grow, do track ids recycle,
do counters wrap cleanly, do interval statistics stay consistent, did anything fail.
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from edge.types import FrameResult, LoopHealth

log = logging.getLogger(__name__)

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_mb() -> float:
    """Current resident set size of this process in MB (Linux /proc; 0 where unavailable)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as fh:
            return int(fh.read().split()[1]) * _PAGE / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


@dataclass
class SoakMonitor:
    """A sink that samples memory and checks the consistency of what the pipeline publishes."""

    total_frames: int
    samples: int = 100
    rss: list[tuple[int, float]] = field(default_factory=list)
    track_ids: set[int] = field(default_factory=set)
    max_track_id: int = 0
    max_concurrent_tracks: int = 0
    lane_sequences: dict[int, list[int]] = field(default_factory=dict)
    lane_volume: dict[int, int] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    frames: int = 0
    last_seq: int = -1

    def publish(self, result: FrameResult | None, health: LoopHealth) -> None:
        if result is None:
            return
        self.frames += 1
        if result.seq <= self.last_seq:
            self.problems.append(f"sequence went backwards: {self.last_seq} -> {result.seq}")
        self.last_seq = result.seq
        ids = [t.track_id for t in result.tracks]
        if len(set(ids)) != len(ids):
            self.problems.append(f"frame {result.seq}: duplicate track ids {sorted(ids)}")
        self.track_ids.update(ids)
        if ids:
            self.max_track_id = max(self.max_track_id, max(ids))
        self.max_concurrent_tracks = max(self.max_concurrent_tracks, len(ids))
        for st in result.lane_stats:
            seqs = self.lane_sequences.setdefault(st.lane, [])
            if seqs and st.sequence != (seqs[-1] + 1) % 65536:
                self.problems.append(f"lane {st.lane}: interval sequence {seqs[-1]} -> {st.sequence}")
            seqs.append(st.sequence)
            self.lane_volume[st.lane] = self.lane_volume.get(st.lane, 0) + st.volume
            if st.volume < 0 or not (0.0 <= st.occupancy_pct <= 100.0 or np.isnan(st.occupancy_pct)):
                self.problems.append(f"lane {st.lane}: impossible statistics {st}")
        step = max(1, self.total_frames // self.samples)
        if self.frames == 1 or self.frames % step == 0:
            self.rss.append((self.frames, rss_mb()))

    def close(self) -> None:
        self.rss.append((self.frames, rss_mb()))


def run_soak(
    profile: str,
    config: Any,
    *,
    frames: int = 200_000,
    record_frames: int = 2000,
    scenario: str | None = None,
    seed: int = 1,
    outputs: bool = True,
    progress: bool = False,
) -> dict:
    from edge.bench import DEFAULT_SCENARIO, board_of, synth_frames
    from edge.commands.run import build_sinks
    from edge.loop import FrameLoop
    from edge.pipeline import build_pipeline
    from hal import open_radar
    from hal.recording import RecordingWriter

    board = board_of(profile)
    scenario = scenario or DEFAULT_SCENARIO[board]
    n_rec = min(record_frames, frames)
    with tempfile.TemporaryDirectory() as d:
        rec = synth_frames(board, scenario, seed, n_rec, progress)
        w = RecordingWriter(rec[0].frontend, meta={"scenario": scenario, "seed": seed})
        for f in rec:
            w.add(f)
        path = w.save(Path(d) / "soak.npz")
        del rec, w
        src = open_radar(f"replay://{path}?speed=0&loop=1")
        pipe = build_pipeline(profile, src.frontend, config)
        mon = SoakMonitor(frames)
        sinks: list = [mon]
        if outputs:
            sinks += build_sinks(config, int(getattr(pipe, "n_lanes", 0)))
        bar = None
        if progress:
            try:
                from tqdm import tqdm

                bar = tqdm(total=frames, unit="frame", desc="soak", smoothing=0.05)
            except ImportError:
                bar = None
        loop = FrameLoop(src, pipe, config.section("loop"), sinks=sinks, pace="none",
                         on_result=(lambda r: bar.update(1)) if bar is not None else None)
        summary = loop.run(max_frames=frames)
        if bar is not None:
            bar.close()
    rss = np.array(mon.rss)
    at10 = rss[np.searchsorted(rss[:, 0], 0.1 * mon.frames), 1] if rss.size else 0.0
    end = rss[-1, 1] if rss.size else 0.0
    ids = sorted(mon.track_ids)
    return {
        "profile": profile,
        "scenario": scenario,
        "seed": seed,
        "frames": summary.frames,
        "recorded_frames": n_rec,
        "simulated_hours": summary.frames * src.frontend.waveform.frame_period_s / 3600.0,
        "wall_s": summary.duration_s,
        "frames_per_s": summary.frames / max(summary.duration_s, 1e-9),
        "rss_mb": {"at_10pct": float(at10), "at_end": float(end), "growth_10_to_100pct": float(end - at10),
                   "max": float(rss[:, 1].max()) if rss.size else 0.0, "samples": rss.tolist()},
        "tracks": {"distinct_ids": len(ids), "max_id": mon.max_track_id, "max_concurrent": mon.max_concurrent_tracks},
        "lane_intervals": {str(k): len(v) for k, v in mon.lane_sequences.items()},
        "lane_volume": {str(k): v for k, v in mon.lane_volume.items()},
        "errors": summary.errors,
        "overruns": summary.overruns,
        "problems": mon.problems[:50],
        "n_problems": len(mon.problems),
        "frame_ms": summary.stages.get("frame", {}),
        "stop_reason": summary.stop_reason,
    }
