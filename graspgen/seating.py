"""Exported grasps of a gripper from CAD, judged where its fingers really touch the part.

CONTRACT.md ("Gripper geometry from CAD"): the fingers close until they touch, and where an inner face is not flat
(a V-groove, a ridge, a chamfered tip) the export's `width` and `contacts` and criteria (c) and (e) use where the
finger's surface first meets the part's triangles, not the sampled pair. The candidates are found and clustered on
the sampled pairs (criteria (a)-(e) over millions of pairs); the grasps to export are then seated
(graspgen.collision.seat_fingers) and judged again on their seats:

- (c): each finger's push along the closing axis lies within the friction cones of its contacts
  (collision.seat_friction_margin_deg >= 0);
- (e): the hold margin (hold.hold_margins) with both fingers' forces along the closing axis on the line through the
  midpoint of their contacts' centres (as far apart along the axis as those centres), each finger's normal the mean
  of its contacts' and its torsion radius from their spread (`seat_torsion_radius`), >= 1. The couple of two
  fingers whose contacts lie off one line (seated on different edges) is not modelled: rigid fingers turn the part
  until it seats, which the simulation (validate=True) shows.

A grasp that fails on its seat is replaced by the nearest member of its cluster that passes (nearest in contact
midpoint, then closing axis), trying at most `SEAT_TRIES` members; a cluster without one is left out of the export.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from . import collision as _collision
from . import hold as _hold
from .params import TOLERANCES

if TYPE_CHECKING:
    from .collision import GripperSolids, MeshTree, Seat

__all__ = ["SEAT_TRIES", "SeatJudge", "SeatHold", "Seated", "nearest_members", "seat_torsion_radius"]

#: members of a cluster tried, nearest first, when its exported grasp fails on its seat
SEAT_TRIES = 16


@dataclass(frozen=True)
class SeatHold:
    """What criterion (e) needs on a seat: the part's centre of mass (3,) m, the load (hold.hold_load) N, the grip
    force per finger N and the friction coefficient."""

    center_of_mass: np.ndarray
    load: float
    grip_force: float
    friction: float


@dataclass(frozen=True)
class Seated:
    """One grasp on its seat: `contacts` and `normals` (2, 3) per finger (-X first) the contact nearest the closing
    line and the part's outward normal there (the export's `contacts`), the seat itself, its friction margin
    (degrees, criterion (c)) and hold margin (criterion (e); None when (e) is off)."""

    seat: Seat
    contacts: np.ndarray
    normals: np.ndarray
    friction_margin_deg: float
    hold_margin: float | None

    @property
    def passes(self) -> bool:
        return self.friction_margin_deg >= 0.0 and (self.hold_margin is None or self.hold_margin >= 1.0)


def seat_torsion_radius(points: np.ndarray, axis: np.ndarray, model: _hold.HoldModel = _hold.HOLD) -> float:
    """The torsion radius (m) of one finger's seat contacts `points` (k, 3) about the closing `axis` (3,): the mean
    distance of the contacts from their centre across the axis, at least the model's point-contact radius.

    Two contacts (a V-groove's flanks) each carry half the grip force at that distance, so the friction torque is
    exactly mu N times it. Three or more outline the patch where a face meets the part (the seat keeps every vertex
    and edge crossing of the overlap), and the mean distance of a patch's area from its centre is at most that of
    its outline: a disc's is 2/3 of its rim's, which is the factor used; a single contact is a point."""
    k = len(points)
    if k < 2:
        return model.min_torsion_radius
    off = points - points.mean(axis=0)
    off -= np.outer(off @ axis, axis)
    spread = float(np.mean(np.linalg.norm(off, axis=1)))
    return max(model.min_torsion_radius, spread if k == 2 else 2.0 * spread / 3.0)


@dataclass(frozen=True)
class SeatJudge:
    """Seats grasps of one gripper from CAD on one part and judges them by criteria (c) and (e) on the seat."""

    tree: MeshTree
    solids: GripperSolids
    half_angle_deg: float
    hold: SeatHold | None
    #: the part's triangle bounds (collision.triangle_bounds): seats only move the triangles near the fingers
    bounds: tuple[np.ndarray, np.ndarray] | None = None

    def seat(self, T_object_grasp: np.ndarray, width: float) -> Seated | None:
        """The grasp T_object_grasp (4, 4) of sampled contact distance `width` (m) on its seat; None when a finger
        reaches the midplane without touching."""
        return self.seat_many(T_object_grasp[None], np.array([width]))[0]

    def seat_many(self, T_object_grasp: np.ndarray, widths: np.ndarray) -> list[Seated | None]:
        """`seat` of k grasps (T (k, 4, 4), widths (k,)); their hold margins in one evaluation (a call of
        hold.hold_margins costs about 20 ms whatever its size). A seat that fails (c) gets no hold margin (None): it
        fails anyway."""
        found: list[tuple[Seat, np.ndarray, np.ndarray, float] | None] = []
        for T, width in zip(T_object_grasp, widths, strict=True):
            seat = _collision.seat_fingers(
                self.tree, self.solids, T, float(width), TOLERANCES.inner_margin, bounds=self.bounds
            )
            if seat is None:
                found.append(None)
                continue
            x, o = T[:3, 0], T[:3, 3]
            contacts = np.empty((2, 3))
            normals = np.empty((2, 3))
            for k in range(2):
                pts = seat.points[k]
                off = (pts - o) - np.outer((pts - o) @ x, x)  # distance from the closing line through the origin
                q = int(np.argmin(np.einsum("ij,ij->i", off, off)))
                contacts[k], normals[k] = pts[q], seat.normals[k][q]
            found.append((seat, contacts, normals, _collision.seat_friction_margin_deg(seat, x, self.half_angle_deg)))
        held = [q for q, f in enumerate(found) if f is not None and f[3] >= 0.0]
        margins = self._hold_margins([f for f in found if f is not None and f[3] >= 0.0], T_object_grasp[held, :3, 0])
        hold_of = dict(zip(held, margins, strict=True)) if margins is not None else {}
        return [None if f is None else Seated(f[0], f[1], f[2], f[3], hold_of.get(q)) for q, f in enumerate(found)]

    def _hold_margins(
        self, found: list[tuple[Seat, np.ndarray, np.ndarray, float]], axes: np.ndarray
    ) -> list[float] | None:
        if self.hold is None or not found:
            return None
        centres = np.empty((len(found), 2, 3))
        normals = np.empty((len(found), 2, 3))
        rho = np.empty((len(found), 2))
        for q, (seat, _, _, _) in enumerate(found):
            x = axes[q]
            c0, c1 = seat.points[0].mean(axis=0), seat.points[1].mean(axis=0)
            # both fingers push along the closing axis x: the forces act on the line along x through the centres'
            # midpoint, at the centres' distance along x (hold_margins reads the axis from the two contacts)
            mid, half = (c0 + c1) / 2, abs(float((c1 - c0) @ x)) / 2
            centres[q, 0], centres[q, 1] = mid - half * x, mid + half * x
            for k in range(2):
                n = seat.normals[k].mean(axis=0)
                normals[q, k] = n / max(float(np.linalg.norm(n)), 1e-300)
                rho[q, k] = seat_torsion_radius(seat.points[k], axes[q])
        h = self.hold
        margins = _hold.hold_margins(
            centres, rho, h.center_of_mass, load=h.load, grip_force=h.grip_force, friction=h.friction, normals=normals
        )
        return [float(v) for v in margins]


def nearest_members(
    labels: np.ndarray, cluster: np.ndarray, medoid: int, midpoints: np.ndarray, axes: np.ndarray
) -> np.ndarray:
    """The members of the final cluster `cluster` (2,) (rows of `labels` (n, 2) equal to it) other than `medoid`,
    nearest first: by contact midpoint (m), then by the angle between closing axes (sign-free)."""
    members = np.flatnonzero((labels[:, 0] == cluster[0]) & (labels[:, 1] == cluster[1]))
    members = members[members != medoid]
    d = np.linalg.norm(midpoints[members] - midpoints[medoid], axis=1)
    c = -np.abs(axes[members] @ axes[medoid])
    ordered: np.ndarray = members[np.lexsort((members, c, d))]
    return ordered
