"""The app of the `celery` command (`celery -A services.worker.celery_main inspect ping`, the compose health check; or
`celery -A services.worker.celery_main worker`): built from the environment when imported, with the reconciler's
signals connected as `graspgen worker` does. Nothing in the package imports this module."""

from __future__ import annotations

from services.common.settings import get_settings
from services.worker.celery_app import make_celery
from services.worker.reconcile import connect_worker_signals

app = make_celery(get_settings())
connect_worker_signals(app.conf.graspgen_settings)
