"""The job listing (`GET /v1/jobs?state=&kind=&cursor=`) and bulk jobs that report partial failure (issue 15)."""

from __future__ import annotations

import uuid

import pytest
from services_conftest import slug
from sqlalchemy import select

from services.common import jobs as J  # noqa: N812
from services.common.models import Job

pytestmark = pytest.mark.integration


def listing(svc, url: str, who: str) -> list[dict]:
    items, nxt = [], url
    for _ in range(100):
        r = svc.get(nxt, who=who)
        assert r.status_code == 200, r.text
        items += r.json()["items"]
        if r.json()["next_cursor"] is None:
            return items
        nxt = r.json()["links"]["next"]
    raise AssertionError("pagination did not end")


def test_job_listing_pages_newest_first_filters_and_shows_only_the_callers_jobs(pg_service, pair):
    svc = pg_service
    obj, grip = pair
    who = "writer2"
    mine = [
        svc.post("/v1/jobs", who=who, json={"object": obj, "gripper": grip, "params": {"seed": s}}).json()["id"]
        for s in range(5)
    ]
    other = svc.post("/v1/jobs", who="writer", json={"object": obj, "gripper": grip, "params": {"seed": 99}}).json()
    bulk = svc.post("/v1/bulk-jobs", who=who, json={"items": [{"object": obj, "gripper": grip}]}).json()
    assert svc.post(f"/v1/jobs/{mine[1]}/cancel", who=who).json()["state"] == "cancelled"

    items = listing(svc, "/v1/jobs?limit=2", who)
    ids = [i["id"] for i in items]
    # writer2's jobs from every test of the session, newest first; this test's are the newest
    assert ids[:6] == [bulk["id"], *reversed(mine)] and len(ids) == len(set(ids))
    assert other["id"] not in ids and bulk["items"][0]["id"] not in ids  # items are listed in their parent
    assert all(i["created_by"] == who for i in items)
    created = [i["created_at"] for i in items]
    assert created == sorted(created, reverse=True)
    assert items[0]["kind"] == "bulk" and items[1]["object"] == obj and items[1]["links"]["self"].endswith(mine[4])

    cancelled = listing(svc, "/v1/jobs?state=cancelled&limit=1", who)
    assert mine[1] in [i["id"] for i in cancelled] and {i["state"] for i in cancelled} == {"cancelled"}
    assert {i["kind"] for i in listing(svc, "/v1/jobs?kind=bulk", who)} == {"bulk"}
    everyone = {i["id"] for i in listing(svc, "/v1/jobs?limit=50", "admin")}
    assert {*mine, other["id"], bulk["id"]} <= everyone
    assert svc.get("/v1/jobs", who="reader").json()["items"] == []  # the reader submitted nothing

    assert svc.client.get("/v1/jobs").status_code == 401
    for bad in ("state=done", "kind=nope", "cursor=abc", "limit=0"):
        r = svc.get(f"/v1/jobs?{bad}", who=who)
        assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json", bad


def _finish_child(svc, child_id: str, state: str) -> None:
    """What the worker does when an item ends: the child's final state, then the parent's aggregate, in one
    transaction (services/worker/runner.py `_end` / `_commit_result`)."""
    with svc.app.state.db.session() as s:
        job = s.execute(select(Job).where(Job.id == uuid.UUID(child_id)).with_for_update()).scalar_one()
        error = J.problem("internal-error", "Internal error", "boom", status=500) if state == "failed" else None
        J.finish(job, state, error=error)
        s.flush()
        J.refresh_parent(s, job.parent_id)


def test_bulk_job_with_a_failed_item_ends_failed_with_counts(pg_service, pair):
    svc = pg_service
    obj, grip = pair
    items = [
        {"object": obj, "gripper": grip, "params": {"seed": 11}},
        {"object": "no-such-object", "gripper": grip},
        {"object": obj, "gripper": grip, "params": {"seed": 12}},
        {"object": obj, "gripper": grip, "params": {"seed": 13}},
        {"object": obj, "gripper": grip, "params": {"seed": 14}},
    ]
    parent = svc.post("/v1/bulk-jobs", json={"items": items}).json()
    kids = [i["id"] for i in parent["items"]]
    for k in (kids[0], kids[2], kids[3]):
        _finish_child(svc, k, "succeeded")
    mid = svc.get(f"/v1/jobs/{parent['id']}").json()
    assert mid["state"] == "running" and mid["error"] is None
    _finish_child(svc, kids[4], "failed")
    done = svc.get(f"/v1/jobs/{parent['id']}").json()
    assert done["state"] == "failed"
    assert done["summary"] == {"queued": 0, "running": 0, "succeeded": 3, "failed": 2, "cancelled": 0, "total": 5}
    assert done["error"]["code"] == "items-failed" and done["error"]["detail"] == "2 of 5 items failed"
    assert done["error"]["counts"] == {"succeeded": 3, "failed": 2, "cancelled": 0, "total": 5}
    # the stored row says the same (the listing and its state filter read it)
    listed = {i["id"]: i for i in listing(svc, "/v1/jobs?state=failed&kind=bulk&limit=100", "writer")}
    assert listed[parent["id"]]["error"]["detail"] == "2 of 5 items failed"


def test_bulk_job_succeeds_only_when_every_item_succeeded(pg_service, pair):
    svc = pg_service
    obj, grip = pair
    parent = svc.post(
        "/v1/bulk-jobs", json={"items": [{"object": obj, "gripper": grip, "params": {"seed": s}} for s in (21, 22)]}
    ).json()
    for i in parent["items"]:
        _finish_child(svc, i["id"], "succeeded")
    done = svc.get(f"/v1/jobs/{parent['id']}").json()
    assert done["state"] == "succeeded" and done["error"] is None and done["summary"]["succeeded"] == 2


def test_aggregate_states():
    agg = J.Aggregate
    assert agg({"succeeded": 2}, 2, 1.0).state(cancel_requested=False) == "succeeded"
    assert agg({"succeeded": 1, "failed": 1}, 2, 1.0).state(cancel_requested=False) == "failed"
    assert agg({"failed": 2}, 2, 1.0).state(cancel_requested=False) == "failed"
    assert agg({"succeeded": 1, "cancelled": 1}, 2, 1.0).state(cancel_requested=False) == "cancelled"
    assert agg({"failed": 1, "cancelled": 1}, 2, 1.0).state(cancel_requested=True) == "cancelled"
    assert agg({"succeeded": 1, "queued": 1}, 2, 0.5).state(cancel_requested=False) == "running"
    assert agg({"succeeded": 1, "failed": 1, "cancelled": 1}, 3, 1.0).error()["detail"] == (
        "1 of 3 items failed; 1 of 3 items cancelled"
    )
    assert agg({"succeeded": 2}, 2, 1.0).error() is None
    assert agg({"failed": 1, "running": 1}, 2, 0.5).error() is None


@pytest.mark.slow
def test_embedded_default_runs_a_bulk_job_to_failed_lists_it_and_catalogues_the_results(sqlite_service):
    """SQLite and the in-process worker: real jobs, the listing's keyset on SQLite, and the worker's catalogue
    refresh."""
    svc = sqlite_service
    obj, grip = slug("emb"), slug("g")
    assert svc.upload(obj).status_code == 201 and svc.gripper(grip).status_code == 201
    small = {"points": 300, "k1": 2, "k2": 1}
    single = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {**small, "seed": 1}}).json()
    items = [
        {"object": obj, "gripper": grip, "params": {**small, "seed": 2}},
        {"object": obj, "gripper": "no-such-gripper"},
        {"object": obj, "gripper": grip, "params": {**small, "seed": 3}},
    ]
    bulk = svc.post("/v1/bulk-jobs", json={"items": items}).json()
    assert svc.wait_job(single["id"])["state"] == "succeeded"
    done = svc.wait_job(bulk["id"])
    assert done["state"] == "failed" and done["error"]["detail"] == "1 of 3 items failed"
    assert [i["state"] for i in done["items"]] == ["succeeded", "failed", "succeeded"]

    listed = listing(svc, "/v1/jobs?limit=1", "writer")
    assert [i["id"] for i in listed[:2]] == [bulk["id"], single["id"]]
    assert bulk["id"] in {i["id"] for i in listing(svc, "/v1/jobs?state=failed", "writer")}
    assert bulk["id"] not in {i["id"] for i in listing(svc, "/v1/jobs?state=succeeded", "writer")}
    assert svc.get("/v1/jobs", who="writer2").json()["items"] == []

    # the worker entered each new set into the catalogue: the newest (the bulk's last item) is served
    newest = max(i["grasp_set"] for i in done["items"] if i["grasp_set"])
    got = svc.get(f"/v1/catalogue/{obj}/{grip}")
    assert got.status_code == 200 and got.headers["graspgen-set-id"] == str(newest)
    fleet = svc.get(f"/v1/catalogue?gripper={grip}").json()
    assert [(i["object"], i["id"]) for i in fleet["items"]] == [(obj, newest)]
