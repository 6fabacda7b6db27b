"""A worker killed with SIGKILL in the middle of a job, on a stack of its own (tests/reliability/worker_stack.py).

The prefork child: Celery rejects the message (`task_reject_on_worker_lost`), it comes back at once and a new child
runs the job again. The whole worker (main process and child, its process group): the message stays unacknowledged
in Redis and comes back after the broker's visibility timeout, to a worker started afterwards. Either way the job
finishes once, with one grasp-set version, and nothing is left in storage or the temp directory that no row refers to.
"""

from __future__ import annotations

import pytest
from services_conftest import box_stl, cylinder_stl
from worker_stack import SMALL, stack_fixture, stopping_workers

# one xdist worker per module: its stack (redis-server, schema, workers) is set up once
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.xdist_group("reliability-worker-kill")]

# the visibility timeout is the shortest the settings allow (above the hard limit); the reconciler's grace is long, so
# that what brings the job back here is the broker, not the reconciler's rule for abandoned running jobs
LIMITS = dict(job_soft_time_limit_s=10, job_time_limit_s=12, broker_visibility_timeout_s=14, reconcile_grace_s=60)


stack = stack_fixture("worker-kill", **LIMITS)
_stop_workers = stopping_workers()


def test_killed_prefork_child_redelivers_once_without_leftovers(stack):
    worker = stack.start_worker()
    obj, grip = stack.pair(cylinder_stl())
    jid = stack.submit(obj, grip, {**SMALL, "seed": 17})
    stack.wait_state(jid, ("running",))
    dead = worker.kill_child()  # mid-job: the message is rejected and delivered again, to a new child

    job = stack.svc.wait_job(jid, timeout=120)
    assert job["state"] == "succeeded" and job["attempts"] == 2, job
    assert stack.grasp_sets(obj) == [(1, jid)]
    assert worker.proc.poll() is None and dead not in [c.pid for c in worker.children()]
    # the redelivery is a takeover, not a duplicate; the dead child's temp directory goes at the next pass
    assert "duplicate message dropped" not in worker.text()
    stack.wait_no_leftovers()


def test_killed_worker_group_redelivers_after_the_visibility_timeout(stack):
    first = stack.start_worker(own_group=True)
    obj, grip = stack.pair(box_stl())
    jid = stack.submit(obj, grip, {**SMALL, "seed": 18})
    stack.wait_state(jid, ("running",))
    first.kill_group()  # main process and child at once: nobody rejects the message

    r = stack.redis.client()
    assert r.hlen("unacked") == 1 and r.llen("graspgen") == 0  # held for the dead worker until the timeout
    assert stack.svc.get(f"/v1/jobs/{jid}").json()["state"] == "running"

    second = stack.start_worker()
    job = stack.svc.wait_job(jid, timeout=120)
    assert job["state"] == "succeeded" and job["attempts"] == 2, job
    assert stack.grasp_sets(obj) == [(1, jid)]
    assert r.hlen("unacked") == 0 and r.llen("graspgen") == 0
    text = second.text()
    assert "reconcile: sent" not in text and "duplicate message dropped" not in text
    stack.wait_no_leftovers()
