"""The `cluster` job kind: a stored grasp set's candidates clustered again with new k1 / k2 / seed (graspgen.recluster)
into a new version of the same object and gripper pair; a parallel set's or a suction set's alike (the export's
`gripper.kind` says which clustering runs)."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import ConfigDict, Field
from sqlalchemy.orm import Session

from graspgen.errors import InvalidParameterError
from graspgen.kinds import check_params_for_kind
from graspgen.params import Params, QualityOptions, from_job
from services.api.schemas import ID_MAX, PARAMS_DOC, NoNulModel
from services.common.grippers import file_digests, gripper_kind
from services.common.models import GraspSet as GraspSetRow
from services.common.models import GripperVersion

from .kind import JobKind, RunContext
from .params import QUALITY_PARAMS, split_quality

if TYPE_CHECKING:
    from graspgen.export import GraspSet
    from graspgen.suction import SuctionGraspSet

__all__ = ["KIND", "ClusterJobRequest", "resolve", "run", "CLUSTER_PARAMS"]

CLUSTER_PARAMS = ("k1", "k2", "seed")


class ClusterJobRequest(NoNulModel):
    """A grasp set's stored candidates clustered again with new k1, k2, seed: a new version of its pair."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"kind": "cluster", "grasp_set": 17, "params": {"k1": 8, "k2": 2, "seed": 1}}]},
    )
    kind: Literal["cluster"]
    grasp_set: int = Field(ge=1, le=ID_MAX, description="the grasp set whose candidates are re-clustered")
    params: Annotated[dict[str, Any] | None, PARAMS_DOC] = Field(
        None,
        description="k1, k2, seed; validate (bool), select ('medoid' | 'best-near-medoid'), density (kg/m^3); "
        "docs/QUALITY.md. A cluster job does not inherit validate and select from its source set. A suction set "
        "takes k1, k2, seed only.",
        examples=[{"k1": 8, "k2": 2, "seed": 1, "validate": True}],
    )


# -- submission (the API) ---------------------------------------------------------------------------------------------
def resolve(session: Session, body: ClusterJobRequest) -> dict[str, Any]:
    """The source set's object and gripper versions; its params with the new k1, k2, seed and quality options."""
    from services.api.problems import ApiError  # the worker imports this module for `run` and never loads the API

    source = session.get(GraspSetRow, body.grasp_set)
    if source is None:
        raise ApiError(422, "unknown-grasp-set", f"there is no grasp set {body.grasp_set}", field="grasp_set")
    given = dict(body.params or {})
    unknown = sorted(set(given) - set(CLUSTER_PARAMS) - set(QUALITY_PARAMS) - {"density"})
    if unknown:
        raise InvalidParameterError(
            "a cluster job takes only k1, k2, seed, validate, select and density; not " + ", ".join(unknown),
            field=unknown[0],
        )
    given, quality = split_quality(given)
    Params.from_dict(given)  # a bad k1, k2, seed or density is named before anything about the source set
    if source.candidates_key is None:
        raise ApiError(422, "no-candidates", f"grasp set {source.id} has no stored candidates", field="grasp_set")
    gv = session.get(GripperVersion, source.gripper_version_id)
    kind = gripper_kind(gv.spec) if gv is not None else "parallel"
    if kind != "parallel" and "density" in given:
        # a suction set's candidates passed criterion hold with its mass; only validation (jaws) takes a new one
        raise InvalidParameterError(
            f"grasp set {source.id} is a {kind} set: its candidates were judged with its mass, and a cluster job "
            "takes no density for it (a generate job with the new mass judges them again)",
            field="density",
        )
    # quality options are the cluster job's own, not inherited from the source set
    base, _ = split_quality(source.params)
    if "density" in given:
        base.pop("mass_kg", None)  # a density for validation replaces the source's mass (one of the two)
    core = Params.from_dict({**base, **given})
    # options the set's gripper kind cannot use (validate, select for a suction set): 422 now, not a failed job
    check_params_for_kind(kind, core, QualityOptions.split_job(quality)[1], recluster=True)
    merged = {**core.to_dict(), **quality}
    return {
        "object_version_id": source.object_version_id,
        "gripper_version_id": source.gripper_version_id,
        "source_grasp_set_id": source.id,
        "params": merged,
    }


# -- the run (the worker) ---------------------------------------------------------------------------------------------
def run(ctx: RunContext) -> GraspSet | SuctionGraspSet:
    import graspgen

    inp, p = ctx.inputs, ctx.inputs.params
    assert inp.source_candidates_key and inp.source_export_key
    npz = ctx.storage.download(inp.source_candidates_key, ctx.tmp / "source-candidates.npz")
    previous = json.loads(ctx.storage.get_bytes(inp.source_export_key))
    params, options = from_job(p)
    # a spec with geometry: with its meshes (the export holds only their digests); a spec without: from the export
    gripper = ctx.gripper() if file_digests(inp.spec) else None
    extra: dict[str, Any] = {}
    if gripper_kind(inp.spec) == "parallel":
        # the mass for validation only; validation and quality scoring need the part, which recluster loads in
        # metres from `units`. A suction set's NPZ and export are all it needs (graspgen.recluster reads the kind
        # from the export): its candidates passed criterion hold with the set's mass, and clustering needs no part
        extra = {"mass_kg": params.mass_kg, "density": params.density}
        if options.needs_part:
            extra.update(mesh=str(ctx.download_part()), units=inp.units)
    return graspgen.recluster(
        str(npz),
        previous,
        gripper=gripper,
        k1=params.k1,
        k2=params.k2,
        seed=params.seed,
        recording=ctx.recording,
        progress=ctx.progress,
        options=options,
        **extra,
    )


KIND = JobKind(
    name="cluster",
    request=ClusterJobRequest,
    resolve=resolve,
    run=run,
    stage_weights={"load": 0.04, "cluster": 0.16, "validate": 0.76, "export": 0.04},
)
