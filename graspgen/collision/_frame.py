"""A candidate's grasp frame at roll 0 and the roll tables, shared by the point and the triangle kernels.

A candidate is a closing axis X (unit, contact 0 -> 1) through a midpoint, with a closing width. Its roll-0 basis is
the contract's: Z0 = the object's +Z made orthogonal to X (the object's +X when |X . z| > switch), Y0 = Z0 x X. At
roll k, with (c, s) = (cos, sin) of 2 pi k / R: Y = c Y0 + s Z0, Z = -s Y0 + c Z0, so a point with roll-0
coordinates (x, y0, z0) has y = c y0 + s z0, z = -s y0 + c z0.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
import numpy.typing as npt
from numba import njit

from .. import libm
from ..transforms import ROLL_REFERENCE_SWITCH, roll_angles_rad
from ._bits import MAX_ROLLS, full_mask

#: The roll angles' tables: cos, sin (R,) of 2 pi k / R by the C library (libm: the same bits on every CPU);
#: half = R / 2 for even R (roll k + half turns (y, z) into (-y, -z)), else 0; gfac bounds the rounding of that
#: symmetry per metre of radius; full = the mask of all R rolls; switch = the roll-0 reference's threshold.
#: a candidate's frame as the kernels pass it: midpoint (3 floats), unit axis (3) and width
Frame7 = tuple[float, float, float, float, float, float, float]

Rolls = namedtuple("Rolls", ["cos", "sin", "half", "gfac", "full", "switch"])


def roll_table(rolls: int) -> Rolls:
    """The Rolls of `rolls` roll angles (1..MAX_ROLLS)."""
    if not 1 <= rolls <= MAX_ROLLS:
        raise ValueError(f"rolls must be 1..{MAX_ROLLS}")
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
    return Rolls(cos_k, sin_k, half, gfac, full_mask(rolls), ROLL_REFERENCE_SWITCH)


#: Candidates as the kernels read them: either given by geometry (mids (m, 3), axes (m, 3) unit, widths (m,)) with
#: points, i, j empty, or as index pairs (points (n, 3), i, j (m,) int64: contact 0 = points[i]) with the geometry
#: arrays empty; inside (m,) bool in both forms.
Candidates = namedtuple("Candidates", ["mids", "axes", "widths", "points", "i", "j", "inside"])


def candidates_of_geometry(
    midpoints: npt.ArrayLike, axes: npt.ArrayLike, widths: npt.ArrayLike, inside: npt.ArrayLike
) -> Candidates:
    """Candidates given by midpoint, unit axis and width."""
    f = np.float64
    no_index = np.zeros(0, dtype=np.int64)
    return Candidates(
        np.ascontiguousarray(midpoints, dtype=f),
        np.ascontiguousarray(axes, dtype=f),
        np.ascontiguousarray(widths, dtype=f),
        np.zeros((0, 3)),
        no_index,
        no_index,
        np.ascontiguousarray(inside, dtype=np.bool_),
    )


def candidates_of_pairs(points: npt.ArrayLike, i: npt.ArrayLike, j: npt.ArrayLike, inside: npt.ArrayLike) -> Candidates:
    """Candidates given as point index pairs (contact 0 = points[i]); the indices are checked (check_pairs)."""
    P = np.ascontiguousarray(points, dtype=np.float64)
    i, j = (np.ascontiguousarray(a, dtype=np.int64) for a in (i, j))
    if len(i):
        check_pairs(len(P), i, j)
    return Candidates(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), P, i, j, np.ascontiguousarray(inside, bool))


def candidate_count(c: Candidates) -> int:
    """The number of candidates that the geometry (or the index pairs) describe; ValueError when those arrays
    disagree on it (`inside` is the caller's to check)."""
    rows = len(c.i) if len(c.points) else len(c.mids)
    if len(c.points) and len(c.j) != rows or not len(c.points) and not len(c.axes) == len(c.widths) == rows:
        raise ValueError("the candidates' arrays must have one row per candidate")
    return rows


def check_pairs(n: int, i: np.ndarray, j: np.ndarray) -> None:
    """The kernels read points[i], points[j] unchecked: indices in [0, n), no point paired with itself."""
    if len(i) != len(j):
        raise ValueError("i, j and inside must have the same length")
    if not len(i):
        return
    lo, hi = min(int(np.min(i)), int(np.min(j))), max(int(np.max(i)), int(np.max(j)))
    if lo < 0 or hi >= n:
        raise ValueError(f"point indices must lie in [0, {n}), got {lo}..{hi}")
    if np.any(i == j):
        raise ValueError("a pair of a point with itself has no closing axis")


@njit(cache=True, inline="always", error_model="numpy")
def roll0_basis(ax: float, ay: float, az: float, switch: float) -> tuple[float, float, float, float, float, float]:
    """(Y0, Z0) of the unit closing axis (ax, ay, az), as six floats: Z0 = the object's +Z made orthogonal to X (its
    +X when |X . z| > switch), Y0 = Z0 x X."""
    if abs(az) > switch:
        rx, ry, rz = 1.0, 0.0, 0.0
    else:
        rx, ry, rz = 0.0, 0.0, 1.0
    d = rx * ax + ry * ay + rz * az
    zx, zy, zz = rx - d * ax, ry - d * ay, rz - d * az
    nz = np.sqrt(zx * zx + zy * zy + zz * zz)
    zx, zy, zz = zx / nz, zy / nz, zz / nz
    yx = zy * az - zz * ay
    yy = zz * ax - zx * az
    yz = zx * ay - zy * ax
    return yx, yy, yz, zx, zy, zz


@njit(cache=True, inline="always", error_model="numpy")
def pair_frame(P: np.ndarray, a: int, b: int) -> Frame7:
    """Midpoint (3 floats), unit axis (3) and width of the candidate (P[a], P[b]), with numpy's arithmetic for
    0.5 (p_a + p_b), d / |d| and |d| (d = p_b - p_a; the squares added in numpy's order): a candidate given as a pair
    gets, bit for bit, the frame that the same candidate given by geometry (made by numpy) has."""
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


@njit(cache=True, inline="always", error_model="numpy")
def candidate_frame(c: Candidates, q: int) -> Frame7:
    """(midpoint, axis, width) of candidate q of the Candidates c, as seven floats (pair_frame for index pairs)."""
    if c.i.shape[0] > 0:
        return pair_frame(c.points, c.i[q], c.j[q])
    return c.mids[q, 0], c.mids[q, 1], c.mids[q, 2], c.axes[q, 0], c.axes[q, 1], c.axes[q, 2], c.widths[q]
