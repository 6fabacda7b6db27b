"""A job past its time limit, with a real worker subprocess: the job fails with `time-limit` and the same worker
(main process) serves the next job.

Celery's soft limit (a signal, handled at the next Python bytecode) and the runner's own deadline (checked in every
progress callback) stop a job that returns to the interpreter. A job stuck in native code past the hard limit is
killed with its prefork child; the task's `on_failure` (services/worker/tasks.py), run in the worker's main process,
then fails the job, and a new child, forked from a main process that has used the database meanwhile, runs the next
job on connections of its own.
"""

from __future__ import annotations

import pytest
from services_conftest import cylinder_stl
from stuck_kernel import STUCK_SEED
from worker_stack import SMALL, stack_fixture

# one xdist worker per module: its stack (redis-server, schema, workers) is set up once
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.xdist_group("reliability-time-limit")]

# a small job stays far below the soft limit even in a fresh child on a busy machine
LIMITS = dict(job_soft_time_limit_s=8, job_time_limit_s=10, broker_visibility_timeout_s=12)


stack = stack_fixture("time-limit", **LIMITS)


@pytest.fixture(scope="module")
def worker(stack):
    """One worker for the module, with the stuck-kernel shim preloaded (only seed STUCK_SEED is affected)."""
    return stack.start_worker(shim=True)


def test_a_job_stuck_past_the_hard_limit_fails_and_the_worker_goes_on(stack, worker):
    obj, grip = stack.pair(cylinder_stl())
    jid = stack.submit(obj, grip, {**SMALL, "seed": STUCK_SEED})
    stack.wait_state(jid, ("running",))
    (child,) = worker.children()

    job = stack.svc.wait_job(jid, timeout=90)
    assert job["state"] == "failed" and job["grasp_set"] is None, job
    assert job["error"]["code"] == "time-limit" and "killed after 10 s" in job["error"]["detail"], job
    assert job["attempts"] == 1
    text = worker.text()
    assert "Hard time limit (10" in text and "could not mark job" not in text

    # the same main process, a new child: the next job succeeds
    after = stack.submit(obj, grip, {**SMALL, "seed": 1})
    done = stack.svc.wait_job(after, timeout=90)
    assert done["state"] == "succeeded", done
    assert worker.proc.poll() is None and child.pid not in [c.pid for c in worker.children()]
    assert stack.grasp_sets(obj) == [(1, after)]
    # the killed job is not delivered again (its message was acknowledged when it failed)
    assert stack.svc.get(f"/v1/jobs/{jid}").json()["attempts"] == 1
    assert worker.text().count(f"graspgen.run_job[{jid}] received") == 1
    stack.wait_no_leftovers()


def test_a_real_job_longer_than_the_limit_fails_and_the_worker_goes_on(stack, worker):
    """Many points on a part: far more than the limit allows. The soft limit or the runner's deadline usually ends
    it; if the signal lands inside a long kernel, the hard limit does. Either way: `time-limit`, and the next job.

    40,000 points: 24 s of work in a warm process on a quiet 2-core host (3.6 M candidates; an estimated peak of
    2 GB, within the worker's memory budget), three times the soft limit. 20,000 points (6.3 s) would finish
    inside the limit."""
    obj, grip = stack.pair(cylinder_stl(radius_mm=15.0))
    jid = stack.submit(obj, grip, {"points": 40000, "seed": 2})
    job = stack.svc.wait_job(jid, timeout=90)
    assert job["state"] == "failed" and job["error"]["code"] == "time-limit", job
    assert job["grasp_set"] is None and stack.grasp_sets(obj) == []

    after = stack.submit(obj, grip, {**SMALL, "seed": 3})
    done = stack.svc.wait_job(after, timeout=90)
    assert done["state"] == "succeeded", done
    assert worker.proc.poll() is None
    stack.wait_no_leftovers()
