"""Run parameters (CONTRACT.md `params`) and the named tolerances of the kernels."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

from .errors import InvalidParameterError

__all__ = ["Params", "Tolerances", "TOLERANCES", "COLLISION_MODES", "HOLD_MODES", "STANDARD_GRAVITY"]

COLLISION_MODES = ("swept", "paper")
#: criterion (e): "any" keeps candidates that hold the part against its load in every direction; "off" skips it
HOLD_MODES = ("any", "off")
#: m/s^2
STANDARD_GRAVITY = 9.81


@dataclass(frozen=True)
class Tolerances:
    """Every geometric tolerance in one place (metres unless named otherwise)."""

    #: the paper's inner cuboid is longer than the contact distance by this much on each side, so that the
    #: contact points themselves (and their immediate neighbours on the surface) never count as collisions
    inner_margin: float = 1.0e-3
    #: points closer than this to a finger's contact plane count as the contact surface, not as an obstacle
    contact_slack: float = 1.0e-6
    #: pairs closer than this are the same point, never a grasp
    min_pair_distance: float = 1.0e-9


TOLERANCES = Tolerances()


@dataclass(frozen=True)
class Params:
    points: int = 10_000
    friction: float | None = None  # None: the gripper's own coefficient
    safety_factor: float = 1.5
    rolls: int = 16
    k1: int = 16
    k2: int = 4
    inside: bool = False
    collision: str = "swept"
    seed: int = 0
    #: the part's mass (kg), or its density (kg/m^3) times the mesh volume; criterion (e) needs one of them
    mass_kg: float | None = None
    density: float | None = None
    #: acceleration (m/s^2) on top of gravity that a held part must resist in every direction
    accel: float = STANDARD_GRAVITY
    hold: str = "any"
    #: criterion (c) holds for every surface normal within this distance (m) of each contact
    position_tolerance: float = 1.0e-3

    def __post_init__(self) -> None:
        _int(self, "points", 100, 1_000_000)
        _int(self, "rolls", 1, 64)  # one 64-bit roll mask per candidate
        _int(self, "k1", 1, 10_000)
        _int(self, "k2", 1, 1_000)
        _int(self, "seed", 0, 2**32 - 1)
        if self.friction is not None:
            _num(self, "friction", lo=0.0, lo_open=True, hi=10.0)
        _num(self, "safety_factor", lo=1.0, hi=100.0)
        if not isinstance(self.inside, bool):
            raise InvalidParameterError(f"inside must be true or false, got {self.inside!r}", field="inside")
        if self.mass_kg is not None:
            _num(self, "mass_kg", lo=0.0, lo_open=True, hi=100_000.0)
        if self.density is not None:
            _num(self, "density", lo=1.0, hi=100_000.0)
        if self.mass_kg is not None and self.density is not None:
            raise InvalidParameterError("give mass_kg or density, not both", field="density")
        _num(self, "accel", lo=0.0, hi=1_000.0)
        _num(self, "position_tolerance", lo=0.0, hi=0.05)
        if self.hold not in HOLD_MODES:
            raise InvalidParameterError(f"hold must be one of {', '.join(HOLD_MODES)}, got {self.hold!r}", field="hold")
        if self.collision not in COLLISION_MODES:
            raise InvalidParameterError(
                f"collision must be one of {', '.join(COLLISION_MODES)}, got {self.collision!r}", field="collision"
            )

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> Params:
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise InvalidParameterError("unknown parameters " + ", ".join(unknown), field=unknown[0])
        return cls(**data)

    def to_dict(self, *, friction: float | None = None, mass_kg: float | None = None) -> dict[str, Any]:
        """The parameters as exported; `friction` and `mass_kg`: the values the run resolved (the gripper's
        coefficient, density x volume)."""
        d = asdict(self)
        if friction is not None:
            d["friction"] = friction
        if mass_kg is not None:
            d["mass_kg"] = mass_kg
        return d


def _int(p: Params, name: str, lo: int, hi: int) -> None:
    v = getattr(p, name)
    if isinstance(v, bool) or not isinstance(v, int):
        raise InvalidParameterError(f"{name} must be an integer, got {v!r}", field=name)
    if not lo <= v <= hi:
        raise InvalidParameterError(f"{name} must be between {lo} and {hi}, got {v}", field=name)


def _num(p: Params, name: str, *, lo: float, hi: float, lo_open: bool = False) -> None:
    v = getattr(p, name)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InvalidParameterError(f"{name} must be a finite number, got {v!r}", field=name)
    if (v <= lo if lo_open else v < lo) or v > hi:
        op = ">" if lo_open else ">="
        raise InvalidParameterError(f"{name} must be {op} {lo} and <= {hi}, got {v}", field=name)
