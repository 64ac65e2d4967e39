"""Set-up the benchmark scripts share (not a benchmark itself): the fastest of a few runs,
the ``--dir``/``--check`` options, the scratch folder they make and the exit status
``--check`` asks for."""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


def fastest(fn: Callable[[], Any], runs: int = 3) -> tuple[float, Any]:
    """The shortest wall-clock time of ``runs`` calls of ``fn`` (s) and the last result."""
    best, out = float("inf"), None
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def add_scratch_args(ap: argparse.ArgumentParser, missed: str = "a target") -> None:
    """``--dir`` (the scratch folder's parent) and ``--check`` (exit 1 when ``missed``
    is missed)."""
    ap.add_argument("--dir", default=None, help="scratch folder (default: system temp)")
    ap.add_argument("--check", action="store_true", help=f"exit 1 when {missed} is missed")


@contextmanager
def scratch(prefix: str, parent: str | None = None) -> Iterator[Path]:
    """A new scratch folder below ``parent`` (default: the system's temp folder), removed
    with all it holds when the block ends (also on an error)."""
    path = Path(tempfile.mkdtemp(prefix=prefix, dir=parent))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


def exit_status(met: bool, check: bool) -> int:
    """The script's exit status: 1 when ``--check`` was given and a target was missed."""
    return 0 if met or not check else 1
