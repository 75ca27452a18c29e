"""``replay://`` backend: a recording reader plus a separate pacing wrapper (python-can's
``LogReader`` + ``MessageSync``).

``replay://path/to/rec.npz?speed=1`` replays at the recorded frame rate; ``speed=2`` twice as fast;
``speed=0`` as fast as the reader asks, each frame stamped on the board's timeline (time of opening +
frame counter x frame period) rather than the host's arrival time. ``loop=1`` starts again at the
end (frame counters and time continue).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Iterator

from hal.base import RadarSource, RawRead
from hal.clock import MonotonicClock
from hal.errors import SourceClosedError, SourceUrlError
from hal.recording import Recording
from hal.registry import Option, SourceUrl, parse_bool, resolve_options


def _speed(text: str) -> float:
    v = float(text)
    if v < 0:
        raise ValueError("speed must be >= 0")
    return v


class RecordingReader:
    """Iterates ``(k, RawRead)`` over a recording; knows nothing about time."""

    def __init__(self, rec: Recording, loop: bool = False) -> None:
        self.rec = rec
        self.loop = loop

    def __iter__(self) -> Iterator[RawRead]:
        n = len(self.rec)
        if n == 0:
            return
        offset = 0
        span = int(self.rec.seq[-1] - self.rec.seq[0]) + 1
        while True:
            for k in range(n):
                yield RawRead(
                    seq=int(self.rec.seq[k]) + offset,
                    i=self.rec.i[k],
                    q=self.rec.q[k],
                    truth=self.rec.truth(k),
                    meta={"recorded_t_ns": int(self.rec.t_ns[k]), "index": k},
                )
            if not self.loop:
                return
            offset += span


class Pacer:
    """Releases items one frame period apart, divided by ``speed`` (0: no pacing).

    Deadlines are computed from the first item's release time, so pacing does not drift.
    """

    def __init__(self, clock: Any, speed: float, period_ns: int) -> None:
        self.clock = clock
        self.speed = speed
        self.period_ns = period_ns
        self._t0: int | None = None
        self._n = 0

    def wait_for_next(self, timeout_s: float | None) -> bool:
        """Wait until the next item is due; False if that is later than ``timeout_s`` from now."""
        if self.speed == 0:
            return True
        now = self.clock.now_ns()
        if self._t0 is None:
            self._t0 = now
        due = self._t0 + int(self._n * self.period_ns / self.speed)
        if timeout_s is not None and due > now + timeout_s * 1e9:
            self.clock.sleep_until_ns(now + int(timeout_s * 1e9))
            return False
        self.clock.sleep_until_ns(due)
        self._n += 1
        return True


class ReplaySource(RadarSource):
    scheme = "replay"
    options = {
        "speed": Option(_speed, 1.0, "playback speed, 0 = as fast as possible"),
        "loop": Option(parse_bool, False, "start again at the end"),
    }

    def __init__(self, path: str, speed: float = 1.0, loop: bool = False, clock: Any = None) -> None:
        self._clock = clock or MonotonicClock()
        super().__init__(clock_ns=self._clock.now_ns)
        self.path = path
        self.speed = speed
        self.paces_itself = speed > 0
        self.loop = loop
        self._rec: Recording | None = None

    @classmethod
    def from_url(cls, url: SourceUrl, overrides: dict[str, Any]) -> "ReplaySource":
        clock = overrides.pop("clock", None)
        opts = resolve_options(url, cls.options, overrides)
        if not url.target:
            raise SourceUrlError("replay:// needs a file: replay://path/to/recording.npz")
        return cls(url.target, clock=clock, **opts)

    @property
    def frontend(self):
        if self._rec is None:
            # the front end is only known once the file is read
            self._rec = Recording(self.path)
        return self._rec.frontend

    @property
    def recording(self) -> Recording:
        self.frontend  # noqa: B018 - loads the file
        return self._rec

    def _open(self) -> None:
        rec = self.recording
        self._it = iter(RecordingReader(rec, self.loop))
        self._period_ns = int(rec.frontend.waveform.frame_period_s * 1e9)
        self._pacer = Pacer(self._clock, self.speed, self._period_ns)
        self._t_open_ns = self._clock.now_ns()

    def _read_raw(self, timeout_s: float | None) -> RawRead | None:
        if not self._pacer.wait_for_next(timeout_s):
            return None
        try:
            raw = next(self._it)
        except StopIteration:
            raise SourceClosedError(f"end of recording {self.path}") from None
        if self.speed == 0:
            # as fast as possible, the host clock says nothing about the traffic: stamp the frame on the
            # board's timeline (open time + frame counter x period) so that trackers, lane statistics and
            # events see the recorded time, across loops too
            raw = replace(raw, t_ns=self._t_open_ns + (raw.seq - int(self.recording.seq[0])) * self._period_ns)
        return raw

    def _close(self) -> None:
        self._it = iter(())
