"""Configuration: one TOML file -> typed frozen dataclasses, validated once.

Every component declares its parameters as a frozen dataclass whose fields carry metadata::

    @dataclass(frozen=True)
    class CfarConfig:
        pfa: float = field(default=1e-6, metadata={"doc": "false-alarm probability", "min": 1e-12, "max": 0.1})
        mode: str = field(default="os", metadata={"doc": "...", "choices": ("os", "ca")})

Defaults are the papers' parameters. Sections are registered in :data:`SECTIONS` under a dotted
name (``loop``, ``pipeline.minimal``, ``outputs.modbus``...), which is also the TOML table. Values
are layered with one precedence: defaults < file < environment (``RADAR_EDGE__LOOP__ERROR_POLICY=stop``,
double underscores between parts) < command line (``--set loop.error_policy=stop``). A bad value is
a :class:`ConfigError` naming the key and what is allowed. The resolved configuration is logged.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import logging
import os
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

log = logging.getLogger(__name__)

ENV_PREFIX = "RADAR_EDGE__"


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of range; the message names the key."""


@dataclass(frozen=True)
class SourceConfig:
    url: str = field(
        default="sim://simo?scenario=highway4&loop=1",
        metadata={"doc": "radar source URL (sim://, replay://, d2g://)"},
    )
    read_timeout_s: float = field(
        default=1.0, metadata={"unit": "s", "doc": "stall detection: no frame for this long", "min": 0.05, "max": 60.0}
    )


@dataclass(frozen=True)
class LoopConfig:
    profile: str = field(
        default="auto",
        metadata={"doc": "pipeline: auto picks by board (simo -> lane, d2g -> surveillance)",
                  "choices": ("auto", "lane", "surveillance", "minimal")},
    )
    error_policy: str = field(
        default="reconnect",
        metadata={"doc": "on a source fault: skip the frame, reconnect the source, or stop",
                  "choices": ("skip", "reconnect", "stop")},
    )
    max_consecutive_errors: int = field(
        default=50, metadata={"doc": "stop after this many failed frames in a row", "min": 1, "max": 1_000_000}
    )
    reconnect_backoff_s: float = field(
        default=1.0, metadata={"unit": "s", "doc": "first wait before reopening a source (doubles, max 30 s)",
                               "min": 0.0, "max": 60.0}
    )
    stats_window_frames: int = field(
        default=4096, metadata={"doc": "frames kept for p50/p99 timing (ring buffer)", "min": 16, "max": 1_000_000}
    )
    health_period_s: float = field(
        default=0.5, metadata={"unit": "s", "doc": "health published at least this often, frames or not",
                               "min": 0.05, "max": 10.0}
    )
    cpus: tuple[int, ...] = field(
        default=(),
        metadata={"doc": "CPUs the frame loop is pinned to, e.g. [3] on a Raspberry Pi 4 with "
                         "outputs.modbus.cpus = [0, 1, 2], so that Modbus polling never takes the loop's core "
                         "(Linux; empty = not pinned)", "min": 0, "max": 1023},
    )


#: dotted section name -> "module:Class" (imported lazily so a section's module loads only when used)
SECTIONS: dict[str, str] = {
    "source": "edge.config:SourceConfig",
    "loop": "edge.config:LoopConfig",
    "pipeline.minimal": "edge.pipelines.minimal:MinimalConfig",
    "pipeline.lane": "edge.pipelines.lane:LaneConfig",
    "track.pdaf": "edge.track.config:PdafConfig",
    "traffic": "edge.traffic.config:TrafficConfig",
    "outputs.modbus": "edge.outputs.config:ModbusConfig",
    "outputs.can": "edge.outputs.config:CanConfig",
    "outputs.failsafe": "edge.outputs.config:FailsafeConfig",
    "ops.recorder": "edge.ops.recorder:RecorderConfig",
    "pipeline.surveillance": "edge.pipelines.surveillance:SurveillanceConfig",
    "track.alphabeta": "edge.track.alphabeta:AlphaBetaConfig",
    "track.events": "edge.track.events:EventConfig",
    "classify.features": "edge.classify.features:FeatureConfig",
    "classify.knn": "edge.classify.knn:KnnConfig",
    "classify.onnx": "edge.classify.onnx_runtime:OnnxConfig",
}


def _section_class(name: str) -> type:
    mod, cls = SECTIONS[name].split(":")
    return getattr(importlib.import_module(mod), cls)


def _convert(key: str, value: Any, ftype: Any) -> Any:
    """Convert a TOML/env/CLI value to the field's type (strings from env/CLI are parsed)."""
    origin = typing.get_origin(ftype)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(ftype) if a is not type(None)]
        if value is None or (isinstance(value, str) and value.lower() in ("none", "null", "")):
            return None
        return _convert(key, value, args[0])
    if origin is tuple:
        if isinstance(value, str):
            value = json.loads(value) if value.strip().startswith("[") else [v for v in value.split(",") if v]
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        args = typing.get_args(ftype)
        inner = args[0] if args else str
        return tuple(_convert(key, v, inner) for v in value)
    if ftype is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("1", "true", "yes", "on", "0", "false", "no", "off"):
            return value.lower() in ("1", "true", "yes", "on")
        raise ConfigError(f"{key}: expected true or false, got {value!r}")
    if ftype is int:
        if isinstance(value, bool):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        try:
            if isinstance(value, float) and not value.is_integer():
                raise ValueError
            return int(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{key}: expected an integer, got {value!r}") from None
    if ftype is float:
        if isinstance(value, bool):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        try:
            return float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{key}: expected a number, got {value!r}") from None
    if ftype is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    return value


def _validate(key: str, value: Any, meta: Mapping[str, Any]) -> None:
    if value is None:
        return
    lo, hi = meta.get("min"), meta.get("max")
    vals = value if isinstance(value, tuple) else (value,)
    for v in vals:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if (lo is not None and v < lo) or (hi is not None and v > hi):
                raise ConfigError(f"{key} = {v!r} is out of range: allowed [{lo}, {hi}] {meta.get('unit', '')}".rstrip())
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"{key} = {value!r} is not allowed: choose one of {', '.join(map(str, choices))}")


def build_section(name: str, values: Mapping[str, Any]) -> Any:
    cls = _section_class(name)
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ConfigError(f"unknown key(s) {', '.join(f'{name}.{k}' for k in unknown)}; known: {', '.join(sorted(known))}")
    kwargs = {}
    for k, v in values.items():
        key = f"{name}.{k}"
        conv = _convert(key, v, hints[k])
        _validate(key, conv, known[k].metadata)
        kwargs[k] = conv
    try:
        obj = cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name}: {exc}") from exc
    return obj


def _flatten_toml(data: Mapping[str, Any], prefix: str = "") -> dict[str, dict[str, Any]]:
    """Split a TOML dict into {section: {key: value}} using the registered section names."""
    out: dict[str, dict[str, Any]] = {}
    for k, v in data.items():
        name = f"{prefix}{k}"
        if name in SECTIONS:
            if not isinstance(v, dict):
                raise ConfigError(f"[{name}] must be a table")
            sub = {kk: vv for kk, vv in v.items() if not (isinstance(vv, dict) and f"{name}.{kk}" in SECTIONS)}
            out.setdefault(name, {}).update(sub)
            nested = {kk: vv for kk, vv in v.items() if isinstance(vv, dict) and f"{name}.{kk}" in SECTIONS}
            out.update(_flatten_toml(nested, f"{name}."))
        elif isinstance(v, dict) and any(s.startswith(name + ".") for s in SECTIONS):
            out.update(_flatten_toml(v, f"{name}."))
        else:
            raise ConfigError(f"unknown configuration section or key {name!r}; sections: {', '.join(sorted(SECTIONS))}")
    return out


def _split_key(dotted: str) -> tuple[str, str]:
    sec, _, key = dotted.rpartition(".")
    if sec not in SECTIONS:
        raise ConfigError(f"unknown configuration key {dotted!r}; sections: {', '.join(sorted(SECTIONS))}")
    return sec, key


class Config:
    """The resolved configuration: ``cfg.section("loop")`` or ``cfg["pipeline.minimal"]``."""

    def __init__(self, sections: dict[str, Any], origin: dict[str, str]):
        self._sections = sections
        self.origin = origin

    def section(self, name: str) -> Any:
        if name not in self._sections:
            if name not in SECTIONS:
                raise ConfigError(f"unknown configuration section {name!r}")
            self._sections[name] = build_section(name, {})
        return self._sections[name]

    __getitem__ = section

    def as_dict(self) -> dict[str, dict[str, Any]]:
        return {n: dataclasses.asdict(self.section(n)) for n in sorted(SECTIONS)}

    def to_toml(self) -> str:
        lines = []
        for name, values in self.as_dict().items():
            lines.append(f"[{name}]")
            for k, v in values.items():
                lines.append(f"{k} = {json.dumps(v) if not isinstance(v, tuple) else json.dumps(list(v))}")
            lines.append("")
        return "\n".join(lines)


def load_config(
    path: str | Path | None = None,
    *,
    env: Mapping[str, str] | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> Config:
    """Resolve defaults < file < environment < overrides (``{"loop.error_policy": "stop"}``)."""
    layers: dict[str, dict[str, Any]] = {}
    origin: dict[str, str] = {}
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"configuration file {str(p)!r} not found")
        try:
            data = tomllib.loads(p.read_text(encoding="utf-8"))
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
        for sec, vals in _flatten_toml(data).items():
            layers.setdefault(sec, {}).update(vals)
            origin.update({f"{sec}.{k}": str(p) for k in vals})
    env = os.environ if env is None else env
    for name, value in env.items():
        if not name.startswith(ENV_PREFIX):
            continue
        dotted = name[len(ENV_PREFIX):].lower().replace("__", ".")
        sec, key = _split_key(dotted)
        layers.setdefault(sec, {})[key] = value
        origin[f"{sec}.{key}"] = f"env {name}"
    for dotted, value in (overrides or {}).items():
        sec, key = _split_key(dotted)
        layers.setdefault(sec, {})[key] = value
        origin[f"{sec}.{key}"] = "command line"
    sections = {name: build_section(name, vals) for name, vals in layers.items()}
    cfg = Config(sections, origin)
    for name in SECTIONS:  # validate every section once, at start
        cfg.section(name)
    return cfg


def log_config(cfg: Config) -> None:
    for sec, values in cfg.as_dict().items():
        for k, v in values.items():
            src = cfg.origin.get(f"{sec}.{k}", "default")
            log.info("config %s.%s = %r (%s)", sec, k, v, src)


def parse_set_option(text: str) -> tuple[str, str]:
    """``--set section.key=value`` -> (dotted key, raw value)."""
    if "=" not in text:
        raise ConfigError(f"--set expects section.key=value, got {text!r}")
    k, v = text.split("=", 1)
    return k.strip(), v.strip()
