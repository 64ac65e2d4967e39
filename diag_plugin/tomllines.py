"""Where a TOML key sits in its file, for ``file:line`` error messages.

``tomllib`` gives values, not positions; the files we read (rule bases, unit files,
``plant.toml``) keep one key per line, so a line scan finds a key's line.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Self


def line_of(
    lines: list[str], section: str, key: str | None = None, nth: int = 0, subtables: bool = False
) -> int:
    """1-based line of ``key =`` in the ``nth`` ``[section]`` or ``[[section]]`` table, or of
    that table's header when ``key`` is None or not in it; 1 when there is no such table.
    ``subtables``: also look in ``[section.sub]`` tables that follow it."""
    header = re.compile(r"^\s*\[\[?\s*" + re.escape(section) + r"\s*\]\]?")
    sub = re.compile(r"^\s*\[\s*" + re.escape(section) + r"\.")
    start, seen = None, -1
    for i, line in enumerate(lines):
        if start is None:
            if header.match(line):
                seen += 1
                if seen == nth:
                    start = i
                    if key is None:
                        return i + 1
            continue
        if re.match(r"^\s*\[", line) and not (subtables and sub.match(line)):
            break
        if key is not None and re.match(r"^\s*" + re.escape(key) + r"\s*=", line):
            return i + 1
    return 1 if start is None else start + 1


_POSITION = re.compile(r"\s*\(?\bat line (\d+),? col(?:umn)? (\d+)\)?\s*$")


def syntax_error(path, exc: Exception, line_offset: int = 0) -> str:
    """``path:line: TOML syntax error: what (column C)`` from a ``tomllib`` or ``tomlkit``
    parse error, with one line number: the parsers end their message with their own ``at
    line L, column C``, which becomes the ``file:line`` in front (``line_offset`` added when
    only part of the file was parsed) and the column at the end."""
    text = str(exc).strip()
    m = _POSITION.search(text)
    if m:
        line, col = int(m.group(1)) + line_offset, int(m.group(2))
        text = f"{text[: m.start()].rstrip()} (column {col})"
    else:
        line = getattr(exc, "line", None)
        line = line + line_offset if isinstance(line, int) else None
    where = f"{path}:{line}" if line is not None else f"{path}"
    return f"{where}: TOML syntax error: {text[:1].lower() + text[1:]}"


def read_text(path: str | Path, error: Callable[[list[str]], Exception]) -> str:
    """The text of a user's file; one that cannot be read raises ``error`` with the message
    ``PATH:0: cannot read: …``."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise error([f"{path}:0: cannot read: {exc}"]) from None


class LinedFile:
    """A user's TOML file read for ``file:line`` problems (the rule-base and the unit file):
    ``cls(text, path)`` reads it, raising ``Error(problems)``; ``error`` records one."""

    Error: Callable[[list[str]], Exception]
    path: Path
    problems: list[str]

    def __init__(self, text: str, path: str | Path) -> None:
        raise NotImplementedError

    @classmethod
    def load(cls, path: str | Path) -> Self:
        """The file at ``path``; one that cannot be read raises ``Error`` naming it."""
        path = Path(path)
        return cls(read_text(path, cls.Error), path)

    def error(self, line: int, msg: str) -> None:
        """Record a problem at ``line`` (1-based) of the file."""
        self.problems.append(f"{self.path}:{line}: {msg}")
