"""services/common/logs.py: request-id validation, the context filter, the text and JSON line formats."""

from __future__ import annotations

import io
import json
import logging
import uuid

import pytest

from services.common.logs import (
    ContextFilter,
    JsonFormatter,
    configure_logging,
    log_context,
    new_request_id,
    valid_request_id,
)


@pytest.mark.parametrize("value", ["a", "plant-7.req_0001", "x" * 64, "~!#$%&'*+-.^_`|", "A1:2/3"])
def test_valid_request_ids_are_kept(value):
    assert valid_request_id(value) == value


@pytest.mark.parametrize("value", [None, "", "x" * 65, "has space", "tab\t", "new\nline", "é", "\x00", "\x7f"])
def test_invalid_request_ids_are_refused(value):
    assert valid_request_id(value) is None


def test_new_request_ids_are_uuid4_hex():
    ids = {new_request_id() for _ in range(1000)}
    assert len(ids) == 1000
    for rid in ids:
        u = uuid.UUID(hex=rid)
        assert len(rid) == 32 and u.version == 4 and u.variant == uuid.RFC_4122


def _logger(fmt: str) -> tuple[logging.Logger, io.StringIO]:
    out = io.StringIO()
    handler = logging.StreamHandler(out)
    handler.addFilter(ContextFilter())
    handler.setFormatter(
        JsonFormatter() if fmt == "json" else logging.Formatter("%(request_id)s %(job_id)s %(message)s")
    )
    log = logging.getLogger(f"test-logs-{fmt}-{uuid.uuid4().hex}")
    log.propagate = False
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    return log, out


def test_context_ids_reach_every_line_and_are_restored():
    log, out = _logger("text")
    log.info("outside")
    with log_context(request_id="r1"):
        log.info("request")
        with log_context(job_id="j1"):
            log.info("job")
        log.info("request again")
    log.info("outside again")
    assert out.getvalue().splitlines() == [
        "- - outside",
        "r1 - request",
        "r1 j1 job",
        "r1 - request again",
        "- - outside again",
    ]


def test_json_lines_are_one_object_each_with_the_traceback_inside():
    log, out = _logger("json")
    with log_context(request_id="r2", job_id="j2"):
        try:
            raise ValueError("bad\nthing")
        except ValueError:
            log.exception("failed with %s", "x\ny")
    log.info("plain")
    lines = out.getvalue().splitlines()
    assert len(lines) == 2  # newlines in messages and tracebacks stay inside the JSON strings
    first, second = (json.loads(line) for line in lines)
    assert first["message"] == "failed with x\ny" and first["level"] == "ERROR"
    assert first["request_id"] == "r2" and first["job_id"] == "j2"
    assert "ValueError: bad\nthing" in first["exc_info"] and first["time"].endswith("+00:00")
    assert second["request_id"] is None and second["job_id"] is None and "exc_info" not in second


def test_configure_logging_replaces_the_root_handlers():
    root = logging.getLogger()
    saved, level = list(root.handlers), root.level
    try:
        configure_logging("warning", "json")
        assert len(root.handlers) == 1 and isinstance(root.handlers[0].formatter, JsonFormatter)
        assert root.level == logging.WARNING
    finally:
        for h in list(root.handlers):
            root.removeHandler(h)
        for h in saved:
            root.addHandler(h)
        root.setLevel(level)
