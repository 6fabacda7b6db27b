"""Job submission (a job of any kind that runs, services/jobkinds; a bulk parent with its items), idempotency keys,
views and cancellation.

Rows are committed before anything is sent to a worker; if the broker refuses, the rows are removed again so that a
failed request leaves the database as it was.
"""

from __future__ import annotations

import logging
import uuid
from datetime import datetime
from typing import Any

from sqlalchemy import and_, delete, or_, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from graspgen.errors import GraspgenError
from services.common import jobs as J  # noqa: N812 - short name for the shared job helpers
from services.common.logs import request_id_var
from services.common.models import TERMINAL_STATES, GripperVersion, Job, ObjectVersion, utcnow
from services.common.settings import Settings
from services.common.storage import Storage, StorageError
from services.common.tokens import Principal
from services.common.versions import GRIPPERS, OBJECTS, name_and_version
from services.jobkinds import RUNNABLE, JobRequest, is_container
from services.jobkinds import bulk as bulk_kind
from services.worker.dispatch import Dispatcher, DispatchError

from ..pagination import decode_cursor, fetch_page, next_link
from ..problems import ApiError
from ..schemas import BulkRequest

__all__ = [
    "submit_job",
    "submit_bulk",
    "job_out",
    "get_job",
    "list_jobs",
    "cancel_job",
]

log = logging.getLogger(__name__)


def _replay(session: Session, principal: Principal, key: str | None, request_sha: str) -> Job | None:
    if key is None:
        return None
    job = session.execute(
        select(Job).where(Job.created_by == principal.name, Job.idempotency_key == key)
    ).scalar_one_or_none()
    if job is not None and job.request_sha256 != request_sha:
        raise ApiError(
            422,
            "idempotency-key-reused",
            "this Idempotency-Key was used for a different request",
            field="Idempotency-Key",
        )
    return job


def _dispatch_or_undo(session: Session, dispatcher: Dispatcher, job_id: uuid.UUID, send: list[str]) -> None:
    if not send:
        return
    try:
        dispatcher.send(send)
    except DispatchError as exc:
        session.execute(delete(Job).where(Job.parent_id == job_id))
        session.execute(delete(Job).where(Job.id == job_id))
        session.commit()
        raise ApiError(
            503, "broker-unavailable", "jobs cannot be queued right now; retry later", headers={"Retry-After": "10"}
        ) from exc


def submit_job(
    session: Session,
    dispatcher: Dispatcher,
    principal: Principal,
    body: JobRequest,
    idempotency_key: str | None,
    *,
    memory: tuple[Settings, Storage] | None = None,
) -> tuple[Job, bool]:
    """Returns (job, replayed): replayed is true when an Idempotency-Key matched an earlier identical request.

    `memory`: check the estimated peak memory of a job whose kind `checks_memory` against the job memory budget (422
    `memory-limit`)."""
    request = body.model_dump(exclude_none=True)
    request_sha = J.sha256_json(request)
    replayed = _replay(session, principal, idempotency_key, request_sha)
    if replayed is not None:
        return replayed, True
    kind = RUNNABLE[body.root.kind]  # the union holds exactly the kinds that run
    resolved = kind.resolve(session, body.root)
    if memory is not None and kind.checks_memory:
        _check_memory(session, *memory, resolved)
    job = Job(
        id=uuid.uuid4(),
        kind=kind.name,
        state="queued",
        request=request,
        idempotency_key=idempotency_key,
        request_sha256=request_sha,
        created_by=principal.name,
        request_id=request_id_var.get(),  # X-Request-ID of this request: logs tie the job to it
        **resolved,
    )
    session.add(job)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()  # the same key committed concurrently
        again = _replay(session, principal, idempotency_key, request_sha)
        if again is None:
            raise
        return again, True
    _dispatch_or_undo(session, dispatcher, job.id, [str(job.id)])
    return job, False


def _check_memory(session: Session, settings: Settings, storage: Storage, resolved: dict[str, Any]) -> None:
    from graspgen.memory import MemoryLimitError
    from graspgen.parts import load_part
    from services.common.grippers import stored_gripper_spec
    from services.common.memory_guard import check_generate, problem_extra

    ov = session.get(ObjectVersion, resolved["object_version_id"])
    gv = session.get(GripperVersion, resolved["gripper_version_id"])
    assert ov is not None and gv is not None
    units, fmt, key, sha, spec = ov.units, ov.format, ov.file_key, ov.sha256, dict(gv.spec)
    session.rollback()  # no transaction (a SQLite write lock) held while a probe runs
    try:
        check_generate(
            budget_bytes=settings.job_memory_budget,
            part_sha256=sha,
            units=units,
            spec=spec,
            params=resolved["params"],
            load_part=lambda: load_part(
                storage.get_bytes(key), units=units, file_type=fmt, max_decoded_bytes=settings.max_decoded_bytes
            ),  # only when no probe of this part, gripper and parameters is cached
            load_gripper=lambda: stored_gripper_spec(storage, spec, max_decoded_bytes=settings.max_decoded_bytes),
        )
    except (OSError, StorageError) as exc:
        # the part's file is unreadable here: the worker, which must read it to run the job, checks the memory
        log.warning("memory check skipped at submission: a part or gripper file is unreadable (%s)", type(exc).__name__)
    except MemoryLimitError as exc:
        extra = problem_extra(exc)
        raise ApiError(422, exc.code, exc.message, title="Job too large for the worker's memory", **extra) from exc


def submit_bulk(
    session: Session,
    dispatcher: Dispatcher,
    principal: Principal,
    body: BulkRequest,
    idempotency_key: str | None,
    *,
    max_items: int,
) -> tuple[Job, bool]:
    if len(body.items) > max_items:
        raise ApiError(422, "too-many-items", f"a bulk job takes at most {max_items} items", field="items")
    request = body.model_dump(exclude_none=True)
    request_sha = J.sha256_json(request)
    replayed = _replay(session, principal, idempotency_key, request_sha)
    if replayed is not None:
        return replayed, True
    item_kind = bulk_kind.KIND.item
    parent = Job(
        id=uuid.uuid4(),
        kind=bulk_kind.KIND.name,
        state="queued",
        request={"items": len(body.items)},
        idempotency_key=idempotency_key,
        request_sha256=request_sha,
        created_by=principal.name,
        request_id=request_id_var.get(),
    )
    session.add(parent)
    session.flush()
    children: list[Job] = []
    for i, (item, body_item) in enumerate(zip(request["items"], body.items, strict=True)):
        child = Job(
            id=uuid.uuid4(),
            kind=item_kind.name,
            state="queued",
            request=item,
            parent_id=parent.id,
            item_index=i,
            created_by=principal.name,
            request_id=request_id_var.get(),
        )
        try:
            for k, v in item_kind.resolve(session, body_item).items():
                setattr(child, k, v)
        except ApiError as exc:
            # a bad item fails alone; the others run
            J.finish(child, "failed", error=J.problem(exc.code, exc.title, exc.detail, status=exc.status, **exc.extra))
        except GraspgenError as exc:
            extra: dict[str, Any] = {"field": exc.field} if exc.field else {}
            J.finish(child, "failed", error=J.problem(exc.code, "Invalid input", exc.message, **extra))
        children.append(child)
    session.add_all(children)
    session.flush()
    J.refresh_parent(session, parent.id)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        again = _replay(session, principal, idempotency_key, request_sha)
        if again is None:
            raise
        return again, True
    _dispatch_or_undo(session, dispatcher, parent.id, [str(c.id) for c in children if c.state == "queued"])
    return parent, False


def get_job(session: Session, job_id: uuid.UUID) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise ApiError(404, "not-found", f"no job {job_id}")
    return job


def job_out(session: Session, job: Job) -> dict[str, Any]:
    out: dict[str, Any] = {
        "id": job.id,
        "kind": job.kind,
        "state": job.state,
        "stage": job.stage,
        "progress": round(float(job.progress), 4),
        "grasp_set": job.grasp_set_id,
        "error": job.error,
        "source_grasp_set": job.source_grasp_set_id,
        "params": job.params,
        "request": job.request,
        "attempts": job.attempts,
        "cancel_requested": job.cancel_requested,
        "parent": job.parent_id,
        "created_at": job.created_at,
        "started_at": job.started_at,
        "finished_at": job.finished_at,
        "links": {"self": f"/v1/jobs/{job.id}", "cancel": f"/v1/jobs/{job.id}/cancel"},
    }
    if job.grasp_set_id is not None:
        out["links"]["grasp_set"] = f"/v1/grasp-sets/{job.grasp_set_id}"
    if job.parent_id is not None:
        out["links"]["parent"] = f"/v1/jobs/{job.parent_id}"
    if job.object_version_id is not None:
        out["object"], out["object_version"] = name_and_version(session, OBJECTS, job.object_version_id)
    if job.gripper_version_id is not None:
        out["gripper"], out["gripper_version"] = name_and_version(session, GRIPPERS, job.gripper_version_id)
    if is_container(job.kind):
        agg = J.aggregate_children(session, job.id)
        children = session.execute(select(Job).where(Job.parent_id == job.id).order_by(Job.item_index)).scalars()
        out["summary"] = {s: agg.counts.get(s, 0) for s in ("queued", "running", "succeeded", "failed", "cancelled")}
        out["summary"]["total"] = agg.total
        # progress and state are read live from the children; the parent row is refreshed as each child ends
        out["progress"] = round(agg.progress, 4)
        out["state"] = agg.state(cancel_requested=job.cancel_requested)
        out["stage"] = f"{agg.done}/{agg.total} items done"
        out["error"] = agg.error()
        out["items"] = [
            {
                "index": c.item_index,
                "id": c.id,
                "state": c.state,
                "stage": c.stage,
                "progress": round(float(c.progress), 4),
                "object": c.request.get("object"),
                "gripper": c.request.get("gripper"),
                "grasp_set": c.grasp_set_id,
                "error": c.error,
                "links": {"self": f"/v1/jobs/{c.id}"},
            }
            for c in children
        ]
    return out


def list_jobs(
    session: Session, principal: Principal, *, state: str | None, kind: str | None, cursor: str | None, limit: int
) -> dict[str, Any]:
    """The caller's jobs (every job for an admin token), newest first; bulk items are listed in their parent."""
    key = decode_cursor(cursor, (str, str))
    q = select(Job).where(Job.parent_id.is_(None))
    if not principal.has("admin"):
        q = q.where(Job.created_by == principal.name)
    if state:
        q = q.where(Job.state == state)
    if kind:
        q = q.where(Job.kind == kind)
    if key:
        try:
            at, jid = datetime.fromisoformat(key[0]), uuid.UUID(key[1])
        except ValueError:
            raise ApiError(422, "invalid-cursor", "the cursor is not one this endpoint issued") from None
        if at.tzinfo is None:
            raise ApiError(422, "invalid-cursor", "the cursor is not one this endpoint issued")
        q = q.where(or_(Job.created_at < at, and_(Job.created_at == at, Job.id < jid)))
    order = q.order_by(Job.created_at.desc(), Job.id.desc())
    rows, nxt = fetch_page(session, order, limit, lambda j: [j.created_at.isoformat(), str(j.id)], scalars=True)
    query = "".join(f"&{k}={v}" for k, v in (("state", state), ("kind", kind)) if v)
    return {
        "items": [
            {
                "id": j.id,
                "kind": j.kind,
                "state": j.state,
                "stage": j.stage,
                "progress": round(float(j.progress), 4),
                "grasp_set": j.grasp_set_id,
                "error": j.error,
                "object": j.request.get("object"),
                "gripper": j.request.get("gripper"),
                "created_by": j.created_by,
                "created_at": j.created_at,
                "finished_at": j.finished_at,
                "links": {"self": f"/v1/jobs/{j.id}"},
            }
            for j in rows
        ],
        "next_cursor": nxt,
        "links": {"next": next_link("/v1/jobs", nxt, limit, query)},
    }


def cancel_job(session: Session, dispatcher: Dispatcher, principal: Principal, job_id: uuid.UUID) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise ApiError(404, "not-found", f"no job {job_id}")
    container = is_container(job.kind)
    if not container:
        # rows are locked child first, then parent, the order the worker uses when a child finishes
        job = session.execute(
            select(Job).where(Job.id == job_id).with_for_update().execution_options(populate_existing=True)
        ).scalar_one()
    if job.created_by != principal.name and not principal.has("admin"):
        raise ApiError(403, "forbidden", "only the job's submitter or an admin token may cancel it")
    if job.state in TERMINAL_STATES and not container:
        if job.state == "cancelled":
            return job
        raise ApiError(409, "job-finished", f"the job has already {job.state}", state=job.state)
    targets = [job]
    if container:
        targets = list(
            session.execute(
                select(Job).where(Job.parent_id == job.id, Job.state.not_in(TERMINAL_STATES)).with_for_update()
            ).scalars()
        )
        if not targets and job.cancel_requested:
            return job
        if not targets and not job.cancel_requested:
            state = J.aggregate_children(session, job.id).state(cancel_requested=False)
            if state in TERMINAL_STATES:
                raise ApiError(409, "job-finished", f"the bulk job has already {state}", state=state)
        job.cancel_requested = True
    revoke = []
    for t in targets:
        t.cancel_requested = True
        if t.state == "queued":
            J.finish(t, "cancelled")  # never started: cancelled now; running ones stop at their next stage
            revoke.append(str(t.id))
    if container:
        session.flush()
        J.refresh_parent(session, job.id)
    elif job.parent_id is not None:
        session.flush()
        J.refresh_parent(session, job.parent_id)
    job.updated_at = utcnow()
    session.commit()
    if revoke:
        dispatcher.revoke(revoke)
    return job
