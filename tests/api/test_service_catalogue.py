"""The fleet catalogue: newest grasp set per object for a gripper, paged by cursor, filtered by time, with ETags."""

from __future__ import annotations

import time
from urllib.parse import quote

import pytest
from services_conftest import seed_grasp_sets, slug

pytestmark = pytest.mark.integration


def all_pages(svc, url: str) -> list[dict]:
    items, cursor = [], None
    for _ in range(100):
        page = svc.get(url + (f"&cursor={cursor}" if cursor else ""))
        assert page.status_code == 200, page.text
        items += page.json()["items"]
        cursor = page.json()["next_cursor"]
        if cursor is None:
            return items
    raise AssertionError("pagination did not end")


def test_catalogue_lists_the_newest_set_of_every_object_in_pages(pg_service):
    grip = slug("fleet")
    names = sorted(slug("cat") for _ in range(7))
    ids = seed_grasp_sets(pg_service, grip, names, version_of={names[2]: 3, names[5]: 2})
    items = all_pages(pg_service, f"/v1/catalogue?gripper={grip}&limit=3")
    assert [i["object"] for i in items] == names
    newest = {i["object"]: i["id"] for i in items}
    assert newest == {n: ids[n][-1] for n in names}
    assert {i["object"]: i["version"] for i in items}[names[2]] == 3
    item = items[0]
    assert item["gripper"] == grip and item["etag"] == f'"{item["sha256"]}"'
    assert item["links"]["self"] == f"/v1/grasp-sets/{item['id']}"
    assert pg_service.get(item["links"]["catalogue"]).headers["etag"] == item["etag"]


def test_catalogue_etag_gives_304_until_something_changes(pg_service):
    grip = slug("etag")
    first = seed_grasp_sets(pg_service, grip, [slug("e")])
    page = pg_service.get(f"/v1/catalogue?gripper={grip}")
    etag = page.headers["etag"]
    assert etag.startswith('"') and page.headers["cache-control"] == "private, no-cache"
    again = pg_service.get(f"/v1/catalogue?gripper={grip}", headers={"If-None-Match": etag})
    assert again.status_code == 304 and again.content == b"" and again.headers["etag"] == etag
    seed_grasp_sets(pg_service, grip, list(first))  # a newer version of the same object
    changed = pg_service.get(f"/v1/catalogue?gripper={grip}", headers={"If-None-Match": etag})
    assert changed.status_code == 200 and changed.headers["etag"] != etag


def test_updated_since_keeps_only_objects_with_a_newer_set(pg_service):
    grip = slug("since")
    old = slug("old")
    seed_grasp_sets(pg_service, grip, [old])
    mark = pg_service.get(f"/v1/catalogue?gripper={grip}").json()["items"][0]["created_at"]
    time.sleep(0.01)
    new = slug("new")
    seed_grasp_sets(pg_service, grip, [new])
    items = pg_service.get(f"/v1/catalogue?gripper={grip}&updated_since={quote(mark)}").json()["items"]
    assert [i["object"] for i in items] == [new]
    naive = mark.replace("Z", "").split("+")[0]  # naive times are UTC
    assert [
        i["object"] for i in pg_service.get(f"/v1/catalogue?gripper={grip}&updated_since={naive}").json()["items"]
    ] == [new]


def test_grasp_sets_list_pages_newest_first_and_filters(pg_service):
    grip = slug("gsl")
    obj = slug("many")
    ids = seed_grasp_sets(pg_service, grip, [obj], version_of={obj: 5})[obj]
    items = all_pages(pg_service, f"/v1/grasp-sets?object={obj}&gripper={grip}&limit=2")
    assert [i["id"] for i in items] == sorted(ids, reverse=True)
    assert [i["version"] for i in items] == [5, 4, 3, 2, 1]
    export = pg_service.get(f"/v1/grasp-sets/{ids[0]}")
    assert export.json()["params"]["seed"] == 1 and "immutable" in export.headers["cache-control"]
    v3 = pg_service.get(f"/v1/catalogue/{obj}/{grip}?version=3")
    assert v3.headers["content-location"] == f"/v1/grasp-sets/{ids[2]}"
    assert pg_service.get(f"/v1/catalogue/{obj}/{grip}?version=9").status_code == 404
    assert pg_service.get(f"/v1/catalogue/{obj}/no-such-gripper").status_code == 404


def test_head_answers_as_get_without_the_body(pg_service):
    """HEAD on a GET route: the GET's status and headers (ETag, Content-Length, the catalogue's Graspgen-*), no
    body; a conditional HEAD gives 304; a path without GET answers 405 with Allow, as a problem."""
    grip = slug("head")
    name = slug("h")
    seed_grasp_sets(pg_service, grip, [name])
    url = f"/v1/catalogue/{name}/{grip}"
    got = pg_service.get(url)
    head = pg_service.client.head(url, headers=pg_service.h("reader"))
    assert got.status_code == head.status_code == 200 and head.content == b""
    for key in ("etag", "content-length", "content-type", "graspgen-set-id", "graspgen-released", "graspgen-stale"):
        assert head.headers[key] == got.headers[key], key
    assert int(head.headers["content-length"]) == len(got.content) > 0
    cond = pg_service.client.head(url, headers=pg_service.h("reader", **{"If-None-Match": got.headers["etag"]}))
    assert cond.status_code == 304 and cond.content == b""
    assert pg_service.client.head(url).status_code == 401  # auth as for GET
    missing = pg_service.client.head(f"/v1/catalogue/{slug('none')}/{grip}", headers=pg_service.h("reader"))
    assert missing.status_code == 404 and missing.content == b""
    post_only = pg_service.client.head("/v1/pick", headers=pg_service.h("reader"))
    assert post_only.status_code == 405 and post_only.headers["allow"] == "POST"
