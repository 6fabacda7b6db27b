"""The one task: run a job by id. The same function runs under `graspgen worker` and in the embedded thread pool."""

from __future__ import annotations

import logging
import os
import threading

from celery import Celery, Task, shared_task
from celery.exceptions import TimeLimitExceeded
from sqlalchemy.exc import OperationalError

from services.common.logs import REQUEST_ID_MESSAGE_HEADER, log_context, valid_request_id
from services.worker.celery_app import RUN_JOB
from services.worker.runner import JobRunner

__all__ = ["run_job", "get_runner"]

log = logging.getLogger(__name__)

_runner_lock = threading.Lock()


def get_runner(app: Celery) -> JobRunner:
    """The runner of `app`'s tasks: the one passed to make_celery (embedded mode), else this process's own.

    A worker process's own runner is built lazily, so that a prefork child opens its own database connections after
    the fork; and built again in a child forked after the main process made one (on_failure runs there after a hard
    time limit): the inherited engine's pooled connections are the parent's sockets.
    """
    given: JobRunner | None = app.conf.get("graspgen_runner")
    if given is not None:
        return given
    with _runner_lock:
        pid, runner = app.conf.get("graspgen_process_runner") or (None, None)
        if runner is not None and pid != os.getpid():
            runner.db.engine.dispose(close=False)  # forget the parent's connections without touching them
            runner = None
        if runner is None:
            runner = JobRunner.from_settings(app.conf.graspgen_settings)
            app.conf.graspgen_process_runner = (os.getpid(), runner)
        return runner


class JobTask(Task):
    def on_failure(self, exc, task_id, args, kwargs, einfo):
        # a hard time limit kills the child process; this hook then runs in the worker's main process
        if isinstance(exc, TimeLimitExceeded) and args:
            try:
                get_runner(self.app).fail_time_limit(str(args[0]))
            except Exception:  # the database may be what is failing; the job then stays for the next delivery
                log.exception("could not mark job %s failed after the hard time limit", args[0])


@shared_task(
    name=RUN_JOB,
    base=JobTask,
    bind=True,
    # the database was unreachable: the job row could not even be claimed or finished, so try again later
    autoretry_for=(OperationalError,),
    retry_backoff=2,
    retry_backoff_max=60,
    max_retries=5,
)
def run_job(self: Task, job_id: str) -> str:
    """Run job `job_id` and return its final state. Redelivery of a finished job does nothing.

    A `running` job is taken over only from a message whose previous holder is gone: one the broker delivers again
    (its worker died), a retry of this task, or the in-process pool (which re-queues a dead process's jobs); any other
    message for it is a duplicate (the reconciler may send one) and does nothing, see services/worker/reconcile.py.
    """
    req = self.request
    redelivered = bool(req.is_eager or req.retries or (req.delivery_info or {}).get("redelivered"))
    # the submitting request's id travels as a message header (services/worker/dispatch.py): every log line of the
    # run carries it and the job id
    request_id = getattr(req, REQUEST_ID_MESSAGE_HEADER, None) or (req.headers or {}).get(REQUEST_ID_MESSAGE_HEADER)
    if request_id is None:  # a message the reconciler sent again, or one sent before request ids existed
        request_id = _stored_request_id(self.app, job_id)
    with log_context(request_id=valid_request_id(request_id), job_id=str(job_id)):
        log.info("job %s: run (delivery %d)", job_id, req.retries + 1)
        state = get_runner(self.app).run(job_id, redelivered=redelivered)
        log.info("job %s: %s", job_id, state)
        return state


def _stored_request_id(app: Celery, job_id: str) -> str | None:
    """The request id kept on the job's row (one small read; only for messages that came without one)."""
    import uuid

    from sqlalchemy import select

    from services.common.models import Job

    try:
        with get_runner(app).db.read_sessions() as s:
            return s.execute(select(Job.request_id).where(Job.id == uuid.UUID(str(job_id)))).scalar_one_or_none()
    except Exception:  # the run itself reports a bad id or an unreachable database
        return None
