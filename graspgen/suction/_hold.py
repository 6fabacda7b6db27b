"""Criterion `hold` for a suction cup: does the sealed cup hold the part's load in every direction?

Model: Dex-Net 3.0's "suction ring" contact (Mahler et al., ICRA 2018), quasi-static, SI units; docs/HOLD.md.
The contact frame has its origin at the contact c and z along the approach a (into the part). A sealed cup of lip
radius r pulls the part onto its lip with the vacuum force V = vacuum x pi r^2 (Schmalz's F = dp x A); the lip then
presses on the part with N = V + f_z, where f_z is the wrench's force along a (the cup pushing, > 0, or pulling,
< 0). The cup resists a wrench (f, tau) at c while

- pull: N >= 0, f_z >= -V (the part is not torn off);
- friction with torsion (an elliptic limit surface, as criterion (e)'s soft fingers): |f_t|^2 + (tau_z / r)^2 <=
  (mu N)^2, f_t the tangential force, tau_z the moment about a (a ring of friction mu N at radius r gives
  r mu N of torsion);
- peel: |tau_t| <= N r / 2, tau_t the moment about the tangential axes. The lip's reaction along the ring,
  N / (2 pi r) (1 + k cos theta), carries the moment N k r / 2; no part of the lip lifts (the seal holds) while
  k <= 1. Dex-Net 3.0 bounds these moments by the lip material's elastic limit; here the limit follows the
  pressure that holds the lip on, so that a lighter vacuum peels off sooner.

The load: a force of magnitude W at the centre of mass, in every direction d (the robot turns and moves the part),
W = safety_factor x mass x (g + accel) (a vendor's sizing: load times a safety factor, >= 1.5 on smooth parts). For
the unit direction d the cup supplies f = -W d and tau = -W rho x d (rho = com - c), and each constraint is linear
in the load's scale s: friction s (|L1 d| + mu a . d) W <= mu V with L1 d = (d_t, (a x rho) . d / r); peel
s (|L2 d| + (r/2) a . d) W <= (r/2) V with L2 d the tangential part of rho x d; pull s (a . d) W <= V. The hold
margin is the largest s that every direction allows: V / W min(mu / G1, (r/2) / G2, 1), with
G = max over unit d of |L d| + b . d. That maximum is exact: max_d |L d| + b . d = max over unit u of |L^T u + b|
(L d's norm is max_u u . L d), a convex function of u, largest on the unit sphere, where the trust-region
equations (lambda I - L L^T) u = L b give it (the secular equation solved by bisection, the hard case included).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

__all__ = ["HoldRule", "HoldOut", "hold_kernel", "FRICTION", "PEEL", "PULL", "LIMITS"]

#: which constraint sets a candidate's margin
FRICTION, PEEL, PULL = 0, 1, 2
LIMITS = ("friction", "peel", "pull")
_CHUNK = 1024
_BISECTIONS = 200

#: radius (m), vacuum_force V (N), friction mu, load W (N, with the safety factor), center_of_mass (3,) metres
HoldRule = namedtuple("HoldRule", ["radius", "vacuum_force", "friction", "load", "center_of_mass"])
#: per candidate: margin (n,) the resisted over the required load, limit (n,) int8 FRICTION, PEEL or PULL
HoldOut = namedtuple("HoldOut", ["margin", "limit"])


def hold_kernel(points: np.ndarray, approach: np.ndarray, rule: HoldRule, max_margin: float = 1.0e6) -> HoldOut:
    """Hold margins of cups at contacts `points` (n, 3) with unit approaches `approach` (n, 3) (module docstring),
    capped at `max_margin` (a part without load holds without limit)."""
    n = len(points)
    out = HoldOut(np.zeros(n), np.zeros(n, dtype=np.int8))
    if n:
        _hold(np.ascontiguousarray(points), np.ascontiguousarray(approach), rule, float(max_margin), out)
    return out


@njit(parallel=True, cache=True, error_model="numpy")
def _hold(P: np.ndarray, A: np.ndarray, rule: HoldRule, cap: float, out: HoldOut) -> None:
    n = P.shape[0]
    chunks = (n + _CHUNK - 1) // _CHUNK
    for c in prange(chunks):
        L1 = np.empty((3, 3))
        L2 = np.empty((2, 3))
        for i in range(c * _CHUNK, min((c + 1) * _CHUNK, n)):
            _hold_one(P, A, rule, cap, out, i, L1, L2)


@njit(cache=True, error_model="numpy")
def _hold_one(
    P: np.ndarray, A: np.ndarray, rule: HoldRule, cap: float, out: HoldOut, i: int, L1: np.ndarray, L2: np.ndarray
) -> None:
    r, V, mu, W = rule.radius, rule.vacuum_force, rule.friction, rule.load
    a = A[i]
    rho = rule.center_of_mass - P[i]
    # any tangential basis: the norms below do not depend on it
    xx, xy, xz, yx, yy, yz = _tangents(a[0], a[1], a[2])
    x = np.array([xx, xy, xz])
    y = np.array([yx, yy, yz])
    ar = np.cross(a, rho)
    L1[0], L1[1], L1[2] = x, y, ar / r
    L2[0], L2[1] = np.cross(x, rho), np.cross(y, rho)
    if W <= 0.0:
        out.margin[i], out.limit[i] = cap, PULL
        return
    g1 = _max_norm_plus_linear(L1, mu * a)
    g2 = _max_norm_plus_linear(L2, 0.5 * r * a)
    m_friction = mu * V / (W * g1)
    m_peel = 0.5 * r * V / (W * g2)
    m_pull = V / W
    best, limit = m_friction, FRICTION
    if m_peel < best:
        best, limit = m_peel, PEEL
    if m_pull < best:
        best, limit = m_pull, PULL
    out.margin[i], out.limit[i] = min(best, cap), limit


@njit(cache=True, inline="always", error_model="numpy")
def _tangents(ax: float, ay: float, az: float) -> tuple[float, float, float, float, float, float]:
    """Two unit vectors orthogonal to the unit a and to each other."""
    if abs(ax) > 0.9:
        ex, ey, ez = 0.0, 1.0, 0.0
    else:
        ex, ey, ez = 1.0, 0.0, 0.0
    dot = ex * ax + ey * ay + ez * az
    xx, xy, xz = ex - dot * ax, ey - dot * ay, ez - dot * az
    inv = 1.0 / math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx * inv, xy * inv, xz * inv
    return xx, xy, xz, ay * xz - az * xy, az * xx - ax * xz, ax * xy - ay * xx


@njit(cache=True, error_model="numpy")
def _max_norm_plus_linear(L: np.ndarray, b: np.ndarray) -> float:
    """max over unit d (3,) of |L d| + b . d, for L (k, 3): the largest |L^T u + b| over unit u (k,), i.e. the
    square root of |b|^2 + max (u^T Q u + 2 p . u) with Q = L L^T, p = L b. With Q's eigenvalues w and p's
    coordinates q in its eigenvectors, the maximum is lambda + sum q_i^2 / (lambda - w_i) at the lambda > max w with
    sum q_i^2 / (lambda - w_i)^2 = 1 (bisection on (max w, max w + |q|]; when q has no part along the largest
    eigenvector and the sum stays below 1, lambda = max w: the hard case, where the formula still holds)."""
    Q = L @ L.T
    p = L @ b
    w, vec = np.linalg.eigh(Q)
    q = vec.T @ p
    k = w.shape[0]
    top = w[k - 1]
    qn = math.sqrt(np.sum(q * q))
    lo, hi = top, top + qn
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        phi = 0.0
        for j in range(k):
            gap = mid - w[j]
            if q[j] != 0.0:
                phi += (q[j] / gap) ** 2 if gap > 0.0 else np.inf
        if phi > 1.0:
            lo = mid
        else:
            hi = mid
    lam = hi
    value = lam
    for j in range(k):
        gap = lam - w[j]
        if q[j] != 0.0 and gap > 0.0:
            value += q[j] * q[j] / gap
    return math.sqrt(max(value + float(b @ b), 0.0))
