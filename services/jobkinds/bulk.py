"""The `bulk` job kind: a parent of generate jobs, submitted on its own route (`POST /v1/bulk-jobs`, BulkRequest,
services/api/crud/jobs.py submit_bulk). It never runs: its state and progress are its items' aggregate
(services/common/jobs.py); the worker, the dispatcher's recovery and the reconciler leave it alone."""

from __future__ import annotations

from . import generate
from .kind import ContainerKind

__all__ = ["KIND"]

KIND = ContainerKind(name="bulk", item=generate.KIND)
