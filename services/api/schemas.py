"""Request and response bodies of the HTTP API (CONTRACT.md), with the examples the OpenAPI document shows."""

from __future__ import annotations

import uuid
from datetime import datetime
from typing import Annotated, Any, Literal, cast

from pydantic import BaseModel, ConfigDict, Field, WithJsonSchema, model_validator

from graspgen.examples import EXAMPLE_CUP, EXAMPLE_GRIPPER
from graspgen.gripper import SLUG_PATTERN

SLUG = SLUG_PATTERN.pattern
#: ids and version numbers are PostgreSQL `integer` columns: a larger number is no such row, never a database error
ID_MAX = 2**31 - 1

# Any: pydantic types json_schema_extra as JSON values, which dict[str, object] is not to mypy
_GRIPPER_EXAMPLE: dict[str, Any] = dict(EXAMPLE_GRIPPER)
#: examples/cup-30.json, the contract's suction cup
SUCTION_SPEC_EXAMPLE: dict[str, Any] = dict(EXAMPLE_CUP)
PARAMS_EXAMPLE: dict[str, Any] = {"points": 10000, "safety_factor": 1.5, "rolls": 16, "k1": 16, "k2": 4, "seed": 0}


class Links(BaseModel):
    model_config = ConfigDict(extra="allow")
    self: str


# -- objects ----------------------------------------------------------------------------------------------------------
class ObjectVersionOut(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "example": {
                "name": "ring-screw",
                "version": 3,
                "sha256": "9f2c...",
                "units": "mm",
                "format": "stl",
                "size_bytes": 184284,
                "extents": [0.042, 0.042, 0.018],
                "watertight": True,
                "warnings": [],
                "created_at": "2026-11-23T16:00:00Z",
                "links": {
                    "self": "/v1/objects/ring-screw/versions/3",
                    "file": "/v1/objects/ring-screw/versions/3/file",
                },
            }
        }
    )
    name: str
    version: int
    sha256: str
    units: str = Field(description="the unit the file was given in; stored data is in metres")
    format: str
    size_bytes: int
    extents: list[float] = Field(description="bounding-box extents, metres")
    watertight: bool
    warnings: list[str]
    mass_kg: float | None = Field(None, description="the part's mass in kg, if given at upload")
    created_at: datetime
    links: dict[str, str]


class _Named(BaseModel):
    # objects and grippers alike (crud/versioned.named_out); each subclass adds its versions and links
    name: str
    latest_version: int
    created_at: datetime
    updated_at: datetime


class ObjectOut(_Named):
    versions: list[ObjectVersionOut]
    links: dict[str, str]


class _NamedSummary(BaseModel):
    # an object or gripper in a list (crud/versioned.list_page)
    name: str
    latest_version: int
    updated_at: datetime
    links: dict[str, str]


class ObjectSummary(_NamedSummary):
    pass


class Page(BaseModel):
    next_cursor: str | None = Field(None, description="pass as ?cursor= for the next page; null on the last page")
    links: dict[str, str | None] = Field(default_factory=dict)


class ObjectPage(Page):
    items: list[ObjectSummary]


# -- grippers ---------------------------------------------------------------------------------------------------------
#: documented by contract_schemas.AnyGripperSpec (either kind); stored specs are the to_dict() of graspgen's validated
#: spec of their kind (graspgen.kinds)
_SPEC_DOC = WithJsonSchema({"allOf": [{"$ref": "#/components/schemas/AnyGripperSpec"}]})


class GripperFileOut(BaseModel):
    path: str = Field(description="the file name as the spec's geometry gives it")
    sha256: str
    link: str = Field(description="GET it here")


class GripperVersionOut(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "example": {
                "name": "pgn-80",
                "version": 1,
                "spec": _GRIPPER_EXAMPLE,
                "created_at": "2026-11-23T16:00:00Z",
                "links": {"self": "/v1/grippers/pgn-80/versions/1"},
            }
        }
    )
    name: str
    version: int
    spec: Annotated[dict[str, Any], _SPEC_DOC]
    files: list[GripperFileOut] = Field(
        default_factory=list, description="a spec with geometry: its mesh files, by name; a box spec: none"
    )
    created_at: datetime
    links: dict[str, str]


class GripperOut(_Named):
    spec: Annotated[dict[str, Any], _SPEC_DOC] = Field(description="the latest version's spec")
    versions: list[GripperVersionOut]
    links: dict[str, str]


class GripperSummary(_NamedSummary):
    pass


class GripperPage(Page):
    items: list[GripperSummary]


GRIPPER_SPEC_EXAMPLE = _GRIPPER_EXAMPLE


def _has_nul(value: Any) -> bool:
    if isinstance(value, str):
        return "\x00" in value
    if isinstance(value, dict):
        return any(_has_nul(k) or _has_nul(v) for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return any(_has_nul(v) for v in value)
    return False


class NoNulModel(BaseModel):
    """Requests are stored as PostgreSQL JSONB, which cannot hold a NUL character: refuse it as invalid input."""

    @model_validator(mode="after")
    def _no_nul(self) -> Any:
        if _has_nul(self.model_dump()):
            raise ValueError("text must not contain NUL (\\u0000) characters")
        return self


# -- jobs -------------------------------------------------------------------------------------------------------------
# the body of POST /v1/jobs is services.jobkinds.JobRequest, one request model per job kind built from these pieces
#: job params are documented by contract_schemas.JobParams and validated by graspgen's Params (one set of messages)
PARAMS_DOC = WithJsonSchema({"anyOf": [{"$ref": "#/components/schemas/JobParams"}, {"type": "null"}]})


class BulkItem(NoNulModel):
    model_config = ConfigDict(extra="forbid")
    object: str = Field(max_length=200)
    object_version: int | None = Field(None, ge=1, le=ID_MAX)
    gripper: str = Field(max_length=200)
    gripper_version: int | None = Field(None, ge=1, le=ID_MAX)
    params: Annotated[dict[str, Any] | None, PARAMS_DOC] = None


class BulkRequest(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "example": {
                "items": [
                    {"object": "ring-screw", "gripper": "pgn-80", "params": {"points": 5000}},
                    {"object": "bracket-7", "gripper": "pgn-80"},
                ]
            }
        },
    )
    items: list[BulkItem] = Field(min_length=1)


class JobItem(BaseModel):
    index: int
    id: uuid.UUID
    state: str
    stage: str | None
    progress: float
    object: str | None
    gripper: str | None
    grasp_set: int | None
    error: dict[str, Any] | None
    links: dict[str, str]


class JobOut(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "example": {
                "id": "4f1c7e4e-3c1a-4a59-9d1e-0b7f6f0b9a10",
                "kind": "generate",
                "state": "running",
                "stage": "collision",
                "progress": 0.62,
                "grasp_set": None,
                "error": None,
                "object": "ring-screw",
                "object_version": 3,
                "gripper": "pgn-80",
                "gripper_version": 1,
                "params": {**PARAMS_EXAMPLE, "friction": 0.5, "inside": False, "collision": "swept"},
                "attempts": 1,
                "created_at": "2026-11-23T16:00:00Z",
                "started_at": "2026-11-23T16:00:01Z",
                "finished_at": None,
                "links": {"self": "/v1/jobs/4f1c7e4e-3c1a-4a59-9d1e-0b7f6f0b9a10"},
            }
        }
    )
    id: uuid.UUID
    kind: str
    state: Literal["queued", "running", "succeeded", "failed", "cancelled"]
    stage: str | None
    progress: float = Field(ge=0, le=1)
    grasp_set: int | None = None
    error: dict[str, Any] | None = Field(None, description="problem details of a failed job")
    object: str | None = None
    object_version: int | None = None
    gripper: str | None = None
    gripper_version: int | None = None
    source_grasp_set: int | None = None
    params: dict[str, Any] | None = None
    request: dict[str, Any] | None = None
    attempts: int = 0
    cancel_requested: bool = False
    parent: uuid.UUID | None = None
    summary: dict[str, int] | None = Field(
        None, description="bulk: children per state; the parent is `succeeded` only when every item succeeded"
    )
    items: list[JobItem] | None = Field(None, description="bulk: every item's state")
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    links: dict[str, str]


class JobSummary(BaseModel):
    id: uuid.UUID
    kind: str
    state: Literal["queued", "running", "succeeded", "failed", "cancelled"]
    stage: str | None
    progress: float = Field(ge=0, le=1)
    grasp_set: int | None = None
    error: dict[str, Any] | None = None
    object: str | None = None
    gripper: str | None = None
    created_by: str = Field(description="name of the token that submitted it")
    created_at: datetime
    finished_at: datetime | None = None
    links: dict[str, str]


class JobPage(Page):
    items: list[JobSummary]


def _extra(model: type[BaseModel]) -> dict[str, Any]:
    """A model's json_schema_extra, which this module always gives as a dict (pydantic also allows a callable)."""
    return cast(dict[str, Any], model.model_config["json_schema_extra"])


# -- grasp sets -------------------------------------------------------------------------------------------------------
class GraspSetSummary(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "example": {
                "id": 17,
                "object": "ring-screw",
                "object_version": 3,
                "gripper": "pgn-80",
                "gripper_version": 1,
                "version": 2,
                "params": {**PARAMS_EXAMPLE, "friction": 0.5, "inside": False, "collision": "swept"},
                "derived_from": None,
                "job": "4f1c7e4e-3c1a-4a59-9d1e-0b7f6f0b9a10",
                "grasp_count": 64,
                "sha256": "5be1...",
                "etag": '"5be1..."',
                "created_at": "2026-11-23T16:00:04Z",
                "links": {
                    "self": "/v1/grasp-sets/17",
                    "candidates": "/v1/grasp-sets/17/candidates",
                    "recording": "/v1/grasp-sets/17/recording",
                    "grasps": "/v1/grasp-sets/17/grasps",
                    "preview": "/v1/grasp-sets/17/preview.png",
                    "catalogue": "/v1/catalogue/ring-screw/pgn-80?version=2",
                },
            }
        }
    )
    id: int
    object: str
    object_version: int
    gripper: str
    gripper_version: int
    version: int = Field(description="numbered per (object, gripper) pair; the highest is the newest")
    params: dict[str, Any]
    derived_from: int | None
    job: uuid.UUID
    grasp_count: int
    sha256: str = Field(description="sha256 of the export bytes (the strong ETag without quotes)")
    etag: str
    created_at: datetime
    withdrawn_at: datetime | None = Field(None, description="set when withdrawn: the catalogue never serves it")
    links: dict[str, str]


class GraspSetPage(Page):
    items: list[GraspSetSummary]


class GraspOut(BaseModel):
    rank: int
    pose: list[list[float]]
    width: float | None = Field(description="a parallel grasp's contact distance, m; null for a suction grasp")
    contacts: list[list[float]] = Field(description="two contacts (parallel), one (suction: the pose's origin)")
    normals: list[list[float]]
    friction_margin_deg: float | None = Field(description="a parallel grasp's friction margin; null for suction")
    free_rolls_deg: list[float]
    cluster: list[int]
    cluster_size: int


class GraspPage(Page):
    items: list[GraspOut]


# -- catalogue (releases, fleet sync) ---------------------------------------------------------------------------------
class CatalogueItem(BaseModel):
    """A grasp-set summary with its pair's state, or a pair that serves nothing now (`id` null, `withdrawn` true)."""

    model_config = ConfigDict(extra="allow")
    id: int | None
    object: str
    gripper: str
    released: bool = Field(description="the current set is the pair's released set")
    stale: bool = Field(description="released, but made for an older object or gripper version")
    withdrawn: bool = Field(description="the pair serves nothing now: drop what you hold for it")
    change_seq: int = Field(description="the change number of the pair's last change")
    links: dict[str, str]


class CataloguePage(Page):
    gripper: str
    items: list[CatalogueItem]
    next_since: int = Field(description="send as ?since= next time; every change up to it is in this answer")


class CatalogueEventOut(BaseModel):
    grasp_set: int
    version: int
    action: Literal["release", "withdraw"]
    at: datetime
    by: str = Field(description="name of the token that did it")
    replaced: int | None = Field(None, description="a release: the previously released set")
    links: dict[str, str]


class CatalogueHistoryPage(Page):
    object: str
    gripper: str
    items: list[CatalogueEventOut]


class CatalogueChange(BaseModel):
    grasp_set: int
    version: int
    object: str
    gripper: str
    action: Literal["release", "withdraw"]
    changed: bool = Field(description="false: it was already so; nothing was recorded")
    event: CatalogueEventOut | None
    current: int | None = Field(description="the set the catalogue serves for the pair now")
    released: int | None = Field(description="the pair's released set now")
    stale: bool
    change_seq: int
    links: dict[str, str]


class PairSetSummary(GraspSetSummary):
    created_by: str | None = Field(None, description="name of the token whose job computed it")


class PairItem(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "example": {
                "object": "ring-screw",
                "gripper": "pgn-80",
                "current": {**_extra(GraspSetSummary)["example"], "created_by": "plant-7"},
                "released": True,
                "released_id": 17,
                "stale": False,
                "updated_at": "2026-11-23T16:10:00Z",
                "change_seq": 412,
                "last_event": {
                    "grasp_set": 17,
                    "version": 2,
                    "action": "release",
                    "at": "2026-11-23T16:10:00Z",
                    "by": "cell-engineer",
                    "replaced": None,
                    "links": {"grasp_set": "/v1/grasp-sets/17"},
                },
                "links": {
                    "catalogue": "/v1/catalogue/ring-screw/pgn-80",
                    "history": "/v1/catalogue/ring-screw/pgn-80/history",
                    "grasp_sets": "/v1/grasp-sets?object=ring-screw&gripper=pgn-80",
                },
            }
        }
    )
    object: str
    gripper: str
    current: PairSetSummary | None = Field(
        description="the set the catalogue serves for the pair (GET /v1/catalogue/{object}/{gripper}); null when it "
        "serves nothing (every set withdrawn, or none made yet for the newest object and gripper versions)"
    )
    released: bool = Field(description="the current set is the pair's released set")
    released_id: int | None = Field(description="the pair's released set, if any")
    stale: bool = Field(description="released, but made for an older object or gripper version")
    updated_at: datetime = Field(description="when what the pair serves last changed")
    change_seq: int = Field(description="the change number of that change (fleet sync's `since`)")
    last_event: CatalogueEventOut | None = Field(description="the pair's newest release or withdrawal and who made it")
    links: dict[str, str]


class PairPage(Page):
    items: list[PairItem]
    total: int = Field(description="pairs matching the filters, on every page")


class Health(BaseModel):
    status: str
    checks: dict[str, str] = Field(default_factory=dict)
