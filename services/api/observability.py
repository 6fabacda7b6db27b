"""Request ids, HTTP metrics, `GET /metrics` and the per-token rate limit of the API.

`RequestContextMiddleware` wraps the whole application, error handling included, so every response (a 401, a 422, a
500) carries `X-Request-ID`, every log line written while the request runs carries its id (services/common/logs.py),
and every request is counted in `graspgen_http_request_duration_seconds` under its route template.
"""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, Request, Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from services.common.logs import REQUEST_ID_HEADER, new_request_id, request_id_var, valid_request_id
from services.common.metrics import CONTENT_TYPE_LATEST, HTTP_DURATION, QueueDepthCollector, render, scrape_registry

from .deps import AdminDep
from .ratelimit import TokenBuckets
from .routers import problems

__all__ = ["RequestContextMiddleware", "TokenBuckets", "router", "install"]

_METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})
_HEADER_KEY = REQUEST_ID_HEADER.lower().encode("latin-1")


class RequestContextMiddleware:
    # about 10 us a request over a bare ASGI app: raw header scans instead of Headers objects, the histogram's
    # labelled children cached here, not looked up under prometheus-client's lock every time
    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self._series: dict[tuple[str, str, int], Any] = {}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        rid = None
        for key, value in scope["headers"]:
            if key == _HEADER_KEY:
                rid = valid_request_id(value.decode("latin-1"))
                break
        rid = rid or new_request_id()
        scope.setdefault("state", {})["request_id"] = rid
        token = request_id_var.set(rid)
        header = (_HEADER_KEY, rid.encode("latin-1"))
        status = 500  # what the server answers when the app raises before starting a response
        started = time.perf_counter()

        async def send_with_id(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                message["headers"] = [*message.get("headers", ()), header]
            await send(message)

        try:
            await self.app(scope, receive, send_with_id)
        finally:
            elapsed = time.perf_counter() - started
            route = scope.get("route")
            # the template (/v1/jobs/{job_id}), never the raw path: one series per route, not per id
            template = getattr(route, "path", None) or "unmatched"
            method = scope.get("method", "GET")
            key = (method if method in _METHODS else "other", template, status)
            series = self._series.get(key)
            if series is None:
                series = self._series[key] = HTTP_DURATION.labels(key[0], template, str(status))
            series.observe(elapsed)
            request_id_var.reset(token)


router = APIRouter(tags=["health"])


@router.get(
    "/metrics",
    summary="Prometheus metrics of this API process (scope admin)",
    description="Text exposition format 0.0.4: HTTP request durations by route template and status, jobs by kind "
    "and final state, stage durations, queue depth, export cache hits, previews, rate-limited requests. "
    "`GRASPGEN_METRICS_PORT` offers the same without a token on a separate port.",
    response_class=Response,
    responses={200: {"content": {CONTENT_TYPE_LATEST: {"schema": {"type": "string"}}}}, **problems()},
)
def get_metrics(request: Request, principal: AdminDep) -> Response:
    return Response(render(request.app.state.metrics_registry), media_type=CONTENT_TYPE_LATEST)


def install(app: Any, settings: Any, dispatcher: Any) -> None:
    """Wire the request-id middleware (outside everything, error handling included), /metrics and the rate limit."""
    app.state.metrics_registry = scrape_registry([QueueDepthCollector(queue_depth_reader(settings, dispatcher))])
    app.state.rate_limiter = (
        TokenBuckets(settings.rate_limit_per_s, settings.rate_limit_burst) if settings.rate_limit_per_s > 0 else None
    )
    app.include_router(router)
    build = app.build_middleware_stack

    def build_middleware_stack() -> ASGIApp:
        # Starlette's ServerErrorMiddleware is always the outermost layer it builds; ours goes around it so that a
        # 500 it answers carries the request id too
        return RequestContextMiddleware(build())

    app.build_middleware_stack = build_middleware_stack


def queue_depth_reader(settings: Any, dispatcher: Any):
    pending = getattr(dispatcher, "pending", None)
    if callable(pending):
        return pending
    if settings.broker_url is not None and settings.broker_url.get_secret_value().startswith(("redis://", "rediss://")):
        from services.common.metrics import redis_queue_depth

        reader = None

        def read() -> int:
            nonlocal reader
            if reader is None:
                reader = redis_queue_depth(
                    settings.broker_url.get_secret_value(), settings.queue, settings.broker_key_prefix
                )
            return reader()

        return read
    return lambda: None
