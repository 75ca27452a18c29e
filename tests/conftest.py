"""Shared fixtures. Every test that opens a radar source must close it: a leak fails the test."""

from __future__ import annotations

import pytest

from hal.base import RadarSource

_open_sources: list[RadarSource] = []
_orig_open = RadarSource.open


def _tracking_open(self):
    out = _orig_open(self)
    _open_sources.append(self)
    return out


@pytest.fixture(autouse=True)
def no_leaked_sources(monkeypatch):
    monkeypatch.setattr(RadarSource, "open", _tracking_open)
    _open_sources.clear()
    yield
    leaked = [s for s in _open_sources if s.is_open]
    for s in leaked:
        s.close()
    _open_sources.clear()
    if leaked:
        pytest.fail(f"test left {len(leaked)} radar source(s) open: {[type(s).__name__ for s in leaked]}")
