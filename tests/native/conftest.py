"""Helpers of the compiled-kernel tests: a kernel that is not built fails its tests, except under
``RADAR_EDGE_KERNELS=0`` (the fallback run of CI), where they skip with that reason."""

from __future__ import annotations

import pytest

from edge import native


def require_kernel(name: str):
    """The compiled module ``edge.native.<name>``; skips under ``RADAR_EDGE_KERNELS=0``, fails when not built."""
    if not native.enabled():
        pytest.skip("RADAR_EDGE_KERNELS=0: compiled kernels disabled, the numpy reference runs")
    mod = native.load(name)
    if mod is None:
        pytest.fail(f"kernel {name} is not built ({native.error(name)}); build it with "
                    "`python setup.py build_ext --inplace` or `pip install -e .` (needs a C compiler)")
    return mod
