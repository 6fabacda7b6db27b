"""What a job kind is: `JobKind` (its name, request body, resolution, run and progress stages) or `ContainerKind`
(a parent of other jobs), and what a run is given (`RunContext` over the claimed job's `JobInputs`). The registry
of the kinds is services/jobkinds/__init__.py."""

from __future__ import annotations

import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel
from sqlalchemy.orm import Session

if TYPE_CHECKING:
    from graspgen.export import GraspSet
    from graspgen.suction import SuctionGraspSet
    from services.common.storage import Storage

__all__ = ["JobKind", "ContainerKind", "JobInputs", "RunContext", "Resolve", "Run"]

#: the validated request body -> the job row's input columns (object_version_id, gripper_version_id,
#: source_grasp_set_id, params); raises services.api.problems.ApiError or a GraspgenError (both 422 problems)
Resolve = Callable[[Session, Any], dict[str, Any]]
#: the claimed job's inputs -> graspgen's result; raises GraspgenError for bad input, Cancelled when cancelled
Run = Callable[["RunContext"], "GraspSet | SuctionGraspSet"]


@dataclass(frozen=True)
class JobKind:
    """A kind of job that runs: its request body (a pydantic model whose `kind` field is `Literal[name]`, one member
    of the discriminated union of `POST /v1/jobs`), its resolution at submission and its run in the worker."""

    name: str
    request: type[BaseModel]
    resolve: Resolve
    run: Run
    #: share of the progress bar per stage of the run, in the order the stages run; "validate" counts only for a job
    #: with params.validate (progress_weights)
    stage_weights: Mapping[str, float]
    #: the job's peak memory is estimated at submission and refused (422 memory-limit) when over the worker's budget
    checks_memory: bool = False

    def progress_weights(self, *, validate: bool) -> dict[str, float]:
        """The stage weights of one job, summing to 1: without validation the "validate" share goes to the others."""
        weights = dict(self.stage_weights)
        if not validate:
            weights.pop("validate", None)
        total = sum(weights.values())
        return {k: w / total for k, w in weights.items()}


@dataclass(frozen=True)
class ContainerKind:
    """A kind of job that is a parent of jobs of kind `item` (bulk), submitted on its own route. It never runs and is
    never queued: its state and progress are its items' aggregate (services/common/jobs.py)."""

    name: str
    item: JobKind


@dataclass(frozen=True)
class JobInputs:
    """A claimed job's row with its object and gripper versions (and the source grasp set of a cluster job)."""

    job_id: uuid.UUID
    kind: str
    attempt: int
    params: dict[str, Any]
    object_name: str
    object_version: int
    object_version_id: int
    object_id: int
    object_sha256: str
    object_file_key: str
    object_format: str
    units: str
    gripper_name: str
    gripper_version: int
    gripper_version_id: int
    gripper_id: int
    spec: dict[str, Any]
    source_grasp_set_id: int | None
    source_export_key: str | None
    source_candidates_key: str | None
    params_key: str

    @property
    def part_path_name(self) -> str:
        return f"part.{self.object_format}"  # the format is a whitelisted token, never a user path


@dataclass(frozen=True)
class RunContext:
    """What a kind's run gets from the worker (services/worker/runner.py)."""

    inputs: JobInputs
    storage: Storage
    #: a temporary directory of this run, removed after it
    tmp: Path
    #: the run's Rerun RecordingStream
    recording: Any
    #: graspgen's progress callback: (stage, fraction within the stage); raises Cancelled when cancelled
    progress: Callable[[str, float], None]
    #: the part file at this path, loaded once after the job's peak memory was checked against the worker's budget
    load_part: Callable[[Path], Any]
    #: the job's gripper version as graspgen.GripperSpec, loaded once: a spec with geometry with its mesh files
    #: from storage (services/common/grippers.py)
    gripper: Callable[[], Any]

    def download_part(self) -> Path:
        """The job's part file in `tmp`."""
        return self.storage.download(self.inputs.object_file_key, self.tmp / self.inputs.part_path_name)
