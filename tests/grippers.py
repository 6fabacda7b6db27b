"""The gripper the tests register and run: the contract's example (graspgen.examples.EXAMPLE_GRIPPER, metres) with
its optional fields left to their defaults: min_width 0, palm_width the finger width, no grip force (criterion (e)
off). Tests that check those defaults rely on their being left out."""

from __future__ import annotations

from graspgen.examples import EXAMPLE_GRIPPER

__all__ = ["GRIPPER", "CUP"]

GRIPPER: dict[str, object] = {
    k: v for k, v in EXAMPLE_GRIPPER.items() if k not in ("min_width", "palm_width", "grip_force")
}

#: the contract's suction cup (examples/cup-30.json): a 30 mm cup at 60 kPa on a round tool
CUP: dict[str, object] = {
    "name": "cup-30",
    "kind": "suction",
    "cup_radius": 0.015,
    "cup_height": 0.02,
    "max_strain": 0.1,
    "vacuum": 60000,
    "friction": 0.5,
    "tool": {"radius": 0.012, "length": 0.12},
    "pregrasp_clearance": 0.03,
}
