"""Issue 16 (1, 3): X-Request-ID on every response, `GET /metrics` (scope admin) with bounded labels, queue depth from
the real Redis queue, jobs by kind and final state, export cache hits; per-token rate limits (429 + Retry-After)."""

from __future__ import annotations

import re

import pytest
from services_conftest import (
    GRIPPER,
    box_stl,
    pg_values,
    seed_grasp_sets,
    slug,
)

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"


def metric(text: str, name: str, **labels: str) -> float:
    """The value of one sample of the exposition `text` (0 when absent)."""
    for line in text.splitlines():
        if line.startswith("#") or not line.startswith(name):
            continue
        m = re.match(r"^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{(.*)\})? (\S+)$", line)
        if not m or m.group(1) != name:
            continue
        have = dict(re.findall(r'(\w+)="((?:[^"\\]|\\.)*)"', m.group(3) or ""))
        if all(have.get(k) == v for k, v in labels.items()):
            return float(m.group(4))
    return 0.0


def test_request_id_is_kept_when_valid_and_made_otherwise(pg_service):
    r = pg_service.get("/v1/objects", headers={"X-Request-ID": "plant-7.req-0001"})
    assert r.status_code == 200 and r.headers["x-request-id"] == "plant-7.req-0001"
    made = pg_service.get("/v1/objects").headers["x-request-id"]
    assert re.fullmatch(r"[0-9a-f]{32}", made)
    assert pg_service.get("/v1/objects").headers["x-request-id"] != made  # one per request
    for bad in ("x" * 65, "has space", "tab\there", ""):
        rid = pg_service.get("/v1/objects", headers={"X-Request-ID": bad}).headers["x-request-id"]
        assert rid != bad and re.fullmatch(r"[0-9a-f]{32}", rid)


@pytest.mark.parametrize(
    ("method", "url", "who", "status"),
    [
        ("GET", "/v1/objects", None, 401),  # no token
        ("GET", "/v1/objects/does-not-exist", "reader", 404),
        ("GET", "/v1/grasp-sets/0", "reader", 422),
        ("POST", "/v1/grippers", "reader", 403),
        ("GET", "/no/such/route", None, 404),
        ("GET", "/healthz", None, 200),
    ],
)
def test_every_response_carries_the_request_id(pg_service, method, url, who, status):
    headers = {"X-Request-ID": f"rid-{status}"}
    if who:
        headers.update(pg_service.h(who))
    r = pg_service.client.request(method, url, headers=headers, json={} if method == "POST" else None)
    assert r.status_code == status and r.headers["x-request-id"] == f"rid-{status}"


def test_metrics_needs_the_admin_scope(pg_service):
    assert pg_service.client.get("/metrics").status_code == 401
    r = pg_service.get("/metrics", who="writer")
    assert r.status_code == 403 and r.headers["content-type"] == PROBLEM
    ok = pg_service.get("/metrics", who="admin")
    assert ok.status_code == 200 and ok.headers["content-type"].startswith("text/plain")
    assert "graspgen_http_request_duration_seconds_bucket" in ok.text


def test_http_metrics_use_route_templates_not_paths(pg_service):
    before = pg_service.get("/metrics", who="admin").text
    route = "/v1/objects/{name}"
    n0 = metric(before, "graspgen_http_request_duration_seconds_count", method="GET", route=route, status="404")
    names = [slug("nope") for _ in range(3)]
    for name in names:
        assert pg_service.get(f"/v1/objects/{name}").status_code == 404
    after = pg_service.get("/metrics", who="admin").text
    assert metric(after, "graspgen_http_request_duration_seconds_count", method="GET", route=route, status="404") == (
        n0 + 3
    )
    assert not any(name in after for name in names)  # raw paths never become labels
    assert metric(after, "graspgen_http_request_duration_seconds_count", route="unmatched", status="404") >= 0


def test_queue_depth_jobs_by_state_and_cache_hits(pg_service):
    # pg_service sends jobs to a Redis queue that no worker reads: the queue depth is the real list length
    obj, grip = slug("obs"), slug("grip")
    assert pg_service.upload(obj, box_stl()).status_code == 201
    assert pg_service.post("/v1/grippers", json={**GRIPPER, "name": grip}).status_code == 201
    text = pg_service.get("/metrics", who="admin").text
    depth0 = metric(text, "graspgen_queue_depth")
    cancelled0 = metric(text, "graspgen_jobs_finished_total", kind="generate", state="cancelled")
    job = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"points": 500}})
    assert job.status_code == 202, job.text
    text = pg_service.get("/metrics", who="admin").text
    assert metric(text, "graspgen_queue_depth") == depth0 + 1
    assert pg_service.post(f"/v1/jobs/{job.json()['id']}/cancel").json()["state"] == "cancelled"
    text = pg_service.get("/metrics", who="admin").text
    assert metric(text, "graspgen_jobs_finished_total", kind="generate", state="cancelled") == cancelled0 + 1
    assert metric(text, "graspgen_job_duration_seconds_count", kind="generate", state="cancelled") >= 1

    name, gname = slug("cat"), slug("grip")
    seed_grasp_sets(pg_service, gname, [name])
    hits0 = metric(text, "graspgen_export_cache_requests_total", result="hit")
    for _ in range(3):
        assert pg_service.get(f"/v1/catalogue/{name}/{gname}").status_code == 200
    text = pg_service.get("/metrics", who="admin").text
    assert metric(text, "graspgen_export_cache_requests_total", result="hit") >= hits0 + 2


@pytest.fixture()
def limited_service(pg_schema, tmp_path):
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.settings import Settings

    limits = {"rate_limit_per_s": 0.5, "rate_limit_burst": 3}
    with pg_values(tmp_path, pg_schema, **limits) as (values, tokens), TestClient(create_app(Settings(**values))) as c:
        yield c, tokens


def test_rate_limit_per_token_answers_429_with_retry_after(limited_service):
    client, tokens = limited_service
    reader = {"Authorization": f"Bearer {tokens['reader']}"}
    got = [client.get("/v1/objects", headers=reader) for _ in range(5)]
    assert [r.status_code for r in got] == [200, 200, 200, 429, 429]
    refused = got[3]
    assert refused.headers["content-type"] == PROBLEM and refused.json()["code"] == "rate-limited"
    assert int(refused.headers["retry-after"]) >= 1 and refused.headers["x-request-id"]
    # the bucket is per token: another token is not held back by the reader's requests
    writer = {"Authorization": f"Bearer {tokens['writer']}"}
    assert client.get("/v1/objects", headers=writer).status_code == 200
    # no token at all stays a 401 (nothing to count against)
    assert client.get("/v1/objects").status_code == 401


def test_rate_limit_is_off_by_default(pg_service):
    assert pg_service.app.state.rate_limiter is None
    assert all(pg_service.get("/v1/objects").status_code == 200 for _ in range(40))


def test_the_request_id_is_stored_on_the_job_it_submitted(pg_service):
    import uuid

    from services.common.models import Job

    obj, grip = slug("rid"), slug("grip")
    assert pg_service.upload(obj, box_stl()).status_code == 201
    assert pg_service.post("/v1/grippers", json={**GRIPPER, "name": grip}).status_code == 201
    r = pg_service.post(
        "/v1/jobs",
        json={"object": obj, "gripper": grip, "params": {"points": 500}},
        headers={"X-Request-ID": "plant-7-submit-42"},
    )
    assert r.status_code == 202 and r.headers["x-request-id"] == "plant-7-submit-42"
    bulk = pg_service.post("/v1/bulk-jobs", json={"items": [{"object": obj, "gripper": grip}]})
    with pg_service.app.state.db.session() as s:
        assert s.get(Job, uuid.UUID(r.json()["id"])).request_id == "plant-7-submit-42"
        parent = s.get(Job, uuid.UUID(bulk.json()["id"]))
        children = s.query(Job).filter(Job.parent_id == parent.id).all()
        assert parent.request_id == bulk.headers["x-request-id"]
        assert [c.request_id for c in children] == [bulk.headers["x-request-id"]]
    for jid in (r.json()["id"], bulk.json()["id"]):
        pg_service.post(f"/v1/jobs/{jid}/cancel")


def test_an_unhandled_error_is_a_500_problem_with_the_request_id_and_counted(pg_service):
    from fastapi.testclient import TestClient

    def boom() -> None:
        raise RuntimeError("an internal failure")

    app = pg_service.app
    if not any(getattr(r, "path", None) == "/__boom" for r in app.router.routes):
        app.add_api_route("/__boom", boom, include_in_schema=False)
    client = TestClient(app, raise_server_exceptions=False)  # the app's lifespan is pg_service's
    r = client.get("/__boom", headers={"X-Request-ID": "rid-500"})
    assert r.status_code == 500 and r.headers["content-type"] == PROBLEM
    assert r.headers["x-request-id"] == "rid-500"
    text = pg_service.get("/metrics", who="admin").text
    assert metric(text, "graspgen_http_request_duration_seconds_count", route="/__boom", status="500") >= 1
