"""Subcommands of ``radar-edge`` (see :mod:`edge.cli`)."""
