"""Fixtures shared by tests/api, tests/worker and tests/integration (imported by their conftest.py).

Real services only: the PostgreSQL at 127.0.0.1:5432 (database `test`, trust auth) and the Redis at 127.0.0.1:6379.
Every test run and every pytest-xdist worker gets its own PostgreSQL schema and its own Redis key prefix (on a Redis
database number of its own), so parallel workers and parallel runs never see each other's rows or messages.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

PG_URL = os.environ.get("GRASPGEN_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")
REDIS_URL = os.environ.get("GRASPGEN_TEST_REDIS_URL", "redis://127.0.0.1:6379")

_RUN = uuid.uuid4().hex[:8]


def worker_id() -> str:
    return os.environ.get("PYTEST_XDIST_WORKER", "main")


def unique_name(prefix: str) -> str:
    """A PostgreSQL identifier / Redis prefix unique to this run and this xdist worker."""
    return f"{prefix}_{_RUN}_{worker_id()}_{uuid.uuid4().hex[:6]}".lower()


def redis_db() -> int:
    w = worker_id()
    return 8 if w == "main" else 9 + int(w.removeprefix("gw")) % 7


def _pg_admin():  # type: ignore[no-untyped-def]
    import psycopg

    return psycopg.connect(PG_URL.replace("postgresql+psycopg", "postgresql"), autocommit=True)


def pg_available() -> bool:
    try:
        with _pg_admin() as conn:
            conn.execute("SELECT 1")
        return True
    except Exception:
        return False


def create_schema(name: str) -> None:
    with _pg_admin() as conn:
        conn.execute(f'CREATE SCHEMA "{name}"')


def drop_schema(name: str) -> None:
    with contextlib.suppress(Exception), _pg_admin() as conn:
        conn.execute(f'DROP SCHEMA IF EXISTS "{name}" CASCADE')


@pytest.fixture
def fresh_pg_schema() -> Iterator[str]:
    """An empty schema of its own (migration tests)."""
    name = unique_name("ggm")
    create_schema(name)
    try:
        yield name
    finally:
        drop_schema(name)


@pytest.fixture(scope="session")
def pg_schema() -> Iterator[str]:
    """One migrated schema per xdist worker for the whole session; tests create uniquely named rows in it."""
    from services.common.migrate import upgrade
    from services.common.settings import Settings

    name = unique_name("gg")
    create_schema(name)
    upgrade(Settings(database_url=PG_URL, database_schema=name))
    try:
        yield name
    finally:
        drop_schema(name)


@pytest.fixture
def storage_dir(tmp_path: Path) -> Path:
    d = tmp_path / "var"
    d.mkdir()
    return d
