"""Artifact storage failing (no space left on the device on the Nth blob write): a job fails with a
`storage-unavailable` problem, makes no grasp-set row and leaves no file behind (neither temp files nor the blobs it
wrote before the failure); an upload gets a 503 problem and makes no row. The fault is injected into the real local
backend's write path, so its own cleanup is what is tested."""

from __future__ import annotations

import errno
import uuid
from pathlib import Path

import pytest
from services_conftest import box_stl, slug
from sqlalchemy import func, select

from services.common.models import GraspSet
from services.common.storage import LocalStorage
from services.worker.runner import JobRunner

pytestmark = pytest.mark.integration

SMALL = {"points": 600, "k1": 4, "k2": 2}


class FullDiskStorage(LocalStorage):
    """LocalStorage whose `fail_on`-th blob write (counting from 1) runs out of space half-way: a partial temp file
    exists when the error is raised, as on a real full disk."""

    def __init__(self, root: Path, fail_on: int) -> None:
        super().__init__(root)
        self.fail_on = fail_on
        self.writes = 0

    def _write(self, key, fill):  # type: ignore[no-untyped-def]
        self.writes += 1
        if self.writes != self.fail_on:
            return super()._write(key, fill)

        def partial(out):  # type: ignore[no-untyped-def]
            out.write(b"\0" * 4096)
            out.flush()
            raise OSError(errno.ENOSPC, "No space left on device")

        return super()._write(key, partial)


def files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()}


@pytest.mark.slow
@pytest.mark.parametrize("fail_on", [1, 2, 3], ids=["export", "candidates", "recording"])
def test_job_fails_cleanly_when_storage_is_full(pg_service, fail_on):
    obj, grip = slug("part"), slug("grip")
    assert pg_service.upload(obj).status_code == 201
    assert pg_service.gripper(grip).status_code == 201
    # a seed of its own: the same box with the same parameters would give byte-identical candidates, which are then
    # already stored (content-addressed) and not written again
    params = {**SMALL, "seed": 40 + fail_on}
    jid = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": params}).json()["id"]
    storage = FullDiskStorage(pg_service.settings.storage_dir, fail_on)
    before = files(storage.root)
    counts = pg_service.row_counts()

    assert JobRunner(pg_service.app.state.db, storage, pg_service.settings).run(jid) == "failed"

    assert storage.writes == fail_on  # the artifacts before the failing one were written, then deleted again
    job = pg_service.get(f"/v1/jobs/{jid}").json()
    assert job["grasp_set"] is None and job["attempts"] == 1
    err = job["error"]
    assert err["code"] == "storage-unavailable" and err["type"] == "urn:graspgen:problem:storage-unavailable"
    assert err["status"] == 503 and "No space left on device" in err["detail"]
    assert str(storage.root) not in err["detail"]  # no server paths in the problem
    with pg_service.app.state.db.session() as s:
        assert s.execute(select(func.count()).where(GraspSet.job_id == uuid.UUID(jid))).scalar_one() == 0
    assert {k: v for k, v in pg_service.row_counts().items() if k != "jobs"} == {
        k: v for k, v in counts.items() if k != "jobs"
    }
    assert files(storage.root) == before  # no temp file, no orphan artifact

    # the storage has room again: the same job submitted anew succeeds
    again = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": params}).json()["id"]
    runner = JobRunner(pg_service.app.state.db, pg_service.app.state.storage, pg_service.settings)
    assert runner.run(again) == "succeeded"
    assert pg_service.get(f"/v1/jobs/{again}").json()["grasp_set"] is not None


def test_upload_gets_503_and_stores_nothing_when_storage_is_full(pg_service):
    state = pg_service.app.state
    full = FullDiskStorage(pg_service.settings.storage_dir, fail_on=1)
    before, counts = files(full.root), pg_service.row_counts()
    name = slug("part")
    part = box_stl((40.0, 30.0, 10.0 + uuid.uuid4().int % 10_000 / 1000))  # bytes not stored yet
    original, state.storage = state.storage, full
    try:
        r = pg_service.upload(name, part)
    finally:
        state.storage = original
    assert r.status_code == 503, r.text
    assert r.headers["content-type"].startswith("application/problem+json") and int(r.headers["retry-after"]) > 0
    body = r.json()
    assert body["code"] == "storage-unavailable" and body["status"] == 503
    assert str(full.root) not in r.text
    assert pg_service.row_counts() == counts and files(full.root) == before
    assert pg_service.get(f"/v1/objects/{name}").status_code == 404
    assert pg_service.upload(name, part).status_code == 201  # the next upload, with room again, succeeds
