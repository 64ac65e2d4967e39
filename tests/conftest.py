"""Shared fixtures: a fresh historian on each backend (SQLite file, PostgreSQL database).

With the environment variable CI=true, a test that would skip because a peer or system
part is missing (a skip reason made by ``helpers.require``/``requires``) fails instead:
on CI every part is installed, so such a skip means a broken set-up step.
"""

from __future__ import annotations

import os
import uuid

import pytest
from helpers import MISSING, require, run_diag, trained_valve_file


@pytest.fixture(scope="module")
def anyio_backend():
    """The async tests (``pytest.mark.anyio``) run on asyncio."""
    return "asyncio"


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
    require(
        "PostgreSQL server",
        pg_available,
        "nothing reachable on 127.0.0.1:5432; .ci/sysdeps starts it",
    )
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


#: the tests `make check` leaves out (marked slow here, beside the few marked in their own
#: files): the slowest files and tests of the whole suite's profile (`pytest --durations=60`,
#: 2026-11-28, a busy 2-core machine); `make test` runs them all. A file listed here is slow
#: as a whole (its module fixtures are the cost); a test is listed by its name in its file.
SLOW_FILES: frozenset[str] = frozenset()
SLOW_TESTS: frozenset[str] = frozenset()


def pytest_collection_modifyitems(config, items):
    """Mark the tests of :data:`SLOW_FILES` and :data:`SLOW_TESTS` slow."""
    for item in items:
        name = f"{item.path.name}::{item.originalname}"
        if item.path.name in SLOW_FILES or name in SLOW_TESTS:
            item.add_marker(pytest.mark.slow)


def _ci() -> bool:
    return os.environ.get("CI", "").strip().lower() == "true"


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """With CI=true, a skip for a missing peer/system part is a failure; other skips stay."""
    rep = yield
    if rep.skipped and _ci() and isinstance(rep.longrepr, tuple):
        reason = str(rep.longrepr[2])
        if MISSING in reason:
            rep.outcome = "failed"
            rep.longrepr = (
                f"CI=true: this test would skip, but on CI nothing may be missing: "
                f"{reason.removeprefix('Skipped: ')}"
            )
    return rep


@pytest.fixture(scope="session")
def cli_plant(tmp_path_factory):
    """A folder where ``diag`` simulated a day of the valve (seed 3) and imported it into its
    historian: the start of a user's session, shared by the tests that add models to it
    (each under its own name)."""
    cwd = tmp_path_factory.mktemp("cli_plant")
    for args in (
        ("simulate", "--days", "1", "--seed", "3", "--out", "p.parquet"),
        ("import", "p.parquet"),
    ):
        r = run_diag(cwd, *args)
        assert r.returncode == 0, r.stderr
    return cwd


@pytest.fixture(scope="module")
def trained(request, tmp_path_factory):
    """A model file of the test module's ``METHOD`` trained on a day of the valve, once per
    module, for the tests that only read it: ``(rule base, training result, frame)``."""
    return trained_valve_file(tmp_path_factory.mktemp("trained"), request.module.METHOD)
