"""Request body limits enforced while the body streams in, answered with a problem+json 413.

A declared Content-Length above the limit is refused before any byte is read; a chunked or lying body is cut off as
soon as the running count passes the limit. The upload routes get larger limits (the files plus multipart overhead):
`POST /v1/objects` for any body, `POST /v1/grippers` for a multipart body only (its JSON body keeps the default).
"""

from __future__ import annotations

from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .problems import problem_response

__all__ = ["BodyLimitMiddleware", "BodyTooLarge"]

#: room for the multipart boundaries and the small form fields around an uploaded file
MULTIPART_OVERHEAD = 64 * 1024


class BodyTooLarge(HTTPException):  # noqa: N818 - an HTTP status, handled as a problem by the app
    def __init__(self, limit: int) -> None:
        super().__init__(413, f"the request body is larger than the limit of {limit} bytes")


class BodyLimitMiddleware:
    def __init__(
        self,
        app: ASGIApp,
        *,
        default_limit: int,
        limits: dict[tuple[str, str], int],
        multipart_limits: dict[tuple[str, str], int] | None = None,
    ) -> None:
        self.app = app
        self.default_limit = default_limit
        self.limits = limits
        #: (method, path) -> the limit of a multipart/form-data body there (other bodies: `limits` or the default)
        self.multipart_limits = multipart_limits or {}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path = scope.get("path", "").rstrip("/") or "/"
        key = (scope.get("method", "GET"), path)
        headers = Headers(scope=scope)
        limit = self.limits.get(key, self.default_limit)
        if key in self.multipart_limits and headers.get("content-type", "").lower().startswith("multipart/form-data"):
            limit = self.multipart_limits[key]
        declared = headers.get("content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            response = problem_response(
                413,
                "content-too-large",
                f"the request body is larger than the limit of {limit} bytes",
                instance=scope.get("path"),
                headers={"Connection": "close"},
            )
            await response(scope, receive, send)
            return
        seen = 0

        async def limited_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    # an HTTPException passes FastAPI's body parsing untouched and reaches the problem handler
                    raise BodyTooLarge(limit)
            return message

        await self.app(scope, limited_receive, send)
