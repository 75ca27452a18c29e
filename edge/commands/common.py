"""Argument helpers shared by subcommands."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from edge.config import Config, load_config, parse_set_option


class StartupError(RuntimeError):
    """A configured output or resource cannot be started (the CLI prints it as one line, exit 2)."""


def add_config_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", help="TOML configuration file (defaults < file < environment < --set)")
    p.add_argument(
        "--set",
        metavar="SECTION.KEY=VALUE",
        action="append",
        default=[],
        help="override one configuration value, e.g. --set loop.error_policy=stop (repeatable)",
    )


def config_from_args(args: argparse.Namespace, extra: dict | None = None) -> Config:
    overrides = dict(parse_set_option(s) for s in args.set)
    overrides.update(extra or {})
    return load_config(args.config, overrides=overrides)


def emit_json(doc: dict, path: str | None) -> None:
    """Write ``doc`` as indented JSON to ``path`` (creating its folder), or print it when no path is given."""
    text = json.dumps(doc, indent=2)
    if path:
        out = Path(path)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n", encoding="utf-8")
    else:
        print(text)
