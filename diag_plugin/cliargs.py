"""Options that many commands declare alike, from one place (the CLI contract,
docs/reference/cli.md). Only argparse: every command module imports it at start-up, and it
sits below every package so that each of them may (``historian/`` keeps its own: it imports
nothing from ``diag_plugin``)."""

from __future__ import annotations

import argparse


def add_json(p: argparse.ArgumentParser, help: str | None = None) -> None:
    """``--json``: the command's answer as JSON on stdout instead of text (``help``: what
    the document holds, for ``--help``)."""
    p.add_argument("--json", action="store_true", help=help)
