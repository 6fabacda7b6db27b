"""Job params shared by the kinds that run: graspgen.Params and the job options of graspgen.QualityOptions
(docs/QUALITY.md), checked at submission and handed to graspgen as those objects at run time (graspgen.params.from_job).
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from graspgen.params import Params, QualityOptions

__all__ = ["QUALITY_PARAMS", "JOB_PARAM_NAMES", "split_quality"]

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
