"""`alembic upgrade head` on an empty database gives exactly the models; `downgrade base` removes them again."""

from __future__ import annotations

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from services_conftest import PG_URL
from sqlalchemy import inspect

from services.common.db import Database
from services.common.migrate import downgrade, upgrade
from services.common.models import Base
from services.common.settings import Settings

pytestmark = pytest.mark.integration


def _diff(db: Database) -> list:
    with db.engine.connect() as conn:
        ctx = MigrationContext.configure(conn, opts={"compare_type": True})
        return compare_metadata(ctx, Base.metadata)


def _tables(db: Database) -> set[str]:
    with db.engine.connect() as conn:
        return set(inspect(conn).get_table_names())


def _check(settings: Settings) -> None:
    upgrade(settings)
    db = Database(settings)
    try:
        assert _tables(db) == set(Base.metadata.tables) | {"alembic_version"}
        assert _diff(db) == []
        downgrade(settings, "base")
        assert _tables(db) == {"alembic_version"}
        upgrade(settings)  # and up again: the downgrade left nothing behind that would clash
        assert _diff(db) == []
    finally:
        db.dispose()


def test_upgrade_head_on_empty_postgresql_matches_models_and_downgrades(fresh_pg_schema):
    _check(Settings(database_url=PG_URL, database_schema=fresh_pg_schema))


def test_upgrade_head_on_empty_sqlite_matches_models_and_downgrades(tmp_path):
    _check(Settings(storage_dir=tmp_path))


def test_graspgen_migrate_command_upgrades_the_configured_database(fresh_pg_schema, monkeypatch, capsys):
    from services.cli import main
    from services.common.settings import get_settings

    monkeypatch.setenv("GRASPGEN_DATABASE_URL", PG_URL)
    monkeypatch.setenv("GRASPGEN_DATABASE_SCHEMA", fresh_pg_schema)
    get_settings.cache_clear()
    try:
        assert main(["migrate"]) == 0
    finally:
        get_settings.cache_clear()
    out = capsys.readouterr().out
    assert "is at head" in out and "postgres@" in out
    db = Database(Settings(database_url=PG_URL, database_schema=fresh_pg_schema))
    try:
        assert _diff(db) == []
    finally:
        db.dispose()
