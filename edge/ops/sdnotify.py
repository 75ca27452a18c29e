"""systemd service notification (``sd_notify``) without extra dependencies, as a frame-loop sink.

The protocol is one datagram of ``KEY=VALUE`` lines to the ``AF_UNIX`` socket named in
``$NOTIFY_SOCKET`` (a path, or ``@name`` for the Linux abstract namespace). The service unit is
``Type=notify`` with ``WatchdogSec``; systemd passes ``$WATCHDOG_USEC`` (and ``$WATCHDOG_PID``).

:class:`NotifySink` follows the frame loop:

* ``READY=1`` after the first frame has been processed (the source is open and the pipeline runs),
  or as soon as the loop serves a source that cannot be opened at start as a fault (the outputs are
  up and tell the controller; the loop retries the board);
* ``WATCHDOG=1`` at most every half watchdog period, and **only if a frame was processed since the
  previous ping**, or while the loop is still retrying a source that has never delivered a frame --
  heartbeats of a source that stalled after frames flowed do not feed the watchdog, so systemd
  restarts the service after ``WatchdogSec``; a board missing at start keeps the service up instead
  of restarting it into the start limit;
* ``STATUS=`` with state, frames, drops and the p99 frame time against the budget, when it changes
  and at most once a second;
* ``STOPPING=1`` when the loop closes its sinks.

Sending never blocks and never raises: a missing or full socket is logged once and counted.
"""

from __future__ import annotations

import errno
import logging
import os
import socket
import time
from typing import Callable, Mapping

from edge.types import FrameResult, LoopHealth

log = logging.getLogger(__name__)


def _address(name: str) -> str | bytes:
    if name.startswith("@"):
        return b"\0" + name[1:].encode()  # abstract namespace
    return name


class Notifier:
    """Sends ``sd_notify`` messages to ``socket_path`` (``$NOTIFY_SOCKET`` by default); no-op without one."""

    def __init__(self, socket_path: str | None = None, env: Mapping[str, str] | None = None) -> None:
        env = os.environ if env is None else env
        self.socket_path = socket_path if socket_path is not None else env.get("NOTIFY_SOCKET", "")
        self.errors = 0
        self.sent = 0
        self._sock: socket.socket | None = None
        if self.socket_path:
            if not (self.socket_path.startswith("/") or self.socket_path.startswith("@")):
                log.warning("NOTIFY_SOCKET=%r is neither a path nor an abstract name: notifications off", self.socket_path)
                self.socket_path = ""
            else:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._sock.setblocking(False)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, *lines: str) -> bool:
        """Send one datagram with ``lines``; False (and counted) when it could not be sent."""
        if self._sock is None:
            return False
        msg = "\n".join(lines).encode("utf-8", "replace")
        try:
            self._sock.sendto(msg, _address(self.socket_path))
        except OSError as exc:
            self.errors += 1
            if self.errors == 1 or exc.errno not in (errno.EAGAIN, errno.ECONNREFUSED, errno.ENOENT):
                log.warning("sd_notify to %s failed: %s", self.socket_path, exc)
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def watchdog_period_s(env: Mapping[str, str] | None = None) -> float | None:
    """The watchdog timeout systemd set for this process (``$WATCHDOG_USEC``), or None."""
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC", "")
    pid = env.get("WATCHDOG_PID", "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    if pid and pid.isdigit() and int(pid) != os.getpid():
        return None  # meant for another process
    return int(usec) / 1e6


class NotifySink:
    """Frame-loop sink that speaks ``sd_notify`` (see the module docstring)."""

    def __init__(
        self,
        notifier: Notifier | None = None,
        *,
        watchdog_s: float | None = None,
        status_period_s: float = 1.0,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        env: Mapping[str, str] | None = None,
    ) -> None:
        self.notifier = notifier or Notifier(env=env)
        wd = watchdog_s if watchdog_s is not None else watchdog_period_s(env)
        # ping at half the timeout (sd_watchdog_enabled(3) advice); without a watchdog, every second
        self.ping_ns = int((wd / 2.0 if wd else 1.0) * 1e9)
        self.status_ns = int(status_period_s * 1e9)
        self.clock_ns = clock_ns
        self.ready = False
        self.pings = 0
        self._frames_at_ping = -1
        self._last_ping_ns: int | None = None
        self._last_status_ns: int | None = None
        self._last_status = ""

    @staticmethod
    def status_line(health: LoopHealth) -> str:
        return (
            f"{health.state}: {health.frames} frames, {health.dropped_frames} dropped, {health.overruns} overruns, "
            f"{health.errors} errors, p99 {health.frame_p99_ms:.1f} of {health.budget_ms:.0f} ms"
        )

    def publish(self, result: FrameResult | None, health: LoopHealth) -> None:
        n = self.notifier
        if not n.enabled:
            return
        now = self.clock_ns()
        lines: list[str] = []
        waiting_for_source = health.state == "fault" and health.frames == 0  # never opened: retrying it
        if not self.ready and (result is not None or waiting_for_source):
            self.ready = True
            lines.append("READY=1")
        # feed the watchdog only if frames were processed since the last ping (or the board is awaited)
        due = self._last_ping_ns is None or now - self._last_ping_ns >= self.ping_ns
        progress = health.frames > self._frames_at_ping and health.state == "running"
        if self.ready and due and (progress or waiting_for_source):
            lines.append("WATCHDOG=1")
            self._last_ping_ns = now
            self._frames_at_ping = health.frames
            self.pings += 1
        status = self.status_line(health)
        state_changed = status.split(":", 1)[0] != self._last_status.split(":", 1)[0]
        if state_changed or self._last_status_ns is None or now - self._last_status_ns >= self.status_ns:
            lines.append(f"STATUS={status}")
            self._last_status_ns = now
            self._last_status = status
        if lines:
            n.notify(*lines)

    def close(self) -> None:
        if self.notifier.enabled:
            self.notifier.notify("STOPPING=1", "STATUS=stopping")
        self.notifier.close()
