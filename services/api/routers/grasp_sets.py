from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request, Response

from ...common.storage import Storage
from ..crud import candidates
from ..crud import grasp_sets as crud
from ..deps import PagingDep, ReadDep, ReadSessionDep, SessionDep, StorageDep, WriteDep
from ..http import IMMUTABLE, REVALIDATE, BlobCache, blob_response, etag_matches, not_modified
from ..problems import ApiError
from ..schemas import ID_MAX, SLUG, CatalogueChange, CatalogueHistoryPage, CataloguePage, GraspPage, GraspSetPage
from . import problems

router = APIRouter(prefix="/v1", tags=["grasp sets"])

GraspSetId = Annotated[int, Path(ge=1, le=ID_MAX, examples=[17])]

_EXPORT_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "The grasp_set/1 export (CONTRACT.md), byte for byte as the core wrote it",
        "content": {
            "application/json": {
                "schema": {"$ref": "#/components/schemas/GraspSetExport"},
                "example": {
                    "format": "graspgen.grasp_set/1",
                    "units": "m",
                    "object": {"name": "ring-screw", "version": 3, "sha256": "...", "source_units": "mm"},
                    "gripper": {"name": "pgn-80", "stroke": 0.08, "...": "..."},
                    "params": {"points": 10000, "k1": 16, "k2": 4, "seed": 0, "...": "..."},
                    "stats": {"points": 10000, "candidates": 812, "...": "..."},
                    "grasps": [{"pose": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "width": 0.031}],
                },
            }
        },
        "headers": {"ETag": {"description": "strong: the sha256 of the body", "schema": {"type": "string"}}},
    }
}


def export_response(request: Request, ref: crud.ExportRef, *, cache_control: str) -> Response:
    etag = crud.etag_of(ref.export_sha256)
    headers = {"ETag": etag, "Cache-Control": cache_control, "Content-Location": f"/v1/grasp-sets/{ref.id}"}
    if etag_matches(request, etag):
        return not_modified(etag, cache_control)
    cache: BlobCache = request.app.state.export_cache
    try:
        body = cache.get(ref.export_key)
    except FileNotFoundError:
        raise ApiError(503, "artifact-missing", "the export is missing from storage") from None
    return Response(body, media_type="application/json", headers=headers)


@router.get(
    "/grasp-sets", response_model=GraspSetPage, summary="List grasp sets, newest first", responses=problems(422)
)
def list_grasp_sets(
    principal: ReadDep,
    session: ReadSessionDep,
    page: PagingDep,
    object: Annotated[str | None, Query(pattern=SLUG)] = None,
    gripper: Annotated[str | None, Query(pattern=SLUG)] = None,
) -> dict:
    return crud.list_grasp_sets(
        session,
        object=object,
        gripper=gripper,
        cursor=page.cursor,
        limit=page.limit,
    )


@router.get(
    "/grasp-sets/{grasp_set_id}",
    summary="One grasp-set version: the export JSON (immutable, strong ETag)",
    response_class=Response,
    responses={**_EXPORT_RESPONSE, **problems(304, 404, 422)},
)
def get_grasp_set(request: Request, grasp_set_id: GraspSetId, principal: ReadDep, session: ReadSessionDep) -> Response:
    return export_response(request, crud.export_ref(session, grasp_set_id), cache_control=IMMUTABLE)


# GET /grasp-sets/{grasp_set_id}/preview.png lives in routers/previews.py (rendered off the request path)


@router.get(
    "/grasp-sets/{grasp_set_id}/candidates",
    summary="The candidate NPZ (CONTRACT.md) of a grasp set, or a view of some of its arrays over fewer rows",
    description=(
        "Without query parameters: the stored NPZ, byte for byte (immutable, ETag the blob's digest). With `arrays` "
        "or `max_rows`: an NPZ of stored (uncompressed) members holding the named arrays (all when `arrays` is "
        "absent; names the set lacks are left out), and with `max_rows` only rows 0, s, 2s, ... of every array over "
        "the n candidates, s = ceil(n / max_rows), plus `rows (k,) int64` (the kept rows' indices in the full NPZ) "
        "and `row_count () int64` (n); `roll_angles_rad`, `medoids` and `center_of_mass` are kept whole "
        "(docs/API.md)."
    ),
    response_class=Response,
    responses={200: {"content": {"application/octet-stream": {}}}, **problems(304, 404, 422)},
)
def get_candidates(
    request: Request,
    grasp_set_id: GraspSetId,
    principal: ReadDep,
    session: ReadSessionDep,
    storage: StorageDep,
    arrays: Annotated[
        str | None,
        Query(
            pattern=candidates.ARRAY_NAMES,
            description="comma-separated array names to return, e.g. `midpoints,friction_margin_deg` (at most 32)",
            examples=["midpoints,friction_margin_deg,hold_margin"],
        ),
    ] = None,
    max_rows: Annotated[
        int | None,
        Query(
            ge=1,
            le=candidates.MAX_ROWS,
            description="at most this many candidates: an even stride through the rows, starting at row 0",
            examples=[50000],
        ),
    ] = None,
) -> Response:
    gs = crud.get_grasp_set(session, grasp_set_id)
    if arrays is None and max_rows is None:
        return _artifact(request, storage, gs.candidates_key, f"grasp-set-{gs.id}-candidates.npz")
    return candidates.view_response(request, gs.id, gs.candidates_key, arrays=arrays, max_rows=max_rows)


@router.get(
    "/grasp-sets/{grasp_set_id}/recording",
    summary="The Rerun recording (.rrd) of the job that computed the grasp set",
    response_class=Response,
    responses={200: {"content": {"application/octet-stream": {}}}, **problems(304, 404, 422)},
)
def get_recording(
    request: Request, grasp_set_id: GraspSetId, principal: ReadDep, session: ReadSessionDep, storage: StorageDep
) -> Response:
    gs = crud.get_grasp_set(session, grasp_set_id)
    return _artifact(request, storage, gs.recording_key, f"grasp-set-{gs.id}.rrd")


def _artifact(request: Request, storage: Storage, key: str | None, filename: str) -> Response:
    """An immutable binary artifact of a grasp set, as a download (404 when it was not stored: key None)."""
    return blob_response(
        request, storage, key, media_type="application/octet-stream", filename=filename, cache_control=IMMUTABLE
    )


@router.get(
    "/grasp-sets/{grasp_set_id}/grasps",
    response_model=GraspPage,
    summary="The grasps of a set from the database, filterable (no file is read)",
    responses=problems(404, 422),
)
def list_grasps(
    grasp_set_id: GraspSetId,
    principal: ReadDep,
    session: ReadSessionDep,
    page: PagingDep,
    min_width: Annotated[float | None, Query(ge=0, description="metres")] = None,
    max_width: Annotated[float | None, Query(ge=0, description="metres")] = None,
    min_friction_margin_deg: float | None = None,
) -> dict:
    return crud.list_grasps(
        session,
        grasp_set_id,
        min_width=min_width,
        max_width=max_width,
        min_friction_margin_deg=min_friction_margin_deg,
        cursor=page.cursor,
        limit=page.limit,
    )


@router.get(
    "/catalogue",
    response_model=CataloguePage,
    tags=["catalogue"],
    summary="Fleet sync: the current grasp set of every object for a gripper",
    description="Without `since`: the current set (the released one, else the newest for the newest object and "
    "gripper versions) of every object that has one, by object name, paginated by cursor; `updated_since` keeps only "
    "those whose current set was created after that instant (kept for compatibility: it relies on clocks). "
    "With `since` (a `next_since` from an earlier answer): every pair whose current set changed after it, in change "
    "order, including pairs that serve nothing now (`id: null, withdrawn: true`: drop them). Store `next_since` "
    "after each page and send it as `since` next time: no change is ever missed (docs/SERVICE.md). Send the page's "
    "ETag back in If-None-Match to get a 304 when nothing changed.",
    responses=problems(304, 404, 422),
)
def list_catalogue(
    request: Request,
    principal: ReadDep,
    session: ReadSessionDep,
    page: PagingDep,
    gripper: Annotated[str, Query(pattern=SLUG, examples=["pgn-80"])],
    since: Annotated[
        int | None, Query(ge=0, le=2**62, description="change number: `next_since` of the previous sync")
    ] = None,
    updated_since: Annotated[datetime | None, Query(description="ISO 8601; naive times are UTC")] = None,
) -> Any:
    if updated_since is not None and updated_since.tzinfo is None:
        from datetime import UTC

        updated_since = updated_since.replace(tzinfo=UTC)
    body, etag = crud.list_catalogue(
        session,
        gripper=gripper,
        since=since,
        updated_since=updated_since,
        cursor=page.cursor,
        limit=page.limit,
    )
    if etag_matches(request, etag):
        return not_modified(etag, REVALIDATE)
    return Response(
        crud.dumps(body), media_type="application/json", headers={"ETag": etag, "Cache-Control": REVALIDATE}
    )


_CATALOGUE_HEADERS = {
    "Graspgen-Set-Id": {"description": "id of the grasp set served", "schema": {"type": "integer"}},
    "Graspgen-Released": {"description": "true: the released set of the pair", "schema": {"type": "string"}},
    "Graspgen-Stale": {
        "description": "true: made for an older object or gripper version (only a released set is served so)",
        "schema": {"type": "string"},
    },
}


@router.get(
    "/catalogue/{object}/{gripper}",
    tags=["catalogue"],
    summary="The grasp set robots should use for an object and a gripper (or a given version), as exported",
    description="The released set of the pair if there is one; otherwise the newest set computed for the newest "
    "object version and the newest gripper version (a set for an older version is never served unless released). "
    "A withdrawn set is never served. 404 when no set qualifies. `version` asks for one numbered set instead.",
    response_class=Response,
    responses={
        200: {**_EXPORT_RESPONSE[200], "headers": {**_EXPORT_RESPONSE[200]["headers"], **_CATALOGUE_HEADERS}},
        **problems(304, 404, 422),
    },
)
def get_catalogue_entry(
    request: Request,
    object: Annotated[str, Path(pattern=SLUG)],
    gripper: Annotated[str, Path(pattern=SLUG)],
    principal: ReadDep,
    session: ReadSessionDep,
    version: Annotated[int | None, Query(ge=1, le=ID_MAX)] = None,
) -> Response:
    ref = crud.catalogue_entry(session, object, gripper, version)
    # a numbered version never changes; "the current one" does, so clients revalidate it with the ETag
    response = export_response(request, ref, cache_control=IMMUTABLE if version else REVALIDATE)
    response.headers["Graspgen-Set-Id"] = str(ref.id)
    response.headers["Graspgen-Released"] = "true" if ref.released else "false"
    response.headers["Graspgen-Stale"] = "true" if ref.stale else "false"
    return response


@router.get(
    "/catalogue/{object}/{gripper}/history",
    response_model=CatalogueHistoryPage,
    tags=["catalogue"],
    summary="Releases and withdrawals of an object and gripper pair, newest first (who and when)",
    responses=problems(404, 422),
)
def get_catalogue_history(
    object: Annotated[str, Path(pattern=SLUG)],
    gripper: Annotated[str, Path(pattern=SLUG)],
    principal: ReadDep,
    session: ReadSessionDep,
    page: PagingDep,
) -> dict:
    return crud.catalogue_history(session, object, gripper, cursor=page.cursor, limit=page.limit)


@router.post(
    "/grasp-sets/{grasp_set_id}/release",
    response_model=CatalogueChange,
    tags=["catalogue"],
    summary="Release a grasp set: the catalogue serves it for its pair until another is released or it is withdrawn",
    description="One released set per object and gripper pair; the previous release stays in the history. A "
    "withdrawn set is reinstated. Releasing the released set again changes nothing (`changed: false`).",
    responses=problems(404, 422),
)
def release_grasp_set(grasp_set_id: GraspSetId, principal: WriteDep, session: SessionDep) -> dict:
    return crud.release(session, grasp_set_id, principal.name)


@router.post(
    "/grasp-sets/{grasp_set_id}/withdraw",
    response_model=CatalogueChange,
    tags=["catalogue"],
    summary="Withdraw a grasp set: the catalogue never serves it again (released or newest)",
    description="If it was the released set, the pair has no release until the next one and serves the newest set "
    "for the newest versions. Withdrawing a withdrawn set changes nothing (`changed: false`).",
    responses=problems(404, 422),
)
def withdraw_grasp_set(grasp_set_id: GraspSetId, principal: WriteDep, session: SessionDep) -> dict:
    return crud.withdraw(session, grasp_set_id, principal.name)
