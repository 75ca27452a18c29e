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
import socket
import struct
import tempfile
from dataclasses import dataclass, field, replace
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
    lane_sequences: dict[int, int] = field(default_factory=dict)  # lane -> last interval sequence
    lane_volume: dict[int, int] = field(default_factory=dict)
    lane_interval_count: dict[int, int] = field(default_factory=dict)  # lane -> intervals closed
    problems: list[str] = field(default_factory=list)
    frames: int = 0
    last_seq: int = -1
    id_reuses: int = 0
    interval_starts: dict[int, int] = field(default_factory=dict)
    probe: Any = None  # callable(monitor) run at every RSS sample (e.g. read the Modbus image back)
    _live: dict[int, int] = field(default_factory=dict)  # track id -> age_frames in the previous frame
    _gone: set[int] = field(default_factory=set)  # ids seen once and not in the previous frame

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
        live = {t.track_id: t.age_frames for t in result.tracks}
        for tid, age in live.items():
            if tid in self._gone:  # an id that ended before and now names a new track: recycled
                self.id_reuses += 1
                self._gone.discard(tid)
            elif tid in self._live and age < self._live[tid]:
                self.problems.append(f"frame {result.seq}: track id {tid} handed to a new track without a gap")
        self._gone.update(set(self._live) - set(live))
        self._live = live
        self.track_ids.update(ids)
        if ids:
            self.max_track_id = max(self.max_track_id, max(ids))
        self.max_concurrent_tracks = max(self.max_concurrent_tracks, len(ids))
        for st in result.lane_stats:
            last = self.lane_sequences.get(st.lane)
            if last is not None and st.sequence != (last + 1) % 65536:
                self.problems.append(f"lane {st.lane}: interval sequence {last} -> {st.sequence}")
            self.lane_sequences[st.lane] = st.sequence
            self.lane_interval_count[st.lane] = self.lane_interval_count.get(st.lane, 0) + 1
            self.lane_volume[st.lane] = self.lane_volume.get(st.lane, 0) + st.volume
            if st.volume < 0 or not (0.0 <= st.occupancy_pct <= 100.0 or np.isnan(st.occupancy_pct)):
                self.problems.append(f"lane {st.lane}: impossible statistics {st}")
            prev = self.interval_starts.get(st.lane)
            if prev is not None and abs(st.interval_start_ns - prev - st.interval_s * 1e9) > 1e6:
                self.problems.append(f"lane {st.lane}: interval starting at {st.interval_start_ns} ns does not follow "
                                     f"the previous one ({prev} ns + {st.interval_s} s)")
            self.interval_starts[st.lane] = st.interval_start_ns
            counted = sum(st.class_counts.values())
            if st.class_counts and counted != st.volume:
                self.problems.append(f"lane {st.lane}: class counts {st.class_counts} do not add up to "
                                     f"volume {st.volume}")
        step = max(1, self.total_frames // self.samples)
        if self.frames == 1 or self.frames % step == 0:
            self.rss.append((self.frames, rss_mb()))
            if self.probe is not None:
                self.probe(self)

    def close(self) -> None:
        self.rss.append((self.frames, rss_mb()))
        if self.probe is not None:
            self.probe(self)


MODBUS_STATUS_BASE = 16  # edge.outputs.registers.STATUS
_MBAP = struct.Struct(">HHHBB")


def modbus_read_registers(address: tuple[str, int], start: int, count: int, *, unit: int = 1, fc: int = 3,
                          timeout_s: float = 2.0) -> list[int]:
    """Read ``count`` holding (``fc=3``) or input (``fc=4``) registers over Modbus TCP with a plain socket
    (no client library: also the basis of the abuse tests). Raises ``OSError`` on a connection problem
    and ``ValueError`` on an exception response or a malformed reply."""
    with socket.create_connection(address, timeout=timeout_s) as sock:
        sock.sendall(_MBAP.pack(1, 0, 6, unit, fc) + struct.pack(">HH", start, count))
        head = _recv_exact(sock, 7)
        tid, proto, length, _unit = struct.unpack(">HHHB", head)
        body = _recv_exact(sock, length - 1)
    if tid != 1 or proto != 0 or not body:
        raise ValueError(f"malformed Modbus reply {head!r} {body!r}")
    if body[0] & 0x80:
        raise ValueError(f"Modbus exception {body[1] if len(body) > 1 else '?'} for function {body[0] & 0x7F}")
    n = body[1] // 2
    return list(struct.unpack(f">{n}H", body[2:2 + 2 * n]))


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("connection closed by the Modbus server")
        buf += chunk
    return buf


def _proc_rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/statm", encoding="ascii") as fh:
            return int(fh.read().split()[1]) * _PAGE / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


class ModbusProbe:
    """Reads the served register image back over Modbus TCP at every RSS sample of a soak and checks it
    against what the pipeline published: the status frame counter is the last frame's sequence number
    mod 65536 (and is seen to wrap), the status interval sequence its last lane interval's mod 256,
    and each lane's cumulative volume the sum of its interval volumes. Also samples the RSS of the
    Modbus server process."""

    def __init__(self, sink: Any, n_lanes: int) -> None:
        self.sink = sink
        self.n_lanes = n_lanes
        self.reads = 0
        self.counter_wraps = 0
        self.last_counter: int | None = None
        self.server_rss: list[tuple[int, float]] = []
        self._dropped = 0

    def __call__(self, mon: SoakMonitor) -> None:
        sink = self.sink
        if getattr(sink, "_conn", None) is None or not sink.tcp_address:
            return  # closed (end of run) or TCP off
        if not sink.sync(5.0):
            mon.problems.append(f"frame {mon.last_seq}: the Modbus server process did not take the images in 5 s")
            return
        proc = getattr(sink, "_proc", None)
        if proc is not None and proc.pid:
            self.server_rss.append((mon.frames, _proc_rss_mb(proc.pid)))
        host, port = sink.tcp_address[:2]
        try:
            st = modbus_read_registers((host if host != "0.0.0.0" else "127.0.0.1", port), MODBUS_STATUS_BASE, 32)
            lanes = [modbus_read_registers((host if host != "0.0.0.0" else "127.0.0.1", port), 100 + 32 * k + 11, 2)
                     for k in range(self.n_lanes)]
        except (OSError, ValueError) as exc:
            mon.problems.append(f"frame {mon.last_seq}: reading the Modbus image failed: {exc}")
            return
        self.reads += 1
        dropped = sink.counters.get("images_dropped", 0)
        fc = st[4]
        if fc != mon.last_seq & 0xFFFF and dropped == self._dropped:
            mon.problems.append(f"Modbus frame counter {fc} != last frame {mon.last_seq} mod 65536")
        self._dropped = dropped
        if self.last_counter is not None and fc < self.last_counter:
            self.counter_wraps += 1
        self.last_counter = fc
        if mon.lane_sequences:
            last = next(iter(mon.lane_sequences.values()))  # every lane closes its interval together
            if st[9] != last & 0xFF:
                mon.problems.append(f"Modbus interval sequence {st[9]} != last interval {last} mod 256")
        for k, (hi, lo) in enumerate(lanes):
            cum = (hi << 16) | lo
            if cum != mon.lane_volume.get(k, 0) & 0xFFFFFFFF:
                mon.problems.append(f"lane {k}: Modbus cumulative volume {cum} != sum of interval volumes "
                                    f"{mon.lane_volume.get(k, 0)}")


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
    seq_start: int = 0,
) -> dict:
    """Run the soak (module docstring). ``seq_start``: the board's frame counter at the first frame
    (e.g. ``65536 - 100`` to see the 16-bit output counters wrap in a short run)."""
    from edge.bench import DEFAULT_SCENARIO, board_of, synth_frames
    from edge.commands.run import build_sinks
    from edge.loop import FrameLoop
    from edge.outputs.modbus import ModbusSink
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
            w.add(replace(f, seq=f.seq + seq_start) if seq_start else f)
        path = w.save(Path(d) / "soak.npz")
        del rec, w
        src = open_radar(f"replay://{path}?speed=0&loop=1")
        pipe = build_pipeline(profile, src.frontend, config)
        n_lanes = pipe.n_lanes
        mon = SoakMonitor(frames)
        sinks: list = build_sinks(config, n_lanes, getattr(pipe, "traffic", None)) if outputs else []
        modbus = next((s for s in sinks if isinstance(s, ModbusSink)), None)
        probe = ModbusProbe(modbus, n_lanes) if modbus is not None and modbus.tcp_address else None
        mon.probe = probe
        sinks.append(mon)  # last: when it probes, the outputs already have the frame
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
        sink_errors = loop.counters.sink_errors
    rss = np.array(mon.rss)
    at10 = rss[np.searchsorted(rss[:, 0], 0.1 * mon.frames), 1] if rss.size else 0.0
    end = rss[-1, 1] if rss.size else 0.0
    ids = sorted(mon.track_ids)
    out = {
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
        "tracks": {"distinct_ids": len(ids), "max_id": mon.max_track_id, "max_concurrent": mon.max_concurrent_tracks,
                   "id_reuses": mon.id_reuses},
        "n_lanes": n_lanes,
        "lane_intervals": {str(k): v for k, v in mon.lane_interval_count.items()},
        "lane_volume": {str(k): v for k, v in mon.lane_volume.items()},
        "errors": summary.errors,
        "sink_errors": sink_errors,
        "dropped_frames": summary.dropped_frames + summary.source_dropped_frames,
        "overruns": summary.overruns,
        "problems": mon.problems[:50],
        "n_problems": len(mon.problems),
        "frame_ms": summary.stages.get("frame", {}),
        "stop_reason": summary.stop_reason,
        "seq_start": seq_start,
        "modbus": None,
    }
    if probe is not None:
        srv = np.array(probe.server_rss) if probe.server_rss else np.zeros((0, 2))
        s10 = srv[min(np.searchsorted(srv[:, 0], 0.1 * mon.frames), len(srv) - 1), 1] if srv.size else 0.0
        out["modbus"] = {"reads": probe.reads, "frame_counter_wraps": probe.counter_wraps,
                         "images_sent": modbus.counters.get("images_sent", 0),
                         "images_dropped": modbus.counters.get("images_dropped", 0),
                         "server_rss_mb": {"at_10pct": float(s10), "at_end": float(srv[-1, 1]) if srv.size else 0.0,
                                           "max": float(srv[:, 1].max()) if srv.size else 0.0}}
    return out
