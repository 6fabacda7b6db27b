"""Where a finger from CAD first meets the part as it closes (CONTRACT.md "Gripper geometry from CAD": the fingers
close until they touch).

A finger whose inner face is not flat at its frame's origin (a V-groove, a ridge, a chamfered tip) does not touch the
part at the sampled contact: it closes further, or touches elsewhere first. From the contact end of its travel (its
frame at s = width / 2 + the inner margin, where criterion (d) found it clear), the finger moves towards the part
along its closing direction until its surface first meets the part's triangles. That first contact of two triangle
meshes under a translation is exact: it happens where a vertex of one meets a face of the other or where two edges
meet (`_first_contact`); every feature that meets within `SEAT_TOLERANCE` of the first is a contact of the seat (a
round part in a V-groove touches both flanks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from ._tritree import COUNT, LEFT, RIGHT, START, MeshTree, node_misses_box

if TYPE_CHECKING:
    from ._meshsolid import MeshSet
    from ._solids import GripperSolids
    from ._tritree import TriangleTree

__all__ = ["Seat", "seat_fingers", "SEAT_TOLERANCE", "seat_friction_margin_deg", "triangle_bounds"]

#: features that meet the part within this distance of the first one are contacts of the same seat, metres
SEAT_TOLERANCE = 2.0e-5
#: contacts of one finger closer than this are one contact, metres
_MERGE = 1.0e-3
_MAX_FEATURES = 4096


@dataclass(frozen=True)
class Seat:
    """Both fingers seated on the part: `travel` (2,) how far each finger (-X, +X) closed past the contact end of its
    travel (m; negative: it touched before), `width` the distance between the seated fingers' frames (m), `points`
    and `normals`: per finger the contact points (k, 3) on the part and the part's outward unit normals there,
    object frame."""

    travel: tuple[float, float]
    width: float
    points: tuple[np.ndarray, np.ndarray]
    normals: tuple[np.ndarray, np.ndarray]


@njit(cache=True, inline="always", error_model="numpy")
def _ray_triangle(o0: float, o1: float, o2: float, eps: float, T: np.ndarray, sign: float) -> float:
    """The distance t >= 0 at which the ray o + t (sign, 0, 0) meets the closed triangle T (3, 3), or inf."""
    e1x, e1y, e1z = T[1, 0] - T[0, 0], T[1, 1] - T[0, 1], T[1, 2] - T[0, 2]
    e2x, e2y, e2z = T[2, 0] - T[0, 0], T[2, 1] - T[0, 1], T[2, 2] - T[0, 2]
    # p = d x e2 with d = (sign, 0, 0)
    px, py, pz = 0.0, -sign * e2z, sign * e2y
    det = e1x * px + e1y * py + e1z * pz
    if abs(det) < 1e-30:
        return np.inf
    inv = 1.0 / det
    sx, sy, sz = o0 - T[0, 0], o1 - T[0, 1], o2 - T[0, 2]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < -eps or u > 1.0 + eps:
        return np.inf
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (sign * qx) * inv
    if v < -eps or u + v > 1.0 + eps:
        return np.inf
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return t if t >= 0.0 else np.inf


@njit(cache=True, error_model="numpy")
def _first_contact(
    A_all: np.ndarray,
    NA: np.ndarray,
    solid: TriangleTree,
    dmax: float,
    limit: float,
    out_t: np.ndarray,
    out_p: np.ndarray,
    out_n: np.ndarray,
) -> tuple[float, int]:
    """The part's triangles A_all (n, 3, 3) (unit outward normals NA (n, 3)), in the finger's frame at the contact
    end of its travel, move along +X (the finger closes along -X) by up to dmax. Every vertex-face and edge-edge
    meeting with the finger's triangles (the TriangleTree `solid`) within that travel is found; those at a distance
    t <= limit go into out_t, out_p (the point on the part, finger frame before the move) and out_n (the part's
    outward normal there), as many as fit (none with limit < 0). Returns (the smallest t, inf for none; how many
    were written). The walk for a part triangle covers its box moved by min(dmax, the smallest t so far) when
    limit < 0, by min(dmax, limit) otherwise: exactly the features that can matter."""
    nodes, children, B_all = solid.nodes, solid.children, solid.triangles
    count = 0
    tmin = np.inf
    stack = np.empty(128, dtype=np.int64)
    cap = out_t.shape[0]
    for a in range(A_all.shape[0]):
        A = A_all[a]
        lo0 = min(A[0, 0], A[1, 0], A[2, 0])
        # a feature at t lies within the triangle's box moved by t: only t up to the smallest found so far (the
        # first contact) or up to `limit` (the contacts written) can matter, so the walk's box shrinks with them
        reach = min(dmax, tmin) if limit < 0.0 else min(dmax, limit)
        hi0 = max(A[0, 0], A[1, 0], A[2, 0]) + reach
        lo1, hi1 = min(A[0, 1], A[1, 1], A[2, 1]), max(A[0, 1], A[1, 1], A[2, 1])
        lo2, hi2 = min(A[0, 2], A[1, 2], A[2, 2]), max(A[0, 2], A[1, 2], A[2, 2])
        stack[0] = 0
        top = 1 if nodes.shape[0] else 0
        while top > 0:
            top -= 1
            k = stack[top]
            if node_misses_box(nodes, k, (lo0, lo1, lo2), (hi0, hi1, hi2)):
                continue
            if children[k, LEFT] >= 0:
                stack[top] = children[k, LEFT]
                stack[top + 1] = children[k, RIGHT]
                top += 2
                continue
            for b in range(children[k, START], children[k, START] + children[k, COUNT]):
                B = B_all[b]
                nbx = (B[1, 1] - B[0, 1]) * (B[2, 2] - B[0, 2]) - (B[1, 2] - B[0, 2]) * (B[2, 1] - B[0, 1])
                nby = (B[1, 2] - B[0, 2]) * (B[2, 0] - B[0, 0]) - (B[1, 0] - B[0, 0]) * (B[2, 2] - B[0, 2])
                nbz = (B[1, 0] - B[0, 0]) * (B[2, 1] - B[0, 1]) - (B[1, 1] - B[0, 1]) * (B[2, 0] - B[0, 0])
                nb = np.sqrt(nbx * nbx + nby * nby + nbz * nbz)
                # a part vertex moving along +X onto the finger's face: the normal there is the face's, reversed
                for c in range(3):
                    t = _ray_triangle(A[c, 0], A[c, 1], A[c, 2], 1e-12, B, 1.0)
                    if t <= dmax and nb > 0.0:
                        tmin = min(tmin, t)
                        if t <= limit and count < cap:
                            out_t[count] = t
                            out_p[count, 0], out_p[count, 1], out_p[count, 2] = A[c, 0], A[c, 1], A[c, 2]
                            out_n[count, 0], out_n[count, 1], out_n[count, 2] = -nbx / nb, -nby / nb, -nbz / nb
                            count += 1
                # a finger vertex meeting the part's face (the finger moves along -X relative to the part)
                for c in range(3):
                    t = _ray_triangle(B[c, 0], B[c, 1], B[c, 2], 1e-12, A, -1.0)
                    if t <= dmax:
                        tmin = min(tmin, t)
                        if t <= limit and count < cap:
                            out_t[count] = t
                            out_p[count, 0], out_p[count, 1], out_p[count, 2] = B[c, 0] - t, B[c, 1], B[c, 2]
                            out_n[count, 0], out_n[count, 1], out_n[count, 2] = NA[a, 0], NA[a, 1], NA[a, 2]
                            count += 1
                # edge against edge: a0 + u ea + t X = b0 + v eb
                for i in range(3):
                    a0x, a0y, a0z = A[i, 0], A[i, 1], A[i, 2]
                    j = (i + 1) % 3
                    eax, eay, eaz = A[j, 0] - a0x, A[j, 1] - a0y, A[j, 2] - a0z
                    for m in range(3):
                        n = (m + 1) % 3
                        ebx, eby, ebz = B[n, 0] - B[m, 0], B[n, 1] - B[m, 1], B[n, 2] - B[m, 2]
                        # columns ea, -eb, X; the right-hand side d = b0 - a0
                        dx, dy, dz = B[m, 0] - a0x, B[m, 1] - a0y, B[m, 2] - a0z
                        # det [ea, -eb, X] = X . (ea x -eb) = -(ea x eb)_x
                        cx = eay * ebz - eaz * eby
                        det = -cx
                        if abs(det) < 1e-30:
                            continue
                        # Cramer: u = det[d, -eb, X] / det, v = det[ea, d, X] / det
                        u = -(dy * ebz - dz * eby) / det
                        v = (eay * dz - eaz * dy) / det
                        if u < 0.0 or u > 1.0 or v < 0.0 or v > 1.0:
                            continue
                        t = dx - u * eax + v * ebx
                        if t < 0.0 or t > dmax:
                            continue
                        nx, ny, nz = cx, eaz * ebx - eax * ebz, eax * eby - eay * ebx
                        nn = np.sqrt(nx * nx + ny * ny + nz * nz)
                        if nn == 0.0:
                            continue
                        if nx < 0.0:  # the part's outward normal faces the finger, which lies along +X
                            nx, ny, nz = -nx, -ny, -nz
                        tmin = min(tmin, t)
                        if t <= limit and count < cap:
                            out_t[count] = t
                            out_p[count, 0], out_p[count, 1] = a0x + u * eax, a0y + u * eay
                            out_p[count, 2] = a0z + u * eaz
                            out_n[count, 0], out_n[count, 1], out_n[count, 2] = nx / nn, ny / nn, nz / nn
                            count += 1
    return tmin, count


def triangle_bounds(part: MeshTree) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle's axis-aligned bounds (lo, hi), (n, 3) each, object frame: seat_fingers' prefilter, computed
    once per part."""
    return part.triangles.min(axis=1), part.triangles.max(axis=1)


def seat_fingers(
    part: MeshTree,
    solids: GripperSolids,
    T_object_grasp: np.ndarray,
    width: float,
    margin: float,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> Seat | None:
    """Seat both fingers of a gripper from CAD (GripperSolids with meshes) on the part at the grasp T_object_grasp
    (4, 4) of contact distance `width`: each closes from width / 2 + margin along its closing direction until it
    first meets the part's triangles (at most to the grasp's midplane). None when a finger reaches the midplane
    without touching. `bounds` (triangle_bounds of the part) lets only the triangles near the fingers' travel be
    moved into the grasp frame; the seat is the same without it."""
    R, o = T_object_grasp[:3, :3], T_object_grasp[:3, 3]
    s0 = width / 2 + margin
    assert solids.meshes is not None  # a gripper from CAD: the pipeline seats only fingers with meshes
    keep = slice(None) if bounds is None else _near_travel(solids.meshes, R, o, s0, bounds)
    tri = (part.triangles[keep] - o) @ R  # the part in the grasp frame
    nrm = part.normals[keep] @ R
    travels, points, normals = [], [], []
    for side, solid in ((-1, solids.meshes.left), (1, solids.meshes.right)):
        # the part in the finger's frame at s0: (x - s0, y, z) for +X; turned half a turn about Z for -X
        flip = np.array([side, side, 1.0])
        A = tri * flip
        A[..., 0] -= s0
        NA = nrm * flip
        lo, hi = np.asarray(solid.bounds.lo), np.asarray(solid.bounds.hi)
        amin, amax = A.min(axis=1), A.max(axis=1)
        near = (
            (amax[:, 0] + s0 >= lo[0])
            & (amin[:, 0] <= hi[0])
            & np.all(amax[:, 1:] >= lo[1:], axis=1)
            & np.all(amin[:, 1:] <= hi[1:], axis=1)
        )
        out_t = np.full(_MAX_FEATURES, np.inf)
        out_p = np.zeros((_MAX_FEATURES, 3))
        out_n = np.zeros((_MAX_FEATURES, 3))
        An, Nn, rec = np.ascontiguousarray(A[near]), np.ascontiguousarray(NA[near]), solid.record()
        # the first contact with the triangles nearest the finger first: the smallest t so far bounds the walk
        nearest = np.argsort(-An[:, :, 0].max(axis=1), kind="stable")
        first, _ = _first_contact(An[nearest], Nn[nearest], rec, s0, -1.0, out_t, out_p, out_n)
        if not np.isfinite(first):
            return None
        first = float(first)
        _, n = _first_contact(An, Nn, rec, s0, first + SEAT_TOLERANCE, out_t, out_p, out_n)
        p, nn = _merge(out_p[:n], out_n[:n])
        # back to the object frame: undo the finger frame, then the grasp frame
        g = p.copy()
        g[:, 0] += s0
        g *= flip
        travels.append(first - margin)
        points.append(g @ R.T + o)
        normals.append((nn * flip) @ R.T)
    seated = 2 * s0 - (travels[0] + margin) - (travels[1] + margin)
    return Seat((travels[0], travels[1]), float(seated), (points[0], points[1]), (normals[0], normals[1]))


def _near_travel(
    meshes: MeshSet, R: np.ndarray, o: np.ndarray, s0: float, bounds: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """Indices of the triangles whose bounds meet the box, in the grasp frame, that holds both fingers over their
    whole travel (from s0 to the midplane): that box's axis-aligned bounds in the object frame (centre o + R c,
    half-extents |R| h), a conservative prefilter."""
    reach = np.zeros(3)
    zlo, zhi = np.inf, -np.inf
    for solid in (meshes.left, meshes.right):
        lo, hi = np.asarray(solid.bounds.lo), np.asarray(solid.bounds.hi)
        reach = np.maximum(reach, np.maximum(np.abs(lo), np.abs(hi)))
        zlo, zhi = min(zlo, float(lo[2])), max(zhi, float(hi[2]))
    half = np.array([s0 + reach[0], reach[1], (zhi - zlo) / 2])
    centre = R @ np.array([0.0, 0.0, (zhi + zlo) / 2]) + o
    h = np.abs(R) @ half + SEAT_TOLERANCE
    lo_t, hi_t = bounds
    hit = np.all(hi_t >= centre - h, axis=1) & np.all(lo_t <= centre + h, axis=1)
    found: np.ndarray = np.flatnonzero(hit)
    return found


def _merge(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contacts closer than _MERGE as one: the first of each group, the group's mean normal."""
    keep_p, keep_n = [], []
    used = np.zeros(len(points), dtype=bool)
    for q in range(len(points)):
        if used[q]:
            continue
        group = ~used & (np.linalg.norm(points - points[q], axis=1) < _MERGE)
        used |= group
        n = normals[group].mean(axis=0)
        keep_p.append(points[q])
        keep_n.append(n / max(np.linalg.norm(n), 1e-300))
    return np.array(keep_p), np.array(keep_n)


def seat_friction_margin_deg(seat: Seat, axis: np.ndarray, half_angle_deg: float) -> float:
    """Criterion (c) on the seat: each finger pushes the part along the closing axis (the -X finger along +X, the +X
    finger along -X); its contacts can carry that push when the push lies in the cone spanned by their friction
    cones (half-angle `half_angle_deg` about each inward normal). For one contact that is the contract's friction
    margin; for two (a V-groove's flanks) the push may lie anywhere within the half-angle of the arc between their
    inward normals. Returns the worse finger's margin: the half-angle less the push's angle to that set, degrees."""
    worst = np.inf
    for k, push in ((0, axis), (1, -axis)):
        inward = -seat.normals[k]
        angles = [_angle_deg(push, n) for n in inward]
        best = min(angles)
        for a in range(len(inward)):
            for b in range(a + 1, len(inward)):
                best = min(best, _angle_to_arc_deg(push, inward[a], inward[b]))
        worst = min(worst, half_angle_deg - best)
    return float(worst)


def _angle_deg(u: np.ndarray, v: np.ndarray) -> float:
    c = float(np.dot(u, v) / (np.linalg.norm(u) * np.linalg.norm(v)))
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


def _angle_to_arc_deg(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """The angle from the unit direction p to the great-circle arc from a to b (the shorter one)."""
    n = np.cross(a, b)
    nn = np.linalg.norm(n)
    if nn < 1e-12:
        return min(_angle_deg(p, a), _angle_deg(p, b))
    n /= nn
    q = p - np.dot(p, n) * n  # p projected onto the arc's plane
    if np.linalg.norm(q) < 1e-12:
        return 90.0
    q /= np.linalg.norm(q)
    # on the arc when q lies between a and b
    if np.dot(np.cross(a, q), n) >= 0 and np.dot(np.cross(q, b), n) >= 0:
        return _angle_deg(p, q)
    return min(_angle_deg(p, a), _angle_deg(p, b))
