"""Event recorder: segments with pre/post frames, the quota ring, a full disk never stops the loop."""

from __future__ import annotations

import errno
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from edge.config import LoopConfig, load_config
from edge.loop import FrameLoop
from edge.ops.recorder import EventRecorder, RecorderConfig
from edge.pipeline import Pipeline
from edge.types import Detections, FrameResult, LoopHealth, RawFrame, TrackState
from hal import open_radar
from hal.clock import FakeClock
from hal.recording import Recording
from hal.waveform import d2g_frontend

FE = d2g_frontend()
H = LoopHealth(t_ns=0, frames=0, dropped_frames=0, overruns=0, errors=0, source_ok=True, last_frame_ns=0,
               frame_p99_ms=0.0, budget_ms=200.0)


def _frame(seq: int, rng: np.random.Generator) -> RawFrame:
    i = rng.integers(-100, 100, FE.frame_shape, dtype=np.int16)
    q = rng.integers(-100, 100, FE.frame_shape, dtype=np.int16)
    return RawFrame(seq=seq, t_ns=seq * 200_000_000, i=i, q=q, frontend=FE)


def _track(tid: int) -> TrackState:
    return TrackState(tid, 0.0, 10.0, 0.0, -5.0, 10.0, -5.0, 0.0, 5, 5, confirmed=True)


def _feed(rec: EventRecorder, seqs, active, rng):
    frames = {}
    for s in seqs:
        f = _frame(s, rng)
        frames[s] = f
        rec.tap(f)
        tracks = (_track(3),) if s in active else ()
        rec.publish(FrameResult("surveillance", s, f.t_ns, Detections.empty(), tracks=tracks), H)
    return frames


def _cfg(tmp_path, **kw) -> RecorderConfig:
    return replace(RecorderConfig(enabled=True, directory=str(tmp_path / "rec"), min_free_mb=0.0), **kw)


def test_segment_holds_pre_trigger_frames_event_and_post_frames(tmp_path):
    rng = np.random.default_rng(1)
    rec = EventRecorder(_cfg(tmp_path, pre_frames=10, post_frames=15), meta={"site": "test"})
    frames = _feed(rec, range(100), set(range(30, 40)), rng)
    rec.close()
    files = rec.files()
    assert len(files) == 1
    r = Recording(files[0])
    # frames 20..29 before the trigger, 30..39 triggered, then 15 quiet frames 40..54
    assert r.seq.tolist() == list(range(20, 55))
    np.testing.assert_array_equal(r.i[5], frames[25].i)
    np.testing.assert_array_equal(r.q[-1], frames[54].q)
    assert r.meta["track_ids"] == [3] and r.meta["site"] == "test" and r.meta["trigger"] == ["tracks"]
    assert r.frontend == FE
    assert rec.stats.files_written == 1 and rec.stats.segments_lost == 0


def test_long_segment_is_split_and_open_segment_is_written_at_close(tmp_path):
    rng = np.random.default_rng(2)
    rec = EventRecorder(_cfg(tmp_path, pre_frames=0, post_frames=5, max_frames_per_file=20))
    _feed(rec, range(50), set(range(50)), rng)
    rec.close()
    seqs = [Recording(p).seq.tolist() for p in rec.files()]
    assert sorted(s[0] for s in seqs) == [0, 20, 40]
    assert sum(len(s) for s in seqs) == 50


def test_quota_keeps_the_newest_recordings(tmp_path):
    rng = np.random.default_rng(3)
    cfg = _cfg(tmp_path, pre_frames=0, post_frames=1, trigger="always", max_frames_per_file=10)
    probe = EventRecorder(replace(cfg, directory=str(tmp_path / "probe")))
    _feed(probe, range(10), set(), rng)
    probe.close()
    size = probe.files()[0].stat().st_size  # one 10-frame file
    quota_mb = 3.5 * size / 1e6
    rec = EventRecorder(replace(cfg, quota_mb=quota_mb, queue_files=16))
    for k in range(8):  # 8 files of 10 frames
        _feed(rec, range(k * 10, k * 10 + 10), set(), rng)
        rec.flush()
    rec.close()
    files = rec.files()
    assert len(files) == 3
    assert sum(p.stat().st_size for p in files) <= quota_mb * 1e6
    assert [Recording(p).seq[0] for p in files] == [50, 60, 70]  # oldest out first
    assert rec.stats.files_deleted == 5


def test_disk_full_stops_recording_not_the_caller_and_recovers(tmp_path):
    rng = np.random.default_rng(4)
    now = [0.0]
    full = [True]

    def save(writer, path: Path):
        if full[0]:
            part = path.with_name(path.name + ".part")
            part.write_bytes(b"half a file")
            raise OSError(errno.ENOSPC, "No space left on device")
        return writer.save(path)

    rec = EventRecorder(_cfg(tmp_path, pre_frames=0, post_frames=2, retry_s=60.0), clock_s=lambda: now[0],
                        writer=save)
    _feed(rec, range(0, 10), set(range(0, 5)), rng)  # segment 0..6 -> ENOSPC
    rec.flush()
    assert rec.state == "disk_full"
    assert rec.stats.segments_lost == 1 and rec.stats.disk_full_events == 1
    assert list((tmp_path / "rec").iterdir()) == []  # the partial file is gone
    full[0] = False
    now[0] = 30.0  # inside retry_s: segments are dropped without touching the disk
    _feed(rec, range(10, 20), set(range(10, 12)), rng)
    rec.flush()
    assert rec.stats.segments_lost == 2 and rec.files() == []
    now[0] = 61.0  # space is back and the retry time passed
    _feed(rec, range(20, 30), set(range(20, 22)), rng)
    rec.close()
    assert rec.state == "idle"
    assert [Recording(p).seq.tolist() for p in rec.files()] == [list(range(20, 24))]


def test_low_free_space_is_treated_as_full(tmp_path):
    class Usage:
        free = 10_000_000  # 10 MB

    rec = EventRecorder(_cfg(tmp_path, pre_frames=0, post_frames=1, min_free_mb=64.0), disk_usage=lambda p: Usage)
    _feed(rec, range(5), {0, 1}, np.random.default_rng(5))
    rec.close()
    assert rec.files() == [] and rec.state == "disk_full" and rec.stats.segments_lost >= 1


class _PassPipeline(Pipeline):
    profile = "surveillance"
    n_lanes = 0

    def __init__(self):
        super().__init__(FE, None)

    def process(self, frame, timer):
        tracks = (_track(7),) if 10 <= frame.seq < 15 else ()
        return FrameResult(self.profile, frame.seq, frame.t_ns, Detections.empty(), tracks=tracks)


def test_in_the_frame_loop_a_failing_disk_never_stops_it(tmp_path):
    """A recorder whose disk is always full: the loop still processes every frame."""
    clock = FakeClock()

    def save(writer, path):
        raise OSError(errno.ENOSPC, "No space left on device")

    rec = EventRecorder(_cfg(tmp_path, pre_frames=2, post_frames=3), writer=save)
    src = open_radar("sim://d2g?scenario=tavanti-test1&frames=30&realtime=0")
    pipe = rec.wrap(_PassPipeline())
    assert pipe.n_lanes == 0  # attributes of the wrapped pipeline stay visible
    loop = FrameLoop(src, pipe, LoopConfig(), sinks=[rec], clock=clock, pace="none")
    summary = loop.run()
    assert summary.frames == 30 and summary.errors == 0 and loop.counters.sink_errors == 0
    assert rec.stats.segments_lost == 1 and rec.state == "disk_full"


def test_recording_written_in_the_loop_replays(tmp_path):
    rec = EventRecorder(_cfg(tmp_path, pre_frames=2, post_frames=3))
    src = open_radar("sim://d2g?scenario=tavanti-test1&frames=30&realtime=0")
    loop = FrameLoop(src, rec.wrap(_PassPipeline()), LoopConfig(), sinks=[rec], clock=FakeClock(), pace="none")
    loop.run()
    (path,) = rec.files()
    with open_radar(f"replay://{path}?speed=0") as rp:
        seqs = [f.seq for f in rp]
    assert len(seqs) == 2 + 5 + 3


def test_recorder_section_is_registered():
    cfg = load_config(overrides={"ops.recorder.quota_mb": "64", "ops.recorder.enabled": "true"})
    assert cfg["ops.recorder"].quota_mb == 64.0 and cfg["ops.recorder"].enabled
    with pytest.raises(ValueError):
        load_config(overrides={"ops.recorder.trigger": "sometimes"})


def test_run_records_and_plot_reads_the_recording(tmp_path, capsys):
    """End to end: `radar-edge run` with the recorder on writes a recording that `radar-edge plot` draws."""
    pytest.importorskip("matplotlib")
    from edge.cli import main

    rec_dir = tmp_path / "recordings"
    rc = main(["run", "--source", "sim://d2g?scenario=tavanti-test1&frames=12&realtime=0", "--frames", "12",
               "--no-outputs", "--status-every", "0", "--set", "ops.recorder.enabled=true",
               "--set", f"ops.recorder.directory={rec_dir}", "--set", "ops.recorder.trigger=always",
               "--set", "ops.recorder.min_free_mb=0"])
    assert rc == 0
    (path,) = sorted(rec_dir.glob("*.npz"))
    r = Recording(path)
    assert len(r) == 12 and r.meta["source"].startswith("sim://d2g") and r.meta["trigger"] == ["always"]
    capsys.readouterr()
    assert main(["plot", str(path), "--out", str(tmp_path / "png"), "--figure", "range-time", "--profile", "minimal"]) == 0
    assert (tmp_path / "png" / f"{path.stem}-range-time.png").stat().st_size > 10_000
