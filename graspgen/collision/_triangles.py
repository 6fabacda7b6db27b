"""The mesh-exact check, criterion (d) against the part's own triangles (`mesh_free_rolls`).

The point test can miss a feature that falls between samples; here every roll it left free is tested again,
exactly: a roll stays free only when no triangle of the part meets any region at that roll (a box region: the closed
box, by Akenine-Moeller's separating axes; a mesh region, a finger or body from CAD: the solid itself over the
finger's travel, _tritree.tri_meets_solid).

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
    MOVES,
    RMAX,
    RMIN,
    SOLID,
    YC,
    ZHI,
    ZLO,
    CollisionModel,
    finger_travel,
    finger_x_ranges,
    fixed_x_ranges,
    region_table,
)
from ._tritree import (
    COUNT,
    LEAF,
    LEFT,
    M_C,
    M_H,
    M_OAX,
    M_OC,
    M_OH,
    M_R,
    RIGHT,
    START,
    MeshTree,
    tri_box,
    tri_meets_solid,
)

if TYPE_CHECKING:
    from ._frame import Candidates, Rolls
    from ._regions import Regions
    from ._tritree import TriangleTree

__all__ = ["mesh_free_rolls", "mesh_free_rolls_of_pairs"]

#: candidates per unit of parallel work
_CHUNK = 256
#: per size class above the leaves, that range is taken while it has turned a finger away at least at every other
#: try (counted per thread and chunk, after the first _EXACT_TRIES tries)
_EXACT_TRIES = 32

#: a thread's working arrays of the mesh-exact walk: F (12,) the candidate's midpoint, X, Y0, Z0; rx (r, 2) the
#: regions' bounds along X; boxes_c, boxes_e (r, 3) their centres and half extents in a roll's grasp frame; rot
#: (R, 6) each roll's Y and Z in the object frame; tri (2, 3, 3) a triangle in the roll-0 frame and at a roll; stack
#: (128,) nodes; masks (128, r) per stack entry and region the rolls to test; hit (r,); ob (15,) a node's oriented box
#: in the roll-0 frame; tally (8, 2) per size class the exact ranges taken and the fingers they turned away.
#: travel (2,): the fingers' (s, L) for a mesh finger (tri_meets_solid); solid_tri (3, 3), solid_stack (128,): the
#: scratch of tri_meets_solid.
MeshWork = namedtuple(
    "MeshWork",
    [
        "F",
        "rx",
        "boxes_c",
        "boxes_e",
        "rot",
        "tri",
        "stack",
        "masks",
        "hit",
        "ob",
        "tally",
        "travel",
        "solid_tri",
        "solid_stack",
    ],
)


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
    """Does [x_lo, x_hi] meet the slab of a finger region (rows 0 and 1) that still has rolls to test at stack
    entry `top`?"""
    for r in range(FINGER_ROWS):  # noqa: SIM110 (numba compiles no generator passed to any())
        if masks[top, r] & ~blocked and rx[r, 0] <= x_hi and x_lo <= rx[r, 1]:
            return True
    return False


@njit(cache=True, error_model="numpy")
def _walk(
    todo: np.uint64,
    tree: TriangleTree,
    regions: Regions,
    rolls: Rolls,
    solids: tuple[TriangleTree, TriangleTree, TriangleTree],
    g: float,
    work: MeshWork,
) -> np.uint64:
    """The rolls of `todo` at which some triangle meets some region, for the candidate in work.F (midpoint, X, Y0,
    Z0) with its regions in work.rx, work.boxes_c, work.boxes_e: one walk of the tree carrying, per region, the rolls
    still to test. A region of a mesh solid (column SOLID: its index in `solids`) is the solid's bounding box for the
    walk; a triangle that meets that box is tested against the solid itself (tri_meets_solid). Its own function,
    called from the parallel loop (inlined in the loop's body it ran slower)."""
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
            while c > LEAF:
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
                        sol = int(rows[r, SOLID])
                        if sol < 0:
                            blocked |= bit
                        else:
                            moves = int(rows[r, MOVES])
                            s_at, sweep = (work.travel[0], work.travel[1]) if moves != 0 else (0.0, 0.0)
                            solid = solids[0] if sol == 0 else (solids[1] if sol == 1 else solids[2])
                            if tri_meets_solid(w, solid, moves, s_at, sweep, g, work.solid_tri, work.solid_stack):
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


@njit(cache=True, error_model="numpy")
def _mesh_thread(
    t: np.int64,
    nthreads: int,
    cands: Candidates,
    free: np.ndarray,
    tree: TriangleTree,
    regions: Regions,
    rolls: Rolls,
    solids: tuple[TriangleTree, TriangleTree, TriangleTree],
    g: float,
) -> None:
    """Thread t's share of the mesh-exact check: chunks t, t + nthreads, ... of the candidates (the work varies
    along the candidates' spatial order, and a static split into one run per thread leaves one thread with most of
    it). Clears in free (n, R) bool every roll at which some triangle of the tree meets some region; `solids`: the
    mesh solids (left, right, body), empty trees for a gripper of boxes (whose regions name no solid)."""
    n = cands.inside.shape[0]
    R = rolls.cos.shape[0]
    nreg = regions.rows.shape[0]
    chunks = (n + _CHUNK - 1) // _CHUNK
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
        np.zeros(2),
        np.empty((3, 3)),
        np.empty(128, dtype=np.int64),
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
            work.travel[0], work.travel[1] = finger_travel(cands.inside[i], wd, regions)
            region_boxes(regions, work.rx, work.boxes_c, work.boxes_e)
            F[0], F[1], F[2] = mx, my, mz
            F[3], F[4], F[5], F[6], F[7], F[8], F[9], F[10], F[11] = ax, ay, az, yx, yy, yz, zx, zy, zz
            blocked = _walk(todo, tree, regions, rolls, solids, g, work)
            if blocked != 0:
                for rl in range(R):
                    if blocked & (np.uint64(1) << np.uint64(rl)):
                        free[i, rl] = False


@njit(parallel=True, cache=True, error_model="numpy")
def _mesh_kernel(
    cands: Candidates,
    free: np.ndarray,
    tree: TriangleTree,
    regions: Regions,
    rolls: Rolls,
    left: TriangleTree,
    right: TriangleTree,
    body: TriangleTree,
    g: float,
    nthreads: int,
) -> None:
    """The mesh-exact check over nthreads threads; left, right, body: the gripper's mesh solids (TriangleTrees, empty
    for a gripper of boxes). numba's parallel loops take flat records, so the solids' tuple is made inside; the
    thread index is cast to int64 so that the typing pass and the parallel loop (which counts in uint64) call one
    compiled _mesh_thread."""
    for t in prange(nthreads):
        _mesh_thread(np.int64(t), nthreads, cands, free, tree, regions, rolls, (left, right, body), g)


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
        regions = region_table(model)
        left, right, body = model.solid_records()
        _mesh_kernel(cands, out, tree.record(), regions, rolls, left, right, body, g, numba.get_num_threads())
    return out
