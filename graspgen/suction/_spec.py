"""SuctionSpec: a vacuum cup and the tool behind it (CONTRACT.md "Suction cups", all lengths in metres).

Geometry in the grasp frame (origin at the contact, the lip's centre on the surface; +Z the approach, into the part):
- the cup: a cylinder of radius `cup_radius` from the lip at z = 0 back to the cup's base at z = -cup_height (the
  bellows' travel);
- the tool behind it: `tool` = {"radius", "length"}, a cylinder on the Z axis from z = -cup_height back to
  z = -(cup_height + length); or `geometry` = {"units", "body"}: a closed body mesh in the grasp frame (the
  gripper_geometry rules for mesh files), which must lie behind the lip (z <= FRAME_TOLERANCE): a body reaching in
  front of the lip would press into every face the cup seals on.

Choices the contract leaves open:
- A tool (cylinder or body) is required: a cup is always carried by something, and criterion `collision` checks it.
  A spec that gives both `tool` and `geometry` is refused.
- A tool wider than the cup is accepted: real tools often are (a vacuum generator's housing behind a small cup);
  criterion `collision` decides where it fits, and the cup's lip still sits cup_height in front of it.
- `vacuum` is at most one standard atmosphere (101,325 Pa): a pump cannot hold a larger pressure difference against
  the ambient air.
- `max_strain` lies in (0, 1): the lip stretches or compresses by that fraction of its length.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ..errors import InvalidGripperError
from ..gripper import SLUG_PATTERN
from ..gripper_geometry import FRAME_TOLERANCE, BodyGeometry, load_body

__all__ = ["SuctionSpec", "ToolCylinder", "KIND", "MAX_VACUUM"]

KIND = "suction"
#: Pa: one standard atmosphere, the largest pressure difference a vacuum can hold against the ambient air
MAX_VACUUM = 101_325.0
#: metres: a cup or tool larger than this in any dimension is almost certainly given in millimetres
_MAX_LENGTH = 2.0
_REQUIRED = ("name", "cup_radius", "cup_height", "max_strain", "vacuum", "friction", "pregrasp_clearance")
_ORDER = ("name", "kind", "cup_radius", "cup_height", "max_strain", "vacuum", "friction", "tool", "geometry")
_FIELDS = frozenset((*_ORDER, "pregrasp_clearance"))


@dataclass(frozen=True)
class ToolCylinder:
    """The cylinder behind the cup, on the grasp frame's Z axis from z = -cup_height to -(cup_height + length)."""

    radius: float
    length: float

    def to_dict(self) -> dict[str, float]:
        return {"radius": self.radius, "length": self.length}


@dataclass(frozen=True)
class SuctionSpec:
    """A suction cup and its tool (module docstring), validated on construction; lengths in metres, `vacuum` in Pa.
    Exactly one of `tool` and `geometry` is set."""

    name: str
    cup_radius: float
    cup_height: float
    max_strain: float
    vacuum: float
    friction: float
    pregrasp_clearance: float
    tool: ToolCylinder | None = None
    geometry: BodyGeometry | None = None
    kind: str = KIND

    def __post_init__(self) -> None:
        if self.kind != KIND:
            raise InvalidGripperError(f"kind {self.kind!r} is not {KIND!r}", field="kind")
        if not isinstance(self.name, str) or not SLUG_PATTERN.match(self.name):
            raise InvalidGripperError(
                f"gripper name {self.name!r} is not a slug ([a-z0-9][a-z0-9._-]{{0,62}})", field="name"
            )
        for name in ("cup_radius", "cup_height", "max_strain", "vacuum", "friction"):
            _check_number(name, getattr(self, name), positive=True)
        _check_number("pregrasp_clearance", self.pregrasp_clearance, positive=False)
        for name in ("cup_radius", "cup_height", "pregrasp_clearance"):
            _check_length(name, getattr(self, name))
        if not self.max_strain < 1:
            raise InvalidGripperError(
                f"max_strain must be < 1 (a fraction of the lip's length: 0.1 = 10 %), got {self.max_strain}",
                field="max_strain",
            )
        if self.vacuum > MAX_VACUUM:
            raise InvalidGripperError(
                f"vacuum = {self.vacuum} Pa is more than one atmosphere ({MAX_VACUUM:g} Pa): it is the pressure "
                "difference under the sealed cup, in pascals",
                field="vacuum",
            )
        if self.friction > 10:
            raise InvalidGripperError(f"friction must be <= 10, got {self.friction}", field="friction")
        if (self.tool is None) == (self.geometry is None):
            raise InvalidGripperError(
                "a suction spec gives its tool as a cylinder (tool) or a body mesh (geometry), "
                + ("not both" if self.tool is not None else "and has neither"),
                field="geometry" if self.tool is not None else "tool",
            )
        if self.tool is not None:
            for key in ("radius", "length"):
                _check_number(f"tool.{key}", getattr(self.tool, key), positive=True)
                _check_length(f"tool.{key}", getattr(self.tool, key))
        if self.geometry is not None:
            front = float(self.geometry.vertices[:, 2].max())
            if front > FRAME_TOLERANCE:
                raise InvalidGripperError(
                    f"the body file {self.geometry.files['body']!r} reaches z = {front * 1e3:.4g} mm: in the grasp "
                    "frame the lip lies at z = 0 and the tool behind it (z <= 0); move the origin to the lip's centre",
                    field="geometry.body",
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
    ) -> SuctionSpec:
        """A checked spec from its JSON object. A spec with `geometry` needs its body file: as bytes by name
        (`files`, exactly that name: HTTP multipart) or read relative to `base_dir` (the spec file's folder)."""
        if not isinstance(data, dict):
            raise InvalidGripperError("a gripper spec must be a JSON object")
        if data.get("kind") != KIND:
            raise InvalidGripperError(f"kind {data.get('kind')!r} is not a suction cup (kind {KIND!r})", field="kind")
        missing = [k for k in _REQUIRED if k not in data]
        if missing:
            raise InvalidGripperError("suction spec lacks " + ", ".join(missing), field=missing[0])
        unknown = sorted(set(data) - _FIELDS)
        if unknown:
            raise InvalidGripperError(
                "suction spec has unknown fields "
                + ", ".join(unknown)
                + " (it takes "
                + ", ".join(sorted(_FIELDS))
                + ")",
                field=unknown[0],
            )
        if "tool" in data and "geometry" in data:
            raise InvalidGripperError(
                "the spec gives both tool and geometry: the tool behind the cup is a cylinder (tool) or a body mesh "
                "(geometry), never both",
                field="geometry",
            )
        if "geometry" not in data and files:
            name = sorted(files)[0]
            raise InvalidGripperError(
                f"file {name!r} was given but the spec has no geometry (a cylinder tool takes no files)", field=name
            )
        kwargs = {k: data[k] for k in _REQUIRED}
        tool = _tool(data["tool"]) if "tool" in data else None
        if "geometry" not in data:
            return cls(**kwargs, tool=tool)
        # the scalar fields first (a bad name or radius is named before any mesh is read), with a stand-in tool
        cls(**kwargs, tool=ToolCylinder(1.0, 1.0))
        body = load_body(data["geometry"], files=files, base_dir=base_dir, max_decoded_bytes=max_decoded_bytes)
        return cls(**kwargs, geometry=body)

    @classmethod
    def load(cls, path: str | Path) -> SuctionSpec:
        """The spec in the JSON file `path`; a body mesh is read beside it."""
        return cls.from_dict(read_spec_json(path), base_dir=Path(path).parent)

    def to_dict(self) -> dict[str, Any]:
        """The spec as JSON in the contract's key order; a body `geometry` with `sha256` {file name: hex}."""
        d: dict[str, Any] = {
            "name": self.name,
            "kind": self.kind,
            "cup_radius": self.cup_radius,
            "cup_height": self.cup_height,
            "max_strain": self.max_strain,
            "vacuum": self.vacuum,
            "friction": self.friction,
        }
        if self.tool is not None:
            d["tool"] = self.tool.to_dict()
        if self.geometry is not None:
            d["geometry"] = self.geometry.to_dict()
        d["pregrasp_clearance"] = self.pregrasp_clearance
        return d

    def with_friction(self, friction: float | None) -> SuctionSpec:
        return self if friction is None else replace(self, friction=friction)

    # -- derived quantities ---------------------------------------------------------------------------------------
    @property
    def vacuum_force(self) -> float:
        """N: the vacuum's pull on the part through a sealed lip, vacuum x pi cup_radius^2 (Schmalz: F = dp A)."""
        return self.vacuum * math.pi * self.cup_radius**2

    @property
    def round_tool(self) -> bool:
        """Whether every roll about +Z gives the same solid (a cylinder tool): then all rolls are free or none."""
        return self.geometry is None


def read_spec_json(path: str | Path) -> Any:
    """The JSON value in the spec file `path`, or InvalidGripperError saying why it cannot be read."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise InvalidGripperError(f"cannot read gripper spec {path}: {exc.strerror}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidGripperError(f"gripper spec {path} is not valid JSON: {exc}") from None


def _tool(value: Any) -> ToolCylinder:
    if not isinstance(value, dict) or set(value) != {"radius", "length"}:
        raise InvalidGripperError(
            'tool must be {"radius": m, "length": m} (the cylinder behind the cup), got ' + json.dumps(value)[:80],
            field="tool",
        )
    return ToolCylinder(radius=value["radius"], length=value["length"])


def _check_number(field: str, value: Any, *, positive: bool) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise InvalidGripperError(f"{field} must be a finite number, got {value!r}", field=field)
    if positive and not value > 0:
        raise InvalidGripperError(f"{field} must be > 0, got {value}", field=field)
    if not positive and value < 0:
        raise InvalidGripperError(f"{field} must be >= 0, got {value}", field=field)


def _check_length(field: str, value: float) -> None:
    if value > _MAX_LENGTH:
        raise InvalidGripperError(
            f"{field} = {value} m is larger than {_MAX_LENGTH} m: lengths are in metres", field=field
        )
