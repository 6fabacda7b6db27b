"""Criterion (d): which roll angles about the closing axis leave the gripper free of the sampled points.

Every mode is a set of up to three boxes in the grasp frame, tested at each roll: a roll is blocked when any
sampled point lies in any box (closed boxes). Modes:

- `paper`: the paper's test, the outer cuboid around both fingers minus the inner cuboid between them, the
  inner cuboid being longer than the contact distance by `Tolerances.inner_margin` on each side. That is the
  two finger boxes, each shortened by the margin at its contact face.
- `swept`: the fingers' whole travel from the pre-grasp opening to the contacts, plus the palm box and, given the
  part's `reach`, the gripper's approach: the palm's footprint (at least a finger wide) swept along -Z from the
  fingers' base to `reach` behind it, so that no part of the part lies where the palm, the open fingers or the
  gripper's body behind them pass on the way in along +Z (a grasp that puts the palm through a ring's eye is not
  reachable).

Inside grasps mirror the fingers: they sit between the contacts and open outwards to them.

Exactness: the result is, bit for bit, what testing every point against every box at every roll gives with the
per-point arithmetic of `_point_mask` (grasp-frame coordinates x = q.X, y = c_k (q.Y0) + s_k (q.Z0),
z = -s_k (q.Y0) + c_k (q.Z0)). Everything else only decides which points need that test: the bounds are padded
far beyond rounding error, and every shortcut (a node wholly inside or outside a box, a point inside the disc
that every roll of a finger covers, the half-turn symmetry of the finger boxes) keeps a guard band and falls
back to the per-roll test inside it.

Speed: the points live in a bounding-volume hierarchy (a balanced binary tree; per node an oriented box, an
axis-aligned box and a ball), each node split along its principal axis or, given the points' normals, along
(position, normal) where that gives thinner children, so that nodes are surface patches that do not straddle an
edge of the part (the fingers' slab test is as tight as a node is thin). A node is skipped when it misses
every region's slab along the closing axis, its radial band around the axis, or (for the palm, and for the
fingers once few rolls are open) the region at every open roll: the ball first, for all rolls at once, then (the
palm only) both boxes projected onto the roll's axes and the node's own axes, against the palm cut to the node's
own slab along the closing axis (all its points lie there). A node wholly inside a region at a roll blocks that
roll at once. Before any traversal, remembered blockers are tried: a memo per thread keyed by the grid cell of
each contact (fingers) and of the palm's front at each open roll (palm), and a small per-thread cache;
neighbouring candidates share most of their blockers, and most blocked candidates end there. The fingers' box is
symmetric under a half turn, so rolls k and k + R/2 share their work (R even). Before the palm's walk, the rolls
at which the whole part lies in front of the palm's front face are taken out of it (_hull_free: the support
function of the points' convex hull, from a cube map of bounds or, near the threshold, a hill climb over the
hull's vertices): the walk could prove such a roll free only by visiting every node near the palm's region, and
without it the walk stops as soon as the other rolls are blocked.

Tried and not kept (work counters of free_rolls_stats, deterministic, and CPU time on the thick ring and tless_04
at 10,000 points): the palm's ball test at the open rolls only instead of at every roll (within the noise); the
memo's grid widened by the palm key's offset, and finer memo cells (_MEMO_H 2 or 1): palm work -20 % on the ring
but as many more memo tests, within 2 % in all; _FINGER_ANGULAR 1 or 8 (finger work within 1 %).
Eighth session (the thick ring's 1,095,172 pairs of (a)-(c), in-process A/B against the previous kernel, runs
interleaved; where the palm's work goes: on the 400,025 candidates that keep a free roll, the fingers leave 15.6 of
16 rolls open and the palm, with its approach, blocks 14.4 of them: three quarters of their time): the palm's
per-roll node tests branch-free over every roll (18 % slower: the branchy loop stops at the first roll the node
reaches); the approach cut per candidate to the farthest corner of the part's boxes from the axis (palm nodes
27.0 -> 26.9); the palm walk before the fingers' (within the noise, up to 6 % slower); _CACHE 16, 32, 64 (walk
work -10 to -45 % but 2-8x the cache tests: within the noise on the ordered stream); _LEAF 16 or 64 (19-20 %
slower); stopping the palm's walk at 2 open rolls and leaving them to the mesh-exact check (its triangles settle a
blocked roll at about 4x a point's cost: 6 % slower in all). A node-visit budget per walk, the rest left to the
mesh-exact check (point and mesh tests together, same final masks on the ring): 40 nodes 8 % faster in one run,
45 nodes 20 % faster in one run of 5 rounds and 4 % in the next of 8 (within the noise); not kept: the free rolls
would then be the triangles' answer alone, not also the points'.
Tenth session (in-process A/B, interleaved, same masks): the hull certificate above: the point test's time on the
thick ring 0.94x (9 rounds; 0.90-0.97 over four runs on a noisy host), tless_04 0.79x, tless_13 0.95x,
featuretype 0.95x, idler riser 0.97x; building the hull and its 24 x 24 x 6 table costs 11-16 ms per point set
(qhull most of it; a table by matrix product instead of hill climbs took 50-70 ms). With exact hill climbs alone
(no table) the ring ran 1.10x: its sample's hull has 1,242 vertices, and a roll's step of 22.5 degrees walks far
along its rims. Taken out before the palm's remembered blockers instead of before its walk: within 1 % in an
oracle run (certificates precomputed), at twice the lookups.
Eleventh session (same A/B, the ring's 1,095,172 pairs, same masks): _CACHE 4 or 2 (1.10x, 1.39x); _MEMO_SLOTS 4
(0.99x); _CHUNK 16,384 or 1,024 (1.04x, 1.01x); the palm's walk before the fingers' now that the hull settles its
free rolls (1.06x), and only where the fingers' remembered blockers blocked nothing (1.05x; tless_04 1.01x); the
stats counters in a per-thread row written once per chunk (1.02x: no false sharing to remove). The two threads' work
counters differ by 3 %, and the kernel runs 1.84x faster on two threads than on one (the tree and hull, built on one
thread per point set, included). Where the time goes: the 400,025 candidates that keep a free roll take 0.73 of the
0.85 s (all pairs: 0.85 s, the blocked ones alone 0.21 s); without the palm the kernel takes 0.37 s, without the
palm's walk (memo, cache and hull only) 0.47 s. A node budget for the fingers' walk, its open rolls then left to the
palm and the mesh-exact check (the final masks are the same: the triangles block whatever the points block): 8, 16
or 32 nodes gave 1.92x, 1.07x and 1.05x the time of the point test and the mesh-exact check together (2.6x, 1.27x
and 1.11x as many candidates reach the triangles). The mesh-exact check's exact range along the axis (meshtree.py)
tried here too, for the fingers, from the points of a leaf and of its parent (or grandparent), per size class while
it turns a finger away at least at every other try: 1.01x (1.04x): the point tree's boxes hug their evenly spread
points, and a leaf's points are tested along the axis first anyway.
"""

from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

from . import libm
from .gripper import GripperSpec
from .params import TOLERANCES, Tolerances

__all__ = ["MAX_ROLLS", "CollisionModel", "approach_reach", "collision_model", "free_rolls", "free_rolls_of_pairs"]

#: roll masks are one 64-bit word per candidate
MAX_ROLLS = 64
_LEAF = 32  # at most about this many points per leaf (the leaf count is a power of two; 20 per leaf at 10,000
# points measured 10-25 % faster than 5: fewer node tests per point test)
_CACHE = 8  # recent blockers kept per thread and phase
_CHUNK = 4096  # candidates per unit of parallel work (a unit of the stats counters)
_FINGER_ANGULAR = 3  # per-roll node tests for the fingers once at most this many (symmetric pairs of) rolls are open
_GUARD = 1e-9  # relative guard band of the point-level shortcuts
_NODE = 24  # floats per tree node: see _build_tree
_STATS = 8  # counters per chunk: see free_rolls_stats
_MEMO_SLOTS = 2  # blockers remembered per memo cell
_MEMO_CELLS = 1 << 20  # at most this many memo cells
_HULL_CELLS = 24  # cube-map cells per face edge of the hull's support bounds (_hull)
_MEMO_H = 4.0  # memo cell width over the mean leaf patch (half extents along its two longer axes, summed)
# the tree, given normals: a node splits along (position, weight x rms radius x normal) when its children's ball
# radius + thickness x thinnest half extent is lower than by position alone. Work counts (deterministic) of a
# sweep on the ring, tless_04 and a cylinder: weight 3 and thickness 2 were best or within 3 % of the best on
# all three (ring finger nodes 24.9 -> 11.0 and points 33.8 -> 11.0 per candidate); thickness 1 or less lost
# the ring's gain, weight 2 or 5 and thickness 3 were close. The palm's work in this tree is within a few per
# cent of a tree by position alone (ring nodes +6 %, points -10 %; cylinder -3 %, -13 %)
_SPLIT_NORMAL_WEIGHT = 3.0
_SPLIT_THICKNESS = 2.0


@dataclass(frozen=True)
class CollisionModel:
    """The numbers of the region boxes, independent of the candidate (metres)."""

    mode: str
    finger_thickness: float
    half_finger_width: float
    half_finger_depth: float
    stroke: float
    min_width: float
    clearance: float
    #: the region behind the fingers (half x, half y, z_low, z_high): the palm box, reaching back along the
    #: approach path when collision_model was given the part's reach; None: no such region
    palm: tuple[float, float, float, float] | None
    inner_margin: float


def collision_model(
    gripper: GripperSpec, mode: str, tolerances: Tolerances = TOLERANCES, *, reach: float = 0.0
) -> CollisionModel:
    """The regions of criterion (d) for `gripper` in `mode`. `reach` (m; `swept` only): how far behind the fingers'
    base the approach region extends, at least the largest distance from a grasp's midpoint to any point of the
    part (the part's bounding-box diagonal does); 0 tests the palm box alone."""
    palm = None
    if mode == "swept" and (gripper.palm_depth > 0 or reach > 0):
        z_hi = -gripper.finger_depth / 2
        half_y = float(gripper.palm_width) / 2 if gripper.palm_depth > 0 else 0.0
        if reach > 0:  # the approach: the open fingers and the body behind them pass here too
            half_y = max(half_y, gripper.finger_width / 2)
        palm = (
            gripper.stroke / 2 + gripper.finger_thickness,
            half_y,
            z_hi - max(gripper.palm_depth, float(reach)),
            z_hi,
        )
    return CollisionModel(
        mode=mode,
        finger_thickness=gripper.finger_thickness,
        half_finger_width=gripper.finger_width / 2,
        half_finger_depth=gripper.finger_depth / 2,
        stroke=gripper.stroke,
        min_width=gripper.min_width,
        clearance=gripper.pregrasp_clearance if mode == "swept" else 0.0,
        palm=palm,
        inner_margin=tolerances.inner_margin,
    )


def approach_reach(points: np.ndarray) -> float:
    """`reach` for collision_model: the diagonal of the points' bounding box plus 5 %, beyond the largest distance
    from any midpoint of two of them (or of a mesh they sample finely) to any of them; 0 for no points."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return 1.05 * float(np.linalg.norm(np.ptp(pts, axis=0))) if len(pts) else 0.0


# region constants, one row per region (0 = finger at -x, 1 = finger at +x, 2 = palm)
_HY, _ZLO, _ZHI, _RMIN, _RMAX, _RIN, _RMIN2, _RMAX2, _RIN2, _SYM, _PX = range(11)


def _regions(model: CollisionModel) -> np.ndarray:
    """Per-region constants (r, 11): hy, z_lo, z_hi, radial band r_min..r_max around the axis that holds the
    region's (y, z) rectangle at every roll, r_in (the disc inside it at every roll), the same squared with the
    point-level guard band, whether the rectangle is symmetric under a half turn, and the palm's half x extent.
    The x extent of the fingers depends on the width and is computed per candidate."""
    hy, hz = model.half_finger_width, model.half_finger_depth
    r_max = float(np.hypot(hy, hz))
    r_in = min(hy, hz)
    lo, hi = 1.0 - _GUARD, 1.0 + _GUARD
    finger = [hy, -hz, hz, 0.0, r_max, r_in, 0.0, r_max * r_max * hi, r_in * r_in * lo, 1.0, 0.0]
    rows = [finger, list(finger)]
    if model.palm is not None:
        phx, phy, zlo, zhi = model.palm
        r_min = 0.0 if zlo <= 0.0 <= zhi else min(abs(zlo), abs(zhi))
        r_mx = float(np.hypot(phy, max(abs(zlo), abs(zhi))))
        sym = 1.0 if zlo == -zhi else 0.0
        rows.append([phy, zlo, zhi, r_min, r_mx, 0.0, r_min * r_min * lo, r_mx * r_mx * hi, -1.0, sym, phx])
    return np.array(rows, dtype=np.float64)


# -- bounding-volume hierarchy ------------------------------------------------------------------------------------


@njit(cache=True)
def _pca_box(Q, order, a, b):
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
def _split_cost(Q, order, a, b, thick):
    """Cost of a child holding the points Q[order[a:b]]: the radius of the ball around its oriented box plus
    `thick` times the box's thinnest half extent (the fingers' slab test is as tight as a node is thin)."""
    _, _, _, lo, hi = _pca_box(Q, order, a, b)
    r2 = 0.0
    thin = np.inf
    for i in range(2, -1, -1):
        h = 0.5 * (hi[i] - lo[i])
        r2 += h * h
        thin = min(thin, h)
    return np.sqrt(r2) + thick * thin


@njit(cache=True)
def _build_tree(P, N, leaves, pad, weight, thick):
    """Balanced implicit binary tree over a permutation of the points: node 1 is the root, children 2k and 2k+1,
    leaves from `leaves` on. Node k at depth d (t = k - 2^d) holds the points [t n >> d, (t + 1) n >> d) of the
    permuted order; each inner node splits its points at the median along their principal axis or, given the
    points' normals N (else N has no rows), along the principal axis of (position, `weight` x the node's rms
    radius x normal), whichever gives the children of lower _split_cost: the second parts a part's faces at
    its edges, so that nodes are thin patches.

    Returns (perm, nodes): nodes (2 leaves, _NODE) = oriented box (centre xyz, three unit axes as rows, half
    extents), the radius of the ball around that centre that holds the node's points, and the axis-aligned box
    (centre xyz, half extents xyz), all padded by `pad`. The oriented box suits surface patches, the axis-aligned
    one the corners and edges of parts modelled along their axes; the tests use both.
    """
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
        nodes[node, 0:3] = c
        for i in range(3):
            nodes[node, 3 + 3 * i : 6 + 3 * i] = ax[i]
            nodes[node, 12 + i] = 0.5 * (hi[i] - lo[i]) + pad
        nodes[node, 15] = np.sqrt(rho) + pad
        for a in range(3):
            a_lo, a_hi = np.inf, -np.inf
            for p in range(s, e):
                a_lo = min(a_lo, Q[p, a])
                a_hi = max(a_hi, Q[p, a])
            nodes[node, 16 + a] = 0.5 * (a_lo + a_hi)
            nodes[node, 19 + a] = 0.5 * (a_hi - a_lo) + pad
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


# -- the kernel --------------------------------------------------------------------------------------------------


@njit(cache=True, inline="always", error_model="numpy")
def _basis(ax, ay, az, switch):
    # the contract's roll-0 frame: Z0 = object +Z made orthogonal to X (object +X when |X.z| > switch)
    if abs(az) > switch:
        rx, ry, rz = 1.0, 0.0, 0.0
    else:
        rx, ry, rz = 0.0, 0.0, 1.0
    d = rx * ax + ry * ay + rz * az
    zx, zy, zz = rx - d * ax, ry - d * ay, rz - d * az
    nz = np.sqrt(zx * zx + zy * zy + zz * zz)
    zx, zy, zz = zx / nz, zy / nz, zz / nz
    # Y0 = Z0 x X
    yx = zy * az - zz * ay
    yy = zz * ax - zx * az
    yz = zx * ay - zy * ax
    return yx, yy, yz, zx, zy, zz


def _x_range_constants(model: CollisionModel) -> np.ndarray:
    """`model_f` of _x_ranges: (finger thickness, stroke, min_width, clearance, inner margin)."""
    return np.array([model.finger_thickness, model.stroke, model.min_width, model.clearance, model.inner_margin])


@njit(cache=True, inline="always", error_model="numpy")
def _x_ranges(xr, kind_inside, w, model_f):
    """Finger x intervals for one candidate into xr[0:2]; model_f = _x_range_constants(model)."""
    t, stroke, min_width, clearance, margin = model_f[0], model_f[1], model_f[2], model_f[3], model_f[4]
    if not kind_inside:
        o = min(w + clearance, stroke)
        a, b = w / 2 + margin, max(o, w) / 2 + t
    else:
        o = max(w - clearance, min_width + 2 * t)
        a, b = min(o, w) / 2 - t, w / 2 - margin
    xr[0, 0], xr[0, 1] = -b, -a
    xr[1, 0], xr[1, 1] = a, b


@njit(cache=True, inline="always", error_model="numpy")
def _in_rect(y, z, hy, zlo, zhi):
    return abs(y) <= hy and z >= zlo and z <= zhi


@njit(cache=True, inline="always", error_model="numpy")
def _point_mask(X, Y, Z, p, F, reg, r0, r1, xr, cos_k, sin_k, half, gfac, todo):
    """Rolls within `todo` at which point p lies in one of the regions r0..r1-1 (exact per-roll arithmetic)."""
    qx = X[p] - F[0]
    qy = Y[p] - F[1]
    qz = Z[p] - F[2]
    x = qx * F[3] + qy * F[4] + qz * F[5]
    mask = np.uint64(0)
    for r in range(r0, r1):
        if x < xr[r, 0] or x > xr[r, 1]:
            continue
        y0 = qx * F[6] + qy * F[7] + qz * F[8]
        z0 = qx * F[9] + qy * F[10] + qz * F[11]
        r2 = y0 * y0 + z0 * z0
        if r2 > reg[r, _RMAX2] or r2 < reg[r, _RMIN2]:
            continue
        if r2 <= reg[r, _RIN2]:
            return todo  # inside the disc that the region covers at every roll
        hy, zlo, zhi = reg[r, _HY], reg[r, _ZLO], reg[r, _ZHI]
        left = todo & ~mask
        if half > 0 and reg[r, _SYM] != 0.0:
            # roll k + half turns (y, z) into (-y, -z) up to rounding of the tables: bounded by g
            g = np.sqrt(r2) * gfac
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
                        if _in_rect(y1, z1, hy, zlo, zhi):
                            mask |= b1
        else:
            # every roll at once, branch-free (vectorised), then the rolls still open: the palm is tested at most
            # rolls (its region is not symmetric under a half turn), and the per-roll branches cost more
            hit = np.uint64(0)
            for k in range(cos_k.shape[0]):
                y = y0 * cos_k[k] + z0 * sin_k[k]
                z = -y0 * sin_k[k] + z0 * cos_k[k]
                in_k = (abs(y) <= hy) & (z >= zlo) & (z <= zhi)
                hit |= np.uint64(in_k) << np.uint64(k)
            mask |= hit & left
        mask &= todo
        if mask == todo:
            return todo
    return mask


@njit(cache=True, inline="always", error_model="numpy")
def _popcount(v):
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (v * np.uint64(0x0101010101010101)) >> np.uint64(56)


@njit(cache=True, inline="always", error_model="numpy")
def _node_axes_separate(xm, zm, xhr, hy, hzr, p0, p1, p2, y0v, y1v, y2v, z0v, z1v, z2v, cv0, cv1, cv2, nd):
    """Whether one of the node's box axes v_i separates it from the region's box (centre (xm, 0, zm) and half
    extents (xhr, hy, hzr) in the grasp frame): p_i, y_iv, z_iv = v_i . (X, Y, Z) at the roll, cv_i = v_i . (node
    centre - midpoint)."""
    if abs(xm * p0 + zm * z0v - cv0) > xhr * abs(p0) + hy * abs(y0v) + hzr * abs(z0v) + nd[12]:
        return True
    if abs(xm * p1 + zm * z1v - cv1) > xhr * abs(p1) + hy * abs(y1v) + hzr * abs(z1v) + nd[13]:
        return True
    return abs(xm * p2 + zm * z2v - cv2) > xhr * abs(p2) + hy * abs(y2v) + hzr * abs(z2v) + nd[14]


@njit(cache=True, inline="always", error_model="numpy")
def _probe(
    F,
    X,
    Y,
    Z,
    reg,
    r0,
    r1,
    xr,
    cos_k,
    sin_k,
    half,
    gfac,
    target,
    finger,
    cache,
    cache_pos,
    memo,
    grid,
    cell0,
    cell1,
    st,
):
    """Rolls within `target` blocked by regions r0..r1-1 (fingers: r0, r1 = 0, 2; palm: 2, 3) at the remembered
    blockers: the memo, then the thread's cache. Inlined: most candidates end here, without a call.

    memo[0, cell] holds the points that last blocked a finger whose contact lies in that grid cell, memo[1, cell]
    those that last blocked a palm whose key (_palm_key_z) lies in it (hints, never trusted without the exact test);
    cell0, cell1 are the cells of this candidate's contacts, -1 for none."""
    mask = np.uint64(0)
    slots = memo.shape[2]
    if finger:
        for cell in (cell0, cell1):
            if cell < 0:
                continue
            for slot in range(slots):
                p = memo[0, cell, slot]
                if p < 0:
                    continue
                st[6] += 1
                mask |= _point_mask(X, Y, Z, p, F, reg, r0, r1, xr, cos_k, sin_k, half, gfac, target & ~mask)
                if mask == target:
                    st[7] += 1
                    return mask, cache_pos
    else:
        zm = _palm_key_z(reg, r0)
        for k in range(cos_k.shape[0]):
            if not (target & ~mask & (np.uint64(1) << np.uint64(k))):
                continue
            cell = _palm_cell(grid, F, zm, cos_k[k], sin_k[k])
            if cell < 0:
                continue
            for slot in range(slots):
                p = memo[1, cell, slot]
                if p < 0:
                    continue
                st[6] += 1
                mask |= _point_mask(X, Y, Z, p, F, reg, r0, r1, xr, cos_k, sin_k, half, gfac, target & ~mask)
                if mask == target:
                    st[7] += 1
                    return mask, cache_pos
    for c in range(cache.shape[0]):
        p = cache[c]
        if p < 0:
            continue
        st[4] += 1
        mask |= _point_mask(X, Y, Z, p, F, reg, r0, r1, xr, cos_k, sin_k, half, gfac, target & ~mask)
        if mask == target:
            st[5] += 1
            return mask, cache_pos
    return mask, cache_pos


@njit(cache=True, error_model="numpy")
def _walk(
    F,
    X,
    Y,
    Z,
    nodes,
    leaves,
    reg,
    r0,
    r1,
    xr,
    cos_k,
    sin_k,
    half,
    gfac,
    target,
    finger,
    stack,
    cache,
    cache_pos,
    memo,
    grid,
    cell0,
    cell1,
    st,
):
    """Rolls within `target` blocked by regions r0..r1-1, by a traversal of the tree (see _probe for the memo)."""
    n = X.shape[0]
    mask = np.uint64(0)
    ax, ay, az = F[3], F[4], F[5]
    ya, yb, yc = F[6], F[7], F[8]
    za, zb, zc = F[9], F[10], F[11]
    nrolls = cos_k.shape[0]
    sym = half > 0 and reg[r0, _SYM] != 0.0
    kmax = half if sym else nrolls
    stack[0] = 1
    top = 1
    vis = 0 if finger else 2
    while top > 0:
        top -= 1
        node = stack[top]
        st[vis] += 1
        nd = nodes[node]
        cx = nd[0] - F[0]
        cy = nd[1] - F[1]
        cz = nd[2] - F[2]
        rho = nd[15]
        xc = cx * ax + cy * ay + cz * az
        p0 = nd[3] * ax + nd[4] * ay + nd[5] * az
        p1 = nd[6] * ax + nd[7] * ay + nd[8] * az
        p2 = nd[9] * ax + nd[10] * ay + nd[11] * az
        xh = min(nd[12] * abs(p0) + nd[13] * abs(p1) + nd[14] * abs(p2), rho)
        bx = nd[16] - F[0]
        by = nd[17] - F[1]
        bz = nd[18] - F[2]
        xb = bx * ax + by * ay + bz * az
        xbh = nd[19] * abs(ax) + nd[20] * abs(ay) + nd[21] * abs(az)
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
            if dp - rho > reg[r, _RMAX] or dp + rho < reg[r, _RMIN]:
                continue
            x_in = x_lo >= xr[r, 0] and x_hi <= xr[r, 1]
            if x_in and dp + rho <= reg[r, _RIN]:
                return target, cache_pos  # the node lies where every roll of this region is
            angular = True
            if finger:
                open_ = todo
                if sym:
                    open_ = (todo | (todo >> np.uint64(half))) & ((np.uint64(1) << np.uint64(half)) - np.uint64(1))
                angular = _popcount(open_) <= _FINGER_ANGULAR
            if not angular:
                hit = True
                break
            # the node's ball against the region at every roll at once (branch-free: vectorised), then the
            # oriented box projected onto the roll's Y and Z axes at the open rolls the ball reaches
            hy, zlo, zhi = reg[r, _HY], reg[r, _ZLO], reg[r, _ZHI]
            near = np.uint64(0)
            ball_in = np.uint64(0)
            for k in range(kmax):
                yk = cos_k[k] * yc0 + sin_k[k] * zc0
                zk = cos_k[k] * zc0 - sin_k[k] * yc0
                ayk = abs(yk)
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
                # the ball alone for the fingers: their boxes are small next to the nodes that reach them, and
                # the per-roll box tests below cost more than they prune (in-process A/B on a znver4 host: ring
                # -10 %, cylinder -9 %)
                reach = near
            elif near:
                q0y = nd[3] * ya + nd[4] * yb + nd[5] * yc
                q1y = nd[6] * ya + nd[7] * yb + nd[8] * yc
                q2y = nd[9] * ya + nd[10] * yb + nd[11] * yc
                q0z = nd[3] * za + nd[4] * zb + nd[5] * zc
                q1z = nd[6] * za + nd[7] * zb + nd[8] * zc
                q2z = nd[9] * za + nd[10] * zb + nd[11] * zc
                cv0 = cx * nd[3] + cy * nd[4] + cz * nd[5]
                cv1 = cx * nd[6] + cy * nd[7] + cz * nd[8]
                cv2 = cx * nd[9] + cy * nd[10] + cz * nd[11]
                yb0 = bx * ya + by * yb + bz * yc
                zb0 = bx * za + by * zb + bz * zc
                # the region cut to the node's own slab along X, where all its points lie: the separation along
                # the node's axes gets far tighter for nodes small next to the palm, which is a stroke wide
                # (palm nodes per candidate: ring 9.3 -> 5.1, cylinder 9.6 -> 8.4; palm points 15.7 -> 5.9)
                cut_lo, cut_hi = max(xr[r, 0], x_lo), min(xr[r, 1], x_hi)
                xm, xhr = 0.5 * (cut_lo + cut_hi), 0.5 * (cut_hi - cut_lo)
                zm, hzr = 0.5 * (zlo + zhi), 0.5 * (zhi - zlo)
                for k in range(kmax):
                    bit = np.uint64(1) << np.uint64(k)
                    if sym:
                        bit |= np.uint64(1) << np.uint64(k + half)
                    if not (near & bit):
                        continue
                    ck, sk = cos_k[k], sin_k[k]
                    yk = ck * yc0 + sk * zc0
                    zk = ck * zc0 - sk * yc0
                    y0v, y1v, y2v = ck * q0y + sk * q0z, ck * q1y + sk * q1z, ck * q2y + sk * q2z
                    z0v, z1v, z2v = ck * q0z - sk * q0y, ck * q1z - sk * q1y, ck * q2z - sk * q2y
                    eh = nd[12] * abs(y0v) + nd[13] * abs(y1v) + nd[14] * abs(y2v)
                    ev = nd[12] * abs(z0v) + nd[13] * abs(z1v) + nd[14] * abs(z2v)
                    # the axis-aligned box along the roll's Y and Z: keep the tighter bound of the two boxes
                    ybk = ck * yb0 + sk * zb0
                    zbk = ck * zb0 - sk * yb0
                    ebh = (
                        nd[19] * abs(ck * ya + sk * za)
                        + nd[20] * abs(ck * yb + sk * zb)
                        + nd[21] * abs(ck * yc + sk * zc)
                    )
                    ebv = (
                        nd[19] * abs(ck * za - sk * ya)
                        + nd[20] * abs(ck * zb - sk * yb)
                        + nd[21] * abs(ck * zc - sk * yc)
                    )
                    y_lo = max(yk - eh, ybk - ebh)
                    y_hi = min(yk + eh, ybk + ebh)
                    z_lo = max(zk - ev, zbk - ebv)
                    z_hi = min(zk + ev, zbk + ebv)
                    if y_lo > hy or y_hi < -hy or z_hi < zlo or z_lo > zhi:
                        continue
                    if x_in and y_lo >= -hy and y_hi <= hy and z_lo >= zlo and z_hi <= zhi:
                        inside |= bit & todo
                        continue
                    # the node's own axes separate too (a surface patch is thin along its normal)
                    if _node_axes_separate(
                        xm, zm, xhr, hy, hzr, p0, p1, p2, y0v, y1v, y2v, z0v, z1v, z2v, cv0, cv1, cv2, nd
                    ):
                        continue
                    reach |= bit
                    if not x_in:
                        break  # no roll can be wholly inside: descend
            if inside:
                mask |= inside & target
                if mask == target:
                    return mask, cache_pos
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
                m = _point_mask(X, Y, Z, p, F, reg, r0, r1, xr, cos_k, sin_k, half, gfac, target & ~mask)
                if m:
                    mask |= m
                    cache[cache_pos] = p
                    cache_pos = (cache_pos + 1) % cache.shape[0]
                    if finger:
                        # finger 0 lies on the -x side of the midpoint, finger 1 on the +x side
                        x = (X[p] - F[0]) * ax + (Y[p] - F[1]) * ay + (Z[p] - F[2]) * az
                        _remember(memo, 0, cell0 if x < 0.0 else cell1, p)
                    else:
                        zm = _palm_key_z(reg, r0)
                        for k in range(nrolls):
                            if m & (np.uint64(1) << np.uint64(k)):
                                _remember(memo, 1, _palm_cell(grid, F, zm, cos_k[k], sin_k[k]), p)
                    if mask == target:
                        return mask, cache_pos
        else:
            near_c, far_c = 2 * node, 2 * node + 1
            if (_axis_dist2(nodes[far_c], F) < _axis_dist2(nodes[near_c], F)) == finger:
                # fingers: the child nearer the axis first (a blocker there blocks most rolls); palm: the child
                # farther from it first (the palm lies beyond the fingers' depth off the axis: 5-30 % fewer palm
                # nodes and points, cylinder -9 %)
                near_c, far_c = far_c, near_c
            stack[top] = far_c
            stack[top + 1] = near_c
            top += 2
    return mask, cache_pos


@njit(cache=True, inline="always", error_model="numpy")
def _axis_dist2(nd, F):
    """Squared distance of a node's centre from the closing axis."""
    cx, cy, cz = nd[0] - F[0], nd[1] - F[1], nd[2] - F[2]
    x = cx * F[3] + cy * F[4] + cz * F[5]
    return cx * cx + cy * cy + cz * cz - x * x


@njit(cache=True, inline="always", error_model="numpy")
def _remember(memo, kind, cell, p):
    if cell >= 0 and memo[kind, cell, 0] != p:
        for slot in range(memo.shape[2] - 1, 0, -1):
            memo[kind, cell, slot] = memo[kind, cell, slot - 1]
        memo[kind, cell, 0] = p


@njit(cache=True, inline="always", error_model="numpy")
def _palm_key_z(reg, r):
    """Where along Z the palm's memo key lies: the centre of the region's front, as deep as the region is wide (or
    the region's centre if it is shallower). Not the centre of the whole region: with the approach it lies a
    part's length behind the fingers, mostly outside the memo's grid, and the memo found no palm blocker (ring:
    palm work per candidate 7 -> 14 nodes and points; with this key 7 again)."""
    return max(0.5 * (reg[r, _ZLO] + reg[r, _ZHI]), reg[r, _ZHI] - reg[r, _HY])


@njit(cache=True, inline="always", error_model="numpy")
def _palm_cell(grid, F, zm, ck, sk):
    """Memo cell of the palm's key at the roll (cos, sin) = (ck, sk): midpoint + zm Z."""
    zx = ck * F[9] - sk * F[6]
    zy = ck * F[10] - sk * F[7]
    zz = ck * F[11] - sk * F[8]
    return _cell(grid, F[0] + zm * zx, F[1] + zm * zy, F[2] + zm * zz)


@njit(cache=True, inline="always", error_model="numpy")
def _cell(grid, x, y, z):
    """Index of the memo cell holding (x, y, z); grid = origin xyz, 1 / cell size, dims xyz. -1 outside."""
    i = int(np.floor((x - grid[0]) * grid[3]))
    j = int(np.floor((y - grid[1]) * grid[3]))
    k = int(np.floor((z - grid[2]) * grid[3]))
    nx, ny, nz = int(grid[4]), int(grid[5]), int(grid[6])
    if i < 0 or j < 0 or k < 0 or i >= nx or j >= ny or k >= nz:
        return -1
    return (i * ny + j) * nz + k


@njit(cache=True, inline="always", error_model="numpy")
def _cube_cell(ux, uy, uz, n):
    """The cell of unit direction u in a cube map of n x n cells per face (see _hull)."""
    bx, by, bz = abs(ux), abs(uy), abs(uz)
    if bx >= by and bx >= bz:
        f, m, p, q = 0 if ux > 0 else 1, bx, uy, uz
    elif by >= bz:
        f, m, p, q = 2 if uy > 0 else 3, by, uz, ux
    else:
        f, m, p, q = 4 if uz > 0 else 5, bz, ux, uy
    i = min(max(int((p / m + 1.0) * 0.5 * n), 0), n - 1)
    j = min(max(int((q / m + 1.0) * 0.5 * n), 0), n - 1)
    return (f * n + i) * n + j


@njit(cache=True, inline="always", error_model="numpy")
def _hull_free(F, hull, target, cos_k, sin_k, thr):
    """Rolls within `target` at which every sample point lies in front of the palm: the support of the points'
    convex hull along -Z_k (the approach's reverse), from the midpoint, is below thr (-z_hi less a guard band), so
    no point has z <= z_hi there and the palm cannot block the roll. hull (see _hull): the hull's vertices W
    relative to o, its vertex graph (CSR), a cube map of directions with, per cell, an upper bound of max W . u
    over the cell's directions and the vertex that attains the maximum at its centre, and (o, n). The bound
    settles most rolls; near the threshold, a hill climb from that vertex (_climb) gives the exact support."""
    W, a_start, adj, bound, arg, info = hull
    free = np.uint64(0)
    if W.shape[0] == 0:
        return free
    n = int(info[3])
    dx, dy, dz = info[0] - F[0], info[1] - F[1], info[2] - F[2]
    for k in range(cos_k.shape[0]):
        bit = np.uint64(1) << np.uint64(k)
        if not (target & bit):
            continue
        s, c = sin_k[k], cos_k[k]
        ux = s * F[6] - c * F[9]
        uy = s * F[7] - c * F[10]
        uz = s * F[8] - c * F[11]
        om = dx * ux + dy * uy + dz * uz  # (o - m) . u
        cell = _cube_cell(ux, uy, uz, n)
        if bound[cell] + om < thr:
            free |= bit
            continue
        v = arg[cell]
        _, best = _climb(W, a_start, adj, v, ux, uy, uz, om, thr)
        if best + om < thr:
            free |= bit
    return free


@njit(cache=True, inline="always", error_model="numpy")
def _climb(W, start, adj, v, ux, uy, uz, shift, stop):
    """(vertex, value) of max_w W[w] . u, by a hill climb over the hull's vertex graph (CSR start, adj) from
    vertex v, each step to the neighbour of largest value; it stops early once value + shift reaches `stop` (inf:
    never). A vertex that no neighbour beats maximises a linear function over a convex polytope."""
    best = W[v, 0] * ux + W[v, 1] * uy + W[v, 2] * uz
    while best + shift < stop:
        nxt = v
        for e in range(start[v], start[v + 1]):
            w = adj[e]
            x = W[w, 0] * ux + W[w, 1] * uy + W[w, 2] * uz
            if x > best:
                best = x
                nxt = w
        if nxt == v:
            break
        v = nxt
    return v, best


@njit(cache=True, inline="always", error_model="numpy")
def _pair_frame(P, a, b):
    """Midpoint, unit axis and width of the candidate (P[a], P[b]) with numpy's arithmetic for 0.5 (p_a + p_b),
    d / |d| and |d| (d = p_b - p_a; the squares added in numpy's order), bit for bit: both kernels' pair entry
    points (free_rolls_of_pairs, meshtree.mesh_free_rolls_of_pairs) give the masks of their geometry entry points."""
    dx, dy, dz = P[b, 0] - P[a, 0], P[b, 1] - P[a, 1], P[b, 2] - P[a, 2]
    w = np.sqrt(dx * dx + dy * dy + dz * dz)
    return (
        0.5 * (P[a, 0] + P[b, 0]),
        0.5 * (P[a, 1] + P[b, 1]),
        0.5 * (P[a, 2] + P[b, 2]),
        dx / w,
        dy / w,
        dz / w,
        w,
    )


@njit(cache=True, error_model="numpy")
def _chunk(
    lo,
    hi,
    from_pairs,
    mids,
    axes,
    widths,
    inside,
    P,
    pi,
    pj,
    X,
    Y,
    Z,
    nodes,
    leaves,
    reg,
    model_f,
    cos_k,
    sin_k,
    half,
    gfac,
    full,
    switch,
    tmemo,
    caches,
    cache_pos,
    grid,
    hull,
    hull_thr,
    out,
    st,
):
    """The free rolls of candidates lo..hi-1 into out (a unit of _free_rolls_kernel's parallel work), with the
    thread's memo and recent blockers (caches, cache_pos). Its own function, called from the parallel loop: with
    this code in the loop's body numba compiled the kernel in 67-72 s, about half of the package's cold start; as
    a function, in 47-51 s (interleaved runs on an empty cache), at the same speed (in-process A/B on the ring's
    and tless_04's pairs: median ratios 0.98-1.04, same masks). Its working arrays (stack, frame, x ranges) are
    its own: with them passed in per candidate, the same code ran 22 % slower."""
    nr = reg.shape[0]
    stack = np.empty(128, dtype=np.int64)
    F = np.empty(12)
    xr = np.empty((nr, 2))
    for r in range(2, nr):
        xr[r, 0] = -reg[r, _PX]
        xr[r, 1] = reg[r, _PX]
    for q in range(lo, hi):
        if from_pairs:
            F[0], F[1], F[2], ax, ay, az, w = _pair_frame(P, pi[q], pj[q])
        else:
            w = widths[q]
            ax, ay, az = axes[q, 0], axes[q, 1], axes[q, 2]
            F[0], F[1], F[2] = mids[q, 0], mids[q, 1], mids[q, 2]
        yx, yy, yz, zx, zy, zz = _basis(ax, ay, az, switch)
        F[3], F[4], F[5] = ax, ay, az
        F[6], F[7], F[8] = yx, yy, yz
        F[9], F[10], F[11] = zx, zy, zz
        _x_ranges(xr, inside[q], w, model_f)
        hw = 0.5 * w
        cell0 = _cell(grid, F[0] - hw * ax, F[1] - hw * ay, F[2] - hw * az)
        cell1 = _cell(grid, F[0] + hw * ax, F[1] + hw * ay, F[2] + hw * az)
        # the remembered blockers first (fingers, then palm), inlined: most candidates end there without a
        # call; then the tree (fingers, then palm). The fingers are small regions and settle most
        # candidates. The calls are spelled out: with their constant arguments the compiler specialises
        # each (one call in a loop over both measured 15-25 % slower)
        blocked, cache_pos[0] = _probe(
            F,
            X,
            Y,
            Z,
            reg,
            0,
            2,
            xr,
            cos_k,
            sin_k,
            half,
            gfac,
            full,
            True,
            caches[0],
            cache_pos[0],
            tmemo,
            grid,
            cell0,
            cell1,
            st,
        )
        if blocked != full and nr > 2:
            more, cache_pos[1] = _probe(
                F,
                X,
                Y,
                Z,
                reg,
                2,
                nr,
                xr,
                cos_k,
                sin_k,
                half,
                gfac,
                full & ~blocked,
                False,
                caches[1],
                cache_pos[1],
                tmemo,
                grid,
                -1,
                -1,
                st,
            )
            blocked |= more
        if blocked != full:
            more, cache_pos[0] = _walk(
                F,
                X,
                Y,
                Z,
                nodes,
                leaves,
                reg,
                0,
                2,
                xr,
                cos_k,
                sin_k,
                half,
                gfac,
                full & ~blocked,
                True,
                stack,
                caches[0],
                cache_pos[0],
                tmemo,
                grid,
                cell0,
                cell1,
                st,
            )
            blocked |= more
        certain = np.uint64(0)
        if blocked != full and nr > 2:
            # rolls at which the whole part lies in front of the palm need no walk: the walk could only prove
            # them free by visiting every node near the palm's region, and it stops once the rest is blocked
            certain = _hull_free(F, hull, full & ~blocked, cos_k, sin_k, hull_thr)
            blocked |= certain
        if blocked != full and nr > 2:
            more, cache_pos[1] = _walk(
                F,
                X,
                Y,
                Z,
                nodes,
                leaves,
                reg,
                2,
                nr,
                xr,
                cos_k,
                sin_k,
                half,
                gfac,
                full & ~blocked,
                False,
                stack,
                caches[1],
                cache_pos[1],
                tmemo,
                grid,
                -1,
                -1,
                st,
            )
            blocked |= more
        blocked &= ~certain
        free = ~blocked & full
        for k in range(out.shape[1]):
            out[q, k] = (free >> np.uint64(k)) & np.uint64(1) != np.uint64(0)


@njit(parallel=True, cache=True, error_model="numpy")
def _free_rolls_kernel(
    mids,
    axes,
    widths,
    inside,
    P,
    pi,
    pj,
    X,
    Y,
    Z,
    nodes,
    leaves,
    reg,
    model_f,
    cos_k,
    sin_k,
    half,
    gfac,
    full,
    switch,
    memo,
    grid,
    hull,
    hull_thr,
    nthreads,
    out,
    stats,
):
    m = inside.shape[0]
    from_pairs = pi.shape[0] > 0  # the candidates as point index pairs (pi, pj) into P, not as mids/axes/widths
    nchunks = (m + _CHUNK - 1) // _CHUNK
    # numba's OpenMP layer splits a prange statically into one contiguous run per thread, and the work per
    # chunk varies a lot along the spatial order (tless_04: 81 % of it in the second half): thread t takes
    # chunks t, t + T, t + 2T, ... instead, which balances because neighbouring chunks cost about the same
    for t in prange(nthreads):
        tmemo = memo[numba.get_thread_id()]
        caches = np.full((2, _CACHE), -1, dtype=np.int64)  # recent blockers: fingers, palm
        cache_pos = np.zeros(2, dtype=np.int64)
        for c in range(t, nchunks, nthreads):
            _chunk(
                c * _CHUNK,
                min((c + 1) * _CHUNK, m),
                from_pairs,
                mids,
                axes,
                widths,
                inside,
                P,
                pi,
                pj,
                X,
                Y,
                Z,
                nodes,
                leaves,
                reg,
                model_f,
                cos_k,
                sin_k,
                half,
                gfac,
                full,
                switch,
                tmemo,
                caches,
                cache_pos,
                grid,
                hull,
                hull_thr,
                out,
                stats[c],
            )


#: the last few prepared point sets: the pipeline calls free_rolls in batches on the same points (the memo of
#: blockers stays warm across the batches; it only ever holds hints)
_PREPARED: dict = {}
_PREPARED_KEEP = 2
_PREPARED_LOCK = threading.Lock()


def _prepared(points, normals, model, rolls):
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


def _normals_or_none(normals, n):
    """The points' normals as float64 (n, 3), or None: they only shape the tree, never the masks."""
    if normals is None:
        return None
    N = np.ascontiguousarray(normals, dtype=np.float64)
    if N.shape != (n, 3):
        raise ValueError(f"normals must be ({n}, 3) like the points, got {N.shape}")
    if not np.isfinite(N).all():
        raise ValueError("normals must be finite")
    return N


def _prepare(points, normals, model, rolls):
    """Tree, region constants, roll tables and the blocker memo for one point set (normals None: the tree is
    split by position alone)."""
    from .transforms import roll_angles_rad

    P = np.ascontiguousarray(points, dtype=np.float64)
    n = len(P)
    leaves = 1 << max(int(np.ceil(np.log2(max((n + _LEAF - 1) // _LEAF, 1)))), 0)
    span = float(np.max(P.max(axis=0) - P.min(axis=0))) if n else 0.0
    pad = 1e-9 * span + 1e-15
    N = np.zeros((0, 3)) if normals is None else normals
    perm, nodes = _build_tree(P, N, leaves, pad, _SPLIT_NORMAL_WEIGHT, _SPLIT_THICKNESS)
    Ps = P[perm]
    psi = roll_angles_rad(rolls)
    cos_k, sin_k = libm.cos(psi), libm.sin(psi)
    half = rolls // 2 if rolls % 2 == 0 else 0
    gfac = 0.0
    if half:
        asym = max(
            float(np.max(np.abs(cos_k[half:] + cos_k[:half]))), float(np.max(np.abs(sin_k[half:] + sin_k[:half])))
        )
        # |y(k + half) + y(k)| <= (|y0| + |z0|) asym + rounding <= r (2 asym + 16 eps), doubled for safety
        gfac = 2.0 * (2.0 * asym + 16.0 * np.finfo(np.float64).eps)
    full = np.uint64((1 << rolls) - 1) if rolls < 64 else np.uint64(0xFFFFFFFFFFFFFFFF)
    model_f = _x_range_constants(model)
    soa = tuple(np.ascontiguousarray(Ps[:, k]) for k in range(3))
    # memo cells _MEMO_H leaf patches wide, at most _MEMO_CELLS of them
    lo = P.min(axis=0)
    ext = np.maximum(P.max(axis=0) - lo, 1e-12)
    h = max(_MEMO_H * float(np.mean(nodes[leaves:, 12] + nodes[leaves:, 13])), 1e-12)
    h = max(h, float(np.prod(ext) / _MEMO_CELLS) ** (1.0 / 3.0))
    dims = np.floor(ext / h).astype(np.int64) + 1
    while int(np.prod(dims)) > _MEMO_CELLS:
        h *= 1.25
        dims = np.floor(ext / h).astype(np.int64) + 1
    grid = np.array([lo[0], lo[1], lo[2], 1.0 / h, dims[0], dims[1], dims[2]], dtype=np.float64)
    # one memo per thread: shared cells that both threads keep rewriting cost more than the hits they share
    memo = np.full((numba.config.NUMBA_NUM_THREADS, 2, int(np.prod(dims)), _MEMO_SLOTS), -1, dtype=np.int64)
    reg = _regions(model)
    hull_thr = -reg[2, _ZHI] - 4.0 * pad if len(reg) > 2 else 0.0
    return soa, nodes, leaves, reg, model_f, cos_k, sin_k, half, gfac, full, memo, grid, _hull(P), hull_thr


def _hull(P: np.ndarray, cells: int = _HULL_CELLS) -> tuple:
    """The points' convex hull for _hull_free: (vertices W (k, 3) relative to o, CSR start (k + 1,), neighbours, per
    cube-map cell an upper bound of max W . u over the cell's directions u and the vertex that attains the maximum
    at the cell's centre, [o, cells]); o is the vertices' mean. The bound: the maximum at the centre direction c
    plus R |u - c|, R = max |W|, with |u - c| at most the chord to the cell's farthest corner (a cell is a convex
    spherical quadrilateral). Empty arrays when the points span no volume (flat, or fewer than 4 points)."""
    from scipy.spatial import ConvexHull, QhullError

    empty = (
        np.zeros((0, 3)),
        np.zeros(1, dtype=np.int64),
        np.zeros(0, dtype=np.int64),
        np.zeros(0),
        np.zeros(0, dtype=np.int64),
        np.zeros(4),
    )
    if len(P) < 4:
        return empty
    try:
        h = ConvexHull(P)
    except (QhullError, ValueError):
        return empty
    ids = np.asarray(h.vertices, dtype=np.int64)
    local = np.full(len(P), -1, dtype=np.int64)
    local[ids] = np.arange(len(ids))
    tri = local[np.asarray(h.simplices, dtype=np.int64)]
    src = np.concatenate([tri[:, 0], tri[:, 1], tri[:, 2], tri[:, 1], tri[:, 2], tri[:, 0]])
    dst = np.concatenate([tri[:, 1], tri[:, 2], tri[:, 0], tri[:, 0], tri[:, 1], tri[:, 2]])
    by_src = np.argsort(src, kind="stable")  # each edge twice per direction (two facets share it): harmless
    adj = np.ascontiguousarray(dst[by_src])
    start = np.zeros(len(ids) + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=len(ids)), out=start[1:])
    o = P[ids].mean(axis=0)
    W = np.ascontiguousarray(P[ids] - o)
    R = float(np.max(np.linalg.norm(W, axis=1)))
    # cube map: face f = 2 a + (u_a < 0), (p, q) = (u_{a+1}, u_{a+2}) / |u_a| in cells of 2 / n (as _cube_cell)
    n = cells
    edge = -1.0 + 2.0 * np.arange(n + 1) / n
    mid = 0.5 * (edge[:-1] + edge[1:])
    centres, chords = [], []
    for f in range(6):
        c = _face_units(f, *np.meshgrid(mid, mid, indexing="ij"))
        chord = np.zeros((n, n))
        for di in (0, 1):
            for dj in (0, 1):
                corner = _face_units(f, *np.meshgrid(edge[di : n + di], edge[dj : n + dj], indexing="ij"))
                chord = np.maximum(chord, np.linalg.norm(corner - c, axis=-1))
        centres.append(c.reshape(-1, 3))
        chords.append(chord.reshape(-1))
    U = np.ascontiguousarray(np.concatenate(centres))
    val = np.empty(len(U))
    arg = np.empty(len(U), dtype=np.int64)
    _support_table(W, start, adj, U, val, arg)
    bound = val + R * (np.concatenate(chords) * (1.0 + 1e-9) + 1e-9)
    info = np.array([o[0], o[1], o[2], float(n)])
    return W, start, adj, np.ascontiguousarray(bound), arg, info


def _face_units(f: int, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Unit directions on cube face f (axis f // 2, + for even f) at face coordinates (p, q), as _cube_cell."""
    a = f // 2
    u = np.empty(p.shape + (3,))
    u[..., a] = 1.0 if f % 2 == 0 else -1.0
    u[..., (a + 1) % 3] = p
    u[..., (a + 2) % 3] = q
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


@njit(cache=True)
def _support_table(W, start, adj, U, val, arg):
    """max_w W[w] . U[c] and its vertex for each direction U[c] (_climb), each climb started where the previous
    one ended (neighbouring cells have neighbouring maxima)."""
    v = 0
    for c in range(U.shape[0]):
        v, val[c] = _climb(W, start, adj, v, U[c, 0], U[c, 1], U[c, 2], 0.0, np.inf)
        arg[c] = v


def _run(points, normals, midpoints, axes, widths, inside, model, rolls, pairs=None):
    from .transforms import ROLL_REFERENCE_SWITCH

    if not 1 <= rolls <= MAX_ROLLS:
        raise ValueError(f"rolls must be 1..{MAX_ROLLS}")
    m = len(inside)
    if pairs is not None and not len(pairs[0]) == len(pairs[1]) == m:
        raise ValueError("i, j and inside must have the same length")
    stats = np.zeros(((m + _CHUNK - 1) // _CHUNK, _STATS), dtype=np.int64)
    if m == 0 or len(points) == 0:
        return np.ones((m, rolls), dtype=bool), stats
    soa, nodes, leaves, reg, model_f, cos_k, sin_k, half, gfac, full, memo, grid, hull, hull_thr = _prepared(
        points, normals, model, rolls
    )
    out = np.empty((m, rolls), dtype=np.bool_)
    no_rows, no_index = np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    if pairs is None:
        geometry = (
            np.ascontiguousarray(midpoints, dtype=np.float64),
            np.ascontiguousarray(axes, dtype=np.float64),
            np.ascontiguousarray(widths, dtype=np.float64),
        )
        index = (no_rows, no_index, no_index)
    else:
        geometry = (no_rows, no_rows, np.zeros(0))
        i, j = (np.ascontiguousarray(a, dtype=np.int64) for a in pairs)
        _check_pairs(len(points), i, j)
        index = (np.ascontiguousarray(points, dtype=np.float64), i, j)
    with numba.parallel_chunksize(1):
        _free_rolls_kernel(
            *geometry,
            np.ascontiguousarray(inside, dtype=np.bool_),
            *index,
            *soa,
            nodes,
            leaves,
            reg,
            model_f,
            cos_k,
            sin_k,
            half,
            gfac,
            full,
            ROLL_REFERENCE_SWITCH,
            memo,
            grid,
            hull,
            hull_thr,
            numba.get_num_threads(),
            out,
            stats,
        )
    return out, stats


def _check_pairs(n: int, i: np.ndarray, j: np.ndarray) -> None:
    """The kernel reads points[i], points[j] unchecked: indices in [0, n), no point paired with itself."""
    lo, hi = min(int(np.min(i)), int(np.min(j))), max(int(np.max(i)), int(np.max(j)))
    if lo < 0 or hi >= n:
        raise ValueError(f"point indices must lie in [0, {n}), got {lo}..{hi}")
    if np.any(i == j):
        raise ValueError("a pair of a point with itself has no closing axis")


def free_rolls(
    points: np.ndarray,
    normals: np.ndarray,
    midpoints: np.ndarray,
    axes: np.ndarray,
    widths: np.ndarray,
    inside: np.ndarray,
    model: CollisionModel,
    rolls: int,
) -> np.ndarray:
    """Collision-free rolls of each candidate: (m, rolls) bool.

    points, normals: (n, 3) the sampled surface, metres, and its outward unit normals (they only shape the
    tree, never the result; None: by position alone, slower on parts with edges); midpoints (m, 3);
    axes (m, 3) unit, contact 0 -> 1;
    widths (m,) contact distances; inside (m,) bool. Roll k is the angle 2 pi k / rolls (CONTRACT.md).
    """
    return _run(points, normals, midpoints, axes, widths, inside, model, rolls)[0]


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
    kernel derives them per candidate, so no (m, 3) arrays are made (0.1 s of page faults at 1.6 M pairs).
    normals: as for free_rolls."""
    return _run(points, normals, None, None, None, inside, model, rolls, pairs=(i, j))[0]


def free_rolls_stats(points, normals, midpoints, axes, widths, inside, model, rolls, pairs=None):
    """free_rolls (or, with `pairs` = (i, j) and midpoints, axes, widths None, free_rolls_of_pairs) and its work
    counters, summed over candidates: finger node visits, finger point tests, palm node visits, palm point tests,
    cached-blocker tests, phases settled by the finger cache alone."""
    fr, stats = _run(points, normals, midpoints, axes, widths, inside, model, rolls, pairs=pairs)
    names = (
        "finger_nodes",
        "finger_points",
        "palm_nodes",
        "palm_points",
        "cache_tests",
        "cache_settled",
        "memo_tests",
        "memo_settled",
    )
    return fr, {k: int(v) for k, v in zip(names, stats.sum(axis=0), strict=True) if not k.startswith("_")}
