"""Criterion `collision` for a suction cup: the cup and the tool behind it, on their way from the pre-grasp pose to
the contact, clear of the part's triangles.

In the grasp frame (origin at the contact, +Z the approach) the tool moves along +Z by `pregrasp_clearance` c from
the pre-grasp pose to the contact; a solid moved along its own axis sweeps the same solid lengthened by c. So:
- the cup sweeps the cylinder of radius cup_radius over z in [-(cup_height + c), z_front], z_front =
  min(lip's shallowest depth, 0) - lip_clearance: the lip itself touches the part and the bellows follow it, so the
  cup's solid starts just behind both the lip and the contact (SuctionModel.lip_clearance);
- a cylinder tool sweeps the cylinder of its radius over z in [-(cup_height + length + c), -cup_height];
- a body mesh (not round: tested at every roll about +Z, 2 pi k / rolls, as the jaws' criterion (d)) sweeps
  the body moved along -Z by c: a part triangle w meets it exactly when the prism conv(w, w + c Z) meets one of the
  body's triangles (graspgen.collision.tri_meets_solid, after turning the frame so that +Z becomes -X, the axis
  that test sweeps along).

A triangle meets a cylinder (axis Z, radius R, z in [z0, z1]) exactly when the part of it within the slab
z0 <= z <= z1 (a convex polygon, the triangle clipped by the two planes) comes within R of the axis: in the (x, y)
plane the polygon contains the origin or one of its edges passes within R of it. Touching counts as meeting (a
guard band far beyond rounding).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..collision import TriangleTree, tri_meets_solid, triangles_near_segment
from ._seal import roll0_axes

__all__ = ["CollisionRule", "collision_kernel", "body_frame"]

_CHUNK = 64
_STACK = 128

#: cup: radius, back (z of the cup's swept end, -(cup_height + c)), clearance (lip_clearance); tool cylinder:
#: tool_radius (0: none), tool_z0, tool_z1; body: body_radius, body_z0, body_z1 (the body's bounding cylinder about
#: Z, swept; the body itself is a TriangleTree beside the rule), sweep (c); rolls: roll_cos, roll_sin (R,); guard:
#: the guard band, metres
CollisionRule = namedtuple(
    "CollisionRule",
    [
        "radius",
        "back",
        "clearance",
        "tool_radius",
        "tool_z0",
        "tool_z1",
        "body_radius",
        "body_z0",
        "body_z1",
        "sweep",
        "roll_cos",
        "roll_sin",
        "guard",
    ],
)


def body_frame(vertices: np.ndarray) -> np.ndarray:
    """The body's vertices (n, 3) in the frame where the grasp frame's +Z is -X, (x, y, z) -> (-z, y, x) (a
    rotation): tri_meets_solid sweeps along -X."""
    v = np.asarray(vertices, dtype=np.float64)
    return np.ascontiguousarray(np.column_stack([-v[:, 2], v[:, 1], v[:, 0]]))


def collision_kernel(
    tree: TriangleTree,
    points: np.ndarray,
    approach: np.ndarray,
    depth_min: np.ndarray,
    rule: CollisionRule,
    body: TriangleTree,
) -> np.ndarray:
    """(n, R) bool: the rolls at which cup and tool are clear (module docstring), for contacts `points` (n, 3),
    unit approaches `approach` (n, 3) and the lips' shallowest depths `depth_min` (n,), metres. `body`: the body
    mesh's tree in body_frame, or one without triangles for a cylinder tool (then every roll is free or none)."""
    n = len(points)
    free = np.zeros((n, len(rule.roll_cos)), dtype=np.bool_)
    if n:
        P, A = np.ascontiguousarray(points), np.ascontiguousarray(approach)
        _collide(tree, P, A, np.ascontiguousarray(depth_min, dtype=np.float64), rule, body, free)
    return free


@njit(parallel=True, cache=True, error_model="numpy")
def _collide(
    tree: TriangleTree,
    P: np.ndarray,
    A: np.ndarray,
    dmin: np.ndarray,
    rule: CollisionRule,
    body: TriangleTree,
    free: np.ndarray,
) -> None:
    n = P.shape[0]
    m = max(tree.triangles.shape[0], 1)
    chunks = (n + _CHUNK - 1) // _CHUNK
    for c in prange(chunks):
        idx = np.empty(m, dtype=np.int64)
        stack = np.empty(_STACK, dtype=np.int64)
        scratch = np.empty((2, 3, 3))
        solid_stack = np.empty(_STACK, dtype=np.int64)
        for i in range(c * _CHUNK, min((c + 1) * _CHUNK, n)):
            z_front = min(dmin[i], 0.0) - rule.clearance
            clear = _cylinder_clear(tree, P[i], A[i], rule.radius, rule.back, z_front, rule.guard, idx, stack)
            if clear and rule.tool_radius > 0.0:
                clear = _cylinder_clear(
                    tree, P[i], A[i], rule.tool_radius, rule.tool_z0, rule.tool_z1, rule.guard, idx, stack
                )
            if not clear:
                continue
            if body.triangles.shape[0] == 0:
                free[i, :] = True
            else:
                _body_rolls(tree, body, P[i], A[i], rule, free[i], idx, stack, (scratch, solid_stack))


@njit(cache=True, error_model="numpy")
def _cylinder_clear(
    tree: TriangleTree,
    p: np.ndarray,
    a: np.ndarray,
    R: float,
    z0: float,
    z1: float,
    guard: float,
    idx: np.ndarray,
    stack: np.ndarray,
) -> bool:
    """Whether no triangle meets the cylinder of radius R about the axis through p along a, z in [z0, z1]."""
    if z1 < z0:
        return True
    q0 = (p[0] + z0 * a[0], p[1] + z0 * a[1], p[2] + z0 * a[2])
    q1 = (p[0] + z1 * a[0], p[1] + z1 * a[1], p[2] + z1 * a[2])
    count = triangles_near_segment(tree, q0, q1, R + guard, idx, stack)
    xx, xy, xz, yx, yy, yz = roll0_axes(a[0], a[1], a[2])
    T = tree.triangles
    loc = np.empty((3, 3))
    for k in range(count):
        t = idx[k]
        for v in range(3):
            dx, dy, dz = T[t, v, 0] - p[0], T[t, v, 1] - p[1], T[t, v, 2] - p[2]
            loc[v, 0] = dx * xx + dy * xy + dz * xz
            loc[v, 1] = dx * yx + dy * yy + dz * yz
            loc[v, 2] = dx * a[0] + dy * a[1] + dz * a[2]
        if triangle_meets_cylinder(loc, R, z0, z1, guard):
            return False
    return True


@njit(cache=True, error_model="numpy")
def triangle_meets_cylinder(tri: np.ndarray, R: float, z0: float, z1: float, guard: float) -> bool:
    """Does the triangle tri (3, 3) meet the closed cylinder x^2 + y^2 <= R^2, z0 <= z <= z1 (within `guard`)?
    The triangle clipped to the slab (at most 5 corners), then the distance of that convex polygon from the axis
    in the (x, y) plane."""
    lo = min(tri[0, 2], tri[1, 2], tri[2, 2])
    hi = max(tri[0, 2], tri[1, 2], tri[2, 2])
    if lo > z1 + guard or hi < z0 - guard:
        return False
    poly = np.empty((5, 3))
    for v in range(3):
        poly[v, 0], poly[v, 1], poly[v, 2] = tri[v, 0], tri[v, 1], tri[v, 2]
    count = _clip(poly, 3, z0 - guard, 1.0)
    count = _clip(poly, count, -(z1 + guard), -1.0)
    if count == 0:
        return False
    # the polygon's distance from the origin of the (x, y) plane
    reach = (R + guard) * (R + guard)
    pos = neg = False
    for j in range(count):
        k = (j + 1) % count
        x0, y0 = poly[j, 0], poly[j, 1]
        ex, ey = poly[k, 0] - x0, poly[k, 1] - y0
        cross = ex * (-y0) - ey * (-x0)
        pos = pos or cross > 0.0
        neg = neg or cross < 0.0
        ee = ex * ex + ey * ey
        t = 0.0 if ee <= 0.0 else min(max(-(x0 * ex + y0 * ey) / ee, 0.0), 1.0)
        cx, cy = x0 + t * ex, y0 + t * ey
        if cx * cx + cy * cy <= reach:
            return True
    return (pos and not neg) or (neg and not pos)


@njit(cache=True, error_model="numpy")
def _clip(poly: np.ndarray, count: int, level: float, sign: float) -> int:
    """Clip the polygon poly[:count] (rows x, y, z) to sign * z >= level in place (Sutherland-Hodgman); returns the
    new corner count (at most count + 1)."""
    out = np.empty((6, 3))
    n = 0
    for j in range(count):
        k = (j + 1) % count
        sj = sign * poly[j, 2] - level
        sk = sign * poly[k, 2] - level
        if sj >= 0.0:
            out[n] = poly[j]
            n += 1
        if (sj >= 0.0) != (sk >= 0.0):
            t = sj / (sj - sk)
            for c in range(3):
                out[n, c] = poly[j, c] + t * (poly[k, c] - poly[j, c])
            n += 1
    for j in range(n):
        poly[j] = out[j]
    return n


@njit(cache=True, error_model="numpy")
def _body_rolls(
    tree: TriangleTree,
    body: TriangleTree,
    p: np.ndarray,
    a: np.ndarray,
    rule: CollisionRule,
    free: np.ndarray,
    idx: np.ndarray,
    stack: np.ndarray,
    work: tuple[np.ndarray, np.ndarray],
) -> None:
    """free[k] = whether the swept body misses every part triangle at roll k (the triangles near its bounding
    cylinder, each turned into the roll's frame and then into body_frame)."""
    free[:] = True
    z0, z1 = rule.body_z0, rule.body_z1
    q0 = (p[0] + z0 * a[0], p[1] + z0 * a[1], p[2] + z0 * a[2])
    q1 = (p[0] + z1 * a[0], p[1] + z1 * a[1], p[2] + z1 * a[2])
    count = triangles_near_segment(tree, q0, q1, rule.body_radius + rule.guard, idx, stack)
    xx, xy, xz, yx, yy, yz = roll0_axes(a[0], a[1], a[2])
    T = tree.triangles
    scratch, solid_stack = work
    local = scratch[0]
    w = scratch[1]
    A = np.empty((3, 3))
    left = free.shape[0]
    for q in range(count):
        t = idx[q]
        for v in range(3):
            dx, dy, dz = T[t, v, 0] - p[0], T[t, v, 1] - p[1], T[t, v, 2] - p[2]
            local[v, 0] = dx * xx + dy * xy + dz * xz
            local[v, 1] = dx * yx + dy * yy + dz * yz
            local[v, 2] = dx * a[0] + dy * a[1] + dz * a[2]
        if not triangle_meets_cylinder(local, rule.body_radius, z0, z1, rule.guard):
            continue
        for k in range(free.shape[0]):
            if not free[k]:
                continue
            c, s = rule.roll_cos[k], rule.roll_sin[k]
            for v in range(3):
                # the roll's frame: X = cos X0 + sin Y0; then (x, y, z) -> (-z, y, x)
                x = c * local[v, 0] + s * local[v, 1]
                y = -s * local[v, 0] + c * local[v, 1]
                w[v, 0], w[v, 1], w[v, 2] = -local[v, 2], y, x
            # int(0), not 0: numba specialises a callee on a literal argument, and the jaws call it with a variable
            if tri_meets_solid(w, body, int(0), 0.0, rule.sweep, rule.guard, A, solid_stack):  # noqa: UP018
                free[k] = False
                left -= 1
                if left == 0:
                    return
