"""The pick query over HTTP: resolve the grasp set, load its candidates once per process, run graspgen.pick.

The database is read in a session of its own that is closed before any filtering; the prepared candidate pairs
(graspgen.pick.PickIndex) of each grasp set are kept in a byte-bounded LRU (`Settings.pick_cache_bytes`). Grasp sets
are immutable, so an entry is never invalidated.
"""

from __future__ import annotations

import io
import threading
from dataclasses import dataclass
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from graspgen.export import load_candidates
from graspgen.pick import DEFAULT_LIMIT, DEFAULT_PREGRASP_DISTANCE, PickIndex, PickQuery
from graspgen.suction import SuctionSpec, load_suction_candidates
from services.common.grippers import stored_gripper_spec
from services.common.models import GraspSet, GripperVersion

from ..cache import SizedLRU
from ..problems import ApiError
from . import grasp_sets

__all__ = ["PickRef", "resolve", "run_pick", "index_cache"]


@dataclass(frozen=True)
class PickRef:
    id: int
    version: int
    candidates_key: str | None
    gripper_spec: dict[str, Any]


def resolve(session: Session, *, grasp_set: int | None, object: str | None, gripper: str | None) -> PickRef:
    """The grasp set a pick request names: `grasp_set`, or the catalogue's current set of (object, gripper)."""
    if grasp_set is None:
        if not object or not gripper:
            raise ApiError(422, "validation-error", "give either grasp_set, or object and gripper")
        grasp_set = grasp_sets.catalogue_entry(session, object, gripper, None).id
    q = select(GraspSet.id, GraspSet.version, GraspSet.candidates_key, GripperVersion.spec).join(
        GripperVersion, GripperVersion.id == GraspSet.gripper_version_id
    )
    return PickRef(*grasp_sets.grasp_set_row(session, grasp_set, q))


_lock = threading.Lock()


def index_cache(state: Any) -> SizedLRU[PickIndex]:
    """The app's cache of prepared candidate pairs, made on first use."""
    cache = getattr(state, "pick_cache", None)
    if cache is None:
        with _lock:
            cache = getattr(state, "pick_cache", None)
            if cache is None:
                cache = state.pick_cache = SizedLRU(state.settings.pick_cache_bytes)
    return cache


def _index(state: Any, ref: PickRef) -> PickIndex:
    cache = index_cache(state)
    index = cache.get(ref.id)
    if index is not None:
        return index
    if ref.candidates_key is None:
        raise ApiError(404, "no-candidates", f"grasp set {ref.id} has no stored candidates to pick from")
    try:
        data = state.storage.get_bytes(ref.candidates_key)
    except FileNotFoundError:
        raise ApiError(503, "artifact-missing", "the candidate NPZ is missing from storage") from None
    try:
        # a spec with geometry is loaded with its meshes; one without keeps only the fields this graspgen knows
        gripper = stored_gripper_spec(state.storage, ref.gripper_spec)
    except FileNotFoundError:
        raise ApiError(503, "artifact-missing", "a mesh file of the gripper is missing from storage") from None
    # the candidate NPZ of the gripper's kind: a parallel set's pairs, a suction set's cups (one contact each)
    load = load_suction_candidates if isinstance(gripper, SuctionSpec) else load_candidates
    index = PickIndex.build(load(io.BytesIO(data)), gripper)
    cache.put(ref.id, index, index.nbytes)
    return index


def run_pick(state: Any, body: dict[str, Any]) -> dict[str, Any]:
    """`body`: the request's fields (PickRequest.model_dump()). Returns the response body."""
    query = PickQuery.parse(  # a bad query is refused before anything is read
        body["T_world_object"],
        approach=body.get("approach"),
        planes=body.get("planes"),
        pregrasp_distance=body.get("pregrasp_distance", DEFAULT_PREGRASP_DISTANCE),
        T_tcp_flange=body.get("T_tcp_flange"),
        limit=body.get("limit", DEFAULT_LIMIT),
    )
    with state.db.read_sessions() as session:
        ref = resolve(session, grasp_set=body.get("grasp_set"), object=body.get("object"), gripper=body.get("gripper"))
    result = query.run(_index(state, ref))
    return {"grasp_set": ref.id, "version": ref.version, **result.to_json()}
