"""The part's own triangles: a bounding-volume tree over them and the exact queries that the sampled points cannot
answer.

- `normal_spread_rad`: for each sample point, the largest angle between its normal and the normal of any triangle
  within `position_tolerance` of it. Criterion (c) with a position tolerance then asks the friction cone to hold
  for every one of them: a contact on or next to an edge is not taken for a point on a face.
- `mesh_free_rolls`: criterion (d) against the triangles themselves. The point test can miss a feature that falls
  between samples; here every roll the point test left free is tested again, exactly, with the same boxes: a roll
  stays free only when no triangle meets any of the gripper's boxes at that roll (closed boxes; separating-axis
  tests of triangle against box).

The tree: a binary tree over triangle centroids, split at the median of the longest axis, at most `_LEAF`
triangles per leaf; per node an axis-aligned box, a ball (centre, radius) and an oriented box (principal axes)
around its triangles. A query walks the tree once per candidate and carries, per region (the two fingers and
the palm with its approach), the set of rolls still to test there. At a node, per region: the node's x range
along the closing axis (the tightest of its two boxes and its ball: the oriented box hugs the long thin
triangles of a curved wall, whose axis-aligned box sticks out far beyond the wall) against the region's, and its
ball against the region's radial band around the axis, for all rolls at once; then per roll (the palm at every
node, the fingers at the leaves: their boxes are small, and above the leaves the per-roll tests pruned little
and cost more) the node's axis-aligned box by separating axes against the region's box cut to the node's slab
along the closing axis, where all its triangles lie (cut, the palm, a stroke wide, and its approach, a part long,
miss most nodes: on the thick ring the palm's triangle tests went from 277 to 2 per candidate), and where that
passes, the node's oriented box the same way (its own three axes and the region's Y and Z): it hugs the thin
patches of curved walls and slanted faces whose axis-aligned boxes are fat. At a node of at
most `_EXACT_TRIANGLES` triangles whose boxes meet a finger's slab, the range of its own distinct vertices along the
axis replaces its boxes' (always at the leaves; above them, per size class, while it turns a finger away at least
at every other try). A triangle is
tested at the rolls its node met for that region, when its extent along the closing axis meets the region's.
Every node test only prunes, with a guard band (1e-9 of the part's size) far beyond rounding; the answer is the
triangle test's, so the masks are those of testing every triangle at every roll (tests/graspgen/test_kernels.py
checks that by brute force).

Tried and not kept (bench/bench_criteria.py, thick ring and tless_04 at 10,000 points): certifying most rolls with
the point kernel and boxes grown by the sample's covering radius, testing triangles only where that failed (same
masks; 10 % faster on the ring, 35 % slower on tless_04: the covering radius, 1.3 mm at 10,000 points, is larger
than the fingers' 1 mm contact margin and a quarter of the rolls stay in doubt); splitting long triangles to 1/25
or 1/100 of the part's diagonal (4-5x slower: more triangles near each box); node balls instead of node boxes
(5x slower on tless_04, whose palm lies parallel to large faces); each triangle's angular sector and radial band
around the axis against the region's before the per-roll tests (25-30 % slower: three atan2 per triangle cost more
than the tests they save); testing the fingers once for rolls k and k + R/2 (their box is the same there):
within the noise. After the cut to the node's slab and the oriented boxes (same benchmark): the fingers' per-roll
node tests at every node, not only at the leaves (ring +50 % in the walk); leaves of 2 or 8 triangles (2 within
the noise, 8 40 % slower on the ring).
Ninth session (the ring's 393,646 candidates as the pipeline passes them, 3.24 open rolls each; work counters in a
throwaway copy of the kernel): the fingers are three quarters of the check (0.42 of 0.55 s), and their cost is the
walk, not the triangles: 81 node visits per candidate end in 0.6 triangle tests. (The eleventh session's counters
correct the reason given here before, a finger in the ring's hole: no candidate that reaches the check has a contact
on the inner wall. All close along horizontal axes between two points of the outer wall, the fingers outside it. Per
candidate 40 inner nodes pass a finger's slab and band tests and 2.3 the palm's, for 3.3 leaves reached: most likely
the boxes of curved patches near a contact stick out past the rim and the outer wall by more than the 1 mm contact
margin, and only their smaller descendants are turned away.) Per-roll node tests for the fingers above the leaves,
when at most L rolls are open: L = 1, 2, 4, 16 gave 1.02, 1.07, 1.43, 1.49x the time (visits 83.6 down to 76.6 at
best). Splitting the tree along (centroid, normal) where that gives thinner children, as collision.py's point tree
does: ring 81.3 visits instead of 83.6 and 0.98x the time, tless_04 0.95x, at 1.6x the build time. Not kept, because
neither gain is above the noise of the whole run.
Tenth session (in-process A/B on the candidates of five parts at 10,000 points, interleaved, same masks): the
oriented box per roll after the axis-aligned one passes, at the leaves and the palm's nodes: ring 0.93x, tless_04
0.81x, tless_13 0.94x, idler riser 0.98x, featuretype 1.04x (0.05 s). Before the axis-aligned box instead: ring
1.03x; for the fingers above the leaves too (alone, as their only per-roll test): ring 1.78x. The palm's rolls
taken out of the walk where the mesh vertices' convex hull lies wholly in front of the palm (collision.py's
hull certificate, on the vertices): ring 1.14x (the palm is a quarter of this check, and the rolls left free
by the point test lie near the certificate's threshold, where its hill climbs cost more than the walk).
Eleventh session (same A/B, the ring's 393,646 candidates; the palm is 0.08 of the check's 0.42 s): the fingers'
per-roll tests above the leaves with the node's ball against each open roll's rectangle (1.21x: a node of 20 mm
slivers has a ball of 10 mm or more, as wide as the finger, and prunes nothing), and with the boxes when at most 1
or 2 rolls are open (1.05x, 1.20x); the node's oriented-box range along the axis computed only when its cheaper
range meets a region's (1.02x). The pipeline now passes the point index pairs (mesh_free_rolls_of_pairs), as it does
to the point test: no (n, 3) arrays. Kept: at a leaf whose boxes meet a finger's slab, the range of the leaf's own
vertices along the axis (the triangle loop skips a region by the same numbers, so the masks cannot change): ring
0.886x, tless_04 0.99x, tless_13 1.01x, idler riser 1.03x, featuretype 1.09x (1 ms); the whole pipeline's (a)-(e) on
the ring 1.569 -> 1.500 s (in process, 12 runs each, alternating). A numpy simulation of the fingers' walk (3,000
ring candidates) showed more to gain: the vertices' range at nodes of up to 16, 32 or 64 triangles gives 46.6, 30.4
or 22.2 visits instead of 85, and 1.4 leaves reached instead of 4.6. With every triangle's corners (duplicates
included) it cost more than it saved (16 or 32 triangles, every region: ring 0.99x, 1.07x); with each node's
distinct vertices, stored at build time, at up to 64 triangles: ring 0.69x, but tless_13 1.09x, featuretype 1.35x,
the Sileane gear 1.43x (their candidates' nodes near a contact do meet the slab). Hence a tally per size class, per
thread and chunk: above the leaves the range is taken while it turns a finger away at least at every other try (one
in four or two in three: within 1 % of that). Against the leaf-only version, same masks: ring 0.674x (0.373 -> 0.251
s), tless_04 1.025x, tless_10 1.055x, tless_13 1.01x, featuretype 1.03x, idler riser 1.025x, Sileane gear 1.04x, IPA
ring screw 1.035x (0.3-2 ms each); the whole pipeline's (a)-(e) on the ring 1.593 -> 1.509 s. The distinct vertices
take about twice the triangles' memory (an icosphere of 327,680 faces: 49 MB, its build 1.12 -> 1.17 s); the memory
guard's probe measures them with the part.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from . import libm
from .collision import CollisionModel, _basis, _check_pairs, _pair_frame, _regions, _x_range_constants, _x_ranges

__all__ = ["MeshTree", "build_tree", "normal_spread_rad", "mesh_free_rolls", "mesh_free_rolls_of_pairs"]

_LEAF = 4
_NODE = 23  # floats per tree node: see _build
_CHUNK = 256  # candidates per unit of parallel work
#: nodes of at most this many triangles keep their distinct vertices, for the exact range along the axis (_walk)
_EXACT_TRIANGLES = 64
#: per size class above the leaves, that range is taken while it has turned a finger away at least at every other
#: try (counted per thread and chunk, after the first _EXACT_TRIES tries)
_EXACT_TRIES = 32


class MeshTree:
    """Triangles (m, 3, 3) metres, their unit normals (m, 3), and the tree's arrays (see `build_tree`): per node
    the box data and (left, right, start, count); for nodes of at most `_EXACT_TRIANGLES` triangles their distinct
    vertices, verts[:, vstart[k]:vstart[k + 1]] (3, .) (none for larger nodes)."""

    def __init__(
        self,
        triangles: np.ndarray,
        normals: np.ndarray,
        nodes: np.ndarray,
        children: np.ndarray,
        vstart: np.ndarray,
        verts: np.ndarray,
    ):
        self.triangles = triangles
        self.normals = normals
        self.nodes = nodes
        self.children = children
        self.vstart = vstart
        self.verts = verts

    def __len__(self) -> int:
        return len(self.triangles)


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
    nodes = np.zeros((max_nodes, _NODE), dtype=np.float64)  # see _build
    children = np.zeros((max_nodes, 4), dtype=np.int64)  # left, right, start, count
    count = _build(np.ascontiguousarray(tri), order, nodes, children) if m else 0
    tri = np.ascontiguousarray(tri[order])
    n = np.ascontiguousarray(n[order])
    children = children[:count].copy()
    vstart, verts = _node_vertices(np.ascontiguousarray(F[keep][order]), V, children, _EXACT_TRIANGLES)
    return MeshTree(tri, n, nodes[:count].copy(), children, vstart, verts)


@njit(cache=True)
def _node_vertices(faces, V, children, max_triangles):
    """The distinct vertices (by index) of each node of at most `max_triangles` triangles, in (3, total) SoA with
    offsets per node: a stamp per vertex index marks the ones a node has listed already."""
    nn = children.shape[0]
    vstart = np.zeros(nn + 1, dtype=np.int64)
    stamp = np.full(V.shape[0], -1, dtype=np.int64)
    for k in range(nn):
        c = 0
        if children[k, 3] <= max_triangles:
            for t in range(children[k, 2], children[k, 2] + children[k, 3]):
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
        if children[k, 3] <= max_triangles:
            for t in range(children[k, 2], children[k, 2] + children[k, 3]):
                for j in range(3):
                    v = faces[t, j]
                    if stamp[v] != k:
                        stamp[v] = k
                        verts[0, q], verts[1, q], verts[2, q] = V[v, 0], V[v, 1], V[v, 2]
                        q += 1
    return vstart, verts


@njit(cache=True)
def _build(T, order, nodes, children):
    """Fill nodes[k] (_NODE floats) = (centre x, y, z of the axis-aligned box, radius of the ball around that
    centre, the box's half extents x, y, z, unused, then the oriented box of the node's vertices: centre xyz,
    three unit axes as rows (principal first), half extents) and children[k] = (left, right, start, count);
    leaves have left = -1. Returns the node count. The oriented box suits the long thin triangles of curved
    walls (an arc's axis-aligned box sticks out far beyond it); its bounds are not padded: the queries pad."""
    m = T.shape[0]
    cen = np.empty((m, 3))
    for t in range(m):
        for a in range(3):
            cen[t, a] = (T[t, 0, a] + T[t, 1, a] + T[t, 2, a]) / 3.0
    stack = np.empty((128, 3), dtype=np.int64)  # node, start, stop
    top = 0
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
        nodes[k, 0], nodes[k, 1], nodes[k, 2] = c[0], c[1], c[2]
        nodes[k, 3] = np.sqrt(r2) * (1.0 + 1e-12) + 1e-15
        nodes[k, 4], nodes[k, 5], nodes[k, 6] = 0.5 * (hi[0] - lo[0]), 0.5 * (hi[1] - lo[1]), 0.5 * (hi[2] - lo[2])
        _oriented_box(T, order, a0, b0, nodes[k])
        children[k, 2], children[k, 3] = a0, b0 - a0
        if b0 - a0 <= _LEAF:
            children[k, 0], children[k, 1] = -1, -1
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
        children[k, 0], children[k, 1] = left, right
        stack[top, 0], stack[top, 1], stack[top, 2] = left, a0, mid
        stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = right, mid, b0
        top += 2
    return count


@njit(cache=True)
def _oriented_box(T, order, a0, b0, out):
    """The oriented box of the vertices of triangles T[order[a0:b0]] into out[8:23] (see _build): axes by
    principal components, bounds by projection."""
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
        out[8 + a] = c
    for i in range(3):
        for a in range(3):
            out[11 + 3 * i + a] = V[a, 2 - i]
        out[20 + i] = 0.5 * (hi[i] - lo[i])


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
def _spread_kernel(P, N, T, TN, nodes, children, tol, out):
    for i in prange(P.shape[0]):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        lowest = 1.0
        stack = np.empty(64, dtype=np.int64)
        stack[0] = 0
        top = 1
        while top > 0:
            top -= 1
            k = stack[top]
            dx = abs(px - nodes[k, 0]) - nodes[k, 4]
            dy = abs(py - nodes[k, 1]) - nodes[k, 5]
            dz = abs(pz - nodes[k, 2]) - nodes[k, 6]
            d2 = max(dx, 0.0) ** 2 + max(dy, 0.0) ** 2 + max(dz, 0.0) ** 2
            if d2 > tol * tol:
                continue
            if children[k, 0] < 0:
                for t in range(children[k, 2], children[k, 2] + children[k, 3]):
                    dot = TN[t, 0] * N[i, 0] + TN[t, 1] * N[i, 1] + TN[t, 2] * N[i, 2]
                    if dot >= lowest:
                        continue
                    if _point_triangle_dist2(px, py, pz, T, t) <= tol * tol:
                        lowest = dot
            else:
                stack[top] = children[k, 0]
                stack[top + 1] = children[k, 1]
                top += 2
        out[i] = np.arccos(max(-1.0, min(1.0, lowest)))


@njit(cache=True, inline="always", error_model="numpy")
def _point_triangle_dist2(px, py, pz, T, t):
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
    return (px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2


# -- boxes against triangles ----------------------------------------------------------------------------------------


@njit(cache=True, inline="always", error_model="numpy")
def _axis_test(p0, p1, p2, r):
    return min(p0, p1, p2) > r or max(p0, p1, p2) < -r


@njit(cache=True, error_model="numpy")
def _tri_box(v, c, e):
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
    return abs(d) <= r


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
    """The rolls of `free` (n, R) bool that stay free when the gripper's boxes (the model's fingers and palm, as
    criterion (d) builds them) are tested against every triangle of `tree`. Returns a new (n, R) bool array."""
    geometry = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in (midpoints, axes, widths))
    no_index = np.zeros(0, dtype=np.int64)
    return _run(tree, geometry, (np.zeros((0, 3)), no_index, no_index), inside, free, model, switch)


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
    kernel derives them per candidate (collision.free_rolls_of_pairs does the same), so no (n, 3) arrays are
    made."""
    P = np.ascontiguousarray(points, dtype=np.float64)
    i, j = (np.ascontiguousarray(a, dtype=np.int64) for a in (i, j))
    if len(i):
        _check_pairs(len(P), i, j)
    geometry = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    return _run(tree, geometry, (P, i, j), inside, free, model, switch)


def _run(tree, geometry, index, inside, free, model, switch) -> np.ndarray:
    from .transforms import ROLL_REFERENCE_SWITCH

    switch = ROLL_REFERENCE_SWITCH if switch is None else switch
    free = np.ascontiguousarray(free, dtype=bool)
    n, R = free.shape
    rows = len(index[1]) if len(index[0]) else len(geometry[0])  # index pairs (points given), else the geometry
    if len(inside) != n or rows != n:
        raise ValueError("the candidates' geometry, inside and free must have one row per candidate")
    out = free.copy()
    if n == 0 or len(tree) == 0:
        return out
    reg = _regions(model)
    model_f = _x_range_constants(model)
    psi = 2.0 * np.pi * np.arange(R) / R
    # the node tests' guard band: far beyond the rounding of the boxes' bounds and of the tests themselves
    guard = 1e-9 * 2.0 * float(np.max(tree.nodes[0, 4:7])) + 1e-15
    with numba.parallel_chunksize(1):
        _mesh_kernel(
            *geometry,
            *index,
            np.ascontiguousarray(inside, dtype=np.bool_),
            out,
            tree.triangles,
            tree.vstart,
            tree.verts,
            tree.nodes,
            tree.children,
            reg,
            model_f,
            libm.cos(psi),
            libm.sin(psi),
            float(switch),
            guard,
            numba.get_num_threads(),
        )
    return out


@njit(cache=True, inline="always", error_model="numpy")
def _node_meets_box(nodes, k, x, y0, z0, ax, ay, az, rot, rl, c, s, bcx, bex, bcy, bey, bcz, bez, g):
    """May node k's axis-aligned box meet the region box at roll rl? The region box: centre (bcx, bcy, bcz) and
    half extents (bex, bey, bez) in the grasp frame of roll rl, whose Y and Z in the object frame are
    rot[rl]; the node's centre in the roll-0 frame is (x, y0, z0). Separating-axis test on the region's Y and Z
    and the world's three axes, each with the guard band g (the caller has tested X; the nine cross axes are
    left out: a node that passes is only descended into)."""
    ex, ey, ez = nodes[k, 4], nodes[k, 5], nodes[k, 6]
    Yx, Yy, Yz, Zx, Zy, Zz = rot[rl, 0], rot[rl, 1], rot[rl, 2], rot[rl, 3], rot[rl, 4], rot[rl, 5]
    # the node's centre relative to the region's centre, along the region's axes
    dX = x - bcx
    dY = y0 * c + z0 * s - bcy
    dZ = -y0 * s + z0 * c - bcz
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
    return abs(wz) <= ez + bex * abs(az) + bey * abs(Yz) + bez * abs(Zz) + g


@njit(cache=True, inline="always", error_model="numpy")
def _obb_meets_box(ob, c, s, bcx, bex, bcy, bey, bcz, bez, g):
    """May the node's oriented box meet the region box at the roll (c, s) = (cos, sin)? ob: the node's oriented
    box in the candidate's roll-0 frame (centre x, y0, z0, then per box axis i its components along X, Y0, Z0 and
    its half extent: ob[3 + 4 i : 7 + 4 i]). Separating-axis test on the region's Y and Z and the box's own three
    axes, each with the guard band g (X: the caller cut the region to the node's slab)."""
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
    return abs(dY) <= bey + sy + g and abs(dZ) <= bez + sz + g


@njit(cache=True, inline="always", error_model="numpy")
def _oriented_in_frame(nodes, k, mx, my, mz, ax, ay, az, yx, yy, yz, zx, zy, zz, ob):
    """Node k's oriented box in the candidate's roll-0 frame into ob (see _obb_meets_box)."""
    qx, qy, qz = nodes[k, 8] - mx, nodes[k, 9] - my, nodes[k, 10] - mz
    ob[0] = qx * ax + qy * ay + qz * az
    ob[1] = qx * yx + qy * yy + qz * yz
    ob[2] = qx * zx + qy * zy + qz * zz
    for i in range(3):
        ux, uy, uz = nodes[k, 11 + 3 * i], nodes[k, 12 + 3 * i], nodes[k, 13 + 3 * i]
        ob[3 + 4 * i] = ux * ax + uy * ay + uz * az
        ob[4 + 4 * i] = ux * yx + uy * yy + uz * yz
        ob[5 + 4 * i] = ux * zx + uy * zy + uz * zz
        ob[6 + 4 * i] = nodes[k, 20 + i]


@njit(cache=True, inline="always", error_model="numpy")
def _vertex_x_range(verts, q0, q1, mx, my, mz, ax, ay, az):
    """The smallest and largest coordinate along the closing axis of verts[:, q0:q1], with the triangle loop's own
    arithmetic (_walk)."""
    lo = np.inf
    hi = -np.inf
    for q in range(q0, q1):
        v = (verts[0, q] - mx) * ax + (verts[1, q] - my) * ay + (verts[2, q] - mz) * az
        lo = min(lo, v)
        hi = max(hi, v)
    return lo, hi


@njit(cache=True, inline="always", error_model="numpy")
def _meets_finger_slab(masks, top, blocked, rx, nreg, x_lo, x_hi):
    """Does [x_lo, x_hi] meet the slab of a finger that still has rolls to test at stack entry `top`?"""
    for r in range(min(nreg, 2)):  # noqa: SIM110 (numba compiles no generator passed to any())
        if masks[top, r] & ~blocked and rx[r, 0] <= x_hi and x_lo <= rx[r, 1]:
            return True
    return False


@njit(cache=True, error_model="numpy")
def _walk(
    F,
    todo,
    T,
    vstart,
    verts,
    tally,
    nodes,
    children,
    reg,
    rx,
    boxes_c,
    boxes_e,
    rot,
    cos_k,
    sin_k,
    g,
    scratch,
    stack,
    masks,
    hit,
    ob,
):
    """The rolls of `todo` at which some triangle meets some region box, for the candidate with midpoint F[0:3]
    and roll-0 frame X, Y0, Z0 = F[3:6], F[6:9], F[9:12]: one walk of the tree carrying, per region, the rolls
    still to test. Its own function, called from the parallel loop: inlined in the loop's body, the same code
    ran 2x slower."""
    R = cos_k.shape[0]
    nreg = reg.shape[0]
    mx, my, mz = F[0], F[1], F[2]
    ax, ay, az, yx, yy, yz, zx, zy, zz = F[3], F[4], F[5], F[6], F[7], F[8], F[9], F[10], F[11]
    v = scratch[0]
    w = scratch[1]
    blocked = np.uint64(0)
    stack[0] = 0
    for r in range(nreg):
        masks[0, r] = todo
    top = 1
    while top > 0:
        top -= 1
        k = stack[top]
        live_any = np.uint64(0)
        for r in range(nreg):
            live_any |= masks[top, r]
        if live_any & ~blocked == 0:
            continue
        # the node's x range along the closing axis (the tighter of its two boxes and its ball), its
        # centre's distance from the axis, in the roll-0 frame
        qx = nodes[k, 0] - mx
        qy = nodes[k, 1] - my
        qz = nodes[k, 2] - mz
        x = qx * ax + qy * ay + qz * az
        y0 = qx * yx + qy * yy + qz * yz
        z0 = qx * zx + qy * zy + qz * zz
        rad = nodes[k, 3]
        rc = np.sqrt(y0 * y0 + z0 * z0)
        xh = min(nodes[k, 4] * abs(ax) + nodes[k, 5] * abs(ay) + nodes[k, 6] * abs(az), rad)
        ox = (nodes[k, 8] - mx) * ax + (nodes[k, 9] - my) * ay + (nodes[k, 10] - mz) * az
        oh = (
            nodes[k, 20] * abs(nodes[k, 11] * ax + nodes[k, 12] * ay + nodes[k, 13] * az)
            + nodes[k, 21] * abs(nodes[k, 14] * ax + nodes[k, 15] * ay + nodes[k, 16] * az)
            + nodes[k, 22] * abs(nodes[k, 17] * ax + nodes[k, 18] * ay + nodes[k, 19] * az)
        )
        x_lo = max(x - xh, ox - oh) - g
        x_hi = min(x + xh, ox + oh) + g
        inner = children[k, 0] >= 0
        if vstart[k + 1] > vstart[k] and _meets_finger_slab(masks, top, blocked, rx, nreg, x_lo, x_hi):
            # a small node whose boxes meet a finger's slab: the range of its own vertices instead. The boxes of a
            # curved patch stick out past a contact's 1 mm margin where its triangles do not; the triangle loop
            # below skips a region by the same numbers, so this only prunes what it would skip. Above the leaves
            # only while it pays: per size class, while it turns a finger away at least at every other try
            cls = 0
            c = children[k, 3]
            while c > _LEAF:
                c >>= 1
                cls += 1
            if cls == 0 or tally[cls, 0] < _EXACT_TRIES or 2 * tally[cls, 1] >= tally[cls, 0]:
                e_lo, e_hi = _vertex_x_range(verts, vstart[k], vstart[k + 1], mx, my, mz, ax, ay, az)
                x_lo, x_hi = max(x_lo, e_lo - g), min(x_hi, e_hi + g)
                tally[cls, 0] += 1
                if not _meets_finger_slab(masks, top, blocked, rx, nreg, x_lo, x_hi):
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
            if rc + rad < reg[r, 3] or rc - rad > reg[r, 4]:
                continue
            if r < 2 and inner:
                # the fingers' boxes are small: their per-roll tests prune little above the leaves
                hit[r] = live
                any_hit |= live
                continue
            # per roll: the region cut to the node's slab along X, where all its triangles lie (the
            # palm is a stroke wide and its approach a part long: cut, it misses most nodes)
            bcx, bex = 0.5 * (lo + hi), 0.5 * (hi - lo)
            bcy, bey, bcz, bez = boxes_c[r, 1], boxes_e[r, 1], boxes_c[r, 2], boxes_e[r, 2]
            h = np.uint64(0)
            for rl in range(R):
                bit = np.uint64(1) << np.uint64(rl)
                if not (live & bit):
                    continue
                if _node_meets_box(
                    nodes,
                    k,
                    x,
                    y0,
                    z0,
                    ax,
                    ay,
                    az,
                    rot,
                    rl,
                    cos_k[rl],
                    sin_k[rl],
                    bcx,
                    bex,
                    bcy,
                    bey,
                    bcz,
                    bez,
                    g,
                ):
                    # then the oriented box, which hugs the thin patches of curved walls and slanted faces
                    if not have_ob:
                        _oriented_in_frame(nodes, k, mx, my, mz, ax, ay, az, yx, yy, yz, zx, zy, zz, ob)
                        have_ob = True
                    if _obb_meets_box(ob, cos_k[rl], sin_k[rl], bcx, bex, bcy, bey, bcz, bez, g):
                        h |= bit
            hit[r] = h
            any_hit |= h
        if any_hit == 0:
            continue
        if inner:
            stack[top] = children[k, 0]
            stack[top + 1] = children[k, 1]
            for r in range(nreg):
                masks[top, r] = hit[r]
                masks[top + 1, r] = hit[r]
            top += 2
            continue
        for t in range(children[k, 2], children[k, 2] + children[k, 3]):
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
                    if _tri_box(w, boxes_c[r], boxes_e[r]):
                        blocked |= bit
        if blocked == todo:
            break
    return blocked


@njit(cache=True, inline="always", error_model="numpy")
def _region_boxes(xr, reg, rx, boxes_c, boxes_e):
    """The regions' boxes in a roll's grasp frame for one candidate: x ranges into rx (r, 2), centres and half
    extents into boxes_c, boxes_e (r, 3); xr: the fingers' x ranges (_x_ranges), reg: _regions."""
    for r in range(reg.shape[0]):
        if r < 2:
            lo_x, hi_x = xr[r, 0], xr[r, 1]
        else:
            lo_x, hi_x = -reg[r, 10], reg[r, 10]
        rx[r, 0], rx[r, 1] = lo_x, hi_x
        boxes_c[r, 0] = 0.5 * (lo_x + hi_x)
        boxes_e[r, 0] = 0.5 * (hi_x - lo_x)
        boxes_c[r, 1] = 0.0
        boxes_e[r, 1] = reg[r, 0]
        boxes_c[r, 2] = 0.5 * (reg[r, 1] + reg[r, 2])
        boxes_e[r, 2] = 0.5 * (reg[r, 2] - reg[r, 1])


@njit(parallel=True, cache=True, error_model="numpy")
def _mesh_kernel(
    M,
    A,
    Wd,
    P,
    pi,
    pj,
    inside,
    free,
    T,
    vstart,
    verts,
    nodes,
    children,
    reg,
    model_f,
    cos_k,
    sin_k,
    switch,
    g,
    nthreads,
):
    n = inside.shape[0]
    from_pairs = pi.shape[0] > 0  # the candidates as point index pairs (pi, pj) into P, not as M, A, Wd
    R = cos_k.shape[0]
    chunks = (n + _CHUNK - 1) // _CHUNK
    # thread t takes chunks t, t + T, ...: the work varies along the candidates' spatial order, and a static split
    # into one run per thread left one thread with 60 % of it (tless_04), as in collision._free_rolls_kernel
    for t in prange(nthreads):
        xr = np.empty((3, 2))
        rx = np.empty((3, 2))
        boxes_c = np.empty((3, 3))
        boxes_e = np.empty((3, 3))
        scratch = np.empty((2, 3, 3))  # a triangle in the roll-0 frame and at a roll
        F = np.empty(12)
        rot = np.empty((R, 6))
        stack = np.empty(128, dtype=np.int64)
        masks = np.empty((128, 3), dtype=np.uint64)  # per stack entry and region: the rolls to test
        hit = np.empty(3, dtype=np.uint64)
        ob = np.empty(15)  # a node's oriented box in the candidate's roll-0 frame
        tally = np.zeros((8, 2), dtype=np.int64)  # per size class: exact ranges taken, and fingers turned away
        for ch in range(t, chunks, nthreads):
            tally[:, :] = 0
            for i in range(ch * _CHUNK, min(n, (ch + 1) * _CHUNK)):
                todo = np.uint64(0)
                for k in range(R):
                    if free[i, k]:
                        todo |= np.uint64(1) << np.uint64(k)
                if todo == 0:
                    continue
                if from_pairs:
                    mx, my, mz, ax, ay, az, wd = _pair_frame(P, pi[i], pj[i])
                else:
                    mx, my, mz, ax, ay, az, wd = M[i, 0], M[i, 1], M[i, 2], A[i, 0], A[i, 1], A[i, 2], Wd[i]
                yx, yy, yz, zx, zy, zz = _basis(ax, ay, az, switch)
                for rl in range(R):
                    c, s = cos_k[rl], sin_k[rl]
                    rot[rl, 0], rot[rl, 1], rot[rl, 2] = c * yx + s * zx, c * yy + s * zy, c * yz + s * zz
                    rot[rl, 3], rot[rl, 4], rot[rl, 5] = -s * yx + c * zx, -s * yy + c * zy, -s * yz + c * zz
                _x_ranges(xr, inside[i], wd, model_f)
                _region_boxes(xr, reg, rx, boxes_c, boxes_e)
                F[0], F[1], F[2] = mx, my, mz
                F[3], F[4], F[5], F[6], F[7], F[8], F[9], F[10], F[11] = ax, ay, az, yx, yy, yz, zx, zy, zz
                blocked = _walk(
                    F,
                    todo,
                    T,
                    vstart,
                    verts,
                    tally,
                    nodes,
                    children,
                    reg,
                    rx,
                    boxes_c,
                    boxes_e,
                    rot,
                    cos_k,
                    sin_k,
                    g,
                    scratch,
                    stack,
                    masks,
                    hit,
                    ob,
                )
                if blocked != 0:
                    for rl in range(R):
                        if blocked & (np.uint64(1) << np.uint64(rl)):
                            free[i, rl] = False
