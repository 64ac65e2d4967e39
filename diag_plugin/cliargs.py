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


#: the most false alarms an hour a budget (``--far``) may ask for: one every 10 minutes, the
#: most an operator can handle (EEMUA 191, ISA-18.2); beyond it the thresholds fall to the
#: residuals' noise (``--far 1000`` at 15 s: limits of ±0.0001 % of span, every sample an alarm)
FAR_MAX = 6.0


def check_far(far: float) -> float:
    """``far`` (alarms per hour) when it is a budget: positive, finite, at most
    :data:`FAR_MAX`; otherwise a :class:`~historian.errors.UserError` saying so."""
    from historian.errors import UserError

    if not 0 < far <= FAR_MAX:
        raise UserError(
            f"--far {far:g}: the budget must be a positive rate per hour, at most {FAR_MAX:g} "
            "(an alarm every 10 minutes); e.g. 0.001, about one in six weeks"
        )
    return far
