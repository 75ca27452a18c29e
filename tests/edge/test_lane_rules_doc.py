"""docs/lane-rules.md accounts for every field of the lane profile's sections (issue 29): each is a rule's knob in
the inventory or is listed under "Parameters that are not rules", and every name listed there is a field."""

from __future__ import annotations

import dataclasses
import fnmatch
import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[2] / "docs" / "lane-rules.md"
APPENDIX = "## Parameters that are not rules"


def _sections() -> dict[str, set[str]]:
    from edge.pipelines.lane import LaneConfig
    from edge.track.config import PdafConfig
    from edge.traffic.config import TrafficConfig

    return {name: {f.name for f in dataclasses.fields(cls)}
            for name, cls in (("pipeline.lane", LaneConfig), ("track.pdaf", PdafConfig), ("traffic", TrafficConfig))}


def _names(text: str) -> set[str]:
    """Backticked identifiers (or patterns like ``resolve_*``), without a section prefix."""
    return {t.rsplit(".", 1)[-1] for t in re.findall(r"`([a-z][a-z0-9_.*]*)`", text)}


def test_every_lane_field_is_a_rule_knob_or_a_listed_parameter():
    text = DOC.read_text()
    assert APPENDIX in text
    names = _names(text)
    unlisted = {sec: sorted(f for f in fields if not any(fnmatch.fnmatchcase(f, n) for n in names))
                for sec, fields in _sections().items()}
    assert not any(unlisted.values()), f"fields in neither the rule inventory nor its parameter list: {unlisted}"


def test_every_listed_parameter_is_a_field():
    text = DOC.read_text()
    section = text[text.index(APPENDIX):].split("\n## ", 1)[0]
    listed = _names("\n".join(line for line in section.splitlines() if line.startswith("|")))
    fields = set().union(*_sections().values())
    assert listed and listed <= fields, sorted(listed - fields)
