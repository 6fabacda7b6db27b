"""Criterion (d) against the sampled points: which rolls of each candidate leave every region free of them.

The result is exact for the points: bit for bit what testing every point against every region at every roll with
the per-point arithmetic of `_point_mask` gives (grasp-frame coordinates x = q . X, y = c_k (q . Y0) + s_k (q . Z0),
z = -s_k (q . Y0) + c_k (q . Z0), q = point - midpoint). Everything else only decides which points need that test:
node bounds are padded far beyond rounding, and every shortcut (a node wholly inside or outside a region, a point
inside the disc that every roll of a region covers, the half-turn symmetry of a symmetric region) keeps a guard band
and falls back to the per-roll test inside it. Why the search is built so: docs/design/collision.md.

Per candidate: the remembered blockers (a memo per thread keyed by grid cell, and a small cache of recent blockers),
first for the fingers, then for the fixed regions; then a walk of the point tree for the fingers; then the hull
certificate for the fixed regions (_hull.py); then a walk for the fixed regions at the rolls still open.
"""

from __future__ import annotations

import hashlib
import threading
from collections import namedtuple
from typing import TYPE_CHECKING

import numba
import numpy as np
from numba import njit, prange

from ..params import TOLERANCES
from ._bits import popcount
from ._frame import (
    Candidates,
    candidate_count,
    candidate_frame,
    candidates_of_geometry,
    candidates_of_pairs,
    roll0_basis,
    roll_table,
)
from ._hull import build_hull, hull_free
from ._regions import (
    FINGER_ROWS,
    HY,
    MOVES,
    RIN,
    RIN2,
    RMAX,
    RMAX2,
    RMIN,
    RMIN2,
    SYM,
    YC,
    ZHI,
    ZLO,
    CollisionModel,
    finger_x_ranges,
    fixed_x_ranges,
    region_table,
)

if TYPE_CHECKING:
    from ._frame import Rolls
    from ._hull import Hull
    from ._regions import Regions

__all__ = ["free_rolls", "free_rolls_of_pairs", "free_rolls_stats", "STATS"]

#: at most about this many points per leaf (the leaf count is a power of two)
_LEAF = 32
#: recent blockers kept per thread and phase (fingers, fixed regions)
_CACHE = 8
#: candidates per unit of parallel work (and per row of the work counters)
_CHUNK = 4096
#: the fingers' per-roll node tests start once at most this many (symmetric pairs of) rolls are open
_FINGER_ANGULAR = 3
#: blockers remembered per memo cell, and at most this many memo cells
_MEMO_SLOTS = 2
_MEMO_CELLS = 1 << 20
#: memo cell width over the mean leaf patch (half extents along its two longer axes, summed)
_MEMO_H = 4.0
#: the tree, given normals: a node splits along (position, weight x rms radius x normal) when its children's ball
#: radius + thickness x thinnest half extent is lower than by position alone (docs/design/collision.md)
_SPLIT_NORMAL_WEIGHT = 3.0
_SPLIT_THICKNESS = 2.0

# A tree node's columns: the oriented box (centre, three unit axes as rows with the principal one first, half
# extents), the radius of the ball around its centre that holds the node's points, the axis-aligned box (centre,
# half extents); all padded.
N_C, N_AX, N_H, N_R, N_BC, N_BH = 0, 3, 12, 15, 16, 19
_NODE = 24

#: the work counters, per chunk of candidates (free_rolls_stats)
STATS = (
    "finger_nodes",
    "finger_points",
    "palm_nodes",
    "palm_points",
    "cache_tests",
    "cache_settled",
    "memo_tests",
    "memo_settled",
)
_CACHE_TESTS, _CACHE_SETTLED, _MEMO_TESTS, _MEMO_SETTLED = 4, 5, 6, 7

#: x, y, z (n,) the points in the tree's order; nodes (2 leaves, _NODE); leaves: the first leaf's node number.
PointTree = namedtuple("PointTree", ["x", "y", "z", "nodes", "leaves"])
#: cells (threads, 2, cells, _MEMO_SLOTS): per thread, per phase (fingers, fixed) and grid cell, the points that last
#: blocked there (-1: none); grid = (origin xyz, 1 / cell size, dims xyz).
Memo = namedtuple("Memo", ["cells", "grid"])
#: everything the kernel reads that does not depend on the candidate (passed to it field by field: numba's parallel
#: loops take flat records only).
Prepared = namedtuple("Prepared", ["tree", "regions", "rolls", "hull", "memo"])
#: a thread's working arrays: the walk's stack, recent blockers caches (2, _CACHE) and their next slots pos (2,),
#: its memo (2, cells, _MEMO_SLOTS) and the memo's grid.
Work = namedtuple("Work", ["stack", "caches", "pos", "memo", "grid"])


# -- the point tree ------------------------------------------------------------------------------------------------


@njit(cache=True)
def _pca_box(
    Q: np.ndarray, order: np.ndarray, a: int, b: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The oriented box of the points Q[order[a:b]]: (mean, covariance sum, axes as rows with the principal one
    first, lower and upper bounds of the points along each axis, relative to the mean)."""
    cnt = b - a
    mean = np.zeros(3)
    for u in range(a, b):
        for c in range(3):
            mean[c] += Q[order[u], c]
    mean /= cnt
    cov = np.zeros((3, 3))
    for u in range(a, b):
        q = order[u]
        for c in range(3):
            for d in range(3):
                cov[c, d] += (Q[q, c] - mean[c]) * (Q[q, d] - mean[d])
    _, V = np.linalg.eigh(cov)
    ax = np.empty((3, 3))
    for i in range(3):
        for c in range(3):
            ax[i, c] = V[c, 2 - i]  # principal axis first
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for u in range(a, b):
        q = order[u]
        for i in range(3):
            pr = (Q[q, 0] - mean[0]) * ax[i, 0] + (Q[q, 1] - mean[1]) * ax[i, 1] + (Q[q, 2] - mean[2]) * ax[i, 2]
            lo[i] = min(lo[i], pr)
            hi[i] = max(hi[i], pr)
    return mean, cov, ax, lo, hi


@njit(cache=True)
def _split_cost(Q: np.ndarray, order: np.ndarray, a: int, b: int, thick: float) -> float:
    """Cost of a child holding the points Q[order[a:b]]: the radius of the ball around its oriented box plus
    `thick` times the box's thinnest half extent (the fingers' slab test is as tight as a node is thin)."""
    _, _, _, lo, hi = _pca_box(Q, order, a, b)
    r2 = 0.0
    thin = np.inf
    for i in range(2, -1, -1):
        h = 0.5 * (hi[i] - lo[i])
        r2 += h * h
        thin = min(thin, h)
    cost: float = np.sqrt(r2) + thick * thin
    return cost


@njit(cache=True)
def _build_tree(
    P: np.ndarray, N: np.ndarray, leaves: int, pad: float, weight: float, thick: float
) -> tuple[np.ndarray, np.ndarray]:
    """Balanced implicit binary tree over a permutation of the points P (n, 3): node 1 is the root, children 2k and
    2k + 1, leaves from `leaves` on. Node k at depth d (t = k - 2^d) holds the points [t n >> d, (t + 1) n >> d) of
    the permuted order. Each inner node splits its points at the median along their principal axis or, given the
    points' normals N (else N has no rows), along the principal axis of (position, `weight` x the node's rms radius x
    normal), whichever gives the children of lower _split_cost: the second parts a part's faces at its edges, so
    that nodes are thin surface patches.

    Returns (perm, nodes): nodes (2 leaves, _NODE), see the column names N_*, padded by `pad`. The oriented box
    suits surface patches, the axis-aligned one the corners and edges of parts modelled along their axes; the tests
    use both."""
    n = P.shape[0]
    with_normals = N.shape[0] == n
    Q = P.copy()
    Nq = N.copy()
    perm = np.arange(n)
    ident = np.arange(n)  # _pca_box over Q[s:e] in place
    nodes = np.zeros((2 * leaves, _NODE))
    depth = 0
    cov6 = np.zeros((6, 6))
    v6 = np.empty(6)
    for node in range(1, 2 * leaves):
        if node >= (1 << (depth + 1)):
            depth += 1
        t = node - (1 << depth)
        s = (t * n) >> depth
        e = ((t + 1) * n) >> depth
        cnt = e - s
        mean, cov, ax, lo, hi = _pca_box(Q, ident, s, e)
        c = mean.copy()
        for i in range(3):
            for a in range(3):
                c[a] += ax[i, a] * 0.5 * (lo[i] + hi[i])
        rho = 0.0
        for p in range(s, e):
            dx, dy, dz = Q[p, 0] - c[0], Q[p, 1] - c[1], Q[p, 2] - c[2]
            rho = max(rho, dx * dx + dy * dy + dz * dz)
        nodes[node, N_C : N_C + 3] = c
        for i in range(3):
            nodes[node, N_AX + 3 * i : N_AX + 3 + 3 * i] = ax[i]
            nodes[node, N_H + i] = 0.5 * (hi[i] - lo[i]) + pad
        nodes[node, N_R] = np.sqrt(rho) + pad
        for a in range(3):
            a_lo, a_hi = np.inf, -np.inf
            for p in range(s, e):
                a_lo = min(a_lo, Q[p, a])
                a_hi = max(a_hi, Q[p, a])
            nodes[node, N_BC + a] = 0.5 * (a_lo + a_hi)
            nodes[node, N_BH + a] = 0.5 * (a_hi - a_lo) + pad
        if node >= leaves:
            continue
        key = np.empty(cnt)
        for p in range(s, e):
            key[p - s] = Q[p, 0] * ax[0, 0] + Q[p, 1] * ax[0, 1] + Q[p, 2] * ax[0, 2]
        o = np.argsort(key, kind="mergesort")
        if with_normals:
            nm = np.zeros(3)
            for p in range(s, e):
                for a in range(3):
                    nm[a] += Nq[p, a]
            nm /= cnt
            sc = weight * np.sqrt((cov[0, 0] + cov[1, 1] + cov[2, 2]) / cnt)
            cov6[:, :] = 0.0
            for p in range(s, e):
                for a in range(3):
                    v6[a] = Q[p, a] - mean[a]
                    v6[3 + a] = sc * (Nq[p, a] - nm[a])
                for a in range(6):
                    for b in range(6):
                        cov6[a, b] += v6[a] * v6[b]
            _, V6 = np.linalg.eigh(cov6)
            for p in range(s, e):
                kk = 0.0
                for a in range(3):
                    kk += (Q[p, a] - mean[a]) * V6[a, 5] + sc * (Nq[p, a] - nm[a]) * V6[3 + a, 5]
                key[p - s] = kk
            o6 = np.argsort(key, kind="mergesort")
            # the children: [s, m) and [m, e) of the sorted order
            m = (((2 * t + 1) * n) >> (depth + 1)) - s
            Qs = Q[s:e]
            by_pos = _split_cost(Qs, o, 0, m, thick) + _split_cost(Qs, o, m, cnt, thick)
            if _split_cost(Qs, o6, 0, m, thick) + _split_cost(Qs, o6, m, cnt, thick) < by_pos:
                o = o6
            Nq[s:e] = Nq[s:e][o]
        Q[s:e] = Q[s:e][o]
        perm[s:e] = perm[s:e][o]
    return perm, nodes


# -- the per-point test ----------------------------------------------------------------------------------------------


@njit(cache=True, inline="always", error_model="numpy")
def _point_mask(
    tree: PointTree,
    p: int,
    F: np.ndarray,
    rows: np.ndarray,
    r0: int,
    r1: int,
    xr: np.ndarray,
    rolls: Rolls,
    todo: np.uint64,
) -> np.uint64:
    """The rolls within `todo` at which point p of the tree lies in one of the regions r0..r1-1: the exact per-roll
    arithmetic (see the module docstring). F: the candidate's midpoint, X, Y0, Z0 (12 floats); xr (r, 2): the
    regions' bounds along X for this candidate."""
    qx = tree.x[p] - F[0]
    qy = tree.y[p] - F[1]
    qz = tree.z[p] - F[2]
    x = qx * F[3] + qy * F[4] + qz * F[5]
    cos_k, sin_k, half = rolls.cos, rolls.sin, rolls.half
    mask = np.uint64(0)
    for r in range(r0, r1):
        if x < xr[r, 0] or x > xr[r, 1]:
            continue
        y0 = qx * F[6] + qy * F[7] + qz * F[8]
        z0 = qx * F[9] + qy * F[10] + qz * F[11]
        r2 = y0 * y0 + z0 * z0
        if r2 > rows[r, RMAX2] or r2 < rows[r, RMIN2]:
            continue
        if r2 <= rows[r, RIN2]:
            return todo  # inside the disc that the region covers at every roll
        yc, hy, zlo, zhi = rows[r, YC], rows[r, HY], rows[r, ZLO], rows[r, ZHI]
        left = todo & ~mask
        if half > 0 and rows[r, SYM] != 0.0:
            # roll k + half turns (y, z) into (-y, -z) up to rounding of the tables: bounded by g
            g = np.sqrt(r2) * rolls.gfac
            for k in range(half):
                b0 = np.uint64(1) << np.uint64(k)
                b1 = np.uint64(1) << np.uint64(k + half)
                if not (left & (b0 | b1)):
                    continue
                y = y0 * cos_k[k] + z0 * sin_k[k]
                z = -y0 * sin_k[k] + z0 * cos_k[k]
                ay = abs(y)
                if ay <= hy and z >= zlo and z <= zhi:
                    mask |= b0
                if left & b1:
                    if ay <= hy - g and z >= zlo + g and z <= zhi - g:
                        mask |= b1
                    elif ay > hy + g or z < zlo - g or z > zhi + g:
                        pass
                    else:
                        k1 = k + half
                        y1 = y0 * cos_k[k1] + z0 * sin_k[k1]
                        z1 = -y0 * sin_k[k1] + z0 * cos_k[k1]
                        if abs(y1) <= hy and z1 >= zlo and z1 <= zhi:
                            mask |= b1
        else:
            # every roll at once, branch-free (vectorised), then the rolls still open
            hit = np.uint64(0)
            if yc == 0.0:  # a region centred on the axis (every box gripper's): one subtraction less per roll
                for k in range(cos_k.shape[0]):
                    y = y0 * cos_k[k] + z0 * sin_k[k]
                    z = -y0 * sin_k[k] + z0 * cos_k[k]
                    in_k = (abs(y) <= hy) & (z >= zlo) & (z <= zhi)
                    hit |= np.uint64(in_k) << np.uint64(k)
            else:
                for k in range(cos_k.shape[0]):
                    y = y0 * cos_k[k] + z0 * sin_k[k] - yc
                    z = -y0 * sin_k[k] + z0 * cos_k[k]
                    in_k = (abs(y) <= hy) & (z >= zlo) & (z <= zhi)
                    hit |= np.uint64(in_k) << np.uint64(k)
            mask |= hit & left
        mask &= todo
        if mask == todo:
            return todo
    return mask


# -- remembered blockers ---------------------------------------------------------------------------------------------


@njit(cache=True, inline="always", error_model="numpy")
def _cell(grid: np.ndarray, x: float, y: float, z: float) -> int:
    """Index of the memo cell holding (x, y, z); grid = origin xyz, 1 / cell size, dims xyz. -1 outside."""
    i = int(np.floor((x - grid[0]) * grid[3]))
    j = int(np.floor((y - grid[1]) * grid[3]))
    k = int(np.floor((z - grid[2]) * grid[3]))
    nx, ny, nz = int(grid[4]), int(grid[5]), int(grid[6])
    if i < 0 or j < 0 or k < 0 or i >= nx or j >= ny or k >= nz:
        return -1
    return (i * ny + j) * nz + k


@njit(cache=True, inline="always", error_model="numpy")
def _palm_key_z(rows: np.ndarray, r: int) -> float:
    """Where along Z the fixed regions' memo key lies: the centre of region r's front, as deep as the region is wide
    (or the region's centre if it is shallower). The approach region reaches a part's length behind the fingers,
    mostly outside the memo's grid: its front is where blockers recur."""
    z: float = max(0.5 * (rows[r, ZLO] + rows[r, ZHI]), rows[r, ZHI] - rows[r, HY])
    return z


@njit(cache=True, inline="always", error_model="numpy")
def _palm_cell(grid: np.ndarray, F: np.ndarray, zm: float, ck: float, sk: float) -> int:
    """Memo cell of the fixed regions' key at the roll (cos, sin) = (ck, sk): midpoint + zm Z."""
    zx = ck * F[9] - sk * F[6]
    zy = ck * F[10] - sk * F[7]
    zz = ck * F[11] - sk * F[8]
    return _cell(grid, F[0] + zm * zx, F[1] + zm * zy, F[2] + zm * zz)


@njit(cache=True, inline="always", error_model="numpy")
def _remember(memo: np.ndarray, phase: int, cell: int, p: int) -> None:
    """Point p blocked in memo cell `cell` (phase 0: fingers, 1: fixed regions): it goes first, the others move down."""
    if cell >= 0 and memo[phase, cell, 0] != p:
        for slot in range(memo.shape[2] - 1, 0, -1):
            memo[phase, cell, slot] = memo[phase, cell, slot - 1]
        memo[phase, cell, 0] = p


@njit(cache=True, inline="always", error_model="numpy")
def _phase_rows(regions: Regions, phase: int) -> tuple[int, int]:
    """The rows a phase tests: the fingers (phase 0) or the fixed regions (phase 1)."""
    if phase == 0:
        return 0, FINGER_ROWS
    return FINGER_ROWS, regions.rows.shape[0]


@njit(cache=True, inline="always", error_model="numpy")
def _probe(
    F: np.ndarray,
    tree: PointTree,
    regions: Regions,
    rolls: Rolls,
    xr: np.ndarray,
    target: np.uint64,
    phase: int,
    work: Work,
    cell0: int,
    cell1: int,
    st: np.ndarray,
) -> np.uint64:
    """The rolls within `target` blocked by the phase's regions at the remembered blockers: the memo, then the
    thread's cache. Inlined: most candidates end here, without a call.

    work.memo[0, cell] holds the points that last blocked a finger whose contact lies in that grid cell, [1, cell]
    those that last blocked a fixed region whose key (_palm_key_z) lies in it: hints, never trusted without the
    exact test. cell0, cell1: the cells of this candidate's contacts, -1 for none."""
    rows = regions.rows
    r0, r1 = _phase_rows(regions, phase)
    mask = np.uint64(0)
    memo = work.memo
    slots = memo.shape[2]
    if phase == 0:
        for cell in (cell0, cell1):
            if cell < 0:
                continue
            for slot in range(slots):
                p = memo[0, cell, slot]
                if p < 0:
                    continue
                st[_MEMO_TESTS] += 1
                mask |= _point_mask(tree, p, F, rows, r0, r1, xr, rolls, target & ~mask)
                if mask == target:
                    st[_MEMO_SETTLED] += 1
                    return mask
    else:
        zm = _palm_key_z(rows, r0)
        for k in range(rolls.cos.shape[0]):
            if not (target & ~mask & (np.uint64(1) << np.uint64(k))):
                continue
            cell = _palm_cell(work.grid, F, zm, rolls.cos[k], rolls.sin[k])
            if cell < 0:
                continue
            for slot in range(slots):
                p = memo[1, cell, slot]
                if p < 0:
                    continue
                st[_MEMO_TESTS] += 1
                mask |= _point_mask(tree, p, F, rows, r0, r1, xr, rolls, target & ~mask)
                if mask == target:
                    st[_MEMO_SETTLED] += 1
                    return mask
    cache = work.caches[phase]
    for c in range(cache.shape[0]):
        p = cache[c]
        if p < 0:
            continue
        st[_CACHE_TESTS] += 1
        mask |= _point_mask(tree, p, F, rows, r0, r1, xr, rolls, target & ~mask)
        if mask == target:
            st[_CACHE_SETTLED] += 1
            return mask
    return mask


# -- the walk --------------------------------------------------------------------------------------------------------


@njit(cache=True, inline="always", error_model="numpy")
def _node_axes_separate(
    nd: np.ndarray,
    box: tuple[float, float, float, float, float, float],
    p: tuple[float, float, float],
    yv: tuple[float, float, float],
    zv: tuple[float, float, float],
    cv: tuple[float, float, float],
) -> bool:
    """Whether one of the node's box axes v_i separates it from a region's box: box = (centre x, y, z, half
    extents x, y, z) in the grasp frame at the roll; p, yv, zv: v_i . (X, Y, Z) at the roll; cv: v_i . (node centre
    - midpoint)."""
    xm, ym, zm, xh, yh, zh = box
    if abs(xm * p[0] + ym * yv[0] + zm * zv[0] - cv[0]) > xh * abs(p[0]) + yh * abs(yv[0]) + zh * abs(zv[0]) + nd[N_H]:
        return True
    if (
        abs(xm * p[1] + ym * yv[1] + zm * zv[1] - cv[1])
        > xh * abs(p[1]) + yh * abs(yv[1]) + zh * abs(zv[1]) + nd[N_H + 1]
    ):
        return True
    separate: bool = (
        abs(xm * p[2] + ym * yv[2] + zm * zv[2] - cv[2])
        > xh * abs(p[2]) + yh * abs(yv[2]) + zh * abs(zv[2]) + nd[N_H + 2]
    )
    return separate


@njit(cache=True, inline="always", error_model="numpy")
def _axis_dist2(nd: np.ndarray, F: np.ndarray) -> float:
    """Squared distance of a node's centre from the closing axis."""
    cx, cy, cz = nd[N_C] - F[0], nd[N_C + 1] - F[1], nd[N_C + 2] - F[2]
    x = cx * F[3] + cy * F[4] + cz * F[5]
    d2: float = cx * cx + cy * cy + cz * cz - x * x
    return d2


@njit(cache=True, error_model="numpy")
def _walk(
    F: np.ndarray,
    tree: PointTree,
    regions: Regions,
    rolls: Rolls,
    xr: np.ndarray,
    target: np.uint64,
    phase: int,
    work: Work,
    cell0: int,
    cell1: int,
    st: np.ndarray,
) -> np.uint64:
    """The rolls within `target` blocked by the phase's regions (0: fingers, 1: fixed), by a walk of the point
    tree; blockers found go into the thread's cache and memo (see _probe)."""
    X, Y, Z, nodes, leaves = tree.x, tree.y, tree.z, tree.nodes, tree.leaves
    rows = regions.rows
    r0, r1 = _phase_rows(regions, phase)
    finger = phase == 0
    cos_k, sin_k, half = rolls.cos, rolls.sin, rolls.half
    stack, cache, memo = work.stack, work.caches[phase], work.memo
    n = X.shape[0]
    mask = np.uint64(0)
    ax, ay, az = F[3], F[4], F[5]
    ya, yb, yc = F[6], F[7], F[8]
    za, zb, zc = F[9], F[10], F[11]
    nrolls = cos_k.shape[0]
    sym = half > 0
    for r in range(r0, r1):
        sym = sym and rows[r, SYM] != 0.0
    kmax = half if sym else nrolls
    stack[0] = 1
    top = 1
    vis = 2 * phase
    while top > 0:
        top -= 1
        node = stack[top]
        st[vis] += 1
        nd = nodes[node]
        cx = nd[N_C] - F[0]
        cy = nd[N_C + 1] - F[1]
        cz = nd[N_C + 2] - F[2]
        rho = nd[N_R]
        xc = cx * ax + cy * ay + cz * az
        p0 = nd[N_AX] * ax + nd[N_AX + 1] * ay + nd[N_AX + 2] * az
        p1 = nd[N_AX + 3] * ax + nd[N_AX + 4] * ay + nd[N_AX + 5] * az
        p2 = nd[N_AX + 6] * ax + nd[N_AX + 7] * ay + nd[N_AX + 8] * az
        xh = min(nd[N_H] * abs(p0) + nd[N_H + 1] * abs(p1) + nd[N_H + 2] * abs(p2), rho)
        bx = nd[N_BC] - F[0]
        by = nd[N_BC + 1] - F[1]
        bz = nd[N_BC + 2] - F[2]
        xb = bx * ax + by * ay + bz * az
        xbh = nd[N_BH] * abs(ax) + nd[N_BH + 1] * abs(ay) + nd[N_BH + 2] * abs(az)
        x_lo = max(xc - xh, xb - xbh)
        x_hi = min(xc + xh, xb + xbh)
        yc0 = cx * ya + cy * yb + cz * yc
        zc0 = cx * za + cy * zb + cz * zc
        dp = np.sqrt(yc0 * yc0 + zc0 * zc0)
        hit = False
        todo = target & ~mask
        for r in range(r0, r1):
            if x_hi < xr[r, 0] or x_lo > xr[r, 1]:
                continue
            if dp - rho > rows[r, RMAX] or dp + rho < rows[r, RMIN]:
                continue
            x_in = x_lo >= xr[r, 0] and x_hi <= xr[r, 1]
            if x_in and dp + rho <= rows[r, RIN]:
                return target  # the node lies where every roll of this region is
            angular: bool | np.bool = True
            if finger:
                open_ = todo
                if sym:
                    open_ = (todo | (todo >> np.uint64(half))) & ((np.uint64(1) << np.uint64(half)) - np.uint64(1))
                angular = popcount(open_) <= _FINGER_ANGULAR
            if not angular:
                hit = True
                break
            # the node's ball against the region at every roll at once (branch-free: vectorised), then the
            # oriented box projected onto the roll's Y and Z axes at the open rolls the ball reaches
            ryc, hy, zlo, zhi = rows[r, YC], rows[r, HY], rows[r, ZLO], rows[r, ZHI]
            near = np.uint64(0)
            ball_in = np.uint64(0)
            if ryc == 0.0:  # a region centred on the axis (every box gripper's): one subtraction less per roll
                for k in range(kmax):
                    yk = cos_k[k] * yc0 + sin_k[k] * zc0
                    zk = cos_k[k] * zc0 - sin_k[k] * yc0
                    ayk = abs(yk)
                    reach_k = (ayk - rho <= hy) & (zk + rho >= zlo) & (zk - rho <= zhi)
                    in_k = (ayk + rho <= hy) & (zk - rho >= zlo) & (zk + rho <= zhi)
                    near |= np.uint64(reach_k) << np.uint64(k)
                    ball_in |= np.uint64(in_k) << np.uint64(k)
            else:
                for k in range(kmax):
                    yk = cos_k[k] * yc0 + sin_k[k] * zc0
                    zk = cos_k[k] * zc0 - sin_k[k] * yc0
                    ayk = abs(yk - ryc)
                    reach_k = (ayk - rho <= hy) & (zk + rho >= zlo) & (zk - rho <= zhi)
                    in_k = (ayk + rho <= hy) & (zk - rho >= zlo) & (zk + rho <= zhi)
                    near |= np.uint64(reach_k) << np.uint64(k)
                    ball_in |= np.uint64(in_k) << np.uint64(k)
            if sym:
                near |= near << np.uint64(half)
                ball_in |= ball_in << np.uint64(half)
            inside = ball_in & todo if x_in else np.uint64(0)
            near &= todo & ~inside
            reach = np.uint64(0)
            if finger:
                # the ball alone for the fingers: their boxes are small next to the nodes that reach them, and the
                # per-roll box tests below cost more than they prune
                reach = near
            elif near:
                q0y = nd[N_AX] * ya + nd[N_AX + 1] * yb + nd[N_AX + 2] * yc
                q1y = nd[N_AX + 3] * ya + nd[N_AX + 4] * yb + nd[N_AX + 5] * yc
                q2y = nd[N_AX + 6] * ya + nd[N_AX + 7] * yb + nd[N_AX + 8] * yc
                q0z = nd[N_AX] * za + nd[N_AX + 1] * zb + nd[N_AX + 2] * zc
                q1z = nd[N_AX + 3] * za + nd[N_AX + 4] * zb + nd[N_AX + 5] * zc
                q2z = nd[N_AX + 6] * za + nd[N_AX + 7] * zb + nd[N_AX + 8] * zc
                cv = (
                    cx * nd[N_AX] + cy * nd[N_AX + 1] + cz * nd[N_AX + 2],
                    cx * nd[N_AX + 3] + cy * nd[N_AX + 4] + cz * nd[N_AX + 5],
                    cx * nd[N_AX + 6] + cy * nd[N_AX + 7] + cz * nd[N_AX + 8],
                )
                yb0 = bx * ya + by * yb + bz * yc
                zb0 = bx * za + by * zb + bz * zc
                # the region cut to the node's own slab along X, where all its points lie: the separation along
                # the node's axes gets far tighter for nodes small next to the palm, which is a stroke wide
                cut_lo, cut_hi = max(xr[r, 0], x_lo), min(xr[r, 1], x_hi)
                box = (0.5 * (cut_lo + cut_hi), ryc, 0.5 * (zlo + zhi), 0.5 * (cut_hi - cut_lo), hy, 0.5 * (zhi - zlo))
                for k in range(kmax):
                    bit = np.uint64(1) << np.uint64(k)
                    if sym:
                        bit |= np.uint64(1) << np.uint64(k + half)
                    if not (near & bit):
                        continue
                    ck, sk = cos_k[k], sin_k[k]
                    yk = ck * yc0 + sk * zc0
                    zk = ck * zc0 - sk * yc0
                    yv = (ck * q0y + sk * q0z, ck * q1y + sk * q1z, ck * q2y + sk * q2z)
                    zv = (ck * q0z - sk * q0y, ck * q1z - sk * q1y, ck * q2z - sk * q2y)
                    eh = nd[N_H] * abs(yv[0]) + nd[N_H + 1] * abs(yv[1]) + nd[N_H + 2] * abs(yv[2])
                    ev = nd[N_H] * abs(zv[0]) + nd[N_H + 1] * abs(zv[1]) + nd[N_H + 2] * abs(zv[2])
                    # the axis-aligned box along the roll's Y and Z: keep the tighter bound of the two boxes
                    ybk = ck * yb0 + sk * zb0
                    zbk = ck * zb0 - sk * yb0
                    ebh = (
                        nd[N_BH] * abs(ck * ya + sk * za)
                        + nd[N_BH + 1] * abs(ck * yb + sk * zb)
                        + nd[N_BH + 2] * abs(ck * yc + sk * zc)
                    )
                    ebv = (
                        nd[N_BH] * abs(ck * za - sk * ya)
                        + nd[N_BH + 1] * abs(ck * zb - sk * yb)
                        + nd[N_BH + 2] * abs(ck * zc - sk * yc)
                    )
                    y_lo = max(yk - eh, ybk - ebh)
                    y_hi = min(yk + eh, ybk + ebh)
                    z_lo = max(zk - ev, zbk - ebv)
                    z_hi = min(zk + ev, zbk + ebv)
                    if y_lo > ryc + hy or y_hi < ryc - hy or z_hi < zlo or z_lo > zhi:
                        continue
                    if x_in and y_lo >= ryc - hy and y_hi <= ryc + hy and z_lo >= zlo and z_hi <= zhi:
                        inside |= bit & todo
                        continue
                    # the node's own axes separate too (a surface patch is thin along its normal)
                    if _node_axes_separate(nd, box, (p0, p1, p2), yv, zv, cv):
                        continue
                    reach |= bit
                    if not x_in:
                        break  # no roll can be wholly inside: descend
            if inside:
                mask |= inside & target
                if mask == target:
                    return mask
                todo = target & ~mask
            if reach & todo:
                hit = True
                break
        if not hit:
            continue
        if node >= leaves:
            leaf = node - leaves
            first = (leaf * n) // leaves
            last = ((leaf + 1) * n) // leaves
            for p in range(first, last):
                st[vis + 1] += 1
                m = _point_mask(tree, p, F, rows, r0, r1, xr, rolls, target & ~mask)
                if m:
                    mask |= m
                    pos = work.pos[phase]
                    cache[pos] = p
                    work.pos[phase] = (pos + 1) % cache.shape[0]
                    if finger:
                        # finger 0 lies on the -x side of the midpoint, finger 1 on the +x side
                        x = (X[p] - F[0]) * ax + (Y[p] - F[1]) * ay + (Z[p] - F[2]) * az
                        _remember(memo, 0, cell0 if x < 0.0 else cell1, p)
                    else:
                        zm = _palm_key_z(rows, r0)
                        for k in range(nrolls):
                            if m & (np.uint64(1) << np.uint64(k)):
                                _remember(memo, 1, _palm_cell(work.grid, F, zm, cos_k[k], sin_k[k]), p)
                    if mask == target:
                        return mask
        else:
            near_c, far_c = 2 * node, 2 * node + 1
            if (_axis_dist2(nodes[far_c], F) < _axis_dist2(nodes[near_c], F)) == finger:
                # fingers: the child nearer the axis first (a blocker there blocks most rolls); fixed regions: the
                # child farther from it first (the palm lies beyond the fingers' depth off the axis)
                near_c, far_c = far_c, near_c
            stack[top] = far_c
            stack[top + 1] = near_c
            top += 2
    return mask


# -- the kernel ------------------------------------------------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def _chunk(
    lo: int,
    hi: int,
    cands: Candidates,
    tree: PointTree,
    regions: Regions,
    rolls: Rolls,
    hull: Hull,
    work: Work,
    out: np.ndarray,
    st: np.ndarray,
) -> None:
    """The free rolls of candidates lo..hi-1 into out (m, R) bool: a unit of _free_rolls_kernel's parallel work,
    with the thread's Work (memo, recent blockers, stack). Its own function, called from the parallel loop, which
    numba compiles far faster than the same code in the loop's body; the frame and x ranges are its own arrays."""
    nr = regions.rows.shape[0]
    fixed = nr > FINGER_ROWS
    full = rolls.full
    grid = work.grid
    F = np.empty(12)
    xr = np.empty((nr, 2))
    fixed_x_ranges(xr, regions)
    for q in range(lo, hi):
        F[0], F[1], F[2], ax, ay, az, w = candidate_frame(cands, q)
        yx, yy, yz, zx, zy, zz = roll0_basis(ax, ay, az, rolls.switch)
        F[3], F[4], F[5] = ax, ay, az
        F[6], F[7], F[8] = yx, yy, yz
        F[9], F[10], F[11] = zx, zy, zz
        finger_x_ranges(xr, cands.inside[q], w, regions)
        hw = 0.5 * w
        cell0 = _cell(grid, F[0] - hw * ax, F[1] - hw * ay, F[2] - hw * az)
        cell1 = _cell(grid, F[0] + hw * ax, F[1] + hw * ay, F[2] + hw * az)
        # the remembered blockers first (fingers, then fixed regions): most candidates end there; then the tree
        # (fingers, then fixed regions). The fingers are small regions and settle most candidates. The calls are
        # spelled out with their constant phase, which the compiler specialises
        blocked = _probe(F, tree, regions, rolls, xr, full, 0, work, cell0, cell1, st)
        if blocked != full and fixed:
            blocked |= _probe(F, tree, regions, rolls, xr, full & ~blocked, 1, work, -1, -1, st)
        if blocked != full:
            blocked |= _walk(F, tree, regions, rolls, xr, full & ~blocked, 0, work, cell0, cell1, st)
        certain = np.uint64(0)
        if blocked != full and fixed:
            # rolls at which the whole part lies in front of the palm need no walk: the walk could only prove
            # them free by visiting every node near the palm's region, and it stops once the rest is blocked
            certain = hull_free(F, hull, full & ~blocked, rolls)
            blocked |= certain
        if blocked != full and fixed:
            blocked |= _walk(F, tree, regions, rolls, xr, full & ~blocked, 1, work, -1, -1, st)
        blocked &= ~certain
        free = ~blocked & full
        for k in range(out.shape[1]):
            out[q, k] = (free >> np.uint64(k)) & np.uint64(1) != np.uint64(0)


@njit(parallel=True, cache=True, error_model="numpy")
def _free_rolls_kernel(
    cands: Candidates,
    tree: PointTree,
    regions: Regions,
    rolls: Rolls,
    hull: Hull,
    memo: Memo,
    nthreads: int,
    out: np.ndarray,
    stats: np.ndarray,
) -> None:
    """The free rolls of every candidate into out (m, R) bool, the work counters per chunk into stats (chunks, 8)."""
    m = cands.inside.shape[0]
    nchunks = (m + _CHUNK - 1) // _CHUNK
    # numba's OpenMP layer splits a prange statically into one contiguous run per thread, and the work per chunk
    # varies a lot along the spatial order: thread t takes chunks t, t + T, t + 2T, ... instead, which balances
    # because neighbouring chunks cost about the same
    for t in prange(nthreads):
        caches = np.full((2, _CACHE), -1, dtype=np.int64)  # recent blockers: fingers, fixed regions
        pos = np.zeros(2, dtype=np.int64)
        work = Work(np.empty(128, dtype=np.int64), caches, pos, memo.cells[numba.get_thread_id()], memo.grid)
        for c in range(t, nchunks, nthreads):
            _chunk(c * _CHUNK, min((c + 1) * _CHUNK, m), cands, tree, regions, rolls, hull, work, out, stats[c])


# -- preparation, once per point set ---------------------------------------------------------------------------------

#: the last few prepared point sets: the pipeline calls free_rolls in batches on the same points (the memo of
#: blockers stays warm across the batches; it only ever holds hints)
_PREPARED: dict[tuple[object, ...], Prepared] = {}
_PREPARED_KEEP = 2
_PREPARED_LOCK = threading.Lock()


def _prepared(points: np.ndarray, normals: np.ndarray | None, model: CollisionModel, rolls: int) -> Prepared:
    """_prepare, reused while the same points and normals (by content), model and roll count come back."""
    P = np.ascontiguousarray(points, dtype=np.float64)
    N = _normals_or_none(normals, len(P))
    h = hashlib.blake2b(P.tobytes(), digest_size=16)
    if N is not None:
        h.update(N.tobytes())
    key = (h.digest(), P.shape, N is None, model, rolls)
    with _PREPARED_LOCK:
        got = _PREPARED.get(key)
    if got is None:
        got = _prepare(P, N, model, rolls)
        with _PREPARED_LOCK:
            while len(_PREPARED) >= _PREPARED_KEEP:
                _PREPARED.pop(next(iter(_PREPARED)))
            _PREPARED[key] = got
    return got


def _normals_or_none(normals: np.ndarray | None, n: int) -> np.ndarray | None:
    """The points' normals as float64 (n, 3), or None: they only shape the tree, never the masks."""
    if normals is None:
        return None
    N = np.ascontiguousarray(normals, dtype=np.float64)
    if N.shape != (n, 3):
        raise ValueError(f"normals must be ({n}, 3) like the points, got {N.shape}")
    if not np.isfinite(N).all():
        raise ValueError("normals must be finite")
    return N


def _prepare(P: np.ndarray, N: np.ndarray | None, model: CollisionModel, rolls: int) -> Prepared:
    """The tree, region table, roll tables, blocker memo and hull for one point set (N None: the tree is split by
    position alone)."""
    tol = TOLERANCES
    n = len(P)
    leaves = 1 << max(int(np.ceil(np.log2(max((n + _LEAF - 1) // _LEAF, 1)))), 0)
    span = float(np.max(P.max(axis=0) - P.min(axis=0))) if n else 0.0
    pad = tol.guard * span + tol.guard_floor
    perm, nodes = _build_tree(
        P, np.zeros((0, 3)) if N is None else N, leaves, pad, _SPLIT_NORMAL_WEIGHT, _SPLIT_THICKNESS
    )
    Ps = P[perm]
    x, y, z = (np.ascontiguousarray(Ps[:, k]) for k in range(3))
    tree = PointTree(x, y, z, nodes, leaves)
    # memo cells _MEMO_H leaf patches wide, at most _MEMO_CELLS of them
    lo = P.min(axis=0)
    ext = np.maximum(P.max(axis=0) - lo, 1e-12)
    h = max(_MEMO_H * float(np.mean(nodes[leaves:, N_H] + nodes[leaves:, N_H + 1])), 1e-12)
    h = max(h, float(np.prod(ext) / _MEMO_CELLS) ** (1.0 / 3.0))
    dims = np.floor(ext / h).astype(np.int64) + 1
    while int(np.prod(dims)) > _MEMO_CELLS:
        h *= 1.25
        dims = np.floor(ext / h).astype(np.int64) + 1
    grid = np.array([lo[0], lo[1], lo[2], 1.0 / h, dims[0], dims[1], dims[2]], dtype=np.float64)
    # one memo per thread: shared cells that both threads keep rewriting cost more than the hits they share
    threads = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]  # numba.config sets it from the environment
    cells = np.full((threads, 2, int(np.prod(dims)), _MEMO_SLOTS), -1, dtype=np.int64)
    regions = region_table(model, prefilter=True)
    rows = regions.rows
    fixed = rows[FINGER_ROWS:][rows[FINGER_ROWS:, MOVES] == 0.0]
    threshold = -float(np.max(fixed[:, ZHI])) - 4.0 * pad if len(fixed) else 0.0
    return Prepared(tree, regions, roll_table(rolls), build_hull(P, threshold), Memo(cells, grid))


def _run(
    points: np.ndarray, normals: np.ndarray | None, cands: Candidates, model: CollisionModel, rolls: int
) -> tuple[np.ndarray, np.ndarray]:
    roll_table(rolls)  # checks the roll count before any work
    m = candidate_count(cands)
    if len(cands.inside) != m:
        raise ValueError("i, j and inside must have the same length")
    stats = np.zeros(((m + _CHUNK - 1) // _CHUNK, len(STATS)), dtype=np.int64)
    if m == 0 or len(points) == 0:
        return np.ones((m, rolls), dtype=bool), stats
    prep = _prepared(points, normals, model, rolls)
    out = np.empty((m, rolls), dtype=np.bool_)
    with numba.parallel_chunksize(1):
        _free_rolls_kernel(
            cands, prep.tree, prep.regions, prep.rolls, prep.hull, prep.memo, numba.get_num_threads(), out, stats
        )
    return out, stats


def free_rolls(
    points: np.ndarray,
    normals: np.ndarray | None,
    midpoints: np.ndarray,
    axes: np.ndarray,
    widths: np.ndarray,
    inside: np.ndarray,
    model: CollisionModel,
    rolls: int,
) -> np.ndarray:
    """Collision-free rolls of each candidate against the sampled points: (m, rolls) bool.

    points, normals: (n, 3) the sampled surface, metres, and its outward unit normals (they only shape the tree,
    never the result; None: by position alone, slower on parts with edges); midpoints (m, 3); axes (m, 3) unit,
    contact 0 -> 1; widths (m,) contact distances; inside (m,) bool. Roll k is the angle 2 pi k / rolls
    (CONTRACT.md)."""
    return _run(points, normals, candidates_of_geometry(midpoints, axes, widths, inside), model, rolls)[0]


def free_rolls_of_pairs(
    points: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    inside: np.ndarray,
    model: CollisionModel,
    rolls: int,
    normals: np.ndarray | None = None,
) -> np.ndarray:
    """free_rolls of the candidates (points[i], points[j]), contact 0 = points[i]: (m, rolls) bool, the same masks
    as free_rolls with midpoints 0.5 (p_i + p_j), axes d / |d| and widths |d| (d = p_j - p_i) made by numpy. The
    kernel derives them per candidate, so no (m, 3) arrays are made. normals: as for free_rolls."""
    if not len(i) == len(j) == len(inside):
        raise ValueError("i, j and inside must have the same length")
    return _run(points, normals, candidates_of_pairs(points, i, j, inside), model, rolls)[0]


def free_rolls_stats(
    points: np.ndarray,
    normals: np.ndarray | None,
    midpoints: np.ndarray | None,
    axes: np.ndarray | None,
    widths: np.ndarray | None,
    inside: np.ndarray,
    model: CollisionModel,
    rolls: int,
    pairs: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, dict[str, int]]:
    """free_rolls (or, with `pairs` = (i, j) and midpoints, axes, widths None, free_rolls_of_pairs) and its work
    counters (STATS), summed over candidates."""
    if pairs is None:
        if midpoints is None or axes is None or widths is None:
            raise ValueError("free_rolls_stats needs midpoints, axes and widths, or pairs")
        cands = candidates_of_geometry(midpoints, axes, widths, inside)
    else:
        cands = candidates_of_pairs(points, pairs[0], pairs[1], inside)
    fr, stats = _run(points, normals, cands, model, rolls)
    return fr, {k: int(v) for k, v in zip(STATS, stats.sum(axis=0), strict=True)}
