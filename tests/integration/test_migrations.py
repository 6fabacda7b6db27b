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


@pytest.fixture(params=["postgresql", "sqlite"])
def empty_db(request, tmp_path) -> Settings:  # type: ignore[no-untyped-def]
    """The settings of an empty database: a PostgreSQL schema of its own, or a SQLite file."""
    if request.param == "postgresql":
        return Settings(database_url=PG_URL, database_schema=request.getfixturevalue("fresh_pg_schema"))
    return Settings(storage_dir=tmp_path)


def test_upgrade_head_on_an_empty_database_matches_models_and_downgrades(empty_db):
    _check(empty_db)


def test_graspgen_migrate_command_upgrades_the_configured_database(
    fresh_pg_schema, monkeypatch, settings_from_env, capsys
):
    from services.cli import main

    monkeypatch.setenv("GRASPGEN_DATABASE_URL", PG_URL)
    monkeypatch.setenv("GRASPGEN_DATABASE_SCHEMA", fresh_pg_schema)
    assert main(["migrate"]) == 0
    out = capsys.readouterr().out
    assert "is at head" in out and "postgres@" in out
    db = Database(Settings(database_url=PG_URL, database_schema=fresh_pg_schema))
    try:
        assert _diff(db) == []
    finally:
        db.dispose()


def _seed_0001(db: Database) -> dict[str, int]:
    """Rows as a 0001 database holds them: one object with two versions, one gripper; grasp sets for both versions."""
    import uuid
    from datetime import UTC, datetime

    from sqlalchemy import MetaData, insert

    md = MetaData()
    md.reflect(db.engine, only=["objects", "object_versions", "grippers", "gripper_versions", "grasp_sets"])
    t = md.tables
    now = datetime.now(UTC)
    ids: dict[str, int] = {}
    with db.engine.begin() as conn:
        for name in ("bolt", "nut"):
            ids[name] = conn.execute(
                insert(t["objects"]).values(name=name, created_at=now, updated_at=now).returning(t["objects"].c.id)
            ).scalar_one()
        ids["grip"] = conn.execute(
            insert(t["grippers"]).values(name="pgn", created_at=now, updated_at=now).returning(t["grippers"].c.id)
        ).scalar_one()
        gv = conn.execute(
            insert(t["gripper_versions"])
            .values(gripper_id=ids["grip"], version=1, spec={}, spec_sha256="g" * 64, created_at=now)
            .returning(t["gripper_versions"].c.id)
        ).scalar_one()
        ov = {}
        for obj, v in (("bolt", 1), ("bolt", 2), ("nut", 1), ("nut", 2)):
            ov[obj, v] = conn.execute(
                insert(t["object_versions"])
                .values(
                    object_id=ids[obj],
                    version=v,
                    sha256=f"{obj}{v}".ljust(64, "0"),
                    units="mm",
                    format="stl",
                    size_bytes=1,
                    extents=[0.1, 0.1, 0.1],
                    watertight=True,
                    warnings=[],
                    file_key="k",
                    created_at=now,
                )
                .returning(t["object_versions"].c.id)
            ).scalar_one()
        # bolt: v1 for version 1, v2 for version 2 (the current one), v3 for version 1 again; nut: only version 1
        for key, obj, n, ov_v in (
            ("b1", "bolt", 1, 1),
            ("b2", "bolt", 2, 2),
            ("b3", "bolt", 3, 1),
            ("n1", "nut", 1, 1),
        ):
            ids[key] = conn.execute(
                insert(t["grasp_sets"])
                .values(
                    object_id=ids[obj],
                    gripper_id=ids["grip"],
                    version=n,
                    object_version_id=ov[obj, ov_v],
                    gripper_version_id=gv,
                    params={},
                    params_key=key.ljust(64, "0"),
                    job_id=uuid.uuid4().hex if db.is_sqlite else uuid.uuid4(),  # reflected: CHAR(32) on SQLite
                    stats={},
                    grasp_count=0,
                    export_key="e",
                    export_sha256="s" * 64,
                    export_size=1,
                    created_at=now,
                )
                .returning(t["grasp_sets"].c.id)
            ).scalar_one()
    return ids


def _check_data_migration(settings: Settings) -> None:
    from sqlalchemy import select

    from services.common.models import CataloguePair, ChangeCounter, GraspSet

    upgrade(settings, "0001")
    db = Database(settings)
    try:
        ids = _seed_0001(db)
        upgrade(settings)
        with db.session() as s:
            pairs = {p.object_id: p for p in s.execute(select(CataloguePair)).scalars()}
            assert pairs[ids["bolt"]].current_id == ids["b2"]  # the newest set for the newest object version
            assert pairs[ids["nut"]].current_id is None  # only a set for an outdated version: nothing served
            assert {p.released_id for p in pairs.values()} == {None} and not any(p.stale for p in pairs.values())
            seqs = sorted(p.change_seq for p in pairs.values())
            assert seqs == [1, 2] and s.get(ChangeCounter, 1).value == 2
            assert s.execute(select(GraspSet.withdrawn_at)).scalars().all() == [None] * 4
        downgrade(settings, "0001")
        assert {"catalogue_pairs", "catalogue_events", "change_counter"}.isdisjoint(_tables(db))
        with db.engine.connect() as conn:
            cols = {c["name"] for c in inspect(conn).get_columns("grasp_sets")}
            assert "withdrawn_at" not in cols
            assert "mass_kg" not in {c["name"] for c in inspect(conn).get_columns("object_versions")}
            assert "request_id" not in {c["name"] for c in inspect(conn).get_columns("jobs")}
        upgrade(settings)  # the grasp sets survived the round trip and are entered again
        with db.session() as s:
            assert s.get(CataloguePair, (ids["bolt"], ids["grip"])).current_id == ids["b2"]
    finally:
        db.dispose()


def test_0002_fills_the_catalogue_from_existing_sets_and_downgrades(empty_db):
    _check_data_migration(empty_db)
