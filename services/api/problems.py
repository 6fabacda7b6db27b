"""RFC 9457 problem details for every error the API returns (`application/problem+json`).

`type` is a URN naming the problem (`urn:graspgen:problem:<code>`), `code` repeats the slug for clients that switch on
it. graspgen's own input errors (GraspgenError) map here once; anything unexpected becomes a 500 without internals.

Failing dependencies are 503s with `Retry-After`, never 500s: `storage-unavailable` (an artifact could not be
written) and `database-unavailable` (a dropped, refused or exhausted connection). A GET or HEAD whose connection
dropped under it is retried once, transparently, before the 503: reads are idempotent and the pool has been renewed
by then (services/common/db.py). Other methods are not retried here, since their commit may have gone through; a
client retries them, with an Idempotency-Key where the route takes one.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from graspgen.errors import GraspgenError
from services.common.db import is_disconnect, is_unavailable
from services.common.jobs import problem
from services.common.storage import StorageError

__all__ = [
    "ApiError",
    "problem_response",
    "install_problem_handlers",
    "PROBLEM_JSON",
    "problem_schema",
    "DatabaseErrorMiddleware",
    "RETRY_AFTER_UNAVAILABLE_S",
]

log = logging.getLogger(__name__)

PROBLEM_JSON = "application/problem+json"

_TITLES = {
    400: "Bad request",
    401: "Unauthorized",
    403: "Forbidden",
    404: "Not found",
    405: "Method not allowed",
    406: "Not acceptable",
    409: "Conflict",
    412: "Precondition failed",
    413: "Content too large",
    415: "Unsupported media type",
    422: "Unprocessable content",
    429: "Too many requests",
    500: "Internal server error",
    503: "Service unavailable",
}
_CODES = {
    400: "bad-request",
    401: "unauthorized",
    403: "forbidden",
    404: "not-found",
    405: "method-not-allowed",
    409: "conflict",
    413: "content-too-large",
    415: "unsupported-media-type",
    422: "validation-error",
    500: "internal-error",
    503: "unavailable",
}

#: Retry-After of the 503s for a failing database or storage
RETRY_AFTER_UNAVAILABLE_S = "5"


class ApiError(Exception):
    def __init__(
        self,
        status: int,
        code: str,
        detail: str,
        *,
        title: str | None = None,
        headers: dict[str, str] | None = None,
        **extra: Any,
    ) -> None:
        super().__init__(detail)
        self.status = status
        self.code = code
        self.detail = detail
        self.title = title or _TITLES.get(status, "Error")
        self.headers = headers or {}
        self.extra = extra


def problem_response(
    status: int,
    code: str,
    detail: str,
    *,
    title: str | None = None,
    instance: str | None = None,
    headers: dict[str, str] | None = None,
    **extra: Any,
) -> JSONResponse:
    body = problem(code, title or _TITLES.get(status, "Error"), detail, status=status)
    if instance:
        body["instance"] = instance
    body.update(extra)
    return JSONResponse(body, status_code=status, media_type=PROBLEM_JSON, headers=headers)


def install_problem_handlers(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError) -> JSONResponse:
        return problem_response(
            exc.status,
            exc.code,
            exc.detail,
            title=exc.title,
            instance=request.url.path,
            headers=exc.headers,
            **exc.extra,
        )

    @app.exception_handler(StorageError)
    async def _storage_error(request: Request, exc: StorageError) -> JSONResponse:
        log.warning("storage failed on %s %s: %s", request.method, request.url.path, exc)
        return problem_response(
            503,
            "storage-unavailable",
            "the artifact storage cannot store files right now; nothing was saved, retry later",
            title="Storage unavailable",
            instance=request.url.path,
            headers={"Retry-After": RETRY_AFTER_UNAVAILABLE_S},
        )

    @app.exception_handler(GraspgenError)
    async def _graspgen_error(request: Request, exc: GraspgenError) -> JSONResponse:
        extra: dict[str, Any] = {"field": exc.field} if exc.field else {}
        return problem_response(422, exc.code, exc.message, title="Invalid input", instance=request.url.path, **extra)

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [
            {"loc": [str(p) for p in e.get("loc", ())], "msg": e.get("msg", ""), "type": e.get("type", "")}
            for e in exc.errors()
        ]
        first: dict[str, Any] = errors[0] if errors else {"loc": [], "msg": "invalid request"}
        where = ".".join(first["loc"])
        detail = f"{where}: {first['msg']}" if where else first["msg"]
        return problem_response(422, "validation-error", detail, instance=request.url.path, errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        status = exc.status_code
        detail = exc.detail if isinstance(exc.detail, str) else _TITLES.get(status, "Error")
        return problem_response(
            status, _CODES.get(status, "error"), detail, instance=request.url.path, headers=dict(exc.headers or {})
        )

    @app.exception_handler(Exception)
    async def _internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem_response(500, "internal-error", "an internal error occurred", instance=request.url.path)

    # database errors pass the handlers above (none matches them) and reach this middleware, which can retry
    app.add_middleware(DatabaseErrorMiddleware)


class DatabaseErrorMiddleware:
    """Database failures as 503 problems; a GET or HEAD whose connection dropped is first run once more.

    Sits outside the routes' exception handlers, so it sees the exception itself and can run the request again;
    only while no response byte was sent (a failure while streaming cannot be turned into a problem any more).
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False
        received: list[Message] = []

        async def recording_receive() -> Message:
            message = await receive()
            received.append(message)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, recording_receive, tracking_send)
            return
        except Exception as error:
            if started or not is_unavailable(error):
                raise
            first = error
        if scope.get("method") in ("GET", "HEAD") and is_disconnect(first):
            log.info("database connection dropped under %s %s; retrying once", scope["method"], scope.get("path"))
            replay = list(received)

            async def replaying_receive() -> Message:
                return replay.pop(0) if replay else await receive()

            try:
                await self.app(scope, replaying_receive, tracking_send)
                return
            except Exception as error:
                if started or not is_unavailable(error):
                    raise
                first = error
        log.warning("database unavailable on %s %s: %s", scope.get("method"), scope.get("path"), type(first).__name__)
        response = problem_response(
            503,
            "database-unavailable",
            "the database cannot be reached right now; retry later",
            title="Database unavailable",
            instance=scope.get("path"),
            headers={"Retry-After": RETRY_AFTER_UNAVAILABLE_S},
        )
        await response(scope, receive, send)


def problem_schema() -> dict[str, Any]:
    """OpenAPI schema of a problem document."""
    return {
        "type": "object",
        "required": ["type", "title", "status", "detail"],
        "properties": {
            "type": {"type": "string", "format": "uri", "example": "urn:graspgen:problem:not-found"},
            "title": {"type": "string", "example": "Not found"},
            "status": {"type": "integer", "example": 404},
            "detail": {"type": "string", "example": "no object named 'ring-screw'"},
            "instance": {"type": "string", "example": "/v1/objects/ring-screw"},
            "code": {"type": "string", "example": "not-found"},
        },
        "additionalProperties": True,
    }
