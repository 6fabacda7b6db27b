"""Parallel-jaw gripper spec (CONTRACT.md, all lengths in metres): the contract's boxes, or finger and body meshes
from CAD (`geometry`, graspgen/gripper_geometry.py).

A spec has either the box fields (finger_width, finger_depth, finger_thickness, palm_depth, palm_width) or
`geometry`, never both. A geometry spec still has the box attributes that code written for boxes reads, derived from
the meshes: finger_thickness, finger_width, finger_depth are the +X finger mesh's bounding-box extents along X, Y, Z
(a box that encloses the finger, not centred on its frame's origin in general), palm_depth is 0 and palm_width the
finger's width. They are not part of the spec (`to_dict` leaves them out) and are not the geometry: what reads the
real fingers and body reads `geometry`.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from .collision import Box, GripperSolids
from .errors import InvalidGripperError
from .gripper_geometry import GripperGeometry, load_geometry

__all__ = ["GripperSpec", "GripperGeometry", "Box", "SLUG_PATTERN", "BOX_FIELDS", "KIND"]

SLUG_PATTERN = re.compile(r"^[a-z0-9][a-z0-9._-]{0,62}$")

_REQUIRED = ("name", "stroke", "finger_width", "finger_depth", "finger_thickness", "friction", "pregrasp_clearance")
_OPTIONAL = ("min_width", "palm_depth", "palm_width", "grip_force")
#: the box fields, which a spec with `geometry` must not have
BOX_FIELDS = ("finger_width", "finger_depth", "finger_thickness", "palm_depth", "palm_width")
_GEOMETRY_REQUIRED = ("name", "stroke", "friction", "pregrasp_clearance", "geometry")
_GEOMETRY_OPTIONAL = ("min_width", "grip_force")
#: the only kind this class is; other kinds (suction) have their own spec class
KIND = "parallel"
#: a gripper larger than this in any dimension is almost certainly given in millimetres
_MAX_LENGTH = 2.0
#: newtons per finger; industrial parallel grippers stay well below this
_MAX_FORCE = 100_000.0


@dataclass(frozen=True)
class GripperSpec:
    name: str
    stroke: float
    finger_width: float
    finger_depth: float
    finger_thickness: float
    friction: float
    pregrasp_clearance: float
    min_width: float = 0.0
    palm_depth: float = 0.0
    palm_width: float | None = None
    #: force each finger presses with (N); criterion (e) and the physics validation need it
    grip_force: float | None = None
    #: the finger and body meshes (CONTRACT.md "Gripper geometry from CAD"); None for the contract's boxes. With it,
    #: the box fields above are derived from the finger mesh's bounding box (module docstring)
    geometry: GripperGeometry | None = None
    #: "parallel" when the spec names its kind (kept in to_dict); None when it leaves the default
    kind: str | None = None

    def __post_init__(self) -> None:
        if self.kind is not None and self.kind != KIND:
            raise InvalidGripperError(f"kind {self.kind!r} is not {KIND!r}", field="kind")
        if self.geometry is not None:
            extents = self.geometry.finger.extents
            for name, value in zip(("finger_thickness", "finger_width", "finger_depth"), extents, strict=True):
                object.__setattr__(self, name, float(value))
            object.__setattr__(self, "palm_depth", 0.0)
            object.__setattr__(self, "palm_width", self.finger_width)
        if self.palm_width is None:
            object.__setattr__(self, "palm_width", self.finger_width)
        if not isinstance(self.name, str) or not SLUG_PATTERN.match(self.name):
            raise InvalidGripperError(
                f"gripper name {self.name!r} is not a slug ([a-z0-9][a-z0-9._-]{{0,62}})", field="name"
            )
        for field in ("stroke", "finger_width", "finger_depth", "finger_thickness", "palm_width", "friction"):
            _check_number(field, getattr(self, field), positive=True)
        for field in ("min_width", "palm_depth", "pregrasp_clearance"):
            _check_number(field, getattr(self, field), positive=False)
        if self.grip_force is not None:
            _check_number("grip_force", self.grip_force, positive=True)
            if self.grip_force > _MAX_FORCE:
                raise InvalidGripperError(
                    f"grip_force = {self.grip_force} N is more than {_MAX_FORCE:g} N per finger", field="grip_force"
                )
        for field in ("stroke", "finger_width", "finger_depth", "finger_thickness", "palm_width", "palm_depth"):
            if getattr(self, field) > _MAX_LENGTH:
                raise InvalidGripperError(
                    f"{field} = {getattr(self, field)} m is larger than {_MAX_LENGTH} m: lengths are in metres",
                    field=field,
                )
        if not self.stroke > self.min_width:
            raise InvalidGripperError(
                f"stroke ({self.stroke} m) must be larger than min_width ({self.min_width} m)", field="stroke"
            )

    # -- construction -------------------------------------------------------------------------------------------
    @classmethod
    def from_dict(
        cls,
        data: Any,
        *,
        files: Mapping[str, bytes] | None = None,
        base_dir: str | Path | None = None,
        max_decoded_bytes: int | None = None,
    ) -> GripperSpec:
        """A checked spec from its JSON object. A spec with `geometry` needs its mesh files: as bytes by the names
        the geometry gives (`files`, exactly those: HTTP multipart) or read relative to `base_dir` (the spec file's
        folder: `load`). `max_decoded_bytes` bounds each mesh file's decoded arrays (graspgen.limits)."""
        if not isinstance(data, dict):
            raise InvalidGripperError("a gripper spec must be a JSON object")
        kind = data.get("kind")
        if "kind" in data and kind != KIND:
            raise InvalidGripperError(f"kind {kind!r} is not a parallel gripper (kind {KIND!r})", field="kind")
        if "geometry" in data:
            return cls._from_geometry_dict(data, files=files, base_dir=base_dir, max_decoded_bytes=max_decoded_bytes)
        if files:
            name = sorted(files)[0]
            raise InvalidGripperError(
                f"file {name!r} was given but the spec has no geometry (a box spec takes no files)", field=name
            )
        data = {k: v for k, v in data.items() if k != "kind"}
        missing = [k for k in _REQUIRED if k not in data]
        if missing:
            raise InvalidGripperError("gripper spec lacks " + ", ".join(missing), field=missing[0])
        unknown = sorted(set(data) - set(_REQUIRED) - set(_OPTIONAL))
        if unknown:
            raise InvalidGripperError("gripper spec has unknown fields " + ", ".join(unknown), field=unknown[0])
        kwargs = {k: data[k] for k in (*_REQUIRED, *_OPTIONAL) if k in data and data[k] is not None}
        return cls(**kwargs, kind=kind)

    @classmethod
    def _from_geometry_dict(
        cls,
        data: dict[str, Any],
        *,
        files: Mapping[str, bytes] | None,
        base_dir: str | Path | None,
        max_decoded_bytes: int | None,
    ) -> GripperSpec:
        both = [k for k in BOX_FIELDS if k in data]
        if both:
            raise InvalidGripperError(
                f"the spec gives both geometry and box fields ({', '.join(both)}): a spec has either the box fields "
                "or geometry, never both",
                field=both[0],
            )
        missing = [k for k in _GEOMETRY_REQUIRED if k not in data]
        if missing:
            raise InvalidGripperError("gripper spec lacks " + ", ".join(missing), field=missing[0])
        unknown = sorted(set(data) - set(_GEOMETRY_REQUIRED) - set(_GEOMETRY_OPTIONAL) - {"kind"})
        if unknown:
            raise InvalidGripperError("gripper spec has unknown fields " + ", ".join(unknown), field=unknown[0])
        kwargs = {k: data[k] for k in (*_GEOMETRY_REQUIRED, *_GEOMETRY_OPTIONAL) if data.get(k) is not None}
        del kwargs["geometry"]
        # the scalar fields first (a bad name or stroke is named before any mesh is read); the box fields are
        # placeholders that __post_init__ replaces by the finger's extents
        placeholder: dict[str, Any] = dict.fromkeys(("finger_width", "finger_depth", "finger_thickness"), 1.0)
        cls(**kwargs, **placeholder, kind=data.get("kind"))
        geometry = load_geometry(data["geometry"], files=files, base_dir=base_dir, max_decoded_bytes=max_decoded_bytes)
        return cls(**kwargs, **placeholder, geometry=geometry, kind=data.get("kind"))

    @classmethod
    def load(cls, path: str | Path) -> GripperSpec:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise InvalidGripperError(f"cannot read gripper spec {path}: {exc.strerror}") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InvalidGripperError(f"gripper spec {path} is not valid JSON: {exc}") from None
        return cls.from_dict(data, base_dir=Path(path).parent)

    def to_dict(self) -> dict[str, Any]:
        """The spec as JSON: a box spec with its defaults filled in; a geometry spec without the derived box fields,
        its `geometry` as given plus `sha256` {file name: hex}. `kind` only when the spec gave it."""
        if self.geometry is not None:
            d: dict[str, Any] = {"name": self.name}
            if self.kind is not None:
                d["kind"] = self.kind
            d.update(
                stroke=self.stroke,
                min_width=self.min_width,
                friction=self.friction,
                pregrasp_clearance=self.pregrasp_clearance,
            )
            if self.grip_force is not None:
                d["grip_force"] = self.grip_force
            d["geometry"] = self.geometry.to_dict()
            return d
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("geometry", "kind")}
        if d["grip_force"] is None:
            del d["grip_force"]  # optional: a spec without it exports as before
        if self.kind is not None:
            d = {"name": d.pop("name"), "kind": self.kind, **d}
        return d

    def with_friction(self, friction: float | None) -> GripperSpec:
        if friction is None:
            return self
        return replace(self, friction=friction)

    # -- geometry in the grasp frame (graspgen.collision.GripperSolids is the one description) ---------------------
    def solids(self) -> GripperSolids:
        """The gripper's solids in the grasp frame."""
        return GripperSolids.of(self)

    def open_width(self, width: float) -> float:
        """Pre-grasp opening for a contact distance `width`: min(width + clearance, stroke)."""
        return self.solids().open_width(width)

    def finger_boxes(self, width: float) -> tuple[Box, Box]:
        """The two finger boxes at closing width `width`, inner faces at x = -+width/2."""
        return self.solids().fingers(width)

    def palm_box(self) -> Box | None:
        return self.solids().palm

    def boxes(self, width: float) -> list[Box]:
        return self.solids().boxes(width)


def _check_number(field: str, value: Any, *, positive: bool) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise InvalidGripperError(f"{field} must be a finite number, got {value!r}", field=field)
    if positive and not value > 0:
        raise InvalidGripperError(f"{field} must be > 0, got {value}", field=field)
    if not positive and value < 0:
        raise InvalidGripperError(f"{field} must be >= 0, got {value}", field=field)
