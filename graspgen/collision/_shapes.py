"""Boxes, as the gripper's solids and the kernels' regions are described."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Box", "Cuboid", "Vec3"]

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in the grasp frame: centre (3,) and full extents (3,), metres."""

    center: Vec3
    extents: Vec3


@dataclass(frozen=True)
class Cuboid:
    """An axis-aligned box given by its bounds lo <= hi (3 floats each), metres, in the frame its owner names."""

    lo: Vec3
    hi: Vec3
