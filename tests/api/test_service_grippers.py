"""Grippers: validated specs, identical specs return the existing version, changes make new versions."""

from __future__ import annotations

import pytest
from services_conftest import GRIPPER, slug

pytestmark = pytest.mark.integration


def test_register_gripper_versions(pg_service):
    name = slug("pgn")
    r = pg_service.gripper(name)
    assert r.status_code == 201, r.text
    assert r.json()["version"] == 1 and r.json()["spec"]["palm_width"] == GRIPPER["finger_width"]
    assert r.headers["location"] == f"/v1/grippers/{name}/versions/1"
    assert pg_service.gripper(name).status_code == 200
    r2 = pg_service.gripper(name, stroke=0.1)
    assert r2.status_code == 201 and r2.json()["version"] == 2
    g = pg_service.get(f"/v1/grippers/{name}").json()
    assert g["latest_version"] == 2 and g["spec"]["stroke"] == 0.1
    assert pg_service.get(f"/v1/grippers/{name}/versions/1").json()["spec"]["stroke"] == 0.08
    assert pg_service.get(f"/v1/grippers/{name}/versions/3").status_code == 404


@pytest.mark.parametrize(
    "spec",
    [
        {**GRIPPER, "stroke": 80.0},  # millimetres given as metres
        {**GRIPPER, "name": "Bad Name"},
        {k: v for k, v in GRIPPER.items() if k != "stroke"},
        {**GRIPPER, "colour": "red"},
        {**GRIPPER, "friction": "high"},
    ],
)
def test_invalid_specs_are_problems_and_change_nothing(pg_service, spec):
    before = pg_service.row_counts()
    r = pg_service.post("/v1/grippers", json=spec)
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json"
    assert r.json()["code"] == "invalid-gripper"
    assert pg_service.row_counts() == before


def test_non_object_body_is_a_problem(pg_service):
    r = pg_service.post("/v1/grippers", content=b"[1,2", headers={"Content-Type": "application/json"})
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json"


def test_list_grippers_paginates(pg_service):
    prefix = slug("gl")
    for i in range(3):
        pg_service.gripper(f"{prefix}-{i}")
    names, cursor = [], None
    while True:
        page = pg_service.get("/v1/grippers?limit=1" + (f"&cursor={cursor}" if cursor else "")).json()
        names += [g["name"] for g in page["items"]]
        cursor = page["next_cursor"]
        if not cursor:
            break
    assert [n for n in names if n.startswith(prefix)] == [f"{prefix}-{i}" for i in range(3)]


def test_concurrent_specs_under_one_new_name_number_their_versions_once(pg_service):
    from concurrent.futures import ThreadPoolExecutor

    name = slug("busy")
    strokes = [0.08, 0.08, 0.09, 0.09, 0.1, 0.11]
    with ThreadPoolExecutor(6) as pool:
        rs = list(pool.map(lambda s: pg_service.gripper(name, stroke=s), strokes))
    assert all(r.status_code in (200, 201) for r in rs), [r.text for r in rs]
    version = {s: {r.json()["version"] for r, t in zip(rs, strokes, strict=True) if t == s} for s in set(strokes)}
    assert all(len(v) == 1 for v in version.values())  # one spec, one version
    assert sorted(v.pop() for v in version.values()) == [1, 2, 3, 4]
    assert sum(r.status_code == 201 for r in rs) == 4
