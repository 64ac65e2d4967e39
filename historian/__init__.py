"""Historian: storage of plant samples (SQLite default, PostgreSQL), import, aligned windows,
Parquet cold store, model registry, experiment log and diagnostic events.

The names below load on first use, so importing a light module of the package (its
errors, tag metadata) does not pull in pandas and SQLAlchemy.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "BAD": "quality",
    "GOOD": "quality",
    "UNCERTAIN": "quality",
    "from_opcua_status": "quality",
    "Historian": "store",
    "quality_table": "window",
}
__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
