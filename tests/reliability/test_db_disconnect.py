"""Dropped database connections (real `pg_terminate_backend` on the service's own backends, found by the pids its
engine opened): the API answers requests in flight with a 503 problem (a GET is retried once and succeeds), the next
requests succeed, and no 500 appears; the worker retries its final commit, so a job still makes exactly one
grasp-set version."""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator

import pytest
from services_conftest import (
    PG_URL,
    Service,
    _pg_admin,
    pg_values,
    seed_grasp_sets,
    slug,
)
from sqlalchemy import event, func, select

from services.common.db import Database
from services.common.models import Grasp, GraspSet, Job
from services.worker.runner import JobRunner

pytestmark = pytest.mark.integration

SMALL = {"points": 600, "k1": 4, "k2": 2}


class Backends:
    """The PostgreSQL backend pids an engine opened; terminates only those."""

    def __init__(self, engine) -> None:  # type: ignore[no-untyped-def]
        self.pids: set[int] = set()
        event.listen(engine, "connect", lambda dbapi_conn, _rec: self.pids.add(dbapi_conn.info.backend_pid))

    def alive(self) -> list[int]:
        with _pg_admin() as conn:
            rows = conn.execute("SELECT pid FROM pg_stat_activity WHERE pid = ANY(%s)", (sorted(self.pids),))
            return [r[0] for r in rows]

    def terminate(self) -> list[int]:
        """Terminate every live backend of the engine; returns once they are gone (their FATAL error and close have
        been sent to the client)."""
        victims = self.alive()
        with _pg_admin() as conn:
            for pid in victims:
                conn.execute("SELECT pg_terminate_backend(%s, 10000)", (pid,))
        return victims

    def wait_for_lock_waits(self, n: int) -> None:
        end = time.monotonic() + 60
        with _pg_admin() as conn:
            while True:
                waiting = conn.execute(
                    "SELECT count(*) FROM pg_stat_activity WHERE pid = ANY(%s) AND wait_event_type = 'Lock'",
                    (sorted(self.pids),),
                ).fetchone()[0]
                if waiting >= n:
                    return
                assert time.monotonic() < end, f"only {waiting} of {n} requests reached the lock"
                time.sleep(0.02)


@pytest.fixture
def own_service(fresh_pg_schema, tmp_path) -> Iterator[tuple[Service, Backends]]:
    """The API (broker dispatch, no worker) on a schema of its own, with the pids of its engine's connections."""
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.migrate import upgrade
    from services.common.settings import Settings

    upgrade(Settings(database_url=PG_URL, database_schema=fresh_pg_schema))
    with pg_values(tmp_path, fresh_pg_schema) as (values, tokens):
        settings = Settings(**values)
        app = create_app(settings)
        backends = Backends(app.state.db.engine)
        with TestClient(app) as client:
            yield Service(client, settings, tokens), backends


def assert_db_unavailable(r) -> None:  # type: ignore[no-untyped-def]
    assert r.status_code == 503, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    assert body["code"] == "database-unavailable" and body["type"] == "urn:graspgen:problem:database-unavailable"
    assert body["status"] == 503 and int(r.headers["retry-after"]) > 0


def test_requests_after_the_connections_dropped_all_succeed(own_service):
    svc, backends = own_service
    obj, grip = slug("part"), slug("grip")
    seed_grasp_sets(svc, grip, [obj])
    # several pooled connections, all idle now
    for url in (f"/v1/objects/{obj}", f"/v1/catalogue/{obj}/{grip}", "/v1/grasp-sets", "/readyz"):
        assert svc.get(url).status_code == 200
    statuses = []
    for _ in range(2):  # twice: the replacements are as good as the originals
        assert backends.terminate()
        assert not backends.alive()
        # every request after the drop must succeed, reads and writes alike: connections the server closed while
        # idle are replaced at checkout, so not even the first write sees a dead one
        writes = [
            svc.gripper(slug("grip")),
            svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": SMALL}),
            svc.upload(slug("part")),
        ]
        reads = [
            svc.get(u) for u in (f"/v1/objects/{obj}", f"/v1/catalogue/{obj}/{grip}", "/v1/jobs/" + str(uuid.uuid4()))
        ]
        statuses += [r.status_code for r in writes + reads]
        assert [r.status_code for r in writes] == [201, 202, 201], [r.text for r in writes]
        assert [r.status_code for r in reads] == [200, 200, 404]
        assert svc.get("/readyz").json()["checks"]["database"] == "ok"
    assert 500 not in statuses


def test_requests_in_flight_get_retried_others_503_then_next_succeed(own_service):
    svc, backends = own_service
    obj, grip = slug("part"), slug("grip")
    assert svc.upload(obj).status_code == 201
    assert svc.gripper(grip).status_code == 201
    schema = svc.settings.database_schema
    results: dict[str, object] = {}
    before = svc.row_counts()

    def call(name, fn):  # type: ignore[no-untyped-def]
        results[name] = fn()

    with _pg_admin() as locker:
        # hold both tables so that one read and one write are inside a statement when their connections drop
        locker.execute("BEGIN")
        locker.execute(f'LOCK TABLE "{schema}".objects, "{schema}".grippers IN ACCESS EXCLUSIVE MODE')
        threads = [
            threading.Thread(target=call, args=("get", lambda: svc.get(f"/v1/objects/{obj}"))),
            threading.Thread(target=call, args=("post", lambda: svc.gripper(slug("grip")))),
        ]
        for t in threads:
            t.start()
        backends.wait_for_lock_waits(2)
        victims = backends.terminate()
        assert len(victims) >= 2
        threads[1].join(60)
        # the write in flight: 503, nothing stored (its transaction died with the backend); not retried, since a
        # write whose COMMIT was cut off may have been applied
        assert_db_unavailable(results["post"])
        # the read in flight was run again on a new connection, which now waits for the lock like the first
        assert "get" not in results
        locker.execute("COMMIT")
        threads[0].join(60)
    assert results["get"].status_code == 200 and results["get"].json()["name"] == obj
    assert svc.row_counts() == before  # nothing of the failed write was stored
    assert not set(victims) & set(backends.alive())
    # the next requests succeed
    assert svc.gripper(slug("grip")).status_code == 201
    assert svc.get(f"/v1/objects/{obj}").status_code == 200


@pytest.mark.slow
@pytest.mark.parametrize("where", ["insert", "commit"])
def test_worker_retries_its_result_commit_when_the_connection_drops(pg_service, where):
    """The runner's connection is terminated while it inserts the grasp set, or just before its COMMIT reaches the
    server: the result transaction runs again on a new connection and the job ends with one grasp-set version."""
    obj, grip = slug("part"), slug("grip")
    assert pg_service.upload(obj).status_code == 201
    assert pg_service.gripper(grip).status_code == 201
    r = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {**SMALL, "seed": 31}})
    jid = r.json()["id"]

    db = Database(pg_service.settings)
    runner = JobRunner(db, pg_service.app.state.storage, pg_service.settings)
    seen = {"inserts": 0, "killed": 0}

    def kill(conn) -> None:  # type: ignore[no-untyped-def]
        pid = conn.connection.dbapi_connection.info.backend_pid
        with _pg_admin() as admin:
            assert admin.execute("SELECT pg_terminate_backend(%s, 10000)", (pid,)).fetchone()[0]
        seen["killed"] += 1

    @event.listens_for(db.engine, "before_cursor_execute")
    def _before(conn, cursor, statement, params, context, executemany):  # type: ignore[no-untyped-def]
        if statement.lstrip().upper().startswith("INSERT INTO GRASP_SETS"):
            seen["inserts"] += 1
            if where == "insert" and not seen["killed"]:
                kill(conn)

    @event.listens_for(db.engine, "commit")
    def _commit(conn):  # type: ignore[no-untyped-def]
        if where == "commit" and seen["inserts"] and not seen["killed"]:
            kill(conn)

    try:
        assert runner.run(jid) == "succeeded"
    finally:
        db.dispose()
    assert seen["killed"] == 1 and seen["inserts"] == 2  # the first insert (or its COMMIT) was lost, then redone
    job = pg_service.get(f"/v1/jobs/{jid}").json()
    assert job["state"] == "succeeded" and job["attempts"] == 1 and job["error"] is None
    with pg_service.app.state.db.session() as s:
        sets = s.execute(select(GraspSet).where(GraspSet.job_id == uuid.UUID(jid))).scalars().all()
        assert [gs.id for gs in sets] == [job["grasp_set"]]
        gs = sets[0]
        assert gs.version == 1
        assert s.execute(select(func.count()).where(Grasp.grasp_set_id == gs.id)).scalar_one() == gs.grasp_count > 0
        assert s.get(Job, uuid.UUID(jid)).grasp_set_id == gs.id
    storage = pg_service.app.state.storage
    assert all(storage.exists(k) for k in (gs.export_key, gs.candidates_key, gs.recording_key))
    assert pg_service.get(f"/v1/grasp-sets/{gs.id}").status_code == 200
