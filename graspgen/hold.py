"""Criterion (e) `hold`: do two soft-finger contacts, pressed with the gripper's force, hold the part's load?

The paper's criteria (a)-(d) are geometric. A grasp far from the centre of mass, or on a patch that the pad touches
in a point only, lets the part turn about the closing axis: only the pads' torsional friction resists that torque.

Model (SI units). A candidate's contacts c0, c1 lie on the closing axis x at -h and +h (h = width / 2); each pad
presses with the normal force F = `grip_force`. The load is a force of magnitude W = m (g + accel) at the centre of
mass, in any direction d relative to the gripper (the robot turns and accelerates the part after the pick), and its
moment about the contact midpoint. The load along x is carried by the coupled fingers. The rest is shared by the
contacts, and for two point-like contacts on one axis the split is fixed by statics:

- the tangential (y, z) force and the moments about y and z give each contact a tangential force t0, t1
  (t0 + t1 balances the force, h (t1 - t0) the moments);
- the moment about x can only be resisted by the pads' torsional friction m0 + m1, split freely.

Each contact is a soft finger with an elliptic limit surface, (|t| / (k mu F))^2 + (m / (k mu F rho))^2 <= 1, where
rho is the contact's torsion radius: the mean distance, from the contact, of the patch that the pad touches (a flat
face gives a patch as large as the pad, a curved surface or an edge nearly a point), and k = tan(phi - theta) /
tan(phi) (tilt_factors) is what is left of the friction cone (half-angle phi = atan(mu)) when the surface normal is
tilted by theta from the closing axis: the finger's push already leans theta inside the cone (a wedge is squeezed
along its faces), so a load leaning further has tan(phi - theta) F left in the worst direction. The load at scale s
is held when s |t_i| <= k_i mu F for both contacts and sum_i rho_i k_i mu F sqrt(1 - (s |t_i| / (k_i mu F))^2) >=
s |moment about x|.
The hold margin is the largest s that holds in every direction d (the ratio of the load the grasp resists to the
load required); criterion (e) keeps margins >= 1. Directions: `HOLD.directions` on a quarter sphere (d and -d need
the same, and so do the two mirror images across the plane of the closing axis and the centre of mass), refined
twice around the worst; the margin is exact for the directions tried and the continuous minimum lies within a
fraction of a per cent of it (a check in tests/graspgen/test_hold.py).

The patch of a sample point p with normal n: the sample points q under the pad's inscribed disc (radius
min(finger_width, finger_depth) / 2 around p in the plane normal to n) that lie within `pad_compliance` of that
plane with normals within `patch_normal_deg` of n. Sample points stand for equal areas (the sampling is blue
noise), so the mean over them is the mean over the patch. rho is floored at `min_torsion_radius`: even a point
contact spreads a little on a pad.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numba import njit, prange

from . import libm
from .sampling import cell_grid, cell_runs

if TYPE_CHECKING:
    from .parts import Part

_CHUNK = 1024  # candidates per unit of parallel work

__all__ = ["HoldModel", "HOLD", "torsion_radii", "hold_margins", "hold_margins_of_pairs", "part_mass", "hold_load"]


@dataclass(frozen=True)
class HoldModel:
    """The constants of criterion (e) in one place (metres unless named otherwise)."""

    #: how far behind the pad's plane the surface may lie and still bear on the pad
    pad_compliance: float = 0.05e-3
    #: surface whose normal differs from the contact's by more than this is not part of the patch
    patch_normal_deg: float = 20.0
    #: torsion radius of a point contact on a pad (a Hertz-like spot of about 1.5 mm)
    min_torsion_radius: float = 0.5e-3
    #: load directions on the quarter sphere (then refined around the worst): 28 there are as dense as 56 on the
    #: half sphere. With 2 refinements the margin lies at most 0.35 % above a 2,048-direction search (0.09 % at
    #: the 99th percentile) on the thick ring's candidates; the largest errors are basins the lattice misses, which
    #: more refinement rounds do not mend (bench/bench_hold_margin.py)
    directions: int = 28
    #: refinement rounds: 8 neighbours of the worst direction at 1/2, then 1/4 ... of the lattice spacing
    refinements: int = 2
    #: bisection steps for a direction's limit scale (relative precision 2^-steps of the bracket)
    bisection_steps: int = 30
    #: margins are reported up to this value (a part with no load at all holds without limit)
    max_margin: float = 1.0e6


HOLD = HoldModel()


def hold_load(mass_kg: float, accel: float, gravity: float = 9.81) -> float:
    """W (N): the part's weight plus `accel` (m/s^2) of acceleration, the worst case in any direction."""
    return float(mass_kg) * (float(gravity) + float(accel))


def part_mass(part: Part, mass_kg: float | None, density: float | None) -> tuple[float | None, str | None]:
    """The part's mass (kg) from `mass_kg` or `density` (kg/m^3) x the volume, and a note when the volume had to be
    taken from the convex hull (an open mesh or a point cloud has no volume of its own)."""
    if mass_kg is not None:
        return float(mass_kg), None
    if density is None:
        return None, None
    mesh = part.mesh
    if mesh is not None and mesh.is_watertight and mesh.volume > 0:
        return float(density) * float(mesh.volume), None
    import trimesh

    pts = np.asarray(mesh.vertices if mesh is not None else part.points, dtype=np.float64)
    hull = trimesh.convex.convex_hull(pts)
    what = "the mesh is not closed" if mesh is not None else "a point cloud has no volume"
    return float(density) * float(hull.volume), f"mass from density uses the convex hull's volume: {what}"


def torsion_radii(points: np.ndarray, normals: np.ndarray, pad_radius: float, model: HoldModel = HOLD) -> np.ndarray:
    """Torsion radius rho (k,) metres of the patch a pad of radius `pad_radius` touches at each sample point.

    `points`, `normals`: (k, 3) float64, the evenly spaced surface sample with outward unit normals."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    nrm = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    k = len(pts)
    if k == 0:
        return np.zeros(0, dtype=np.float64)
    order, cells, cell_start, dims = cell_grid(pts, pad_radius)
    out = np.empty(k, dtype=np.float64)
    _radii_kernel(
        pts[order],
        nrm[order],
        cells,
        cell_start,
        dims,
        float(pad_radius),
        float(model.pad_compliance),
        math.cos(math.radians(model.patch_normal_deg)),
        float(model.min_torsion_radius),
        out,
    )
    result = np.empty_like(out)
    result[order] = out
    return result


@njit(parallel=True, cache=True)
def _radii_kernel(
    P: np.ndarray,
    N: np.ndarray,
    cells: np.ndarray,
    cell_start: np.ndarray,
    dims: np.ndarray,
    R: float,
    depth: float,
    cos_min: float,
    rho_min: float,
    out: np.ndarray,
) -> None:
    R2 = R * R
    for i in prange(P.shape[0]):
        total = 0.0
        count = 0
        runs = np.empty((9, 2), dtype=np.int64)
        for r in range(cell_runs(cells, cell_start, dims, i, runs)):
            for j in range(runs[r, 0], runs[r, 1]):
                dx = P[j, 0] - P[i, 0]
                dy = P[j, 1] - P[i, 1]
                dz = P[j, 2] - P[i, 2]
                off = dx * N[i, 0] + dy * N[i, 1] + dz * N[i, 2]
                # the part lies on the inner side (-n): the pad's plane touches at p, the patch bears on it
                if abs(off) > depth:
                    continue
                if N[j, 0] * N[i, 0] + N[j, 1] * N[i, 1] + N[j, 2] * N[i, 2] < cos_min:
                    continue
                r2 = dx * dx + dy * dy + dz * dz - off * off
                if r2 <= R2:
                    total += np.sqrt(max(r2, 0.0))
                    count += 1
        out[i] = max(total / max(count, 1), rho_min)


def tilt_factors(contacts: np.ndarray, normals: np.ndarray, friction: float) -> np.ndarray:
    """(n, 2) factors in [0, 1] on each contact's friction capacity (tangential and torsional) for a surface normal
    tilted by theta from the closing axis: the finger pushes along the axis, so the contact force already leans
    theta inside the friction cone (half-angle phi = atan(mu)) before any load, and a load leaning further has
    tan(phi - theta) F left instead of tan(phi) F (the worst direction, taken for every direction). 0 at or beyond
    the cone's edge (that contact holds no load); 1 for a normal along the axis. The margin kernel computes the same
    per candidate (_tilt)."""
    c = np.ascontiguousarray(contacts, dtype=np.float64).reshape(-1, 2, 3)
    n = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 2, 3)
    out = np.empty((len(c), 2), dtype=np.float64)
    _tilt_kernel(c, n, float(friction), out)
    return out


@njit(cache=True, inline="always", error_model="numpy")
def _tilt(ax: float, ay: float, az: float, nx: float, ny: float, nz: float, phi: float, tan_phi: float) -> float:
    """tilt_factors of one contact: unit closing axis a, surface normal n (any length)."""
    nl = max(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
    cos = min(abs(nx * ax + ny * ay + nz * az) / nl, 1.0)
    factor: float = min(max(np.tan(max(phi - np.arccos(cos), 0.0)) / tan_phi, 0.0), 1.0)
    return factor


@njit(parallel=True, cache=True, error_model="numpy")
def _tilt_kernel(C: np.ndarray, N: np.ndarray, mu: float, out: np.ndarray) -> None:
    phi = math.atan(mu)
    tan_phi = math.tan(phi)
    for n in prange(C.shape[0]):
        ax = C[n, 1, 0] - C[n, 0, 0]
        ay = C[n, 1, 1] - C[n, 0, 1]
        az = C[n, 1, 2] - C[n, 0, 2]
        w = max(np.sqrt(ax * ax + ay * ay + az * az), 1e-300)
        for k in range(2):
            out[n, k] = _tilt(ax / w, ay / w, az / w, N[n, k, 0], N[n, k, 1], N[n, k, 2], phi, tan_phi)


def _quarter_sphere(count: int) -> np.ndarray:
    """`count` unit vectors spread evenly over the quarter sphere x >= 0, z >= 0 (a Fibonacci lattice), (count, 3)."""
    k = np.arange(count, dtype=np.float64) + 0.5
    x = k / count  # uniform in [0, 1]: equal areas
    phi = np.mod(k * (math.sqrt(5.0) - 1.0) / 2.0, 1.0) * math.pi  # golden-ratio steps over the half turn
    s = np.sqrt(1.0 - x * x)
    return np.ascontiguousarray(np.stack([x, s * libm.cos(phi), s * libm.sin(phi)], axis=1))


def hold_margins(
    contacts: np.ndarray,
    radii: np.ndarray,
    center_of_mass: np.ndarray,
    *,
    load: float,
    grip_force: float,
    friction: float,
    normals: np.ndarray | None = None,
    model: HoldModel = HOLD,
    floor: float = 0.0,
) -> np.ndarray:
    """Hold margin (n,) float64 of candidates with `contacts` (n, 2, 3) metres and torsion radii `radii` (n, 2)
    metres, for a load of `load` N (hold_load) at `center_of_mass` (3,), `grip_force` N per finger and Coulomb
    `friction`. >= 1: the grasp holds (criterion (e)). `normals` (n, 2, 3): the contacts' surface normals; a contact
    whose normal is tilted from the closing axis spends friction on the grip force itself (tilt_factors); None:
    both on the axis. With `floor` > 0, a candidate stops as soon as its margin is known to be below `floor` and
    reports an upper bound of it (below `floor`): criterion (e) needs no more."""
    contacts = np.ascontiguousarray(contacts, dtype=np.float64).reshape(-1, 2, 3)
    radii = np.ascontiguousarray(radii, dtype=np.float64).reshape(-1, 2)
    n = len(contacts)
    if len(radii) != n:
        raise ValueError("radii must be (n, 2) for n candidates")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 2, 3)
        if len(normals) != n:
            raise ValueError("normals must be (n, 2, 3) for n candidates")
        normals = normals.reshape(-1, 3)
    i = np.arange(0, 2 * n, 2, dtype=np.int64)
    return _margins(
        contacts.reshape(-1, 3),
        normals,
        radii.reshape(-1),
        i,
        i + 1,
        center_of_mass,
        load,
        grip_force,
        friction,
        model,
        floor,
    )


def hold_margins_of_pairs(
    points: np.ndarray,
    normals: np.ndarray,
    radii: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    center_of_mass: np.ndarray,
    *,
    load: float,
    grip_force: float,
    friction: float,
    model: HoldModel = HOLD,
    floor: float = 0.0,
) -> np.ndarray:
    """hold_margins of the candidates (points[i], points[j]) with the sample's `normals` (k, 3) and per-point
    torsion radii `radii` (k,) (torsion_radii): the same margins, without (n, 2, 3) arrays of contacts and normals."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    i = np.ascontiguousarray(i, dtype=np.int64)
    j = np.ascontiguousarray(j, dtype=np.int64)
    if len(i) != len(j):
        raise ValueError("i and j must have the same length")
    if len(i) and (min(int(i.min()), int(j.min())) < 0 or max(int(i.max()), int(j.max())) >= len(pts)):
        raise ValueError(f"point indices must lie in [0, {len(pts)})")
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    rho = np.asarray(radii, dtype=np.float64).reshape(-1)
    if len(nrm) != len(pts) or len(rho) != len(pts):
        raise ValueError("normals and radii must have one row per point")
    return _margins(pts, nrm, rho, i, j, center_of_mass, load, grip_force, friction, model, floor)


def _margins(
    P: np.ndarray,
    normals: np.ndarray | None,
    rho: np.ndarray,
    i: np.ndarray,
    j: np.ndarray,
    center_of_mass: np.ndarray,
    load: float,
    grip_force: float,
    friction: float,
    model: HoldModel,
    floor: float,
) -> np.ndarray:
    """The margin kernel over the pairs (P[i], P[j]); normals None: both contacts on the closing axis."""
    com = np.ascontiguousarray(center_of_mass, dtype=np.float64).reshape(3)
    out = np.empty(len(i), dtype=np.float64)
    if len(i) == 0:
        return out
    nrm = np.zeros((0, 3)) if normals is None else np.ascontiguousarray(normals, dtype=np.float64)
    part = HoldPart(P, nrm, np.ascontiguousarray(rho, dtype=np.float64), com)
    search = HoldSearch(
        _quarter_sphere(model.directions), int(model.bisection_steps), int(model.refinements), float(model.max_margin)
    )
    grip = (float(load), float(friction), float(friction) * float(grip_force), float(floor))
    _margins_kernel(part, i, j, grip, search, out)
    return out


@njit(cache=True, inline="always", error_model="numpy")
def _slack(s: float, a0: float, a1: float, b: float, c0: float, c1: float) -> float:
    """Torsional capacity left at load scale s (>= 0: held), -1 when a contact's tangential load alone slips."""
    u0 = a0 * s
    u1 = a1 * s
    if u0 > 1.0 or u1 > 1.0:
        return -1.0
    slack: float = c0 * np.sqrt(1.0 - u0 * u0) + c1 * np.sqrt(1.0 - u1 * u1) - b * s
    return slack


@njit(cache=True, inline="always", error_model="numpy")
def _coeffs(
    dx: float,
    dy: float,
    dz: float,
    rx: float,
    ry: float,
    rz: float,
    inv_h: float,
    w_cap0: float,
    w_cap1: float,
    W: float,
) -> tuple[float, float, float]:
    """In direction d (local frame, x = closing axis), per unit load scale: a0, a1 = each contact's tangential
    load over its friction capacity (w_cap_i = W over contact i's capacity), b = the moment about x (N m)."""
    mx = ry * dz - rz * dy
    my = rz * dx - rx * dz
    mz = rx * dy - ry * dx
    # h (t1 - t0) balances the moments about y and z, t0 + t1 the force along y and z
    ddy = -mz * inv_h
    ddz = my * inv_h
    a0 = 0.5 * w_cap0 * np.sqrt((dy + ddy) ** 2 + (dz + ddz) ** 2)
    a1 = 0.5 * w_cap1 * np.sqrt((dy - ddy) ** 2 + (dz - ddz) ** 2)
    return a0, a1, W * abs(mx)


@njit(cache=True, inline="always", error_model="numpy")
def _lower(a0: float, a1: float, b: float, c0: float, c1: float, inv_c: float) -> float:
    """A lower bound of the direction's limit scale: sqrt(1 - u^2) >= 1 - u makes the slack linear in s, so the
    bound costs no square root. A direction whose bound is not below the running best ends there; for the others
    it is the held end of _limit's bracket, so the margins' last bits depend on it (and so does the first direction
    _margin_one solves, the one with the lowest bound)."""
    top = max(a0, a1, (c0 * a0 + c1 * a1 + b) * inv_c)
    return np.inf if top <= 0.0 else 1.0 / top


@njit(cache=True, inline="always", error_model="numpy")
def _limit(best: float, lo: float, a0: float, a1: float, b: float, c0: float, c1: float, steps: int) -> float:
    """min(best, the largest load scale held in the direction with coefficients a0, a1, b; lo = their _lower)."""
    if lo >= best:
        return best
    hi = best
    if a0 > 0.0:
        hi = min(hi, 1.0 / a0)
    if a1 > 0.0:
        hi = min(hi, 1.0 / a1)
    if b > 0.0:
        hi = min(hi, (c0 + c1) / b)
    g_hi = _slack(hi, a0, a1, b, c0, c1)
    if g_hi >= 0.0:
        return hi
    g_lo = _slack(lo, a0, a1, b, c0, c1)
    # Illinois (regula falsi): the slack is concave and falls on [lo, hi]; the held side lo is kept exact
    side = 0
    for _ in range(steps):
        if hi - lo <= 1e-9 * hi:
            break
        mid = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
        if not (lo < mid < hi):
            mid = 0.5 * (lo + hi)
        g = _slack(mid, a0, a1, b, c0, c1)
        if g >= 0.0:
            lo, g_lo = mid, g
            if side == 1:
                g_hi *= 0.5
            side = 1
        else:
            hi, g_hi = mid, g
            if side == -1:
                g_lo *= 0.5
            side = -1
    return lo


@njit(cache=True, inline="always", error_model="numpy")
def _neighbour(
    bx: float, by: float, bz: float, tangents: tuple[float, float, float, float, float, float], ca: float, sa: float
) -> tuple[float, float, float]:
    """The unit direction b + ca p + sa q, normalised (tangents = p, q at b): a refinement's neighbour."""
    px, py, pz, qx, qy, qz = tangents
    vx = bx + ca * px + sa * qx
    vy = by + ca * py + sa * qy
    vz = bz + ca * pz + sa * qz
    lv = np.sqrt(vx * vx + vy * vy + vz * vz)
    return vx / lv, vy / lv, vz / lv


#: The part as the margin kernel reads it: points (n, 3) metres, normals (n, 3) unit (no rows: both contacts on the
#: closing axis), rho (n,) torsion radii, com (3,) the centre of mass.
HoldPart = namedtuple("HoldPart", ["points", "normals", "rho", "com"])
#: The search over load directions: dirs (K, 3) the lattice, bisection steps, refinement rounds, the largest margin
#: reported.
HoldSearch = namedtuple("HoldSearch", ["dirs", "steps", "refinements", "max_margin"])


@njit(parallel=True, cache=True, error_model="numpy")
def _margins_kernel(
    part: HoldPart,
    I: np.ndarray,
    J: np.ndarray,
    grip: tuple[float, float, float, float],
    search: HoldSearch,
    out: np.ndarray,
) -> None:
    """The hold margin of every candidate (P[I[n]], P[J[n]]) into out (N,); grip = (the load W, mu, mu F, the floor
    below which a margin need not be exact)."""
    W, mu, cap, floor = grip
    dirs, steps, refinements, max_margin = search.dirs, search.steps, search.refinements, search.max_margin
    K = dirs.shape[0]
    dirsT = np.ascontiguousarray(dirs.T)
    # refinement: around the worst direction, 8 neighbours at 1/2, 1/4, ... of the lattice spacing
    spacing = np.sqrt(np.pi / K)
    ring_c = np.cos(np.arange(8) * np.pi / 4.0)
    ring_s = np.sin(np.arange(8) * np.pi / 4.0)
    phi = math.atan(mu)
    run = (W, cap, W / cap, max_margin, floor, spacing, phi, math.tan(phi))
    N = I.shape[0]
    chunks = (N + _CHUNK - 1) // _CHUNK
    for ch in prange(chunks):
        co = np.empty((4, max(K, 8)))
        for n in range(ch * _CHUNK, min(N, (ch + 1) * _CHUNK)):
            out[n] = _margin_one(part, I[n], J[n], dirsT, (co, ring_c, ring_s), (steps, refinements), run)


@njit(cache=True, error_model="numpy")
def _margin_one(
    part: HoldPart,
    ia: int,
    ib: int,
    dirs: np.ndarray,
    work: tuple[np.ndarray, np.ndarray, np.ndarray],
    rounds: tuple[int, int],
    run: tuple[float, float, float, float, float, float, float, float],
) -> float:
    """The margin of the candidate (P[ia], P[ib]) of `part` (its normals Nrm, none: both on the closing axis, and
    torsion radii rho); `dirs` (3, K): the lattice's directions as columns; work = (co, ring_c, ring_s): co (4,
    >= max(K, 8)) work rows of a0, a1, b and the lower bound per direction, ring_c, ring_s (8,) the cosines and
    sines of a refinement's 8 neighbours; rounds = (bisection steps, refinements); `run`: the load W, mu F,
    W / (mu F), max_margin, floor, the lattice spacing, atan(mu) and its tangent (the same for every candidate).

    The coefficients of all directions (the lattice's, then each refinement's 8) come first in a loop without
    branches, which the compiler vectorises; the limit scales follow in order (the root finding branches)."""
    W, cap, w_cap, max_margin, floor, spacing, phi, tan_phi = run
    P, Nrm, rho, com = part.points, part.normals, part.rho, part.com
    co, ring_c, ring_s = work
    steps, refinements = rounds
    K = dirs.shape[1]
    ax = P[ib, 0] - P[ia, 0]
    ay = P[ib, 1] - P[ia, 1]
    az = P[ib, 2] - P[ia, 2]
    w = np.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / w, ay / w, az / w
    k0 = k1 = 1.0
    if Nrm.shape[0] > 0:
        k0 = _tilt(ax, ay, az, Nrm[ia, 0], Nrm[ia, 1], Nrm[ia, 2], phi, tan_phi)
        k1 = _tilt(ax, ay, az, Nrm[ib, 0], Nrm[ib, 1], Nrm[ib, 2], phi, tan_phi)
    if k0 <= 0.0 or k1 <= 0.0:  # a contact on the cone's edge has no friction left for any load
        return 0.0
    mx = 0.5 * (P[ia, 0] + P[ib, 0])
    my = 0.5 * (P[ia, 1] + P[ib, 1])
    mz = 0.5 * (P[ia, 2] + P[ib, 2])
    qx, qy, qz = com[0] - mx, com[1] - my, com[2] - mz
    rx = qx * ax + qy * ay + qz * az
    # the local y axis along the centre of mass's offset from the closing axis (rz = 0): the model is symmetric
    # about the closing axis, and in this frame also under dz -> -dz, so directions with dz >= 0 suffice
    px, py, pz = qx - rx * ax, qy - rx * ay, qz - rx * az
    ry = np.sqrt(px * px + py * py + pz * pz)
    rz = 0.0
    inv_h = 2.0 / w
    c0 = cap * k0 * rho[ia]
    c1 = cap * k1 * rho[ib]
    # the tangential loads over each contact's own capacity mu F k: a0 and a1 of _coeffs divided by k
    w_cap0 = w_cap / k0
    w_cap1 = w_cap / k1
    inv_c = 1.0 / (c0 + c1)
    # every direction's coefficients and lower bound in one branch-free loop (vectorised), then the direction
    # with the lowest lower bound first: most other directions then end at their bound
    for k in range(K):
        a0, a1, b = _coeffs(dirs[0, k], dirs[1, k], dirs[2, k], rx, ry, rz, inv_h, w_cap0, w_cap1, W)
        co[0, k], co[1, k], co[2, k] = a0, a1, b
        co[3, k] = _lower(a0, a1, b, c0, c1, inv_c)
    first = 0
    low = co[3, 0]
    for k in range(1, K):
        if co[3, k] < low:
            low = co[3, k]
            first = k
    best = _limit(max_margin, low, co[0, first], co[1, first], co[2, first], c0, c1, steps)
    worst = first
    if best >= floor:
        for k in range(K):
            s = _limit(best, co[3, k], co[0, k], co[1, k], co[2, k], c0, c1, steps)
            if s < best:
                best = s
                worst = k
                if best < floor:
                    break
    dx, dy, dz = dirs[0, worst], dirs[1, worst], dirs[2, worst]
    step = 0.5 * spacing
    for _ in range(refinements):
        if best < floor:
            break
        # two tangent vectors at d
        if abs(dx) < 0.9:
            px, py, pz = 0.0, -dz, dy
        else:
            px, py, pz = dz, 0.0, -dx
        lp = np.sqrt(px * px + py * py + pz * pz)
        px, py, pz = px / lp, py / lp, pz / lp
        qx2 = dy * pz - dz * py
        qy2 = dz * px - dx * pz
        qz2 = dx * py - dy * px
        bx, by, bz = dx, dy, dz
        # the 8 neighbours' coefficients and bounds at once (vectorised), then each against the running best
        tangents = (px, py, pz, qx2, qy2, qz2)
        for j in range(8):
            vx, vy, vz = _neighbour(bx, by, bz, tangents, ring_c[j] * step, ring_s[j] * step)
            a0, a1, b = _coeffs(vx, vy, vz, rx, ry, rz, inv_h, w_cap0, w_cap1, W)
            co[0, j], co[1, j], co[2, j] = a0, a1, b
            co[3, j] = _lower(a0, a1, b, c0, c1, inv_c)
        for j in range(8):
            s = _limit(best, co[3, j], co[0, j], co[1, j], co[2, j], c0, c1, steps)
            if s < best:
                best = s
                dx, dy, dz = _neighbour(bx, by, bz, tangents, ring_c[j] * step, ring_s[j] * step)
        step *= 0.5
    return min(best, max_margin)
