"""Instructions per lane frame under callgrind: a fixed recording, a warm-up, then measured frames.

    python tools/lane_instructions.py record highway4 out/highway4.npz --frames 240 --seed 1
    python tools/lane_instructions.py measure out/highway4.npz --warmup 120 --frames 60

``measure`` runs the lane pipeline twice under ``valgrind --tool=callgrind`` (the recording's first ``warmup``
frames, then ``warmup + frames``) and prints the difference of the two totals per measured frame: start-up,
imports and warm-up cancel. The same recording gives the same count on any x86-64 machine with the same numpy,
scipy and Python (the count depends on the instruction set of the build, not on the clock).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile


def record(scenario: str, out: str, frames: int, seed: int) -> None:
    import numpy as np

    from hw_sim.scenario import load_scenario
    from hw_sim.simulator import FrameSimulator

    sc = load_scenario(scenario)
    board = sc.sim_board()
    sim = FrameSimulator(board, sc.build_scene(seed), seed)
    fr = [sim.frame(n) for n in range(frames)]
    np.savez_compressed(out, i=np.stack([f.i for f in fr]), q=np.stack([f.q for f in fr]),
                        t_s=np.array([f.t_s for f in fr]), scenario=scenario, seed=seed)


def run(path: str, n: int) -> None:
    """Process the recording's first ``n`` frames (what callgrind counts)."""
    import numpy as np

    from edge.config import load_config
    from edge.evaluation.lane import _installer_config
    from edge.pipeline import StageTimer
    from edge.pipelines.lane import LanePipeline
    from edge.types import RawFrame
    from hw_sim.scenario import load_scenario

    d = np.load(path)
    sc = load_scenario(str(d["scenario"]))
    fe = sc.sim_board().frontend
    pipe = LanePipeline(fe, *_installer_config(load_config(env={}), sc))
    timer = StageTimer(window=16)
    n_tracks = 0
    for k in range(n):
        res = pipe.process(RawFrame(k, int(round(float(d["t_s"][k]) * 1e9)), d["i"][k], d["q"][k], fe, None), timer)
        n_tracks = sum(1 for t in res.tracks if t.confirmed)
    print(json.dumps({"frames": n, "confirmed_tracks_last_frame": n_tracks}))


def _callgrind_total(path: str, n: int) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "cg.out")
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", PYTHONHASHSEED="0")
        subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", sys.executable, __file__,
                        "run", path, str(n)], check=True, env=env, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)
        text = open(out).read()
        m = re.search(r"^(?:summary|totals):\s+(\d+)", text, re.M)
        return int(m.group(1))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("scenario"), r.add_argument("out")
    r.add_argument("--frames", type=int, default=240), r.add_argument("--seed", type=int, default=1)
    m = sub.add_parser("measure")
    m.add_argument("recording"), m.add_argument("--warmup", type=int, default=120)
    m.add_argument("--frames", type=int, default=60)
    u = sub.add_parser("run")
    u.add_argument("recording"), u.add_argument("n", type=int)
    a = p.parse_args()
    if a.cmd == "record":
        record(a.scenario, a.out, a.frames, a.seed)
    elif a.cmd == "run":
        run(a.recording, a.n)
    else:
        lo = _callgrind_total(a.recording, a.warmup)
        hi = _callgrind_total(a.recording, a.warmup + a.frames)
        print(json.dumps({"recording": a.recording, "warmup": a.warmup, "frames": a.frames,
                          "instructions_per_frame": (hi - lo) / a.frames}))


if __name__ == "__main__":
    main()
