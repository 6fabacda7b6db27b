"""Criterion (d) in all its forms: the gripper's solids, the regions they sweep, and the exact tests of those regions
against the part's sampled points and against its triangles.

- `_solids`: the gripper's solids in the grasp frame, read from a GripperSpec (collision, pick, previews,
  recordings and validation all use them); `_meshsolid`: a solid given as a closed mesh (fingers and bodies from
  CAD), `_shapes`: boxes.
- `_regions`: the regions of criterion (d) (`collision_model`) and their table as the kernels read it.
- `_points`: the point kernel (free_rolls): every roll of every candidate against the sampled points.
- `_hull`: the sample's convex hull, a certificate that the palm is clear at a roll.
- `_tritree`: the part's triangle tree, the exact triangle tests, normals near a point, triangles near a segment
  (graspgen.suction's walks).
- `_triangles`: the mesh-exact check (mesh_free_rolls).
- `_seat`: where a CAD finger first touches the part as it closes (the export's contacts).
- `_frame`, `_bits`: the candidate's roll-0 frame and roll tables, roll masks.

Design notes (why the walks are built as they are, why their bounds are exact): docs/design/collision.md.
"""

from ._bits import MAX_ROLLS, any_free, popcount
from ._meshsolid import MeshSet, MeshSolid, mesh_solid
from ._points import STATS, free_rolls, free_rolls_of_pairs, free_rolls_stats
from ._regions import CollisionModel, Region, approach_reach, collision_model
from ._seat import Seat, seat_fingers, seat_friction_margin_deg
from ._shapes import Box, Cuboid
from ._solids import GripperSolids
from ._triangles import mesh_free_rolls, mesh_free_rolls_of_pairs
from ._tritree import (
    MeshTree,
    TriangleTree,
    build_tree,
    normal_spread_rad,
    prism_meets_triangle,
    tri_meets_solid,
    triangles_near_segment,
)

__all__ = [
    "MAX_ROLLS",
    "STATS",
    "Box",
    "CollisionModel",
    "Cuboid",
    "GripperSolids",
    "MeshSet",
    "MeshSolid",
    "MeshTree",
    "TriangleTree",
    "Region",
    "Seat",
    "any_free",
    "approach_reach",
    "build_tree",
    "collision_model",
    "free_rolls",
    "free_rolls_of_pairs",
    "free_rolls_stats",
    "mesh_free_rolls",
    "mesh_free_rolls_of_pairs",
    "mesh_solid",
    "normal_spread_rad",
    "popcount",
    "prism_meets_triangle",
    "seat_fingers",
    "seat_friction_margin_deg",
    "tri_meets_solid",
    "triangles_near_segment",
]
