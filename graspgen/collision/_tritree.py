"""The part's triangles in a bounding-volume tree, and the exact tests of a triangle: against a box
(Akenine-Moeller's separating axes), against a mesh solid swept along X, and a point's distance to it.

The tree: a binary tree over triangle centroids, split at the median of the longest axis, at most LEAF triangles
per leaf; per node an axis-aligned box, a ball and an oriented box (columns M_*), and for nodes of at most
EXACT_TRIANGLES triangles their distinct vertices. `normal_spread_rad`: for each sample point, the largest angle
between its normal and the normal of a triangle within a distance (criterion (c)'s position tolerance).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit, prange

__all__ = [
    "MeshTree",
    "TriangleTree",
    "build_tree",
    "empty_tree",
    "normal_spread_rad",
    "tri_box",
    "prism_meets_triangle",
    "tri_meets_solid",
    "node_misses_box",
    "triangles_near_segment",
]

LEAF = 4
#: nodes of at most this many triangles keep their distinct vertices, for the exact range along the axis (_walk)
EXACT_TRIANGLES = 64

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
    centroids along the longest axis of their extent, at most LEAF triangles per leaf; leaves have left = -1.
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
        if b0 - a0 <= LEAF:
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


# -- a part's triangle against a mesh solid, swept along X -------------------------------------------------------


@njit(cache=True, inline="always", error_model="numpy")
def node_misses_box(nodes: np.ndarray, k: int, lo: tuple[float, float, float], hi: tuple[float, float, float]) -> bool:
    """Does node k's axis-aligned box lie wholly outside the box [lo, hi] (closed)?"""
    return bool(
        nodes[k, M_C] + nodes[k, M_H] < lo[0]
        or nodes[k, M_C] - nodes[k, M_H] > hi[0]
        or nodes[k, M_C + 1] + nodes[k, M_H + 1] < lo[1]
        or nodes[k, M_C + 1] - nodes[k, M_H + 1] > hi[1]
        or nodes[k, M_C + 2] + nodes[k, M_H + 2] < lo[2]
        or nodes[k, M_C + 2] - nodes[k, M_H + 2] > hi[2]
    )


@njit(cache=True, inline="always", error_model="numpy")
def _separates(A: np.ndarray, L: float, B: np.ndarray, dx: float, dy: float, dz: float, g: float) -> bool:
    """Does the axis d separate the prism conv(A, A - L X) from the triangle B by more than g |d|?"""
    a0 = A[0, 0] * dx + A[0, 1] * dy + A[0, 2] * dz
    a1 = A[1, 0] * dx + A[1, 1] * dy + A[1, 2] * dz
    a2 = A[2, 0] * dx + A[2, 1] * dy + A[2, 2] * dz
    a_lo, a_hi = min(a0, a1, a2), max(a0, a1, a2)
    shift = L * dx
    p_lo, p_hi = min(a_lo, a_lo - shift), max(a_hi, a_hi - shift)
    b0 = B[0, 0] * dx + B[0, 1] * dy + B[0, 2] * dz
    b1 = B[1, 0] * dx + B[1, 1] * dy + B[1, 2] * dz
    b2 = B[2, 0] * dx + B[2, 1] * dy + B[2, 2] * dz
    b_lo, b_hi = min(b0, b1, b2), max(b0, b1, b2)
    tol = g * np.sqrt(dx * dx + dy * dy + dz * dz)
    apart: bool = p_hi < b_lo - tol or b_hi < p_lo - tol
    return apart


@njit(cache=True, error_model="numpy")
def prism_meets_triangle(A: np.ndarray, L: float, B: np.ndarray, g: float) -> bool:
    """Does the prism conv(A, A - L X) (A (3, 3), L >= 0: the triangle swept along -X) meet the triangle B (3, 3),
    closed, within the guard band g? The separating-axis test over both shapes' face normals (A's normal, the
    prism's side faces e_A x X, B's normal and its in-plane edge normals, A's in-plane edge normals and n_A x X for a
    flat prism) and every pair of edges (A's edges and X against B's edges): two convex shapes are apart exactly when
    one of these separates them. An axis of length 0 never separates."""
    e = np.empty((3, 3))
    f = np.empty((3, 3))
    for i in range(3):
        j = (i + 1) % 3
        for c in range(3):
            e[i, c] = A[j, c] - A[i, c]
            f[i, c] = B[j, c] - B[i, c]
    nax = e[0, 1] * e[1, 2] - e[0, 2] * e[1, 1]
    nay = e[0, 2] * e[1, 0] - e[0, 0] * e[1, 2]
    naz = e[0, 0] * e[1, 1] - e[0, 1] * e[1, 0]
    nbx = f[0, 1] * f[1, 2] - f[0, 2] * f[1, 1]
    nby = f[0, 2] * f[1, 0] - f[0, 0] * f[1, 2]
    nbz = f[0, 0] * f[1, 1] - f[0, 1] * f[1, 0]
    if _separates(A, L, B, nax, nay, naz, g) or _separates(A, L, B, nbx, nby, nbz, g):
        return False
    # n_A x X = (0, naz, -nay): the flat prism's in-plane normal along the sweep
    if _separates(A, L, B, 0.0, naz, -nay, g):
        return False
    for i in range(3):
        # e_A x X = (0, e_z, -e_y) and f_B x X
        if _separates(A, L, B, 0.0, e[i, 2], -e[i, 1], g):
            return False
        if _separates(A, L, B, 0.0, f[i, 2], -f[i, 1], g):
            return False
        # in-plane edge normals n x e
        if _separates(
            A,
            L,
            B,
            nay * e[i, 2] - naz * e[i, 1],
            naz * e[i, 0] - nax * e[i, 2],
            nax * e[i, 1] - nay * e[i, 0],
            g,
        ):
            return False
        if _separates(
            A,
            L,
            B,
            nby * f[i, 2] - nbz * f[i, 1],
            nbz * f[i, 0] - nbx * f[i, 2],
            nbx * f[i, 1] - nby * f[i, 0],
            g,
        ):
            return False
    for i in range(3):
        for j in range(3):
            dx = e[i, 1] * f[j, 2] - e[i, 2] * f[j, 1]
            dy = e[i, 2] * f[j, 0] - e[i, 0] * f[j, 2]
            dz = e[i, 0] * f[j, 1] - e[i, 1] * f[j, 0]
            if _separates(A, L, B, dx, dy, dz, g):
                return False
    return True


@njit(cache=True, error_model="numpy")
def tri_meets_solid(
    w: np.ndarray,
    solid: TriangleTree,
    side: int,
    s: float,
    L: float,
    g: float,
    A: np.ndarray,
    stack: np.ndarray,
) -> bool:
    """Does the part's triangle w (3, 3), in a roll's grasp frame, meet the mesh solid (a TriangleTree in its own
    frame) anywhere on the solid's travel? side +1: the +X finger, its frame at (s, 0, 0) at the contact end of the
    travel and moving outwards by L; side -1: the -X finger, at (-s, 0, 0) turned half a turn about Z; side 0: a
    fixed solid in the grasp frame (s and L are 0). A (3, 3) and stack (128,) are scratch arrays."""
    for c in range(3):
        if side > 0:
            A[c, 0], A[c, 1], A[c, 2] = w[c, 0] - s, w[c, 1], w[c, 2]
        elif side < 0:
            A[c, 0], A[c, 1], A[c, 2] = -w[c, 0] - s, -w[c, 1], w[c, 2]
        else:
            A[c, 0], A[c, 1], A[c, 2] = w[c, 0], w[c, 1], w[c, 2]
    # the prism's box: x from min - L to max
    lo0, hi0 = min(A[0, 0], A[1, 0], A[2, 0]) - L - g, max(A[0, 0], A[1, 0], A[2, 0]) + g
    lo1, hi1 = min(A[0, 1], A[1, 1], A[2, 1]) - g, max(A[0, 1], A[1, 1], A[2, 1]) + g
    lo2, hi2 = min(A[0, 2], A[1, 2], A[2, 2]) - g, max(A[0, 2], A[1, 2], A[2, 2]) + g
    nodes, children, T = solid.nodes, solid.children, solid.triangles
    if nodes.shape[0] == 0:
        return False
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        k = stack[top]
        if node_misses_box(nodes, k, (lo0, lo1, lo2), (hi0, hi1, hi2)):
            continue
        if children[k, LEFT] < 0:
            for t in range(children[k, START], children[k, START] + children[k, COUNT]):
                if prism_meets_triangle(A, L, T[t], g):
                    return True
        else:
            stack[top] = children[k, LEFT]
            stack[top + 1] = children[k, RIGHT]
            top += 2
    return False


# -- triangles near a segment (the suction cup's axis) ----------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def triangles_near_segment(
    tree: TriangleTree,
    p: tuple[float, float, float],
    q: tuple[float, float, float],
    radius: float,
    out: np.ndarray,
    stack: np.ndarray,
) -> int:
    """Indices (into tree.triangles) of every triangle within `radius` of the segment p..q, and possibly more, into
    `out` (capacity: the tree's triangle count); returns how many. A node is skipped when its ball (centre, radius
    M_R, which holds its triangles) lies farther than `radius` from the segment: a sound prune, so the caller's exact
    test of the listed triangles decides. `stack`: scratch of at least 128 entries."""
    nodes, children = tree.nodes, tree.children
    if nodes.shape[0] == 0:
        return 0
    dx, dy, dz = q[0] - p[0], q[1] - p[1], q[2] - p[2]
    dd = dx * dx + dy * dy + dz * dz
    n = 0
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        k = stack[top]
        cx, cy, cz = nodes[k, M_C] - p[0], nodes[k, M_C + 1] - p[1], nodes[k, M_C + 2] - p[2]
        t = 0.0
        if dd > 0.0:
            t = min(max((cx * dx + cy * dy + cz * dz) / dd, 0.0), 1.0)
        ex, ey, ez = cx - t * dx, cy - t * dy, cz - t * dz
        reach = radius + nodes[k, M_R]
        if ex * ex + ey * ey + ez * ez > reach * reach:
            continue
        if children[k, LEFT] < 0:
            for tri in range(children[k, START], children[k, START] + children[k, COUNT]):
                out[n] = tri
                n += 1
        else:
            stack[top] = children[k, LEFT]
            stack[top + 1] = children[k, RIGHT]
            top += 2
    return n


def empty_tree() -> TriangleTree:
    """A TriangleTree without triangles (the kernels' placeholder for a solid that is not there)."""
    return TriangleTree(
        np.zeros((0, 3, 3)),
        np.zeros(1, dtype=np.int64),
        np.zeros((3, 0)),
        np.zeros((0, _NODE)),
        np.zeros((0, 4), dtype=np.int64),
    )
