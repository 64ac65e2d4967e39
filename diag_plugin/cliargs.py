"""Options that many commands declare alike, from one place (the CLI contract,
docs/reference/cli.md), and the console their tables print to. Only argparse at import
(rich when a command prints): every command module imports it at start-up, and it sits
below every package so that each of them may (``historian/`` keeps its own: it imports
nothing from ``diag_plugin``)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console

#: the width tables are laid out for where stdout is not a terminal (as ``diag tags``)
PIPE_WIDTH = 160


def add_json(p: argparse.ArgumentParser, help: str | None = None) -> None:
    """``--json``: the command's answer as JSON on stdout instead of text (``help``: what
    the document holds, for ``--help``)."""
    p.add_argument("--json", action="store_true", help=help)


def table_console() -> Console:
    """The console a command prints its tables to: the terminal's width, or
    :data:`PIPE_WIDTH` columns into a pipe or a file, where rich would take 80 and cut a
    table's last column short (``diag explain``'s next commands ended in ``…``); a width
    set in ``COLUMNS`` is kept."""
    import os

    from rich.console import Console

    con = Console()
    return con if con.is_terminal or os.environ.get("COLUMNS") else Console(width=PIPE_WIDTH)
