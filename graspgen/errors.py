"""One exception hierarchy for the whole product.

The API maps every `GraspgenError` to RFC 9457 problem+json (4xx) and the CLI to exit status 2;
anything else is an internal error (HTTP 500 / exit 1).
"""

from __future__ import annotations

__all__ = [
    "GraspgenError",
    "InvalidMeshError",
    "InvalidGripperError",
    "InvalidParameterError",
    "InvalidUnitsError",
    "InvalidCandidatesError",
    "Cancelled",
]


class GraspgenError(Exception):
    """Bad input a user can act on. `code` is a stable machine-readable slug."""

    code = "invalid-input"

    def __init__(self, message: str, *, field: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field


class InvalidMeshError(GraspgenError):
    code = "invalid-mesh"


class InvalidGripperError(GraspgenError):
    code = "invalid-gripper"


class InvalidParameterError(GraspgenError):
    code = "invalid-parameter"


class InvalidUnitsError(GraspgenError):
    code = "invalid-units"


class InvalidCandidatesError(GraspgenError):
    code = "invalid-candidates"


class Cancelled(Exception):  # noqa: N818 - it is a signal, not an error of the input
    """Raised from a progress callback to stop a run between stages."""
