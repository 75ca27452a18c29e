"""Instructions per frame under valgrind's callgrind (``radar-edge bench --instructions``).

Instruction counts do not depend on the machine's load or clock, so they compare runs across
sessions and machines of one architecture. The frames are synthesised once (seeded) and written as
a recording. A child process replays it under callgrind with instrumentation off (imports and
start-up run at valgrind's plain speed), warms the pipeline and the FFT-only bound up on the first
``warmup`` frames, then, instrumented, runs the next ``frames`` frames and, as a control, zero
frames through the same request path. The difference of the two regions, divided by ``frames``, is
a frame's cost. The parent switches instrumentation, zeroes and dumps through ``vgdb`` monitor commands,
without ptrace (``--max-invoke-ms=0``): the waiting child wakes every few milliseconds, which lets valgrind
serve them, so the count works where ptrace is not allowed (containers).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

_TOTALS = re.compile(r"^(?:totals|summary):\s*(\d+)", re.MULTILINE)


def valgrind_missing() -> str | None:
    """One line saying what to install, or None when valgrind and vgdb are on the PATH."""
    if shutil.which("valgrind") is None or shutil.which("vgdb") is None:
        return "valgrind not found: apt-get install valgrind (bench --instructions needs callgrind)"
    return None


class _Child:
    """A replay child under callgrind, driven line by line over its stdin/stdout."""

    def __init__(self, recording: Path, profile: str, warmup: int, out: Path, config_args: list[str]):
        self.out = out
        cmd = ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}",
               sys.executable, "-m", "edge.bench.instructions", str(recording),
               "--profile", profile, "--warmup", str(warmup), *config_args]
        env = dict(os.environ, PYTHONHASHSEED="0", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                   MKL_NUM_THREADS="1", PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env)
        self.dumps = 0
        self._expect("ready")

    def _expect(self, word: str) -> None:
        line = self.proc.stdout.readline().strip() if self.proc.stdout else ""
        if line != word:
            self.proc.kill()
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise RuntimeError(f"callgrind child: expected {word!r}, got {line!r}: {err.strip()[-800:]}")

    def _control(self, *args: str) -> None:
        r = subprocess.run(["vgdb", f"--pid={self.proc.pid}", "--max-invoke-ms=0", *args], capture_output=True, text=True,
                           timeout=600)
        if r.returncode != 0:
            raise RuntimeError(f"vgdb {' '.join(args)} failed: {r.stderr.strip() or r.stdout.strip()}")

    def region(self, what: str, n: int) -> int:
        """Instructions of the child running ``what`` on its next ``n`` frames (request path included)."""
        self._control("zero")
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"{what} {n}\n")
        self.proc.stdin.flush()
        self._expect("done")
        self._control("dump")
        self.dumps += 1
        text = Path(f"{self.out}.{self.dumps}").read_text(encoding="utf-8", errors="replace")
        m = _TOTALS.findall(text)
        if not m:
            raise RuntimeError("callgrind dump without a total")
        return int(m[-1])

    def start(self) -> None:
        self._control("instrumentation", "on")

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.write("quit\n")
            self.proc.stdin.close()
        self.proc.wait(timeout=600)


def measure(frames_list: list, profile: str, *, warmup: int, frames: int,
            config_args: list[str] | None = None, fft_bound: bool = True) -> dict:
    """Instructions per frame of the pipeline (and of the FFT-only bound) on ``frames_list``, which must hold at
    least ``warmup + 2 * frames`` frames. Returns ``{"pipeline_per_frame", "fft_bound_per_frame", "ratio", ...}``."""
    from hal.recording import RecordingWriter

    if len(frames_list) < warmup + 2 * frames:
        raise ValueError(f"need {warmup + 2 * frames} frames, got {len(frames_list)}")
    missing = valgrind_missing()
    if missing:
        raise RuntimeError(missing)
    from edge.bench import _hooks

    fft_bound = fft_bound and hasattr(_hooks(profile), "fft_bound")
    out: dict = {"warmup_frames": warmup, "frames": frames, "tool": "valgrind --tool=callgrind"}
    with tempfile.TemporaryDirectory() as d:
        w = RecordingWriter(frames_list[0].frontend)
        for f in frames_list[: warmup + 2 * frames]:
            w.add(f)
        rec = w.save(Path(d) / "instructions.npz")
        child = _Child(rec, profile, warmup, Path(d) / "cg.out", list(config_args or []))
        try:
            child.start()
            for what in ("pipeline", "fft") if fft_bound else ("pipeline",):
                busy = child.region(what, frames)
                idle = child.region(what, 0)
                out[f"{'pipeline' if what == 'pipeline' else 'fft_bound'}_per_frame"] = (busy - idle) / frames
        finally:
            child.close()
    if out.get("fft_bound_per_frame"):
        out["ratio"] = out["pipeline_per_frame"] / out["fft_bound_per_frame"]
    return out


def _lines():
    """stdin's lines, waiting in short select() timeouts: a child blocked in one read would never let valgrind
    serve the parent's monitor commands without ptrace."""
    import select

    buf = b""
    fd = sys.stdin.fileno()
    while True:
        ready, _, _ = select.select([fd], [], [], 0.005)
        if not ready:
            continue
        chunk = os.read(fd, 4096)
        if not chunk:
            return
        buf += chunk
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            yield line.decode()


def _child(argv: list[str]) -> int:
    """Load a recording, warm the pipeline and the FFT bound up, then serve ``WHAT N`` requests on stdin."""
    p = argparse.ArgumentParser(prog="python -m edge.bench.instructions")
    p.add_argument("recording")
    p.add_argument("--profile", default="lane")
    p.add_argument("--warmup", type=int, required=True)
    p.add_argument("--config")
    p.add_argument("--set", action="append", default=[])
    args = p.parse_args(argv)

    from edge.bench import _hooks
    from edge.commands.common import config_from_args
    from edge.ops.heap import frozen_heap
    from edge.pipeline import StageTimer, build_pipeline
    from hal import open_radar

    cfg = config_from_args(args)
    with open_radar(f"replay://{args.recording}?speed=0&loop=0") as src:
        frames = list(src)
    fe = frames[0].frontend
    pipe = build_pipeline(args.profile, fe, cfg)
    timer = StageTimer(16)
    hooks = _hooks(args.profile)
    fft = hooks.fft_bound(fe, cfg) if hasattr(hooks, "fft_bound") else None
    with frozen_heap():  # as the frame loop runs its frames
        for f in frames[: args.warmup]:
            pipe.process(f, timer)
            if fft is not None:
                fft(f)
        _serve(pipe, fft, timer, frames, args.warmup)
    pipe.close()
    return 0


def _serve(pipe, fft, timer, frames: list, warmup: int) -> None:
    """Answer ``WHAT N`` requests on stdin: run the next N frames through the pipeline or the FFT bound."""
    nxt = {"pipeline": warmup, "fft": warmup}
    print("ready", flush=True)
    for line in _lines():
        words = line.split()
        if not words or words[0] == "quit":
            break
        what, n = words[0], int(words[1])
        k = nxt[what]
        if what == "pipeline":
            for f in frames[k: k + n]:
                pipe.process(f, timer)
        else:
            for f in frames[k: k + n]:
                fft(f)
        nxt[what] = k + n
        print("done", flush=True)


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))
