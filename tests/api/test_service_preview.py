"""GET /v1/grasp-sets/{id}/preview.png: a PNG at the requested size, immutable with a strong ETag, problems for a bad
size or an unknown id; and the quality job params (validate, select, density) checked at submission."""

from __future__ import annotations

import io

import pytest
from services_conftest import seed_grasp_sets, slug

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def grasp_set(pg_service) -> int:
    name = slug("prev")
    return seed_grasp_sets(pg_service, slug("grip"), [name])[name][0]


def test_preview_is_a_png_of_the_requested_size(pg_service, grasp_set):
    from PIL import Image

    r = pg_service.get(f"/v1/grasp-sets/{grasp_set}/preview.png?size=320x200")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png"
    assert "immutable" in r.headers["cache-control"]
    etag = r.headers["etag"]
    assert etag.startswith('"') and not etag.startswith("W/")
    image = Image.open(io.BytesIO(r.content))
    assert image.format == "PNG" and image.size == (320, 200)
    again = pg_service.get(f"/v1/grasp-sets/{grasp_set}/preview.png?size=320x200", headers={"If-None-Match": etag})
    assert again.status_code == 304 and again.headers["etag"] == etag and not again.content
    other = pg_service.get(f"/v1/grasp-sets/{grasp_set}/preview.png?size=200x160")
    assert other.status_code == 200 and other.headers["etag"] != etag
    assert Image.open(io.BytesIO(other.content)).size == (200, 160)


def test_preview_default_size(pg_service, grasp_set):
    from PIL import Image

    r = pg_service.get(f"/v1/grasp-sets/{grasp_set}/preview.png")
    assert r.status_code == 200 and Image.open(io.BytesIO(r.content)).size == (800, 600)


@pytest.mark.parametrize("size", ["big", "800", "10x10", "5000x100", "-3x40", "80x60x2"])
def test_preview_bad_size_is_a_422_problem(pg_service, grasp_set, size):
    r = pg_service.get(f"/v1/grasp-sets/{grasp_set}/preview.png", params={"size": size})
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM, r.text
    assert r.json()["field"] == "size"


def test_preview_unknown_grasp_set_is_404(pg_service):
    r = pg_service.get("/v1/grasp-sets/999999999/preview.png")
    assert r.status_code == 404 and r.headers["content-type"] == PROBLEM
    assert r.json()["code"] == "not-found"


def test_preview_needs_a_token(pg_service, grasp_set):
    r = pg_service.client.get(f"/v1/grasp-sets/{grasp_set}/preview.png")
    assert r.status_code == 401 and r.headers["content-type"] == PROBLEM


def test_preview_is_in_openapi(pg_service):
    op = pg_service.client.get("/openapi.json").json()["paths"]["/v1/grasp-sets/{grasp_set_id}/preview.png"]["get"]
    assert "image/png" in op["responses"]["200"]["content"]
    assert {"304", "404", "422"} <= set(op["responses"])


@pytest.mark.parametrize(
    "params",
    [
        {"select": "best"},
        {"select": 3},
        {"density": 0},
        {"density": -5},
        {"density": "heavy"},
        {"density": True},
        {"density": 1e9},
        {"validate": "yes"},
        {"validate": 1},
    ],
)
def test_bad_quality_params_are_422_and_add_no_rows(pg_service, pair, params):
    obj, grip = pair
    before = pg_service.row_counts()
    r = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": params})
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM, r.text
    body = r.json()
    assert body["code"] == "invalid-parameter" and body["field"] == next(iter(params))
    assert pg_service.row_counts() == before


def test_quality_params_are_stored(pg_service, pair):
    obj, grip = pair
    params = {"points": 600, "validate": True, "select": "best-near-medoid", "density": 2700}
    r = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": params})
    assert r.status_code == 202, r.text
    stored = r.json()["params"]
    assert stored["validate"] is True and stored["select"] == "best-near-medoid" and stored["density"] == 2700.0
    # default quality options are not stored; density is a core parameter (graspgen.Params), None by default
    r = pg_service.post(
        "/v1/jobs", json={"object": obj, "gripper": grip, "params": {"points": 600, "select": "medoid"}}
    )
    assert r.status_code == 202 and not {"validate", "select"} & set(r.json()["params"])
    assert r.json()["params"]["density"] is None


def test_bulk_item_with_bad_quality_param_fails_alone(pg_service, pair):
    obj, grip = pair
    r = pg_service.post(
        "/v1/bulk-jobs",
        json={
            "items": [
                {"object": obj, "gripper": grip, "params": {"points": 600, "select": "nope"}},
                {"object": obj, "gripper": grip, "params": {"points": 600, "validate": True}},
            ]
        },
    )
    assert r.status_code == 202, r.text
    items = r.json()["items"]
    assert items[0]["state"] == "failed" and items[0]["error"]["field"] == "select"
    assert items[1]["state"] == "queued"


def test_cluster_job_rejects_bad_quality_params(pg_service, grasp_set):
    before = pg_service.row_counts()
    r = pg_service.post("/v1/jobs", json={"kind": "cluster", "grasp_set": grasp_set, "params": {"density": -1}})
    assert r.status_code == 422 and r.json()["field"] == "density", r.text
    assert pg_service.row_counts() == before
