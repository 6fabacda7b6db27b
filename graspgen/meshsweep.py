"""A closed triangle mesh moved along +Z against points: which points it passes through on its way in.

The physics validation (physics.py) confirms an approach collision against the part's own surface. The gripper comes
in along +Z of the grasp frame, so one of its solids S (a finger at the pre-grasp opening, the body) passes through a
point q exactly when the segment q + u Z, u in [0, D], meets S, D being the approach distance. With a tolerance t the
question is whether the segment meets S eroded by t: the points of S farther than t from its boundary (for a box,
the box shrunk by t on every side, which is what the box gripper's test uses).

Along the vertical line through q the kernel finds:
- where the line is inside S. Each crossing of the line with a triangle counts +1 where the triangle faces down (the
  line enters S going up) and -1 where it faces up; summed from below, that is the winding number along the line,
  positive inside a closed, outward-wound mesh, including shells that touch. A line through an edge or a vertex is
  counted once: the top-left rule on the triangles' projections onto XY decides, with each edge's function evaluated
  with its end points in one canonical order, so that the two triangles of an edge see the same value;
- where the line lies within t of a triangle. The distance from a point moving along a line to a triangle is convex,
  so that set is one interval: golden section finds its minimum and bisection its ends, to 1e-10 m.

q meets the eroded solid when some u in [0, D] is inside S and in none of those intervals.

Triangles are binned by their XY bounding box, grown by t, on a uniform grid, so each line reads only the triangles
that can cross it or come within t of it.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["SweptMesh", "SweepGrid"]

#: the triangles as the kernel reads them: triangles (m, 3, 3) metres; the grid's cells, row-major (gx, gy), each
#: listing items[start[c]:start[c + 1]] (indices into triangles); origin (2,) and cell (2,) of the grid in metres;
#: shape (2,) int64; grow: how far (m) each triangle's XY box was grown before binning (the largest tolerance a
#: query may use)
SweepGrid = namedtuple("SweepGrid", ["triangles", "start", "items", "origin", "cell", "shape", "grow"])

#: bisection and golden-section precision of the near intervals (m)
_PRECISION = 1e-10
_INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True, eq=False)
class SweptMesh:
    """A closed, outward-wound triangle mesh in its own frame (metres), binned for vertical lines.

    `tolerance` (m): the erosion t of `hits` (module docstring). `lo`, `hi` (3,): the mesh's bounds."""

    grid: SweepGrid
    lo: np.ndarray
    hi: np.ndarray
    tolerance: float

    @classmethod
    def of(cls, triangles: np.ndarray, tolerance: float = 0.0) -> SweptMesh:
        """Bin `triangles` (m, 3, 3), metres, of a closed outward-wound mesh; `tolerance` >= 0 (m)."""
        tri = np.ascontiguousarray(np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3))
        if len(tri) == 0:
            raise ValueError("a swept mesh needs triangles")
        tol = float(tolerance)
        if not (math.isfinite(tol) and tol >= 0.0):
            raise ValueError(f"tolerance must be >= 0, got {tolerance!r}")
        lo2 = tri[:, :, :2].min(axis=1) - tol
        hi2 = tri[:, :, :2].max(axis=1) + tol
        origin = lo2.min(axis=0)
        span = np.maximum(hi2.max(axis=0) - origin, 1e-9)
        m = len(tri)
        g = int(min(128, max(1, round(math.sqrt(m)))))
        while True:
            shape = np.array([g, g], dtype=np.int64)
            cell = span / shape
            i0 = np.clip(np.floor((lo2 - origin) / cell).astype(np.int64), 0, shape - 1)
            i1 = np.clip(np.floor((hi2 - origin) / cell).astype(np.int64), 0, shape - 1)
            entries = int(np.sum((i1[:, 0] - i0[:, 0] + 1) * (i1[:, 1] - i0[:, 1] + 1)))
            if g == 1 or entries <= 8 * m + 4 * g * g:  # long thin triangles over many cells: a coarser grid
                break
            g //= 2
        start, items = _bin(i0, i1, shape, entries)
        grid = SweepGrid(tri, start, items, origin.astype(np.float64), cell.astype(np.float64), shape, tol)
        flat = tri.reshape(-1, 3)
        return cls(grid, flat.min(axis=0), flat.max(axis=0), tol)

    def hits(self, points: np.ndarray, distance: float, *, first: bool = False) -> np.ndarray:
        """Which of `points` (n, 3), metres, in the mesh's frame, the mesh eroded by `tolerance` passes through as it
        moves along +Z from `distance` (m, >= 0) below its place into it: (n,) bool. `first`: stop at the first hit
        (the rest stay False)."""
        q = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        D = float(distance)
        t = self.tolerance
        lo, hi = self.lo + t, self.hi - t
        near = np.all((q[:, :2] > lo[:2]) & (q[:, :2] < hi[:2]), axis=1) & (q[:, 2] > lo[2] - D) & (q[:, 2] < hi[2])
        out = np.zeros(len(q), dtype=bool)
        idx = np.flatnonzero(near)
        if len(idx):
            out[idx] = _sweep_hits(self.grid, q[idx], D, t, bool(first))
        return out

    def any_hit(self, points: np.ndarray, distance: float) -> bool:
        """Does the eroded mesh pass through any of `points` on its way in (`hits`)?"""
        return bool(self.hits(points, distance, first=True).any())

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Which of `points` (n, 3) lie inside the mesh (winding number along the vertical line, no erosion): (n,)
        bool."""
        q = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        return _sweep_hits(self.grid, q, 0.0, 0.0, False)


@njit(cache=True)
def _bin(i0: np.ndarray, i1: np.ndarray, shape: np.ndarray, entries: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR lists of the triangles over the grid's cells: triangle k lies in cells [i0[k], i1[k]] (inclusive)."""
    gx, gy = shape[0], shape[1]
    count = np.zeros(gx * gy + 1, dtype=np.int64)
    for k in range(i0.shape[0]):
        for a in range(i0[k, 0], i1[k, 0] + 1):
            for b in range(i0[k, 1], i1[k, 1] + 1):
                count[a * gy + b + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    items = np.empty(entries, dtype=np.int64)
    for k in range(i0.shape[0]):
        for a in range(i0[k, 0], i1[k, 0] + 1):
            for b in range(i0[k, 1], i1[k, 1] + 1):
                c = a * gy + b
                items[fill[c]] = k
                fill[c] += 1
    return start, items


@njit(cache=True, inline="always")
def _edge(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> float:
    """The edge function of the directed edge a -> b at p (> 0: p left of it), computed with the end points in
    lexicographic order, so that b -> a gives exactly the negated value."""
    if ax < bx or (ax == bx and ay <= by):
        return (bx - ax) * (py - ay) - (by - ay) * (px - ax)
    return -((ax - bx) * (py - by) - (ay - by) * (px - bx))


@njit(cache=True, inline="always")
def _owns(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> bool:
    """Is p on the inner side of the counter-clockwise edge a -> b, the edge itself belonging to the triangle when
    it is a top or a left edge (the top-left rule)?"""
    e = _edge(ax, ay, bx, by, px, py)
    if e > 0.0:
        return True
    if e < 0.0:
        return False
    dy, dx = by - ay, bx - ax
    return dy < 0.0 or (dy == 0.0 and dx < 0.0)


@njit(cache=True)
def _crossing(T: np.ndarray, px: float, py: float) -> tuple[int, float]:
    """Where the vertical line through (px, py) crosses triangle T (3, 3): (sign, z); sign +1 where T faces down
    (the line enters the solid going up), -1 where it faces up, 0 for no crossing (or a vertical triangle)."""
    ax, ay, bx, by, cx, cy = T[0, 0], T[0, 1], T[1, 0], T[1, 1], T[2, 0], T[2, 1]
    area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    if area == 0.0:
        return 0, 0.0
    if area > 0.0:
        inside = _owns(ax, ay, bx, by, px, py) and _owns(bx, by, cx, cy, px, py) and _owns(cx, cy, ax, ay, px, py)
        sign = -1
    else:  # facing down: its counter-clockwise order in XY is a, c, b
        inside = _owns(ax, ay, cx, cy, px, py) and _owns(cx, cy, bx, by, px, py) and _owns(bx, by, ax, ay, px, py)
        sign = 1
    if not inside:
        return 0, 0.0
    # the plane through T: n . (p - a) = 0 with n = (b - a) x (c - a), n_z = area
    ux, uy, uz = bx - ax, by - ay, T[1, 2] - T[0, 2]
    vx, vy, vz = cx - ax, cy - ay, T[2, 2] - T[0, 2]
    nx, ny = uy * vz - uz * vy, uz * vx - ux * vz
    return sign, T[0, 2] - (nx * (px - ax) + ny * (py - ay)) / area


@njit(cache=True, inline="always")
def _segment_distance2_2d(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> float:
    dx, dy = bx - ax, by - ay
    L = dx * dx + dy * dy
    s = 0.0
    if L > 0.0:
        s = min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / L))
    ex, ey = ax + s * dx - px, ay + s * dy - py
    return ex * ex + ey * ey


@njit(cache=True)
def _xy_distance(T: np.ndarray, px: float, py: float) -> float:
    """Distance (m) from the vertical line through (px, py) to triangle T: from the point to T's projection."""
    ax, ay, bx, by, cx, cy = T[0, 0], T[0, 1], T[1, 0], T[1, 1], T[2, 0], T[2, 1]
    e0 = (bx - ax) * (py - ay) - (by - ay) * (px - ax)
    e1 = (cx - bx) * (py - by) - (cy - by) * (px - bx)
    e2 = (ax - cx) * (py - cy) - (ay - cy) * (px - cx)
    area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    if area != 0.0 and ((e0 >= 0.0 and e1 >= 0.0 and e2 >= 0.0) or (e0 <= 0.0 and e1 <= 0.0 and e2 <= 0.0)):
        return 0.0
    d = _segment_distance2_2d(ax, ay, bx, by, px, py)
    d = min(d, _segment_distance2_2d(bx, by, cx, cy, px, py))
    d = min(d, _segment_distance2_2d(cx, cy, ax, ay, px, py))
    return math.sqrt(d)


@njit(cache=True)
def _distance(T: np.ndarray, px: float, py: float, pz: float) -> float:
    """Distance (m) from p to triangle T (3, 3) (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ax, ay, az = T[0, 0], T[0, 1], T[0, 2]
    abx, aby, abz = T[1, 0] - ax, T[1, 1] - ay, T[1, 2] - az
    acx, acy, acz = T[2, 0] - ax, T[2, 1] - ay, T[2, 2] - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        qx, qy, qz = ax, ay, az
    else:
        bpx, bpy, bpz = px - T[1, 0], py - T[1, 1], pz - T[1, 2]
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        cpx, cpy, cpz = px - T[2, 0], py - T[2, 1], pz - T[2, 2]
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            qx, qy, qz = T[1, 0], T[1, 1], T[1, 2]
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            v = d1 / (d1 - d3)
            qx, qy, qz = ax + v * abx, ay + v * aby, az + v * abz
        elif d6 >= 0.0 and d5 <= d6:
            qx, qy, qz = T[2, 0], T[2, 1], T[2, 2]
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            w = d2 / (d2 - d6)
            qx, qy, qz = ax + w * acx, ay + w * acy, az + w * acz
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            qx = T[1, 0] + w * (T[2, 0] - T[1, 0])
            qy = T[1, 1] + w * (T[2, 1] - T[1, 1])
            qz = T[1, 2] + w * (T[2, 2] - T[1, 2])
        else:
            denom = 1.0 / (va + vb + vc)
            v, w = vb * denom, vc * denom
            qx, qy, qz = ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w
    return math.sqrt((px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2)


@njit(cache=True)
def _near_interval(T: np.ndarray, px: float, py: float, pz: float, tol: float) -> tuple[float, float]:
    """The interval [lo, hi] of u where p + u Z lies within `tol` of triangle T (lo > hi: nowhere). The distance is
    convex in u: its minimum by golden section, the interval's ends by bisection."""
    zmin = min(T[0, 2], min(T[1, 2], T[2, 2]))
    zmax = max(T[0, 2], max(T[1, 2], T[2, 2]))
    a, b = zmin - tol - pz, zmax + tol - pz  # beyond these the point is farther than tol along z alone
    lo, hi = a, b
    x1 = hi - _INV_PHI * (hi - lo)
    x2 = lo + _INV_PHI * (hi - lo)
    f1, f2 = _distance(T, px, py, pz + x1), _distance(T, px, py, pz + x2)
    while hi - lo > _PRECISION:
        if f1 <= tol or f2 <= tol:
            break
        if f1 < f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - _INV_PHI * (hi - lo)
            f1 = _distance(T, px, py, pz + x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + _INV_PHI * (hi - lo)
            f2 = _distance(T, px, py, pz + x2)
    if f1 <= tol:
        m = x1
    elif f2 <= tol:
        m = x2
    else:
        return 1.0, 0.0
    # f(a) >= tol and f(b) >= tol; f(m) <= tol; convex: one crossing on each side
    l0, l1 = a, m
    while l1 - l0 > _PRECISION:
        c = 0.5 * (l0 + l1)
        if _distance(T, px, py, pz + c) <= tol:
            l1 = c
        else:
            l0 = c
    h0, h1 = m, b
    while h1 - h0 > _PRECISION:
        c = 0.5 * (h0 + h1)
        if _distance(T, px, py, pz + c) <= tol:
            h0 = c
        else:
            h1 = c
    return l1, h0


@njit(cache=True)
def _uncovered(a: float, b: float, lo: np.ndarray, hi: np.ndarray, order: np.ndarray, n: int) -> bool:
    """Is some part of [a, b] (a <= b) outside the union of the closed intervals [lo[k], hi[k]] (k in order[:n],
    sorted by lo)? A single point a == b counts; a gap of no length between intervals that touch does not."""
    if a == b:
        for j in range(n):  # noqa: SIM110 (a numba kernel: no generator expressions)
            if lo[order[j]] <= a <= hi[order[j]]:
                return False
        return True
    cur = a
    for j in range(n):
        k = order[j]
        if lo[k] > cur:
            return True
        cur = max(cur, hi[k])
        if cur >= b:
            return False
    return True


@njit(cache=True, nogil=True)
def _sweep_hits(grid: SweepGrid, points: np.ndarray, distance: float, tol: float, first: bool) -> np.ndarray:
    """For each point q (n, 3): does the segment q + u Z, u in [0, distance], meet the closed mesh eroded by `tol`
    (<= grid.grow)? (n,) bool; with `first`, the points after the first hit are left False."""
    T, start, items = grid.triangles, grid.start, grid.items
    ox, oy, cx, cy = grid.origin[0], grid.origin[1], grid.cell[0], grid.cell[1]
    gx, gy = grid.shape[0], grid.shape[1]
    n = points.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    width = 1
    for c in range(gx * gy):
        width = max(width, start[c + 1] - start[c])
    zs = np.empty(width)
    signs = np.empty(width, dtype=np.int64)
    nlo = np.empty(width)
    nhi = np.empty(width)
    seg_a = np.empty(width + 1)
    seg_b = np.empty(width + 1)
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        ix = int(math.floor((px - ox) / cx))
        iy = int(math.floor((py - oy) / cy))
        if ix < 0 or iy < 0 or ix >= gx or iy >= gy:
            continue
        cell = ix * gy + iy
        s0, s1 = start[cell], start[cell + 1]
        nc = 0
        for k in range(s0, s1):
            sign, z = _crossing(T[items[k]], px, py)
            if sign != 0:
                zs[nc] = z
                signs[nc] = sign
                nc += 1
        if nc == 0:
            continue
        # the parts of [0, distance] inside the mesh
        order = np.argsort(zs[:nc])
        ns = 0
        w = 0
        z_prev = 0.0
        for j in range(nc):
            z = zs[order[j]]
            if w > 0:
                a = max(z_prev - pz, 0.0)
                b = min(z - pz, distance)
                if a <= b:
                    seg_a[ns] = a
                    seg_b[ns] = b
                    ns += 1
            w += signs[order[j]]
            z_prev = z
        if ns == 0:
            continue
        if tol <= 0.0:
            out[i] = True
        else:
            lo_u, hi_u = seg_a[0], seg_b[ns - 1]
            nn = 0
            for k in range(s0, s1):
                t = items[k]
                zmin = min(T[t, 0, 2], min(T[t, 1, 2], T[t, 2, 2])) - pz
                zmax = max(T[t, 0, 2], max(T[t, 1, 2], T[t, 2, 2])) - pz
                if zmax + tol < lo_u or zmin - tol > hi_u or _xy_distance(T[t], px, py) > tol:
                    continue
                lo, hi = _near_interval(T[t], px, py, pz, tol)
                if lo <= hi:
                    nlo[nn] = lo
                    nhi[nn] = hi
                    nn += 1
            near = np.argsort(nlo[:nn])
            for j in range(ns):
                if _uncovered(seg_a[j], seg_b[j], nlo, nhi, near, nn):
                    out[i] = True
                    break
        if out[i] and first:
            return out
    return out
