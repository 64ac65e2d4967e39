"""Historian: storage of plant samples (SQLite default, PostgreSQL), import, aligned windows,
Parquet cold store, model registry, experiment log and diagnostic events."""

from .quality import BAD, GOOD, UNCERTAIN, from_opcua_status
from .store import Historian
from .window import quality_table

__all__ = ["BAD", "GOOD", "UNCERTAIN", "Historian", "from_opcua_status", "quality_table"]
