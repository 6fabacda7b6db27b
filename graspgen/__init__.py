"""graspgen: automatic grasp pose generation for parallel-jaw grippers (Kleeberger et al.), fast and exact.

The public surface is `generate`, `recluster`, `GraspSet`, `GripperSpec`, `Params`, `load_part` and the errors.
"""

from .errors import (
    Cancelled,
    GraspgenError,
    InvalidCandidatesError,
    InvalidGripperError,
    InvalidMeshError,
    InvalidParameterError,
    InvalidUnitsError,
)
from .export import Candidates, GraspSet, load_candidates
from .gripper import GripperSpec
from .params import Params
from .parts import Part, load_part
from .pick import PickResult, pick
from .pipeline import generate, recluster

__all__ = [
    "generate",
    "recluster",
    "pick",
    "PickResult",
    "GraspSet",
    "Candidates",
    "load_candidates",
    "GripperSpec",
    "Params",
    "Part",
    "load_part",
    "GraspgenError",
    "InvalidMeshError",
    "InvalidGripperError",
    "InvalidParameterError",
    "InvalidUnitsError",
    "InvalidCandidatesError",
    "Cancelled",
]
__version__ = "0.1.0"
