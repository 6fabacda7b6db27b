"""Job submission against PostgreSQL and Redis (no worker consumes here): rows, messages, idempotency, cancel, bulk."""

from __future__ import annotations

import uuid

import pytest
import redis
from services_conftest import REDIS_URL, redis_db, slug

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"


def queued_messages(service) -> int:
    r = redis.Redis.from_url(f"{REDIS_URL}/{redis_db()}")
    try:
        return r.llen(service.settings.broker_key_prefix + service.settings.queue)
    finally:
        r.close()


def test_submit_commits_the_row_and_queues_one_message(pg_service, pair):
    obj, grip = pair
    before = queued_messages(pg_service)
    r = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"points": 500, "k1": 4}})
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/jobs/{job['id']}" and int(r.headers["retry-after"]) > 0
    assert job["state"] == "queued" and job["kind"] == "generate" and job["progress"] == 0
    assert job["object"] == obj and job["object_version"] == 1 and job["gripper"] == grip
    # friction resolved from the gripper: the stored parameters are complete
    assert job["params"] == {
        "points": 500,
        "friction": 0.5,
        "safety_factor": 1.5,
        "rolls": 16,
        "k1": 4,
        "k2": 4,
        "inside": False,
        "collision": "swept",
        "seed": 0,
        "mass_kg": None,
        "density": None,
        "accel": 9.81,
        "hold": "any",
        "position_tolerance": 0.001,
    }
    assert queued_messages(pg_service) == before + 1
    got = pg_service.get(r.headers["location"])
    assert got.status_code == 200 and got.json()["id"] == job["id"] and "retry-after" in got.headers


def test_idempotency_key_replays_and_refuses_reuse(pg_service, pair):
    obj, grip = pair
    body = {"object": obj, "gripper": grip, "params": {"points": 600}}
    key = {"Idempotency-Key": slug("key")}
    first = pg_service.post("/v1/jobs", json=body, headers=key)
    counts = pg_service.row_counts()
    msgs = queued_messages(pg_service)
    again = pg_service.post("/v1/jobs", json=body, headers=key)
    assert again.status_code == 202 and again.json()["id"] == first.json()["id"]
    assert again.headers["idempotent-replayed"] == "true"
    assert pg_service.row_counts() == counts and queued_messages(pg_service) == msgs
    # keys are per token: another client's identical key is another job
    other = pg_service.post("/v1/jobs", json=body, headers=key, who="writer2")
    assert other.status_code == 202 and other.json()["id"] != first.json()["id"]
    counts = pg_service.row_counts()
    reused = pg_service.post("/v1/jobs", json={**body, "params": {"points": 700}}, headers=key)
    assert reused.status_code == 422 and reused.json()["code"] == "idempotency-key-reused"
    assert pg_service.row_counts() == counts


@pytest.mark.parametrize(
    ("body", "code"),
    [
        ({"object": "no-such-object", "gripper": "{grip}"}, "unknown-object"),
        ({"object": "{obj}", "gripper": "no-such-gripper"}, "unknown-gripper"),
        ({"object": "{obj}", "object_version": 7, "gripper": "{grip}"}, "unknown-object"),
        ({"object": "{obj}", "gripper": "{grip}", "params": {"points": 5}}, "invalid-parameter"),
        ({"object": "{obj}", "gripper": "{grip}", "params": {"colour": 1}}, "invalid-parameter"),
        ({"object": "{obj}", "gripper": "{grip}", "params": {"collision": "maybe"}}, "invalid-parameter"),
        ({"object": "{obj}"}, "validation-error"),
        ({"object": "{obj}", "gripper": "{grip}", "extra": 1}, "validation-error"),
        ({"kind": "explode", "object": "{obj}", "gripper": "{grip}"}, "validation-error"),
        ({"kind": "cluster", "grasp_set": 999999999}, "unknown-grasp-set"),
        ({"kind": "cluster"}, "validation-error"),
        ({"kind": "cluster", "grasp_set": 1, "object": "{obj}"}, "validation-error"),
    ],
)
def test_bad_job_requests_are_problems_and_change_nothing(pg_service, pair, body, code):
    obj, grip = pair
    body = {k: (v.format(obj=obj, grip=grip) if isinstance(v, str) else v) for k, v in body.items()}
    before, msgs = pg_service.row_counts(), queued_messages(pg_service)
    r = pg_service.post("/v1/jobs", json=body)
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM, r.text
    assert r.json()["code"] == code
    assert pg_service.row_counts() == before and queued_messages(pg_service) == msgs


def test_unknown_and_malformed_job_ids(pg_service):
    r = pg_service.get(f"/v1/jobs/{uuid.uuid4()}")
    assert r.status_code == 404 and r.headers["content-type"] == PROBLEM
    r = pg_service.get("/v1/jobs/not-a-uuid")
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM
    r = pg_service.post(f"/v1/jobs/{uuid.uuid4()}/cancel")
    assert r.status_code == 404 and r.headers["content-type"] == PROBLEM


def test_cancel_a_queued_job(pg_service, pair):
    obj, grip = pair
    job = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"seed": 3}}).json()
    r = pg_service.post(f"/v1/jobs/{job['id']}/cancel")
    assert r.status_code == 200 and r.json()["state"] == "cancelled" and r.json()["finished_at"]
    assert pg_service.post(f"/v1/jobs/{job['id']}/cancel").status_code == 200  # idempotent


def test_only_the_submitter_or_an_admin_cancels(pg_service, pair):
    obj, grip = pair
    job = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"seed": 4}}).json()
    before = pg_service.row_counts()
    r = pg_service.post(f"/v1/jobs/{job['id']}/cancel", who="writer2")
    assert r.status_code == 403 and r.headers["content-type"] == PROBLEM
    assert pg_service.get(f"/v1/jobs/{job['id']}").json()["state"] == "queued"
    assert pg_service.row_counts() == before
    assert pg_service.post(f"/v1/jobs/{job['id']}/cancel", who="admin").json()["state"] == "cancelled"


def test_bulk_with_a_bad_item_fails_that_item_alone(pg_service, pair):
    obj, grip = pair
    msgs = queued_messages(pg_service)
    items = [
        {"object": obj, "gripper": grip, "params": {"seed": 1}},
        {"object": "no-such-object", "gripper": grip},
        {"object": obj, "gripper": grip, "params": {"points": 1}},
        {"object": obj, "gripper": grip, "params": {"seed": 2}},
    ]
    r = pg_service.post("/v1/bulk-jobs", json={"items": items})
    assert r.status_code == 202, r.text
    parent = r.json()
    assert parent["kind"] == "bulk" and parent["state"] == "running"  # two items are already done (failed)
    assert parent["summary"] == {"queued": 2, "running": 0, "succeeded": 0, "failed": 2, "cancelled": 0, "total": 4}
    states = [(i["index"], i["state"]) for i in parent["items"]]
    assert states == [(0, "queued"), (1, "failed"), (2, "failed"), (3, "queued")]
    assert parent["items"][1]["error"]["code"] == "unknown-object"
    assert parent["items"][2]["error"]["code"] == "invalid-parameter"
    assert queued_messages(pg_service) == msgs + 2  # one group of the two good items
    child = pg_service.get(parent["items"][0]["links"]["self"]).json()
    assert child["parent"] == parent["id"]
    # cancelling the parent cancels every unfinished item
    c = pg_service.post(f"/v1/jobs/{parent['id']}/cancel").json()
    assert c["state"] == "cancelled" and c["summary"]["cancelled"] == 2 and c["summary"]["failed"] == 2


def test_bulk_request_shape_is_validated(pg_service):
    before = pg_service.row_counts()
    for body in ({"items": []}, {"items": [{"object": "a"}]}, {"things": []}, []):
        r = pg_service.post("/v1/bulk-jobs", json=body)
        assert r.status_code == 422 and r.headers["content-type"] == PROBLEM
    assert pg_service.row_counts() == before


def test_broker_down_is_503_and_leaves_no_rows(pg_schema, tmp_path, pg_service, pair):
    from fastapi.testclient import TestClient
    from services_conftest import Service, pg_values

    from services.api.app import create_app
    from services.common.settings import Settings

    with pg_values(tmp_path, pg_schema, broker=False, broker_url="redis://127.0.0.1:1/0") as (values, tokens):
        settings = Settings(**values)
        with TestClient(create_app(settings)) as client:
            svc = Service(client, settings, tokens)
            obj, grip = pair
            before = svc.row_counts()
            r = svc.post("/v1/jobs", json={"object": obj, "gripper": grip})
            assert r.status_code == 503 and r.headers["content-type"] == PROBLEM and "retry-after" in r.headers
            r = svc.post("/v1/bulk-jobs", json={"items": [{"object": obj, "gripper": grip}]})
            assert r.status_code == 503
            assert svc.row_counts() == before
            ready = svc.client.get("/readyz")
            assert ready.status_code == 503 and ready.json()["checks"]["broker"] == "unreachable"
