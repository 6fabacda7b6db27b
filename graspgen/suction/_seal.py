"""Criterion `seal` (and the lip plane that criterion `tilt` reads): does the cup's lip seal on the part's triangles?

Model (Dex-Net 3.0's quasi-static spring model, on the triangles rather than the samples; docs/HOLD.md). The cup's
axis is the approach a through the contact p. Probes are cast along +a, parallel to the axis, from the cup's plane
onto the part's triangles; a probe's depth d is how far beyond the contact's plane (the plane through p normal to a)
it first meets the surface.

- Lip: `lip_points` probes on the circle of radius r about the axis. Each must meet a triangle that faces the cup
  (its normal against a: the probe started outside the part), at a depth in [lo, hi] (`depth_limits`): the cone
  spring from the cup's apex, `cup_height` behind p on the axis, to the lip point strains by at most max_strain.
  None found within [lo, hi + recess_depth]: the lip leaves the part (off an edge, a rod thinner than the cup) or the
  surface falls away beyond the springs' reach (a sphere hardly larger than the cup). The perimeter springs between
  neighbouring lip points (rest length the chord c0 of the circle) strain by at most max_strain: a depth step
  between neighbours of more than c0 sqrt((1 + e)^2 - 1) (an edge, a step) fails.
- Between the lip points: probes on the lip circle every `lip_slot_spacing` (`lip_slot_probes`). Each must meet a
  triangle facing the cup no deeper than the deeper of its two neighbouring lip points plus `recess_depth`: a slot,
  groove or pit crossing under the lip, narrower than the lip points' spacing, is a channel the air leaks through.
- Interior: probes on rings between the centre and the lip (`inner_probes`). Each must meet a triangle facing the
  cup no deeper than the deepest lip point plus `recess_depth`: a hole, slot or gap under the cup (between samples
  too: the probes are denser than any hole of interest) fails.
- Lip plane: the least-squares plane d = alpha x + beta y through the lip's hit points (closed form for the regular
  ring); its normal's angle to the axis, atan(sqrt(alpha^2 + beta^2)), is the approach's tilt from the surface.

A probe's first hit: the part's triangles near the axis are gathered once per candidate (triangles_near_segment),
put in the cup's frame and binned into a GRID x GRID grid over the cup's disc; a probe tests the triangles of its
cell (2D point in triangle by edge functions, the depth interpolated). Triangles seen edge-on (a wall parallel to
the axis) have no area in the plane and are skipped: a probe along a wall meets the face beside it.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..collision import TriangleTree, triangles_near_segment

__all__ = [
    "SealPart",
    "SealRule",
    "SealOut",
    "seal_kernel",
    "roll0_axes",
    "PASS",
    "OFF",
    "DEPTH",
    "STRETCH",
    "HOLE",
    "REASONS",
]

#: a candidate's seal outcome
PASS, OFF, DEPTH, STRETCH, HOLE = 0, 1, 2, 3, 4
#: what each failure means (stats.seal and empty_reason)
REASONS = {
    OFF: "reach",  # a lip probe meets no surface facing the cup within the lip's reach (off the part, past an edge, or
    # a surface that falls away faster than the cone springs stretch)
    DEPTH: "depth",  # a lip point lies too deep or too shallow for its cone spring (curvature, a step)
    STRETCH: "stretch",  # a perimeter spring stretches more than max_strain (an edge or a crease)
    HOLE: "hole",  # a hole, slot or gap under the cup, or a slot or groove crossing under its lip
}
GRID = 8
#: every this many lip probes are tested on their own before the cup's triangles are gathered (8 of 32)
_PRETEST_STEP = 4
_CHUNK = 256
_STACK = 128

#: the part as the kernel reads it: its triangle tree and the triangles' unit normals (m, 3)
SealPart = namedtuple("SealPart", ["tree", "normals"])
#: radius, height, max_strain (the cup); lo, hi: the lip's depth window (depth_limits); recess: recess_depth;
#: lip (N, 2), slot (N m, 2) (lip_slot_probes: every m-th is lip[k / m]), inner (M, 2): probe positions in the
#: cup's (x, y) plane, metres; guard: relative guard band
SealRule = namedtuple(
    "SealRule", ["radius", "height", "max_strain", "lo", "hi", "recess", "lip", "slot", "inner", "guard"]
)
#: per candidate: status (n,) int8 (PASS or a failure), strain (n,) the largest spring strain seen, tilt (n,) rad
#: the lip plane's angle to the axis, depth_min and depth_max (n,) the lip's depth range, metres (nan when the lip
#: failed before all its points were found)
SealOut = namedtuple("SealOut", ["status", "strain", "tilt", "depth_min", "depth_max"])


@njit(cache=True, inline="always", error_model="numpy")
def roll0_axes(ax: float, ay: float, az: float) -> tuple[float, float, float, float, float, float]:
    """The roll-0 X and Y (CONTRACT.md, suction grasp frame) for the unit approach (ax, ay, az): X0 = the object's
    +X made orthogonal to Z (its +Y when |X . Z| > 0.9), Y0 = Z x X0."""
    if abs(ax) > 0.9:
        ex, ey, ez = 0.0, 1.0, 0.0
    else:
        ex, ey, ez = 1.0, 0.0, 0.0
    dot = ex * ax + ey * ay + ez * az
    xx, xy, xz = ex - dot * ax, ey - dot * ay, ez - dot * az
    inv = 1.0 / math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx * inv, xy * inv, xz * inv
    yx, yy, yz = ay * xz - az * xy, az * xx - ax * xz, ax * xy - ay * xx
    return xx, xy, xz, yx, yy, yz


def seal_kernel(part: SealPart, points: np.ndarray, approach: np.ndarray, rule: SealRule) -> SealOut:
    """The seal outcome of n candidates: contacts `points` (n, 3) and unit approaches `approach` (n, 3), metres, on
    the part's triangles (module docstring)."""
    n = len(points)
    out = SealOut(
        np.zeros(n, dtype=np.int8),
        np.zeros(n),
        np.zeros(n),
        np.full(n, np.nan),
        np.full(n, np.nan),
    )
    if n:
        _seal(part.tree, part.normals, np.ascontiguousarray(points), np.ascontiguousarray(approach), rule, out)
    return out


#: per chunk of candidates: idx (m,) gathered triangles, stack (128,), loc (m, 3, 3) kept triangles in the cup's
#: frame (x, y, depth), front (m,) whether each faces the cup, box (m, 4) its (x, y) bounds, starts (GRID^2 + 1,)
#: the cells' offsets into the item buffer, depth (N,) the lip's depths
_Scratch = namedtuple("_Scratch", ["idx", "stack", "loc", "front", "box", "starts", "depth"])


@njit(parallel=True, cache=True, error_model="numpy")
def _seal(tree: TriangleTree, normals: np.ndarray, P: np.ndarray, A: np.ndarray, rule: SealRule, out: SealOut) -> None:
    """seal_kernel's loop (numba's parallel loops take flat records: the part's record is made inside)."""
    n = P.shape[0]
    m = max(tree.triangles.shape[0], 1)
    chunks = (n + _CHUNK - 1) // _CHUNK
    for c in prange(chunks):
        scratch = _Scratch(
            np.empty(m, dtype=np.int64),
            np.empty(_STACK, dtype=np.int64),
            np.empty((m, 3, 3)),
            np.empty(m, dtype=np.bool_),
            np.empty((m, 4)),
            np.empty(GRID * GRID + 1, dtype=np.int64),
            np.empty(rule.lip.shape[0]),
        )
        items = np.empty(4 * m, dtype=np.int64)
        part = SealPart(tree, normals)
        for i in range(c * _CHUNK, min((c + 1) * _CHUNK, n)):
            items = _seal_one(part, P, A, rule, out, i, scratch, items)


@njit(cache=True, error_model="numpy")
def _seal_one(
    part: SealPart, P: np.ndarray, A: np.ndarray, rule: SealRule, out: SealOut, i: int, s: _Scratch, items: np.ndarray
) -> np.ndarray:
    """Candidate i's seal into out[i]; returns the cell item buffer (a larger one when this candidate needed it)."""
    r = rule.radius
    px, py, pz = P[i, 0], P[i, 1], P[i, 2]
    ax, ay, az = A[i, 0], A[i, 1], A[i, 2]
    xx, xy, xz, yx, yy, yz = roll0_axes(ax, ay, az)
    frame = (px, py, pz, xx, xy, xz, yx, yy, yz, ax, ay, az)
    z_lo = rule.lo
    z_hi = rule.hi + rule.recess
    g = rule.guard * (r + abs(z_lo) + abs(z_hi))
    tiny = rule.guard * r * r  # twice the area in the plane of a triangle seen edge-on
    lip = rule.lip
    nl = lip.shape[0]

    # a few lip probes on their own first (each walks the tree along its own line): most failing cups fail there,
    # before the triangles under the whole cup are gathered
    for k in range(0, nl, _PRETEST_STEP):
        d, facing = _probe(part, frame, lip[k, 0], lip[k, 1], (z_lo - g, z_hi + g), g, tiny, s)
        status = _lip_status(d, facing, rule, g)
        if status != PASS:
            out.status[i] = status
            return items

    reach = r + g
    p0 = (px + z_lo * ax, py + z_lo * ay, pz + z_lo * az)
    p1 = (px + z_hi * ax, py + z_hi * ay, pz + z_hi * az)
    count = triangles_near_segment(part.tree, p0, p1, reach, s.idx, s.stack)

    # the gathered triangles in the cup's frame, those that reach the disc and the depth window
    N = part.normals
    kept = 0
    for q in range(count):
        t = s.idx[q]
        if not _to_cup_frame(part.tree.triangles, t, frame, s.loc[kept], z_lo - g, z_hi + g):
            continue
        L = s.loc[kept]
        lo_x, hi_x = min(L[0, 0], L[1, 0], L[2, 0]), max(L[0, 0], L[1, 0], L[2, 0])
        lo_y, hi_y = min(L[0, 1], L[1, 1], L[2, 1]), max(L[0, 1], L[1, 1], L[2, 1])
        if lo_x > reach or hi_x < -reach or lo_y > reach or hi_y < -reach:
            continue
        area2 = (L[1, 0] - L[0, 0]) * (L[2, 1] - L[0, 1]) - (L[1, 1] - L[0, 1]) * (L[2, 0] - L[0, 0])
        if abs(area2) <= tiny:
            continue  # seen edge-on: a wall along the axis
        s.front[kept] = N[t, 0] * ax + N[t, 1] * ay + N[t, 2] * az < 0.0
        s.box[kept, 0], s.box[kept, 1], s.box[kept, 2], s.box[kept, 3] = lo_x, hi_x, lo_y, hi_y
        kept += 1
    items = _bin(s, kept, r, items)

    # the lip
    c0 = 2.0 * r * math.sin(math.pi / nl)
    l0 = math.hypot(r, rule.height)
    worst = 0.0
    for k in range(nl):
        d, facing = _first_hit(s, items, lip[k, 0], lip[k, 1], r, (z_lo - g, z_hi + g), tiny)
        status = _lip_status(d, facing, rule, g)
        if status != PASS:
            out.status[i] = status
            return items
        s.depth[k] = d
        worst = max(worst, abs(math.hypot(r, rule.height + d) / l0 - 1.0))
    d_min, d_max = np.inf, -np.inf
    sum_x = sum_y = 0.0
    for k in range(nl):
        d = s.depth[k]
        step = s.depth[(k + 1) % nl] - d
        worst = max(worst, math.sqrt(1.0 + (step / c0) ** 2) - 1.0)
        d_min, d_max = min(d_min, d), max(d_max, d)
        sum_x += d * lip[k, 0]
        sum_y += d * lip[k, 1]
    out.strain[i] = worst
    out.depth_min[i], out.depth_max[i] = d_min, d_max
    scale = 2.0 / (nl * r * r)
    out.tilt[i] = math.atan(math.hypot(sum_x * scale, sum_y * scale))
    if worst > rule.max_strain * (1.0 + rule.guard):
        out.status[i] = STRETCH
        return items

    # between the lip points: no slot, groove or pit crossing under the lip
    slot = rule.slot
    per = slot.shape[0] // nl
    for q in range(slot.shape[0]):
        if q % per == 0:
            continue  # a lip point
        k = q // per
        floor = max(s.depth[k], s.depth[(k + 1) % nl]) + rule.recess + g
        d, facing = _first_hit(s, items, slot[q, 0], slot[q, 1], r, (z_lo - g, floor), tiny)
        if d == np.inf or not facing:
            out.status[i] = HOLE
            return items

    # the interior: no hole, slot or gap under the cup
    inner = rule.inner
    deepest = d_max + rule.recess + g
    for k in range(inner.shape[0]):
        d, facing = _first_hit(s, items, inner[k, 0], inner[k, 1], r, (z_lo - g, deepest), tiny)
        if d == np.inf or not facing:
            out.status[i] = HOLE
            return items
    out.status[i] = PASS
    return items


@njit(cache=True, inline="always", error_model="numpy")
def _lip_status(d: float, facing: bool, rule: SealRule, g: float) -> int:
    """A lip probe's verdict from its first hit (depth d, inf: none): OFF, DEPTH or PASS."""
    if d == np.inf:
        return OFF
    if not facing or d < rule.lo - g or d > rule.hi + g:
        return DEPTH
    return PASS


@njit(cache=True, inline="always", error_model="numpy")
def _to_cup_frame(
    T: np.ndarray,
    t: int,
    frame: tuple[float, float, float, float, float, float, float, float, float, float, float, float],
    out: np.ndarray,
    z0: float,
    z1: float,
) -> bool:
    """Triangle t's corners in the cup's frame (x, y, depth) into out (3, 3); False (out partly written) when the
    triangle lies wholly outside the depths [z0, z1]. The depth first: most triangles near a curved cup are rejected
    by it alone."""
    px, py, pz, xx, xy, xz, yx, yy, yz, ax, ay, az = frame
    lo, hi = np.inf, -np.inf
    for v in range(3):
        d = (T[t, v, 0] - px) * ax + (T[t, v, 1] - py) * ay + (T[t, v, 2] - pz) * az
        out[v, 2] = d
        lo, hi = min(lo, d), max(hi, d)
    if lo > z1 or hi < z0:
        return False
    for v in range(3):
        dx, dy, dz = T[t, v, 0] - px, T[t, v, 1] - py, T[t, v, 2] - pz
        out[v, 0] = dx * xx + dy * xy + dz * xz
        out[v, 1] = dx * yx + dy * yy + dz * yz
    return True


@njit(cache=True, inline="always", error_model="numpy")
def _depth_at(L: np.ndarray, x: float, y: float, tiny: float) -> float:
    """The depth of the triangle L (3, 3) (cup frame) at (x, y), or inf when (x, y) lies outside it (2D edge
    functions, closed, within the band `tiny`) or it is seen edge-on (twice its area in the plane at most `tiny`)."""
    area2 = (L[1, 0] - L[0, 0]) * (L[2, 1] - L[0, 1]) - (L[1, 1] - L[0, 1]) * (L[2, 0] - L[0, 0])
    if abs(area2) <= tiny:
        return np.inf
    e0 = (L[2, 0] - L[1, 0]) * (y - L[1, 1]) - (L[2, 1] - L[1, 1]) * (x - L[1, 0])
    e1 = (L[0, 0] - L[2, 0]) * (y - L[2, 1]) - (L[0, 1] - L[2, 1]) * (x - L[2, 0])
    e2 = (L[1, 0] - L[0, 0]) * (y - L[0, 1]) - (L[1, 1] - L[0, 1]) * (x - L[0, 0])
    # closed, with a band of `tiny` (in the edge functions' units, twice an area): a probe on an edge shared by two
    # triangles (the spokes of a round part's face meet the lip's probes exactly) then lies in both, whatever the
    # rounding
    if area2 > 0.0:
        if e0 < -tiny or e1 < -tiny or e2 < -tiny:
            return np.inf
    elif e0 > tiny or e1 > tiny or e2 > tiny:
        return np.inf
    d: float = (e0 * L[0, 2] + e1 * L[1, 2] + e2 * L[2, 2]) / area2
    return d


@njit(cache=True, error_model="numpy")
def _probe(
    part: SealPart,
    frame: tuple[float, float, float, float, float, float, float, float, float, float, float, float],
    x: float,
    y: float,
    window: tuple[float, float],
    g: float,
    tiny: float,
    s: _Scratch,
) -> tuple[float, bool]:
    """One probe through (x, y) of the cup's plane on its own: the triangles near its line (depths `window`) from
    the tree, then the first hit as _first_hit finds it (the same arithmetic: the same answer for that probe)."""
    px, py, pz, xx, xy, xz, yx, yy, yz, ax, ay, az = frame
    z0, z1 = window
    ox, oy, oz = px + x * xx + y * yx, py + x * xy + y * yy, pz + x * xz + y * yz
    p0 = (ox + z0 * ax, oy + z0 * ay, oz + z0 * az)
    p1 = (ox + z1 * ax, oy + z1 * ay, oz + z1 * az)
    count = triangles_near_segment(part.tree, p0, p1, g, s.idx, s.stack)
    L = s.loc[0]
    best, facing = np.inf, False
    for q in range(count):
        t = s.idx[q]
        if not _to_cup_frame(part.tree.triangles, t, frame, L, z0, z1):
            continue
        d = _depth_at(L, x, y, tiny)
        if d < z0 or d > z1:
            continue
        front = part.normals[t, 0] * ax + part.normals[t, 1] * ay + part.normals[t, 2] * az < 0.0
        if d < best or (d == best and front and not facing):
            best, facing = d, front
    return best, facing


@njit(cache=True, error_model="numpy")
def _bin(s: _Scratch, kept: int, r: float, items: np.ndarray) -> np.ndarray:
    """The kept triangles into a GRID x GRID grid over [-r, r]^2 by their (x, y) bounds (s.starts: the offsets of
    each cell's items). Returns the item buffer, grown when needed."""
    cell = 2.0 * r / GRID
    counts = s.starts
    counts[:] = 0
    total = 0
    for t in range(kept):
        i0, i1, j0, j1 = _cells(s.box[t], r, cell)
        for a in range(i0, i1 + 1):
            for b in range(j0, j1 + 1):
                counts[a * GRID + b + 1] += 1
        total += (i1 - i0 + 1) * (j1 - j0 + 1)
    for k in range(GRID * GRID):
        counts[k + 1] += counts[k]
    if total > items.shape[0]:
        items = np.empty(2 * total, dtype=np.int64)
    fill = counts[:-1].copy()
    for t in range(kept):
        i0, i1, j0, j1 = _cells(s.box[t], r, cell)
        for a in range(i0, i1 + 1):
            for b in range(j0, j1 + 1):
                items[fill[a * GRID + b]] = t
                fill[a * GRID + b] += 1
    return items


@njit(cache=True, inline="always", error_model="numpy")
def _cells(bx: np.ndarray, r: float, cell: float) -> tuple[int, int, int, int]:
    """The cell index ranges (x from i0 to i1, y from j0 to j1, inclusive) that the bounds bx = (x0, x1, y0, y1)
    cover, clamped to the grid: a probe on a cell border lies in both cells' reach."""
    i0 = min(max(int(math.floor((bx[0] + r) / cell)), 0), GRID - 1)
    i1 = min(max(int(math.floor((bx[1] + r) / cell)), 0), GRID - 1)
    j0 = min(max(int(math.floor((bx[2] + r) / cell)), 0), GRID - 1)
    j1 = min(max(int(math.floor((bx[3] + r) / cell)), 0), GRID - 1)
    return i0, i1, j0, j1


@njit(cache=True, error_model="numpy")
def _first_hit(
    s: _Scratch, items: np.ndarray, x: float, y: float, r: float, window: tuple[float, float], tiny: float
) -> tuple[float, bool]:
    """(depth, faces the cup) of the first triangle that the probe through (x, y) along +a meets within depths
    `window` (z0, z1); (inf, False) when none does. A tie in depth (a probe on a shared edge) prefers a triangle
    facing the cup. The probe lies in the cell of (x, y); the triangles whose bounds reach it are in that cell's
    items (_bin puts a triangle in every cell its bounds touch, and a probe on a cell border lies in both)."""
    z0, z1 = window
    cell = 2.0 * r / GRID
    a = min(max(int(math.floor((x + r) / cell)), 0), GRID - 1)
    b = min(max(int(math.floor((y + r) / cell)), 0), GRID - 1)
    k = a * GRID + b
    best, facing = np.inf, False
    for q in range(s.starts[k], s.starts[k + 1]):
        t = items[q]
        bx = s.box[t]
        if x < bx[0] or x > bx[1] or y < bx[2] or y > bx[3]:
            continue
        d = _depth_at(s.loc[t], x, y, tiny)
        if d < z0 or d > z1:
            continue
        if d < best or (d == best and s.front[t] and not facing):
            best, facing = d, bool(s.front[t])
    return best, facing
