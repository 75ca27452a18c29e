"""Frame-by-frame simulation of a scenario on a simulated board."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hw_sim.scene import GroundTruth, Scene
from hw_sim.synth import SimBoard, quantize, synthesize_if


@dataclass
class SimFrame:
    index: int
    t_s: float
    i: np.ndarray
    q: np.ndarray
    truth: GroundTruth


class FrameSimulator:
    """Synthesises frame ``n`` of a scene at ``t = n * frame_period`` (deterministic per seed).

    Noise for frame ``n`` comes from a generator seeded with ``(seed, n)``, so frames can be produced
    in any order (a real-time source that skips frames sees exactly the frames it would otherwise).
    """

    def __init__(self, board: SimBoard, scene: Scene, seed: int) -> None:
        self.board = board
        self.scene = scene
        self.seed = seed
        self.period_s = board.frontend.waveform.frame_period_s

    def frame(self, n: int) -> SimFrame:
        t = n * self.period_s
        scat = self.scene.scatterers(t, np.random.default_rng([self.seed, n, 0x5C]))
        rng = np.random.default_rng([self.seed, n, 0x5EED])
        x = synthesize_if(self.board, self.scene.pose, scat, t, rng, seed=self.seed)
        i, q = quantize(x, self.board.frontend.adc_bits)
        return SimFrame(n, t, i, q, self.scene.truth(t))


class FrameCache:
    """A :class:`FrameSimulator` whose frames are kept once made: several evaluations of one recording (a rule
    ablation's baseline and each ablated configuration) read the same frames and pay for the synthesis once."""

    def __init__(self, sim: FrameSimulator) -> None:
        self.sim = sim
        self._frames: dict[int, SimFrame] = {}

    def frame(self, n: int) -> SimFrame:
        f = self._frames.get(n)
        if f is None:
            f = self._frames[n] = self.sim.frame(n)
        return f
