"""Backends chosen by a URL, imported lazily (pySerial ``serial_for_url``, python-can ``BACKENDS``).

``open_radar("sim://simo?scenario=highway4&seed=1")`` looks the scheme up in :data:`BACKENDS`,
imports only that backend's module, parses the options it declares and returns an *unopened*
source. A machine without pyserial can still run ``sim://`` and ``replay://``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Callable
from urllib.parse import parse_qsl, urlsplit

from hal.errors import SourceUrlError

#: scheme -> "module:Class"
BACKENDS: dict[str, str] = {
    "sim": "hal.sim:SimSource",
    "replay": "hal.replay:ReplaySource",
    "d2g": "hal.d2g:D2GSource",
}

#: one example per scheme, shown in error messages and ``--help``
EXAMPLES: dict[str, str] = {
    "sim": "sim://simo?scenario=highway4&seed=1  or  sim://d2g?scenario=tavanti-test1",
    "replay": "replay://recordings/run.npz?speed=1  (speed=0: as fast as possible)",
    "d2g": "d2g:///dev/serial/by-id/usb-Infineon_IFX_CDC-if00  or  d2g://auto",
}


@dataclass(frozen=True)
class Option:
    """An option a backend accepts in its URL query."""

    parse: Callable[[str], Any]
    default: Any
    doc: str


@dataclass(frozen=True)
class SourceUrl:
    scheme: str
    target: str
    options: dict[str, str]
    text: str


def parse_bool(text: str) -> bool:
    t = text.strip().lower()
    if t in ("1", "true", "yes", "on"):
        return True
    if t in ("0", "false", "no", "off"):
        return False
    raise ValueError(f"not a boolean: {text!r}")


def parse_url(url: str) -> SourceUrl:
    if "://" not in url:
        raise SourceUrlError(f"{url!r} is not a source URL; expected one of:\n  " + "\n  ".join(EXAMPLES.values()))
    parts = urlsplit(url)
    scheme = parts.scheme.lower()
    target = parts.netloc + parts.path
    opts: dict[str, str] = {}
    for k, v in parse_qsl(parts.query, keep_blank_values=True):
        if k in opts:
            raise SourceUrlError(f"option {k!r} given twice in {url!r}")
        opts[k] = v
    return SourceUrl(scheme, target, opts, url)


def resolve_options(url: SourceUrl, declared: dict[str, Option], overrides: dict[str, Any]) -> dict[str, Any]:
    """Parse ``url.options`` against ``declared``; overrides (already typed) win."""
    unknown = sorted(set(url.options) - set(declared))
    unknown += sorted(k for k in overrides if k not in declared)
    if unknown:
        allowed = ", ".join(f"{k} ({o.doc})" for k, o in declared.items())
        raise SourceUrlError(
            f"unknown option(s) {', '.join(unknown)} for {url.scheme}://; allowed: {allowed}. "
            f"Example: {EXAMPLES.get(url.scheme, '')}"
        )
    out = {k: o.default for k, o in declared.items()}
    for k, v in url.options.items():
        try:
            out[k] = declared[k].parse(v)
        except (ValueError, TypeError) as exc:
            raise SourceUrlError(f"bad value {v!r} for option {k!r} in {url.text!r}: {exc}") from exc
    out.update(overrides)
    return out


def backend_class(scheme: str) -> type:
    try:
        spec = BACKENDS[scheme]
    except KeyError:
        raise SourceUrlError(
            f"unknown source scheme {scheme + '://'!r}; expected one of:\n  " + "\n  ".join(EXAMPLES.values())
        ) from None
    mod_name, cls_name = spec.split(":")
    try:
        module = importlib.import_module(mod_name)
    except ImportError as exc:
        raise SourceUrlError(f"backend {scheme}:// is not available here: {exc}") from exc
    return getattr(module, cls_name)


def open_radar(url: str, **overrides: Any):
    """Create the source a URL names (not yet opened: use it as a context manager).

    Keyword ``overrides`` replace URL options (typed values, e.g. ``realtime=False``).
    """
    parsed = parse_url(url)
    cls = backend_class(parsed.scheme)
    return cls.from_url(parsed, overrides)
