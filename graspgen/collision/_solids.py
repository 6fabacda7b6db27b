"""The gripper's solids in the grasp frame (CONTRACT.md "Gripper spec"), read from one source, the GripperSpec.

Criterion (d), the mesh-exact check, the pick query's plane test, previews, recordings and the physics validation
all take the gripper's geometry from here. Frames:

- finger frame: origin at the pad's contact point, the pad's inner face looking along -X (towards the part), +Z the
  approach direction. At closing width w the +X finger's frame sits at (+w/2, 0, 0) of the grasp frame; the -X
  finger's at (-w/2, 0, 0), turned 180 degrees about Z ((x, y, z) -> (-x, -y, z)).
- grasp frame: the contract's (origin at the contacts' midpoint, X the closing axis, the palm at -Z).

A box finger is the cuboid x in [0, finger_thickness], |y| <= finger_width / 2, |z| <= finger_depth / 2 of its
finger frame; the palm is a box of the grasp frame behind the fingers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, overload

import numpy as np

from ._meshsolid import MeshSet, mesh_solid
from ._shapes import Box, Cuboid

__all__ = ["Box", "Cuboid", "GripperSolids", "BoxGripper"]


class BoxGripper(Protocol):
    """What the solids read of a gripper spec (graspgen.gripper.GripperSpec; read by attribute, because gripper.py
    builds its boxes from this package). `geometry`: the finger and body meshes (GripperGeometry), or None.
    Read-only members, so that a frozen dataclass satisfies it."""

    @property
    def stroke(self) -> float: ...
    @property
    def min_width(self) -> float: ...
    @property
    def finger_width(self) -> float: ...
    @property
    def finger_depth(self) -> float: ...
    @property
    def finger_thickness(self) -> float: ...
    @property
    def palm_depth(self) -> float: ...
    @property
    def palm_width(self) -> float | None: ...
    @property
    def pregrasp_clearance(self) -> float: ...
    @property
    def geometry(self) -> Any: ...


@dataclass(frozen=True)
class GripperSolids:
    """The solids of a parallel-jaw gripper: each finger's bounding box in its own finger frame (for box fingers the
    finger itself; the -X finger is turned 180 degrees about Z in the grasp frame), the palm box in the grasp frame
    (None: no palm), the mesh solids of a gripper from CAD (None for boxes), the contact pad's size and the fingers'
    travel."""

    finger: Cuboid
    finger_left: Cuboid
    palm: Box | None
    stroke: float
    min_width: float
    #: total extra opening before closing: the pre-grasp opening is min(width + clearance, stroke)
    clearance: float
    #: the palm's extent along Y (the approach region is at least this wide)
    palm_width: float
    #: the contact pad's extent along Y and Z of the finger frame, metres (criterion (e)'s patch)
    pad: tuple[float, float]
    meshes: MeshSet | None = None

    @classmethod
    def of(cls, spec: BoxGripper) -> GripperSolids:
        geometry = getattr(spec, "geometry", None)
        if geometry is not None:
            return cls._of_meshes(spec, geometry)
        t, fw, fd = spec.finger_thickness, spec.finger_width, spec.finger_depth
        finger = Cuboid((0.0, -fw / 2, -fd / 2), (t, fw / 2, fd / 2))
        # GripperSpec.__post_init__ fills palm_width (the finger's width when the spec leaves it out)
        assert spec.palm_width is not None
        palm = None
        if spec.palm_depth > 0:
            half_x = spec.stroke / 2 + t
            z_top = -fd / 2
            palm = Box((0.0, 0.0, z_top - spec.palm_depth / 2), (2 * half_x, float(spec.palm_width), spec.palm_depth))
        return cls(
            finger, finger, palm, spec.stroke, spec.min_width, spec.pregrasp_clearance, float(spec.palm_width), (fw, fd)
        )

    @classmethod
    def _of_meshes(cls, spec: BoxGripper, geometry: Any) -> GripperSolids:
        right = _solid(geometry.finger)
        left = _solid(geometry.finger_left)
        body = _solid(geometry.body) if geometry.body is not None else None
        return cls(
            right.bounds,
            left.bounds,
            None,
            spec.stroke,
            spec.min_width,
            spec.pregrasp_clearance,
            0.0,
            (float(geometry.pad_width), float(geometry.pad_depth)),
            MeshSet(left, right, body),
        )

    @property
    def finger_thickness(self) -> float:
        """The +X finger's extent along X, from its pad's plane outwards."""
        return self.finger.hi[0]

    @property
    def finger_base_z(self) -> float:
        """The fingers' base: their lowest z (the palm's front face when there is a palm), grasp frame."""
        return min(self.finger.lo[2], self.finger_left.lo[2])

    @overload
    def open_width(self, width: float, *, inside: bool = False) -> float: ...
    @overload
    def open_width(self, width: np.ndarray, *, inside: bool = False) -> np.ndarray: ...
    def open_width(self, width: float | np.ndarray, *, inside: bool = False) -> float | np.ndarray:
        """The pre-grasp opening for the contact distance `width` (float or array): min(width + clearance, stroke);
        for an inside grasp (the fingers open outwards onto the part) the narrower max(width - clearance, min_width
        + 2 thickness), the fingers' outer faces then."""
        if inside:
            floor = self.min_width + 2 * self.finger_thickness
            return (
                np.maximum(width - self.clearance, floor)
                if isinstance(width, np.ndarray)
                else max(width - self.clearance, floor)
            )
        return (
            np.minimum(width + self.clearance, self.stroke)
            if isinstance(width, np.ndarray)
            else min(width + self.clearance, self.stroke)
        )

    def fingers(self, width: float) -> tuple[Box, Box]:
        """The -X and +X finger boxes in the grasp frame at closing width `width` (inner faces at x = -+width/2)."""
        lo, hi = self.finger.lo, self.finger.hi
        cx = width / 2 + (lo[0] + hi[0]) / 2
        cy, cz = (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2
        ext = (hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])
        return Box((-cx, 0.0 - cy, cz), ext), Box((cx, cy, cz), ext)

    def boxes(self, width: float) -> list[Box]:
        """Every box of the gripper at closing width `width`: both fingers, then the palm when there is one."""
        return [*self.fingers(width), *([self.palm] if self.palm else [])]

    def approach(self, reach: float) -> Cuboid | None:
        """Where the gripper passes on its way in along +Z, grasp frame: the palm, and (reach > 0) the gripper's
        footprint (the palm's, at least a finger wide; with meshes, the fingers' at full stroke and the body's) swept
        back along -Z from the fingers' base `reach` behind it. None without a palm and without a reach."""
        depth = self.palm.extents[2] if self.palm is not None else 0.0
        if depth <= 0 and reach <= 0:
            return None
        z_hi = self.finger_base_z
        if self.meshes is None:
            half_x = self.stroke / 2 + self.finger_thickness
            half_y = self.palm_width / 2 if depth > 0 else 0.0
            if reach > 0:  # the open fingers and the body behind them pass here too
                half_y = max(half_y, self.finger.hi[1])
            z_lo = z_hi - max(depth, float(reach))
            return Cuboid((-half_x, -half_y, z_lo), (half_x, half_y, z_hi))
        half_x = self.stroke / 2 + max(self.finger.hi[0], self.finger_left.hi[0])
        half_y = max(abs(v) for c in (self.finger, self.finger_left) for v in (c.lo[1], c.hi[1]))
        lo_x, hi_x, lo_y, hi_y = -half_x, half_x, -half_y, half_y
        body = self.meshes.body
        if body is not None:
            lo_x, hi_x = min(lo_x, body.bounds.lo[0]), max(hi_x, body.bounds.hi[0])
            lo_y, hi_y = min(lo_y, body.bounds.lo[1]), max(hi_y, body.bounds.hi[1])
        return Cuboid((lo_x, lo_y, z_hi - float(reach)), (hi_x, hi_y, z_hi))

    def trimeshes(self, width: float) -> list[Any]:
        """Every solid of the gripper at closing width `width` as a trimesh.Trimesh in the grasp frame (fingers, then
        palm or body): what previews, recordings and the physics validation draw and simulate."""
        import trimesh

        out = []
        if self.meshes is None:
            for box in self.boxes(width):
                m = trimesh.creation.box(extents=box.extents)
                m.apply_translation(box.center)
                out.append(m)
            return out
        for side, solid in ((-1, self.meshes.left), (1, self.meshes.right)):
            tri = solid.tree.triangles.reshape(-1, 3).copy()
            if side < 0:
                tri[:, 0], tri[:, 1] = -tri[:, 0] - width / 2, -tri[:, 1]
            else:
                tri[:, 0] += width / 2
            out.append(trimesh.Trimesh(tri, np.arange(len(tri)).reshape(-1, 3), process=True))
        if self.meshes.body is not None:
            tri = solid_triangles(self.meshes.body)
            out.append(trimesh.Trimesh(tri, np.arange(len(tri)).reshape(-1, 3), process=True))
        return out

    def finger_hulls(self) -> tuple[np.ndarray, np.ndarray]:
        """The (-X, +X) fingers' convex-hull vertices, each (h, 3) in its own finger frame (boxes: their corners):
        a finger's lowest point along any direction is one of them."""
        if self.meshes is not None:
            return self.meshes.left.hull_vertices, self.meshes.right.hull_vertices
        return _corners(self.finger_left), _corners(self.finger)

    def plane_offsets(self, mx: np.ndarray, my: np.ndarray, mz: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """For a direction m of the grasp frame given per candidate as mx = |m . X|, my = |m . Y|, mz = m . Z (each
        (k,)): (side, palm). side: how far below a finger's centre line its lowest corner lies, |mx| aside (that
        part depends on the opening: a finger reaches |mx| (opening / 2 + thickness) along X); palm: the height of
        the palm's lowest corner above the grasp origin (None without a palm). A box's lowest corner lies
        sum_i |m_i| h_i below its centre (h: its half extents)."""
        amz = np.abs(mz)
        lo, hi = self.finger.lo, self.finger.hi
        side = my * ((hi[1] - lo[1]) / 2) + amz * ((hi[2] - lo[2]) / 2)
        palm = None
        if self.palm is not None:
            c, e = self.palm.center, self.palm.extents
            palm = mz * c[2] - mx * (e[0] / 2) - my * (e[1] / 2) - amz * (e[2] / 2)
        return side, palm


def _corners(c: Cuboid) -> np.ndarray:
    return np.array([[x, y, z] for x in (c.lo[0], c.hi[0]) for y in (c.lo[1], c.hi[1]) for z in (c.lo[2], c.hi[2])])


def solid_triangles(solid: Any) -> np.ndarray:
    """A mesh solid's triangles as (3 m, 3) vertex rows in its own frame."""
    return np.ascontiguousarray(solid.tree.triangles.reshape(-1, 3))


def _solid(mesh: Any) -> Any:
    return mesh_solid(mesh.vertices, mesh.faces)
