"""Shared fixtures. Every test that opens a radar source must close it: a leak fails the test."""

from __future__ import annotations

import os
import sys


def _pin_numpy_below_avx512() -> None:
    """The compiled kernels call libm's exp, log, sin...; numpy runs its own SIMD versions of them on AVX-512 CPUs,
    which differ from libm by a few units in the last place, so the kernels' bit-identity tests against the numpy
    reference fail there (and nowhere else: CI, AVX2 and the Pi's arm64). On such CPUs the tests run numpy with its
    AVX-512 dispatch off (NPY_DISABLE_CPU_FEATURES, read when numpy is first imported)."""
    if "numpy" in sys.modules or "NPY_DISABLE_CPU_FEATURES" in os.environ:
        return
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            flags = next((line for line in f if line.startswith("flags")), "")
    except OSError:
        return
    if " avx512f" not in flags:
        return
    from importlib.metadata import version

    try:  # numpy 2.4 groups the x86 features (X86_V4 is AVX-512 F/CD/BW/DQ/VL); older releases name each
        major, minor = (int(p) for p in version("numpy").split(".")[:2])
    except (ValueError, ImportError):
        return
    new = (major, minor) >= (2, 4)
    os.environ["NPY_DISABLE_CPU_FEATURES"] = ("X86_V4 AVX512_ICL AVX512_SPR" if new else
                                              "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX "
                                              "AVX512_CNL AVX512_ICL AVX512_SPR")


_pin_numpy_below_avx512()

import pytest  # noqa: E402

from hal.base import RadarSource  # noqa: E402

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
