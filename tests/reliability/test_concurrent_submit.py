"""Identical job submissions at the same moment (20 threads over the app's HTTP interface, embedded mode on
PostgreSQL with two in-process workers, so two jobs really run at once):

* with one Idempotency-Key: one job (one request creates it, the 19 others replay it), one grasp-set version;
* without a key, same object, gripper and parameters: 20 jobs, every one succeeds with the same grasp set, one new
  version; the jobs that lose the race link to the winner's set and delete the artifacts they wrote (docs/SERVICE.md,
  "Identical submissions")."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import pytest
from services_conftest import PG_URL, Service, pg_values, slug
from sqlalchemy import func, select

from services.common.models import GraspSet, Job, ObjectVersion

pytestmark = [pytest.mark.integration, pytest.mark.slow]

N = 20
SMALL = {"points": 600, "k1": 4, "k2": 2}


@pytest.fixture
def embedded(fresh_pg_schema, tmp_path) -> Iterator[Service]:
    """The API with in-process workers on a schema of its own (embedded mode re-queues every unfinished job of its
    database at start, so it must not share one)."""
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.migrate import upgrade
    from services.common.settings import Settings

    upgrade(Settings(database_url=PG_URL, database_schema=fresh_pg_schema))
    with pg_values(tmp_path, fresh_pg_schema, broker=False, embedded_workers=2) as (values, tokens):
        settings = Settings(**values)
        with TestClient(create_app(settings)) as client:
            yield Service(client, settings, tokens)


def at_once(fn, n: int = N) -> list:  # type: ignore[no-untyped-def]
    with ThreadPoolExecutor(n) as pool:
        return list(pool.map(lambda _: fn(), range(n)))


def blob_files(svc: Service) -> set[str]:
    root = svc.app.state.storage.root
    return {f"sha256/{p.parent.name}/{p.name}" for p in root.rglob("*") if p.is_file()}


def referenced_keys(svc: Service) -> set[str]:
    with svc.app.state.db.session() as s:
        keys = set(s.execute(select(ObjectVersion.file_key)).scalars())
        for gs in s.execute(select(GraspSet)).scalars():
            keys |= {gs.export_key, gs.candidates_key, gs.recording_key}
    return keys


def test_twenty_identical_submissions_make_one_grasp_set_version(embedded):
    svc = embedded
    obj, grip = slug("part"), slug("grip")
    assert svc.upload(obj).status_code == 201
    assert svc.gripper(grip).status_code == 201
    body = {"object": obj, "gripper": grip, "params": SMALL}

    # one Idempotency-Key: one job
    key = f"plant-7-{uuid.uuid4().hex}"
    rs = at_once(lambda: svc.post("/v1/jobs", json=body, headers={"Idempotency-Key": key}))
    assert {r.status_code for r in rs} == {202}
    ids = {r.json()["id"] for r in rs}
    assert len(ids) == 1
    assert sum(r.headers.get("idempotent-replayed") == "true" for r in rs) == N - 1
    (jid,) = ids
    job = svc.wait_job(jid)
    assert job["state"] == "succeeded"
    first_set = job["grasp_set"]

    # no key, same inputs (another seed, so that they have to be computed): 20 jobs, one grasp set
    body["params"] = {**SMALL, "seed": 5}
    rs = at_once(lambda: svc.post("/v1/jobs", json=body))
    assert {r.status_code for r in rs} == {202} and not any(r.headers.get("idempotent-replayed") for r in rs)
    ids = {r.json()["id"] for r in rs}
    assert len(ids) == N
    done = [svc.wait_job(i) for i in ids]
    assert {j["state"] for j in done} == {"succeeded"}
    sets = {j["grasp_set"] for j in done}
    assert len(sets) == 1 and first_set not in sets

    with svc.app.state.db.session() as s:
        assert s.execute(select(func.count()).select_from(Job)).scalar_one() == N + 1
        versions = s.execute(select(GraspSet.id, GraspSet.version).order_by(GraspSet.version)).all()
    assert [tuple(v) for v in versions] == [(first_set, 1), (sets.pop(), 2)]
    newest = svc.get(f"/v1/catalogue/{obj}/{grip}")
    assert newest.status_code == 200 and newest.json()["params"]["seed"] == 5
    # the jobs that computed in vain left nothing behind: every stored blob is referenced
    assert blob_files(svc) == referenced_keys(svc)
