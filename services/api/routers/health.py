from __future__ import annotations

import logging

from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from ..problems import problem_response
from ..schemas import Health

router = APIRouter(tags=["health"])
log = logging.getLogger(__name__)


@router.get("/healthz", response_model=Health, summary="The process is up (no dependencies checked)")
async def healthz() -> dict:
    return {"status": "ok", "checks": {}}


@router.get(
    "/readyz",
    response_model=Health,
    summary="Database, broker and storage are reachable",
    responses={503: {"description": "A dependency is unreachable", "content": {"application/problem+json": {}}}},
)
async def readyz(request: Request) -> JSONResponse | dict:
    state = request.app.state
    checks: dict[str, str] = {}
    for name, probe in (
        ("database", state.db.ping),
        ("broker", state.dispatcher.ping),
        ("storage", state.storage.ping),
    ):
        try:
            await run_in_threadpool(probe)
            checks[name] = "ok"
        except Exception as exc:  # report which dependency failed, never its URL or credentials
            log.warning("readiness: %s unreachable (%s)", name, type(exc).__name__)
            checks[name] = "unreachable"
    if all(v == "ok" for v in checks.values()):
        return {"status": "ok", "checks": checks}
    bad = ", ".join(k for k, v in checks.items() if v != "ok")
    return problem_response(503, "not-ready", f"unreachable: {bad}", checks=checks)
