"""Pair criteria (a) stroke, (b) outside, (c) friction, as compiled kernels over a spatial grid.

All unordered pairs (i < j) of the sampled points are judged, cheapest test first; pairs in grid cells farther
apart than the largest allowed width are counted as stroke rejections without being visited, so no n^2 array is
ever built. Contact 0 is the point with the smaller index; the closing axis runs from contact 0 to contact 1.

Outside grasp: the fingers close from outside, so each normal points away from the other contact
(n0 . d < 0 < n1 . d, d = p1 - p0). Inside grasp (optional): the fingers sit between the contacts and open
outwards, so the normals face each other (n0 . d > 0 > n1 . d). Friction: the finger force is along the closing
axis, so the angle between the axis and each (inward) normal must stay within arctan(mu) / safety_factor. With a
position tolerance (a per-point `spread`: the largest angle between the point's normal and a surface normal within
the tolerance), (c) holds for every such normal: contact angle + spread <= the half-angle, i.e. a per-point cone
cos(half - spread), judged in the same pass.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass
from typing import cast

import numpy as np
from numba import njit, prange

from . import libm
from .collision import popcount

__all__ = [
    "PairResult",
    "PairPlan",
    "pair_plan",
    "cone_half_angle_rad",
    "antipodal_pairs",
    "friction_margin_deg",
    "grid_order",
    "pair_cell_size",
]


@dataclass(frozen=True)
class PairResult:
    """Pairs that pass (a)-(c), in a deterministic order (by contact 0, then contact 1)."""

    i: np.ndarray  # (m,) int64, contact 0 (index into the sample)
    j: np.ndarray  # (m,) int64, contact 1, i < j
    inside: np.ndarray  # (m,) bool, True for inside grasps
    pairs_total: int
    rejected_stroke: int
    rejected_outside: int
    rejected_friction: int


def cone_half_angle_rad(friction: float, safety_factor: float) -> float:
    """The usable friction cone half-angle: arctan(mu) / safety factor."""
    return math.atan(friction) / safety_factor


def pair_cell_size(stroke: float, inside: bool, finger_thickness: float) -> float:
    """Grid cell of the pair search: half the largest allowed contact distance."""
    return (stroke + (2 * finger_thickness if inside else 0.0)) / 2.0


def grid_order(points: np.ndarray, cell: float) -> np.ndarray:
    """A deterministic spatial order of `points` (n, 3): by grid cell (x-major), stable within a cell.

    Points already in this order skip a re-sort of the pairs, and neighbouring candidates share blockers in
    the collision stage.
    """
    return _grid(np.asarray(points, dtype=np.float64), cell)[0]


def _grid(points: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sort points into a dense grid: returns (order, cell_start (ncells+1,), dims (3,), origin (3,))."""
    origin = points.min(axis=0)
    idx = np.floor((points - origin) / cell).astype(np.int64)
    dims = idx.max(axis=0) + 1
    flat = (idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2]
    order = np.argsort(flat, kind="stable")
    counts = np.bincount(flat, minlength=int(np.prod(dims)))
    cell_start = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=cell_start[1:])
    return order, cell_start, dims.astype(np.int64), origin


#: The points in the kernel's grid order: coordinates x, y, z (n,) and normals nx, ny, nz (n,), metres; c2 (n,) the
#: cos^2 of each point's friction cone within the position tolerance.
PairSurface = namedtuple("PairSurface", ["x", "y", "z", "nx", "ny", "nz", "c2"])
#: The spatial grid the pairs are searched in: cell_start (cells + 1,) offsets into the points, dims (3,), origin
#: (3,), cell size (m) and reach (cells searched on each side).
PairGrid = namedtuple("PairGrid", ["cell_start", "dims", "origin", "cell", "reach"])
#: What a pair must satisfy: lims (7,) = squared distance bounds (all, outside, inside grasps) and cos^2 of the
#: cone; inside_ok: inside grasps are wanted.
PairRule = namedtuple("PairRule", ["lims", "inside_ok"])
#: Where the kernel writes: fill (False: count only), offsets (n + 1,) of each row's pairs, out_j, out_inside (the
#: pairs of a block), counters (n, 4) per row (counting pass).
PairOut = namedtuple("PairOut", ["fill", "offsets", "out_j", "out_inside", "counters"])


@njit(cache=True, inline="always", error_model="numpy")
def _judge(s: PairSurface, i: int | np.int64, j: int, rule: PairRule) -> tuple[bool, bool, bool, bool, bool]:
    """(accepted, bad orientation, passes (a) and (b), inside, passes (c) without the tolerance) for the pair
    (i, j); branch-free. C2: per point, cos^2 of its cone within the position tolerance (cos2 where no spread)."""
    X, Y, Z, NX, NY, NZ, C2 = s.x, s.y, s.z, s.nx, s.ny, s.nz, s.c2
    lims, inside_ok = rule.lims, rule.inside_ok
    lo2, hi2, out_lo2, out_hi2, in_lo2, in_hi2, cos2 = lims[0], lims[1], lims[2], lims[3], lims[4], lims[5], lims[6]
    dx = X[j] - X[i]
    dy = Y[j] - Y[i]
    dz = Z[j] - Z[i]
    d2 = dx * dx + dy * dy + dz * dz
    u = NX[i] * dx + NY[i] * dy + NZ[i] * dz
    v = NX[j] * dx + NY[j] * dy + NZ[j] * dz
    lim = cos2 * d2
    in_range = (d2 <= hi2) & (d2 >= lo2)
    o_out = (u < 0.0) & (v > 0.0)
    o_in = inside_ok & (u > 0.0) & (v < 0.0)
    ab_out = o_out & (d2 <= out_hi2) & (d2 >= out_lo2)
    ab_in = o_in & (d2 <= in_hi2) & (d2 >= in_lo2)
    pass_ab = in_range & (ab_out | ab_in)
    u2 = u * u
    v2 = v * v
    acc_c = pass_ab & (u2 >= lim) & (v2 >= lim)
    acc = acc_c & (u2 >= C2[i] * d2) & (v2 >= C2[j] * d2)
    return acc, in_range & ~(o_out | o_in), pass_ab, ab_in, acc_c


@njit(cache=True, error_model="numpy")
def _count_run(s: PairSurface, i: int | np.int64, start: int, stop: int, rule: PairRule) -> tuple[int, int, int, int]:
    # no stores in this loop, so that it vectorises
    n_acc = 0
    n_bad = 0
    n_ab = 0
    n_c = 0
    for j in range(start, stop):
        acc, bad, ab, _, acc_c = _judge(s, i, j, rule)
        n_acc += acc
        n_bad += bad
        n_ab += ab
        n_c += acc_c
    return n_acc, n_bad, n_ab, n_c


@njit(cache=True, error_model="numpy")
def _fill_run(
    s: PairSurface, i: int | np.int64, start: int, stop: int, rule: PairRule, out: PairOut, pos: int, end: int
) -> int:
    # 64 pairs at a time: their verdicts packed into a word by a branch-free (vectorised) loop, then the few
    # accepted ones (~3 %) stored in order. The row's count is known from the counting pass: stop at `end`
    for b0 in range(start, stop, 64):
        if pos == end:
            break
        acc_w = np.uint64(0)
        ins_w = np.uint64(0)
        for t in range(min(64, stop - b0)):
            acc, _, _, ins, _ = _judge(s, i, b0 + t, rule)
            acc_w |= np.uint64(acc) << np.uint64(t)
            ins_w |= np.uint64(ins) << np.uint64(t)
        while acc_w:
            low = acc_w & (~acc_w + np.uint64(1))
            out.out_j[pos] = b0 + np.int64(popcount(low - np.uint64(1)))
            out.out_inside[pos] = (ins_w & low) != np.uint64(0)
            pos += 1
            acc_w ^= low
    return pos


@njit(parallel=True, cache=True, error_model="numpy")
def _pairs_kernel(s: PairSurface, grid: PairGrid, rule: PairRule, out: PairOut, r0: int, r1: int) -> None:
    """Criteria (a)-(c) for the pairs (i, j > i) of rows r0 <= i < r1 within the grid's reach: counted per row into
    out.counters, or (out.fill) written into out.out_j and out.out_inside at the rows' offsets."""
    # row i has n - 1 - i partners: pairing row r0 + k with row r1 - 1 - k balances the threads
    for k in prange((r1 - r0 + 1) // 2):
        for side in range(2):
            kk = np.int64(k)  # prange indices are unsigned: keep the row index signed
            i = r0 + kk if side == 0 else r1 - 1 - kk
            if side == 1 and i == r0 + kk:
                break
            _pairs_row(s, grid, rule, out, i, out.offsets[r0] if out.fill else 0)


@njit(cache=True, error_model="numpy")
def _pairs_row(s: PairSurface, grid: PairGrid, rule: PairRule, out: PairOut, i: int | np.int64, base: int) -> None:
    """Row i of _pairs_kernel: the grid cells within reach of point i, one contiguous run of points per (x, y)
    column of cells; `base`: the block's first offset (fill)."""
    cell_start, dims, origin, cell, reach = grid.cell_start, grid.dims, grid.origin, grid.cell, grid.reach
    fill, offsets, counters = out.fill, out.offsets, out.counters
    xi, yi, zi = s.x[i], s.y[i], s.z[i]
    ci = min(max(int((xi - origin[0]) / cell), 0), dims[0] - 1)
    cj = min(max(int((yi - origin[1]) / cell), 0), dims[1] - 1)
    ck = min(max(int((zi - origin[2]) / cell), 0), dims[2] - 1)
    n_bad_orient = 0
    n_pass_ab = 0
    n_pass_c = 0
    n_acc = 0
    pos = offsets[i] - base if fill else 0
    end = offsets[i + 1] - base if fill else 0
    for a in range(max(ci - reach, 0), min(ci + reach + 1, dims[0])):
        for b in range(max(cj - reach, 0), min(cj + reach + 1, dims[1])):
            col = (a * dims[1] + b) * dims[2]
            # the cells of one (a, b) column are contiguous: one run of points
            start = max(cell_start[col + max(ck - reach, 0)], i + 1)
            stop = cell_start[col + min(ck + reach + 1, dims[2])]
            if fill:
                pos = _fill_run(s, i, start, stop, rule, out, pos, end)
            else:
                c0, c1, c2, c3 = _count_run(s, i, start, stop, rule)
                n_acc += c0
                n_bad_orient += c1
                n_pass_ab += c2
                n_pass_c += c3
    if fill:
        return
    counters[i, 0] = n_acc
    counters[i, 1] = n_bad_orient
    counters[i, 2] = n_pass_ab
    counters[i, 3] = n_pass_c


def _cone_cos2(half: float, cos2: float, spread: np.ndarray | None, order: np.ndarray, n: int) -> np.ndarray:
    """Per point (in grid order), cos^2 of the cone its contact angle must stay in: cos^2(half - spread), or a
    value no pair reaches (4) when the spread alone exceeds the half-angle; exactly cos2 where the spread is 0."""
    c2 = np.full(n, cos2)
    if spread is not None:
        sp = np.asarray(spread, dtype=np.float64)[order]
        at = sp > 0
        room = half - sp[at]
        c2[at] = np.where(room >= 0.0, libm.cos(room) ** 2, 4.0)
    return c2


class PairPlan:
    """The counting pass of (a)-(c) over all pairs: exact per-criterion counts and how many pairs each row keeps.

    `rejected_friction` counts the pairs (c) rejects with the point's own normals, `rejected_tolerance` those it
    rejects only because of a normal within the position tolerance (`spread`, see pair_plan).

    `fill(r0, r1)` then produces the accepted pairs of rows r0 <= i < r1 (rows = points in the grid order the
    kernel uses), so a caller can stream the pairs through the collision stage in blocks of bounded size
    (`blocks(max_pairs)`) instead of holding all of them at once. Build it with `pair_plan()`.
    """

    def __init__(
        self,
        points: np.ndarray,
        normals: np.ndarray,
        *,
        stroke: float,
        min_width: float,
        friction: float,
        safety_factor: float,
        inside: bool,
        finger_thickness: float,
        spread: np.ndarray | None = None,
    ) -> None:
        p = np.ascontiguousarray(points, dtype=np.float64)
        nrm = np.ascontiguousarray(normals, dtype=np.float64)
        n = len(p)
        self.n = n
        self.pairs_total = n * (n - 1) // 2
        self.rejected_tolerance = 0
        out_lo, out_hi = float(min_width), float(stroke)
        in_lo, in_hi = float(min_width + 2 * finger_thickness), float(stroke + 2 * finger_thickness)
        lo = out_lo if not inside else min(out_lo, in_lo)
        hi = out_hi if not inside else max(out_hi, in_hi)
        self.offsets = np.zeros(n + 1, dtype=np.int64)
        if n < 2:
            self.order = np.arange(n)
            self.identity = True
            self.rejected_outside = self.rejected_friction = 0
            self.rejected_stroke = self.pairs_total
            return
        half = cone_half_angle_rad(friction, safety_factor)
        cos2 = math.cos(half) ** 2
        # cells of half the reach keep the visited volume near the sphere of radius `hi`
        cell = max(pair_cell_size(stroke, inside, finger_thickness), 1e-6)
        order, cell_start, dims, origin = _grid(p, cell)
        self.order = order
        self.identity = bool(np.array_equal(order, np.arange(n)))
        ps, ns = p[order], nrm[order]
        # x, y, z of the points, then of the normals (cast: a generator's tuple has no length to mypy)
        soa = cast(
            tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
            tuple(np.ascontiguousarray(a[:, k]) for a in (ps, ns) for k in range(3)),
        )
        lims = np.array([lo * lo, hi * hi, out_lo**2, out_hi**2, in_lo**2, in_hi**2, cos2])
        c2 = _cone_cos2(half, cos2, spread, order, n)
        self._surface = PairSurface(*soa, c2)
        self._grid = PairGrid(cell_start, dims, origin, cell, 2)
        self._rule = PairRule(lims, bool(inside))
        counters = np.zeros((n, 4), dtype=np.int64)
        count = PairOut(False, self.offsets, np.zeros(0, np.int64), np.zeros(0, np.bool_), counters)
        _pairs_kernel(self._surface, self._grid, self._rule, count, 0, n)
        np.cumsum(counters[:, 0], out=self.offsets[1:])
        m = int(self.offsets[-1])
        passed_ab, passed_c = int(counters[:, 2].sum()), int(counters[:, 3].sum())
        self.rejected_outside = int(counters[:, 1].sum())
        self.rejected_friction = passed_ab - passed_c
        self.rejected_tolerance = passed_c - m
        self.rejected_stroke = self.pairs_total - self.rejected_outside - passed_ab

    @property
    def accepted(self) -> int:
        """Pairs passing (a)-(c)."""
        return int(self.offsets[-1])

    def blocks(self, max_pairs: int) -> list[tuple[int, int]]:
        """Row ranges [r0, r1) covering all rows, each holding at most `max_pairs` pairs (or one row)."""
        out: list[tuple[int, int]] = []
        r0 = 0
        while r0 < self.n:
            r1 = int(np.searchsorted(self.offsets, self.offsets[r0] + max_pairs, side="right")) - 1
            r1 = min(max(r1, r0 + 1), self.n)
            out.append((r0, r1))
            r0 = r1
        return out

    def fill(self, r0: int = 0, r1: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(i, j, inside) of the pairs of rows [r0, r1), in the caller's indices, contact 0 the smaller index.

        Sorted by (i, j) within the block; blocks concatenate to the order of `antipodal_pairs` when the points
        were already in `grid_order`.
        """
        r1 = self.n if r1 is None else r1
        m = int(self.offsets[r1] - self.offsets[r0])
        if m == 0:
            e = np.zeros(0, dtype=np.int64)
            return e, e.copy(), np.zeros(0, dtype=np.bool_)
        out_j = np.empty(m, dtype=np.int64)
        out_inside = np.empty(m, dtype=np.bool_)
        fill = PairOut(True, self.offsets, out_j, out_inside, np.zeros((0, 4), dtype=np.int64))
        _pairs_kernel(self._surface, self._grid, self._rule, fill, r0, r1)
        out_i = np.repeat(np.arange(r0, r1, dtype=np.int64), np.diff(self.offsets[r0 : r1 + 1]))
        if self.identity:
            return out_i, out_j, out_inside
        # back to the caller's indices, contact 0 = the smaller original index
        oi, oj = self.order[out_i], self.order[out_j]
        i_final, j_final = np.minimum(oi, oj), np.maximum(oi, oj)
        key = np.lexsort((j_final, i_final))
        return i_final[key], j_final[key], out_inside[key]


def pair_plan(
    points: np.ndarray,
    normals: np.ndarray,
    *,
    stroke: float,
    min_width: float,
    friction: float,
    safety_factor: float,
    inside: bool,
    finger_thickness: float,
    spread: np.ndarray | None = None,
) -> PairPlan:
    """Count the pairs passing (a)-(c) without storing them (see PairPlan); arguments as for antipodal_pairs.

    spread: (n,) rad or None; per point, the largest angle between its normal and a surface normal within the
    position tolerance. Criterion (c) then holds for every such normal: contact angle + spread <= the half-angle.
    """
    return PairPlan(
        points,
        normals,
        stroke=stroke,
        min_width=min_width,
        friction=friction,
        safety_factor=safety_factor,
        inside=inside,
        finger_thickness=finger_thickness,
        spread=spread,
    )


def antipodal_pairs(
    points: np.ndarray,
    normals: np.ndarray,
    *,
    stroke: float,
    min_width: float,
    friction: float,
    safety_factor: float,
    inside: bool,
    finger_thickness: float,
) -> PairResult:
    """All pairs passing (a)-(c). points, normals: (n, 3) float64, metres / unit outward normals.

    Outside grasps need a contact distance in [min_width, stroke]; inside grasps in
    [min_width + 2 finger_thickness, stroke + 2 finger_thickness] (the fingers' own thickness sits between the
    contacts).
    """
    plan = pair_plan(
        points,
        normals,
        stroke=stroke,
        min_width=min_width,
        friction=friction,
        safety_factor=safety_factor,
        inside=inside,
        finger_thickness=finger_thickness,
    )
    i, j, ins = plan.fill()
    return PairResult(
        i=i,
        j=j,
        inside=ins,
        pairs_total=plan.pairs_total,
        rejected_stroke=plan.rejected_stroke,
        rejected_outside=plan.rejected_outside,
        rejected_friction=plan.rejected_friction,
    )


def friction_margin_deg(
    points: np.ndarray, normals: np.ndarray, i: np.ndarray, j: np.ndarray, inside: np.ndarray, half_angle_rad: float
) -> np.ndarray:
    """Cone half-angle (after the safety factor) minus the worse contact angle, degrees: (m,) float64."""
    d = points[j] - points[i]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sign = np.where(inside, 1.0, -1.0)
    c0 = np.clip(sign * np.sum(normals[i] * d, axis=1), -1.0, 1.0)
    c1 = np.clip(-sign * np.sum(normals[j] * d, axis=1), -1.0, 1.0)
    worst = np.maximum(libm.arccos(c0), libm.arccos(c1))
    margin: np.ndarray = np.degrees(half_angle_rad - worst)
    return margin
