"""On-device event recording: a bounded ring of recordings on disk, as a frame-loop sink.

While nothing happens, the last ``pre_frames`` raw frames are kept in memory. When a frame's result
*triggers* (confirmed tracks, traffic events/classifications, any detection, or always -- see
``ops.recorder.trigger``) a segment starts with those frames and continues until ``post_frames``
frames in a row did not trigger, or ``max_frames_per_file`` is reached. The segment is written by a
background thread as one version-1 recording (:mod:`hal.recording`, ``radar-edge replay``/``plot``
read it) named ``YYYYmmddTHHMMSSZ-<first seq>-<profile>.npz``; its ``meta_json`` tells what triggered.

The ring is bounded: after every write the oldest files go until the directory holds at most
``quota_mb``. Before a write the free space of the file system is checked against ``min_free_mb``.
A full disk (``ENOSPC``/``EDQUOT`` while writing, or too little free space) **stops recording, never
the service**: the partial file is removed, the segment is counted as lost, and recording resumes
by itself after ``retry_s`` once space is back. ``publish`` never blocks: segments waiting for the
writer are bounded (``queue_files``) and a segment that does not fit is dropped and counted.

Raw frames reach the recorder through :meth:`EventRecorder.wrap`, a pass-through pipeline that
hands every frame to the recorder before processing it (the loop's sinks only see results).
"""

from __future__ import annotations

import collections
import errno
import logging
import queue
import shutil
import threading
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

from edge.pipeline import Pipeline, StageTimer
from edge.types import FrameResult, LoopHealth, RawFrame
from hal.recording import RecordingWriter

log = logging.getLogger(__name__)

_DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


@dataclass(frozen=True)
class RecorderConfig:
    enabled: bool = field(default=False, metadata={"doc": "record event segments to disk"})
    directory: str = field(
        default="/var/lib/radar-edge/recordings",
        metadata={"doc": "where the ring of recordings lives (the service may write only there)"},
    )
    quota_mb: float = field(
        default=1024.0, metadata={"unit": "MB", "doc": "the ring's size: oldest recordings are deleted beyond it",
                                  "min": 1.0, "max": 1_000_000.0},
    )
    min_free_mb: float = field(
        default=256.0, metadata={"unit": "MB", "doc": "do not write when the file system has less free space",
                                 "min": 0.0, "max": 1_000_000.0},
    )
    trigger: str = field(
        default="tracks",
        metadata={"doc": "what starts a segment: confirmed tracks, events (traffic events and classified "
                         "passages), any detection, or always (continuous)",
                  "choices": ("tracks", "events", "detections", "always")},
    )
    pre_frames: int = field(default=10, metadata={"doc": "frames kept before the trigger", "min": 0, "max": 1000})
    post_frames: int = field(
        default=15, metadata={"doc": "a segment ends after this many frames without a trigger", "min": 1, "max": 10000}
    )
    max_frames_per_file: int = field(
        default=300, metadata={"doc": "a long segment is split into files of at most this many frames",
                               "min": 2, "max": 100_000},
    )
    queue_files: int = field(
        default=2, metadata={"doc": "segments waiting for the writer thread; more are dropped and counted",
                             "min": 1, "max": 16},
    )
    retry_s: float = field(
        default=60.0, metadata={"unit": "s", "doc": "after a full disk, try again after this long",
                                "min": 0.0, "max": 86400.0},
    )


@dataclass
class RecorderStats:
    files_written: int = 0
    files_deleted: int = 0
    bytes_written: int = 0
    segments_dropped: int = 0  # writer busy (queue full)
    segments_lost: int = 0  # disk full / write error
    disk_full_events: int = 0


class _TapPipeline(Pipeline):
    """Hands each frame to ``tap`` and processes it with ``inner`` (attributes delegate to ``inner``)."""

    def __init__(self, inner: Pipeline, tap: Callable[[RawFrame], None]) -> None:
        self.inner = inner
        self.tap = tap
        self.profile = inner.profile
        self.stages = inner.stages
        self.frontend = inner.frontend
        self.config = inner.config

    def process(self, frame: RawFrame, timer: StageTimer) -> FrameResult:
        self.tap(frame)
        return self.inner.process(frame, timer)

    def close(self) -> None:
        self.inner.close()

    def __getattr__(self, name: str) -> Any:  # n_lanes, models... of the wrapped pipeline
        return getattr(self.__dict__["inner"], name)


def _triggers(mode: str, result: FrameResult) -> bool:
    if mode == "always":
        return True
    if mode == "detections":
        return len(result.detections) > 0
    if mode == "events":
        return bool(result.events or result.classifications)
    return any(t.confirmed for t in result.tracks) or bool(result.events or result.classifications)


class EventRecorder:
    """Frame-loop sink writing event segments to a bounded ring of recordings (module docstring)."""

    def __init__(
        self,
        config: RecorderConfig,
        *,
        meta: dict[str, Any] | None = None,
        clock_s: Callable[[], float] = time.monotonic,
        disk_usage: Callable[[str], Any] = shutil.disk_usage,
        writer: Callable[[RecordingWriter, Path], Path] | None = None,
    ) -> None:
        self.config = config
        self.dir = Path(config.directory)
        self.meta = dict(meta or {})
        self.stats = RecorderStats()
        self.state = "idle"  # idle | recording | disk_full | error
        self._clock_s = clock_s
        self._disk_usage = disk_usage
        self._save = writer or (lambda w, p: w.save(p))
        self._ring: collections.deque[RawFrame] = collections.deque(maxlen=max(config.pre_frames, 0) or 1)
        self._segment: list[RawFrame] | None = None
        self._why: set[str] = set()
        self._track_ids: set[int] = set()
        self._quiet = 0
        self._last: RawFrame | None = None
        self._profile = ""
        self._blocked_until = 0.0
        self._queue: queue.Queue = queue.Queue(maxsize=config.queue_files)
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    # --- frame side --------------------------------------------------------------------------------
    def wrap(self, pipeline: Pipeline) -> Pipeline:
        return _TapPipeline(pipeline, self.tap)

    def tap(self, frame: RawFrame) -> None:
        """Keep a copy of the frame (the source may reuse its buffers) until its result is published."""
        self._last = RawFrame(seq=frame.seq, t_ns=frame.t_ns, i=frame.i.copy(), q=frame.q.copy(),
                              frontend=frame.frontend, truth=frame.truth, meta=dict(frame.meta))

    # --- sink ----------------------------------------------------------------------------------------
    def publish(self, result: FrameResult | None, health: LoopHealth) -> None:
        if result is None or not self.config.enabled:
            return
        frame, self._last = self._last, None
        if frame is None or frame.seq != result.seq:
            return  # result without its frame (recorder attached without wrap)
        self._profile = result.profile
        hit = _triggers(self.config.trigger, result)
        if self._segment is None:
            if not hit:
                if self.config.pre_frames:
                    self._ring.append(frame)
                return
            self._segment = list(self._ring) if self.config.pre_frames else []
            self._ring.clear()
            self._why.clear()
            self._track_ids.clear()
            self._quiet = 0
            if self.state != "disk_full":
                self.state = "recording"
        self._segment.append(frame)
        if hit:
            self._quiet = 0
            self._why.add(self.config.trigger)
            self._track_ids.update(t.track_id for t in result.tracks if t.confirmed)
            self._why.update(e.kind for e in result.events)
            self._why.update(f"class:{c.cls}" for c in result.classifications)
        else:
            self._quiet += 1
        if self._quiet >= self.config.post_frames or len(self._segment) >= self.config.max_frames_per_file:
            self._finish(result.profile)

    def _finish(self, profile: str) -> None:
        seg, self._segment = self._segment, None
        if self.state == "recording":
            self.state = "idle"
        if not seg:
            return
        if self._clock_s() < self._blocked_until:
            self.stats.segments_lost += 1
            return
        meta = dict(self.meta, profile=profile, trigger=sorted(self._why), track_ids=sorted(self._track_ids),
                    first_seq=seg[0].seq, frames=len(seg),
                    recorded_utc=datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"))
        try:
            self._queue.put_nowait((seg, meta))
        except queue.Full:
            self.stats.segments_dropped += 1
            log.warning("recorder: writer busy, segment of %d frames dropped", len(seg))
            return
        self._ensure_thread()

    def _ensure_thread(self) -> None:
        if self._thread is None or not self._thread.is_alive():
            self._thread = threading.Thread(target=self._writer, name="recorder", daemon=True)
            self._thread.start()

    def flush(self) -> None:
        """Wait until every queued segment is written (tests, shutdown)."""
        if self._thread is None:
            return
        self._queue.join()

    def close(self) -> None:
        if self._segment:
            self._finish(self._profile)
        self._ensure_thread()  # first: the writer must be there to make room in a full queue
        self._queue.put(None)
        self._thread.join(timeout=30.0)

    # --- writer thread -----------------------------------------------------------------------------
    def _writer(self) -> None:
        while True:
            item = self._queue.get()
            try:
                if item is None:
                    return
                self._write(*item)
            except Exception as exc:  # noqa: BLE001 - the recorder thread must survive any write problem
                self.stats.segments_lost += 1
                self.state = "error"
                log.error("recorder: writing a segment failed: %s", exc)
            finally:
                self._queue.task_done()

    def _write(self, frames: list[RawFrame], meta: dict[str, Any]) -> None:
        cfg = self.config
        est = sum(f.i.nbytes + f.q.nbytes for f in frames) + 4096
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            free = self._disk_usage(str(self.dir)).free
        except OSError as exc:
            self._lost(f"recordings directory {self.dir} is not usable: {exc}", disk_full=exc.errno in _DISK_FULL)
            return
        if free - est < cfg.min_free_mb * 1e6:
            self._lost(f"only {free / 1e6:.0f} MB free on {self.dir} (min_free_mb = {cfg.min_free_mb:g})", disk_full=True)
            return
        w = RecordingWriter(frames[0].frontend, meta=meta, max_frames=len(frames))
        for f in frames:
            w.add(f)
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        path = self.dir / f"{stamp}-{frames[0].seq:08d}-{meta.get('profile') or 'rec'}.npz"
        try:
            out = self._save(w, path)
        except OSError as exc:
            part = path.with_name(path.name + ".part")
            part.unlink(missing_ok=True)
            self._lost(f"writing {path.name} failed: {exc}", disk_full=exc.errno in _DISK_FULL)
            return
        with self._lock:
            self.stats.files_written += 1
            self.stats.bytes_written += out.stat().st_size
        if self.state in ("disk_full", "error"):
            log.info("recorder: recording again")
            self.state = "idle"
        self._enforce_quota()

    def _lost(self, why: str, disk_full: bool) -> None:
        self.stats.segments_lost += 1
        if disk_full:
            self.stats.disk_full_events += 1
            self._blocked_until = self._clock_s() + self.config.retry_s
            if self.state != "disk_full":
                log.error("recorder: %s -- recording stops for %.0f s (the service keeps running)", why,
                          self.config.retry_s)
            self.state = "disk_full"
        else:
            self.state = "error"
            log.error("recorder: %s", why)

    def files(self) -> list[Path]:
        """Recordings in the ring, oldest first."""
        try:
            found = [p for p in self.dir.glob("*.npz") if p.is_file()]
        except OSError:
            return []
        return sorted(found, key=lambda p: (p.stat().st_mtime_ns, p.name))

    def _enforce_quota(self) -> None:
        quota = self.config.quota_mb * 1e6
        files = self.files()
        sizes = {p: p.stat().st_size for p in files}
        total = sum(sizes.values())
        for p in files:
            if total <= quota:
                break
            try:
                p.unlink()
            except OSError as exc:
                log.warning("recorder: cannot delete %s: %s", p, exc)
                continue
            total -= sizes[p]
            self.stats.files_deleted += 1
            log.info("recorder: quota %.0f MB reached, deleted %s", self.config.quota_mb, p.name)


def recorder_from_config(cfg: RecorderConfig, meta: dict[str, Any] | None = None) -> EventRecorder | None:
    return EventRecorder(cfg, meta=meta) if cfg.enabled else None


