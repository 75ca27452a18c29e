"""Accuracy evaluation against simulator ground truth (DESIGN §6).

Each profile provides ``edge.evaluation.<profile>.evaluate(scenario, *, seed, frames, events, config,
progress) -> dict`` returning the JSON document of DESIGN §6 (fields that do not apply are ``None``).
"""

from __future__ import annotations

import importlib
from typing import Any

from edge.pipeline import BOARD_PROFILE


def evaluate(scenario: str, *, seed: int | None, frames: int | None, events: int | None, config: Any, progress: bool = False,
             record_tracks: str | None = None, patch: dict | None = None) -> dict:
    """``record_tracks``: a path for the traffic layer's input (lane profile only, :mod:`edge.evaluation.track_log`);
    ``patch``: changes to the scenario's TOML document (:func:`hw_sim.scenario.apply_patch`)."""
    from hw_sim.scenario import load_scenario_for_eval

    sc = load_scenario_for_eval(scenario, events=events, patch=patch)
    profile = BOARD_PROFILE[sc.board]
    try:
        mod = importlib.import_module(f"edge.evaluation.{profile}")
    except ModuleNotFoundError as exc:
        raise ValueError(f"evaluation of the {profile!r} profile is not available yet") from exc
    if record_tracks is None:
        return mod.evaluate(sc, seed=seed, frames=frames, events=events, config=config, progress=progress)
    if profile != "lane":
        raise ValueError(f"--record-tracks records the lane profile's traffic layer; {scenario!r} runs the {profile} "
                         "profile")
    return mod.evaluate(sc, seed=seed, frames=frames, events=events, config=config, progress=progress,
                        record_tracks=record_tracks)
