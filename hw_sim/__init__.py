"""The world outside the box: scenes, targets, IF synthesis and board emulators.

Used by the ``sim://`` HAL backends and by hardware-in-the-loop tests; never imports :mod:`edge`.
"""

from hw_sim.boards import SIMO_BOARD, D2G_BOARD, board_for
from hw_sim.scenario import Scenario, ScenarioError, builtin_names, load_scenario
from hw_sim.scene import CLASSES, GroundTruth, RadarPose, Scene, Target
from hw_sim.simulator import FrameSimulator
from hw_sim import events as _events  # noqa: F401,E402  registers the Distance2Go event generators

__all__ = [
    "CLASSES",
    "D2G_BOARD",
    "FrameSimulator",
    "GroundTruth",
    "RadarPose",
    "SIMO_BOARD",
    "Scenario",
    "ScenarioError",
    "Scene",
    "Target",
    "board_for",
    "builtin_names",
    "load_scenario",
]
