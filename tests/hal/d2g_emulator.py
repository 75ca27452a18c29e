"""The Distance2Go firmware emulator as a source URL, for the conformance suite and the d2g tests."""

from __future__ import annotations

import contextlib
from typing import Iterator

from hw_sim.d2g_device import D2GEmulator

#: trigger period the tests ask for: just above the emulated board's minimum (47.1 ms for 21 chirps)
TEST_PERIOD_MS = 50.0


@contextlib.contextmanager
def emulated_d2g_url(
    scenario: str = "tavanti-test1", seed: int = 1, period_ms: float = TEST_PERIOD_MS, **options: object
) -> Iterator[str]:
    """Run an emulated Distance2Go on a pty and yield ``d2g://PATH?period_ms=..`` for it."""
    query = "&".join(f"{k}={v}" for k, v in {"period_ms": period_ms, **options}.items())
    with D2GEmulator(scenario, seed=seed) as emu:
        yield f"d2g://{emu.port}?{query}"
