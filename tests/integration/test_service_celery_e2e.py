"""End to end with real parts: the API (in this process) on PostgreSQL, a real Celery worker (subprocess) on Redis,
and artifacts shared through an S3-compatible server (moto, loopback), as when API and workers run on other hosts.

upload -> gripper -> job -> poll -> grasp set -> catalogue; a second run becomes the newest version; idempotent
submission; cancel; a bulk job with one bad item. Killed workers (the prefork child, the whole worker) are in
tests/reliability/test_worker_kill.py, on a stack whose storage can be checked for leftovers.
"""

from __future__ import annotations

import time

import pytest
from services_conftest import (
    Service,
    box_stl,
    cylinder_stl,
    pg_values,
    settings_env,
    slug,
    start_worker,
    stop_process,
    unique_name,
)

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.xdist_group("celery-e2e")]

SMALL = {"points": 800, "k1": 4, "k2": 2}


@pytest.fixture(scope="module")
def stack(pg_schema, s3_server, tmp_path_factory):
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.settings import Settings

    root = tmp_path_factory.mktemp("celery-e2e")
    with pg_values(
        root,
        pg_schema,
        storage_url=f"s3://{s3_server['bucket']}/{unique_name('e2e')}",
        s3_endpoint_url=s3_server["endpoint"],
        job_soft_time_limit_s=120,
        job_time_limit_s=150,
        broker_visibility_timeout_s=300,
        progress_interval_s=0.1,
    ) as (values, tokens):
        log = root / "worker.log"
        proc = start_worker(settings_env(**values), log)
        try:
            settings = Settings(**values)
            with TestClient(create_app(settings)) as client:
                yield Service(client, settings, tokens), proc, log
        finally:
            stop_process(proc)


@pytest.fixture(scope="module")
def pair(stack):
    svc, _, _ = stack
    obj, grip = slug("ring"), slug("pgn")
    assert svc.upload(obj, cylinder_stl()).status_code == 201
    assert svc.gripper(grip).status_code == 201
    return obj, grip


def test_upload_job_poll_grasp_set_catalogue(stack, pair):
    svc, _, _ = stack
    obj, grip = pair
    r = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": SMALL})
    assert r.status_code == 202
    job = svc.wait_job(r.json()["id"])
    assert job["state"] == "succeeded", job
    gs = svc.get(f"/v1/grasp-sets/{job['grasp_set']}")
    assert gs.status_code == 200 and gs.json()["object"]["name"] == obj and gs.json()["grasps"]
    etag = gs.headers["etag"]
    assert "immutable" in gs.headers["cache-control"]
    assert svc.get(f"/v1/grasp-sets/{job['grasp_set']}", headers={"If-None-Match": etag}).status_code == 304
    # artifacts written by the worker on another "host" are served by the API through S3
    assert svc.get(f"/v1/grasp-sets/{job['grasp_set']}/candidates").content[:2] == b"PK"
    assert len(svc.get(f"/v1/grasp-sets/{job['grasp_set']}/recording").content) > 1000

    cat = svc.get(f"/v1/catalogue?gripper={grip}")
    assert cat.status_code == 200 and [i["object"] for i in cat.json()["items"]] == [obj]
    assert cat.json()["items"][0]["links"]["self"] == f"/v1/grasp-sets/{job['grasp_set']}"
    assert svc.get(f"/v1/catalogue?gripper={grip}", headers={"If-None-Match": cat.headers["etag"]}).status_code == 304
    entry = svc.get(f"/v1/catalogue/{obj}/{grip}")
    assert entry.content == gs.content and entry.headers["etag"] == etag

    # a second run with other parameters becomes the newest version, and the catalogue moves on
    r2 = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {**SMALL, "k1": 3}})
    job2 = svc.wait_job(r2.json()["id"])
    assert job2["state"] == "succeeded" and job2["grasp_set"] != job["grasp_set"]
    assert svc.get(f"/v1/catalogue/{obj}/{grip}").headers["content-location"] == f"/v1/grasp-sets/{job2['grasp_set']}"
    changed = svc.get(f"/v1/catalogue?gripper={grip}", headers={"If-None-Match": cat.headers["etag"]})
    assert changed.status_code == 200 and changed.json()["items"][0]["version"] == 2
    later = svc.get(f"/v1/catalogue?gripper={grip}&updated_since={changed.json()['items'][0]['created_at']}")
    assert later.json()["items"] == []


def test_idempotent_submission_runs_once(stack, pair):
    svc, _, _ = stack
    obj, grip = pair
    body = {"object": obj, "gripper": grip, "params": {**SMALL, "seed": 7}}
    key = {"Idempotency-Key": slug("k")}
    a = svc.post("/v1/jobs", json=body, headers=key).json()
    b = svc.post("/v1/jobs", json=body, headers=key).json()
    assert a["id"] == b["id"]
    assert svc.wait_job(a["id"])["state"] == "succeeded"


def test_cancel_a_running_job(stack, pair):
    svc, _, _ = stack
    obj, grip = pair
    jid = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"points": 20000, "seed": 9}}).json()[
        "id"
    ]
    end = time.monotonic() + 60
    while svc.get(f"/v1/jobs/{jid}").json()["state"] == "queued" and time.monotonic() < end:
        time.sleep(0.02)
    r = svc.post(f"/v1/jobs/{jid}/cancel")
    assert r.status_code == 202 and r.json()["state"] == "running" and r.json()["cancel_requested"]
    job = svc.wait_job(jid)
    assert job["state"] == "cancelled" and job["grasp_set"] is None


def test_bulk_one_bad_item_fails_alone(stack, pair):
    svc, _, _ = stack
    obj, grip = pair
    other = slug("box")
    assert svc.upload(other, box_stl()).status_code == 201
    items = [
        {"object": obj, "gripper": grip, "params": {**SMALL, "seed": 3}},
        {"object": "no-such-part", "gripper": grip},
        {"object": other, "gripper": grip, "params": SMALL},
    ]
    r = svc.post("/v1/bulk-jobs", json={"items": items})
    assert r.status_code == 202
    parent = svc.wait_job(r.json()["id"], timeout=180)
    assert parent["state"] == "failed" and parent["error"]["detail"] == "1 of 3 items failed"  # never "succeeded"
    assert [i["state"] for i in parent["items"]] == ["succeeded", "failed", "succeeded"]
    assert parent["summary"]["succeeded"] == 2 and parent["summary"]["failed"] == 1 and parent["progress"] == 1.0
    assert parent["items"][1]["error"]["code"] == "unknown-object"
    cat = svc.get(f"/v1/catalogue?gripper={grip}").json()
    assert {obj, other} <= {i["object"] for i in cat["items"]}
