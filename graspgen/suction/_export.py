"""A suction run's result: its candidates (the NPZ) and its grasp set (the grasp_set/1 JSON), CONTRACT.md.

The export has the jaws' format with `gripper.kind` "suction": each grasp's `contacts` and `normals` hold one
point (the lip's centre on the surface, its outward normal), `pose` is T_object_grasp with the origin at the contact
and +Z the approach. The NPZ has `contacts (n, 1, 3)`, `normals (n, 1, 3)`, `midpoints (n, 3)` (the contacts, for
readers of either kind), `axes (n, 3)` (the approaches), `free_rolls (n, R)`, `roll_angles_rad (R,)`, `labels`,
`medoids`, and the suction terms `seal_strain (n,)`, `tilt_deg (n,)` and, when `hold` ran, `hold_margin (n,)`.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InvalidCandidatesError
from ..export import FORMAT, npz_bytes, write_atomic
from ..params import Params
from ._spec import SuctionSpec

__all__ = ["SuctionCandidates", "SuctionGraspSet", "load_suction_candidates"]


@dataclass(frozen=True)
class SuctionCandidates:
    """The cups that passed every active criterion (arrays over n candidates, metres, object frame)."""

    contacts: np.ndarray  # (n, 1, 3) float64: the lip's centre on the surface
    normals: np.ndarray  # (n, 1, 3) float64: the outward unit normal there (the sample's)
    approach: np.ndarray  # (n, 3) float64: unit, the grasp's +Z (into the part)
    free_rolls: np.ndarray  # (n, R) bool
    roll_angles_rad: np.ndarray  # (R,)
    seal_strain: np.ndarray  # (n,): the largest strain of the lip's springs (<= max_strain)
    tilt_deg: np.ndarray  # (n,): the approach's angle to the lip plane's normal
    labels: np.ndarray  # (n, 2) int32 (translation cluster, direction cluster); -1 before clustering
    medoids: np.ndarray  # (m,) int64, export order
    #: (n,) the load each cup resists over the load required, when criterion hold ran
    hold_margin: np.ndarray | None = None

    @property
    def midpoints(self) -> np.ndarray:
        """(n, 3): the contacts (what clustering and coverage read for either kind)."""
        mid: np.ndarray = self.contacts[:, 0]
        return mid

    @property
    def axes(self) -> np.ndarray:
        """(n, 3): the approaches."""
        return self.approach

    def __len__(self) -> int:
        return len(self.contacts)

    def arrays(self) -> dict[str, np.ndarray]:
        extra = {"hold_margin": self.hold_margin.astype(np.float64)} if self.hold_margin is not None else {}
        return {
            "contacts": self.contacts,
            "normals": self.normals,
            "midpoints": np.ascontiguousarray(self.midpoints),
            "axes": self.approach,
            "free_rolls": self.free_rolls,
            "roll_angles_rad": self.roll_angles_rad,
            "seal_strain": self.seal_strain,
            "tilt_deg": self.tilt_deg,
            "labels": self.labels.astype(np.int32),
            "medoids": self.medoids.astype(np.int64),
            **extra,
        }


def load_suction_candidates(path: str | os.PathLike[str]) -> SuctionCandidates:
    """Read a suction candidate NPZ back, checking shapes so that a damaged file fails with a clear reason."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise InvalidCandidatesError(f"cannot read candidates {path}: {exc}") from None
    required = ("contacts", "normals", "axes", "free_rolls", "roll_angles_rad", "seal_strain", "tilt_deg")
    missing = [k for k in required if k not in data]
    if missing:
        raise InvalidCandidatesError(f"suction candidates {path} lack " + ", ".join(missing))
    n, R = len(data["contacts"]), len(data["roll_angles_rad"])
    shapes = {"contacts": (n, 1, 3), "normals": (n, 1, 3), "axes": (n, 3), "free_rolls": (n, R)}
    shapes.update(seal_strain=(n,), tilt_deg=(n,))
    for key, shape in shapes.items():
        if data[key].shape != shape:
            raise InvalidCandidatesError(f"{key} must have shape {shape}, got {data[key].shape}", field=key)
    if "hold_margin" in data and data["hold_margin"].shape != (n,):
        raise InvalidCandidatesError(f"hold_margin must have shape {(n,)}", field="hold_margin")
    return SuctionCandidates(
        contacts=data["contacts"].astype(np.float64),
        normals=data["normals"].astype(np.float64),
        approach=data["axes"].astype(np.float64),
        free_rolls=data["free_rolls"].astype(bool),
        roll_angles_rad=data["roll_angles_rad"].astype(np.float64),
        seal_strain=data["seal_strain"].astype(np.float64),
        tilt_deg=data["tilt_deg"].astype(np.float64),
        labels=data.get("labels", np.full((n, 2), -1, dtype=np.int32)).astype(np.int32),
        medoids=data.get("medoids", np.zeros(0, dtype=np.int64)).astype(np.int64),
        hold_margin=data["hold_margin"].astype(np.float64) if "hold_margin" in data else None,
    )


@dataclass
class SuctionGraspSet:
    """The result of a suction run: the export (to_json) and its candidates (save_candidates), as GraspSet is for
    jaws."""

    object: dict[str, Any]
    gripper: SuctionSpec
    params: Params
    friction: float
    stats: dict[str, Any]
    grasps: list[dict[str, Any]]
    candidates: SuctionCandidates
    warnings: list[str] = field(default_factory=list)
    #: the part's mass (kg) that criterion hold used: given, or density x volume
    mass_kg: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "units": "m",
            "object": dict(self.object),
            "gripper": self.gripper.to_dict(),
            "params": self.params.to_dict(friction=self.friction, mass_kg=self.mass_kg),
            "stats": self.stats,
            "grasps": self.grasps,
        }

    def to_json_bytes(self) -> bytes:
        """Canonical bytes: the same inputs, parameters and seed give the same bytes (but for timings)."""
        return (json.dumps(self.to_json(), indent=1, allow_nan=False) + "\n").encode("utf-8")

    def save(self, path: str | os.PathLike[str]) -> None:
        write_atomic(path, self.to_json_bytes())

    def save_candidates(self, path: str | os.PathLike[str]) -> None:
        write_atomic(path, self.candidates_npz_bytes())

    def candidates_npz_bytes(self) -> bytes:
        """The candidate NPZ (module docstring) as bytes, as save_candidates writes it."""
        return npz_bytes(self.candidates.arrays())
