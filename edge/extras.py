"""Optional dependencies and the package extras that install them.

A command that cannot work without one calls :func:`require`, which raises
:class:`MissingExtraError` with one line naming the extra (the CLI prints it and exits 2); a command
that only loses a convenience (a progress bar) asks :func:`available` and says so in one line.
"""

from __future__ import annotations

import importlib
from types import ModuleType

#: module -> the extra of pyproject.toml that installs it
EXTRA_OF: dict[str, str] = {"onnx": "train", "tqdm": "train", "sklearn": "train", "matplotlib": "plot"}


class MissingExtraError(RuntimeError):
    """An optional dependency a command needs is not installed."""


def install_hint(module: str) -> str:
    extra = EXTRA_OF.get(module)
    return f"pip install 'radar-edge[{extra}]'" if extra else f"pip install {module}"


def available(module: str) -> bool:
    """True if ``module`` imports."""
    try:
        importlib.import_module(module)
    except ImportError:
        return False
    return True


def require(module: str, command: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtraError` naming the extra ``command`` needs."""
    try:
        return importlib.import_module(module)
    except ImportError:
        extra = EXTRA_OF.get(module, module)
        raise MissingExtraError(
            f"{command} needs the '{extra}' extra ({module} is not installed): {install_hint(module)}"
        ) from None
