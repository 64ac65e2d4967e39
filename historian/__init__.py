"""Historian: storage of plant samples (SQLite default, PostgreSQL), import, aligned windows,
Parquet cold store, model registry, experiment log and diagnostic events.

The names below load on first use, so importing a light module of the package (its
errors, tag metadata) does not pull in pandas and SQLAlchemy.
"""

from __future__ import annotations

from historian.lazy import lazy

__getattr__, __all__ = lazy(
    __name__,
    """
quality: BAD GOOD UNCERTAIN from_opcua_status
store: Historian
window: quality_table
""",
)
