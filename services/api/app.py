"""The FastAPI application: `create_app(settings)` wires database, storage, tokens and the job dispatcher."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import APIRoute

from graspgen.gripper_geometry import MESH_ROLES
from services.common.db import Database, redacted_url
from services.common.settings import Settings, get_settings
from services.common.storage import make_storage
from services.common.tokens import TokenStore
from services.worker.dispatch import Dispatcher, EmbeddedDispatcher, make_dispatcher

from . import observability, ui
from .http import BlobCache, HeadMiddleware
from .limits import MULTIPART_OVERHEAD, BodyLimitMiddleware
from .openapi_docs import document_contract
from .problems import install_problem_handlers, problem_schema
from .routers import grasp_sets, grippers, health, jobs, objects, pairs, pick, previews

__all__ = ["create_app"]

log = logging.getLogger(__name__)

DESCRIPTION = """\
Grasps for parallel-jaw grippers as a service (CONTRACT.md, HTTP API). Every length is in metres.

* Upload parts (`/v1/objects`) and gripper specs (`/v1/grippers`), submit jobs (`/v1/jobs`, `/v1/bulk-jobs`),
  poll them, then read immutable grasp-set versions (`/v1/grasp-sets/{id}`) or the catalogue (`/v1/catalogue`).
* Errors are RFC 9457 `application/problem+json`.
* Authentication: `Authorization: Bearer <token>`; scopes `read` < `write` < `admin`.
"""


def create_app(
    settings: Settings | None = None, *, dispatcher: Dispatcher | None = None, recover_jobs: bool = True
) -> FastAPI:
    settings = settings or get_settings()
    db = Database(settings)
    storage = make_storage(settings)
    tokens = TokenStore(settings.tokens_path)  # fails fast on a missing or malformed tokens file
    dispatcher = dispatcher or make_dispatcher(settings, db, storage)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        log.info(
            "database %s, jobs %s, storage %s",
            redacted_url(db.url),
            "in-process" if settings.embedded_worker else f"Celery queue {settings.queue!r}",
            settings.storage_url or settings.storage_dir,
        )
        if recover_jobs and isinstance(dispatcher, EmbeddedDispatcher):
            n = dispatcher.recover()
            if n:
                log.info("re-queued %d unfinished job(s) from the previous run", n)
        try:
            yield
        finally:
            app.state.previews.close()
            dispatcher.close()
            db.dispose()

    app = FastAPI(
        title="graspgen",
        version="1",
        description=DESCRIPTION,
        lifespan=lifespan,
        generate_unique_id_function=operation_id,
        openapi_tags=[
            {"name": "objects", "description": "Parts, versioned by content"},
            {"name": "grippers", "description": "Gripper specs, versioned"},
            {"name": "jobs", "description": "Asynchronous generate, cluster and bulk jobs"},
            {"name": "grasp sets", "description": "Immutable grasp-set versions and their artifacts"},
            {"name": "catalogue", "description": "Newest grasp sets per object and gripper, for fleets"},
            {"name": "pick", "description": "World-frame grasps for a part where it lies (docs/API.md)"},
            {"name": "health", "description": "Liveness and readiness"},
        ],
    )
    app.state.settings = settings
    app.state.db = db
    app.state.storage = storage
    app.state.tokens = tokens
    app.state.export_cache = BlobCache(storage, settings.export_cache_bytes)
    app.state.dispatcher = dispatcher
    install_problem_handlers(app)
    for r in (
        objects.router,
        grippers.router,
        jobs.router,
        grasp_sets.router,
        pairs.router,
        previews.router,
        pick.router,
        health.router,
    ):
        app.include_router(r)
    previews.install(app, settings)
    ui.install(app)  # the review page at /ui/ (issue 34)
    observability.install(app, settings, dispatcher)  # request ids, /metrics, rate limits (issue 16)
    app.add_middleware(HeadMiddleware)  # outside request ids, metrics and rate limits: they count a HEAD as a GET
    app.add_middleware(
        BodyLimitMiddleware,
        default_limit=settings.max_json_bytes,
        limits={("POST", "/v1/objects"): settings.max_upload_bytes + MULTIPART_OVERHEAD},
        # a gripper's mesh files: finger, finger_left and body, each at most max_upload_bytes
        multipart_limits={("POST", "/v1/grippers"): len(MESH_ROLES) * settings.max_upload_bytes + MULTIPART_OVERHEAD},
    )

    def openapi() -> dict:
        if app.openapi_schema is None:
            schema = get_openapi(
                title=app.title,
                version=app.version,
                description=app.description,
                routes=app.routes,
                tags=app.openapi_tags,
            )
            schema.setdefault("components", {}).setdefault("schemas", {})["Problem"] = problem_schema()
            document_contract(schema)
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]  # FastAPI's documented way to extend the schema
    return app


def operation_id(route: APIRoute) -> str:
    """Readable operation ids for generated clients: the route function's name in camelCase (`get_object` ->
    `getObject`); function names are unique across the routers."""
    head, *rest = route.name.split("_")
    return head + "".join(w[:1].upper() + w[1:] for w in rest)
