"""Every corpus entry through the API: meshes to POST /v1/objects, gripper specs to POST /v1/grippers, run parameters
to POST /v1/jobs. Refused input is a 422 application/problem+json naming the problem, with no database row and no
stored blob added; an accepted-with-warning mesh is stored with the warning in its version."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import pytest
from corpus_cases import code, corpus_params, known_pair, says
from services_conftest import GRIPPER, PG_URL, slug

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"


def _storage(service) -> set[str]:  # type: ignore[no-untyped-def]
    root = Path(service.settings.storage_dir)
    return {str(p.relative_to(root)) for p in root.rglob("*")} if root.exists() else set()


@pytest.fixture(scope="module")
def known(pg_service) -> dict[str, str]:
    """An object and a gripper that exist, for the job-parameter entries."""
    return known_pair(pg_service, "corpus")


def _send(service, case: dict[str, Any], known: dict[str, str]):  # type: ignore[no-untyped-def]
    if case["kind"] == "mesh":
        data = {"name": slug("corpus")}
        if case["units"] is not None:
            data["units"] = case["units"]
        files = {"file": (case["path"].name, case["path"].read_bytes(), "application/octet-stream")}
        return service.post("/v1/objects", files=files, data=data)
    if case["kind"] == "gripper":
        body = case["path"].read_bytes().replace(b'"pgn-80"', f'"{slug("corpus-grip")}"'.encode())
        return service.post("/v1/grippers", content=body, headers={"Content-Type": "application/json"})
    return service.post("/v1/jobs", json={**known, "params": case["params"]})


@pytest.mark.parametrize("case", corpus_params())
def test_api(pg_service, known, case):
    rows, blobs = pg_service.row_counts(), _storage(pg_service)
    r = _send(pg_service, case, known)
    text = r.text
    # no secret, no stack trace, no server path (the upload's temp file, the storage directory)
    server_paths = ("graspgen-upload", tempfile.gettempdir() + "/", str(pg_service.settings.storage_dir))
    for secret in (*pg_service.tokens.values(), PG_URL, "postgresql", "Traceback", 'File "', *server_paths):
        assert secret not in text
    if case["expect"] == "warn" or (case["expect"] == "reject-or-warn" and r.status_code < 300):
        assert r.status_code == 201, text
        warnings = " ".join(r.json()["warnings"]).lower()
        assert all(s.lower() in warnings for s in says(case, api=True)), warnings
        return
    assert r.status_code == 422, text
    assert r.headers["content-type"] == PROBLEM
    body = r.json()
    assert body["status"] == 422 and body["title"] and body["instance"] == r.request.url.path
    assert body["code"] == (code(case) or body["code"]) and body["type"] == f"urn:graspgen:problem:{body['code']}"
    for s in says(case, api=True):
        assert s.lower() in body["detail"].lower(), (s, body["detail"])
    if "field" in case:
        assert body.get("field") == case["field"], body
    assert pg_service.row_counts() == rows
    assert _storage(pg_service) == blobs


def test_gripper_fixture_is_the_corpus_baseline():
    """The corpus's good gripper is the service tests' gripper plus the optional min_width: the gripper entries
    each change one thing from a spec the API accepts."""
    import json

    from corpus_cases import GOOD_GRIPPER

    good = json.loads(GOOD_GRIPPER.read_text())
    assert {k: v for k, v in good.items() if k != "min_width"} == GRIPPER
