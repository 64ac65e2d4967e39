"""Database schema of the historian (SQLAlchemy 2 Core).

Times are stored as integer microseconds since the Unix epoch, UTC (``BIGINT``), in every
table and on every backend: exact comparison, cheap range scans, and the same code path for
SQLite and PostgreSQL. The Python API speaks tz-aware UTC :class:`pandas.Timestamp`.
"""

from __future__ import annotations

from sqlalchemy import (
    BigInteger,
    Column,
    Float,
    Integer,
    MetaData,
    SmallInteger,
    String,
    Table,
    Text,
    UniqueConstraint,
)

metadata = MetaData()

#: one row per measured or computed signal
tags = Table(
    "tags",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("name", String(200), nullable=False, unique=True),
    Column("unit", String(50)),
    Column("lo", Float),  # nominal range, engineering units
    Column("hi", Float),
    Column("description", Text),
    Column("source", String(200)),
)

#: narrow sample table; (tag_id, ts) is the primary key, so a re-sent batch never duplicates.
#: No foreign key to ``tags`` on purpose: it would cost a lookup per row on bulk ingest.
samples = Table(
    "samples",
    metadata,
    Column("tag_id", Integer, primary_key=True, autoincrement=False),
    Column("ts", BigInteger, primary_key=True, autoincrement=False),  # µs since epoch, UTC
    Column("value", Float),
    Column("quality", SmallInteger, nullable=False, server_default="0"),
    sqlite_with_rowid=False,
)

#: rule-base versions of a model (the text as the expert saw it)
model_versions = Table(
    "model_versions",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("name", String(200), nullable=False),
    Column("version", String(100), nullable=False),
    Column("rulebase_text", Text),
    Column("created_at", BigInteger, nullable=False),
    UniqueConstraint("name", "version", name="uq_model_version"),
)

#: one row per training / validation run
experiments = Table(
    "experiments",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("model", String(200), nullable=False, index=True),
    Column("version", String(100)),
    Column("inputs", Text, nullable=False),  # JSON list of input specs
    Column("data_from", BigInteger),
    Column("data_to", BigInteger),
    Column("metrics", Text, nullable=False),  # JSON object
    Column("notes", Text),
    Column("created_at", BigInteger, nullable=False),
)

#: diagnoses reported by units (NE 107 status, fault certainty)
diag_events = Table(
    "diag_events",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("ts", BigInteger, nullable=False, index=True),
    Column("unit", String(200), nullable=False, index=True),
    Column("fault", String(200)),
    Column("status", SmallInteger, nullable=False, server_default="0"),
    Column("certainty", Float),
    Column("severity", Integer),
    Column("quality", SmallInteger, nullable=False, server_default="0"),
    Column("message", Text),
)

#: months rolled to the Parquet cold store
cold_segments = Table(
    "cold_segments",
    metadata,
    Column("month", String(7), primary_key=True),  # 'YYYY-MM'
    Column("path", Text, nullable=False),  # file name inside the cold directory
    Column("rows", BigInteger, nullable=False),
    Column("ts_min", BigInteger),
    Column("ts_max", BigInteger),
    Column("created_at", BigInteger, nullable=False),
)

#: settings of the database itself, e.g. where its rolled months are (``cold_dir``)
settings = Table(
    "settings",
    metadata,
    Column("key", String(100), primary_key=True),
    Column("value", Text),
)
