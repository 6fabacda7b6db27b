"""Suction cups over HTTP (CONTRACT.md "Suction cups"): `POST /v1/grippers` takes a cup spec as JSON (a cylinder
tool) or as multipart with its body mesh (`tool` given by `geometry`), versions it by content, lists it and serves
it back with its file; every invalid spec is a 422 problem naming the field, with nothing stored (rows and blobs
counted before and after)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from services_conftest import slug

from graspgen.example_grippers import box, stl_bytes
from tests.grippers import CUP

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"
#: a tool housing behind the lip, in mm: 40 x 40 mm across, from 20 mm behind the lip to 150 mm
BODY = stl_bytes(box((-20, -20, -150), (20, 20, -20)))


def cup(name: str, **changes: object) -> dict:
    return {**CUP, "name": name, **changes}


def body_cup(name: str, **geometry: object) -> dict:
    spec = {k: v for k, v in cup(name).items() if k != "tool"}
    return {**spec, "geometry": {"units": "mm", "body": "tool/body.stl", **geometry}}


def post_multipart(svc, spec: dict, files: dict[str, bytes]):  # type: ignore[no-untyped-def]
    parts = [("spec", (None, json.dumps(spec).encode(), "application/json"))]  # multipart even without files
    parts += [(name, (name.rsplit("/", 1)[-1], data, "model/stl")) for name, data in files.items()]
    return svc.post("/v1/grippers", files=parts)


def blobs(svc) -> set[str]:  # type: ignore[no-untyped-def]
    root = Path(svc.settings.storage_dir)
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()} if root.exists() else set()


def test_a_cup_registers_versions_by_content_and_is_listed(pg_service):
    name = slug("cup")
    r = pg_service.post("/v1/grippers", json=cup(name))
    assert r.status_code == 201, r.text
    out = r.json()
    assert out["version"] == 1 and out["files"] == []
    assert out["spec"] == {**CUP, "name": name}  # stored as given: the contract's fields, in metres
    assert r.headers["location"] == f"/v1/grippers/{name}/versions/1"
    before = pg_service.row_counts()
    again = pg_service.post("/v1/grippers", json=cup(name))
    assert again.status_code == 200 and again.json()["version"] == 1
    assert pg_service.row_counts() == before
    r2 = pg_service.post("/v1/grippers", json=cup(name, vacuum=80000))
    assert r2.status_code == 201 and r2.json()["version"] == 2
    g = pg_service.get(f"/v1/grippers/{name}").json()
    assert g["latest_version"] == 2 and g["spec"]["kind"] == "suction" and g["spec"]["vacuum"] == 80000
    assert pg_service.get(f"/v1/grippers/{name}/versions/1").json()["spec"]["vacuum"] == 60000
    listed = pg_service.get("/v1/grippers?limit=1000").json()["items"]
    assert any(item["name"] == name and item["latest_version"] == 2 for item in listed)


def test_a_cup_with_a_body_mesh_uploads_and_serves_its_file(pg_service):
    name = slug("cupbody")
    r = post_multipart(pg_service, body_cup(name), {"tool/body.stl": BODY})
    assert r.status_code == 201, r.text
    out = r.json()
    digest = hashlib.sha256(BODY).hexdigest()
    assert out["spec"]["geometry"] == {"units": "mm", "body": "tool/body.stl", "sha256": {"tool/body.stl": digest}}
    assert "tool" not in out["spec"] and out["spec"]["kind"] == "suction"
    assert [(f["path"], f["sha256"]) for f in out["files"]] == [("tool/body.stl", digest)]
    got = pg_service.get(out["files"][0]["link"])
    assert got.status_code == 200 and got.content == BODY and got.headers["content-type"] == "model/stl"
    # the same spec and file (or the stored form sent back): the existing version; a changed file: a new one
    assert post_multipart(pg_service, body_cup(name), {"tool/body.stl": BODY}).status_code == 200
    assert post_multipart(pg_service, out["spec"], {"tool/body.stl": BODY}).json()["version"] == 1
    longer = stl_bytes(box((-20, -20, -180), (20, 20, -20)))
    r2 = post_multipart(pg_service, body_cup(name), {"tool/body.stl": longer})
    assert r2.status_code == 201 and r2.json()["version"] == 2
    assert pg_service.get(f"/v1/grippers/{name}/versions/2/files/tool/body.stl").content == longer
    assert pg_service.get(f"/v1/grippers/{name}/versions/1/files/tool/body.stl").content == BODY


BAD_JSON = [
    # (case, spec changes, field)
    ("unknown kind", {"kind": "magnetic"}, "kind"),
    ("radius in mm", {"cup_radius": 15.0}, "cup_radius"),
    ("negative height", {"cup_height": -0.02}, "cup_height"),
    ("strain over 1", {"max_strain": 1.5}, "max_strain"),
    ("vacuum above an atmosphere", {"vacuum": 200000}, "vacuum"),
    ("friction a word", {"friction": "high"}, "friction"),
    ("negative clearance", {"pregrasp_clearance": -0.01}, "pregrasp_clearance"),
    ("unknown field", {"colour": "red"}, "colour"),
    ("jaw field", {"stroke": 0.08}, "stroke"),
    ("tool without length", {"tool": {"radius": 0.012}}, "tool"),
    ("tool of zero radius", {"tool": {"radius": 0.0, "length": 0.1}}, "tool.radius"),
    ("no tool", {"tool": None}, "tool"),
    ("tool and geometry", {"geometry": {"units": "mm", "body": "body.stl"}}, "geometry"),
    ("bad name", {"name": "Bad Name"}, "name"),
]


@pytest.mark.parametrize("case, change, field", BAD_JSON, ids=[b[0] for b in BAD_JSON])
def test_invalid_cup_specs_are_problems_naming_the_field_and_store_nothing(pg_service, case, change, field):
    spec = {**cup(slug("badcup")), **change}
    spec = {k: v for k, v in spec.items() if v is not None}
    before, stored = pg_service.row_counts(), blobs(pg_service)
    r = pg_service.post("/v1/grippers", json=spec)
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM, r.text
    assert r.json()["code"] == "invalid-gripper" and r.json()["field"] == field, r.json()
    assert pg_service.row_counts() == before and blobs(pg_service) == stored


BAD_MULTIPART = [
    # (case, geometry changes, files, field)
    ("missing file", {}, {}, "geometry.body"),
    ("extra file", {}, {"tool/body.stl": BODY, "camera.stl": BODY}, "camera.stl"),
    ("body in front of the lip", {}, {"tool/body.stl": stl_bytes(box((-20, -20, -150), (20, 20, 5)))}, "geometry.body"),
    ("mm read as m", {"units": "m"}, {"tool/body.stl": BODY}, "geometry.body"),
    ("finger role", {"finger": "finger.stl"}, {"tool/body.stl": BODY, "finger.stl": BODY}, "geometry.finger"),
    ("wrong digest", {"sha256": {"tool/body.stl": "0" * 64}}, {"tool/body.stl": BODY}, "geometry.sha256"),
]


@pytest.mark.parametrize("case, geometry, files, field", BAD_MULTIPART, ids=[b[0] for b in BAD_MULTIPART])
def test_invalid_body_uploads_are_problems_and_store_nothing(pg_service, case, geometry, files, field):
    before, stored = pg_service.row_counts(), blobs(pg_service)
    r = post_multipart(pg_service, body_cup(slug("badbody"), **geometry), files)
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM, r.text
    assert r.json()["code"] == "invalid-gripper" and r.json()["field"] == field, r.json()
    assert pg_service.row_counts() == before and blobs(pg_service) == stored


def test_a_file_beside_a_cylinder_tool_is_refused(pg_service):
    before, stored = pg_service.row_counts(), blobs(pg_service)
    r = post_multipart(pg_service, cup(slug("cylfile")), {"tool/body.stl": BODY})
    assert r.status_code == 422 and r.json()["field"] == "tool/body.stl", r.json()
    assert pg_service.row_counts() == before and blobs(pg_service) == stored


def test_the_shipped_example_cup_registers(pg_service):
    spec = json.loads((Path(__file__).parents[2] / "examples" / "cup-30.json").read_text())
    r = pg_service.post("/v1/grippers", json={**spec, "name": slug("example-cup")})
    assert r.status_code == 201, r.text
    assert r.json()["spec"]["cup_radius"] == 0.015
