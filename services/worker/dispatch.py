"""How the API hands jobs to workers: through the Celery broker, or (embedded mode) to an in-process thread pool
that runs the very same Celery task (`run_job.apply`), so both modes share one code path for running a job.

Both are called only after the job rows are committed, so a worker never receives a job it cannot read.
"""

from __future__ import annotations

import logging
import threading
from abc import ABC, abstractmethod
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor

from sqlalchemy import select

from services.common.db import Database
from services.common.models import Job
from services.common.settings import Settings
from services.jobkinds import CONTAINER_KINDS

__all__ = ["Dispatcher", "CeleryDispatcher", "EmbeddedDispatcher", "make_dispatcher", "DispatchError"]

log = logging.getLogger(__name__)


class DispatchError(Exception):
    """The broker could not take the job."""


class Dispatcher(ABC):
    @abstractmethod
    def send(self, job_ids: Sequence[str]) -> None:
        """Queue jobs; more than one goes out as one Celery group (a bulk job's items)."""

    @abstractmethod
    def revoke(self, job_ids: Sequence[str]) -> None:
        """Drop queued messages for these jobs where possible (the database flag stops running ones)."""

    @abstractmethod
    def ping(self) -> None:
        """Raise when jobs cannot be queued."""

    def close(self) -> None:  # noqa: B027 - optional hook
        pass


class CeleryDispatcher(Dispatcher):
    def __init__(self, settings: Settings) -> None:
        from services.worker.celery_app import RUN_JOB, make_celery

        self.settings = settings
        self.app = make_celery(settings)
        self.queue = settings.queue
        self.task_name = RUN_JOB

    def send(self, job_ids: Sequence[str]) -> None:
        from celery import group

        headers = _request_headers()
        try:
            sig = [
                self.app.signature(self.task_name, args=(jid,), immutable=True).set(
                    task_id=jid,
                    queue=self.queue,
                    headers=headers,  # type: ignore[arg-type]  # None is Celery's own default; celery-types says dict
                )
                for jid in job_ids
            ]
            if len(sig) == 1:
                sig[0].apply_async()
            elif sig:
                group(sig).apply_async()
        except Exception as exc:  # kombu raises several kinds for an unreachable broker
            raise DispatchError(f"broker unavailable: {type(exc).__name__}") from exc

    def revoke(self, job_ids: Sequence[str]) -> None:
        try:
            self.app.control.revoke(list(job_ids))
        except Exception:
            log.warning("revoke of %d job(s) failed; the cancel flag still stops them", len(job_ids))

    def ping(self) -> None:
        with self.app.connection_for_write() as conn:
            conn.ensure_connection(max_retries=1, timeout=2)

    def close(self) -> None:
        self.app.close()


class EmbeddedDispatcher(Dispatcher):
    """A thread pool inside the API process running `run_job.apply` (the Celery task, executed locally)."""

    def __init__(self, settings: Settings, db: Database, storage) -> None:
        from services.worker.celery_app import job_task, make_celery
        from services.worker.runner import JobRunner

        # an app of this dispatcher's own, whose tasks run with the API process's runner (its engine and storage)
        self.app = make_celery(settings, runner=JobRunner(db, storage, settings))
        self._task = job_task(self.app)
        self._pool = ThreadPoolExecutor(max_workers=settings.embedded_workers, thread_name_prefix="graspgen-job")
        self._futures: dict[str, Future] = {}
        self._lock = threading.Lock()
        self.db = db

    def send(self, job_ids: Sequence[str]) -> None:
        headers = _request_headers()
        for jid in job_ids:
            fut = self._pool.submit(self._run, jid, headers)
            with self._lock:
                self._futures[jid] = fut

    def _run(self, jid: str, headers: dict[str, str] | None = None) -> None:
        try:
            result = self._task.apply(args=(jid,), task_id=jid, headers=headers)
            if result.failed():
                log.error("job %s: task raised %r", jid, result.result)
        finally:
            with self._lock:
                self._futures.pop(jid, None)

    def pending(self) -> int:
        """Jobs waiting for a thread of the pool (the embedded mode's queue depth)."""
        return self._pool._work_queue.qsize()  # noqa: SLF001 - no public count

    def revoke(self, job_ids: Sequence[str]) -> None:
        with self._lock:
            for jid in job_ids:
                fut = self._futures.get(jid)
                if fut is not None:
                    fut.cancel()

    def ping(self) -> None:
        if self._pool._shutdown:  # noqa: SLF001 - no public flag
            raise RuntimeError("the in-process worker is shut down")

    def recover(self) -> int:
        """Queue again the jobs a previous process left queued or running (the in-memory queue died with it)."""
        with self.db.session() as s:
            ids = [
                str(i)
                for i in s.execute(
                    select(Job.id)
                    .where(Job.state.in_(("queued", "running")), Job.kind.not_in(CONTAINER_KINDS))
                    .order_by(Job.created_at)
                ).scalars()
            ]
        self.send(ids)
        return len(ids)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
        self.app.close()


def _request_headers() -> dict[str, str] | None:
    """The message headers that carry the current request's id to the job's worker (its log lines show it)."""
    from services.common.logs import REQUEST_ID_MESSAGE_HEADER, request_id_var

    rid = request_id_var.get()
    return {REQUEST_ID_MESSAGE_HEADER: rid} if rid else None


def make_dispatcher(settings: Settings, db: Database, storage) -> Dispatcher:
    if settings.embedded_worker:
        return EmbeddedDispatcher(settings, db, storage)
    return CeleryDispatcher(settings)
