"""Plain-numpy reference implementations of the criteria, written from CONTRACT.md and the paper, independent
of the kernels: slow, obvious, and used to check the compiled code exactly."""

from __future__ import annotations

import math

import numpy as np

from graspgen.gripper import GripperSpec
from graspgen.params import TOLERANCES
from graspgen.transforms import grasp_frames, roll_angles_rad


def pair_criteria(points, normals, *, stroke, min_width, friction, safety_factor, inside=False, finger_thickness=0.0):
    """Boolean (n, n) upper-triangle masks: accepted outside, accepted inside (all pairs i < j)."""
    n = len(points)
    I, J = np.triu_indices(n, 1)
    d = points[J] - points[I]
    dist = np.linalg.norm(d, axis=1)
    dh = d / dist[:, None]
    cos0 = np.sum(normals[I] * dh, axis=1)
    cos1 = np.sum(normals[J] * dh, axis=1)
    alpha = math.atan(friction) / safety_factor
    ang_out = np.maximum(np.arccos(np.clip(-cos0, -1, 1)), np.arccos(np.clip(cos1, -1, 1)))
    ang_in = np.maximum(np.arccos(np.clip(cos0, -1, 1)), np.arccos(np.clip(-cos1, -1, 1)))
    outside = (cos0 < 0) & (cos1 > 0) & (dist <= stroke) & (dist >= min_width) & (ang_out <= alpha)
    inner = np.zeros_like(outside)
    if inside:
        lo, hi = min_width + 2 * finger_thickness, stroke + 2 * finger_thickness
        inner = (cos0 > 0) & (cos1 < 0) & (dist <= hi) & (dist >= lo) & (ang_in <= alpha)
    return I, J, outside, inner


def gripper_boxes(gripper: GripperSpec, width: float, mode: str, inside: bool = False, reach: float = 0.0):
    """Forbidden boxes in the grasp frame as (lo (3,), hi (3,)) pairs, per the module docstring of collision.py;
    `reach` > 0 (swept): the palm's footprint, at least a finger wide, swept from the fingers' base to `reach`
    behind it (the approach)."""
    t, m = gripper.finger_thickness, TOLERANCES.inner_margin
    hy, hz = gripper.finger_width / 2, gripper.finger_depth / 2
    if not inside:
        o = min(width + gripper.pregrasp_clearance, gripper.stroke) if mode == "swept" else width
        a, b = width / 2 + m, max(o, width) / 2 + t
    else:
        o = max(width - gripper.pregrasp_clearance, gripper.min_width + 2 * t) if mode == "swept" else width
        a, b = min(o, width) / 2 - t, width / 2 - m
    boxes = [(np.array([-b, -hy, -hz]), np.array([-a, hy, hz])), (np.array([a, -hy, -hz]), np.array([b, hy, hz]))]
    if mode == "swept" and (gripper.palm_depth > 0 or reach > 0):
        px = gripper.stroke / 2 + t
        py = gripper.palm_width / 2 if gripper.palm_depth > 0 else 0.0
        if reach > 0:
            py = max(py, hy)
        boxes.append((np.array([-px, -py, -hz - max(gripper.palm_depth, reach)]), np.array([px, py, -hz])))
    return boxes


def free_rolls(points, midpoints, axes, widths, inside, gripper, mode, rolls, reach=0.0):
    """(m, rolls) bool by brute force: every point against every box at every roll."""
    psi = roll_angles_rad(rolls)
    out = np.zeros((len(midpoints), rolls), dtype=bool)
    for c in range(len(midpoints)):
        boxes = gripper_boxes(gripper, widths[c], mode, bool(inside[c]), reach)
        T = grasp_frames(np.repeat(midpoints[c : c + 1], rolls, 0), np.repeat(axes[c : c + 1], rolls, 0), psi)
        for k in range(rolls):
            R, t = T[k, :3, :3], T[k, :3, 3]
            local = (points - t) @ R
            hit = False
            for lo, hi in boxes:
                if np.any(np.all((local >= lo) & (local <= hi), axis=1)):
                    hit = True
                    break
            out[c, k] = not hit
    return out
