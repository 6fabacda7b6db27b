"""Memory guard (issue 16.4) in the service: PostgreSQL, Redis, the real core.

A job whose estimated peak exceeds the budget (GRASPGEN_WORKER_MEMORY_BYTES) is refused at submission with a 422
`memory-limit` problem naming the largest point count that fits, and no row; a job at that count is accepted and
runs. A job accepted under a larger budget is failed by a worker with a smaller one before it runs: `failed` with
the same problem, one attempt, and a redelivery does not run it again.
"""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from services_conftest import (
    GRIPPER,
    Service,
    box_stl,
    pg_values,
    slug,
)

from graspgen import memory
from graspgen.parts import load_part
from services.api.app import create_app
from services.common.settings import Settings
from services.worker.runner import JobRunner

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # runs the core


@pytest.fixture
def make_service(pg_schema, tmp_path):
    made = []
    with pg_values(tmp_path, pg_schema) as (values, tokens):

        def make(budget: int) -> Service:
            settings = Settings(**values, worker_memory_bytes=budget)
            client = TestClient(create_app(settings))
            client.__enter__()
            made.append(client)
            return Service(client, settings, tokens)

        yield make
        for c in made:
            c.__exit__(None, None, None)


@pytest.fixture(scope="module")
def box_probe():
    return memory.probe(load_part(box_stl(), units="mm", file_type="stl"), GRIPPER)


def _pair(svc: Service) -> tuple[str, str]:
    obj, grip = slug("mem"), slug("grip")
    assert svc.upload(obj).status_code == 201
    assert svc.gripper(grip).status_code == 201
    return obj, grip


def test_submission_refuses_a_job_above_the_budget_and_names_a_count_that_fits(make_service, box_probe):
    budget = box_probe.estimate(3000).peak_bytes
    svc = make_service(budget)
    obj, grip = _pair(svc)
    before = svc.row_counts()
    r = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"points": 20_000}})
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    fit = body["max_points"]
    assert body["code"] == "memory-limit" and body["field"] == "points" and 100 <= fit < 20_000
    assert body["budget_bytes"] == budget and body["estimated_peak_bytes"] > budget
    assert f"at most {fit:,} points fit" in body["detail"] and "20,000 points" in body["detail"]
    assert svc.row_counts() == before  # no job row
    # it is the boundary: 100 points more are refused, the count it names is accepted and runs
    over = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"points": fit + 100}})
    assert over.status_code == 422 and over.json()["max_points"] == fit
    ok = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"points": fit, "k1": 4, "k2": 2}})
    assert ok.status_code == 202, ok.text
    state = svc.app.state
    assert JobRunner(state.db, state.storage, svc.settings).run(ok.json()["id"]) == "succeeded"
    assert svc.get(f"/v1/jobs/{ok.json()['id']}").json()["state"] == "succeeded"


def test_the_worker_fails_a_queued_job_above_its_budget_once(make_service, box_probe):
    svc = make_service(64 * 2**30)  # the API's budget admits it
    obj, grip = _pair(svc)
    r = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"points": 20_000}})
    assert r.status_code == 202, r.text
    jid = r.json()["id"]
    small = svc.settings.model_copy(update={"worker_memory_bytes": box_probe.estimate(3000).peak_bytes})
    state = svc.app.state
    runner = JobRunner(state.db, state.storage, small)
    assert runner.run(jid) == "failed"
    job = svc.get(f"/v1/jobs/{jid}").json()
    assert job["state"] == "failed" and job["attempts"] == 1 and job["grasp_set"] is None
    err = job["error"]
    assert err["code"] == "memory-limit" and err["field"] == "points"
    assert 100 <= err["max_points"] < 20_000 and err["budget_bytes"] == small.worker_memory_bytes
    assert f"at most {err['max_points']:,} points fit" in err["detail"]
    # a redelivered message finds the job finished: not run again, still one attempt
    assert runner.run(jid) == "failed"
    assert svc.get(f"/v1/jobs/{jid}").json()["attempts"] == 1


def test_a_suction_job_is_estimated_linear_in_the_points(make_service):
    """A cup keeps at most one candidate per point and approach: the estimate is the base plus the sampling, and the
    largest count that fits is named without a probe run."""
    from tests.grippers import CUP

    budget = memory.BASE_BYTES + memory.BYTES_PER_SAMPLED_POINT * 50_000
    svc = make_service(budget)
    obj, cup = slug("mem"), slug("cup")
    assert svc.upload(obj, box_stl((80.0, 60.0, 30.0))).status_code == 201
    assert svc.post("/v1/grippers", json={**CUP, "name": cup}).status_code == 201
    before = svc.row_counts()
    r = svc.post("/v1/jobs", json={"object": obj, "gripper": cup, "params": {"points": 100_000}})
    assert r.status_code == 422 and r.json()["code"] == "memory-limit", r.text
    assert r.json()["max_points"] == 50_000 and svc.row_counts() == before
    assert svc.post("/v1/jobs", json={"object": obj, "gripper": cup, "params": {"points": 50_000}}).status_code == 202
