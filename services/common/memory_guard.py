"""The memory guard of generate jobs (issue 16.4): graspgen.memory's estimate against the job memory budget.

Checked twice: at submission (`POST /v1/jobs`: a 422 `memory-limit` problem naming the largest point count that
fits, no job row) and by the worker before it runs a job (the job fails with the same problem, is acknowledged and
never redelivered), because the worker's budget is the one that matters and a job may have been queued before it
changed. A probe (one pipeline run at graspgen.memory.PROBE_POINTS points, ~0.3 s) is kept per part, gripper and
the parameters that change the candidate density (graspgen.memory.probe_params), in a small per-process LRU, so
resubmissions cost nothing.

A suction job (CONTRACT.md "Suction cups") needs no probe: it keeps at most one candidate per sample point and
approach, so its largest phase is the sampling, linear in the points; its estimate is graspgen.memory's with no pairs
(base + sampling: 170 MB for 100,000 points on a box, 167 MB measured).
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from graspgen.memory import PROBE_POINTS, MemoryEstimate, MemoryLimitError, Probe, limit_error, probe, probe_params
from graspgen.params import Params, from_job

from .grippers import gripper_kind

__all__ = ["check_generate", "problem_extra"]

_MAX_PROBES = 256
_probes: OrderedDict[str, Probe] = OrderedDict()
_lock = threading.Lock()


def _key(part_sha256: str, units: str, spec: dict[str, Any], params: Params) -> str:
    """Runs with the same part, gripper and probe parameters (graspgen.memory.probe_params) share a probe."""
    return json.dumps([part_sha256, units, spec, probe_params(params).to_dict()], sort_keys=True, default=str)


def check_generate(
    *,
    budget_bytes: int,
    part_sha256: str,
    units: str,
    spec: dict[str, Any],
    params: dict[str, Any],
    load_part: Callable[[], Any],
    load_gripper: Callable[[], Any] | None = None,
) -> MemoryEstimate:
    """The estimate of a generate job with these (effective) params, or `MemoryLimitError` when it exceeds the
    budget. `params` is the job's stored params dict (graspgen.params.from_job). `load_part()` returns the graspgen
    Part, `load_gripper()` the GripperSpec of `spec` (needed for a spec with geometry, whose meshes the stored dict
    only names; default: `spec` itself); both are called only when no probe of this part and gripper is cached."""
    run, _ = from_job(params)
    if gripper_kind(spec) == "suction":  # linear in the points (module docstring): no probe
        linear = Probe(PROBE_POINTS, 0.0, 0.0, run.rolls)
        estimate = linear.estimate(run.points)
        if estimate.peak_bytes > budget_bytes:
            raise limit_error(linear, estimate, budget_bytes)
        return estimate
    key = _key(part_sha256, units, spec, run)
    with _lock:
        pr = _probes.get(key)
        if pr is not None:
            _probes.move_to_end(key)
    if pr is None:
        gripper = load_gripper() if load_gripper is not None else spec
        pr = probe(load_part(), gripper, run)
        with _lock:
            _probes[key] = pr
            while len(_probes) > _MAX_PROBES:
                _probes.popitem(last=False)
    est = pr.estimate(run.points)
    if est.peak_bytes > budget_bytes:
        raise limit_error(pr, est, budget_bytes)
    return est


def problem_extra(exc: MemoryLimitError) -> dict[str, Any]:
    """The fields a memory-limit problem carries beside `detail` (API response and the failed job's `error`)."""
    return {
        "field": "points",
        "max_points": exc.max_points,
        "estimated_peak_bytes": exc.estimate.peak_bytes,
        "budget_bytes": exc.budget_bytes,
    }
