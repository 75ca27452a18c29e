"""Accuracy evaluation against simulator ground truth (DESIGN §6).

Each profile provides ``edge.evaluation.<profile>.evaluate(scenario, *, seed, frames, events, config,
progress) -> dict`` returning the JSON document of DESIGN §6 (fields that do not apply are ``None``).
"""

from __future__ import annotations

import importlib
from typing import Any

from edge.pipeline import BOARD_PROFILE


def evaluate(scenario: str, *, seed: int | None, frames: int | None, events: int | None, config: Any, progress: bool = False) -> dict:
    from hw_sim.scenario import load_scenario_for_eval

    sc = load_scenario_for_eval(scenario, events=events)
    profile = BOARD_PROFILE[sc.board]
    try:
        mod = importlib.import_module(f"edge.evaluation.{profile}")
    except ModuleNotFoundError as exc:
        raise ValueError(f"evaluation of the {profile!r} profile is not available yet") from exc
    return mod.evaluate(sc, seed=seed, frames=frames, events=events, config=config, progress=progress)
