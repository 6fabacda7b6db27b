"""Views of a grasp set's candidate NPZ: some of its arrays over an even stride of its rows (graspgen.export.
candidate_view), for clients that draw or sample the candidates (the review page's cloud) without downloading them all.
A view is made once per process and kept beside the exports (`Settings.export_cache_bytes`); the stored NPZ is
immutable, so a view never changes."""

from __future__ import annotations

import hashlib

from fastapi import Request, Response

from graspgen.errors import InvalidCandidatesError
from graspgen.export import candidate_view, npz_bytes

from ..http import REVALIDATE, BlobCache, etag_matches, not_modified
from ..problems import ApiError

__all__ = ["ARRAY_NAMES", "MAX_ROWS", "view_response"]

#: `arrays`: up to 32 comma-separated array names of the candidate NPZ
ARRAY_NAMES = r"^[a-z][a-z0-9_]{0,63}(,[a-z][a-z0-9_]{0,63}){0,31}$"
MAX_ROWS = 100_000_000


def view_response(
    request: Request, grasp_set_id: int, key: str | None, *, arrays: str | None, max_rows: int | None
) -> Response:
    """The view as an NPZ of stored (uncompressed) members: nothing to inflate for the reader. Strong ETag: the
    sha256 of the body; revalidated (a later graspgen may cut rows differently for the same query)."""
    if key is None:
        raise ApiError(404, "not-found", "this artifact was not stored")
    names = tuple(arrays.split(",")) if arrays else None
    cache: BlobCache = request.app.state.export_cache

    def make() -> bytes:
        try:
            data = cache.storage.get_bytes(key)
        except FileNotFoundError:
            raise ApiError(404, "not-found", "the artifact is missing from storage") from None
        try:
            return npz_bytes(candidate_view(data, arrays=names, max_rows=max_rows), deflate=False)
        except InvalidCandidatesError as exc:
            raise ApiError(503, "artifact-invalid", f"the stored candidate NPZ cannot be read: {exc}") from None

    body = cache.derived(("candidate-view", key, names, max_rows), make)
    etag = f'"{hashlib.sha256(body).hexdigest()}"'
    if etag_matches(request, etag):
        return not_modified(etag, REVALIDATE)
    headers = {
        "ETag": etag,
        "Cache-Control": REVALIDATE,
        "Content-Disposition": f'attachment; filename="grasp-set-{grasp_set_id}-candidates-view.npz"',
    }
    return Response(body, media_type="application/octet-stream", headers=headers)
