"""The `generate` job kind: grasps for an object version and a gripper version (graspgen.generate). A job that names
no kind is one of these (CONTRACT.md), and so is every item of a bulk job."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import ConfigDict, Field
from sqlalchemy.orm import Session

from graspgen.kinds import check_params_for_kind
from graspgen.params import Params, QualityOptions, from_job
from services.api.schemas import ID_MAX, PARAMS_DOC, PARAMS_EXAMPLE, SLUG, BulkItem, NoNulModel
from services.common.grippers import gripper_kind
from services.common.versions import GRIPPERS, OBJECTS, Versioned, find_version

from .kind import JobKind, RunContext
from .params import JOB_PARAM_NAMES, split_quality

if TYPE_CHECKING:
    from graspgen.export import GraspSet

__all__ = ["KIND", "GenerateJobRequest", "resolve", "run"]


class GenerateJobRequest(NoNulModel):
    """Grasps for an object and a gripper (their newest versions unless given) with the given params."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"object": "ring-screw", "gripper": "pgn-80", "params": PARAMS_EXAMPLE},
                {
                    "kind": "generate",
                    "object": "ring-screw",
                    "gripper": "pgn-80",
                    "params": {**PARAMS_EXAMPLE, "validate": True, "select": "best-near-medoid", "density": 7850},
                },
            ]
        },
    )
    kind: Literal["generate"] = Field("generate", description="may be left out: the default kind")
    object: str = Field(pattern=SLUG, description="object name")
    object_version: int | None = Field(None, ge=1, le=ID_MAX, description="default: the newest version")
    gripper: str = Field(pattern=SLUG, description="gripper name")
    gripper_version: int | None = Field(None, ge=1, le=ID_MAX, description="default: the newest version")
    params: Annotated[dict[str, Any] | None, PARAMS_DOC] = Field(
        None,
        description=f"any of {', '.join(JOB_PARAM_NAMES)} (JobParams: each one's type, range and default). "
        "mass_kg defaults to the object version's mass_kg unless density is given; validate (simulate every exported "
        "grasp in MuJoCo under four settings and repair failures) and select: docs/QUALITY.md; criterion (e) "
        "(mass_kg or density, accel, hold) and position_tolerance: CONTRACT.md.",
        examples=[
            {"points": 10000, "k1": 16, "k2": 4, "validate": True, "select": "best-near-medoid", "density": 7850}
        ],
    )


# -- submission (the API) ---------------------------------------------------------------------------------------------
def _version(session: Session, kind: Versioned, name: str, version: int | None) -> Any:
    """The object's or gripper's given version (an ObjectVersion or a GripperVersion, as `kind` says), or its newest;
    422 `unknown-<what>` when there is none."""
    from services.api.problems import ApiError  # the worker imports this module for `run` and never loads the API

    v = find_version(session, kind, name, version)
    if v is None:
        label = f"{kind.what} {name!r}" + (f" version {version}" if version else "")
        raise ApiError(422, f"unknown-{kind.what}", f"there is no {label}", field=kind.what)
    return v


def _effective_params(
    given: dict[str, Any] | None, spec: dict[str, Any], mass_kg: float | None = None
) -> dict[str, Any]:
    """graspgen.Params with friction resolved from the gripper (a parallel gripper's or a suction cup's) and the
    object version's mass when the job gives neither mass_kg nor density: the stored params say exactly what the run
    used."""
    core, quality = split_quality(given)
    if mass_kg is not None and core.get("mass_kg") is None and core.get("density") is None:
        core["mass_kg"] = mass_kg
    p = Params.from_dict(core)  # InvalidParameterError -> 422
    effective = {**p.to_dict(friction=p.friction if p.friction is not None else float(spec["friction"])), **quality}
    # params the gripper's kind cannot use: 422 now, not a failed job
    check_params_for_kind(gripper_kind(spec), p, QualityOptions.split_job(quality)[1])
    return effective


def resolve(session: Session, body: GenerateJobRequest | BulkItem) -> dict[str, Any]:
    """A `POST /v1/jobs` body or a bulk item (the same fields): the newest versions unless given, and the params."""
    ov = _version(session, OBJECTS, body.object, body.object_version)
    gv = _version(session, GRIPPERS, body.gripper, body.gripper_version)
    return {
        "object_version_id": ov.id,
        "gripper_version_id": gv.id,
        "params": _effective_params(body.params, gv.spec, ov.mass_kg),
    }


# -- the run (the worker) ---------------------------------------------------------------------------------------------
def run(
    ctx: RunContext, params_cls: type[Params] = Params, options_cls: type[QualityOptions] = QualityOptions
) -> GraspSet:
    """graspgen.generate with the job's stored params, as `params_cls` and `options_cls` (graspgen.params.from_job):
    every field of Params reaches the run without naming it here."""
    import graspgen

    inp = ctx.inputs
    params, options = from_job(inp.params, params_cls, options_cls)
    loaded = ctx.load_part(ctx.download_part())  # MemoryLimitError: the job fails, never redelivered
    return graspgen.generate(
        loaded,
        ctx.gripper(),  # with its meshes when the spec has geometry
        units=inp.units,
        params=params,
        options=options,
        recording=ctx.recording,
        progress=ctx.progress,
        object_name=inp.object_name,
        object_version=inp.object_version,
    )


KIND = JobKind(
    name="generate",
    request=GenerateJobRequest,
    resolve=resolve,
    run=run,
    # "validate" (MuJoCo simulation of the exported grasps, four simulations each: physics.validation_set) counts
    # only with params.validate; it then takes most of a job's time
    stage_weights={
        "load": 0.01,
        "sample": 0.03,
        "pairs": 0.12,
        "collision": 0.14,
        "cluster": 0.04,
        "validate": 0.64,
        "export": 0.02,
    },
    checks_memory=True,
)
