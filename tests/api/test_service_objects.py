"""Objects: upload (idempotent, versioned, validated, size-limited), lookup, file download, pagination."""

from __future__ import annotations

import hashlib

import pytest
from services_conftest import box_stl, cylinder_stl, slug

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"


def test_upload_creates_version_and_same_bytes_return_it(pg_service):
    name = slug("ring-screw")
    data = box_stl()
    r = pg_service.upload(name, data)
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["name"] == name and body["version"] == 1
    assert body["sha256"] == hashlib.sha256(data).hexdigest()
    assert body["units"] == "mm" and body["format"] == "stl" and body["watertight"] is True
    assert body["extents"] == pytest.approx([0.04, 0.03, 0.02])  # stored in metres
    assert r.headers["location"] == f"/v1/objects/{name}/versions/1"

    again = pg_service.upload(name, data)
    assert again.status_code == 200 and again.json()["version"] == 1

    other = pg_service.upload(name, cylinder_stl())
    assert other.status_code == 201 and other.json()["version"] == 2
    # the same bytes in other units are another part
    inches = pg_service.upload(name, data, units="in")
    assert inches.status_code == 201 and inches.json()["version"] == 3

    obj = pg_service.get(f"/v1/objects/{name}").json()
    assert obj["latest_version"] == 3 and [v["version"] for v in obj["versions"]] == [1, 2, 3]
    v2 = pg_service.get(f"/v1/objects/{name}/versions/2").json()
    assert v2["sha256"] == other.json()["sha256"]


def test_file_download_is_the_upload_with_strong_etag(pg_service):
    name = slug("bracket")
    data = box_stl((10, 20, 30))
    pg_service.upload(name, data)
    r = pg_service.get(f"/v1/objects/{name}/versions/1/file")
    assert r.status_code == 200 and r.content == data
    etag = r.headers["etag"]
    assert etag == f'"{hashlib.sha256(data).hexdigest()}"'
    assert "immutable" in r.headers["cache-control"]
    assert f"{name}-v1.stl" in r.headers["content-disposition"]
    again = pg_service.get(f"/v1/objects/{name}/versions/1/file", headers={"If-None-Match": etag})
    assert again.status_code == 304 and again.content == b""


@pytest.mark.parametrize(
    ("form", "code"),
    [
        ({"name": "Not A Slug", "units": "mm"}, "invalid-name"),
        ({"name": "../../etc", "units": "mm"}, "invalid-name"),
        ({"name": "ok-name", "units": "furlong"}, "invalid-units"),
        ({"name": "ok-name", "units": "mm", "format": "../x"}, "invalid-format"),
    ],
)
def test_bad_upload_fields_are_problems_and_change_nothing(pg_service, form, code):
    before = pg_service.row_counts()
    r = pg_service.post("/v1/objects", files={"file": ("p.stl", box_stl(), "model/stl")}, data=form)
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM
    assert r.json()["code"] == code
    assert pg_service.row_counts() == before


def test_missing_units_is_a_validation_problem(pg_service):
    r = pg_service.post("/v1/objects", files={"file": ("p.stl", box_stl(), "model/stl")}, data={"name": "x-1"})
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM
    assert r.json()["code"] == "validation-error"
    assert any("units" in e["loc"] for e in r.json()["errors"])


def test_broken_mesh_is_refused_before_storage(pg_service):
    before = pg_service.row_counts()
    blobs = pg_service.settings.storage_dir / "blobs"
    n_blobs = sum(1 for _ in blobs.rglob("*") if _.is_file())
    r = pg_service.upload(slug("broken"), b"solid nothing\nendsolid nothing\n")
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM
    assert r.json()["code"] == "invalid-mesh"
    assert pg_service.row_counts() == before
    assert sum(1 for _ in blobs.rglob("*") if _.is_file()) == n_blobs


def test_wrong_units_for_the_part_is_refused(pg_service):
    # a 40 mm box declared in metres is 40 m long: implausible, never guessed
    r = pg_service.upload(slug("huge"), box_stl(), units="m")
    assert r.status_code == 422 and r.json()["code"] in ("invalid-mesh", "invalid-units")


def test_upload_over_the_limit_is_413_while_streaming(pg_service):
    limit = pg_service.settings.max_upload_bytes
    before = pg_service.row_counts()
    big = b"\0" * (limit + 128 * 1024)

    # chunked: no Content-Length, the running count cuts it off
    def chunks():
        body = (
            b'--b\r\nContent-Disposition: form-data; name="name"\r\n\r\nbig-1\r\n'
            b'--b\r\nContent-Disposition: form-data; name="units"\r\n\r\nmm\r\n'
            b'--b\r\nContent-Disposition: form-data; name="file"; filename="a.stl"\r\n\r\n'
        )
        yield body
        for i in range(0, len(big), 65536):
            yield big[i : i + 65536]
        yield b"\r\n--b--\r\n"

    r = pg_service.client.post(
        "/v1/objects", headers={**pg_service.h(), "Content-Type": "multipart/form-data; boundary=b"}, content=chunks()
    )
    assert r.status_code == 413 and r.headers["content-type"] == PROBLEM
    # declared: refused before reading
    r = pg_service.upload("big-2", big)
    assert r.status_code == 413 and r.headers["content-type"] == PROBLEM
    # just above the file limit but within the multipart allowance: refused after parsing
    r = pg_service.upload("big-3", b"\0" * (limit + 1))
    assert r.status_code == 413 and r.json()["code"] == "content-too-large"
    assert pg_service.row_counts() == before


def test_list_objects_is_cursor_paginated(pg_service):
    prefix = slug("pg")
    names = [f"{prefix}-{i}" for i in range(5)]
    for n in names:
        assert pg_service.upload(n, box_stl((10 + names.index(n), 10, 10))).status_code == 201
    seen, cursor = [], None
    for _ in range(50):
        url = "/v1/objects?limit=2" + (f"&cursor={cursor}" if cursor else "")
        page = pg_service.get(url).json()
        seen += [i["name"] for i in page["items"]]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    assert [n for n in seen if n.startswith(prefix)] == names
    assert seen == sorted(seen)
    bad = pg_service.get("/v1/objects?cursor=not-a-cursor")
    assert bad.status_code == 422 and bad.json()["code"] == "invalid-cursor"


def test_unknown_object_and_version_are_404(pg_service):
    r = pg_service.get("/v1/objects/does-not-exist")
    assert r.status_code == 404 and r.headers["content-type"] == PROBLEM
    name = slug("one")
    pg_service.upload(name)
    assert pg_service.get(f"/v1/objects/{name}/versions/9").status_code == 404
    assert pg_service.get(f"/v1/objects/{name}/versions/9/file").status_code == 404


def test_concurrent_uploads_under_one_new_name_number_their_versions_once(pg_service):
    from concurrent.futures import ThreadPoolExecutor

    same, different = slug("same"), slug("different")
    with ThreadPoolExecutor(6) as pool:
        same_bytes = list(pool.map(lambda _: pg_service.upload(same, box_stl()), range(6)))
        sizes = [(10 + k, 20, 30) for k in range(6)]
        other_bytes = list(pool.map(lambda e: pg_service.upload(different, box_stl(e)), sizes))
    # the same bytes: one version, created once, returned to every other upload
    assert sorted(r.status_code for r in same_bytes) == [200] * 5 + [201]
    assert {r.json()["version"] for r in same_bytes} == {1}
    # other bytes: each its own version, numbered without gaps or repeats
    assert all(r.status_code == 201 for r in other_bytes), [r.text for r in other_bytes]
    assert sorted(r.json()["version"] for r in other_bytes) == [1, 2, 3, 4, 5, 6]
    assert pg_service.get(f"/v1/objects/{different}").json()["latest_version"] == 6
