"""Criterion (d) in all its forms: the gripper's solids, the regions they sweep, and the exact tests of those regions
against the part's sampled points and against its triangles.

- `_solids`: the gripper's solids in the grasp frame, read from a GripperSpec (collision, pick, previews,
  recordings and validation all use them).
- `_regions`: the regions of criterion (d) (`collision_model`) and their table as the kernels read it.
- `_points`: the point kernel (free_rolls): every roll of every candidate against the sampled points.
- `_hull`: the sample's convex hull, a certificate that the palm is clear at a roll.
- `_triangles`: the part's triangle tree, the mesh-exact check (mesh_free_rolls) and normals near a point.
- `_frame`, `_bits`: the candidate's roll-0 frame and roll tables, roll masks.

Design notes (why the walks are built as they are, why their bounds are exact): docs/design/collision.md.
"""

from ._bits import MAX_ROLLS, any_free, popcount
from ._points import STATS, free_rolls, free_rolls_of_pairs, free_rolls_stats
from ._regions import CollisionModel, Region, approach_reach, collision_model
from ._solids import Box, Cuboid, GripperSolids
from ._triangles import MeshTree, build_tree, mesh_free_rolls, mesh_free_rolls_of_pairs, normal_spread_rad

__all__ = [
    "MAX_ROLLS",
    "STATS",
    "Box",
    "CollisionModel",
    "Cuboid",
    "GripperSolids",
    "MeshTree",
    "Region",
    "any_free",
    "approach_reach",
    "build_tree",
    "collision_model",
    "free_rolls",
    "free_rolls_of_pairs",
    "free_rolls_stats",
    "mesh_free_rolls",
    "mesh_free_rolls_of_pairs",
    "normal_spread_rad",
    "popcount",
]
