"""``radar-edge run --view``: a live terminal table of tracks, lane counters and budget use.

A frame-loop sink that keeps the latest state and redraws the screen with ANSI escape codes at most
``max_hz`` times a second (cursor home, each line cleared to its end, the rest of the screen cleared:
no flicker from a full clear). Drawing is one ``write`` of a few kilobytes; results between redraws
only update counters.
"""

from __future__ import annotations

import collections
import math
import sys
import time
from typing import Callable, TextIO

from edge.types import FrameResult, LoopHealth

HOME = "\x1b[H"
CLEAR_EOL = "\x1b[K"
CLEAR_BELOW = "\x1b[J"
BOLD = "\x1b[1m"
DIM = "\x1b[2m"
RED = "\x1b[31m"
GREEN = "\x1b[32m"
YELLOW = "\x1b[33m"
RESET = "\x1b[0m"
HIDE_CURSOR = "\x1b[?25l"
SHOW_CURSOR = "\x1b[?25h"


def _bar(frac: float, width: int = 24) -> str:
    frac = 0.0 if not math.isfinite(frac) else max(0.0, frac)
    n = min(width, int(round(frac * width)))
    colour = GREEN if frac < 0.5 else YELLOW if frac < 0.9 else RED
    return f"{colour}{'#' * n}{RESET}{DIM}{'.' * (width - n)}{RESET}"


def _f(v, fmt: str, width: int) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-".rjust(width)
    return format(v, fmt).rjust(width)


class LiveView:
    """Sink drawing a live table (see the module docstring)."""

    def __init__(self, stream: TextIO | None = None, *, max_hz: float = 4.0, max_tracks: int = 12,
                 clock_s: Callable[[], float] = time.monotonic, color: bool = True, title: str = "") -> None:
        self.stream = stream or sys.stdout
        self.period_s = 1.0 / max_hz
        self.max_tracks = max_tracks
        self.clock_s = clock_s
        self.color = color
        self.title = title
        self.redraws = 0
        self._last_draw = -math.inf
        self._result: FrameResult | None = None
        self._health: LoopHealth | None = None
        self._volume: dict[int, int] = collections.defaultdict(int)
        self._last_stats: dict[int, object] = {}
        self._events: collections.deque[str] = collections.deque(maxlen=6)
        self._started = False
        self._t0_ns: int | None = None

    def publish(self, result: FrameResult | None, health: LoopHealth) -> None:
        self._health = health
        if result is not None:
            self._result = result
            for s in result.lane_stats:
                self._volume[s.lane] += s.volume
                self._last_stats[s.lane] = s
            if self._t0_ns is None:
                self._t0_ns = result.t_ns
            t = (result.t_ns - self._t0_ns) / 1e9  # since the view started
            for e in result.events:
                self._events.append(f"{t:+9.1f} s  {e.kind:<16} track #{e.track_id}  lane {e.lane}")
            for c in result.classifications:
                self._events.append(f"{t:+9.1f} s  {c.cls:<16} track #{c.track_id}  {c.direction} "
                                    f"{'n/a' if c.speed_uncertain else f'{c.mean_radial_speed_kmh:.1f}'} km/h  p={max(c.probabilities.values(), default=0):.2f}")
        now = self.clock_s()
        if now - self._last_draw < self.period_s:
            return
        self._last_draw = now
        self.draw()

    def render(self) -> list[str]:
        h, r = self._health, self._result
        lines = []
        if h is None:
            return ["radar-edge: waiting for the first frame..."]
        state_col = GREEN if h.state == "running" else RED
        lines.append(f"{BOLD}radar-edge{RESET} {self.title}  {r.profile if r else ''}  "
                     f"state {state_col}{h.state}{RESET}  frames {h.frames}  dropped {h.dropped_frames}  "
                     f"overruns {h.overruns}  errors {h.errors}")
        frac = h.frame_p99_ms / h.budget_ms if h.budget_ms else float("nan")
        age_ms = (h.t_ns - h.last_frame_ns) / 1e6 if h.last_frame_ns else float("nan")
        lines.append(f"budget  p99 {h.frame_p99_ms:7.2f} of {h.budget_ms:.0f} ms  [{_bar(frac)}] {frac:6.1%}   "
                     f"last frame {_f(age_ms, '.0f', 5)} ms ago")
        lines.append("")
        tracks = sorted((r.tracks if r else ()), key=lambda s: s.range_m)
        lines.append(f"{BOLD}TRACKS ({len(tracks)}){RESET}   detections {len(r.detections) if r else 0}   "
                     f"seq {r.seq if r else '-'}")
        lines.append(f"{DIM}{'id':>4} {'lane':>4} {'range m':>8} {'az deg':>7} {'x m':>7} {'y m':>7} "
                     f"{'km/h':>7} {'class':<12} {'p':>5} {'age':>5}{RESET}")
        for s in tracks[: self.max_tracks]:
            mark = "" if s.confirmed else f"{DIM}"
            lines.append(f"{mark}{s.track_id:>4} {_f(s.lane, 'd', 4)} {s.range_m:8.1f} {_f(math.degrees(s.az_rad), '.1f', 7)} "
                         f"{s.x_m:7.1f} {s.y_m:7.1f} {s.speed_mps * 3.6:7.1f} {(s.cls or '-'):<12} "
                         f"{_f(s.class_probability, '.2f', 5)} {s.age_frames:5d}{RESET if mark else ''}")
        if len(tracks) > self.max_tracks:
            lines.append(f"{DIM}  ... {len(tracks) - self.max_tracks} more{RESET}")
        presence = r.presence if r else ()
        lanes = sorted(set(range(len(presence))) | set(self._volume))
        if lanes:
            lines.append("")
            lines.append(f"{BOLD}LANES{RESET}")
            lines.append(f"{DIM}{'lane':>4} {'presence':>8} {'volume':>7} {'last: veh':>10} {'km/h':>7} {'occ %':>6}{RESET}")
            for ln in lanes:
                p = presence[ln] if ln < len(presence) else None
                pres = f"{GREEN}{'occupied':>8}{RESET}" if p else f"{'-' if p is None else 'free':>8}"
                st = self._last_stats.get(ln)
                lines.append(f"{ln:>4} {pres} {self._volume.get(ln, 0):7d} "
                             f"{_f(getattr(st, 'volume', None), 'd', 10)} {_f(getattr(st, 'mean_speed_kmh', None), '.1f', 7)} "
                             f"{_f(getattr(st, 'occupancy_pct', None), '.1f', 6)}")
        if self._events:
            lines.append("")
            lines.append(f"{BOLD}EVENTS{RESET}")
            lines.extend(self._events)
        if not self.color:
            import re

            lines = [re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", x) for x in lines]
        return lines

    def draw(self) -> None:
        head = "" if self._started else HIDE_CURSOR
        self._started = True
        text = HOME + "".join(line + CLEAR_EOL + "\n" for line in self.render()) + CLEAR_BELOW
        self.stream.write(head + text)
        self.stream.flush()
        self.redraws += 1

    def close(self) -> None:
        if self._health is not None:
            self.draw()
        if self._started:
            self.stream.write(SHOW_CURSOR)
            self.stream.flush()
