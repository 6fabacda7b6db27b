"""Job params shared by the kinds that run: the quality options (docs/QUALITY.md), which are keyword arguments of
graspgen.generate / recluster beside graspgen.Params, checked at submission and passed by name at run time."""

from __future__ import annotations

from typing import Any

from graspgen.params import QualityOptions

__all__ = ["QUALITY_PARAMS", "split_quality", "given_kwargs"]

#: job params beyond graspgen.Params: keyword arguments of graspgen.generate / recluster
QUALITY_PARAMS = QualityOptions.JOB_OPTIONS


def split_quality(given: dict[str, Any] | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(core params, quality params) of a job's params; quality params are checked here (graspgen's QualityOptions)
    so that a bad value is a 422 at submission. Only non-default values are kept: `validate` only when true, `select`
    only when not "medoid". `density` is a core parameter (graspgen.Params: criterion (e) and validation)."""
    core, options = QualityOptions.split_job(given)
    return core, options.job_dict()


def given_kwargs(params: dict[str, Any], names: tuple[str, ...]) -> dict[str, Any]:
    """The stored params among `names` that have a value, as keyword arguments (a job stored before a param existed
    has none of it and runs with the core's default)."""
    return {k: params[k] for k in names if params.get(k) is not None}
