"""Every error is application/problem+json (RFC 9457) and changes no rows, whatever the route or the mistake."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"


@pytest.mark.parametrize(
    ("method", "url", "kwargs", "status"),
    [
        ("GET", "/v1/nothing-here", {}, 404),
        ("DELETE", "/v1/objects", {}, 405),
        ("PUT", "/v1/jobs", {"json": {}}, 405),
        ("POST", "/v1/jobs", {"content": b"{not json", "headers": {"Content-Type": "application/json"}}, 422),
        ("POST", "/v1/jobs", {"content": b"object=x", "headers": {"Content-Type": "text/plain"}}, 422),
        ("POST", "/v1/jobs", {"json": {"object": "x", "gripper": "y", "object_version": 0}}, 422),
        ("POST", "/v1/jobs", {"json": {"object": "x" * 100, "gripper": "y"}}, 422),
        ("POST", "/v1/grippers", {"json": [1, 2]}, 422),
        ("POST", "/v1/objects", {"data": {"name": "x", "units": "mm"}}, 422),  # no file
        (
            "POST",
            "/v1/jobs",
            {"content": b"[" * (3 * 1024 * 1024), "headers": {"Content-Type": "application/json"}},
            413,
        ),
        ("GET", "/v1/grasp-sets/0", {}, 422),
        ("GET", "/v1/grasp-sets/123456789", {}, 404),
        ("GET", "/v1/grasp-sets/123456789/candidates", {}, 404),
        ("GET", "/v1/grasp-sets/123456789/recording", {}, 404),
        ("GET", "/v1/grasp-sets?object=Not%20A%20Slug", {}, 422),
        ("GET", "/v1/grasp-sets?cursor=%%%", {}, 422),
        ("GET", "/v1/catalogue", {}, 422),  # gripper is required
        ("GET", "/v1/catalogue?gripper=no-such-gripper", {}, 404),
        ("GET", "/v1/catalogue?gripper=x&updated_since=yesterday", {}, 422),
        ("GET", "/v1/catalogue/no-such-object/no-such-gripper", {}, 404),
        ("GET", "/v1/catalogue/a/b?version=0", {}, 422),
        ("GET", "/v1/objects?limit=0", {}, 422),
        ("GET", "/v1/grippers/UPPER", {}, 422),
    ],
)
def test_errors_are_problems_and_change_nothing(pg_service, method, url, kwargs, status):
    before = pg_service.row_counts()
    headers = {**pg_service.h("writer"), **kwargs.pop("headers", {})}
    r = pg_service.client.request(method, url, headers=headers, **kwargs)
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    body = r.json()
    assert body["status"] == status and body["type"].startswith("urn:graspgen:problem:") and body["title"]
    assert body["detail"] and body["code"]
    assert pg_service.row_counts() == before
