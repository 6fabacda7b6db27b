"""GET /v1/grasp-sets/{id}/preview.png: drawn in a bounded pool of render processes (services/api/previews.py), never
while the request holds a database connection."""

from __future__ import annotations

import json
from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request, Response
from starlette.concurrency import run_in_threadpool

from services.common.grippers import file_digests
from services.common.storage import blob_key

from ..crud import grasp_sets as crud
from ..deps import ReadDep
from ..http import IMMUTABLE, etag_matches, not_modified
from ..previews import PreviewCache, PreviewRenderer, PreviewsBusy
from ..problems import ApiError
from ..schemas import ID_MAX
from . import problems

router = APIRouter(prefix="/v1", tags=["grasp sets"])

#: bump when the picture for the same grasp set and size changes (renderer changes): it is part of the ETag
PREVIEW_REVISION = 1
#: seconds a client is asked to wait when every render process is busy
RETRY_AFTER_BUSY_S = "2"

_PREVIEW_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "A PNG of the part (shaded, grey) with every exported gripper at its pose in its cluster's "
        "colour, in four orthographic views (iso, front, side, top) in a 2 x 2 grid (graspgen.render)",
        "content": {"image/png": {"schema": {"type": "string", "format": "binary"}}},
        "headers": {
            "ETag": {"description": "strong: from the grasp set id and the size", "schema": {"type": "string"}},
            "Cache-Control": {"description": "immutable, like the grasp set", "schema": {"type": "string"}},
        },
    }
}


def install(app: Any, settings: Any) -> None:
    """The app's render pool and PNG cache (closed with the app)."""
    app.state.preview_cache = PreviewCache(settings.preview_cache_bytes)
    app.state.previews = PreviewRenderer(workers=settings.preview_workers, queue=settings.preview_queue)


def _ref(request: Request, grasp_set_id: int) -> crud.PreviewRef:
    # a session of its own, closed before anything is drawn: a render never holds a database connection
    with request.app.state.db.read_sessions() as session:
        return crud.preview_ref(session, grasp_set_id)


@router.get(
    "/grasp-sets/{grasp_set_id}/preview.png",
    summary="A picture of a grasp set: the part and its grippers in four views (PNG, immutable, strong ETag)",
    description="Drawn on the server without a GPU (graspgen.render), in a small pool of render processes. `size` is "
    "`WIDTHxHEIGHT` in pixels, each side 16..4096 and at most GRASPGEN_PREVIEW_MAX_PIXELS in all (default 800x600); "
    "anything else is a 422 problem. When every render process is busy and the waiting line is full the answer is "
    "a 503 problem with Retry-After. The picture of a grasp set never changes, so send the ETag back in "
    "If-None-Match for a 304.",
    response_class=Response,
    responses={**_PREVIEW_RESPONSE, **problems(304, 404, 422)},
)
async def get_preview(
    request: Request,
    grasp_set_id: Annotated[int, Path(ge=1, le=ID_MAX, examples=[17])],
    principal: ReadDep,
    size: Annotated[
        str | None, Query(max_length=20, description="WIDTHxHEIGHT in pixels", examples=["800x600"])
    ] = None,
) -> Response:
    from graspgen.render import DEFAULT_SIZE, parse_size
    from services.common.metrics import PREVIEW_DURATION, PREVIEWS

    settings = request.app.state.settings
    W, H = parse_size(size) if size is not None else DEFAULT_SIZE  # InvalidParameterError -> 422 problem
    if settings.preview_max_pixels < W * H:
        raise ApiError(
            422,
            "validation-error",
            f"a preview has at most {settings.preview_max_pixels} pixels, {W} x {H} has {W * H}",
            field="size",
        )
    ref = await run_in_threadpool(_ref, request, grasp_set_id)
    etag = f'"preview-{PREVIEW_REVISION}-{ref.id}-{W}x{H}"'
    headers = {"ETag": etag, "Cache-Control": IMMUTABLE}
    if etag_matches(request, etag):
        return not_modified(etag, IMMUTABLE)
    cache: PreviewCache = request.app.state.preview_cache
    key = (ref.id, W, H)
    png = cache.get(key)
    if png is not None:
        PREVIEWS.labels("cached").inc()
        return Response(png, media_type="image/png", headers=headers)

    storage = request.app.state.storage
    exports = request.app.state.export_cache

    def inputs() -> tuple[Any, ...]:
        try:
            export = exports.get(ref.export_key)
            part = storage.get_bytes(ref.object_file_key)
            # a gripper from CAD is drawn with its meshes: the export names them by digest
            digests = file_digests(json.loads(export).get("gripper") or {})
            files = {name: storage.get_bytes(blob_key(sha)) for name, sha in digests.items()}
        except FileNotFoundError:
            raise ApiError(503, "artifact-missing", "a file of this grasp set is missing from storage") from None
        return part, ref.object_units, ref.object_format, export, (W, H), files

    renderer: PreviewRenderer = request.app.state.previews
    try:
        with PREVIEW_DURATION.time():
            png = await renderer.render(key, inputs)
    except PreviewsBusy:
        PREVIEWS.labels("rejected").inc()
        raise ApiError(
            503,
            "previews-busy",
            "every preview renderer is busy; retry later",
            title="Previews busy",
            headers={"Retry-After": RETRY_AFTER_BUSY_S},
        ) from None
    except ApiError:
        PREVIEWS.labels("failed").inc()
        raise
    cache.put(key, png)
    PREVIEWS.labels("rendered").inc()
    return Response(png, media_type="image/png", headers=headers)
