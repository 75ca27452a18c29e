"""Monotonic clocks. Real time for the product, a fake one for tests (no sleeps in tests)."""

from __future__ import annotations

import threading
import time


class MonotonicClock:
    """``time.monotonic_ns`` with an interruptible ``sleep_until_ns``."""

    def __init__(self) -> None:
        self._wake = threading.Event()

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep_until_ns(self, t_ns: int) -> None:
        """Sleep until ``t_ns`` or until :meth:`interrupt` is called."""
        while True:
            dt = t_ns - time.monotonic_ns()
            if dt <= 0 or self._wake.is_set():
                return
            self._wake.wait(dt / 1e9)

    def interrupt(self) -> None:
        self._wake.set()


class FakeClock:
    """A clock that only moves when told to; ``sleep_until_ns`` jumps to the deadline."""

    def __init__(self, start_ns: int = 1_000_000_000) -> None:
        self.t_ns = start_ns
        self.sleeps: list[int] = []

    def now_ns(self) -> int:
        return self.t_ns

    def advance_ns(self, dt_ns: int) -> None:
        self.t_ns += int(dt_ns)

    def sleep_until_ns(self, t_ns: int) -> None:
        self.sleeps.append(int(t_ns))
        if t_ns > self.t_ns:
            self.t_ns = int(t_ns)

    def interrupt(self) -> None:
        pass
