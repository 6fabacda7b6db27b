"""GET /v1/pairs: every object x gripper pair across grippers, filtered, paged by keyset cursor (the review page's
catalogue), on PostgreSQL and on the embedded SQLite default."""

from __future__ import annotations

import uuid

import pytest
from services_conftest import seed_grasp_sets

pytestmark = pytest.mark.integration


@pytest.fixture(params=["pg_service", "sqlite_service"])
def svc(request):
    return request.getfixturevalue(request.param)


def all_pages(svc, url: str) -> tuple[list[dict], list[int]]:
    items, totals, cursor = [], [], None
    for _ in range(100):
        page = svc.get(url + (f"&cursor={cursor}" if cursor else ""))
        assert page.status_code == 200, page.text
        items += page.json()["items"]
        totals.append(page.json()["total"])
        cursor = page.json()["next_cursor"]
        if cursor is None:
            return items, totals
        assert page.json()["links"]["next"].startswith("/v1/pairs?cursor=")
    raise AssertionError("pagination did not end")


def test_pairs_across_grippers_in_name_order_with_paging_and_filters(svc):
    run = uuid.uuid4().hex[:8]
    objects = [f"pp{run}-{c}" for c in "cab"]
    grippers = [f"g{run}-2", f"g{run}-1"]
    ids = {g: seed_grasp_sets(svc, g, objects, version_of={objects[0]: 2}) for g in grippers}

    items, totals = all_pages(svc, f"/v1/pairs?object_contains=pp{run}&limit=4")
    want = sorted((o, g) for o in objects for g in grippers)
    assert [(i["object"], i["gripper"]) for i in items] == want
    assert totals == [6, 6]
    by_pair = {(i["object"], i["gripper"]): i for i in items}
    first = by_pair[(objects[0], grippers[0])]
    assert first["current"]["id"] == ids[grippers[0]][objects[0]][-1] and first["current"]["version"] == 2
    assert first["released"] is False and first["released_id"] is None and first["stale"] is False
    assert first["last_event"] is None
    assert first["links"]["history"] == f"/v1/catalogue/{objects[0]}/{grippers[0]}/history"

    one = svc.get(f"/v1/pairs?object_contains=pp{run}&gripper={grippers[1]}").json()
    assert [i["object"] for i in one["items"]] == sorted(objects) and one["total"] == 3
    assert {i["gripper"] for i in one["items"]} == {grippers[1]}
    middle = svc.get(f"/v1/pairs?object_contains={run}-a").json()
    assert {i["object"] for i in middle["items"]} == {objects[1]} and middle["total"] == 2

    # a release shows as released, with who made it; the filters follow it
    older = ids[grippers[1]][objects[0]][0]
    assert svc.post(f"/v1/grasp-sets/{older}/release", who="writer").status_code == 200
    released = svc.get(f"/v1/pairs?object_contains=pp{run}&released=true").json()
    assert [(i["object"], i["gripper"]) for i in released["items"]] == [(objects[0], grippers[1])]
    item = released["items"][0]
    assert item["released"] is True and item["released_id"] == older and item["current"]["id"] == older
    assert item["last_event"]["action"] == "release" and item["last_event"]["by"] == "writer"
    assert item["last_event"]["grasp_set"] == older and item["last_event"]["version"] == 1
    assert svc.get(f"/v1/pairs?object_contains=pp{run}&released=false").json()["total"] == 5

    # withdrawn: the pair stays listed, serving its other set, and says who withdrew
    assert svc.post(f"/v1/grasp-sets/{older}/withdraw", who="writer2").status_code == 200
    item = svc.get(f"/v1/pairs?object_contains={objects[0]}&gripper={grippers[1]}").json()["items"][0]
    assert item["released"] is False and item["current"]["id"] == ids[grippers[1]][objects[0]][-1]
    assert (item["last_event"]["action"], item["last_event"]["by"]) == ("withdraw", "writer2")
    assert svc.get(f"/v1/pairs?object_contains=pp{run}&stale=true").json()["total"] == 0


def test_pairs_refuses_bad_input(pg_service):
    assert pg_service.get("/v1/pairs?cursor=nonsense").status_code == 422
    assert pg_service.get("/v1/pairs?object_contains=a%25b").status_code == 422
    assert pg_service.get("/v1/pairs?gripper=Not%20a%20slug").status_code == 422
    assert pg_service.client.get("/v1/pairs").status_code == 401
