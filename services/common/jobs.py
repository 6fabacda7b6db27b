"""Job bookkeeping shared by the API (submission, cancellation, views) and the worker (claim, result, failure).

States: queued -> running -> succeeded | failed | cancelled. A bulk job is a parent whose state and progress are the
aggregate of its child jobs; one failed child fails alone, but the parent then ends `failed` (never `succeeded` unless
every item succeeded) with an error that counts the failed items.
"""

from __future__ import annotations

import hashlib
import json
import uuid
from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from .models import TERMINAL_STATES, Job, utcnow

__all__ = [
    "canonical_json",
    "sha256_json",
    "params_key",
    "problem",
    "Aggregate",
    "aggregate_children",
    "refresh_parent",
    "finish",
]


def canonical_json(data: Any) -> bytes:
    return json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode()


def sha256_json(data: Any) -> str:
    return hashlib.sha256(canonical_json(data)).hexdigest()


def params_key(params: dict[str, Any], derived_from: int | None) -> str:
    """Identity of a grasp set's inputs next to its object and gripper versions: equal keys, equal grasp sets."""
    return sha256_json({"params": params, "derived_from": derived_from})


def problem(code: str, title: str, detail: str, *, status: int = 422, **extra: Any) -> dict[str, Any]:
    """RFC 9457 fields: a job's `error`, and the body of every problem response of the API (api/problems.py)."""
    return {
        "type": f"urn:graspgen:problem:{code}",
        "title": title,
        "status": status,
        "detail": detail,
        "code": code,
        **extra,
    }


def finish(job: Job, state: str, error: dict[str, Any] | None = None) -> None:
    job.state = state
    job.error = error
    job.finished_at = utcnow()
    if state == "succeeded":
        job.progress = 1.0
        job.stage = "done"
    _count_finished(job)


def _count_finished(job: Job) -> None:
    """graspgen_jobs_finished_total and graspgen_job_duration_seconds, in the process that writes the final state."""
    from .metrics import JOB_DURATION, JOBS_FINISHED

    JOBS_FINISHED.labels(job.kind, job.state).inc()
    created, finished = job.created_at, job.finished_at
    if created is not None and finished is not None:
        if created.tzinfo is None:  # SQLite hands back naive UTC
            created = created.replace(tzinfo=finished.tzinfo)
        JOB_DURATION.labels(job.kind, job.state).observe(max(0.0, (finished - created).total_seconds()))


@dataclass(frozen=True)
class Aggregate:
    counts: dict[str, int]
    total: int
    progress: float

    @property
    def done(self) -> int:
        return sum(self.counts.get(s, 0) for s in TERMINAL_STATES)

    def state(self, *, cancel_requested: bool) -> str:
        """succeeded only when every item succeeded; cancelled when the parent was cancelled or items were cancelled
        and none failed; failed when any item failed."""
        if self.total and self.done == self.total:
            if self.counts.get("succeeded", 0) == self.total:
                return "succeeded"
            if cancel_requested or not self.counts.get("failed", 0):
                return "cancelled"
            return "failed"
        if self.counts.get("queued", 0) == self.total:
            return "queued"
        return "running"

    def error(self) -> dict[str, Any] | None:
        """The parent's problem once it ended other than succeeded: how many items failed (or were cancelled)."""
        failed, cancelled = self.counts.get("failed", 0), self.counts.get("cancelled", 0)
        if not self.total or self.done < self.total or not (failed or cancelled):
            return None
        parts = [f"{n} of {self.total} items {what}" for n, what in ((failed, "failed"), (cancelled, "cancelled")) if n]
        code, title = ("items-failed", "Some items failed") if failed else ("items-cancelled", "Items were cancelled")
        counts = {s: self.counts.get(s, 0) for s in ("succeeded", "failed", "cancelled")}
        return problem(code, title, "; ".join(parts), counts={**counts, "total": self.total})


def aggregate_children(session: Session, parent_id: uuid.UUID) -> Aggregate:
    rows = session.execute(
        select(Job.state, func.count(), func.sum(Job.progress)).where(Job.parent_id == parent_id).group_by(Job.state)
    ).all()
    counts = {state: n for state, n, _ in rows}
    total = sum(counts.values())
    # a finished child counts as complete whatever its own progress said
    progress_sum = sum(float(n) if state in TERMINAL_STATES else float(p or 0.0) for state, n, p in rows)
    return Aggregate(counts, total, progress_sum / total if total else 1.0)


def refresh_parent(session: Session, parent_id: uuid.UUID) -> None:
    """Store the aggregate on the parent row (lists and filters read it); the child's transaction calls this."""
    parent = session.execute(select(Job).where(Job.id == parent_id).with_for_update()).scalar_one_or_none()
    if parent is None:
        return
    agg = aggregate_children(session, parent_id)
    state = agg.state(cancel_requested=parent.cancel_requested)
    parent.progress = agg.progress
    parent.stage = f"{agg.done}/{agg.total} items done"
    if state in TERMINAL_STATES and parent.state not in TERMINAL_STATES:
        parent.state = state
        parent.error = agg.error()
        parent.finished_at = utcnow()
    elif state not in TERMINAL_STATES:
        if parent.state == "queued" and state == "running":
            parent.started_at = parent.started_at or utcnow()
        parent.state = state
