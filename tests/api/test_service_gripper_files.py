"""Grippers with finger and body meshes over HTTP (CONTRACT.md "Gripper geometry from CAD"): multipart upload,
versions by content (a changed file is a new version), files served back, every bad input a 422 (or 413) problem that
stores nothing (rows and blobs counted before and after)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
from services_conftest import slug

from graspgen.example_grippers import box, example_gripper_files, stl_bytes

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"
FINGER = stl_bytes(box((0, -10, -15), (10, 10, 15)))
BODY = stl_bytes(box((-40, -20, -35), (40, 20, -15)))


def spec_of(name: str, **geometry) -> dict:
    return {
        "name": name,
        "stroke": 0.06,
        "friction": 0.5,
        "pregrasp_clearance": 0.02,
        "geometry": {"units": "mm", "finger": "finger.stl", "body": "meshes/body.stl", **geometry},
    }


def post(svc, spec: dict, files: dict[str, bytes], who: str = "writer"):  # type: ignore[no-untyped-def]
    parts = [(name, (name.rsplit("/", 1)[-1], data, "model/stl")) for name, data in files.items()]
    return svc.post("/v1/grippers", who=who, data={"spec": json.dumps(spec)}, files=parts)


def blobs(svc) -> set[str]:  # type: ignore[no-untyped-def]
    root = Path(svc.settings.storage_dir)
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()} if root.exists() else set()


def test_upload_versions_by_content_and_serves_files(pg_service):
    name = slug("cad")
    files = {"finger.stl": FINGER, "meshes/body.stl": BODY}
    r = post(pg_service, spec_of(name), files)
    assert r.status_code == 201, r.text
    out = r.json()
    assert out["version"] == 1 and r.headers["location"] == f"/v1/grippers/{name}/versions/1"
    digests = {n: hashlib.sha256(b).hexdigest() for n, b in files.items()}
    assert out["spec"]["geometry"]["sha256"] == digests
    assert "finger_width" not in out["spec"]
    assert {f["path"]: f["sha256"] for f in out["files"]} == digests
    # served back as uploaded, cacheable forever, conditional
    link = next(f["link"] for f in out["files"] if f["path"] == "meshes/body.stl")
    assert link == f"/v1/grippers/{name}/versions/1/files/meshes/body.stl"
    got = pg_service.get(link)
    assert got.status_code == 200 and got.content == BODY and got.headers["content-type"] == "model/stl"
    assert "immutable" in got.headers["cache-control"]
    assert pg_service.get(link, headers={"If-None-Match": got.headers["etag"]}).status_code == 304
    for missing in ("nothing.stl", "meshes/finger.stl", "finger.STL"):
        nf = pg_service.get(f"/v1/grippers/{name}/versions/1/files/{missing}")
        assert nf.status_code == 404 and nf.headers["content-type"] == PROBLEM and nf.json()["field"] == "path"
    assert pg_service.get(f"/v1/grippers/{name}/versions/2/files/finger.stl").status_code == 404
    # the same spec with the same files: the existing version, nothing added
    before, stored = pg_service.row_counts(), blobs(pg_service)
    again = post(pg_service, spec_of(name), files)
    assert again.status_code == 200 and again.json()["version"] == 1
    assert pg_service.row_counts() == before and blobs(pg_service) == stored
    # ... also when the client sends the digests it was given back (the stored form round-trips)
    assert post(pg_service, out["spec"], files).json()["version"] == 1
    # a changed file is a new version; the unchanged one is stored once
    wider = stl_bytes(box((-50, -20, -35), (50, 20, -15)))
    r2 = post(pg_service, spec_of(name), {"finger.stl": FINGER, "meshes/body.stl": wider})
    assert r2.status_code == 201 and r2.json()["version"] == 2
    assert blobs(pg_service) - stored == {
        f"blobs/{hashlib.sha256(wider).hexdigest()[:2]}/" + hashlib.sha256(wider).hexdigest()
    }
    assert pg_service.get(f"/v1/grippers/{name}/versions/2/files/meshes/body.stl").content == wider
    assert pg_service.get(f"/v1/grippers/{name}/versions/1/files/meshes/body.stl").content == BODY
    g = pg_service.get(f"/v1/grippers/{name}").json()
    assert g["latest_version"] == 2 and [len(v["files"]) for v in g["versions"]] == [2, 2]


def test_box_specs_have_no_files(pg_service):
    name = slug("box")
    r = pg_service.gripper(name)
    assert r.status_code == 201 and r.json()["files"] == []
    assert "geometry" not in r.json()["spec"]


def test_shipped_example_uploads(pg_service):
    files = example_gripper_files("pgn-80-vgroove")
    spec = json.loads(files.pop("pgn-80-vgroove.json"))
    spec["name"] = slug("vgroove")
    r = post(pg_service, spec, files)
    assert r.status_code == 201, r.text
    assert sorted(f["path"] for f in r.json()["files"]) == sorted(files)


def _tampered(data: bytes) -> bytes:
    return data[:-50]  # a binary STL one triangle short of what its header declares


def _flipped() -> bytes:
    v, f = box((0, -10, -15), (10, 10, 15))
    return stl_bytes((v, f[:, ::-1]))


BAD = [
    # (case, spec changes, geometry changes, files, field)
    ("missing file", {}, {}, {"finger.stl": FINGER}, "geometry.body"),
    ("extra file", {}, {}, {"finger.stl": FINGER, "meshes/body.stl": BODY, "camera.stl": BODY}, "camera.stl"),
    ("box fields too", {"finger_width": 0.02}, {}, None, "finger_width"),
    ("unknown units", {}, {"units": "furlong"}, None, "geometry.units"),
    ("mm read as m", {}, {"units": "m"}, None, "geometry.finger"),
    ("truncated", {}, {}, {"finger.stl": _tampered(FINGER), "meshes/body.stl": BODY}, "geometry.finger"),
    ("inside out", {}, {}, {"finger.stl": _flipped(), "meshes/body.stl": BODY}, "geometry.finger"),
    ("origin off the finger", {}, {}, {"finger.stl": BODY, "meshes/body.stl": BODY}, "geometry.finger"),
    (
        "not a mesh format",
        {},
        {"finger": "finger.step"},
        {"finger.step": FINGER, "meshes/body.stl": BODY},
        "geometry.finger",
    ),
    (
        "path traversal",
        {},
        {"finger": "../finger.stl"},
        {"../finger.stl": FINGER, "meshes/body.stl": BODY},
        "geometry.finger",
    ),
    ("wrong digest", {}, {"sha256": {"finger.stl": "0" * 64, "meshes/body.stl": "0" * 64}}, None, "geometry.sha256"),
    (
        "too many triangles",
        {},
        {},
        {
            "finger.stl": b"\0" * 80 + (200_001).to_bytes(4, "little") + b"\0" * (50 * 200_001),
            "meshes/body.stl": BODY,
        },
        None,
    ),
    ("bad name", {"name": "Bad Name"}, {}, None, "name"),
]


@pytest.mark.parametrize("case, change, geometry, files, field", BAD, ids=[b[0] for b in BAD])
def test_bad_uploads_are_problems_and_store_nothing(pg_service, case, change, geometry, files, field):
    spec = spec_of(slug("bad"), **geometry)
    spec.update(change)
    files = files if files is not None else {"finger.stl": FINGER, "meshes/body.stl": BODY}
    before, stored = pg_service.row_counts(), blobs(pg_service)
    r = post(pg_service, spec, files)
    if case == "too many triangles":  # 10 MB: over the test service's upload limit before any triangle is read
        assert r.status_code == 413 and r.json()["code"] == "content-too-large", r.text
    else:
        assert r.status_code == 422, r.text
        assert r.headers["content-type"] == PROBLEM and r.json()["code"] == "invalid-gripper", r.json()
        assert r.json()["field"] == field, r.json()
    assert pg_service.row_counts() == before and blobs(pg_service) == stored


def test_triangle_limit_over_http(pg_service, monkeypatch):
    from graspgen import gripper_geometry

    monkeypatch.setattr(gripper_geometry, "MAX_TRIANGLES", 11)  # the 12-triangle finger is one too many
    before, stored = pg_service.row_counts(), blobs(pg_service)
    r = post(pg_service, spec_of(slug("tri")), {"finger.stl": FINGER, "meshes/body.stl": BODY})
    assert r.status_code == 422 and "12 triangles, more than the limit of 11" in r.json()["detail"]
    assert r.json()["field"] == "geometry.finger"
    assert pg_service.row_counts() == before and blobs(pg_service) == stored


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"json": spec_of("no-files")}, "geometry"),  # geometry as a JSON body: its files cannot come with it
        ({"data": {"spec": "{not json"}, "files": [("finger.stl", ("f.stl", FINGER))]}, "spec"),
        ({"data": {"other": "x"}, "files": [("finger.stl", ("f.stl", FINGER))]}, "spec"),
        (
            {"data": {"spec": json.dumps(spec_of("txt")), "finger.stl": "solid"}, "files": [("x.stl", ("x", b"1"))]},
            "finger.stl",
        ),
    ],
)
def test_malformed_bodies_are_problems(pg_service, kwargs, field):
    before = pg_service.row_counts()
    r = pg_service.post("/v1/grippers", **kwargs)
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM, r.text
    assert r.json()["field"] == field, r.json()
    assert pg_service.row_counts() == before


def test_a_file_over_the_upload_limit_is_413(pg_service):
    limit = pg_service.settings.max_upload_bytes
    before, stored = pg_service.row_counts(), blobs(pg_service)
    r = post(pg_service, spec_of(slug("big")), {"finger.stl": FINGER, "meshes/body.stl": b"x" * (limit + 1)})
    assert r.status_code == 413 and r.headers["content-type"] == PROBLEM
    assert pg_service.row_counts() == before and blobs(pg_service) == stored


def test_reader_cannot_upload(pg_service):
    r = post(pg_service, spec_of(slug("ro")), {"finger.stl": FINGER, "meshes/body.stl": BODY}, who="reader")
    assert r.status_code == 403


def test_openapi_documents_the_multipart_form(pg_service):
    schema = pg_service.get("/openapi.json").json()
    body = schema["paths"]["/v1/grippers"]["post"]["requestBody"]["content"]
    assert body["application/json"]["schema"]["allOf"] == [{"$ref": "#/components/schemas/AnyGripperSpec"}]
    form = body["multipart/form-data"]["schema"]
    assert form["required"] == ["spec"] and form["additionalProperties"]["format"] == "binary"
    files = schema["paths"]["/v1/grippers/{name}/versions/{version}/files/{path}"]["get"]
    assert "404" in files["responses"]
    spec = schema["components"]["schemas"]["GripperSpec"]["properties"]
    assert "geometry" in spec and "kind" in spec
    assert {"units", "finger", "finger_left", "body", "pad"} <= set(
        schema["components"]["schemas"]["GripperGeometry"]["properties"]
    )


def test_spec_may_come_as_a_file_part(pg_service):
    name = slug("curl")
    spec = json.dumps(spec_of(name)).encode()
    parts = [("spec", ("spec.json", spec, "application/json"))]
    parts += [(n, (n, b, "model/stl")) for n, b in {"finger.stl": FINGER, "meshes/body.stl": BODY}.items()]
    r = pg_service.post("/v1/grippers", files=parts)
    assert r.status_code == 201, r.text
    assert r.json()["spec"]["name"] == name
