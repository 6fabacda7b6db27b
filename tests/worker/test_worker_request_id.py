"""Issue 16 (1): the task puts the submitting request's id and the job id on every log line of the run, from the
message header, or from the job row when the message came without one (the reconciler sends jobs again)."""

from __future__ import annotations

import logging

import pytest
from services_conftest import slug

from services.common.logs import ContextFilter

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # runs the core


class _Records(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.addFilter(ContextFilter())
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.mark.parametrize("header", [True, False], ids=["message-header", "job-row"])
def test_every_line_of_the_run_carries_the_request_id(pg_service, header):
    from services.common.logs import REQUEST_ID_MESSAGE_HEADER
    from services.worker.celery_app import job_task, make_celery
    from services.worker.runner import JobRunner

    obj, grip = slug("rid"), slug("grip")
    assert pg_service.upload(obj).status_code == 201
    assert pg_service.gripper(grip).status_code == 201
    rid = slug("req")
    r = pg_service.post(
        "/v1/jobs",
        json={"object": obj, "gripper": grip, "params": {"points": 600, "k1": 4, "k2": 2}},
        headers={"X-Request-ID": rid},
    )
    jid = r.json()["id"]
    state = pg_service.app.state
    handler = _Records()
    root = logging.getLogger()
    old_level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    app = make_celery(pg_service.settings, runner=JobRunner(state.db, state.storage, pg_service.settings))
    try:
        headers = {REQUEST_ID_MESSAGE_HEADER: rid} if header else None
        result = job_task(app).apply(args=(jid,), task_id=jid, headers=headers)
        assert result.get() == "succeeded"
    finally:
        app.close()
        root.removeHandler(handler)
        root.setLevel(old_level)
    mine = [rec for rec in handler.records if rec.job_id == jid]
    assert {rec.getMessage() for rec in mine} >= {f"job {jid}: run (delivery 1)", f"job {jid}: succeeded"}
    assert all(rec.request_id == rid for rec in mine)
