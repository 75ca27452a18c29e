"""Compiled post-FFT kernels, built ahead of time from ``edge/native/*.pyx`` (see setup.py).

Each kernel has a numpy reference in the stage that uses it; the stage calls :func:`load` and
falls back to its numpy code when the kernel is missing. ``RADAR_EDGE_KERNELS=0`` forces the
fallback at run time (the tests run both ways).
"""

from __future__ import annotations

import importlib
import logging
import os
from types import ModuleType

log = logging.getLogger(__name__)

#: kernel module names (``edge/native/<name>.pyx``) the product uses
KERNELS: tuple[str, ...] = ("_probe", "_spectra", "_peaks", "_track", "_pairs", "_angles", "_resolve", "_faces", "_aided",
                             "_anglesout", "_traffic", "_dbscan", "_survsig", "_unalias", "_alphabeta", "_aliasfit", "_detect")

_cache: dict[str, ModuleType | None] = {}
_errors: dict[str, str] = {}  # why a kernel did not load (the ImportError's message)
_warned = False


def enabled() -> bool:
    """False when ``RADAR_EDGE_KERNELS=0`` asks for the numpy reference everywhere."""
    return os.environ.get("RADAR_EDGE_KERNELS", "1") != "0"


def load(name: str) -> ModuleType | None:
    """The compiled kernel module ``edge.native.<name>``, or None (disabled or not built)."""
    if not enabled():
        return None
    if name not in _cache:
        try:
            _cache[name] = importlib.import_module(f"{__name__}.{name}")
        except ImportError as exc:  # not built, or built for another Python/numpy
            _cache[name] = None
            _errors[name] = str(exc)
            log.debug("kernel %s not loaded: %s", name, exc)
    return _cache[name]


def missing() -> list[str]:
    """Kernels that are not built (empty when disabled on purpose: nothing is missing then)."""
    if not enabled():
        return []
    return [k for k in KERNELS if load(k) is None]


def error(name: str) -> str | None:
    """Why kernel ``name`` did not load (None when it loaded or was not tried)."""
    return _errors.get(name)


def status() -> str:
    """One line for ``doctor`` and the start-up log."""
    if not enabled():
        return "compiled kernels disabled (RADAR_EDGE_KERNELS=0): numpy reference in use"
    gone = missing()
    if not gone:
        return f"compiled kernels loaded ({len(KERNELS)})"
    return (f"compiled kernels missing ({', '.join(gone)}): numpy fallback in use, slower; "
            "reinstall with a C compiler (apt-get install build-essential python3-dev)")


def warn_if_missing() -> None:
    """Log a warning once per process when a kernel is not built."""
    global _warned
    if not _warned and missing():
        log.warning("%s", status())
        _warned = True


class _KernelName:
    """A loaded kernel module's stand-in in a pickle or a deep copy (a module does not pickle)."""

    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name


class KernelUser:
    """Mixin for a stage or role that keeps a kernel module as an attribute: copies and pickles hold the kernel's
    name and load it again, so a pipeline deep-copies and pickles with its kernels."""

    def __getstate__(self) -> dict:
        return {k: _KernelName(v.__name__) if isinstance(v, ModuleType) else v for k, v in self.__dict__.items()}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update({k: importlib.import_module(v.name) if isinstance(v, _KernelName) else v
                              for k, v in state.items()})
