from __future__ import annotations

import uuid
from typing import Annotated

from fastapi import APIRouter, Header, Path, Query, Response

from services.common.models import JOB_STATES, TERMINAL_STATES
from services.jobkinds import DEFAULT_KIND, KINDS, RUNNABLE, JobRequest

from ..crud import jobs as crud
from ..deps import DispatcherDep, PagingDep, ReadDep, ReadSessionDep, SessionDep, SettingsDep, StorageDep, WriteDep
from ..schemas import BulkRequest, JobOut, JobPage
from . import problems

router = APIRouter(prefix="/v1", tags=["jobs"])

IdempotencyKey = Annotated[
    str | None,
    Header(
        alias="Idempotency-Key",
        max_length=255,
        description="Retries with the same key and body return the first job instead of creating another",
        examples=["plant-7-ring-screw-2026-11-23"],
    ),
]
JobId = Annotated[uuid.UUID, Path(examples=["4f1c7e4e-3c1a-4a59-9d1e-0b7f6f0b9a10"])]

#: how long a client should wait before polling a job again
RETRY_AFTER_S = "2"


def _accepted(response: Response, out: dict, replayed: bool) -> dict:
    response.headers["Location"] = f"/v1/jobs/{out['id']}"
    response.headers["Retry-After"] = RETRY_AFTER_S
    if replayed:
        response.headers["Idempotent-Replayed"] = "true"
    return out


@router.post(
    "/jobs",
    status_code=202,
    response_model=JobOut,
    summary="Submit a job: generate grasps, or re-cluster a stored grasp set",
    description="`kind` chooses the body: "
    + ", ".join(f"`{name}`" for name in RUNNABLE)
    + f" (default `{DEFAULT_KIND}`), each described in its schema. "
    "The job row is committed before the job is queued. Poll the `Location` until `state` is final.",
    responses=problems(413, 422, 503),
)
def submit_job(
    body: JobRequest,
    response: Response,
    principal: WriteDep,
    session: SessionDep,
    dispatcher: DispatcherDep,
    settings: SettingsDep,
    storage: StorageDep,
    idempotency_key: IdempotencyKey = None,
) -> dict:
    job, replayed = crud.submit_job(session, dispatcher, principal, body, idempotency_key, memory=(settings, storage))
    return _accepted(response, crud.job_out(session, job), replayed)


@router.post(
    "/bulk-jobs",
    status_code=202,
    response_model=JobOut,
    summary="Submit many generate jobs as one parent job",
    description="Every item becomes a child job; items that cannot be resolved (unknown object or gripper, invalid "
    "parameters) fail alone while the rest run. The parent shows per-item state and aggregated progress.",
    responses=problems(413, 422, 503),
)
def submit_bulk(
    body: BulkRequest,
    response: Response,
    principal: WriteDep,
    session: SessionDep,
    dispatcher: DispatcherDep,
    settings: SettingsDep,
    idempotency_key: IdempotencyKey = None,
) -> dict:
    job, replayed = crud.submit_bulk(
        session, dispatcher, principal, body, idempotency_key, max_items=settings.max_bulk_items
    )
    return _accepted(response, crud.job_out(session, job), replayed)


@router.get(
    "/jobs",
    response_model=JobPage,
    summary="List your jobs, newest first",
    description="The jobs submitted with this token's name (every job for an admin token), filtered by `state` and "
    "`kind`, paginated by cursor. Bulk items are not listed on their own: they are in their parent's `items`.",
    responses=problems(422),
)
def list_jobs(
    principal: ReadDep,
    session: ReadSessionDep,
    page: PagingDep,
    state: Annotated[str | None, Query(pattern="^(" + "|".join(JOB_STATES) + ")$")] = None,
    kind: Annotated[str | None, Query(pattern="^(" + "|".join(KINDS) + ")$")] = None,
) -> dict:
    return crud.list_jobs(
        session,
        principal,
        state=state,
        kind=kind,
        cursor=page.cursor,
        limit=page.limit,
    )


@router.get(
    "/jobs/{job_id}", response_model=JobOut, summary="A job's state, stage and progress", responses=problems(404, 422)
)
def get_job(job_id: JobId, response: Response, principal: ReadDep, session: ReadSessionDep) -> dict:
    out = crud.job_out(session, crud.get_job(session, job_id))
    if out["state"] not in TERMINAL_STATES:
        response.headers["Retry-After"] = RETRY_AFTER_S
    return out


@router.post(
    "/jobs/{job_id}/cancel",
    response_model=JobOut,
    summary="Cancel a job (a bulk job: all its unfinished items)",
    description="A queued job is cancelled at once (200). A running job is flagged and stops at its next stage "
    "(202 while it winds down). Cancelling a finished job is a 409; cancelling a cancelled job is a no-op.",
    responses={202: {"description": "Cancellation requested", "model": JobOut}, **problems(404, 409, 422)},
)
def cancel_job(
    job_id: JobId, response: Response, principal: WriteDep, session: SessionDep, dispatcher: DispatcherDep
) -> dict:
    job = crud.cancel_job(session, dispatcher, principal, job_id)
    out = crud.job_out(session, job)
    if out["state"] not in TERMINAL_STATES:
        response.status_code = 202
        response.headers["Retry-After"] = RETRY_AFTER_S
    return out
