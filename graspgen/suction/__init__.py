"""Suction cups, the second gripper kind (CONTRACT.md "Suction cups"): the spec, and the method's criteria for a cup.

`SuctionSpec` is the validated spec (a cup and the tool behind it); `graspgen.generate(part, gripper=SuctionSpec)`
runs the suction method (docs/HOLD.md "Suction cups: the model") and returns a `SuctionGraspSet`; `judge_cups`
evaluates every criterion on given contacts and approaches; `cup_meshes` gives the cup and tool in the grasp frame
(for drawing and simulating them).
"""

from ._export import SuctionCandidates, SuctionGraspSet, load_suction_candidates
from ._generate import CRITERIA, CupJudgement, generate_suction, judge_cups, suction_candidates
from ._model import SUCTION, SuctionModel
from ._recording import cup_meshes
from ._spec import KIND, MAX_VACUUM, SuctionSpec, ToolCylinder, read_spec_json

__all__ = [
    "SuctionSpec",
    "ToolCylinder",
    "KIND",
    "MAX_VACUUM",
    "read_spec_json",
    "SuctionCandidates",
    "SuctionGraspSet",
    "load_suction_candidates",
    "generate_suction",
    "judge_cups",
    "CupJudgement",
    "suction_candidates",
    "CRITERIA",
    "SuctionModel",
    "SUCTION",
    "cup_meshes",
]
