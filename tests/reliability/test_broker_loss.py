"""The broker loses messages while jobs are queued (a redis-server of the test's own, without persistence: FLUSHALL,
or killed and started again), and the reconciler (services/worker/reconcile.py) puts the jobs back. Sending again is
safe: a duplicate message for a queued or running job runs nothing twice.
"""

from __future__ import annotations

import time
from datetime import timedelta

import pytest
from services_conftest import box_stl, cylinder_stl
from worker_stack import SMALL, stack_fixture, stopping_workers

from services.common.models import utcnow
from services.worker.reconcile import Reconciler

# one xdist worker per module: its stack (redis-server, schema, workers) is set up once
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.xdist_group("reliability-broker-loss")]

LIMITS = dict(job_soft_time_limit_s=10, job_time_limit_s=12, broker_visibility_timeout_s=14)
GRACE = 1  # reconcile_grace_s of the stack


stack = stack_fixture("broker-loss", **LIMITS)
_stop_workers = stopping_workers()


def wait_log(worker, needle: str, count: int = 1, timeout: float = 60.0) -> str:
    end = time.monotonic() + timeout
    while (text := worker.text()).count(needle) < count:
        assert worker.proc.poll() is None, text[-3000:]
        assert time.monotonic() < end, f"{needle!r} not {count}x in the worker log:\n{text[-3000:]}"
        time.sleep(0.1)
    return text


@pytest.mark.parametrize("fault", ["flushall", "restart"])
def test_jobs_queued_when_the_broker_lost_them_run_once(stack, fault):
    obj, grip = stack.pair(cylinder_stl())
    jids = [stack.submit(obj, grip, {**SMALL, "seed": seed}) for seed in (1, 2, 3)]
    r = stack.redis.client()
    assert r.llen("graspgen") == 3  # no worker runs: the messages wait in the queue
    if fault == "flushall":
        r.flushall()
    else:
        stack.redis.restart()  # no persistence: everything is gone
        r = stack.redis.client()
    assert r.llen("graspgen") == 0
    assert {stack.svc.get(f"/v1/jobs/{j}").json()["state"] for j in jids} == {"queued"}

    worker = stack.start_worker()  # its reconciler's first pass finds the three, older than the grace period
    for jid in jids:
        job = stack.svc.wait_job(jid, timeout=120)
        assert job["state"] == "succeeded" and job["attempts"] == 1, job
    assert sorted(j for _, j in stack.grasp_sets(obj)) == sorted(jids)
    assert [v for v, _ in stack.grasp_sets(obj)] == [1, 2, 3]
    text = worker.text()
    assert all(text.count(f"graspgen.run_job[{j}] received") == 1 for j in jids), text[-3000:]
    assert "reconcile: sent" in text and "duplicate message dropped" not in text
    stack.wait_no_leftovers()


def test_a_pass_sends_only_lost_jobs_and_leaves_live_running_ones(stack):
    """No worker: the reconciler in this process, against the stack's database and redis-server."""
    obj, grip = stack.pair(box_stl())
    jid = stack.submit(obj, grip, {**SMALL, "seed": 4})
    time.sleep(GRACE + 0.2)
    r = stack.redis.client()
    rec = Reconciler(stack.svc.settings)
    try:
        p = rec.run_once()
        assert jid in p.queued and jid not in p.sent and r.llen("graspgen") == 1  # its message is still there

        r.flushall()
        p = rec.run_once()
        assert jid in p.sent and r.llen("graspgen") == 1
        assert rec.run_once().sent == []  # sent once: the next pass sees the new message

        # claimed by a worker that still runs it (row fresh): the reconciler leaves it to that worker
        r.flushall()
        stack.set_job(jid, state="running", attempts=1, stage="pairs")
        p = rec.run_once()
        assert jid not in p.abandoned and p.sent == [] and r.llen("graspgen") == 0

        # the row has not changed for longer than the hard limit plus the grace: its worker is gone
        stale = utcnow() - timedelta(seconds=LIMITS["job_time_limit_s"] + GRACE + 5)
        stack.set_job(jid, updated_at=stale)
        p = rec.run_once()
        assert jid in p.abandoned and p.sent == [jid] and r.llen("graspgen") == 1
    finally:
        rec.close()

    # a fresh message for an abandoned running job takes it over: a second attempt, one version
    stack.start_worker()
    job = stack.svc.wait_job(jid, timeout=120)
    assert job["state"] == "succeeded" and job["attempts"] == 2, job
    assert stack.grasp_sets(obj) == [(1, jid)]


def test_a_duplicate_of_a_queued_job_runs_it_once(stack):
    """The message was not lost and the reconciler sends another anyway (the race it cannot exclude): two
    messages, two worker processes taking them at the same moment, one run."""
    obj, grip = stack.pair(cylinder_stl(radius_mm=10.0))
    jid = stack.submit(obj, grip, {**SMALL, "seed": 5})
    rec = Reconciler(stack.svc.settings)
    try:
        rec.resend([jid])
    finally:
        rec.close()
    assert stack.redis.client().llen("graspgen") == 2

    worker = stack.start_worker(concurrency=2)
    job = stack.svc.wait_job(jid, timeout=120)
    assert job["state"] == "succeeded" and job["attempts"] == 1, job
    text = wait_log(worker, f"graspgen.run_job[{jid}] succeeded in", count=2)  # both messages were consumed
    assert text.count(f"graspgen.run_job[{jid}] received") == 2
    assert stack.grasp_sets(obj) == [(1, jid)]
    assert stack.svc.get(f"/v1/jobs/{jid}").json()["attempts"] == 1


def test_a_duplicate_of_a_running_job_does_not_run_it_again(stack):
    """A second message while a worker process runs the job: the other process drops it (no takeover: not a
    redelivery, and the row is fresh); attempts stay 1."""
    worker = stack.start_worker(concurrency=2)
    obj, grip = stack.pair(cylinder_stl(radius_mm=14.0))
    jid = stack.submit(obj, grip, {"points": 3000, "k1": 4, "k2": 2, "seed": 6})
    stack.wait_state(jid, ("running",))
    rec = Reconciler(stack.svc.settings)
    try:
        rec.resend([jid])
    finally:
        rec.close()
    wait_log(worker, f"job {jid} is running elsewhere; duplicate message dropped")
    job = stack.svc.wait_job(jid, timeout=120)
    assert job["state"] == "succeeded" and job["attempts"] == 1, job
    assert stack.grasp_sets(obj) == [(1, jid)]
    stack.wait_no_leftovers()
