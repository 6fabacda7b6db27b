"""The Celery app: Redis broker, one job per worker process at a time, late acknowledgement.

A job's message is acknowledged only after the task returns, so a worker that dies mid-job has the job delivered again
(the task is idempotent by job id). The broker's visibility timeout lies above the hard time limit, so a job that is
still running legitimately is never handed to a second worker. Results live in the database, not in a result backend.
"""

from __future__ import annotations

from celery import Celery

from services.common.settings import Settings, get_settings

__all__ = ["make_celery", "celery_app"]


def make_celery(settings: Settings) -> Celery:
    broker = settings.broker_url.get_secret_value() if settings.broker_url else "memory://"
    app = Celery("graspgen", broker=broker, set_as_current=False)
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
    return app


celery_app = make_celery(get_settings())

# registers the tasks on celery_app (`celery -A services.worker.celery_app worker` imports only this module), and the
# reconciler's worker signals (start-up and periodic passes in the main process, a temp directory per prefork child)
from services.worker import reconcile as _reconcile  # noqa: E402,F401
from services.worker import tasks as _tasks  # noqa: E402,F401
