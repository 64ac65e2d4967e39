"""Shared fixtures: a fresh historian on each backend (SQLite file, PostgreSQL database)."""

from __future__ import annotations

import uuid

import pytest

PG_ADMIN = "postgresql://postgres@127.0.0.1:5432/postgres"


def _pg_reachable() -> bool:
    try:
        import psycopg

        with psycopg.connect(
            "host=127.0.0.1 port=5432 user=postgres dbname=postgres", connect_timeout=3
        ):
            return True
    except Exception:  # noqa: BLE001 - any failure means "no server"
        return False


@pytest.fixture(scope="session")
def pg_available() -> bool:
    return _pg_reachable()


@pytest.fixture
def pg_url(pg_available):
    """URL of a new, empty PostgreSQL database, dropped after the test."""
    if not pg_available:
        pytest.skip("no PostgreSQL server reachable on 127.0.0.1:5432")
    import psycopg

    name = f"diag_test_{uuid.uuid4().hex[:12]}"
    dsn = "host=127.0.0.1 port=5432 user=postgres dbname=postgres"
    with psycopg.connect(dsn, autocommit=True) as c:
        c.execute(f'CREATE DATABASE "{name}"')
    try:
        yield f"postgresql://postgres@127.0.0.1:5432/{name}"
    finally:
        with psycopg.connect(dsn, autocommit=True) as c:
            c.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture(params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def db_url(request, tmp_path):
    """A fresh database URL, once per backend."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'diag.db'}"
    else:
        yield request.getfixturevalue("pg_url")


@pytest.fixture
def historian(db_url, tmp_path):
    """A fresh :class:`historian.Historian` (cold store under tmp_path), once per backend."""
    from historian import Historian

    h = Historian(db_url, cold_dir=tmp_path / "cold")
    try:
        yield h
    finally:
        h.close()
