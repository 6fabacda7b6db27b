"""The gripper the tests register and run: the contract's example (graspgen.examples.EXAMPLE_GRIPPER, metres) with
its optional fields left to their defaults: min_width 0, palm_width the finger width, no grip force (criterion (e)
off). Tests that check those defaults rely on their being left out."""

from __future__ import annotations

from graspgen.examples import EXAMPLE_CUP, EXAMPLE_GRIPPER

__all__ = ["GRIPPER", "CUP"]

GRIPPER: dict[str, object] = {
    k: v for k, v in EXAMPLE_GRIPPER.items() if k not in ("min_width", "palm_width", "grip_force")
}

#: the contract's suction cup (examples/cup-30.json): a 30 mm cup at 60 kPa on a round tool
CUP: dict[str, object] = dict(EXAMPLE_CUP)
