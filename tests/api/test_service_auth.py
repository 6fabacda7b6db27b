"""Bearer tokens: 401 without a valid token, 403 without the scope, hashed tokens file, rotation without restart."""

from __future__ import annotations

import json

import pytest
from services_conftest import write_tokens_file

from services.common.tokens import Principal, TokensFileError, TokenStore, bootstrap_tokens_file, hash_token

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"

PROTECTED = [
    ("GET", "/v1/objects"),
    ("GET", "/v1/objects/x"),
    ("GET", "/v1/grippers"),
    ("GET", "/v1/grasp-sets"),
    ("GET", "/v1/grasp-sets/1"),
    ("GET", "/v1/catalogue?gripper=x"),
    ("GET", "/v1/catalogue/x/y"),
    ("GET", "/v1/jobs/4f1c7e4e-3c1a-4a59-9d1e-0b7f6f0b9a10"),
    ("POST", "/v1/objects"),
    ("POST", "/v1/grippers"),
    ("POST", "/v1/jobs"),
    ("POST", "/v1/bulk-jobs"),
    ("POST", "/v1/jobs/4f1c7e4e-3c1a-4a59-9d1e-0b7f6f0b9a10/cancel"),
]


@pytest.mark.parametrize(("method", "url"), PROTECTED)
def test_every_route_needs_a_valid_token(pg_service, method, url):
    for headers in (
        {},
        {"Authorization": "Bearer nope"},
        {"Authorization": "Basic dXNlcjpwYXNz"},
        {"Authorization": f"Bearer {pg_service.tokens['reader']}x"},
    ):
        r = pg_service.client.request(method, url, headers=headers)
        assert r.status_code == 401, (headers, r.text)
        assert r.headers["content-type"] == PROBLEM and r.headers["www-authenticate"].startswith("Bearer")


@pytest.mark.parametrize(("method", "url"), [p for p in PROTECTED if p[0] == "POST"])
def test_read_scope_cannot_write(pg_service, method, url):
    before = pg_service.row_counts()
    r = pg_service.client.request(method, url, headers=pg_service.h("reader"), json={})
    assert r.status_code == 403 and r.headers["content-type"] == PROBLEM
    assert r.json()["required_scope"] == "write"
    assert pg_service.row_counts() == before


def test_write_and_admin_include_read(pg_service):
    for who in ("writer", "admin"):
        assert pg_service.get("/v1/objects", who=who).status_code == 200


def test_health_needs_no_token(pg_service):
    assert pg_service.client.get("/healthz").json()["status"] == "ok"
    ready = pg_service.client.get("/readyz")
    assert ready.status_code == 200 and ready.json()["checks"] == {"database": "ok", "broker": "ok", "storage": "ok"}


def test_token_store_hashes_rotates_and_fails_fast(tmp_path):
    path = tmp_path / "tokens.json"
    tokens = write_tokens_file(path)
    assert all(t not in path.read_text() for t in tokens.values())  # only hashes on disk
    store = TokenStore(path)
    assert store.authenticate(tokens["reader"]) == Principal("reader", frozenset({"read"}))
    assert store.authenticate("wrong") is None
    # rotation: a rewritten file is picked up without a restart
    path.write_text(json.dumps({"tokens": [{"name": "new", "sha256": hash_token("fresh-token"), "scopes": ["write"]}]}))
    import os

    os.utime(path, ns=(1, 1))
    assert store.authenticate("fresh-token").name == "new"
    assert store.authenticate(tokens["reader"]) is None
    # a broken rewrite keeps the last good set rather than locking everyone out
    path.write_text("{broken")
    assert store.authenticate("fresh-token").name == "new"
    for bad in (
        "{broken",
        '{"tokens": [{"name": "a", "sha256": "xyz", "scopes": ["read"]}]}',
        '{"tokens": [{"name": "a", "sha256": "' + "0" * 64 + '", "scopes": ["root"]}]}',
    ):
        path.write_text(bad)
        with pytest.raises(TokensFileError):
            TokenStore(path)
    with pytest.raises(TokensFileError):
        TokenStore(tmp_path / "missing.json")


def test_bootstrap_creates_one_admin_token_once(tmp_path):
    path = tmp_path / "var" / "tokens.json"
    token = bootstrap_tokens_file(path)
    assert token and token not in path.read_text()
    assert TokenStore(path).authenticate(token).has("admin")
    assert oct(path.stat().st_mode & 0o777) == "0o600"
    assert bootstrap_tokens_file(path) is None
