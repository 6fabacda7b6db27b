"""Typed OpenAPI documents of the contract's payloads: the gripper specs of both kinds, job params, the grasp_set/1
export and the pick query (CONTRACT.md; docs/API.md explains frames and units).

GripperSpec (kind `parallel`), SuctionGripperSpec (kind `suction`), their union AnyGripperSpec, JobParams and
GraspSetExport *document*: the routes still hand the raw JSON to graspgen (graspgen.kinds.gripper_from_dict,
Params.from_dict), which stays the single source of validation and of its messages; the schemas state the same
rules. JobParams is built from the declared fields of graspgen's Params and QualityOptions
(`job_params_model`): each parameter's type, range, choices and default are params.py's. The export models allow extra
fields, so fields the library adds pass through. PickRequest validates shapes and types; the numbers (pose
orthonormality, non-zero vectors, ranges) are checked by graspgen.pick.PickQuery with the same rules as the Python API.
"""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, RootModel, create_model, model_validator

from graspgen.examples import EXAMPLE_GRIPPER
from graspgen.gripper import SLUG_PATTERN
from graspgen.params import ParamOption, Params, QualityOptions, param_options
from graspgen.pick import DEFAULT_LIMIT, DEFAULT_PREGRASP_DISTANCE, MAX_LIMIT, MAX_PLANES
from graspgen.suction import MAX_VACUUM

from .schemas import SUCTION_SPEC_EXAMPLE

__all__ = [
    "GripperSpec",
    "GripperGeometry",
    "GripperPad",
    "SuctionGripperSpec",
    "SuctionTool",
    "SuctionGeometry",
    "AnyGripperSpec",
    "JobParams",
    "job_params_model",
    "GraspSetExport",
    "ExportGrasp",
    "PickRequest",
    "PickResponse",
    "PickedGrasp",
    "DOCUMENT_MODELS",
]

SLUG = SLUG_PATTERN.pattern
ID_MAX = 2**31 - 1

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Row4 = Annotated[list[float], Field(min_length=4, max_length=4)]
Matrix4 = Annotated[
    list[Row4],
    Field(
        min_length=4,
        max_length=4,
        description="4x4 homogeneous pose, row-major, metres; rotation orthonormal with det +1, last row 0 0 0 1",
        examples=[[[1, 0, 0, 0.4], [0, 1, 0, 0], [0, 0, 1, 0.02], [0, 0, 0, 1]]],
    ),
]
# Any: pydantic types json_schema_extra as JSON values, which list[list[float]] and dict[str, object] are not to mypy
_IDENTITY: list[Any] = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
_EXAMPLE_GRIPPER: dict[str, Any] = dict(EXAMPLE_GRIPPER)


# -- gripper spec -----------------------------------------------------------------------------------------------------
class GripperPad(BaseModel):
    model_config = ConfigDict(extra="forbid")
    width: float = Field(gt=0, le=2, description="pad extent along Y, m")
    depth: float = Field(gt=0, le=2, description="pad extent along Z, m")


class GripperGeometry(BaseModel):
    """Finger and body meshes from CAD (CONTRACT.md "Gripper geometry from CAD"; docs/API.md has the frames).
    Each value is a file name: relative to the spec file (CLI, Python), or the name of a multipart file part (HTTP).
    Files are STL, OBJ, PLY, OFF or GLB, watertight with outward normals, at most 200,000 triangles each."""

    model_config = ConfigDict(extra="forbid")
    units: Literal["mm", "cm", "m", "in"] = Field(description="the unit of the mesh files")
    finger: str = Field(
        description="the +X finger in its finger frame: origin at the pad's contact point, inner face at x = 0 "
        "looking along -X, the finger at x >= 0, +Z the approach",
        examples=["finger.stl"],
    )
    finger_left: str | None = Field(
        None, description="the -X finger in its own finger frame (same convention); default: the finger's mesh"
    )
    body: str | None = Field(
        None, description="all that does not move with the fingers (housing, adapter, flange), in the grasp frame"
    )
    pad: GripperPad | None = Field(
        None, description="the contact pad on the inner face, m; default: the finger's extent at its inner face"
    )
    sha256: dict[str, str] | None = Field(
        None,
        description="file name -> hex sha256; stored specs and exports carry it; when given, the files must match",
    )


class GripperSpec(BaseModel):
    """A parallel-jaw gripper (CONTRACT.md gripper spec). All lengths in metres, in the grasp frame: X closing axis,
    Y pad width, Z approach (the palm lies at -Z). Either the box fields (finger_width, finger_depth,
    finger_thickness, optional palm_depth, palm_width) or `geometry`, never both. Unknown fields are refused."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [_EXAMPLE_GRIPPER]})
    name: str = Field(pattern=SLUG, description="slug", examples=["pgn-80"])
    kind: Literal["parallel"] | None = Field(None, description="the default kind")
    stroke: float = Field(gt=0, le=2, description="maximum opening between the finger pads, m")
    min_width: float | None = Field(0.0, ge=0, description="smallest width the gripper can hold, m (< stroke)")
    finger_width: float | None = Field(None, gt=0, le=2, description="box spec (required there): pad extent along Y, m")
    finger_depth: float | None = Field(
        None, gt=0, le=2, description="box spec (required there): pad extent along Z, m; the contact sits at its centre"
    )
    finger_thickness: float | None = Field(
        None, gt=0, le=2, description="box spec (required there): finger extent along X, m"
    )
    palm_depth: float | None = Field(0.0, ge=0, le=2, description="box behind the fingers along -Z, m; 0 = no palm")
    palm_width: float | None = Field(None, gt=0, le=2, description="palm extent along Y, m; default finger_width")
    geometry: GripperGeometry | None = Field(None, description="finger and body meshes instead of the box fields")
    friction: float = Field(gt=0, description="Coulomb coefficient pad/part (a job's `friction` overrides it)")
    pregrasp_clearance: float = Field(
        ge=0, description="extra opening before closing, m: open width = min(width + this, stroke)"
    )
    grip_force: float | None = Field(
        None, gt=0, description="force each finger presses with, N (criterion (e) `hold` needs it)"
    )


class SuctionTool(BaseModel):
    """The cylinder behind the cup, on the grasp frame's Z axis from z = -cup_height back to -(cup_height + length)."""

    model_config = ConfigDict(extra="forbid")
    radius: float = Field(gt=0, le=2, description="m")
    length: float = Field(gt=0, le=2, description="m")


class SuctionGeometry(BaseModel):
    """The tool behind the cup as a body mesh in the grasp frame (origin at the lip's centre, +Z the approach, the
    body at z <= 0): a file name, relative to the spec file (CLI, Python) or the name of a multipart file part (HTTP);
    STL, OBJ, PLY, OFF or GLB, watertight with outward normals, at most 200,000 triangles."""

    model_config = ConfigDict(extra="forbid")
    units: Literal["mm", "cm", "m", "in"] = Field(description="the unit of the mesh file")
    body: str = Field(description="the tool's mesh (everything behind the cup)", examples=["tool.stl"])
    sha256: dict[str, str] | None = Field(
        None,
        description="file name -> hex sha256; stored specs and exports carry it; when given, the file must match",
    )


class SuctionGripperSpec(BaseModel):
    """A vacuum cup and the tool behind it (CONTRACT.md "Suction cups"), lengths in metres. Grasp frame: origin at
    the contact (the lip's centre on the surface), +Z the approach into the part along the cup's axis, the cup from
    z = 0 back to -cup_height, the tool behind it. The tool is a cylinder (`tool`) or a body mesh (`geometry`, sent
    as multipart with its file), exactly one of them. Unknown fields are refused."""

    model_config = ConfigDict(extra="forbid", json_schema_extra={"examples": [SUCTION_SPEC_EXAMPLE]})
    name: str = Field(pattern=SLUG, description="slug", examples=["cup-30"])
    kind: Literal["suction"] = Field(description="required: a spec without kind is a parallel gripper")
    cup_radius: float = Field(gt=0, le=2, description="radius of the sealing lip, m")
    cup_height: float = Field(gt=0, le=2, description="lip to cup base along the cup's axis (the bellows' travel), m")
    max_strain: float = Field(gt=0, lt=1, description="how far the lip may stretch or compress (0.1 = 10 %)")
    vacuum: float = Field(
        gt=0, le=MAX_VACUUM, description="pressure difference the pump holds under a sealed cup, Pa (<= 1 atm)"
    )
    friction: float = Field(gt=0, le=10, description="Coulomb coefficient lip/part (a job's `friction` overrides it)")
    # no `| None`: the tool or the geometry is left out, never null (graspgen refuses null)
    tool: SuctionTool = Field(None, description="the cylinder behind the cup (or `geometry`)")  # type: ignore[assignment]
    geometry: SuctionGeometry = Field(None, description="the tool as a body mesh (or `tool`)")  # type: ignore[assignment]
    pregrasp_clearance: float = Field(ge=0, le=2, description="stand-off of the pre-grasp pose along -Z, m")

    @model_validator(mode="after")
    def _one_tool(self) -> SuctionGripperSpec:
        if (self.tool is None) == (self.geometry is None):
            raise ValueError("give the tool as a cylinder (tool) or a body mesh (geometry), exactly one of them")
        return self


class AnyGripperSpec(RootModel[GripperSpec | SuctionGripperSpec]):
    """A gripper spec of either kind: a parallel-jaw gripper (GripperSpec, `kind` "parallel" or left out) or a
    suction cup (SuctionGripperSpec, `kind` "suction")."""


# -- job params -------------------------------------------------------------------------------------------------------
#: what a job adds to a parameter's description (the service's own rules beyond graspgen's)
JOB_NOTES = {"mass_kg": "a job's default: the object version's mass_kg unless density is given"}


def job_params_model(
    params_cls: type[Params] = Params, options_cls: type[QualityOptions] = QualityOptions
) -> type[BaseModel]:
    """The model of a job's params: one optional field per field of `params_cls` and per job option of
    `options_cls`, typed, bounded and described as params.py declares it (`_option`). Absent means the default, which
    the description names (the schema's own `default` stays null: graspgen fills it in); null is accepted only where
    graspgen accepts it (the `T | None` fields); unknown names are refused."""
    quality = [o for o in param_options(options_cls) if o.name in options_cls.JOB_OPTIONS]
    defs: dict[str, Any] = {}
    for o in (*param_options(params_cls), *quality):
        key = o.name + "_" if hasattr(BaseModel, o.name) else o.name  # `validate` is a BaseModel method
        kind: Any = Literal[o.choices] if o.choices else o.kind
        field = Field(
            None,
            alias=o.name if key != o.name else None,
            ge=o.ge,
            gt=o.gt,
            le=o.le,
            description=_job_description(o, params_cls, options_cls),
        )
        defs[key] = (kind | None if o.optional else kind, field)
    return create_model(
        "JobParams",
        __config__=ConfigDict(
            extra="forbid",
            json_schema_extra={
                "examples": [
                    {"points": 10000, "safety_factor": 1.5, "rolls": 16, "k1": 16, "k2": 4, "seed": 0},
                    {"points": 10000, "density": 7850, "hold": "any", "accel": 9.81, "select": "best-near-medoid"},
                ]
            },
        ),
        __doc__="Parameters of a job (CONTRACT.md CLI and HTTP API); every field is optional. graspgen's Params and "
        "the job service check them; unknown names are refused. A `cluster` job takes only k1, k2, seed and the "
        "quality fields.",
        **defs,
    )


def _job_description(o: ParamOption, params_cls: type[Params], options_cls: type[QualityOptions]) -> str:
    """The option's help, its default (when it has one), the options it excludes and the job's own note."""
    text = o.help
    if o.default is not None:
        text += f" (default {o.default if isinstance(o.default, str) else json.dumps(o.default)})"
    if o.exclusive:
        others = [
            p.name
            for p in (*param_options(params_cls), *param_options(options_cls))
            if p.exclusive == o.exclusive and p.name != o.name
        ]
        text += "; not with " + " or ".join(others)
    if o.name in JOB_NOTES:
        text += "; " + JOB_NOTES[o.name]
    return text


JobParams = job_params_model()


# -- the grasp_set/1 export -------------------------------------------------------------------------------------------
class ExportObject(BaseModel):
    model_config = ConfigDict(extra="allow")
    name: str
    version: int
    sha256: str | None = Field(None, description="sha256 of the uploaded file")
    source_units: str | None = Field(None, description="the unit the file was given in; the export is in metres")


class ExportStats(BaseModel):
    model_config = ConfigDict(extra="allow")
    points: int | None = None
    pairs_total: int | None = None
    rejected: dict[str, int] | None = Field(None, description="candidates each criterion removed")
    candidates: int | None = Field(None, description="pairs that passed every criterion: the NPZ's rows")
    timings_s: dict[str, float] | None = Field(None, description="wall-clock seconds per stage (not reproducible)")
    warnings: list[str] | None = None


class ExportGrasp(BaseModel):
    """One exported grasp (a cluster representative), object frame, metres. A parallel gripper's grasp has two
    contacts, its width and friction margin; a suction cup's has one contact (the lip's centre on the surface), its
    approach, seal strain and tilt."""

    model_config = ConfigDict(extra="allow")
    pose: Matrix4 = Field(description="T_object_grasp at the roll `roll_deg`, row-major")
    width: float | None = Field(None, description="parallel: contact distance, m")
    contacts: list[Vec3] = Field(
        description="object frame, m: the two contacts of a parallel grasp (+X points from 0 to 1), the one contact "
        "of a suction grasp (the pose's origin)"
    )
    normals: list[Vec3] = Field(description="outward unit surface normals at the contacts")
    friction_margin_deg: float | None = Field(
        None, description="parallel: cone half-angle / safety factor minus the worse contact angle"
    )
    free_rolls_deg: list[float] = Field(
        description="every collision-free roll, degrees: about +X (parallel), about +Z (suction)"
    )
    cluster: list[int] = Field(description="[translation cluster, direction cluster]")
    cluster_size: int = Field(description="candidates this grasp represents")
    roll_deg: float | None = Field(None, description="the roll the pose uses")
    mode: Literal["outside", "inside"] | None = None
    candidate: int | None = Field(None, description="row in the candidate NPZ")
    medoid: int | None = Field(None, description="the cluster's medoid this grasp stands in for (best-near-medoid)")
    quality: dict[str, float] | None = Field(None, description="score and terms (docs/QUALITY.md)")
    sim: dict[str, Any] | None = Field(None, description="MuJoCo validation of this grasp")
    hold_margin: float | None = Field(None, description="criterion hold: load resisted / load required (>= 1)")
    approach: Vec3 | None = Field(None, description="suction: the approach (the pose's +Z, into the part), unit")
    seal_strain: float | None = Field(None, description="suction: the lip's largest strain (<= max_strain)")
    tilt_deg: float | None = Field(None, description="suction: the approach's angle to the surface's normal")


class GraspSetExport(BaseModel):
    """`graspgen.grasp_set/1` (CONTRACT.md): one run's representatives, object frame, metres."""

    model_config = ConfigDict(extra="allow")
    format: Literal["graspgen.grasp_set/1"]
    units: Literal["m"]
    object: ExportObject
    gripper: dict[str, Any] = Field(
        description="the gripper spec (AnyGripperSpec) the set was computed for; its `kind` says which"
    )
    params: dict[str, Any] = Field(description="the run's parameters (JobParams), friction resolved")
    stats: ExportStats
    grasps: list[ExportGrasp] = Field(description="representatives, best first within each translation cluster")


# -- the pick query ---------------------------------------------------------------------------------------------------
class Approach(BaseModel):
    model_config = ConfigDict(extra="forbid")
    direction: Vec3 = Field(description="world frame; any non-zero length", examples=[[0, 0, -1]])
    max_angle_deg: float = Field(ge=0, le=180, description="the grasp's +Z must lie within this angle of direction")


class Plane(BaseModel):
    model_config = ConfigDict(extra="forbid")
    point: Vec3 = Field(description="a point on the plane, world frame, m")
    normal: Vec3 = Field(description="points to the free side (any non-zero length)")


class PickRequest(BaseModel):
    """Give `grasp_set`, or `object` and `gripper` (the catalogue's current set of the pair)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "object": "ring-screw",
                    "gripper": "pgn-80",
                    "T_world_object": [[1, 0, 0, 0.4], [0, 1, 0, 0], [0, 0, 1, 0.02], [0, 0, 0, 1]],
                    "approach": {"direction": [0, 0, -1], "max_angle_deg": 30},
                    "planes": [{"point": [0, 0, 0], "normal": [0, 0, 1]}],
                    "pregrasp_distance": 0.05,
                    "T_tcp_flange": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -0.1], [0, 0, 0, 1]],
                    "limit": 10,
                },
                {"grasp_set": 12, "T_world_object": _IDENTITY, "limit": 1},
            ]
        },
    )
    object: str | None = Field(None, pattern=SLUG, description="object name (with gripper)")
    gripper: str | None = Field(None, pattern=SLUG, description="gripper name (with object)")
    grasp_set: int | None = Field(None, ge=1, le=ID_MAX, description="a grasp set id instead of object and gripper")
    T_world_object: Matrix4 = Field(description="where the part lies: the object's model frame in the world")
    approach: Approach | None = Field(None, description="cone of allowed approach directions; omitted: any")
    planes: list[Plane] = Field(
        default_factory=list,
        max_length=MAX_PLANES,
        description="half-spaces (bin floor, walls): the fingers and palm at the grasp and the open fingers and palm "
        "at the pre-grasp (a suction cup: the cup and the tool at both) must lie on each plane's normal side",
    )
    pregrasp_distance: float = Field(
        DEFAULT_PREGRASP_DISTANCE, ge=0, le=2, description="m: the pre-grasp is the grasp retreated along its -Z"
    )
    T_tcp_flange: Matrix4 | None = Field(None, description="the flange pose relative to the TCP (grasp frame)")
    limit: int = Field(DEFAULT_LIMIT, ge=1, le=MAX_LIMIT, description="grasps returned at most")

    @model_validator(mode="after")
    def _one_source(self) -> PickRequest:
        if self.grasp_set is None and not (self.object and self.gripper):
            raise ValueError("give either grasp_set, or object and gripper")
        if self.grasp_set is not None and (self.object or self.gripper):
            raise ValueError("give either grasp_set, or object and gripper, not both")
        return self


class PickedGrasp(BaseModel):
    """One feasible (candidate, roll), world frame, metres. A parallel gripper's grasp has width, open_width and
    friction_margin_deg; a suction cup's has seal_strain and tilt_deg instead (its position is the contact)."""

    model_config = ConfigDict(extra="allow")
    T_world_grasp: Matrix4 = Field(description="T_world_object @ T_object_grasp(candidate, roll)")
    position: Vec3 = Field(
        description="the grasp origin in the world, m: the contacts' midpoint (parallel), the contact (suction)"
    )
    quaternion_xyzw: list[float] = Field(min_length=4, max_length=4, description="rotation of T_world_grasp, w >= 0")
    T_world_pregrasp: Matrix4 = Field(description="the grasp retreated pregrasp_distance along its -Z")
    T_world_flange: Matrix4 | None = Field(None, description="T_world_grasp @ T_tcp_flange (when given)")
    T_world_preflange: Matrix4 | None = Field(None, description="T_world_pregrasp @ T_tcp_flange (when given)")
    width: float | None = Field(None, description="parallel: contact distance, m")
    open_width: float | None = Field(
        None, description="parallel: opening at the pre-grasp: min(width + pregrasp_clearance, stroke), m"
    )
    roll_deg: float = Field(
        description="roll about the closing axis +X (parallel) or the cup's axis +Z (suction), CONTRACT.md"
    )
    roll_index: int = Field(description="index into the NPZ's roll_angles_rad")
    approach_angle_deg: float = Field(description="angle between the grasp's +Z and approach.direction")
    candidate: int = Field(description="row in the candidate NPZ")
    cluster: list[int] = Field(description="[translation cluster, direction cluster]")
    medoid: bool = Field(description="the candidate is one of the exported representatives")
    score: float = Field(description="the ranking score (see the response's `score`), higher is better")
    friction_margin_deg: float | None = Field(None, description="parallel: the candidate's friction margin")
    hold_margin: float | None = Field(None, description="criterion hold's margin, when the set has one")
    seal_strain: float | None = Field(None, description="suction: the lip's largest strain (<= max_strain)")
    tilt_deg: float | None = Field(None, description="suction: the approach's angle to the surface's normal")


class PickRemoved(BaseModel):
    approach: int = Field(description="(candidate, roll) pairs outside the approach cone")
    planes: int = Field(description="pairs inside the cone that some plane blocks")
    per_plane: list[int] = Field(description="pairs inside the cone each plane blocks (they overlap)")
    candidates: int | None = Field(None, description="(reason only) pairs considered")


class PickResponse(BaseModel):
    model_config = ConfigDict(
        json_schema_extra={
            "example": {
                "grasp_set": 12,
                "version": 3,
                "considered": 300000,
                "feasible": 41234,
                "score": "quality",
                "removed": {"approach": 251000, "planes": 7766, "per_plane": [7766]},
                "grasps": [
                    {
                        "T_world_grasp": [[0, 1, 0, 0.41], [1, 0, 0, 0.0], [0, 0, -1, 0.03], [0, 0, 0, 1]],
                        "position": [0.41, 0.0, 0.03],
                        "quaternion_xyzw": [0.7071068, 0.7071068, 0.0, 0.0],
                        "T_world_pregrasp": [[0, 1, 0, 0.41], [1, 0, 0, 0.0], [0, 0, -1, 0.08], [0, 0, 0, 1]],
                        "width": 0.024,
                        "open_width": 0.044,
                        "roll_deg": 180.0,
                        "roll_index": 8,
                        "approach_angle_deg": 0.0,
                        "candidate": 10234,
                        "cluster": [4, 1],
                        "medoid": False,
                        "score": 0.91,
                        "friction_margin_deg": 12.5,
                    }
                ],
            }
        }
    )
    grasp_set: int
    version: int = Field(description="the set's version within its object and gripper pair")
    considered: int = Field(description="(candidate, free roll) pairs of the set")
    feasible: int = Field(description="pairs that pass the cone and every plane")
    score: Literal["quality", "friction_margin_deg", "hold_margin", "seal_strain"] = Field(
        description="what `score` is: parallel sets: the quality score when the set has quality terms, else the "
        "friction margin; suction sets: the hold margin when criterion hold ran, else minus the seal strain"
    )
    removed: PickRemoved
    grasps: list[PickedGrasp] = Field(description="up to `limit`, best first (score, then smaller approach angle)")
    reason: PickRemoved | None = Field(None, description="when `grasps` is empty: what each filter removed")


#: schemas added to the OpenAPI components by name (routes that take or give raw JSON refer to them)
DOCUMENT_MODELS: tuple[type[BaseModel], ...] = (
    AnyGripperSpec,
    GripperSpec,
    SuctionGripperSpec,
    JobParams,
    GraspSetExport,
)
