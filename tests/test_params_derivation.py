"""A run parameter is one field of graspgen.Params (issue 31.4): the CLI's options, the job params schema of the
OpenAPI document and the worker's run are built from the fields, so a field added to Params reaches all three
without another edit. Each builder takes the class (the real Params by default); here they get Params extended by
one field, as a developer would add it to params.py."""

from __future__ import annotations

import json
import uuid
from dataclasses import dataclass

import pytest
from pydantic import ValidationError
from services_conftest import box_stl

from graspgen.cli import _parser, _run_params, main
from graspgen.errors import InvalidParameterError
from graspgen.examples import EXAMPLE_GRIPPER
from graspgen.gripper import GripperSpec
from graspgen.params import Params, QualityOptions, _option, from_job
from graspgen.parts import load_part
from services.api.contract_schemas import JobParams, job_params_model
from services.common.storage import LocalStorage
from services.jobkinds import generate as generate_kind
from services.jobkinds.kind import JobInputs, RunContext


@dataclass(frozen=True)
class Extended(Params):
    """Params with one more run parameter, declared the way params.py declares its own."""

    grip_margin: float = _option(0.25, "a parameter added by this test, m", ge=0, le=1)


CLI_COMMAND = ["generate", "part.stl", "--units", "mm", "--gripper", "g.json", "--out", "o.json"]


def test_a_new_field_is_a_cli_option(capsys):
    with pytest.raises(SystemExit) as done:
        _parser(Extended).parse_args(["generate", "--help"])
    assert done.value.code == 0
    help_text = " ".join(capsys.readouterr().out.split())
    assert "--grip-margin GRIP_MARGIN a parameter added by this test, m (default 0.25)" in help_text
    params, _ = _run_params(_parser(Extended).parse_args([*CLI_COMMAND, "--grip-margin", "0.5"]), Extended)
    assert params == Extended(grip_margin=0.5)
    assert _run_params(_parser(Extended).parse_args(["demo"]), Extended)[0] == Extended()
    with pytest.raises(InvalidParameterError, match="grip_margin must be >= 0.0 and <= 1.0, got 2.0"):
        _run_params(_parser(Extended).parse_args([*CLI_COMMAND, "--grip-margin", "2"]), Extended)
    # the real command line has no such option
    assert main([*CLI_COMMAND, "--grip-margin", "0.5"]) == 2
    assert "unrecognized arguments: --grip-margin 0.5" in capsys.readouterr().err


def test_a_new_field_is_in_the_job_params_schema():
    model = job_params_model(Extended)
    prop = model.model_json_schema()["properties"]["grip_margin"]
    assert prop["type"] == "number" and (prop["minimum"], prop["maximum"]) == (0, 1)
    assert prop["description"] == "a parameter added by this test, m (default 0.25)"
    model.model_validate({"grip_margin": 0.5, "points": 500}, strict=True)
    for bad in ({"grip_margin": 1.5}, {"grip_margin": None}, {"grip_margin": "wide"}):
        with pytest.raises(ValidationError):
            model.model_validate(bad, strict=True)
    # the schema in the OpenAPI document is the one built from the real Params
    assert JobParams.model_json_schema() == job_params_model().model_json_schema()
    assert "grip_margin" not in JobParams.model_json_schema()["properties"]


def _run_context(tmp_path, params: dict) -> RunContext:
    storage = LocalStorage(tmp_path / "storage")
    blob = storage.put_bytes(box_stl())
    inputs = JobInputs(
        job_id=uuid.uuid4(),
        kind="generate",
        attempt=1,
        params=params,
        object_name="box",
        object_version=1,
        object_version_id=1,
        object_id=1,
        object_sha256=blob.sha256,
        object_file_key=blob.key,
        object_format="stl",
        units="mm",
        gripper_name=EXAMPLE_GRIPPER["name"],
        gripper_version=1,
        gripper_version_id=1,
        gripper_id=1,
        spec=dict(EXAMPLE_GRIPPER),
        source_grasp_set_id=None,
        source_export_key=None,
        source_candidates_key=None,
        params_key="unused",
    )
    work = tmp_path / "run"
    work.mkdir(parents=True)
    return RunContext(
        inputs=inputs,
        storage=storage,
        tmp=work,
        recording=None,
        progress=lambda stage, fraction: None,
        load_part=lambda path: load_part(str(path), units="mm", name="box"),
        gripper=lambda: GripperSpec.from_dict(EXAMPLE_GRIPPER),
    )


def test_a_new_field_reaches_the_workers_run(tmp_path):
    # the job row's params as the service stores them: every field, then the job options
    stored = json.loads(json.dumps({**Extended(points=300, k1=2, k2=1, grip_margin=0.75).to_dict(), "validate": False}))
    assert from_job(stored, Extended) == (Extended(points=300, k1=2, k2=1, grip_margin=0.75), QualityOptions())
    result = generate_kind.run(_run_context(tmp_path, stored), Extended)
    export = result.to_json()
    assert export["params"]["grip_margin"] == 0.75  # the run had it: its export states its parameters
    assert export["params"]["points"] == 300 and export["params"]["k1"] == 2 and export["object"]["name"] == "box"
    with pytest.raises(InvalidParameterError, match="unknown parameters grip_margin"):
        generate_kind.run(_run_context(tmp_path / "real", stored))  # the real Params has no such field


CASES = [
    {},
    {"points": 100},
    {"points": 99},
    {"points": 1_000_000},
    {"points": 1_000_001},
    {"friction": None},
    {"friction": 0.0},
    {"hold": None},
    {"mass_kg": None, "density": None},
    {"select": "best-near-medoid", "validate": True},
    {"select": None},
    {"validate": None},
    {"validate": "yes"},
    {"repair_limit": 3},
    {"colour": "red"},
]


@pytest.mark.parametrize("params", CASES)
def test_the_job_schema_accepts_what_the_job_service_accepts(params):
    """The job service hands params to graspgen.params.from_job (Params and the job options): the schema built from
    the same fields must accept exactly that."""
    try:
        from_job(params)
        library = True
    except InvalidParameterError:
        library = False
    try:
        JobParams.model_validate(params, strict=True)
        documented = True
    except ValidationError:
        documented = False
    assert documented == library, params
