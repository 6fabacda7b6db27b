"""Conditional requests and artifact responses (strong ETags, immutable caching), and HEAD for every GET."""

from __future__ import annotations

from collections.abc import Callable, Hashable

from fastapi import Request, Response
from fastapi.responses import StreamingResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from services.common.storage import Storage

from .cache import SizedLRU
from .problems import ApiError

__all__ = [
    "BlobCache",
    "HeadMiddleware",
    "IMMUTABLE",
    "REVALIDATE",
    "not_modified",
    "etag_matches",
    "blob_response",
    "blob_etag",
]

IMMUTABLE = "private, max-age=31536000, immutable"
REVALIDATE = "private, no-cache"


def etag_matches(request: Request, etag: str) -> bool:
    """If-None-Match uses the weak comparison (RFC 9110 13.1.2): W/ prefixes are ignored."""
    header = request.headers.get("if-none-match")
    if not header:
        return False
    if header.strip() == "*":
        return True
    want = etag.removeprefix("W/")
    return any(tag.strip().removeprefix("W/") == want for tag in header.split(","))


def not_modified(etag: str, cache_control: str) -> Response:
    return Response(status_code=304, headers={"ETag": etag, "Cache-Control": cache_control})


def blob_etag(key: str) -> str:
    # keys are sha256/<2>/<64 hex>: the digest is the content's identity
    return f'"{key.rsplit("/", 1)[-1]}"'


def blob_response(
    request: Request, storage: Storage, key: str | None, *, media_type: str, filename: str, cache_control: str
) -> Response:
    if key is None:
        raise ApiError(404, "not-found", "this artifact was not stored")
    etag = blob_etag(key)
    if etag_matches(request, etag):
        return not_modified(etag, cache_control)
    try:
        size = storage.size(key)
    except FileNotFoundError:
        raise ApiError(404, "not-found", "the artifact is missing from storage") from None
    headers = {
        "ETag": etag,
        "Cache-Control": cache_control,
        "Content-Length": str(size),
        "Content-Disposition": f'attachment; filename="{filename}"',
    }
    return StreamingResponse(storage.iter_chunks(key), media_type=media_type, headers=headers)


class BlobCache:
    """Bytes of immutable blobs (grasp-set exports) and of what is made from them (views of candidate NPZs) kept in
    memory, least recently used evicted first.

    Content-addressed keys never change meaning, so nothing is ever invalidated; with S3 storage this saves a round
    trip to the bucket on every catalogue lookup.
    """

    def __init__(self, storage: Storage, max_bytes: int) -> None:
        self.storage = storage
        self.max_bytes = max_bytes
        self._lru: SizedLRU[bytes] = SizedLRU(max_bytes)

    def get(self, key: str) -> bytes:
        from services.common.metrics import EXPORT_CACHE

        data = self._lru.get(key)
        EXPORT_CACHE.labels("miss" if data is None else "hit").inc()
        if data is None:
            data = self.storage.get_bytes(key)
            self._lru.put(key, data, len(data))
        return data

    def derived(self, key: Hashable, make: Callable[[], bytes]) -> bytes:
        """Bytes made from immutable blobs (a view of a candidate NPZ), made once and kept in the same budget."""
        data = self._lru.get(key)
        if data is None:
            data = make()
            self._lru.put(key, data, len(data))
        return data


class HeadMiddleware:
    """HEAD answered as GET without the body (RFC 9110 9.3.2: the same status and headers, Content-Length and ETag
    included), so a client can check a catalogue entry's ETag or an artifact's size without downloading it. The
    route runs as a GET (auth, rate limits and metrics count it as one); a path without GET still answers 405 with
    its Allow header."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("method") != "HEAD":
            await self.app(scope, receive, send)
            return

        async def send_headers_only(message: Message) -> None:
            if message["type"] == "http.response.body":
                if message.get("more_body", False):
                    return  # the rest of a streamed body: dropped
                message = {"type": "http.response.body", "body": b"", "more_body": False}
            await send(message)

        await self.app({**scope, "method": "GET"}, receive, send_headers_only)
