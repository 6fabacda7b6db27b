"""Issue 16 (1) with real processes: `graspgen serve` on PostgreSQL and Redis and a real `graspgen worker`, both
logging JSON lines. A job submitted with an X-Request-ID keeps that id on its row, in the API's log lines of the
request and in every worker log line written while the job runs; the worker's own /metrics (GRASPGEN_METRICS_PORT,
prometheus-client multiprocess mode over the prefork children) counts the job and its stages; the API's /metrics
shows the queue depth."""

from __future__ import annotations

import json
import time
import uuid
from pathlib import Path

import httpx
import pytest
from services_conftest import (
    GRASPGEN,
    GRIPPER,
    PG_URL,
    cylinder_stl,
    free_port,
    pg_values,
    settings_env,
    slug,
    start_serve,
    start_worker,
    stop_process,
    wait_for_log,
    write_tokens_file,
)

pytestmark = [pytest.mark.integration, pytest.mark.slow]

RID = "trace-" + uuid.uuid4().hex[:12]


def _json_lines(path: Path) -> list[dict]:
    lines = [line for line in path.read_text(errors="replace").splitlines() if line.strip()]
    out = []
    for line in lines:
        if line.startswith("{"):
            out.append(json.loads(line))  # a line that starts as JSON must be one whole JSON object
    return out


def _sample(text: str, prefix: str) -> float:
    for line in text.splitlines():
        if line.startswith(prefix):
            return float(line.rsplit(" ", 1)[1])
    return 0.0


@pytest.fixture()
def stack(pg_schema, tmp_path):
    metrics_port = free_port()
    worker_log = tmp_path / "worker.log"
    with pg_values(tmp_path, pg_schema, log_format="json", progress_interval_s=0.1) as (values, tokens):
        worker = start_worker(
            settings_env(**values, metrics_port=metrics_port, metrics_dir=tmp_path / "metrics"),
            worker_log,
            command=[GRASPGEN],
            wait=False,
        )
        api = None
        try:
            api, url = start_serve(settings_env(**values), tmp_path / "api.log")
            wait_for_log(worker_log, " ready.", worker)
            yield url, f"http://127.0.0.1:{metrics_port}/metrics", tokens, tmp_path / "api.log", worker_log
        finally:
            if api is not None:
                stop_process(api)
            stop_process(worker)


def test_request_id_follows_the_job_into_the_worker_and_metrics_count_it(stack, pg_schema):
    url, worker_metrics, tokens, api_log, worker_log = stack
    w = {"Authorization": f"Bearer {tokens['writer']}"}
    obj, grip = slug("trace"), slug("grip")
    with httpx.Client(base_url=url, timeout=60) as c:
        up = c.post(
            "/v1/objects", headers=w, files={"file": ("p.stl", cylinder_stl())}, data={"name": obj, "units": "mm"}
        )
        assert up.status_code == 201, up.text
        assert c.post("/v1/grippers", headers=w, json={**GRIPPER, "name": grip}).status_code == 201
        r = c.post(
            "/v1/jobs",
            headers={**w, "X-Request-ID": RID},
            json={"object": obj, "gripper": grip, "params": {"points": 600, "k1": 4, "k2": 2}},
        )
        assert r.status_code == 202 and r.headers["x-request-id"] == RID
        job_id = r.json()["id"]
        end = time.monotonic() + 180
        while (state := c.get(f"/v1/jobs/{job_id}", headers=w).json()["state"]) not in ("succeeded", "failed"):
            assert time.monotonic() < end, state
            time.sleep(0.2)
        assert state == "succeeded"
        api_metrics = c.get("/metrics", headers={"Authorization": f"Bearer {tokens['admin']}"}).text
    assert "graspgen_queue_depth " in api_metrics
    assert _sample(api_metrics, 'graspgen_http_request_duration_seconds_count{method="POST",route="/v1/jobs"') >= 1

    # the job row keeps the id of the request that made it
    from services.common.db import Database
    from services.common.models import Job
    from services.common.settings import Settings

    db = Database(Settings(database_url=PG_URL, database_schema=pg_schema))
    try:
        with db.session() as s:
            assert s.get(Job, uuid.UUID(job_id)).request_id == RID
    finally:
        db.dispose()

    # the API's lines of that request carry it (uvicorn's access line among them), and all lines are JSON
    api_lines = _json_lines(api_log)
    assert api_lines and all({"time", "level", "logger", "message"} <= set(d) for d in api_lines)
    mine = [d for d in api_lines if d["request_id"] == RID]
    assert any("POST /v1/jobs" in d["message"] for d in mine), mine

    # every worker line written while the job ran carries the request id and the job id
    time.sleep(0.5)  # the last line is flushed
    job_lines = [d for d in _json_lines(worker_log) if d.get("job_id") == job_id]
    assert len(job_lines) >= 2, _json_lines(worker_log)[-20:]
    assert all(d["request_id"] == RID for d in job_lines)
    assert any(d["message"] == f"job {job_id}: succeeded" for d in job_lines)

    # the worker's own metrics, summed over its prefork children
    text = httpx.get(worker_metrics, timeout=10).text
    assert _sample(text, 'graspgen_jobs_finished_total{kind="generate",state="succeeded"}') >= 1
    assert _sample(text, 'graspgen_job_stage_duration_seconds_count{kind="generate",stage="collision"}') >= 1
    assert _sample(text, 'graspgen_job_duration_seconds_count{kind="generate",state="succeeded"}') >= 1
    assert "graspgen_queue_depth " in text


def test_embedded_jobs_carry_the_request_id_into_their_log_lines(tmp_path):
    """The embedded pool runs the same task in the API process; the id travels with it the same way."""
    tokens = write_tokens_file(tmp_path / "tokens.json")
    log = tmp_path / "serve.log"
    env = settings_env(storage_dir=tmp_path / "var", tokens_file=tmp_path / "tokens.json", log_format="json")
    proc, url = start_serve(env, log)
    try:
        w = {"Authorization": f"Bearer {tokens['writer']}"}
        with httpx.Client(base_url=url, timeout=60) as c:
            up = c.post(
                "/v1/objects", headers=w, files={"file": ("p.stl", cylinder_stl())}, data={"name": "p", "units": "mm"}
            )
            assert up.status_code == 201
            assert c.post("/v1/grippers", headers=w, json=GRIPPER).status_code == 201
            rid = "embedded-" + uuid.uuid4().hex[:8]
            r = c.post(
                "/v1/jobs",
                headers={**w, "X-Request-ID": rid},
                json={"object": "p", "gripper": GRIPPER["name"], "params": {"points": 600, "k1": 4, "k2": 2}},
            )
            job_id = r.json()["id"]
            end = time.monotonic() + 180
            while c.get(f"/v1/jobs/{job_id}", headers=w).json()["state"] not in ("succeeded", "failed"):
                assert time.monotonic() < end
                time.sleep(0.2)
            # the embedded queue depth is the in-process pool's: nothing waits once the job is done
            text = c.get("/metrics", headers={"Authorization": f"Bearer {tokens['admin']}"}).text
            assert _sample(text, "graspgen_queue_depth ") == 0.0 and "graspgen_queue_depth 0.0" in text
            assert _sample(text, 'graspgen_jobs_finished_total{kind="generate",state="succeeded"}') == 1.0
        time.sleep(0.3)
        job_lines = [d for d in _json_lines(log) if d.get("job_id") == job_id]
        assert any(d["message"] == f"job {job_id}: succeeded" for d in job_lines), job_lines
        assert all(d["request_id"] == rid for d in job_lines)
        # lines of other requests (the polls) carry their own ids, not this one
        polls = [d for d in _json_lines(log) if f"GET /v1/jobs/{job_id}" in d["message"]]
        assert polls and all(d["request_id"] not in (None, rid) for d in polls)
    finally:
        stop_process(proc)


def test_serve_with_two_processes_reports_the_sum_of_both(pg_schema, tmp_path):
    """`serve --workers 2`: prometheus-client's multiprocess mode, so /metrics (from whichever process answers) and the
    metrics port count the requests of both processes."""
    metrics_port = free_port()
    log = tmp_path / "serve.log"
    with pg_values(
        tmp_path, pg_schema, metrics_port=metrics_port, metrics_dir=tmp_path / "metrics", log_format="json"
    ) as (values, tokens):
        proc, url = start_serve(settings_env(**values), log, "--workers", "2")
        try:
            answered: set[int] = set()
            end = time.monotonic() + 60
            n = 0
            while len(answered) < 2:  # until both processes have answered (each logs its own access lines)
                assert time.monotonic() < end, "one process answered everything"
                with httpx.Client(base_url=url, timeout=10) as c:  # a new connection: either process may take it
                    c.get("/healthz", headers={"X-Request-ID": f"probe-{n}"})
                    n += 1
                time.sleep(0.05)
                answered = {d["process"] for d in _json_lines(log) if (d["request_id"] or "").startswith("probe-")}
            prefix = 'graspgen_http_request_duration_seconds_count{method="GET",route="/healthz",status="200"}'
            text = httpx.get(f"http://127.0.0.1:{metrics_port}/metrics", timeout=10).text
            assert _sample(text, prefix) >= n  # (wait_http's own probes come on top)
            admin = {"Authorization": f"Bearer {tokens['admin']}"}
            assert _sample(httpx.get(url + "/metrics", headers=admin, timeout=10).text, prefix) >= n
            # both processes log their requests (each set up its own JSON logging), each line with its request id
            access = [d for d in _json_lines(log) if "GET /healthz" in d["message"]]
            assert all(d["request_id"] for d in access)
        finally:
            stop_process(proc)
