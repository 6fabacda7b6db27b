"""The part's own triangles: a bounding-volume tree over them and the exact queries that the sampled points cannot
answer.

- `normal_spread_rad`: for each sample point, the largest angle between its normal and the normal of any triangle
  within `position_tolerance` of it. Criterion (c) with a position tolerance then asks the friction cone to hold
  for every one of them: a contact on or next to an edge is not taken for a point on a face.
- `mesh_free_rolls`: criterion (d) against the triangles themselves. The point test can miss a feature that falls
  between samples; here every roll the point test left free is tested again, exactly, with the same regions: a roll
  stays free only when no triangle meets any region at that roll (closed boxes; the separating-axis test of a
  triangle against a box, Akenine-Moeller).

Exactness: every node test only prunes, with a guard band (Tolerances.guard of the part's size) far beyond rounding;
the answer is the triangle test's, so the masks are those of testing every triangle at every roll
(tests/graspgen/test_kernels.py checks that by brute force). How the walk prunes: docs/design/collision.md.
"""

from __future__ import annotations

from collections import namedtuple
from typing import TYPE_CHECKING

import numba
import numpy as np
from numba import njit, prange

from ..params import TOLERANCES
from ._frame import (
    candidate_count,
    candidate_frame,
    candidates_of_geometry,
    candidates_of_pairs,
    roll0_basis,
    roll_table,
)
from ._regions import (
    FINGER_ROWS,
    HY,
    RMAX,
    RMIN,
    YC,
    ZHI,
    ZLO,
    CollisionModel,
    finger_x_ranges,
    fixed_x_ranges,
    region_table,
)

if TYPE_CHECKING:
    from ._frame import Candidates, Rolls
    from ._regions import Regions

__all__ = ["MeshTree", "build_tree", "normal_spread_rad", "mesh_free_rolls", "mesh_free_rolls_of_pairs"]

#: at most this many triangles per leaf
_LEAF = 4
#: candidates per unit of parallel work
_CHUNK = 256
#: nodes of at most this many triangles keep their distinct vertices, for the exact range along the axis (_walk)
EXACT_TRIANGLES = 64
#: per size class above the leaves, that range is taken while it has turned a finger away at least at every other
#: try (counted per thread and chunk, after the first _EXACT_TRIES tries)
_EXACT_TRIES = 32

# A node's columns: the axis-aligned box's centre, the radius of the ball around that centre holding the node's
# triangles, the box's half extents, (unused), then the oriented box of the node's vertices: centre, three unit axes
# as rows (principal first), half extents. The oriented box is not padded: the queries pad.
M_C, M_R, M_H, M_OC, M_OAX, M_OH = 0, 3, 4, 8, 11, 20
_NODE = 23
# A node's links: children (-1: a leaf) and its triangles [START, START + COUNT) of the tree's order.
LEFT, RIGHT, START, COUNT = 0, 1, 2, 3

#: the tree as the kernels read it: triangles (m, 3, 3), verts (3, total) with vstart (nodes + 1,) (a node's
#: distinct vertices), nodes (k, _NODE), children (k, 4).
TriangleTree = namedtuple("TriangleTree", ["triangles", "vstart", "verts", "nodes", "children"])
#: a thread's working arrays of the mesh-exact walk: F (12,) the candidate's midpoint, X, Y0, Z0; rx (r, 2) the
#: regions' bounds along X; boxes_c, boxes_e (r, 3) their centres and half extents in a roll's grasp frame; rot
#: (R, 6) each roll's Y and Z in the object frame; tri (2, 3, 3) a triangle in the roll-0 frame and at a roll; stack
#: (128,) nodes; masks (128, r) per stack entry and region the rolls to test; hit (r,); ob (15,) a node's oriented box
#: in the roll-0 frame; tally (8, 2) per size class the exact ranges taken and the fingers they turned away.
MeshWork = namedtuple(
    "MeshWork", ["F", "rx", "boxes_c", "boxes_e", "rot", "tri", "stack", "masks", "hit", "ob", "tally"]
)


class MeshTree:
    """Triangles (m, 3, 3) metres, their unit normals (m, 3), and the tree's arrays (see `build_tree`): per node the
    box data (columns M_*) and (left, right, start, count); for nodes of at most `EXACT_TRIANGLES` triangles their
    distinct vertices, verts[:, vstart[k]:vstart[k + 1]] (3, .) (none for larger nodes)."""

    def __init__(
        self,
        triangles: np.ndarray,
        normals: np.ndarray,
        nodes: np.ndarray,
        children: np.ndarray,
        vstart: np.ndarray,
        verts: np.ndarray,
    ) -> None:
        self.triangles = triangles
        self.normals = normals
        self.nodes = nodes
        self.children = children
        self.vstart = vstart
        self.verts = verts

    def __len__(self) -> int:
        return len(self.triangles)

    def record(self) -> TriangleTree:
        """The arrays the kernels read."""
        return TriangleTree(self.triangles, self.vstart, self.verts, self.nodes, self.children)


def build_tree(vertices: np.ndarray, faces: np.ndarray) -> MeshTree:
    """A tree over the mesh's non-degenerate triangles. `vertices` (v, 3) float64 metres, `faces` (m, 3) int."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    tri = V[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(n, axis=1)
    keep = area2 > 1e-20
    tri, n, area2 = tri[keep], n[keep], area2[keep]
    n = n / area2[:, None]
    m = len(tri)
    max_nodes = 2 * m + 1
    order = np.arange(m, dtype=np.int64)
    nodes = np.zeros((max_nodes, _NODE), dtype=np.float64)
    children = np.zeros((max_nodes, 4), dtype=np.int64)
    count = _build(np.ascontiguousarray(tri), order, nodes, children) if m else 0
    tri = np.ascontiguousarray(tri[order])
    n = np.ascontiguousarray(n[order])
    children = children[:count].copy()
    vstart, verts = _node_vertices(np.ascontiguousarray(F[keep][order]), V, children, EXACT_TRIANGLES)
    return MeshTree(tri, n, nodes[:count].copy(), children, vstart, verts)


@njit(cache=True)
def _node_vertices(
    faces: np.ndarray, V: np.ndarray, children: np.ndarray, max_triangles: int
) -> tuple[np.ndarray, np.ndarray]:
    """The distinct vertices (by index) of each node of at most `max_triangles` triangles, in (3, total) SoA with
    offsets per node: a stamp per vertex index marks the ones a node has listed already."""
    nn = children.shape[0]
    vstart = np.zeros(nn + 1, dtype=np.int64)
    stamp = np.full(V.shape[0], -1, dtype=np.int64)
    for k in range(nn):
        c = 0
        if children[k, COUNT] <= max_triangles:
            for t in range(children[k, START], children[k, START] + children[k, COUNT]):
                for j in range(3):
                    v = faces[t, j]
                    if stamp[v] != k:
                        stamp[v] = k
                        c += 1
        vstart[k + 1] = vstart[k] + c
    verts = np.empty((3, vstart[nn]))
    stamp[:] = -1
    for k in range(nn):
        q = vstart[k]
        if children[k, COUNT] <= max_triangles:
            for t in range(children[k, START], children[k, START] + children[k, COUNT]):
                for j in range(3):
                    v = faces[t, j]
                    if stamp[v] != k:
                        stamp[v] = k
                        verts[0, q], verts[1, q], verts[2, q] = V[v, 0], V[v, 1], V[v, 2]
                        q += 1
    return vstart, verts


@njit(cache=True)
def _build(T: np.ndarray, order: np.ndarray, nodes: np.ndarray, children: np.ndarray) -> int:
    """Fill nodes[k] (columns M_*) and children[k] = (left, right, start, count) by median splits of the triangles'
    centroids along the longest axis of their extent, at most _LEAF triangles per leaf; leaves have left = -1.
    Returns the node count. The oriented box suits the long thin triangles of curved walls (an arc's axis-aligned
    box sticks out far beyond it)."""
    m = T.shape[0]
    cen = np.empty((m, 3))
    for t in range(m):
        for a in range(3):
            cen[t, a] = (T[t, 0, a] + T[t, 1, a] + T[t, 2, a]) / 3.0
    stack = np.empty((128, 3), dtype=np.int64)  # node, start, stop
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, m
    top = 1
    count = 1
    while top > 0:
        top -= 1
        k, a0, b0 = stack[top, 0], stack[top, 1], stack[top, 2]
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        clo = np.full(3, np.inf)
        chi = np.full(3, -np.inf)
        for q in range(a0, b0):
            t = order[q]
            for v in range(3):
                for a in range(3):
                    lo[a] = min(lo[a], T[t, v, a])
                    hi[a] = max(hi[a], T[t, v, a])
            for a in range(3):
                clo[a] = min(clo[a], cen[t, a])
                chi[a] = max(chi[a], cen[t, a])
        c = 0.5 * (lo + hi)
        r2 = 0.0
        for q in range(a0, b0):
            t = order[q]
            for v in range(3):
                d = (T[t, v, 0] - c[0]) ** 2 + (T[t, v, 1] - c[1]) ** 2 + (T[t, v, 2] - c[2]) ** 2
                r2 = max(r2, d)
        nodes[k, M_C], nodes[k, M_C + 1], nodes[k, M_C + 2] = c[0], c[1], c[2]
        nodes[k, M_R] = np.sqrt(r2) * (1.0 + 1e-12) + 1e-15
        for a in range(3):
            nodes[k, M_H + a] = 0.5 * (hi[a] - lo[a])
        _oriented_box(T, order, a0, b0, nodes[k])
        children[k, START], children[k, COUNT] = a0, b0 - a0
        if b0 - a0 <= _LEAF:
            children[k, LEFT], children[k, RIGHT] = -1, -1
            continue
        axis = 0
        if chi[1] - clo[1] > chi[axis] - clo[axis]:
            axis = 1
        if chi[2] - clo[2] > chi[axis] - clo[axis]:
            axis = 2
        seg = order[a0:b0]
        keys = cen[seg, axis]
        idx = np.argsort(keys, kind="mergesort")
        order[a0:b0] = seg[idx]
        mid = (a0 + b0) // 2
        left, right = count, count + 1
        count += 2
        children[k, LEFT], children[k, RIGHT] = left, right
        stack[top, 0], stack[top, 1], stack[top, 2] = left, a0, mid
        stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = right, mid, b0
        top += 2
    return count


@njit(cache=True)
def _oriented_box(T: np.ndarray, order: np.ndarray, a0: int, b0: int, out: np.ndarray) -> None:
    """The oriented box of the vertices of triangles T[order[a0:b0]] into out[M_OC:] (see _build): axes by principal
    components, bounds by projection."""
    cnt = 3 * (b0 - a0)
    mean = np.zeros(3)
    for q in range(a0, b0):
        for v in range(3):
            for a in range(3):
                mean[a] += T[order[q], v, a]
    mean /= cnt
    cov = np.zeros((3, 3))
    for q in range(a0, b0):
        for v in range(3):
            for a in range(3):
                for b in range(3):
                    cov[a, b] += (T[order[q], v, a] - mean[a]) * (T[order[q], v, b] - mean[b])
    _, V = np.linalg.eigh(cov)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for q in range(a0, b0):
        for v in range(3):
            for i in range(3):
                pr = 0.0
                for a in range(3):
                    pr += (T[order[q], v, a] - mean[a]) * V[a, 2 - i]
                lo[i] = min(lo[i], pr)
                hi[i] = max(hi[i], pr)
    for a in range(3):
        c = mean[a]
        for i in range(3):
            c += V[a, 2 - i] * 0.5 * (lo[i] + hi[i])
        out[M_OC + a] = c
    for i in range(3):
        for a in range(3):
            out[M_OAX + 3 * i + a] = V[a, 2 - i]
        out[M_OH + i] = 0.5 * (hi[i] - lo[i])


# -- normals within a distance -------------------------------------------------------------------------------------


def normal_spread_rad(tree: MeshTree, points: np.ndarray, normals: np.ndarray, tolerance: float) -> np.ndarray:
    """(k,) float64 radians: for each point, the largest angle between its normal and the normal of a triangle
    within `tolerance` metres of it (0 when only faces parallel to its own are near)."""
    P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    N = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(P), dtype=np.float64)
    if len(P) == 0 or len(tree) == 0 or tolerance <= 0:
        return out
    _spread_kernel(P, N, tree.triangles, tree.normals, tree.nodes, tree.children, float(tolerance), out)
    return out


@njit(parallel=True, cache=True, error_model="numpy")
def _spread_kernel(
    P: np.ndarray,
    N: np.ndarray,
    T: np.ndarray,
    TN: np.ndarray,
    nodes: np.ndarray,
    children: np.ndarray,
    tol: float,
    out: np.ndarray,
) -> None:
    for i in prange(P.shape[0]):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        lowest = 1.0
        stack = np.empty(64, dtype=np.int64)
        stack[0] = 0
        top = 1
        while top > 0:
            top -= 1
            k = stack[top]
            dx = abs(px - nodes[k, M_C]) - nodes[k, M_H]
            dy = abs(py - nodes[k, M_C + 1]) - nodes[k, M_H + 1]
            dz = abs(pz - nodes[k, M_C + 2]) - nodes[k, M_H + 2]
            d2 = max(dx, 0.0) ** 2 + max(dy, 0.0) ** 2 + max(dz, 0.0) ** 2
            if d2 > tol * tol:
                continue
            if children[k, LEFT] < 0:
                for t in range(children[k, START], children[k, START] + children[k, COUNT]):
                    dot = TN[t, 0] * N[i, 0] + TN[t, 1] * N[i, 1] + TN[t, 2] * N[i, 2]
                    if dot >= lowest:
                        continue
                    if _point_triangle_dist2(px, py, pz, T, t) <= tol * tol:
                        lowest = dot
            else:
                stack[top] = children[k, LEFT]
                stack[top + 1] = children[k, RIGHT]
                top += 2
        out[i] = np.arccos(max(-1.0, min(1.0, lowest)))


@njit(cache=True, inline="always", error_model="numpy")
def _point_triangle_dist2(px: float, py: float, pz: float, T: np.ndarray, t: int) -> float:
    """Squared distance from p to triangle t (Ericson, Real-Time Collision Detection 5.1.5)."""
    ax, ay, az = T[t, 0, 0], T[t, 0, 1], T[t, 0, 2]
    bx, by, bz = T[t, 1, 0], T[t, 1, 1], T[t, 1, 2]
    cx, cy, cz = T[t, 2, 0], T[t, 2, 1], T[t, 2, 2]
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        qx, qy, qz = ax, ay, az
    else:
        bpx, bpy, bpz = px - bx, py - by, pz - bz
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        cpx, cpy, cpz = px - cx, py - cy, pz - cz
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            qx, qy, qz = bx, by, bz
        elif d6 >= 0.0 and d5 <= d6:
            qx, qy, qz = cx, cy, cz
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            v = d1 / (d1 - d3)
            qx, qy, qz = ax + v * abx, ay + v * aby, az + v * abz
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            w = d2 / (d2 - d6)
            qx, qy, qz = ax + w * acx, ay + w * acy, az + w * acz
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            qx, qy, qz = bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
        else:
            denom = 1.0 / (va + vb + vc)
            v = vb * denom
            w = vc * denom
            qx, qy, qz = ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w
    dist2: float = (px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2
    return dist2


# -- regions against triangles ---------------------------------------------------------------------------------------


@njit(cache=True, inline="always", error_model="numpy")
def _axis_test(p0: float, p1: float, p2: float, r: float) -> bool:
    return min(p0, p1, p2) > r or max(p0, p1, p2) < -r


@njit(cache=True, error_model="numpy")
def tri_box(v: np.ndarray, c: np.ndarray, e: np.ndarray) -> bool:
    """Does the triangle v (3, 3) meet the closed axis-aligned box with centre c (3,) and half extents e (3,)?
    (Akenine-Moeller's separating-axis test: the box's 3 axes, the triangle's normal, 9 edge cross products.)"""
    x0, y0, z0 = v[0, 0] - c[0], v[0, 1] - c[1], v[0, 2] - c[2]
    x1, y1, z1 = v[1, 0] - c[0], v[1, 1] - c[1], v[1, 2] - c[2]
    x2, y2, z2 = v[2, 0] - c[0], v[2, 1] - c[1], v[2, 2] - c[2]
    ex, ey, ez = e[0], e[1], e[2]
    if min(x0, x1, x2) > ex or max(x0, x1, x2) < -ex:
        return False
    if min(y0, y1, y2) > ey or max(y0, y1, y2) < -ey:
        return False
    if min(z0, z1, z2) > ez or max(z0, z1, z2) < -ez:
        return False
    # edges
    for k in range(3):
        if k == 0:
            fx, fy, fz = x1 - x0, y1 - y0, z1 - z0
        elif k == 1:
            fx, fy, fz = x2 - x1, y2 - y1, z2 - z1
        else:
            fx, fy, fz = x0 - x2, y0 - y2, z0 - z2
        # a = ex_axis x f = (0, -fz, fy)
        r = ey * abs(fz) + ez * abs(fy)
        if _axis_test(-fz * y0 + fy * z0, -fz * y1 + fy * z1, -fz * y2 + fy * z2, r):
            return False
        # a = ey_axis x f = (fz, 0, -fx)
        r = ex * abs(fz) + ez * abs(fx)
        if _axis_test(fz * x0 - fx * z0, fz * x1 - fx * z1, fz * x2 - fx * z2, r):
            return False
        # a = ez_axis x f = (-fy, fx, 0)
        r = ex * abs(fy) + ey * abs(fx)
        if _axis_test(-fy * x0 + fx * y0, -fy * x1 + fx * y1, -fy * x2 + fx * y2, r):
            return False
    # the triangle's plane
    nx = (y1 - y0) * (z2 - z0) - (z1 - z0) * (y2 - y0)
    ny = (z1 - z0) * (x2 - x0) - (x1 - x0) * (z2 - z0)
    nz = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
    d = nx * x0 + ny * y0 + nz * z0
    r = ex * abs(nx) + ey * abs(ny) + ez * abs(nz)
    meets: bool = abs(d) <= r
    return meets


@njit(cache=True, inline="always", error_model="numpy")
def _node_meets_box(
    nd: np.ndarray,
    q: tuple[float, float, float],
    X: tuple[float, float, float],
    rot_k: np.ndarray,
    cs: tuple[float, float],
    box: tuple[float, float, float, float, float, float],
    g: float,
) -> bool:
    """May the node's axis-aligned box meet a region's box at a roll? q = (x, y0, z0): the node's centre in the
    candidate's roll-0 frame; X: the closing axis; rot_k (6,): the roll's Y and Z in the object frame; cs = (cos,
    sin) of the roll; box = (centre x, half x, centre y, half y, centre z, half z) of the region in the roll's grasp
    frame. Separating axes: the region's Y and Z and the world's three, each with the guard band g (the caller has
    tested X; the nine cross axes are left out: a node that passes is only descended into)."""
    ex, ey, ez = nd[M_H], nd[M_H + 1], nd[M_H + 2]
    ax, ay, az = X
    c, s = cs
    bcx, bex, bcy, bey, bcz, bez = box
    Yx, Yy, Yz, Zx, Zy, Zz = rot_k[0], rot_k[1], rot_k[2], rot_k[3], rot_k[4], rot_k[5]
    # the node's centre relative to the region's centre, along the region's axes
    dX = q[0] - bcx
    dY = q[1] * c + q[2] * s - bcy
    dZ = -q[1] * s + q[2] * c - bcz
    if abs(dY) > bey + ex * abs(Yx) + ey * abs(Yy) + ez * abs(Yz) + g:
        return False
    if abs(dZ) > bez + ex * abs(Zx) + ey * abs(Zy) + ez * abs(Zz) + g:
        return False
    # along the world's axes: the offset in the object frame
    wx = dX * ax + dY * Yx + dZ * Zx
    wy = dX * ay + dY * Yy + dZ * Zy
    wz = dX * az + dY * Yz + dZ * Zz
    if abs(wx) > ex + bex * abs(ax) + bey * abs(Yx) + bez * abs(Zx) + g:
        return False
    if abs(wy) > ey + bex * abs(ay) + bey * abs(Yy) + bez * abs(Zy) + g:
        return False
    meets: bool = abs(wz) <= ez + bex * abs(az) + bey * abs(Yz) + bez * abs(Zz) + g
    return meets


@njit(cache=True, inline="always", error_model="numpy")
def _obb_meets_box(
    ob: np.ndarray, cs: tuple[float, float], box: tuple[float, float, float, float, float, float], g: float
) -> bool:
    """May the node's oriented box meet a region's box at a roll? ob: the node's oriented box in the candidate's
    roll-0 frame (centre x, y0, z0, then per box axis i its components along X, Y0, Z0 and its half extent:
    ob[3 + 4 i : 7 + 4 i]); cs, box as for _node_meets_box. Separating axes: the region's Y and Z and the box's own
    three, each with the guard band g (X: the caller cut the region to the node's slab)."""
    c, s = cs
    bcx, bex, bcy, bey, bcz, bez = box
    dX = ob[0] - bcx
    dY = ob[1] * c + ob[2] * s - bcy
    dZ = -ob[1] * s + ob[2] * c - bcz
    sy = 0.0
    sz = 0.0
    for i in range(3):
        pX, pY, pZ, e = ob[3 + 4 * i], ob[4 + 4 * i], ob[5 + 4 * i], ob[6 + 4 * i]
        uY = pY * c + pZ * s
        uZ = -pY * s + pZ * c
        sy += e * abs(uY)
        sz += e * abs(uZ)
        if abs(dX * pX + dY * uY + dZ * uZ) > e + bex * abs(pX) + bey * abs(uY) + bez * abs(uZ) + g:
            return False
    meets: bool = abs(dY) <= bey + sy + g and abs(dZ) <= bez + sz + g
    return meets


@njit(cache=True, inline="always", error_model="numpy")
def _oriented_in_frame(nd: np.ndarray, F: np.ndarray, ob: np.ndarray) -> None:
    """The node's oriented box in the candidate's roll-0 frame (F: midpoint, X, Y0, Z0) into ob (_obb_meets_box)."""
    qx, qy, qz = nd[M_OC] - F[0], nd[M_OC + 1] - F[1], nd[M_OC + 2] - F[2]
    ob[0] = qx * F[3] + qy * F[4] + qz * F[5]
    ob[1] = qx * F[6] + qy * F[7] + qz * F[8]
    ob[2] = qx * F[9] + qy * F[10] + qz * F[11]
    for i in range(3):
        ux, uy, uz = nd[M_OAX + 3 * i], nd[M_OAX + 1 + 3 * i], nd[M_OAX + 2 + 3 * i]
        ob[3 + 4 * i] = ux * F[3] + uy * F[4] + uz * F[5]
        ob[4 + 4 * i] = ux * F[6] + uy * F[7] + uz * F[8]
        ob[5 + 4 * i] = ux * F[9] + uy * F[10] + uz * F[11]
        ob[6 + 4 * i] = nd[M_OH + i]


@njit(cache=True, inline="always", error_model="numpy")
def _vertex_x_range(verts: np.ndarray, q0: int, q1: int, F: np.ndarray) -> tuple[float, float]:
    """The smallest and largest coordinate along the closing axis of verts[:, q0:q1], with the triangle loop's own
    arithmetic (_walk)."""
    lo = np.inf
    hi = -np.inf
    for q in range(q0, q1):
        v = (verts[0, q] - F[0]) * F[3] + (verts[1, q] - F[1]) * F[4] + (verts[2, q] - F[2]) * F[5]
        lo = min(lo, v)
        hi = max(hi, v)
    return lo, hi


@njit(cache=True, inline="always", error_model="numpy")
def _meets_finger_slab(
    masks: np.ndarray, top: int, blocked: np.uint64, rx: np.ndarray, x_lo: float, x_hi: float
) -> bool:
    """Does [x_lo, x_hi] meet the slab of a finger region that still has rolls to test at stack entry `top`?"""
    for r in range(FINGER_ROWS):  # noqa: SIM110 (numba compiles no generator passed to any())
        if masks[top, r] & ~blocked and rx[r, 0] <= x_hi and x_lo <= rx[r, 1]:
            return True
    return False


@njit(cache=True, error_model="numpy")
def _walk(todo: np.uint64, tree: TriangleTree, regions: Regions, rolls: Rolls, g: float, work: MeshWork) -> np.uint64:
    """The rolls of `todo` at which some triangle meets some region, for the candidate in work.F (midpoint, X, Y0,
    Z0) with its regions in work.rx, work.boxes_c, work.boxes_e: one walk of the tree carrying, per region, the rolls
    still to test. Its own function, called from the parallel loop (inlined in the loop's body it ran slower)."""
    F, rx, boxes_c, boxes_e, rot = work.F, work.rx, work.boxes_c, work.boxes_e, work.rot
    stack, masks, hit, ob, tally = work.stack, work.masks, work.hit, work.ob, work.tally
    T, vstart, verts, nodes, children = tree.triangles, tree.vstart, tree.verts, tree.nodes, tree.children
    rows = regions.rows
    cos_k, sin_k = rolls.cos, rolls.sin
    R = cos_k.shape[0]
    nreg = rows.shape[0]
    mx, my, mz = F[0], F[1], F[2]
    ax, ay, az, yx, yy, yz, zx, zy, zz = F[3], F[4], F[5], F[6], F[7], F[8], F[9], F[10], F[11]
    v = work.tri[0]
    w = work.tri[1]
    blocked = np.uint64(0)
    stack[0] = 0
    for r in range(nreg):
        masks[0, r] = todo
    top = 1
    while top > 0:
        top -= 1
        k = stack[top]
        nd = nodes[k]
        live_any = np.uint64(0)
        for r in range(nreg):
            live_any |= masks[top, r]
        if live_any & ~blocked == 0:
            continue
        # the node's x range along the closing axis (the tighter of its two boxes and its ball), its centre's
        # distance from the axis, in the roll-0 frame
        qx = nd[M_C] - mx
        qy = nd[M_C + 1] - my
        qz = nd[M_C + 2] - mz
        x = qx * ax + qy * ay + qz * az
        y0 = qx * yx + qy * yy + qz * yz
        z0 = qx * zx + qy * zy + qz * zz
        rad = nd[M_R]
        rc = np.sqrt(y0 * y0 + z0 * z0)
        xh = min(nd[M_H] * abs(ax) + nd[M_H + 1] * abs(ay) + nd[M_H + 2] * abs(az), rad)
        ox = (nd[M_OC] - mx) * ax + (nd[M_OC + 1] - my) * ay + (nd[M_OC + 2] - mz) * az
        oh = (
            nd[M_OH] * abs(nd[M_OAX] * ax + nd[M_OAX + 1] * ay + nd[M_OAX + 2] * az)
            + nd[M_OH + 1] * abs(nd[M_OAX + 3] * ax + nd[M_OAX + 4] * ay + nd[M_OAX + 5] * az)
            + nd[M_OH + 2] * abs(nd[M_OAX + 6] * ax + nd[M_OAX + 7] * ay + nd[M_OAX + 8] * az)
        )
        x_lo = max(x - xh, ox - oh) - g
        x_hi = min(x + xh, ox + oh) + g
        inner = children[k, LEFT] >= 0
        if vstart[k + 1] > vstart[k] and _meets_finger_slab(masks, top, blocked, rx, x_lo, x_hi):
            # a small node whose boxes meet a finger's slab: the range of its own vertices instead. The boxes of a
            # curved patch stick out past a contact's margin where its triangles do not; the triangle loop below
            # skips a region by the same numbers, so this only prunes what it would skip. Above the leaves only
            # while it pays: per size class, while it turns a finger away at least at every other try
            cls = 0
            c = children[k, COUNT]
            while c > _LEAF:
                c >>= 1
                cls += 1
            if cls == 0 or tally[cls, 0] < _EXACT_TRIES or 2 * tally[cls, 1] >= tally[cls, 0]:
                e_lo, e_hi = _vertex_x_range(verts, vstart[k], vstart[k + 1], F)
                x_lo, x_hi = max(x_lo, e_lo - g), min(x_hi, e_hi + g)
                tally[cls, 0] += 1
                if not _meets_finger_slab(masks, top, blocked, rx, x_lo, x_hi):
                    tally[cls, 1] += 1
        any_hit = np.uint64(0)
        have_ob = False
        for r in range(nreg):
            hit[r] = 0
            live = masks[top, r] & ~blocked
            if live == 0:
                continue
            # roll-free tests first: the region's x range and its radial band around the axis
            lo, hi = max(rx[r, 0], x_lo), min(rx[r, 1], x_hi)
            if lo > hi:
                continue
            if rc + rad < rows[r, RMIN] or rc - rad > rows[r, RMAX]:
                continue
            if r < FINGER_ROWS and inner:
                # the fingers' boxes are small: their per-roll tests prune little above the leaves
                hit[r] = live
                any_hit |= live
                continue
            # per roll: the region cut to the node's slab along X, where all its triangles lie (the palm is a
            # stroke wide and its approach a part long: cut, it misses most nodes)
            box = (0.5 * (lo + hi), 0.5 * (hi - lo), boxes_c[r, 1], boxes_e[r, 1], boxes_c[r, 2], boxes_e[r, 2])
            h = np.uint64(0)
            for rl in range(R):
                bit = np.uint64(1) << np.uint64(rl)
                if not (live & bit):
                    continue
                cs = (cos_k[rl], sin_k[rl])
                if _node_meets_box(nd, (x, y0, z0), (ax, ay, az), rot[rl], cs, box, g):
                    # then the oriented box, which hugs the thin patches of curved walls and slanted faces
                    if not have_ob:
                        _oriented_in_frame(nd, F, ob)
                        have_ob = True
                    if _obb_meets_box(ob, cs, box, g):
                        h |= bit
            hit[r] = h
            any_hit |= h
        if any_hit == 0:
            continue
        if inner:
            stack[top] = children[k, LEFT]
            stack[top + 1] = children[k, RIGHT]
            for r in range(nreg):
                masks[top, r] = hit[r]
                masks[top + 1, r] = hit[r]
            top += 2
            continue
        for t in range(children[k, START], children[k, START] + children[k, COUNT]):
            # the triangle in the roll-0 frame
            for c in range(3):
                px = T[t, c, 0] - mx
                py = T[t, c, 1] - my
                pz = T[t, c, 2] - mz
                v[c, 0] = px * ax + py * ay + pz * az
                v[c, 1] = px * yx + py * yy + pz * yz
                v[c, 2] = px * zx + py * zy + pz * zz
            tx0 = min(v[0, 0], v[1, 0], v[2, 0])
            tx1 = max(v[0, 0], v[1, 0], v[2, 0])
            for r in range(nreg):
                if tx1 < rx[r, 0] or tx0 > rx[r, 1]:
                    continue
                for rl in range(R):
                    bit = np.uint64(1) << np.uint64(rl)
                    if not (hit[r] & bit & ~blocked):
                        continue
                    ck, sk = cos_k[rl], sin_k[rl]
                    for c in range(3):
                        w[c, 0] = v[c, 0]
                        w[c, 1] = v[c, 1] * ck + v[c, 2] * sk
                        w[c, 2] = -v[c, 1] * sk + v[c, 2] * ck
                    if tri_box(w, boxes_c[r], boxes_e[r]):
                        blocked |= bit
        if blocked == todo:
            break
    return blocked


@njit(cache=True, inline="always", error_model="numpy")
def region_boxes(regions: Regions, rx: np.ndarray, boxes_c: np.ndarray, boxes_e: np.ndarray) -> None:
    """The regions' boxes in a roll's grasp frame for one candidate, from their bounds along X in rx (r, 2):
    centres and half extents into boxes_c, boxes_e (r, 3)."""
    rows = regions.rows
    for r in range(rows.shape[0]):
        boxes_c[r, 0] = 0.5 * (rx[r, 0] + rx[r, 1])
        boxes_e[r, 0] = 0.5 * (rx[r, 1] - rx[r, 0])
        boxes_c[r, 1] = rows[r, YC]
        boxes_e[r, 1] = rows[r, HY]
        boxes_c[r, 2] = 0.5 * (rows[r, ZLO] + rows[r, ZHI])
        boxes_e[r, 2] = 0.5 * (rows[r, ZHI] - rows[r, ZLO])


@njit(parallel=True, cache=True, error_model="numpy")
def _mesh_kernel(
    cands: Candidates, free: np.ndarray, tree: TriangleTree, regions: Regions, rolls: Rolls, g: float, nthreads: int
) -> None:
    """Clear in free (n, R) bool every roll at which some triangle of the tree meets some region."""
    n = cands.inside.shape[0]
    R = rolls.cos.shape[0]
    nreg = regions.rows.shape[0]
    chunks = (n + _CHUNK - 1) // _CHUNK
    # thread t takes chunks t, t + T, ...: the work varies along the candidates' spatial order, and a static split
    # into one run per thread leaves one thread with most of it
    for t in prange(nthreads):
        work = MeshWork(
            np.empty(12),
            np.empty((nreg, 2)),
            np.empty((nreg, 3)),
            np.empty((nreg, 3)),
            np.empty((R, 6)),
            np.empty((2, 3, 3)),
            np.empty(128, dtype=np.int64),
            np.empty((128, nreg), dtype=np.uint64),
            np.empty(nreg, dtype=np.uint64),
            np.empty(15),
            np.zeros((8, 2), dtype=np.int64),
        )
        F, rot = work.F, work.rot
        fixed_x_ranges(work.rx, regions)
        for ch in range(t, chunks, nthreads):
            work.tally[:, :] = 0
            for i in range(ch * _CHUNK, min(n, (ch + 1) * _CHUNK)):
                todo = np.uint64(0)
                for k in range(R):
                    if free[i, k]:
                        todo |= np.uint64(1) << np.uint64(k)
                if todo == 0:
                    continue
                mx, my, mz, ax, ay, az, wd = candidate_frame(cands, i)
                yx, yy, yz, zx, zy, zz = roll0_basis(ax, ay, az, rolls.switch)
                for rl in range(R):
                    c, s = rolls.cos[rl], rolls.sin[rl]
                    rot[rl, 0], rot[rl, 1], rot[rl, 2] = c * yx + s * zx, c * yy + s * zy, c * yz + s * zz
                    rot[rl, 3], rot[rl, 4], rot[rl, 5] = -s * yx + c * zx, -s * yy + c * zy, -s * yz + c * zz
                finger_x_ranges(work.rx, cands.inside[i], wd, regions)
                region_boxes(regions, work.rx, work.boxes_c, work.boxes_e)
                F[0], F[1], F[2] = mx, my, mz
                F[3], F[4], F[5], F[6], F[7], F[8], F[9], F[10], F[11] = ax, ay, az, yx, yy, yz, zx, zy, zz
                blocked = _walk(todo, tree, regions, rolls, g, work)
                if blocked != 0:
                    for rl in range(R):
                        if blocked & (np.uint64(1) << np.uint64(rl)):
                            free[i, rl] = False


def mesh_free_rolls(
    tree: MeshTree,
    midpoints: np.ndarray,
    axes: np.ndarray,
    widths: np.ndarray,
    inside: np.ndarray,
    free: np.ndarray,
    model: CollisionModel,
    *,
    switch: float | None = None,
) -> np.ndarray:
    """The rolls of `free` (n, R) bool that stay free when the model's regions are tested against every triangle
    of `tree`. midpoints (n, 3), axes (n, 3) unit, widths (n,), inside (n,) bool: the candidates. Returns a new (n, R)
    bool array. `switch`: the roll-0 reference's threshold (default the contract's)."""
    return _run(tree, candidates_of_geometry(midpoints, axes, widths, inside), free, model, switch)


def mesh_free_rolls_of_pairs(
    tree: MeshTree,
    points: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    inside: np.ndarray,
    free: np.ndarray,
    model: CollisionModel,
    *,
    switch: float | None = None,
) -> np.ndarray:
    """mesh_free_rolls of the candidates (points[i], points[j]), contact 0 = points[i]: the same masks as
    mesh_free_rolls with midpoints 0.5 (p_i + p_j), axes d / |d| and widths |d| (d = p_j - p_i) made by numpy. The
    kernel derives them per candidate, so no (n, 3) arrays are made."""
    return _run(tree, candidates_of_pairs(points, i, j, inside), free, model, switch)


def _run(
    tree: MeshTree, cands: Candidates, free: np.ndarray, model: CollisionModel, switch: float | None
) -> np.ndarray:
    free = np.ascontiguousarray(free, dtype=bool)
    n, R = free.shape
    if candidate_count(cands) != n or len(cands.inside) != n:
        raise ValueError("the candidates' geometry, inside and free must have one row per candidate")
    out = free.copy()
    if n == 0 or len(tree) == 0:
        return out
    rolls = roll_table(R)
    if switch is not None:
        rolls = rolls._replace(switch=float(switch))
    # the node tests' guard band: far beyond the rounding of the boxes' bounds and of the tests themselves
    g = TOLERANCES.guard * 2.0 * float(np.max(tree.nodes[0, M_H : M_H + 3])) + TOLERANCES.guard_floor
    with numba.parallel_chunksize(1):
        _mesh_kernel(cands, out, tree.record(), region_table(model), rolls, g, numba.get_num_threads())
    return out
