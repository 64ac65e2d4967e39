"""The rule-base folder: which file in it is what, and where the shipped example files are,
so the example unit and ``diag benchmark`` work from any folder.

A ``*.toml`` in the folder is a unit file (``NAME.unit.toml``, read by diagnose/unitfile.py),
a diagnostic matrix (``NAME.matrix.toml``) or else a model's rule-base file.

The examples live in the repository's ``rulebases/`` folder (the rule bases, the example
unit and its matrix; :mod:`diag_plugin.examples.build` makes them). A source checkout or an
editable install (what ``make`` sets up) finds them beside the package; an installed wheel
carries them as data files under ``<prefix>/share/diag-plugin/rulebases``
(``[tool.setuptools.data-files]`` in ``pyproject.toml``).
"""

from __future__ import annotations

import sys
from pathlib import Path

#: a unit file's and a diagnostic matrix file's suffix; every other ``*.toml`` is a model
UNIT_SUFFIX = ".unit.toml"
MATRIX_SUFFIX = ".matrix.toml"


def unit_path(name_or_path: str, folder: str | Path = "rulebases") -> Path:
    """A unit name (``valve_unit``) or a path to its file."""
    p = Path(name_or_path)
    if p.name.endswith(".toml") or p.exists():
        return p
    return Path(folder) / f"{name_or_path}{UNIT_SUFFIX}"


def is_model_file(path: Path) -> bool:
    """Rule-base (model) files are the ``*.toml`` that are neither unit nor matrix files."""
    return not path.name.endswith((UNIT_SUFFIX, MATRIX_SUFFIX))


#: the shipped example files
NAMES = ("valve_a", "valve_b", "valve_b2", "damadics_f", "valve_unit", "valve_t4")


def shipped_folder() -> Path | None:
    """The folder of the shipped examples, or None when this installation has none."""
    for folder in (
        Path(__file__).resolve().parents[2] / "rulebases",
        Path(sys.prefix) / "share" / "diag-plugin" / "rulebases",
    ):
        if (folder / "valve_unit.unit.toml").is_file():
            return folder
    return None


def find_shipped(name: str, suffix: str = ".toml") -> Path | None:
    """The shipped file ``NAME`` + ``suffix`` (a bare name, no folder), if there is one."""
    if Path(name).name != name or name.endswith(".toml"):
        return None
    folder = shipped_folder()
    path = folder / f"{name}{suffix}" if folder else None
    return path if path is not None and path.is_file() else None
