"""graspgen: automatic grasp pose generation for parallel-jaw grippers (Kleeberger et al.), fast and exact.

The public surface is `generate`, `recluster`, `GraspSet`, `GripperSpec`, `SuctionSpec` (`load_gripper` reads either
by its `kind`), `Params`, `load_part` and the errors.
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
from .kinds import GripperKind, load_gripper
from .params import Params
from .parts import Part, load_part
from .pick import PickResult, pick
from .pipeline import generate, recluster
from .suction import SuctionGraspSet, SuctionSpec

__all__ = [
    "generate",
    "recluster",
    "pick",
    "PickResult",
    "GraspSet",
    "Candidates",
    "load_candidates",
    "GripperSpec",
    "SuctionSpec",
    "SuctionGraspSet",
    "GripperKind",
    "load_gripper",
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
