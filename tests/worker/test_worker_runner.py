"""The job runner against PostgreSQL with the real core: results, idempotency on redelivery, versions, cancel,
re-clustering, and the .rrd each job writes."""

from __future__ import annotations

import io
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import func, select, update

from services.common.models import Grasp, GraspSet, Job
from services.worker.runner import JobRunner

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # runs the core; the first job compiles its kernels

SMALL = {"points": 600, "k1": 4, "k2": 2}


@pytest.fixture
def runner(pg_service):
    state = pg_service.app.state
    return JobRunner(state.db, state.storage, pg_service.settings)


def submit(svc, obj, grip, params=SMALL, **extra) -> str:
    r = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": params, **extra})
    assert r.status_code == 202, r.text
    return r.json()["id"]


def grasp_sets_of(svc, job_id: str) -> int:
    with svc.app.state.db.session() as s:
        return s.execute(
            select(func.count()).select_from(GraspSet).where(GraspSet.job_id == uuid.UUID(job_id))
        ).scalar_one()


def test_run_stores_result_rows_and_artifacts(pg_service, runner, pair):
    obj, grip = pair
    jid = submit(pg_service, obj, grip)
    assert runner.run(jid) == "succeeded"
    job = pg_service.get(f"/v1/jobs/{jid}").json()
    assert job["state"] == "succeeded" and job["progress"] == 1.0 and job["stage"] == "done"
    assert job["attempts"] == 1 and job["started_at"] and job["finished_at"]
    gs_id = job["grasp_set"]
    export = pg_service.get(f"/v1/grasp-sets/{gs_id}").json()
    assert export["format"] == "graspgen.grasp_set/1" and export["units"] == "m"
    assert export["object"]["name"] == obj and export["object"]["version"] == 1
    assert export["gripper"]["name"] == grip and export["params"]["points"] == 600
    with pg_service.app.state.db.session() as s:
        gs = s.get(GraspSet, gs_id)
        rows = s.execute(select(Grasp).where(Grasp.grasp_set_id == gs_id).order_by(Grasp.rank)).scalars().all()
        assert gs.version == 1 and gs.grasp_count == len(export["grasps"]) == len(rows) > 0
        for row, g in zip(rows, export["grasps"], strict=True):
            assert row.pose == g["pose"] and row.width == g["width"] and row.free_rolls_deg == g["free_rolls_deg"]
            assert [row.cluster_translation, row.cluster_direction] == g["cluster"]
    # the catalogue can be queried without loading files
    wide = pg_service.get(f"/v1/grasp-sets/{gs_id}/grasps?min_width=0.025").json()["items"]
    assert wide and all(g["width"] >= 0.025 for g in wide)
    npz = np.load(io.BytesIO(pg_service.get(f"/v1/grasp-sets/{gs_id}/candidates").content))
    assert npz["contacts"].shape[1:] == (2, 3) and len(npz["medoids"]) == len(export["grasps"])


def test_redelivery_never_makes_a_second_version(pg_service, runner, pair):
    obj, grip = pair
    jid = submit(pg_service, obj, grip, {**SMALL, "seed": 11})
    assert runner.run(jid) == "succeeded"
    counts = pg_service.row_counts()
    assert runner.run(jid) == "succeeded"  # the broker delivered the finished job again
    assert pg_service.row_counts() == counts
    # a worker died mid-run: the row says running; the next delivery runs it and still makes one version
    jid2 = submit(pg_service, obj, grip, {**SMALL, "seed": 12})
    with pg_service.app.state.db.session() as s:
        s.execute(update(Job).where(Job.id == uuid.UUID(jid2)).values(state="running", attempts=1, stage="pairs"))
    assert runner.run(jid2) == "succeeded"
    assert runner.run(jid2) == "succeeded"
    assert grasp_sets_of(pg_service, jid2) == 1
    assert pg_service.get(f"/v1/jobs/{jid2}").json()["attempts"] == 2


def test_a_job_whose_worker_keeps_dying_fails(pg_service, runner, pair):
    obj, grip = pair
    jid = submit(pg_service, obj, grip, {**SMALL, "seed": 13})
    with pg_service.app.state.db.session() as s:
        s.execute(
            update(Job)
            .where(Job.id == uuid.UUID(jid))
            .values(state="running", attempts=pg_service.settings.job_max_attempts)
        )
    assert runner.run(jid) == "failed"
    job = pg_service.get(f"/v1/jobs/{jid}").json()
    assert job["error"]["code"] == "worker-lost" and job["grasp_set"] is None


def test_same_inputs_share_a_version_other_params_make_the_newest(pg_service, runner, pair):
    obj, grip = pair
    first = submit(pg_service, obj, grip)
    runner.run(first)
    same = submit(pg_service, obj, grip, dict(SMALL))  # equal request without an idempotency key: a new job ...
    assert same != first and runner.run(same) == "succeeded"
    a = pg_service.get(f"/v1/jobs/{first}").json()["grasp_set"]
    assert pg_service.get(f"/v1/jobs/{same}").json()["grasp_set"] == a  # ... but the same grasp set
    other = submit(pg_service, obj, grip, {**SMALL, "k1": 6})
    runner.run(other)
    b = pg_service.get(f"/v1/jobs/{other}").json()["grasp_set"]
    assert b != a
    newest = pg_service.get(f"/v1/catalogue/{obj}/{grip}")
    assert newest.headers["content-location"] == f"/v1/grasp-sets/{b}"
    assert newest.json()["params"]["k1"] == 6
    v1 = pg_service.get(f"/v1/catalogue/{obj}/{grip}?version=1")
    assert v1.headers["content-location"] == f"/v1/grasp-sets/{a}" and "immutable" in v1.headers["cache-control"]


def test_cancel_flag_stops_a_running_job_between_stages(pg_service, pair):
    obj, grip = pair
    jid = submit(pg_service, obj, grip, {**SMALL, "seed": 21})
    state = pg_service.app.state

    class CancelDuringPairs(JobRunner):
        def write_progress(self, job_id, stage, progress):  # type: ignore[no-untyped-def]
            if stage == "pairs":
                # what POST /v1/jobs/{id}/cancel does to a running job, at the moment the job reaches "pairs"
                with self.db.session() as s:
                    s.execute(update(Job).where(Job.id == job_id).values(cancel_requested=True))
            return super().write_progress(job_id, stage, progress)

    counts = pg_service.row_counts()
    assert CancelDuringPairs(state.db, state.storage, pg_service.settings).run(jid) == "cancelled"
    job = pg_service.get(f"/v1/jobs/{jid}").json()
    assert job["state"] == "cancelled" and job["stage"] == "pairs" and job["grasp_set"] is None
    assert pg_service.row_counts()["grasp_sets"] == counts["grasp_sets"]


def test_cluster_job_reclusters_into_a_derived_version(pg_service, runner, pair):
    obj, grip = pair
    src_job = submit(pg_service, obj, grip, {**SMALL, "k1": 6, "k2": 2})
    runner.run(src_job)
    src = pg_service.get(f"/v1/jobs/{src_job}").json()["grasp_set"]
    r = pg_service.post("/v1/jobs", json={"kind": "cluster", "grasp_set": src, "params": {"k1": 2, "k2": 1, "seed": 5}})
    assert r.status_code == 202, r.text
    assert r.json()["params"]["points"] == 600 and r.json()["params"]["k1"] == 2
    assert runner.run(r.json()["id"]) == "succeeded"
    job = pg_service.get(f"/v1/jobs/{r.json()['id']}").json()
    assert job["kind"] == "cluster" and job["source_grasp_set"] == src
    summary = next(
        i for i in pg_service.get(f"/v1/grasp-sets?object={obj}").json()["items"] if i["id"] == job["grasp_set"]
    )
    assert summary["derived_from"] == src and summary["version"] == 2
    export = pg_service.get(f"/v1/grasp-sets/{job['grasp_set']}").json()
    assert export["params"]["k1"] == 2 and len(export["grasps"]) <= 2
    bad = pg_service.post("/v1/jobs", json={"kind": "cluster", "grasp_set": src, "params": {"points": 100}})
    assert bad.status_code == 422 and bad.json()["code"] == "invalid-parameter"


def test_each_job_writes_a_loadable_recording(pg_service, runner, pair, tmp_path):
    obj, grip = pair
    jid = submit(pg_service, obj, grip, {**SMALL, "seed": 31})
    runner.run(jid)
    gs = pg_service.get(f"/v1/jobs/{jid}").json()["grasp_set"]
    r = pg_service.get(f"/v1/grasp-sets/{gs}/recording")
    assert r.status_code == 200 and r.headers["etag"] and "immutable" in r.headers["cache-control"]
    rrd = tmp_path / "run.rrd"
    rrd.write_bytes(r.content)
    rerun = Path(sys.executable).with_name("rerun")
    verify = subprocess.run([str(rerun), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    printed = subprocess.run([str(rerun), "rrd", "print", str(rrd)], capture_output=True, text=True, timeout=120)
    assert "/job" in printed.stdout  # the job's metadata beside the core's own logging
    assert f'"{jid}"' in printed.stdout  # one recording per job: its id is the job id
    assert printed.stdout.count("Chunk(") > 2  # and the core logged into it


@pytest.mark.parametrize(
    ("cause", "code"),
    [("soft-limit", "time-limit"), ("other", "internal-error")],
)
def test_a_time_limit_wrapped_by_compiled_code_is_a_time_limit(pg_service, runner, pair, monkeypatch, cause, code):
    """Celery's soft limit is a signal: landing while numba calls back into Python (unpickling a constant), it comes
    out as a SystemError whose cause is SoftTimeLimitExceeded (seen in test_time_limit). That is the time limit, not
    an internal error; a SystemError of any other cause still is one."""
    from celery.exceptions import SoftTimeLimitExceeded

    def execute(inputs, tmp):
        try:
            raise SoftTimeLimitExceeded() if cause == "soft-limit" else ValueError("boom")
        except Exception as inner:
            raise SystemError(
                "CPUDispatcher(<function _assign_parallel>) returned a result with an exception set"
            ) from inner

    monkeypatch.setattr(runner, "_execute", execute)
    obj, grip = pair
    jid = submit(pg_service, obj, grip)
    assert runner.run(jid) == "failed"
    job = pg_service.get(f"/v1/jobs/{jid}").json()
    assert job["state"] == "failed" and job["error"]["code"] == code and job["grasp_set"] is None
