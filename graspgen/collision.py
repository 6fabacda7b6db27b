"""Criterion (d): which roll angles about the closing axis leave the gripper free of the sampled points.

Every mode is a set of up to three boxes in the grasp frame, tested at each roll: a roll is blocked when any
sampled point lies in any box (closed boxes). Modes:

- `paper`: the paper's test, the outer cuboid around both fingers minus the inner cuboid between them, the
  inner cuboid being longer than the contact distance by `Tolerances.inner_margin` on each side. That is the
  two finger boxes, each shortened by the margin at its contact face.
- `swept`: the fingers' whole travel from the pre-grasp opening to the contacts, plus the palm box.

Inside grasps mirror the fingers: they sit between the contacts and open outwards to them.

Speed: the points live in a bounding-volume hierarchy over Morton-ordered leaves. A node is skipped when its
box misses every region's slab along the axis or its radial band around the axis; a node lying wholly inside
the disc that every roll of a finger covers blocks all rolls at once. Points that blocked rolls recently are
kept per thread and tried first, because neighbouring candidates share most of their blockers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

from .gripper import GripperSpec
from .params import TOLERANCES, Tolerances

__all__ = ["MAX_ROLLS", "CollisionModel", "collision_model", "free_rolls"]

#: roll masks are one 64-bit word per candidate
MAX_ROLLS = 64
_LEAF = 8
_CACHE = 8
_CHUNK = 64


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
    palm: tuple[float, float, float, float] | None  # (half x, half y, z_low, z_high)
    inner_margin: float


def collision_model(gripper: GripperSpec, mode: str, tolerances: Tolerances = TOLERANCES) -> CollisionModel:
    palm = None
    if mode == "swept" and gripper.palm_depth > 0:
        z_hi = -gripper.finger_depth / 2
        palm = (
            gripper.stroke / 2 + gripper.finger_thickness,
            float(gripper.palm_width) / 2,
            z_hi - gripper.palm_depth,
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


def _regions(model: CollisionModel) -> np.ndarray:
    """Per-region constants (r, 10): kind, hy, z_lo, z_hi, r_min, r_max, r_in, palm half-x, angular half-width
    and centre angle of the region's sector around the axis at roll 0 (used for the palm only).

    kind 0 = finger at -x, 1 = finger at +x, 2 = palm. The x extent of fingers depends on the width and is
    computed per candidate.
    """
    hy, hz = model.half_finger_width, model.half_finger_depth
    r_max = np.hypot(hy, hz)
    rows = [[0, hy, -hz, hz, 0.0, r_max, min(hy, hz), 0.0, np.pi, 0.0]]
    rows.append([1, *rows[0][1:]])
    if model.palm is not None:
        phx, phy, zlo, zhi = model.palm
        r_min = 0.0 if zlo <= 0.0 <= zhi else min(abs(zlo), abs(zhi))
        # the palm lies wholly on the -z side (zhi < 0): its sector is centred on -pi/2, widest at z = zhi
        beta = np.arctan2(phy, abs(zhi)) if zhi < 0 else np.pi
        rows.append([2, phy, zlo, zhi, r_min, np.hypot(phy, max(abs(zlo), abs(zhi))), 0.0, phx, beta, -np.pi / 2])
    return np.array(rows, dtype=np.float64)


# -- bounding-volume hierarchy ------------------------------------------------------------------------------------


def _morton_order(points: np.ndarray) -> np.ndarray:
    lo = points.min(axis=0)
    span = max(float((points.max(axis=0) - lo).max()), 1e-12)
    q = np.minimum(((points - lo) / span * 1023.0).astype(np.int64), 1023)
    code = np.zeros(len(points), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.argsort(code, kind="stable")


@njit(cache=True)
def _build_bvh(P, N, leaves, leaf_size):
    """Implicit complete binary tree: node 1 is the root, children 2k and 2k+1, leaves from `leaves` on.

    Each node has an axis-aligned box (lo, hi) and a disc bound (disc: centre xyz, unit normal xyz, thickness
    along the normal, radius in its plane): surface patches are thin along their normal, and near a contact the
    closing axis is close to that normal, so the disc projects onto the axis far tighter than the box.
    """
    n = P.shape[0]
    lo = np.full((2 * leaves, 3), np.inf)
    hi = np.full((2 * leaves, 3), -np.inf)
    disc = np.zeros((2 * leaves, 8))
    for node in range(1, 2 * leaves):
        depth = 0
        k = node
        while k > 1:
            k >>= 1
            depth += 1
        span = leaves >> depth  # leaves under this node
        first_leaf = node * span - leaves
        first = first_leaf * leaf_size
        last = min(n, (first_leaf + span) * leaf_size)
        if first >= last:
            continue
        cnt = last - first
        c = np.zeros(3)
        nm = np.zeros(3)
        for p in range(first, last):
            for a in range(3):
                lo[node, a] = min(lo[node, a], P[p, a])
                hi[node, a] = max(hi[node, a], P[p, a])
                c[a] += P[p, a]
                nm[a] += N[p, a]
        c /= cnt
        ln = np.sqrt(nm[0] ** 2 + nm[1] ** 2 + nm[2] ** 2)
        if ln < 1e-9:
            nm[0], nm[1], nm[2] = 0.0, 0.0, 1.0
        else:
            nm /= ln
        th = 0.0
        rad = 0.0
        for p in range(first, last):
            dx, dy, dz = P[p, 0] - c[0], P[p, 1] - c[1], P[p, 2] - c[2]
            h = dx * nm[0] + dy * nm[1] + dz * nm[2]
            th = max(th, abs(h))
            rad = max(rad, np.sqrt(max(dx * dx + dy * dy + dz * dz - h * h, 0.0)))
        disc[node, 0], disc[node, 1], disc[node, 2] = c[0], c[1], c[2]
        disc[node, 3], disc[node, 4], disc[node, 5] = nm[0], nm[1], nm[2]
        disc[node, 6] = th * (1.0 + 1e-12) + 1e-15  # outward rounding keeps the bound conservative
        disc[node, 7] = rad * (1.0 + 1e-12) + 1e-15
    return lo, hi, disc


# -- the kernel --------------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
def _x_ranges(regions, kind_inside, w, model_f):
    """Per-region x interval for one candidate; model_f = (t, stroke, min_width, clearance, margin)."""
    t, stroke, min_width, clearance, margin = model_f[0], model_f[1], model_f[2], model_f[3], model_f[4]
    nr = regions.shape[0]
    xr = np.empty((nr, 2))
    for r in range(nr):
        kind = regions[r, 0]
        if kind == 2.0:
            xr[r, 0] = -regions[r, 7]
            xr[r, 1] = regions[r, 7]
            continue
        if not kind_inside:
            o = min(w + clearance, stroke)
            a, b = w / 2 + margin, max(o, w) / 2 + t
        else:
            o = max(w - clearance, min_width + 2 * t)
            a, b = min(o, w) / 2 - t, w / 2 - margin
        if kind == 0.0:
            xr[r, 0], xr[r, 1] = -b, -a
        else:
            xr[r, 0], xr[r, 1] = a, b
    return xr


@njit(cache=True, inline="always")
def _point_mask(qx, qy, qz, ax, ay, az, yb, zb, regions, r0, r1, xr, cos_k, sin_k, target):
    """Rolls within `target` blocked by one point (relative position q) in regions r0..r1-1."""
    x = qx * ax + qy * ay + qz * az
    mask = np.uint64(0)
    for r in range(r0, r1):
        if x < xr[r, 0] or x > xr[r, 1]:
            continue
        y0 = qx * yb[0] + qy * yb[1] + qz * yb[2]
        z0 = qx * zb[0] + qy * zb[1] + qz * zb[2]
        r2 = y0 * y0 + z0 * z0
        if r2 > regions[r, 5] * regions[r, 5] or r2 < regions[r, 4] * regions[r, 4]:
            continue
        if r2 <= regions[r, 6] * regions[r, 6]:
            return target
        hy, zlo, zhi = regions[r, 1], regions[r, 2], regions[r, 3]
        for k in range(cos_k.shape[0]):
            bit = np.uint64(1) << np.uint64(k)
            if not (target & bit):
                continue
            y = y0 * cos_k[k] + z0 * sin_k[k]
            z = -y0 * sin_k[k] + z0 * cos_k[k]
            if abs(y) <= hy and z >= zlo and z <= zhi:
                mask |= bit
        if mask == target:
            return target
    return mask


@njit(cache=True)
def _phase(
    mid,
    ax,
    ay,
    az,
    yb,
    zb,
    P,
    lo,
    hi,
    disc,
    leaves,
    leaf_size,
    regions,
    r0,
    r1,
    xr,
    cos_k,
    sin_k,
    psi,
    target,
    angular,
    stack,
    cache,
    cache_pos,
):
    """Rolls within `target` blocked by regions r0..r1-1. With `angular` (the palm, which lies on one side of
    the axis), a node is skipped when no target roll turns the region towards the node's angular sector."""
    mask = np.uint64(0)
    for c in range(cache.shape[0]):
        p = cache[c]
        if p < 0:
            continue
        mask |= _point_mask(
            P[p, 0] - mid[0],
            P[p, 1] - mid[1],
            P[p, 2] - mid[2],
            ax,
            ay,
            az,
            yb,
            zb,
            regions,
            r0,
            r1,
            xr,
            cos_k,
            sin_k,
            target & ~mask,
        )
        if mask == target:
            return mask, cache_pos
    n = P.shape[0]
    stack[0] = 1
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        if lo[node, 0] > hi[node, 0]:
            continue  # empty padding
        cx = 0.5 * (lo[node, 0] + hi[node, 0]) - mid[0]
        cy = 0.5 * (lo[node, 1] + hi[node, 1]) - mid[1]
        cz = 0.5 * (lo[node, 2] + hi[node, 2]) - mid[2]
        hx_ = 0.5 * (hi[node, 0] - lo[node, 0])
        hy_ = 0.5 * (hi[node, 1] - lo[node, 1])
        hz_ = 0.5 * (hi[node, 2] - lo[node, 2])
        xc = cx * ax + cy * ay + cz * az
        xh = hx_ * abs(ax) + hy_ * abs(ay) + hz_ * abs(az)
        rho = np.sqrt(hx_ * hx_ + hy_ * hy_ + hz_ * hz_)
        # the disc bound along the axis; keep the tighter of the two intervals
        cn = disc[node, 3] * ax + disc[node, 4] * ay + disc[node, 5] * az
        dxc = (disc[node, 0] - mid[0]) * ax + (disc[node, 1] - mid[1]) * ay + (disc[node, 2] - mid[2]) * az
        dxh = disc[node, 6] * abs(cn) + disc[node, 7] * np.sqrt(max(1.0 - cn * cn, 0.0))
        x_lo = max(xc - xh, dxc - dxh)
        x_hi = min(xc + xh, dxc + dxh)
        dp = np.sqrt(max(cx * cx + cy * cy + cz * cz - xc * xc, 0.0))
        hit = False
        for r in range(r0, r1):
            if x_hi < xr[r, 0] or x_lo > xr[r, 1]:
                continue
            if dp - rho > regions[r, 5] or dp + rho < regions[r, 4]:
                continue
            if x_lo >= xr[r, 0] and x_hi <= xr[r, 1] and dp + rho <= regions[r, 6]:
                return target, cache_pos  # the node lies where every roll of this finger is
            if angular:
                # per roll: skip the node where its bounding sphere misses the rotated box; block the roll
                # outright where the sphere lies inside it (every point of the node is then in the box)
                y0 = cx * yb[0] + cy * yb[1] + cz * yb[2]
                z0 = cx * zb[0] + cy * zb[1] + cz * zb[2]
                hy, zlo, zhi = regions[r, 1], regions[r, 2], regions[r, 3]
                x_in = x_lo >= xr[r, 0] and x_hi <= xr[r, 1]
                todo = target & ~mask
                reach = np.uint64(0)
                for k in range(psi.shape[0]):
                    bit = np.uint64(1) << np.uint64(k)
                    if not (todo & bit):
                        continue
                    y = y0 * cos_k[k] + z0 * sin_k[k]
                    z = -y0 * sin_k[k] + z0 * cos_k[k]
                    if abs(y) > hy + rho or z < zlo - rho or z > zhi + rho:
                        continue
                    if x_in and abs(y) + rho <= hy and z - rho >= zlo and z + rho <= zhi:
                        mask |= bit
                    else:
                        reach |= bit
                if mask == target:
                    return mask, cache_pos
                if not reach:
                    continue
            hit = True
            break
        if not hit:
            continue
        if node >= leaves:
            first = (node - leaves) * leaf_size
            for p in range(first, min(first + leaf_size, n)):
                m = _point_mask(
                    P[p, 0] - mid[0],
                    P[p, 1] - mid[1],
                    P[p, 2] - mid[2],
                    ax,
                    ay,
                    az,
                    yb,
                    zb,
                    regions,
                    r0,
                    r1,
                    xr,
                    cos_k,
                    sin_k,
                    target & ~mask,
                )
                if m:
                    mask |= m
                    cache[cache_pos] = p
                    cache_pos = (cache_pos + 1) % cache.shape[0]
                    if mask == target:
                        return mask, cache_pos
        else:
            stack[top] = 2 * node + 1
            stack[top + 1] = 2 * node
            top += 2
    return mask, cache_pos


@njit(cache=True)
def _candidate(
    mid,
    ax,
    ay,
    az,
    w,
    kind_inside,
    P,
    lo,
    hi,
    disc,
    leaves,
    leaf_size,
    regions,
    model_f,
    cos_k,
    sin_k,
    psi,
    full,
    switch,
    stack,
    caches,
    cache_pos,
):
    yx, yy, yz, zx, zy, zz = _basis(ax, ay, az, switch)
    yb = (yx, yy, yz)
    zb = (zx, zy, zz)
    xr = _x_ranges(regions, kind_inside, w, model_f)
    # the fingers first: small regions, and they settle most candidates
    blocked, cache_pos[0] = _phase(
        mid,
        ax,
        ay,
        az,
        yb,
        zb,
        P,
        lo,
        hi,
        disc,
        leaves,
        leaf_size,
        regions,
        0,
        2,
        xr,
        cos_k,
        sin_k,
        psi,
        full,
        False,
        stack,
        caches[0],
        cache_pos[0],
    )
    if blocked != full and regions.shape[0] > 2:
        more, cache_pos[1] = _phase(
            mid,
            ax,
            ay,
            az,
            yb,
            zb,
            P,
            lo,
            hi,
            disc,
            leaves,
            leaf_size,
            regions,
            2,
            regions.shape[0],
            xr,
            cos_k,
            sin_k,
            psi,
            full & ~blocked,
            True,
            stack,
            caches[1],
            cache_pos[1],
        )
        blocked |= more
    return blocked


@njit(parallel=True, cache=True)
def _free_rolls_kernel(
    mids,
    axes,
    widths,
    inside,
    P,
    lo,
    hi,
    disc,
    leaves,
    leaf_size,
    regions,
    model_f,
    cos_k,
    sin_k,
    psi,
    full,
    switch,
    out,
):
    m = mids.shape[0]
    nchunks = (m + _CHUNK - 1) // _CHUNK
    for c in prange(nchunks):
        stack = np.empty(128, dtype=np.int64)
        caches = np.full((2, _CACHE), -1, dtype=np.int64)  # recent blockers: fingers, palm
        cache_pos = np.zeros(2, dtype=np.int64)
        for q in range(c * _CHUNK, min((c + 1) * _CHUNK, m)):
            blocked = _candidate(
                mids[q],
                axes[q, 0],
                axes[q, 1],
                axes[q, 2],
                widths[q],
                inside[q],
                P,
                lo,
                hi,
                disc,
                leaves,
                leaf_size,
                regions,
                model_f,
                cos_k,
                sin_k,
                psi,
                full,
                switch,
                stack,
                caches,
                cache_pos,
            )
            out[q] = ~blocked & full


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

    points, normals: (n, 3) the sampled surface, metres, and its unit normals (they only tighten bounds);
    midpoints (m, 3); axes (m, 3) unit, contact 0 -> 1;
    widths (m,) contact distances; inside (m,) bool. Roll k is the angle 2 pi k / rolls (CONTRACT.md).
    """
    from .transforms import ROLL_REFERENCE_SWITCH, roll_angles_rad

    if not 1 <= rolls <= MAX_ROLLS:
        raise ValueError(f"rolls must be 1..{MAX_ROLLS}")
    m = len(midpoints)
    if m == 0 or len(points) == 0:
        return np.ones((m, rolls), dtype=bool)
    order = _morton_order(points)
    P = np.ascontiguousarray(points[order], dtype=np.float64)
    n_leaves = (len(P) + _LEAF - 1) // _LEAF
    leaves = 1 << max(int(np.ceil(np.log2(max(n_leaves, 1)))), 0)
    lo, hi, disc = _build_bvh(P, np.ascontiguousarray(normals[order], dtype=np.float64), leaves, _LEAF)
    psi = roll_angles_rad(rolls)
    full = np.uint64((1 << rolls) - 1) if rolls < 64 else np.uint64(0xFFFFFFFFFFFFFFFF)
    model_f = np.array([model.finger_thickness, model.stroke, model.min_width, model.clearance, model.inner_margin])
    out = np.zeros(m, dtype=np.uint64)
    with numba.parallel_chunksize(1):
        _free_rolls_kernel(
            np.ascontiguousarray(midpoints, dtype=np.float64),
            np.ascontiguousarray(axes, dtype=np.float64),
            np.ascontiguousarray(widths, dtype=np.float64),
            np.ascontiguousarray(inside, dtype=np.bool_),
            P,
            lo,
            hi,
            disc,
            leaves,
            _LEAF,
            _regions(model),
            model_f,
            np.cos(psi),
            np.sin(psi),
            psi,
            full,
            ROLL_REFERENCE_SWITCH,
            out,
        )
    bits = (out[:, None] >> np.arange(rolls, dtype=np.uint64)[None, :]) & np.uint64(1)
    return bits.astype(bool)
