"""The registry of job kinds: the one place that lists them. The API takes `POST /v1/jobs` bodies as the discriminated
union of the kinds' request models and resolves them with the kind's `resolve`; the worker runs a claimed job with
its kind's `run` and weighs its progress with the kind's stages; containers (bulk) are never run or queued.

A new kind: a module here with its request model (`kind: Literal["<name>"]`), `resolve`, `run` and stage weights,
ending in `KIND = JobKind(...)` (services/jobkinds/kind.py); then the module imported and its `KIND` in `KINDS`
below. Nothing registers itself on import.
"""

from __future__ import annotations

import functools
import operator
from collections.abc import Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Annotated, Any, cast

from pydantic import ConfigDict, Field, RootModel, model_validator

from . import bulk, cluster, generate
from .kind import ContainerKind, JobInputs, JobKind, RunContext

__all__ = [
    "KINDS",
    "RUNNABLE",
    "CONTAINER_KINDS",
    "DEFAULT_KIND",
    "JobKind",
    "ContainerKind",
    "JobInputs",
    "RunContext",
    "JobRequest",
    "is_container",
]

KINDS: Mapping[str, JobKind | ContainerKind] = MappingProxyType(
    {k.name: k for k in (generate.KIND, cluster.KIND, bulk.KIND)}
)
#: the kinds that run, each with its request model in the union of `POST /v1/jobs`
RUNNABLE: Mapping[str, JobKind] = MappingProxyType({n: k for n, k in KINDS.items() if isinstance(k, JobKind)})
#: parents of other jobs: never run, never queued; their state is their items' aggregate
CONTAINER_KINDS = tuple(n for n, k in KINDS.items() if isinstance(k, ContainerKind))
#: the kind of a `POST /v1/jobs` body without `kind` (CONTRACT.md)
DEFAULT_KIND = generate.KIND.name

_REQUESTS = tuple(k.request for k in RUNNABLE.values())
#: the union of the request models, told apart by their `kind` (built from the registered kinds at run time, which
#: no static type can name: Any to mypy)
if TYPE_CHECKING:
    _BODY = Any
else:
    _BODY = Annotated[functools.reduce(operator.or_, _REQUESTS), Field(discriminator="kind")]


def is_container(name: str) -> bool:
    return name in CONTAINER_KINDS


class JobRequest(RootModel[_BODY]):
    """One request per job kind, chosen by `kind`; a body without `kind` is a job of the default kind (generate)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                ex
                for model in _REQUESTS
                for ex in cast(dict[str, Any], model.model_config["json_schema_extra"])["examples"]
            ]
        }
    )

    @model_validator(mode="before")
    @classmethod
    def _default_kind(cls, data: Any) -> Any:
        if isinstance(data, dict) and "kind" not in data:
            return {**data, "kind": DEFAULT_KIND}
        return data
