"""4x4 pose helpers and the contract's grasp frames (T_object_grasp): the jaws' and the suction cup's.

Frame (CONTRACT.md): origin at the contact midpoint, +X the closing axis (contact 0 -> 1), +Z the approach
direction, +Y = Z x X, roll psi about +X measured from Z0 = object +Z made orthogonal to X (object +X when
|X . Z_object| > 0.9).
"""

from __future__ import annotations

import numpy as np

from . import libm

__all__ = [
    "ROLL_REFERENCE_SWITCH",
    "roll_angles_rad",
    "choose_roll",
    "roll_basis",
    "grasp_frames",
    "approach_basis",
    "suction_frames",
    "matrix_to_quaternion_xyzw",
    "quaternion_xyzw_to_matrix",
]

#: above this |X . Z_object| the roll reference switches from object +Z to object +X
ROLL_REFERENCE_SWITCH = 0.9


def roll_angles_rad(rolls: int) -> np.ndarray:
    """`2 pi k / rolls`, k = 0..rolls-1: (rolls,) float64."""
    return 2.0 * np.pi * np.arange(rolls, dtype=np.float64) / rolls


def choose_roll(free: np.ndarray) -> int:
    """The roll at the middle of the widest circular run of free rolls.

    Ties go to the run whose middle is closest to half a turn (approach from the object's +Z side, palm up),
    then to the smaller index; with every roll free, half a turn itself.
    """
    R = len(free)
    if free.all():
        return R // 2
    if not free.any():
        raise ValueError("no free roll")
    start = int(np.argmin(free))  # a blocked roll: runs do not wrap past it
    best = None
    k = 0
    while k < R:
        idx = (start + k) % R
        if free[idx]:
            length = 0
            while k < R and free[(start + k) % R]:
                length += 1
                k += 1
            middle = (idx + (length - 1) // 2) % R
            dist = min(abs(middle - R // 2), R - abs(middle - R // 2))
            key = (-length, dist, middle)
            if best is None or key < best:
                best = key
        else:
            k += 1
    assert best is not None  # some roll is free
    return int(best[2])


def roll_basis(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll-0 basis for unit closing axes `axes` (n, 3): returns (Y0, Z0), each (n, 3) unit, per the contract."""
    axes = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    ref = np.zeros_like(axes)
    use_x = np.abs(axes[:, 2]) > ROLL_REFERENCE_SWITCH
    ref[~use_x, 2] = 1.0
    ref[use_x, 0] = 1.0
    z0 = ref - np.sum(ref * axes, axis=1, keepdims=True) * axes
    z0 /= np.linalg.norm(z0, axis=1, keepdims=True)
    y0 = np.cross(z0, axes)
    return y0, z0


def grasp_frames(midpoints: np.ndarray, axes: np.ndarray, rolls_rad: np.ndarray) -> np.ndarray:
    """T_object_grasp for each candidate: (n, 4, 4) float64 from midpoints (n, 3), axes (n, 3), roll (n,)."""
    midpoints = np.asarray(midpoints, dtype=np.float64).reshape(-1, 3)
    axes = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    psi = np.asarray(rolls_rad, dtype=np.float64).reshape(-1, 1)
    y0, z0 = roll_basis(axes)
    c, s = libm.cos(psi), libm.sin(psi)
    y = c * y0 + s * z0
    z = -s * y0 + c * z0
    T = np.zeros((len(axes), 4, 4), dtype=np.float64)
    T[:, :3, 0] = axes
    T[:, :3, 1] = y
    T[:, :3, 2] = z
    T[:, :3, 3] = midpoints
    T[:, 3, 3] = 1.0
    return T


def approach_basis(approach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roll-0 basis of a suction grasp for unit approaches `approach` (n, 3) (CONTRACT.md "Suction cups"): (X0, Y0),
    each (n, 3) unit, X0 = the object's +X made orthogonal to Z (its +Y when |X . Z| > 0.9), Y0 = Z x X0."""
    z = np.asarray(approach, dtype=np.float64).reshape(-1, 3)
    ref = np.zeros_like(z)
    use_y = np.abs(z[:, 0]) > ROLL_REFERENCE_SWITCH
    ref[~use_y, 0] = 1.0
    ref[use_y, 1] = 1.0
    x0 = ref - np.sum(ref * z, axis=1, keepdims=True) * z
    x0 /= np.linalg.norm(x0, axis=1, keepdims=True)
    return x0, np.cross(z, x0)


def suction_frames(contacts: np.ndarray, approach: np.ndarray, rolls_rad: np.ndarray) -> np.ndarray:
    """T_object_grasp of suction grasps: (n, 4, 4) float64 with the origin at the contact (n, 3), +Z the unit
    approach (n, 3) and the roll psi (n,) about +Z: X = cos(psi) X0 + sin(psi) Y0, Y = Z x X (approach_basis)."""
    contacts = np.asarray(contacts, dtype=np.float64).reshape(-1, 3)
    z = np.asarray(approach, dtype=np.float64).reshape(-1, 3)
    psi = np.asarray(rolls_rad, dtype=np.float64).reshape(-1, 1)
    x0, y0 = approach_basis(z)
    x = libm.cos(psi) * x0 + libm.sin(psi) * y0
    T = np.zeros((len(z), 4, 4), dtype=np.float64)
    T[:, :3, 0] = x
    T[:, :3, 1] = np.cross(z, x)
    T[:, :3, 2] = z
    T[:, :3, 3] = contacts
    T[:, 3, 3] = 1.0
    return T


def matrix_to_quaternion_xyzw(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> unit quaternion [x, y, z, w] with w >= 0."""
    R = np.asarray(R, dtype=np.float64)[:3, :3]
    tr = np.trace(R)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    u: np.ndarray = np.asarray(q)
    u /= np.linalg.norm(u)
    return -u if u[3] < 0 else u


def quaternion_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternion [x, y, z, w] -> rotation matrix (3, 3)."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
