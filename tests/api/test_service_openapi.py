"""The OpenAPI document covers the contract's HTTP API, with examples, problem responses and bearer security."""

from __future__ import annotations

import re

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
    ("post", "/v1/pick"),
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


def test_the_job_kinds_documented_are_the_registry(schema):
    """`POST /v1/jobs` takes one body per kind that runs (services/jobkinds), `GET /v1/jobs?kind=` every kind."""
    from services.jobkinds import KINDS, RUNNABLE

    body = schema["components"]["schemas"]["JobRequest"]
    mapping = body["discriminator"]["mapping"]
    assert body["discriminator"]["propertyName"] == "kind" and set(mapping) == set(RUNNABLE)
    assert sorted(ref["$ref"] for ref in body["oneOf"]) == sorted(mapping.values())
    for name, ref in mapping.items():
        variant = schema["components"]["schemas"][ref.rsplit("/", 1)[1]]
        assert variant["properties"]["kind"]["const"] == name and variant["additionalProperties"] is False
    (kind,) = [p for p in schema["paths"]["/v1/jobs"]["get"]["parameters"] if p["name"] == "kind"]
    (pattern,) = [s["pattern"] for s in kind["schema"]["anyOf"] if "pattern" in s]
    assert all(re.fullmatch(pattern, name) for name in KINDS)
    assert not any(re.fullmatch(pattern, bad) for bad in ("nope", "", "generate|cluster", "Generate"))


def test_the_candidate_view_parameters_are_documented(schema):
    op = schema["paths"]["/v1/grasp-sets/{grasp_set_id}/candidates"]["get"]
    params = {p["name"]: p for p in op["parameters"] if p["in"] == "query"}
    assert set(params) == {"arrays", "max_rows"}
    assert all(not p.get("required") and p.get("description") and p["schema"].get("examples") for p in params.values())
    rows = params["max_rows"]["schema"]["anyOf"][0]
    assert rows["type"] == "integer" and rows["minimum"] == 1
    assert "row_count" in op["description"] and "rows" in op["description"]


def test_operation_ids_are_readable_and_unique(schema):
    ids = [op["operationId"] for ops in schema["paths"].values() for op in ops.values()]
    assert len(ids) == len(set(ids))
    for op_id in ids:
        assert re.fullmatch(r"[a-z][a-zA-Z0-9]*", op_id) and len(op_id) <= 40, op_id
    by_route = {(m, p): op["operationId"] for p, ops in schema["paths"].items() for m, op in ops.items()}
    assert by_route[("get", "/v1/objects/{name}")] == "getObject"
    assert by_route[("get", "/v1/objects")] == "listObjects"
    assert by_route[("post", "/v1/jobs")] == "submitJob"
    assert by_route[("post", "/v1/pick")] == "pick"


def test_every_error_response_is_a_problem_document(schema):
    assert "HTTPValidationError" not in schema["components"]["schemas"]
    for path, ops in schema["paths"].items():
        for method, op in ops.items():
            for code, response in op["responses"].items():
                if code[0] in "45":
                    content = response.get("content", {})
                    assert list(content) == ["application/problem+json"], (method, path, code)
                    assert content["application/problem+json"]["schema"] == {"$ref": "#/components/schemas/Problem"}


def test_contract_payloads_are_typed_with_units_and_examples(schema):
    components = schema["components"]["schemas"]
    spec = components["GripperSpec"]
    assert spec["additionalProperties"] is False and "grip_force" in spec["properties"]
    assert "m" in spec["properties"]["stroke"]["description"] and spec["examples"]
    assert "N" in spec["properties"]["grip_force"]["description"]
    params = components["JobParams"]["properties"]
    for name in (
        "points",
        "friction",
        "safety_factor",
        "rolls",
        "k1",
        "k2",
        "inside",
        "collision",
        "seed",
        "mass_kg",
        "density",
        "accel",
        "hold",
        "position_tolerance",
        "select",
        "validate",
    ):
        assert name in params, name
    export = components["GraspSetExport"]
    assert export["properties"]["format"]["const"] == "graspgen.grasp_set/1"
    assert components["ExportGrasp"]["additionalProperties"] is True  # new library fields pass through
    gripper_body = schema["paths"]["/v1/grippers"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    assert gripper_body["allOf"] == [{"$ref": "#/components/schemas/AnyGripperSpec"}]
    kinds = {ref["$ref"] for ref in components["AnyGripperSpec"]["anyOf"]}
    assert kinds == {"#/components/schemas/GripperSpec", "#/components/schemas/SuctionGripperSpec"}
    cup = components["SuctionGripperSpec"]
    assert cup["additionalProperties"] is False and cup["examples"] and "kind" in cup["required"]
    assert "Pa" in cup["properties"]["vacuum"]["description"]
    assert "m" in cup["properties"]["cup_radius"]["description"]
    for kind_ref in components["JobRequest"]["oneOf"]:  # each job kind's body (services/jobkinds)
        job_params = components[kind_ref["$ref"].rsplit("/", 1)[1]]["properties"]["params"]
        assert {"$ref": "#/components/schemas/JobParams"} in job_params["anyOf"]
    for path in ("/v1/grasp-sets/{grasp_set_id}", "/v1/catalogue/{object}/{gripper}"):
        ok = schema["paths"][path]["get"]["responses"]["200"]["content"]["application/json"]
        assert ok["schema"] == {"$ref": "#/components/schemas/GraspSetExport"}
    pick = schema["paths"]["/v1/pick"]["post"]
    assert pick["requestBody"]["content"]["application/json"]["schema"]["$ref"].endswith("PickRequest")
    assert pick["responses"]["200"]["content"]["application/json"]["schema"]["$ref"].endswith("PickResponse")
    grasp = components["PickedGrasp"]["properties"]
    assert {"T_world_grasp", "quaternion_xyzw", "T_world_pregrasp", "T_world_flange", "approach_angle_deg"} <= set(
        grasp
    )
    assert components["PickRequest"]["examples"]


GRIPPER_CASES = [
    {},
    {"stroke": 0.0},
    {"stroke": 3.0},
    {"finger_width": -0.01},
    {"palm_depth": None},
    {"min_width": None},
    {"palm_width": None},
    {"grip_force": 20.0},
    {"grip_force": 0.0},
    {"friction": 0.0},
    {"pregrasp_clearance": -0.001},
    {"name": "Bad Name"},
    {"colour": "red"},
]


def _accepts(check, value, refusals) -> bool:  # type: ignore[no-untyped-def]
    """Whether `check(value)` passes; False when it raises one of `refusals` (anything else is a test error)."""
    try:
        check(value)
    except refusals:
        return False
    return True


@pytest.mark.parametrize("change", GRIPPER_CASES)
def test_the_gripper_schema_accepts_what_the_library_accepts(change):
    """The typed schema documents graspgen's own validation: it must not accept or refuse differently."""
    from pydantic import ValidationError

    from graspgen.errors import InvalidGripperError
    from graspgen.examples import EXAMPLE_GRIPPER
    from graspgen.gripper import GripperSpec
    from services.api.contract_schemas import AnyGripperSpec
    from services.api.contract_schemas import GripperSpec as GripperSpecDoc

    spec = {**EXAMPLE_GRIPPER, **change}
    library = _accepts(GripperSpec.from_dict, spec, InvalidGripperError)
    documented = _accepts(lambda s: GripperSpecDoc.model_validate(s, strict=True), spec, ValidationError)
    either = _accepts(lambda s: AnyGripperSpec.model_validate(s, strict=True), spec, ValidationError)
    assert documented == library == either, spec


CUP_CASES = [
    {},
    {"cup_radius": 0.0},
    {"cup_radius": 15.0},
    {"cup_height": -0.01},
    {"max_strain": 0.99},
    {"max_strain": 1.0},
    {"vacuum": 101325},
    {"vacuum": 101326},
    {"friction": 10.0},
    {"friction": 10.5},
    {"pregrasp_clearance": 0.0},
    {"pregrasp_clearance": -0.001},
    {"tool": None},
    {"tool": {"radius": 0.012}},
    {"tool": {"radius": 0.012, "length": 0.0}},
    {"tool": {"radius": 0.012, "length": 0.1, "colour": "red"}},
    {"kind": None},
    {"kind": "magnetic"},
    {"name": "Bad Name"},
    {"stroke": 0.08},
    {"colour": "red"},
]


@pytest.mark.parametrize("change", CUP_CASES)
def test_the_suction_schema_accepts_what_the_library_accepts(change):
    """The typed cup schema, and the union of both kinds, accept and refuse what graspgen.kinds does (a cup without
    its tool: `None` in a change removes the field)."""
    from pydantic import ValidationError

    from graspgen.errors import InvalidGripperError
    from graspgen.kinds import gripper_from_dict
    from services.api.contract_schemas import AnyGripperSpec, SuctionGripperSpec
    from services.api.schemas import SUCTION_SPEC_EXAMPLE

    spec = {k: v for k, v in {**SUCTION_SPEC_EXAMPLE, **change}.items() if v is not None}
    library = _accepts(gripper_from_dict, spec, InvalidGripperError)
    documented = _accepts(lambda s: SuctionGripperSpec.model_validate(s, strict=True), spec, ValidationError)
    either = _accepts(lambda s: AnyGripperSpec.model_validate(s, strict=True), spec, ValidationError)
    assert documented == library == either, spec


PARAM_CASES = [
    {},
    {"points": 99},
    {"points": 100},
    {"points": 1_000_001},
    {"rolls": 64},
    {"rolls": 65},
    {"k1": 0},
    {"k2": 1000},
    {"seed": -1},
    {"safety_factor": 0.5},
    {"friction": 0.0},
    {"friction": 10.0},
    {"inside": True},
    {"collision": "paper"},
    {"collision": "exact"},
    {"colour": "red"},
    {"points": None},
    {"friction": None},
    {"mass_kg": 2.5},
    {"mass_kg": 0.0},
    {"density": 7850},
    {"density": 0.5},
    {"accel": 1000.0},
    {"accel": 1001.0},
    {"hold": "off"},
    {"hold": "maybe"},
    {"position_tolerance": 0.05},
    {"position_tolerance": 0.06},
]


@pytest.mark.parametrize("params", PARAM_CASES)
def test_the_params_schema_accepts_what_the_library_accepts(params):
    from pydantic import ValidationError

    from graspgen.errors import InvalidParameterError
    from graspgen.params import Params
    from services.api.contract_schemas import JobParams

    library = _accepts(Params.from_dict, params, (InvalidParameterError, TypeError))
    documented = _accepts(lambda p: JobParams.model_validate(p, strict=True), params, ValidationError)
    assert documented == library, params
