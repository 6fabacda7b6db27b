"""The Celery app: Redis broker, one job per worker process at a time, late acknowledgement.

A job's message is acknowledged only after the task returns, so a worker that dies mid-job has the job delivered again
(the task is idempotent by job id). The broker's visibility timeout lies above the hard time limit, so a job that is
still running legitimately is never handed to a second worker. Results live in the database, not in a result backend.

Importing this module builds nothing: `make_celery(settings)` builds an app whose worker imports the task module
(`include`); the task is a `shared_task`, so every app has it. `graspgen worker` (services/cli.py) builds the app and
connects the reconciler's signals; `celery -A services.worker.celery_main` is the same for the celery command. The
embedded mode passes its runner to `make_celery(settings, runner=...)` (services/worker/dispatch.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from celery import Celery, Task

from services.common.settings import Settings

if TYPE_CHECKING:
    from services.worker.runner import JobRunner

__all__ = ["make_celery", "job_task", "RUN_JOB", "TASK_MODULES"]

#: the one task's name (services/worker/tasks.py)
RUN_JOB = "graspgen.run_job"
#: the modules a worker of the app imports at start-up (they register the tasks)
TASK_MODULES = ("services.worker.tasks",)


def make_celery(settings: Settings, runner: JobRunner | None = None) -> Celery:
    """The Celery app for `settings`. `runner`: the job runner every task of this app uses (the embedded mode's,
    sharing the API's engine and storage); without one, each worker process builds its own on its first job."""
    broker = settings.broker_url.get_secret_value() if settings.broker_url else "memory://"
    app = Celery("graspgen", broker=broker, set_as_current=False, include=list(TASK_MODULES))
    transport_options: dict[str, object] = {
        "visibility_timeout": settings.broker_visibility_timeout_s,
        # look for messages of dead workers (unacknowledged for longer than the visibility timeout) every tenth of the
        # timeout, at most every 10 s: kombu's default scans only about every 100 s
        "unacked_restore_interval": max(1, min(10, settings.broker_visibility_timeout_s // 10)),
        "unacked_restore_throttle": 1,
    }
    if settings.broker_key_prefix:
        transport_options["global_keyprefix"] = settings.broker_key_prefix
    app.conf.update(
        task_default_queue=settings.queue,
        task_serializer="json",
        accept_content=["json"],
        task_ignore_result=True,
        result_backend=None,
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_soft_time_limit=settings.job_soft_time_limit_s,
        task_time_limit=settings.job_time_limit_s,
        worker_max_tasks_per_child=settings.worker_max_tasks_per_child,
        worker_concurrency=settings.worker_concurrency,
        broker_transport_options=transport_options,
        broker_connection_retry_on_startup=True,
        worker_hijack_root_logger=False,
        worker_send_task_events=False,
        task_send_sent_event=False,
        enable_utc=True,
    )
    app.conf.graspgen_settings = settings
    app.conf.graspgen_runner = runner
    return app


def job_task(app: Celery) -> Task:
    """The run-job task of `app` (imports the task modules, as a worker does at start-up)."""
    app.loader.import_default_modules()
    return app.tasks[RUN_JOB]
