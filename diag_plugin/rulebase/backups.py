"""Numbered backups of a rule-base file (``NAME.toml.~N~``, as GNU ``cp --backup=numbered``
names them), kept before an edit of the model's inputs rewrites the file; ``diag
experiments`` lists them. The ``.~N~`` ending keeps them out of ``diag train --all``.
"""

from __future__ import annotations

import shutil
from pathlib import Path


def keep_backup(path: Path) -> Path:
    """Copy ``path`` to the next numbered backup ``NAME.toml.~N~`` beside it."""
    path = Path(path)
    n = max((_backup_number(p) for p in path.parent.glob(path.name + ".~*~")), default=0) + 1
    target = path.with_name(f"{path.name}.~{n}~")
    shutil.copy2(path, target)
    return target


def backups(path: Path) -> list[Path]:
    """The numbered backups of a model file, oldest first."""
    path = Path(path)
    found = [p for p in path.parent.glob(path.name + ".~*~") if _backup_number(p)]
    return sorted(found, key=_backup_number)


def _backup_number(p: Path) -> int:
    text = p.name.rsplit(".~", 1)[-1].rstrip("~")
    return int(text) if text.isdigit() else 0
