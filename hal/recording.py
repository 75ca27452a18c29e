"""Recording format, version 1: one ``.npz`` file (numpy's zip of arrays), documented here.

=========================  ===========================  ==============================================
key                        dtype, shape                 meaning
=========================  ===========================  ==============================================
``format``                 str                          ``"radar-edge-recording"``
``version``                int                          1
``frontend_json``          str                          :meth:`hal.FrontendInfo.to_json` (waveform etc.)
``meta_json``              str                          free-form: scenario, seed, software version
``seq``                    int64 (F,)                   board frame counter
``t_ns``                   int64 (F,)                   host monotonic receive time
``i``, ``q``               int16 (F, n_rx, C, N)        centred ADC counts
``truth_t_s``              float64 (F,)                 simulation time of each frame (simulated only)
``truth_frame``            int32 (T,)                   frame index of each truth row
``truth_id``               int32 (T,)                   target id
``truth_cls``              int8 (T,)                    index into ``truth_classes``
``truth_classes``          str                          JSON list of class names
``truth_lane``             int16 (T,)                   lane index, -1 if none
``truth_position_m``       float64 (T, 3)               reference point, world frame
``truth_velocity_mps``     float64 (T, 3)               velocity, world frame
``truth_range_m``          float64 (T,)                 radar to reference point
``truth_radial_speed_mps`` float64 (T,)                 positive receding
``truth_az_rad``           float64 (T,)                 azimuth in the radar frame
=========================  ===========================  ==============================================

Truth keys are present only for simulated recordings. Readers refuse other formats and newer
versions with :class:`hal.RecordingError`.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from hal.errors import RecordingError
from hal.frame import RawFrame
from hal.waveform import FrontendInfo

FORMAT = "radar-edge-recording"
VERSION = 1
_TRUTH_ARRAYS = ("id", "lane", "position_m", "velocity_mps", "range_m", "radial_speed_mps", "az_rad")


class RecordingWriter:
    """Collects frames in memory and writes one file on :meth:`save` (bounded by ``max_frames``)."""

    def __init__(self, frontend: FrontendInfo, meta: dict[str, Any] | None = None, max_frames: int = 100_000):
        self.frontend = frontend
        self.meta = dict(meta or {})
        self.max_frames = max_frames
        self._frames: list[RawFrame] = []

    def __len__(self) -> int:
        return len(self._frames)

    def add(self, frame: RawFrame) -> None:
        if len(self._frames) >= self.max_frames:
            raise RecordingError(f"recording is full ({self.max_frames} frames)")
        if frame.frontend != self.frontend:
            raise RecordingError("frame taken with a different front-end configuration")
        self._frames.append(frame)

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(".npz")
        fr = self._frames
        arrays: dict[str, Any] = {
            "format": np.array(FORMAT),
            "version": np.array(VERSION),
            "frontend_json": np.array(self.frontend.to_json()),
            "meta_json": np.array(json.dumps(self.meta, sort_keys=True, default=str)),
            "seq": np.array([f.seq for f in fr], dtype=np.int64),
            "t_ns": np.array([f.t_ns for f in fr], dtype=np.int64),
            "i": np.stack([f.i for f in fr]) if fr else np.zeros((0, *self.frontend.frame_shape), np.int16),
            "q": np.stack([f.q for f in fr]) if fr else np.zeros((0, *self.frontend.frame_shape), np.int16),
        }
        if fr and all(f.truth is not None for f in fr):
            arrays.update(_pack_truth([f.truth for f in fr]))
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".part")
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
        tmp.replace(path)
        return path


def _pack_truth(truths: list) -> dict[str, np.ndarray]:
    classes = sorted({c for t in truths for c in t.cls})
    cidx = {c: k for k, c in enumerate(classes)}
    out: dict[str, Any] = {
        "truth_t_s": np.array([t.t_s for t in truths], dtype=np.float64),
        "truth_frame": np.concatenate([np.full(len(t), k, dtype=np.int32) for k, t in enumerate(truths)]),
        "truth_cls": np.array([cidx[c] for t in truths for c in t.cls], dtype=np.int8),
        "truth_classes": np.array(json.dumps(classes)),
    }
    for name in _TRUTH_ARRAYS:
        out[f"truth_{name}"] = np.concatenate([getattr(t, name) for t in truths])
    return out


class Recording:
    """A loaded recording: arrays plus :meth:`frame` and :meth:`truth` accessors."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise RecordingError(f"recording {str(self.path)!r} not found")
        try:
            with np.load(self.path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
            raise RecordingError(f"{self.path}: not a readable .npz recording ({exc})") from exc
        if str(data.get("format", "")) != FORMAT:
            raise RecordingError(f"{self.path}: not a {FORMAT} file")
        ver = int(data.get("version", -1))
        if ver != VERSION:
            raise RecordingError(f"{self.path}: recording version {ver} is not supported (this software reads {VERSION})")
        try:
            self.frontend = FrontendInfo.from_json(str(data["frontend_json"]))
            self.meta = json.loads(str(data["meta_json"]))
            self.seq = data["seq"]
            self.t_ns = data["t_ns"]
            self.i = data["i"]
            self.q = data["q"]
        except (KeyError, ValueError, TypeError) as exc:
            raise RecordingError(f"{self.path}: corrupt recording ({exc})") from exc
        shape = (self.seq.size, *self.frontend.frame_shape)
        if self.i.shape != shape or self.q.shape != shape or self.i.dtype != np.int16:
            raise RecordingError(f"{self.path}: sample arrays {self.i.shape} do not match {shape}")
        self._truth = {k[6:]: v for k, v in data.items() if k.startswith("truth_")}

    def __len__(self) -> int:
        return int(self.seq.size)

    @property
    def has_truth(self) -> bool:
        return bool(self._truth)

    def truth(self, k: int):
        """Ground truth of frame ``k`` as a :class:`hw_sim.scene.GroundTruth`, or ``None``."""
        if not self._truth:
            return None
        from hw_sim.scene import GroundTruth  # lazy: only simulated recordings carry truth

        tr = self._truth
        sel = tr["frame"] == k
        classes = json.loads(str(tr["classes"]))
        return GroundTruth(
            t_s=float(tr["t_s"][k]),
            cls=tuple(classes[c] for c in tr["cls"][sel]),
            **{name: tr[name][sel] for name in _TRUTH_ARRAYS},
        )
