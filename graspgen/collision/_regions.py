"""The regions of criterion (d): the gripper's boxes as the kernels test them, one row of a table per box.

A region is a box of the grasp frame at each roll. It either moves with a finger (`moves` = -1 or +1: its bounds
are given in that finger's frame and it is swept along X over the finger's travel, from the pre-grasp opening to
the contact) or is fixed in the grasp frame (`moves` = 0: the palm and the approach path behind it). A roll of a
candidate is blocked when a point (the point kernel) or a triangle (the triangle kernel) of the part lies in a
region at that roll (closed boxes).

Modes (`collision_model`):

- `paper`: the paper's test, the outer cuboid around both fingers minus the inner cuboid between them, the inner
  cuboid being longer than the contact distance by `Tolerances.inner_margin` on each side: the two finger boxes at
  the contacts, each shortened by the margin at its contact face.
- `swept`: the fingers' whole travel from the pre-grasp opening to the contacts, plus the palm and, given the part's
  `reach`, the gripper's approach: the palm's footprint (at least a finger wide) swept along -Z from the fingers'
  base to `reach` behind it, so that no part of the part lies where the palm, the open fingers or the gripper's
  body behind them pass on the way in along +Z.

Inside grasps mirror the fingers: they sit between the contacts and open outwards to them.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit

from ..params import TOLERANCES, Tolerances
from ._meshsolid import MeshSet
from ._solids import BoxGripper, GripperSolids
from ._tritree import empty_tree

if TYPE_CHECKING:
    from ._meshsolid import MeshSolid
    from ._tritree import TriangleTree

__all__ = ["Region", "CollisionModel", "collision_model", "approach_reach", "Regions", "region_table", "FINGER_ROWS"]

# The columns of a region row (region_table): MOVES (-1, +1: the finger it moves with; 0: fixed); X0, X1 (the
# bounds along X: in the finger's frame for a moving region, in the grasp frame for a fixed one); YC, HY (centre and
# half extent along Y, grasp frame: a moving region's are mirrored for the -X finger); ZLO, ZHI (bounds along Z);
# RMIN, RMAX: the radial band around the closing axis that holds the region's (y, z) rectangle at every roll; RIN:
# the radius of the disc around the axis that the rectangle covers at every roll (0 when it does not hold the
# axis); RMIN2, RMAX2, RIN2: the same squared, widened by the point tests' relative guard band (RIN2 = -1: no such
# disc); SYM: 1 when the rectangle is symmetric under a half turn about X (roll k + R/2 covers what roll k does);
# SOLID: -1 for a box region, else the index of its mesh solid in CollisionModel.solid_records() (the region's box
# is then the solid's bounding box, and the triangle kernel tests the solid itself where a triangle meets it).
MOVES, X0, X1, YC, HY, ZLO, ZHI, RMIN, RMAX, RIN, RMIN2, RMAX2, RIN2, SYM, SOLID = range(15)
COLUMNS = 15

#: rows 0 and 1 of a region table are the -X and the +X finger, one box each (a compile-time constant of the
#: kernels: their loops over the fingers unroll); the fixed regions follow, then (the point kernel's prefilter of a
#: CAD gripper) further boxes inside the fingers, tested with the fixed regions
FINGER_ROWS = 2

#: The region table as the kernels read it: rows (r, COLUMNS) float64, ordered as FINGER_ROWS says; travel =
#: (finger thickness, stroke, min_width, clearance, inner margin), metres (finger_x_ranges).
Regions = namedtuple("Regions", ["rows", "travel"])


@dataclass(frozen=True)
class Region:
    """A box of criterion (d): `moves` -1 / +1 (the -X / +X finger; lo, hi in that finger's frame) or 0 (fixed; lo,
    hi in the grasp frame), metres. `solid` >= 0: the region is that mesh solid (model.meshes), lo and hi its
    bounding box."""

    moves: int
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    solid: int = -1


@dataclass(frozen=True)
class CollisionModel:
    """What criterion (d) tests, independent of the candidate: the regions (moving ones first) and the fingers'
    travel (metres)."""

    mode: str
    regions: tuple[Region, ...]
    finger_thickness: float
    stroke: float
    min_width: float
    #: extra opening before closing (0 in `paper` mode: the fingers are tested at the contacts only)
    clearance: float
    inner_margin: float
    #: the mesh solids the regions name (left finger, right finger, body; None where there is none), or None for a
    #: gripper of boxes
    meshes: MeshSet | None = None
    #: what the point kernel tests instead of `regions` when they hold mesh solids: boxes inside the solids (a
    #: sampled point in one is in the solid) and the box regions; None: the regions themselves
    prefilter: tuple[Region, ...] | None = None

    def solid_records(self) -> tuple[TriangleTree, TriangleTree, TriangleTree]:
        """The mesh solids as the triangle kernel reads them: a tuple of three TriangleTrees (empty where none)."""
        if self.meshes is None:
            e = empty_tree()
            return (e, e, e)
        return self.meshes.records()

    @property
    def palm(self) -> Region | None:
        """The fixed region behind the fingers (the palm, reaching back along the approach path when the model was
        given the part's reach); None: there is none."""
        return next((r for r in self.regions if r.moves == 0), None)


def collision_model(
    gripper: BoxGripper, mode: str, tolerances: Tolerances = TOLERANCES, *, reach: float = 0.0
) -> CollisionModel:
    """The regions of criterion (d) for `gripper` in `mode` (`swept` or `paper`). `reach` (m; `swept` only): how
    far behind the fingers' base the approach region extends, at least the largest distance from a grasp's
    midpoint to any point of the part (approach_reach); 0 tests the palm box alone. A gripper with finger and body
    meshes (GripperSpec.geometry) gets mesh regions (the solids themselves, exact) and, for the point kernel, the
    boxes inside them."""
    solids = GripperSolids.of(gripper)
    meshes = solids.meshes
    common: dict[str, Any] = dict(
        mode=mode,
        finger_thickness=solids.finger_thickness,
        stroke=solids.stroke,
        min_width=solids.min_width,
        clearance=solids.clearance if mode == "swept" else 0.0,
        inner_margin=tolerances.inner_margin,
    )
    approach = solids.approach(reach) if mode == "swept" else None
    fixed = [Region(0, approach.lo, approach.hi)] if approach is not None else []
    if meshes is None:
        finger = solids.finger
        regions = [Region(-1, finger.lo, finger.hi), Region(1, finger.lo, finger.hi), *fixed]
        return CollisionModel(regions=tuple(regions), **common)
    left, right, body = meshes.left, meshes.right, meshes.body
    regions = [Region(-1, left.bounds.lo, left.bounds.hi, 0), Region(1, right.bounds.lo, right.bounds.hi, 1), *fixed]
    prefilter = [*_inner_regions(-1, left), *_inner_regions(1, right), *fixed]
    if body is not None and mode == "swept":
        regions.append(Region(0, body.bounds.lo, body.bounds.hi, 2))
        prefilter += [Region(0, b.lo, b.hi) for b in body.inner]
    return CollisionModel(regions=tuple(regions), meshes=meshes, prefilter=tuple(prefilter), **common)


def _inner_regions(moves: int, solid: MeshSolid) -> list[Region]:
    """The point kernel's regions for a mesh finger: the boxes inside it, or one box that holds nothing (x from 1 km
    on) when it has none."""
    if solid.inner:
        return [Region(moves, b.lo, b.hi) for b in solid.inner]
    return [Region(moves, (1.0e3, 0.0, 0.0), (1.0e3, 0.0, 0.0))]


def approach_reach(points: np.ndarray) -> float:
    """`reach` for collision_model: the diagonal of the points' bounding box plus 5 %, beyond the largest distance
    from any midpoint of two of them (or of a mesh they sample finely) to any of them; 0 for no points."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return 1.05 * float(np.linalg.norm(np.ptp(pts, axis=0))) if len(pts) else 0.0


def region_table(model: CollisionModel, guard: float = TOLERANCES.guard, *, prefilter: bool = False) -> Regions:
    """The model's regions as the kernels' table (see the column names above): its exact regions, or (`prefilter`)
    what the point kernel tests; `guard` widens the squared radial bounds relatively (the point tests' shortcuts
    keep this band and fall back to the exact test inside it)."""
    lo_g, hi_g = 1.0 - guard, 1.0 + guard
    rows = []
    regions = model.prefilter if prefilter and model.prefilter is not None else model.regions
    first = [next((r for r in regions if r.moves == m), None) for m in (-1, 1)]
    if first[0] is None or first[1] is None:
        raise ValueError("a collision model has a region for each finger")
    fixed = [r for r in regions if r.moves == 0]
    more = [r for r in regions if r.moves != 0 and r is not first[0] and r is not first[1]]
    for reg in [first[0], first[1], *fixed, *more]:
        ylo, yhi = reg.lo[1], reg.hi[1]
        yc, hy = (ylo + yhi) / 2, (yhi - ylo) / 2
        if reg.moves < 0:  # the -X finger is turned half a turn about Z: y -> -y
            yc = 0.0 - yc
        zlo, zhi = reg.lo[2], reg.hi[2]
        y_far, z_far = max(abs(yc - hy), abs(yc + hy)), max(abs(zlo), abs(zhi))
        r_max = float(np.hypot(y_far, z_far))
        y_in, z_in = yc - hy <= 0.0 <= yc + hy, zlo <= 0.0 <= zhi
        dy = 0.0 if y_in else min(abs(yc - hy), abs(yc + hy))
        dz = 0.0 if z_in else min(abs(zlo), abs(zhi))
        r_min = dz if dy == 0.0 else (dy if dz == 0.0 else float(np.hypot(dy, dz)))
        if y_in and z_in:
            r_in = min(hy - yc, yc + hy, zhi, -zlo)
            r_in2 = r_in * r_in * lo_g
        else:
            r_in, r_in2 = 0.0, -1.0
        sym = 1.0 if yc == 0.0 and zlo == -zhi else 0.0
        row = [float(reg.moves), reg.lo[0], reg.hi[0], yc, hy, zlo, zhi, r_min, r_max, r_in]
        rows.append(row + [r_min * r_min * lo_g, r_max * r_max * hi_g, r_in2, sym, float(reg.solid)])
    travel = np.array([model.finger_thickness, model.stroke, model.min_width, model.clearance, model.inner_margin])
    table = np.array(rows, dtype=np.float64).reshape(-1, COLUMNS)
    return Regions(table, travel)


@njit(cache=True, inline="always", error_model="numpy")
def finger_x_ranges(xr: np.ndarray, inside: bool, w: float, regions: Regions) -> None:
    """The moving regions' bounds along X in the grasp frame for one candidate of closing width `w` (inside: an
    inside grasp), into xr[r, 0:2] for every row that moves: each finger's box swept over its travel from the
    pre-grasp opening to the contact, less the inner margin at the contact."""
    rows = regions.rows
    t, stroke, min_width, clearance, margin = (
        regions.travel[0],
        regions.travel[1],
        regions.travel[2],
        regions.travel[3],
        regions.travel[4],
    )
    if not inside:
        o = min(w + clearance, stroke)
        a, b = w / 2 + margin, max(o, w) / 2
    else:
        o = max(w - clearance, min_width + 2 * t)
        a, b = min(o, w) / 2, w / 2 - margin
    for r in range(FINGER_ROWS):
        _swept_x_range(xr, rows, r, inside, a, b)
    for r in range(FINGER_ROWS, rows.shape[0]):  # further boxes inside CAD fingers
        if rows[r, MOVES] != 0.0:
            _swept_x_range(xr, rows, r, inside, a, b)


@njit(cache=True, inline="always", error_model="numpy")
def _swept_x_range(xr: np.ndarray, rows: np.ndarray, r: int, inside: bool, a: float, b: float) -> None:
    """Row r's box swept with its finger from a to b (its frame's distance from the midpoint at either end of the
    travel), into xr[r]: mirrored for the -X finger; for an inside grasp the finger is turned to face outwards."""
    if not inside:
        lo, hi = a + rows[r, X0], b + rows[r, X1]
    else:
        lo, hi = a - rows[r, X1], b - rows[r, X0]
    if rows[r, MOVES] < 0:
        xr[r, 0], xr[r, 1] = -hi, -lo
    else:
        xr[r, 0], xr[r, 1] = lo, hi


@njit(cache=True, inline="always", error_model="numpy")
def finger_travel(inside: bool, w: float, regions: Regions) -> tuple[float, float]:
    """(s, L) of a finger for a candidate of closing width `w`: its frame lies at s from the midpoint (less the
    inner margin's clearance of the contact) at the contact end of its travel, and moves away from the part by L >= 0
    to the pre-grasp opening (0 in `paper` mode)."""
    t, stroke, min_width, clearance, margin = (
        regions.travel[0],
        regions.travel[1],
        regions.travel[2],
        regions.travel[3],
        regions.travel[4],
    )
    if not inside:
        s = w / 2 + margin
        return s, max(max(min(w + clearance, stroke), w) / 2 - s, 0.0)
    s = w / 2 - margin
    return s, max(s - min(max(w - clearance, min_width + 2 * t), w) / 2, 0.0)


@njit(cache=True, inline="always", error_model="numpy")
def fixed_x_ranges(xr: np.ndarray, regions: Regions) -> None:
    """The fixed regions' bounds along X into xr[r, 0:2]."""
    for r in range(FINGER_ROWS, regions.rows.shape[0]):
        if regions.rows[r, MOVES] == 0.0:
            xr[r, 0], xr[r, 1] = regions.rows[r, X0], regions.rows[r, X1]
