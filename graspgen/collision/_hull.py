"""The sample points' convex hull as a certificate for the palm: the rolls at which the whole part lies in front of
the palm's front face need no search for a blocker (docs/design/collision.md, "The palm's hull certificate").

The support of the hull along a unit direction u, h(u) = max_w W[w] . u, is read from a cube map of directions
that stores per cell an upper bound of h over the cell, and, near the threshold, computed exactly by a hill climb
over the hull's vertex graph: a vertex that no neighbour beats maximises a linear function over a convex polytope.
"""

from __future__ import annotations

from collections import namedtuple
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from ..params import TOLERANCES

if TYPE_CHECKING:
    from ._frame import Rolls

__all__ = ["Hull", "build_hull", "hull_free", "cube_cell", "HULL_CELLS"]

#: cube-map cells per face edge of the support bounds
HULL_CELLS = 24

#: vertices (k, 3): the hull's vertices relative to o; start (k + 1,), adj: the vertex graph (CSR); bound, arg (6 n^2,):
#: per cube-map cell an upper bound of the support over the cell's directions and the vertex that attains the maximum
#: at its centre; info = (o x, o y, o z, n); threshold: the palm's front as -z_hi less a guard band (hull_free).
Hull = namedtuple("Hull", ["vertices", "start", "adj", "bound", "arg", "info", "threshold"])


@njit(cache=True, inline="always", error_model="numpy")
def cube_cell(ux: float, uy: float, uz: float, n: int) -> int:
    """The cell of unit direction u in a cube map of n x n cells per face: face f = 2 a + (u_a < 0) of the axis a of
    the largest |u_a|, then (u_{a+1}, u_{a+2}) / |u_a| in cells of 2 / n."""
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
def hull_free(F: np.ndarray, hull: Hull, target: np.uint64, rolls: Rolls) -> np.uint64:
    """The rolls within `target` at which every sample point lies in front of the palm: the support of the hull
    along -Z_k (the approach reversed), measured from the candidate's midpoint F[0:3], is below hull.threshold, so no
    point has z <= z_hi there and the palm cannot block the roll. F: midpoint, X, Y0, Z0 (12 floats)."""
    W, a_start, adj, bound, arg, info = hull.vertices, hull.start, hull.adj, hull.bound, hull.arg, hull.info
    thr = hull.threshold
    free = np.uint64(0)
    if W.shape[0] == 0:
        return free
    n = int(info[3])
    dx, dy, dz = info[0] - F[0], info[1] - F[1], info[2] - F[2]
    for k in range(rolls.cos.shape[0]):
        bit = np.uint64(1) << np.uint64(k)
        if not (target & bit):
            continue
        s, c = rolls.sin[k], rolls.cos[k]
        ux = s * F[6] - c * F[9]
        uy = s * F[7] - c * F[10]
        uz = s * F[8] - c * F[11]
        om = dx * ux + dy * uy + dz * uz  # (o - m) . u
        cell = cube_cell(ux, uy, uz, n)
        if bound[cell] + om < thr:
            free |= bit
            continue
        v = arg[cell]
        _, best = _climb(W, a_start, adj, v, ux, uy, uz, om, thr)
        if best + om < thr:
            free |= bit
    return free


@njit(cache=True, inline="always", error_model="numpy")
def _climb(
    W: np.ndarray,
    start: np.ndarray,
    adj: np.ndarray,
    v: int,
    ux: float,
    uy: float,
    uz: float,
    shift: float,
    stop: float,
) -> tuple[int, float]:
    """(vertex, value) of max_w W[w] . u by a hill climb over the vertex graph (CSR start, adj) from vertex v, each
    step to the neighbour of largest value; it stops early once value + shift reaches `stop` (inf: never)."""
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


def build_hull(P: np.ndarray, threshold: float, cells: int = HULL_CELLS, guard: float = TOLERANCES.guard) -> Hull:
    """The Hull of the points P (n, 3), metres, for the palm threshold `threshold` (see Hull). The bound of a cell:
    the support at its centre direction c plus R |u - c|, R = max |W|, with |u - c| at most the chord to the cell's
    farthest corner (a cell is a convex spherical quadrilateral), widened by `guard`. Empty arrays when the points
    span no volume (flat, or fewer than 4 points): then hull_free certifies nothing."""
    from scipy.spatial import ConvexHull, QhullError

    empty = Hull(
        np.zeros((0, 3)),
        np.zeros(1, dtype=np.int64),
        np.zeros(0, dtype=np.int64),
        np.zeros(0),
        np.zeros(0, dtype=np.int64),
        np.zeros(4),
        float(threshold),
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
    bound = val + R * (np.concatenate(chords) * (1.0 + guard) + guard)
    info = np.array([o[0], o[1], o[2], float(n)])
    return Hull(W, start, adj, np.ascontiguousarray(bound), arg, info, float(threshold))


def _face_units(f: int, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Unit directions on cube face f (axis f // 2, + for even f) at face coordinates (p, q), as cube_cell."""
    a = f // 2
    u = np.empty(p.shape + (3,))
    u[..., a] = 1.0 if f % 2 == 0 else -1.0
    u[..., (a + 1) % 3] = p
    u[..., (a + 2) % 3] = q
    unit: np.ndarray = u / np.linalg.norm(u, axis=-1, keepdims=True)
    return unit


@njit(cache=True)
def _support_table(
    W: np.ndarray, start: np.ndarray, adj: np.ndarray, U: np.ndarray, val: np.ndarray, arg: np.ndarray
) -> None:
    """The support max_w W[w] . U[c] and its vertex for each direction U[c], each climb started where the previous
    one ended (neighbouring cells have neighbouring maxima)."""
    v = 0
    for c in range(U.shape[0]):
        v, val[c] = _climb(W, start, adj, v, U[c, 0], U[c, 1], U[c, 2], 0.0, np.inf)
        arg[c] = v
