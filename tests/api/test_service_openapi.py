"""The OpenAPI document covers the contract's HTTP API, with examples, problem responses and bearer security."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from services_conftest import write_tokens_file

from services.api.app import create_app
from services.common.settings import Settings

CONTRACT_ROUTES = {
    ("post", "/v1/objects"),
    ("get", "/v1/objects"),
    ("get", "/v1/objects/{name}"),
    ("get", "/v1/objects/{name}/versions/{version}"),
    ("get", "/v1/objects/{name}/versions/{version}/file"),
    ("post", "/v1/grippers"),
    ("get", "/v1/grippers"),
    ("get", "/v1/grippers/{name}"),
    ("get", "/v1/grippers/{name}/versions/{version}"),
    ("post", "/v1/jobs"),
    ("post", "/v1/bulk-jobs"),
    ("get", "/v1/jobs/{job_id}"),
    ("post", "/v1/jobs/{job_id}/cancel"),
    ("get", "/v1/grasp-sets"),
    ("get", "/v1/grasp-sets/{grasp_set_id}"),
    ("get", "/v1/grasp-sets/{grasp_set_id}/candidates"),
    ("get", "/v1/grasp-sets/{grasp_set_id}/recording"),
    ("get", "/v1/catalogue/{object}/{gripper}"),
    ("get", "/v1/catalogue"),
    ("get", "/healthz"),
    ("get", "/readyz"),
}


@pytest.fixture(scope="module")
def schema(tmp_path_factory):
    d = tmp_path_factory.mktemp("openapi")
    write_tokens_file(d / "tokens.json")
    app = create_app(Settings(storage_dir=d, tokens_file=d / "tokens.json"), recover_jobs=False)
    with TestClient(app) as c:
        return c.get("/openapi.json").json()


def test_every_contract_route_is_documented(schema):
    documented = {(m, p) for p, ops in schema["paths"].items() for m in ops}
    assert documented >= CONTRACT_ROUTES


def test_protected_routes_declare_bearer_security_and_problems(schema):
    assert schema["components"]["securitySchemes"]["HTTPBearer"]["scheme"] == "bearer"
    assert "Problem" in schema["components"]["schemas"]
    for path, ops in schema["paths"].items():
        for method, op in ops.items():
            if path.startswith("/v1/"):
                assert op.get("security"), (method, path)
                for code in ("401", "403"):
                    content = op["responses"][code]["content"]
                    assert "application/problem+json" in content, (method, path, code)
            assert op.get("summary"), (method, path)


def test_bodies_and_payloads_carry_examples(schema):
    text = str(schema)
    for needle in ("ring-screw", "pgn-80", "graspgen.grasp_set/1", "4f1c7e4e-3c1a-4a59-9d1e-0b7f6f0b9a10"):
        assert needle in text
    job_body = schema["paths"]["/v1/jobs"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    assert job_body["$ref"].endswith("JobRequest")
    assert schema["components"]["schemas"]["JobRequest"]["examples"]
