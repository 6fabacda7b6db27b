"""How well a selection of grasps covers the space of valid grasps, and how far apart the selected grasps are.

A candidate is covered by a selected grasp when their contact midpoints lie within `radius` (metres) and their
closing axes within `angle_deg` of each other. The axis angle is sign-invariant, arccos |a . b| (a closing axis and
its reverse are the same jaw pair with the contacts swapped), as in the clustering.

Coverage is the share of all candidates covered by at least one selected grasp, reported at the `LEVELS`
(1 cm, 30 deg) and (2 cm, 45 deg). Diversity is the smallest pairwise distance among the selected grasps: in
translation (metres), in axis angle (degrees), and combined as max(dt / 1 cm, angle / 30 deg), the smallest
coverage level's neighbourhood: below 1, two selected grasps cover each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit, prange

from . import libm

__all__ = ["LEVELS", "CoverageReport", "coverage", "coverage_shares", "axis_angles_deg", "combined_distance"]

#: (radius in metres, axis angle in degrees) at which coverage is reported
LEVELS: tuple[tuple[float, float], ...] = ((0.01, 30.0), (0.02, 45.0))
#: candidates compared against all selected grasps at once, per block (memory: block x selected floats)


@dataclass(frozen=True)
class CoverageReport:
    """Coverage shares at each level and the diversity of the selection."""

    candidates: int
    selected: int
    shares: tuple[float, ...]  # one per level, 0..1
    levels: tuple[tuple[float, float], ...]
    min_pair_translation: float | None  # metres; None with fewer than two selected grasps
    min_pair_angle_deg: float | None
    min_pair_combined: float | None

    def to_json(self) -> dict[str, Any]:
        def r(v: float | None) -> float | None:
            return None if v is None else round(float(v), 9)

        return {
            "candidates": self.candidates,
            "selected": self.selected,
            "levels": [
                {"radius": r(rad), "angle_deg": r(ang), "share": r(share)}
                for (rad, ang), share in zip(self.levels, self.shares, strict=True)
            ],
            "min_pair_translation": r(self.min_pair_translation),
            "min_pair_angle_deg": r(self.min_pair_angle_deg),
            "min_pair_combined": r(self.min_pair_combined),
        }


def _unit(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64).reshape(-1, 3)
    n = np.linalg.norm(a, axis=1, keepdims=True)
    return a / np.where(n > 0, n, 1.0)


def axis_angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sign-invariant angles (degrees, 0..90) between axes a (n, 3) and b (m, 3): (n, m)."""
    c = np.abs(_unit(a) @ _unit(b).T)
    deg: np.ndarray = np.degrees(libm.arccos(np.clip(c, 0.0, 1.0)))
    return deg


def combined_distance(
    midpoints_a: np.ndarray,
    axes_a: np.ndarray,
    midpoints_b: np.ndarray,
    axes_b: np.ndarray,
    *,
    radius: float = LEVELS[0][0],
    angle_deg: float = LEVELS[0][1],
) -> np.ndarray:
    """max(translation / radius, axis angle / angle_deg) between grasps a (n) and b (m): (n, m), unitless."""
    pa = np.asarray(midpoints_a, dtype=np.float64).reshape(-1, 3)
    pb = np.asarray(midpoints_b, dtype=np.float64).reshape(-1, 3)
    dt = np.linalg.norm(pa[:, None, :] - pb[None, :, :], axis=2)
    d: np.ndarray = np.maximum(dt / radius, axis_angles_deg(axes_a, axes_b) / angle_deg)
    return d


def coverage_shares(
    midpoints: np.ndarray,
    axes: np.ndarray,
    selected: np.ndarray,
    levels: tuple[tuple[float, float], ...] = LEVELS,
) -> tuple[float, ...]:
    """Share of the candidates (midpoints (n, 3) m, axes (n, 3)) within each level of some selected candidate."""
    P = np.asarray(midpoints, dtype=np.float64).reshape(-1, 3)
    U = _unit(axes)
    sel = np.asarray(selected, dtype=np.int64).reshape(-1)
    n = len(P)
    if n == 0 or len(sel) == 0:
        return tuple(0.0 for _ in levels)
    Ps, Us = P[sel], U[sel]
    # 1e-12 slack: a grasp exactly at the level's edge counts as covered
    r2 = np.array([radius * radius + 1e-12 for radius, _ in levels])
    cos_a = np.array([math.cos(math.radians(a)) - 1e-12 for _, a in levels])
    covered = _covered(
        np.ascontiguousarray(P), np.ascontiguousarray(U), np.ascontiguousarray(Ps), np.ascontiguousarray(Us), r2, cos_a
    )
    return tuple(float(covered[k].mean()) for k in range(len(levels)))


@njit(parallel=True, cache=True)
def _covered(
    P: np.ndarray, U: np.ndarray, Ps: np.ndarray, Us: np.ndarray, r2: np.ndarray, cos_a: np.ndarray
) -> np.ndarray:
    """(levels, n) bool: candidate i lies within level k of some selected grasp; stops at the first one found
    (the same tests as a full candidates x selected comparison, without building it)."""
    n, m, L = P.shape[0], Ps.shape[0], r2.shape[0]
    out = np.zeros((L, n), dtype=np.bool_)
    for i in prange(n):
        todo = L
        for s in range(m):
            dx = P[i, 0] - Ps[s, 0]
            dy = P[i, 1] - Ps[s, 1]
            dz = P[i, 2] - Ps[s, 2]
            d2 = dx * dx + dy * dy + dz * dz
            c = abs(U[i, 0] * Us[s, 0] + U[i, 1] * Us[s, 1] + U[i, 2] * Us[s, 2])
            for k in range(L):
                if not out[k, i] and d2 <= r2[k] and c >= cos_a[k]:
                    out[k, i] = True
                    todo -= 1
            if todo == 0:
                break
    return out


def coverage(
    midpoints: np.ndarray, axes: np.ndarray, selected: np.ndarray, levels: tuple[tuple[float, float], ...] = LEVELS
) -> CoverageReport:
    """Coverage shares and the diversity of `selected` (indices into the candidates)."""
    P = np.asarray(midpoints, dtype=np.float64).reshape(-1, 3)
    sel = np.asarray(selected, dtype=np.int64).reshape(-1)
    shares = coverage_shares(P, axes, sel, levels)
    mt = ma = mc = None
    if len(sel) >= 2:
        U = _unit(axes)
        iu = np.triu_indices(len(sel), k=1)
        dt = np.linalg.norm(P[sel][:, None, :] - P[sel][None, :, :], axis=2)[iu]
        da = axis_angles_deg(U[sel], U[sel])[iu]
        radius, angle = levels[0]
        mt, ma = float(dt.min()), float(da.min())
        mc = float(np.maximum(dt / radius, da / angle).min())
    return CoverageReport(len(P), len(sel), shares, tuple(levels), mt, ma, mc)
