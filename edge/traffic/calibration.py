"""The traffic layer's self-calibration (mounting yaw, learned lanes) kept across restarts.

A box on a pole is power-cycled now and then. Without a memory it starts from the configured yaw and,
with learned lanes, from no lanes at all, and needs tens of seconds of traffic to find them again --
counting vehicles into the wrong lane meanwhile. With ``traffic.calibration_file`` set, the monitor
saves what it learned every ``calibration_save_every_s`` (and at stop) and starts from it.

File: one small JSON document, written atomically (a temporary file beside it, flushed and
``fsync``-ed, then renamed over the old one), so a power cut leaves the old or the new file, never half
of one::

    {"format": "radar-edge-traffic-calibration", "version": 1, "saved_unix_s": 1764000000.0,
     "yaw_deg": 2.996, "yaw_stderr_deg": 0.021, "yaw_votes": 200,
     "lane_mode": "learned", "lanes": [{"center_m": -5.2, "width_m": 3.5, "direction": "toward"}, ...]}

Writes happen on a background thread (:class:`CalibrationWriter`): a slow SD card never stalls the
frame loop; the newest state wins when writes queue up. A file that is missing starts the monitor
uncalibrated; one that is unreadable or invalid is ignored with a warning (and left in place for a
look); write errors are counted and logged, never raised into the frame loop.
"""

from __future__ import annotations

import json
import logging
import math
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from edge.traffic.lanes import Lane

log = logging.getLogger(__name__)

__all__ = ["FORMAT", "VERSION", "Calibration", "CalibrationError", "load_calibration", "CalibrationWriter"]

FORMAT = "radar-edge-traffic-calibration"
VERSION = 1


class CalibrationError(ValueError):
    """A calibration file that cannot be used (unreadable, wrong format, values out of range)."""


@dataclass(frozen=True)
class Calibration:
    yaw_rad: float
    yaw_stderr_rad: float
    yaw_votes: int
    lane_mode: str
    lanes: tuple[Lane, ...]
    saved_unix_s: float = 0.0

    def to_json(self) -> dict:
        return {
            "format": FORMAT, "version": VERSION, "saved_unix_s": round(self.saved_unix_s, 3),
            "yaw_deg": math.degrees(self.yaw_rad), "yaw_stderr_deg": math.degrees(self.yaw_stderr_rad),
            "yaw_votes": int(self.yaw_votes), "lane_mode": self.lane_mode,
            "lanes": [{"center_m": ln.center_m, "width_m": ln.width_m, "direction": ln.direction_name}
                      for ln in self.lanes],
        }

    @classmethod
    def from_json(cls, doc: object) -> "Calibration":
        if not isinstance(doc, dict):
            raise CalibrationError("not a JSON object")
        if doc.get("format") != FORMAT:
            raise CalibrationError(f"format is {doc.get('format')!r}, expected {FORMAT!r}")
        if doc.get("version") != VERSION:
            raise CalibrationError(f"version {doc.get('version')!r} is not supported (this build reads {VERSION})")
        try:
            yaw_deg = float(doc["yaw_deg"])
            se_deg = float(doc["yaw_stderr_deg"])
            votes = int(doc["yaw_votes"])
            lane_mode = str(doc["lane_mode"])
            lanes = tuple(Lane(float(ln["center_m"]), float(ln["width_m"]), _direction(ln["direction"]))
                          for ln in doc["lanes"])
            saved = float(doc.get("saved_unix_s", 0.0))
        except (KeyError, TypeError, ValueError) as e:
            raise CalibrationError(f"bad or missing field: {e}") from None
        if not (math.isfinite(yaw_deg) and abs(yaw_deg) <= 45.0):
            raise CalibrationError(f"yaw_deg {yaw_deg} outside [-45, 45]")
        if not (math.isfinite(se_deg) and 0.0 <= se_deg <= 45.0):
            raise CalibrationError(f"yaw_stderr_deg {se_deg} outside [0, 45]")
        if votes < 0:
            raise CalibrationError(f"yaw_votes {votes} < 0")
        if lane_mode not in ("configured", "learned"):
            raise CalibrationError(f"lane_mode {lane_mode!r} is neither configured nor learned")
        for ln in lanes:
            if not (math.isfinite(ln.center_m) and abs(ln.center_m) <= 200.0 and 0.5 <= ln.width_m <= 20.0):
                raise CalibrationError(f"lane {ln} out of range")
        return cls(math.radians(yaw_deg), math.radians(se_deg), votes, lane_mode, lanes, saved)


def _direction(name: object) -> int:
    if name == "away":
        return 1
    if name == "toward":
        return -1
    raise ValueError(f"direction {name!r} is neither away nor toward")


def load_calibration(path: str | os.PathLike) -> Calibration | None:
    """The calibration saved at ``path``; None when there is none yet. Raises :class:`CalibrationError`
    when the file exists but cannot be used."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as e:
        raise CalibrationError(f"cannot read {p}: {e}") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise CalibrationError(f"{p} is not JSON: {e}") from None
    return Calibration.from_json(doc)


class CalibrationWriter:
    """Writes :class:`Calibration` documents to one file on a background thread, newest first.

    :meth:`submit` never blocks on the disk (it hands the state over under a lock); :meth:`close`
    writes what is pending and joins the thread. ``saved`` and ``errors`` count writes."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.saved = 0
        self.errors = 0
        self._pending: Calibration | None = None
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name="calibration-writer", daemon=True)
        self._thread.start()

    def submit(self, cal: Calibration) -> None:
        with self._lock:
            self._pending = cal
        self._wake.set()

    def close(self, timeout_s: float = 5.0) -> None:
        self._closing = True
        self._wake.set()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning("calibration writer did not finish within %.1f s (%s)", timeout_s, self.path)

    def _run(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            closing = self._closing  # read before taking the state: what was submitted before close() is written
            with self._lock:
                cal, self._pending = self._pending, None
            if cal is not None:
                self._write(cal)
            if closing:
                return

    def _write(self, cal: Calibration) -> None:
        tmp = self.path.with_name(self.path.name + ".tmp")
        doc = cal.to_json()
        if not doc["saved_unix_s"]:
            doc["saved_unix_s"] = round(time.time(), 3)
        try:
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump(doc, f, indent=1)
                f.write("\n")
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
            self.saved += 1
        except OSError as e:
            self.errors += 1
            if self.errors == 1 or self.errors % 10 == 0:
                log.warning("cannot save the traffic calibration to %s (%d failures): %s", self.path, self.errors, e)
            try:
                tmp.unlink()
            except OSError:
                pass
