"""The one contract every radar backend fulfils.

:class:`RadarSource` owns the generic behaviour (python-can's ``BusABC.recv`` over
``_recv_internal``): opening as a context manager, host monotonic timestamps, frame-counter gap
accounting, shape/dtype/range checks and the ``read_frame(timeout)`` deadline. A backend fills four
small hooks: ``_open``, ``_read_raw``, ``_close`` and the ``frontend`` it describes. Nothing is opened
in ``__init__``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from hal.errors import FrameFormatError, SourceClosedError, SourceNotOpenError, SourceTimeoutError
from hal.frame import RawFrame
from hal.waveform import FrontendInfo

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RawRead:
    """What a backend's ``_read_raw`` hands back: the board's counter and the samples."""

    seq: int
    i: np.ndarray
    q: np.ndarray
    truth: Any = None
    t_ns: int | None = None
    meta: dict | None = None


@dataclass
class SourceStats:
    """Counters a source keeps over its life (across opens)."""

    frames: int = 0
    dropped_frames: int = 0
    timeouts: int = 0
    faults: int = 0  # link faults the backend handled itself (each one reconnects)
    reconnects: int = 0  # reconnects the backend made itself
    malformed_frames: int = 0  # frames that arrived corrupted or truncated and were dropped
    resyncs: int = 0  # times the stream decoder skipped garbage to find the next message

    @property
    def errors(self) -> int:
        """Faults the backend absorbed without raising: link faults, malformed frames, resynchronisations."""
        return self.faults + self.malformed_frames + self.resyncs


class RadarSource:
    """Base class of all backends. Use as ``with open_radar(url) as src: src.read_frame(1.0)``."""

    #: URL scheme the backend is registered under (for messages)
    scheme: str = ""
    #: True when ``read_frame`` blocks until the board's next frame (hardware, real-time simulation,
    #: paced replay); False when frames come back to back as fast as they are read. The frame loop
    #: schedules its own deadlines only for sources that do not pace themselves.
    paces_itself: bool = True

    def __init__(self, *, clock_ns: Callable[[], int] = time.monotonic_ns) -> None:
        self._clock_ns = clock_ns
        self._is_open = False
        self._last_seq: int | None = None
        self.stats = SourceStats()

    # --- hooks -------------------------------------------------------------------------------
    @property
    def frontend(self) -> FrontendInfo:  # pragma: no cover - abstract
        raise NotImplementedError

    def _open(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _read_raw(self, timeout_s: float | None) -> RawRead | None:  # pragma: no cover - abstract
        """Return the next frame, or ``None`` if none arrived within ``timeout_s``.

        Raise :class:`SourceClosedError` at the end of the data.
        """
        raise NotImplementedError

    def _close(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    # --- generic behaviour ---------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._is_open

    def open(self) -> "RadarSource":
        if not self._is_open:
            self._open()
            self._is_open = True
            self._last_seq = None
            log.info("opened %s source: %s", self.scheme or type(self).__name__, self.frontend.board)
        return self

    def close(self) -> None:
        if self._is_open:
            self._is_open = False
            self._close()
            log.info(
                "closed %s source: %d frames, %d dropped",
                self.scheme or type(self).__name__,
                self.stats.frames,
                self.stats.dropped_frames,
            )

    def __enter__(self) -> "RadarSource":
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __iter__(self):
        """Frames until the source ends (for offline use: recordings, non-real-time simulation)."""
        while True:
            try:
                yield self.read_frame(timeout=None)
            except SourceClosedError:
                return

    def read_frame(self, timeout: float | None = 1.0) -> RawFrame:
        """Return the next frame; raise :class:`SourceTimeoutError` after ``timeout`` seconds.

        ``timeout=None`` waits as long as the backend needs.
        """
        if not self._is_open:
            raise SourceNotOpenError(f"{type(self).__name__} is not open")
        raw = self._read_raw(timeout)
        if raw is None:
            self.stats.timeouts += 1
            raise SourceTimeoutError(f"no frame within {timeout} s from {self.scheme}")
        t_ns = raw.t_ns if raw.t_ns is not None else self._clock_ns()
        self._check(raw)
        if self._last_seq is not None:
            gap = raw.seq - self._last_seq - 1
            if gap > 0:
                self.stats.dropped_frames += gap
                log.debug("frame counter jumped %d -> %d: %d dropped", self._last_seq, raw.seq, gap)
            elif gap < 0:
                log.info("frame counter restarted (%d -> %d)", self._last_seq, raw.seq)
        self._last_seq = raw.seq
        self.stats.frames += 1
        return RawFrame(
            seq=raw.seq, t_ns=t_ns, i=raw.i, q=raw.q, frontend=self.frontend, truth=raw.truth, meta=raw.meta or {}
        )

    def _check(self, raw: RawRead) -> None:
        fe = self.frontend
        shape = fe.frame_shape
        for name, a in (("i", raw.i), ("q", raw.q)):
            if not isinstance(a, np.ndarray) or a.dtype != np.int16:
                raise FrameFormatError(f"{name} must be an int16 array, got {getattr(a, 'dtype', type(a))}")
            if a.shape != shape:
                raise FrameFormatError(f"{name} has shape {a.shape}, expected {shape}")
        lo, hi = fe.adc_min, fe.adc_max
        if (
            int(raw.i.min()) < lo
            or int(raw.i.max()) > hi
            or int(raw.q.min()) < lo
            or int(raw.q.max()) > hi
        ):
            raise FrameFormatError(f"samples outside the {fe.adc_bits}-bit ADC range [{lo}, {hi}]")
