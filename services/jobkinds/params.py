"""Job params shared by the kinds that run: graspgen.Params and the job options of graspgen.QualityOptions
(docs/QUALITY.md), checked at submission and handed to graspgen as those objects at run time (graspgen.params.from_job).
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from graspgen.errors import InvalidParameterError
from graspgen.params import Params, QualityOptions

__all__ = ["QUALITY_PARAMS", "JOB_PARAM_NAMES", "split_quality", "check_for_kind", "NOT_FOR_KIND"]

#: job params beyond graspgen.Params: the job options of graspgen.QualityOptions
QUALITY_PARAMS = QualityOptions.JOB_OPTIONS
#: every name a job's params may carry
JOB_PARAM_NAMES = (*(f.name for f in fields(Params)), *QUALITY_PARAMS)


def split_quality(given: dict[str, Any] | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(core params, quality params) of a job's params; quality params are checked here (graspgen's QualityOptions)
    so that a bad value is a 422 at submission. Only non-default values are kept: `validate` only when true, `select`
    only when not "medoid". `density` is a core parameter (graspgen.Params: criterion (e) and validation)."""
    core, options = QualityOptions.split_job(given)
    return core, options.job_dict()


#: per gripper kind, the job params it has no use for, as (name, the values refused, why): graspgen refuses the same
#: when the run starts (tests/worker/test_worker_suction.py checks that it does); here they are refused at
#: submission, so that a job that cannot run is never stored
NOT_FOR_KIND: dict[str, tuple[tuple[str, Any, str], ...]] = {
    "suction": (
        ("inside", lambda v: v is True, "inside grasps are for jaws: a suction cup seals on an outer face"),
        ("collision", lambda v: v not in (None, "swept"), "a suction cup's collision is its cup and tool swept"),
        ("validate", lambda v: bool(v), "suction grasps are not validated in simulation yet"),
        ("select", lambda v: v not in (None, "medoid"), "suction grasps are the clusters' medoids"),
    ),
    "parallel": (
        (
            "max_tilt_deg",
            lambda v: v is not None,
            "max_tilt_deg is for suction cups: a parallel grasp's approach follows from its contacts",
        ),
    ),
}


def check_for_kind(kind: str, params: dict[str, Any]) -> None:
    """InvalidParameterError (a 422 naming the field) when the effective job `params` give one that the gripper
    `kind` has no use for (NOT_FOR_KIND)."""
    for name, refused, why in NOT_FOR_KIND.get(kind, ()):
        if refused(params.get(name)):
            raise InvalidParameterError(
                f"{name} = {params[name]!r} does not apply to a {kind} gripper: {why}", field=name
            )
