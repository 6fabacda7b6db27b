"""Parallel-jaw gripper spec (CONTRACT.md, all lengths in metres) and its boxes in the grasp frame."""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from .collision import Box, GripperSolids
from .errors import InvalidGripperError

__all__ = ["GripperSpec", "Box", "SLUG_PATTERN"]

SLUG_PATTERN = re.compile(r"^[a-z0-9][a-z0-9._-]{0,62}$")

_REQUIRED = ("name", "stroke", "finger_width", "finger_depth", "finger_thickness", "friction", "pregrasp_clearance")
_OPTIONAL = ("min_width", "palm_depth", "palm_width", "grip_force")
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

    def __post_init__(self) -> None:
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
    def from_dict(cls, data: Any) -> GripperSpec:
        if not isinstance(data, dict):
            raise InvalidGripperError("a gripper spec must be a JSON object")
        missing = [k for k in _REQUIRED if k not in data]
        if missing:
            raise InvalidGripperError("gripper spec lacks " + ", ".join(missing), field=missing[0])
        unknown = sorted(set(data) - set(_REQUIRED) - set(_OPTIONAL))
        if unknown:
            raise InvalidGripperError("gripper spec has unknown fields " + ", ".join(unknown), field=unknown[0])
        kwargs = {k: data[k] for k in (*_REQUIRED, *_OPTIONAL) if k in data and data[k] is not None}
        return cls(**kwargs)

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
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if d["grip_force"] is None:
            del d["grip_force"]  # optional: a spec without it exports as before
        return d

    def with_friction(self, friction: float | None) -> GripperSpec:
        if friction is None:
            return self
        return GripperSpec(**{**self.to_dict(), "friction": friction})

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
