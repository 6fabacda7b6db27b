"""A gripper solid given as a closed triangle mesh (CONTRACT.md "Gripper geometry from CAD"): the exact test of a
part's triangle against it, swept along X, and what the cheaper tests need of it.

A finger mesh lies in its finger frame; as the finger opens from the contact to the pre-grasp width, the part moves
relative to it along -X. A part triangle A meets the finger somewhere on that travel exactly when the prism
conv(A, A - L X) meets the finger's solid; for closed surfaces that is when the prism meets one of the finger's
triangles (the boundary of the swept solid lies in the union of its triangles' sweeps) or lies wholly inside the
finger, which the part's other triangles then show (a part surface that crosses into a finger crosses its boundary:
a part that touches a finger only from inside it is not seen, as with the box fingers). The prism against a triangle
is a separating-axis test over every face normal and edge pair of the two (`prism_meets_triangle`); touching counts
as meeting, within the guard band.

For the point kernel, which only tests whether a sampled point lies in a box, a mesh solid offers its inner box
(`inner_boxes`): a box that lies wholly inside the solid, so that a point in it is certainly in the solid (a prefilter
that can only block what the exact test blocks too).
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass
from typing import cast

import numpy as np
from numba import njit

from ._shapes import Cuboid, Vec3
from ._tritree import COUNT, LEFT, M_C, M_H, RIGHT, START, MeshTree, TriangleTree, build_tree, empty_tree, tri_box

__all__ = ["MeshSolid", "MeshSet", "mesh_solid", "inner_boxes"]


@dataclass(frozen=True, eq=False)
class MeshSolid:
    """A closed triangle mesh in its own frame, metres: its triangle tree, the vertices of its convex hull (the
    lowest point along any direction is one of them), its bounding box and a few boxes inside it (inner_boxes)."""

    tree: MeshTree
    hull_vertices: np.ndarray  # (h, 3)
    bounds: Cuboid
    inner: tuple[Cuboid, ...]

    def record(self) -> TriangleTree:
        return self.tree.record()


@dataclass(frozen=True, eq=False)
class MeshSet:
    """A gripper's mesh solids: the -X finger and the +X finger, each in its own finger frame, and the body in the
    grasp frame (None: no body)."""

    left: MeshSolid
    right: MeshSolid
    body: MeshSolid | None

    def records(self) -> tuple[TriangleTree, TriangleTree, TriangleTree]:
        """(left, right, body) as TriangleTrees, an empty one for no body (the triangle kernel's `solids`)."""
        return (self.left.record(), self.right.record(), self.body.record() if self.body else empty_tree())


_CACHE: dict[bytes, MeshSolid] = {}
_CACHE_LOCK = threading.Lock()
_CACHE_KEEP = 16


def mesh_solid(vertices: np.ndarray, faces: np.ndarray) -> MeshSolid:
    """The MeshSolid of a closed mesh (vertices (n, 3) metres, faces (m, 3)), cached by content: a gripper's meshes
    are prepared once per process."""
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    F = np.ascontiguousarray(faces, dtype=np.int64)
    key = hashlib.blake2b(V.tobytes() + F.tobytes(), digest_size=16).digest()
    with _CACHE_LOCK:
        got = _CACHE.get(key)
    if got is not None:
        return got
    from scipy.spatial import ConvexHull

    tree = build_tree(V, F)
    hull = V[ConvexHull(V).vertices] if len(V) >= 4 else V
    lo, hi = V.min(axis=0), V.max(axis=0)
    solid = MeshSolid(tree, np.ascontiguousarray(hull), Cuboid(tuple(lo), tuple(hi)), inner_boxes(tree, V))
    with _CACHE_LOCK:
        while len(_CACHE) >= _CACHE_KEEP:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = solid
    return solid


# -- a box inside the solid ------------------------------------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def _box_meets_tree(tree: TriangleTree, c: np.ndarray, e: np.ndarray) -> bool:
    """Does any triangle of the tree meet the closed box with centre c (3,) and half extents e (3,)?"""
    nodes, children, T = tree.nodes, tree.children, tree.triangles
    if nodes.shape[0] == 0:
        return False
    stack = np.empty(128, dtype=np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        k = stack[top]
        if (
            abs(nodes[k, M_C] - c[0]) > nodes[k, M_H] + e[0]
            or abs(nodes[k, M_C + 1] - c[1]) > nodes[k, M_H + 1] + e[1]
            or abs(nodes[k, M_C + 2] - c[2]) > nodes[k, M_H + 2] + e[2]
        ):
            continue
        if children[k, LEFT] < 0:
            for t in range(children[k, START], children[k, START] + children[k, COUNT]):
                if tri_box(T[t], c, e):
                    return True
        else:
            stack[top] = children[k, LEFT]
            stack[top + 1] = children[k, RIGHT]
            top += 2
    return False


@njit(cache=True, error_model="numpy")
def _winding(T: np.ndarray, p: np.ndarray) -> float:
    """The generalised winding number of the closed triangle soup T (m, 3, 3) at p: 1 inside, 0 outside (van
    Oosterom and Strackee's solid angle of each triangle, summed over 4 pi)."""
    total = 0.0
    for t in range(T.shape[0]):
        ax, ay, az = T[t, 0, 0] - p[0], T[t, 0, 1] - p[1], T[t, 0, 2] - p[2]
        bx, by, bz = T[t, 1, 0] - p[0], T[t, 1, 1] - p[1], T[t, 1, 2] - p[2]
        cx, cy, cz = T[t, 2, 0] - p[0], T[t, 2, 1] - p[1], T[t, 2, 2] - p[2]
        la = np.sqrt(ax * ax + ay * ay + az * az)
        lb = np.sqrt(bx * bx + by * by + bz * bz)
        lc = np.sqrt(cx * cx + cy * cy + cz * cz)
        det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
        div = la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (ax * cx + ay * cy + az * cz) * lb
        div += (bx * cx + by * cy + bz * cz) * la
        total += 2.0 * np.arctan2(det, div)
    return total / (4.0 * np.pi)


def _grow(tree: TriangleTree, lo: np.ndarray, hi: np.ndarray, limit_lo: np.ndarray, limit_hi: np.ndarray) -> None:
    """Push each face of the box [lo, hi] outwards, in turn, as far as no triangle meets it (bisection to 1e-4 of
    the room left), in place."""
    for face in range(6):
        axis, up = face // 2, face % 2 == 1
        ok, bad = 0.0, (limit_hi[axis] - hi[axis]) if up else (lo[axis] - limit_lo[axis])
        for _ in range(24):
            if bad - ok <= 1e-4 * max(bad, 1e-12):
                break
            mid = 0.5 * (ok + bad)
            tl, th = lo.copy(), hi.copy()
            if up:
                th[axis] += mid
            else:
                tl[axis] -= mid
            if _box_meets_tree(tree, 0.5 * (tl + th), 0.5 * (th - tl)):
                bad = mid
            else:
                ok = mid
        if up:
            hi[axis] += ok
        else:
            lo[axis] -= ok


def inner_boxes(tree: MeshTree, vertices: np.ndarray, grid: int = 10, most: int = 3) -> tuple[Cuboid, ...]:
    """Up to `most` large boxes wholly inside the closed mesh, together covering most of it: greedily, each grown
    (a cube first, then face by face, twice) from the grid point inside the mesh (winding number) with the most room
    around it among those no earlier box covers; a box is kept while it covers at least a tenth of the inside grid
    points that the earlier ones leave out. Each box is checked at the end: no triangle meets it and its centre is
    inside, so it lies in the solid. Empty when the mesh has no room at the grid's resolution."""
    rec = tree.record()
    if len(tree) == 0:
        return ()
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    span = hi - lo
    axes = [lo[a] + span[a] * (np.arange(grid) + 0.5) / grid for a in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = np.array([p for p in pts if _winding(rec.triangles, p) > 0.5]).reshape(-1, 3)
    if not len(inside):
        return ()
    # room around each inside point: the largest clear cube (bisection)
    room = np.zeros(len(inside))
    for n, p in enumerate(inside):
        ok, bad = 0.0, float(span.max())
        for _ in range(16):
            mid = 0.5 * (ok + bad)
            if _box_meets_tree(rec, p, np.full(3, mid)):
                bad = mid
            else:
                ok = mid
        room[n] = ok
    boxes: list[Cuboid] = []
    covered = np.zeros(len(inside), dtype=bool)
    while len(boxes) < most:
        left = np.flatnonzero(~covered & (room > 0.0))
        if not len(left):
            break
        k = left[np.argmax(room[left])]
        b_lo, b_hi = inside[k] - room[k], inside[k] + room[k]
        for _ in range(2):
            _grow(rec, b_lo, b_hi, lo, hi)
        centre = 0.5 * (b_lo + b_hi)
        if _box_meets_tree(rec, centre, 0.5 * (b_hi - b_lo)) or _winding(rec.triangles, centre) <= 0.5:
            room[k] = 0.0  # a box that fails its check is not grown from here again
            continue
        now = np.all((inside >= b_lo) & (inside <= b_hi), axis=1)
        gain = int(np.count_nonzero(now & ~covered))
        if boxes and gain < 0.1 * int(np.count_nonzero(~covered)):
            break
        covered |= now
        covered[k] = True
        boxes.append(Cuboid(cast(Vec3, tuple(float(v) for v in b_lo)), cast(Vec3, tuple(float(v) for v in b_hi))))
    return tuple(boxes)
