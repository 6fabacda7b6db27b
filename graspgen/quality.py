"""A quality score per candidate from named terms, and quality-aware selection within the final clusters.

The paper's criteria are geometric: a pair inside the friction cone is accepted however far its closing axis passes
from the centre of mass, so long or lopsided parts held near one end turn in the fingers. Every candidate gets three
terms in [0, 1], higher is better:

- `friction`: the friction margin as a share of the usable cone half-angle (arctan(mu) / safety factor): 1 when both
  contact normals lie on the closing axis, 0 at the cone's edge;
- `torque`: 1 - (distance of the centre of mass to the closing axis) / (half the part's bounding-box diagonal),
  clipped to [0, 1]: gravity's torque about the closing axis grows with that distance and only the pads' torsional
  friction resists it;
- `flatness`: the lower of the two contact patches' mean normal agreement, mean(max(0, n_i . n_c)) over the sampled
  surface points within a pad radius (half the smaller pad side) of the contact c: 1 on a flat face, lower on
  curved patches and near edges, where the pad rests on less of the surface.

The score is the weighted sum with `WEIGHTS` (summing to 1). The centre of mass is the volume centroid of a closed
mesh (the area centroid of an open one or of a point cloud).

`select_best_near_medoid` replaces each final cluster's medoid by the best-scoring member of the same cluster that
lies within `NEAR` of the medoid (midpoints within `radius`, axes within `angle_deg`), so the selection keeps the
clusters' diversity and drops weak representatives.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

from . import libm
from .params import SELECT_MODES
from .sampling import cell_grid, cell_runs

if TYPE_CHECKING:
    import trimesh

__all__ = [
    "TERMS",
    "QualityWeights",
    "WEIGHTS",
    "Near",
    "NEAR",
    "SELECT_MODES",
    "quality_terms",
    "point_flatness",
    "scores",
    "center_of_mass",
    "select_best_near_medoid",
    "members_by_distance",
]

#: term names, the columns of `quality_terms`
TERMS = ("friction", "torque", "flatness")


@dataclass(frozen=True)
class QualityWeights:
    """Weights of the terms in the score (they sum to 1, so the score is in [0, 1])."""

    friction: float = 0.4
    torque: float = 0.4
    flatness: float = 0.2

    def vector(self) -> np.ndarray:
        return np.array([self.friction, self.torque, self.flatness], dtype=np.float64)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


WEIGHTS = QualityWeights()


@dataclass(frozen=True)
class Near:
    """How close to its medoid a member must be to replace it (and the scale of the repair order)."""

    radius: float = 0.005  # metres between contact midpoints
    angle_deg: float = 15.0  # sign-invariant closing-axis angle


NEAR = Near()


def center_of_mass(mesh: trimesh.Trimesh | None = None, points: np.ndarray | None = None) -> np.ndarray:
    """Centre of mass (3,) metres: the volume centroid of a closed mesh, else the area / point centroid."""
    if mesh is not None:
        if mesh.is_watertight and mesh.volume > 0:
            return np.asarray(mesh.center_mass, dtype=np.float64)
        areas = mesh.area_faces
        return np.asarray((mesh.triangles_center * areas[:, None]).sum(axis=0) / areas.sum(), dtype=np.float64)
    centroid: np.ndarray = np.asarray(points, dtype=np.float64).reshape(-1, 3).mean(axis=0)
    return centroid


def quality_terms(
    contacts: np.ndarray,
    normals: np.ndarray,
    friction_margin_deg: np.ndarray,
    *,
    half_angle_deg: float,
    center_of_mass: np.ndarray,
    length_scale: float,
    surface_points: np.ndarray | None = None,
    surface_normals: np.ndarray | None = None,
    patch_radius: float | None = None,
    flatness: np.ndarray | None = None,
) -> np.ndarray:
    """Terms (n, 3) float64 in [0, 1] (columns `TERMS`) for candidates with contacts and normals (n, 2, 3).

    `length_scale` (m): the torque arm at which the torque term reaches 0 (half the part's bounding-box diagonal);
    `surface_points` / `surface_normals` (k, 3): the sampled surface; `patch_radius` (m): the pad radius. When the
    contacts are sample points, pass their `flatness` (n, 2) from `point_flatness` instead (much cheaper).
    """
    contacts = np.asarray(contacts, dtype=np.float64).reshape(-1, 2, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 2, 3)
    n = len(contacts)
    out = np.zeros((n, 3), dtype=np.float64)
    if n == 0:
        return out
    out[:, 0] = np.clip(np.asarray(friction_margin_deg, dtype=np.float64) / half_angle_deg, 0.0, 1.0)
    mid = contacts.mean(axis=1)
    d = contacts[:, 1] - contacts[:, 0]
    axis = d / np.linalg.norm(d, axis=1, keepdims=True)
    arm = np.linalg.norm(np.cross(np.asarray(center_of_mass, dtype=np.float64) - mid, axis), axis=1)
    out[:, 1] = np.clip(1.0 - arm / max(length_scale, 1e-12), 0.0, 1.0)
    if flatness is not None:
        out[:, 2] = np.asarray(flatness, dtype=np.float64).reshape(n, 2).min(axis=1)
    else:
        if surface_points is None or surface_normals is None or patch_radius is None:
            raise ValueError(
                "quality_terms needs `flatness`, or `surface_points`, `surface_normals` and `patch_radius`"
            )
        out[:, 2] = np.minimum(
            *(
                _patch_flatness(contacts[:, k], normals[:, k], surface_points, surface_normals, patch_radius)
                for k in range(2)
            )
        )
    return out


def point_flatness(points: np.ndarray, normals: np.ndarray, radius: float) -> np.ndarray:
    """Flatness (k,) of the patch around each sample point: mean(max(0, n_i . n_p)) over the sample points within
    `radius` (m) of point p (itself included), as `_patch_flatness` gives for a contact at p with normal n_p.

    A compiled pass over a grid of cells `radius` wide: a small part has thousands of points in every patch."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    nrm = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.ones(0, dtype=np.float64)
    order, cells, cell_start, dims = cell_grid(pts, radius)
    out = np.empty(len(pts), dtype=np.float64)
    _flatness_kernel(pts[order], nrm[order], cells, cell_start, dims, float(radius) ** 2, out)
    result = np.empty_like(out)
    result[order] = out
    return result


@njit(parallel=True, cache=True)
def _flatness_kernel(
    P: np.ndarray,
    N: np.ndarray,
    cells: np.ndarray,
    cell_start: np.ndarray,
    dims: np.ndarray,
    r2: float,
    out: np.ndarray,
) -> None:
    for i in prange(P.shape[0]):
        total = 0.0
        count = 0
        runs = np.empty((9, 2), dtype=np.int64)
        for r in range(cell_runs(cells, cell_start, dims, i, runs)):
            for j in range(runs[r, 0], runs[r, 1]):
                dx = P[j, 0] - P[i, 0]
                dy = P[j, 1] - P[i, 1]
                dz = P[j, 2] - P[i, 2]
                if dx * dx + dy * dy + dz * dz <= r2:
                    dot = N[j, 0] * N[i, 0] + N[j, 1] * N[i, 1] + N[j, 2] * N[i, 2]
                    total += min(max(dot, 0.0), 1.0)
                    count += 1
        out[i] = total / count


def _patch_flatness(c: np.ndarray, nc: np.ndarray, pts: np.ndarray, nrm: np.ndarray, radius: float) -> np.ndarray:
    """mean(max(0, n_i . n_c)) over surface points within `radius` of each contact c (m, 3)."""
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
    nrm = np.asarray(nrm, dtype=np.float64).reshape(-1, 3)
    # contacts are sample points, shared by many pairs: evaluate each distinct point once
    uniq, inverse = np.unique(np.round(c, 12), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    first = np.zeros(len(uniq), dtype=np.int64)
    first[inverse[::-1]] = np.arange(len(c))[::-1]
    tree = cKDTree(pts)
    hoods = tree.query_ball_point(uniq, r=radius)
    flat = np.ones(len(uniq), dtype=np.float64)
    for u, idx in enumerate(hoods):
        if idx:
            flat[u] = float(np.mean(np.clip(nrm[idx] @ nc[first[u]], 0.0, 1.0)))
    return flat[inverse]


def scores(terms: np.ndarray, weights: QualityWeights = WEIGHTS) -> np.ndarray:
    """The weighted score (n,) in [0, 1] from terms (n, 3)."""
    score: np.ndarray = np.asarray(terms, dtype=np.float64).reshape(-1, 3) @ weights.vector()
    return score


def members_by_distance(
    members: np.ndarray, centre: int, midpoints: np.ndarray, axes: np.ndarray, near: Near = NEAR
) -> tuple[np.ndarray, np.ndarray]:
    """`members` (indices) sorted by distance to candidate `centre`, and the distances, where the distance is
    max(midpoint distance / near.radius, axis angle / near.angle_deg): below 1 is 'near'. Ties by index."""
    members = np.asarray(members, dtype=np.int64)
    dt = np.linalg.norm(midpoints[members] - midpoints[centre], axis=1)
    a = axes[members] / np.linalg.norm(axes[members], axis=1, keepdims=True)
    b = axes[centre] / np.linalg.norm(axes[centre])
    ang = np.degrees(libm.arccos(np.clip(np.abs(a @ b), 0.0, 1.0)))
    dist = np.maximum(dt / near.radius, ang / near.angle_deg)
    order = np.lexsort((members, dist))
    return members[order], dist[order]


class _Held(Protocol):
    @property
    def success(self) -> bool: ...


_O = TypeVar("_O", bound=_Held)


@dataclass(frozen=True)
class Repaired:
    """The selection after validation: `selected` (k,) candidate indices (a failing one replaced where a member of
    its cluster held), `results` each one's outcome, `first` the outcomes of the first pass, `simulated` how many
    candidates were simulated in all."""

    selected: np.ndarray
    results: list[Any]
    first: list[Any]
    simulated: int


def repair_by_simulation(
    selected: np.ndarray,
    clusters: np.ndarray,
    labels: np.ndarray,
    geometry: tuple[np.ndarray, np.ndarray],
    limit: int,
    simulate: Callable[[np.ndarray, float, float], Sequence[_O]],
    start: float = 0.1,
) -> Repaired:
    """The validation's selection: simulate(idx, lo, hi) gives the outcomes of candidates idx (reporting progress
    from lo to hi). The selected candidates are simulated first (progress from `start`); each that fails is replaced
    by the first of up to `limit` members of its final cluster (`clusters` (k, 2) per selected, `labels` (n, 2) per
    candidate), nearest to it first (members_by_distance over `geometry` = (midpoints, axes)), that holds. The jaws'
    and the suction cups' validation share it."""
    mids, axes = geometry
    first_hi = 0.55 if limit else 1.0
    results = list(simulate(selected, start, first_hi))
    first = list(results)
    simulated = len(selected)
    final = selected.copy()
    alternatives = {}
    for r, res in enumerate(results):
        if res.success or limit == 0:
            continue
        t, k = clusters[r]
        members = np.flatnonzero((labels[:, 0] == t) & (labels[:, 1] == k))
        members = members[members != selected[r]]
        ordered, _ = members_by_distance(members, int(selected[r]), mids, axes)
        alternatives[r] = ordered[:limit]
    for j in range(limit):
        rows = [r for r, alts in alternatives.items() if not results[r].success and j < len(alts)]
        if not rows:
            break
        idx = np.array([alternatives[r][j] for r in rows], dtype=np.int64)
        simulated += len(idx)
        lo = first_hi + (1.0 - first_hi) * j / limit
        for r, m, res in zip(rows, idx, simulate(idx, lo, lo + (1.0 - first_hi) / limit), strict=True):
            if res.success:
                final[r], results[r] = m, res
    return Repaired(final, results, first, simulated)


def select_best_near_medoid(
    labels: np.ndarray,
    medoids: np.ndarray,
    clusters: np.ndarray,
    score: np.ndarray,
    midpoints: np.ndarray,
    axes: np.ndarray,
    near: Near = NEAR,
) -> np.ndarray:
    """For each medoid (m,) of final cluster clusters[r] = (translation, direction), the member of that cluster
    (labels (n, 2)) within `near` of it with the highest score (ties: the nearer, then the smaller index).
    Returns (m,) int64 candidate indices; a medoid with no better member keeps itself."""
    labels = np.asarray(labels).reshape(-1, 2)
    out = np.asarray(medoids, dtype=np.int64).copy()
    for r, (m, (t, k)) in enumerate(zip(out.copy(), np.asarray(clusters).reshape(-1, 2), strict=True)):
        members = np.flatnonzero((labels[:, 0] == t) & (labels[:, 1] == k))
        if members.size <= 1:
            continue
        cand, dist = members_by_distance(members, int(m), midpoints, axes, near)
        cand, dist = cand[dist <= 1.0], dist[dist <= 1.0]
        if cand.size == 0:
            continue
        best = np.lexsort((cand, dist, -score[cand]))[0]
        if score[cand[best]] > score[m]:
            out[r] = cand[best]
    return out


def describe(terms_row: np.ndarray, score: float) -> dict[str, Any]:
    """The per-grasp `quality` object of the export."""
    return {
        "score": round(float(score), 6),
        **{name: round(float(v), 6) for name, v in zip(TERMS, terms_row, strict=True)},
    }


def half_angle_deg(friction: float, safety_factor: float) -> float:
    return math.degrees(math.atan(friction) / safety_factor)
