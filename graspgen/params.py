"""Run parameters (CONTRACT.md `params`) and the named tolerances of the kernels."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, ClassVar

from .errors import InvalidParameterError

__all__ = [
    "Params",
    "QualityOptions",
    "Tolerances",
    "TOLERANCES",
    "COLLISION_MODES",
    "HOLD_MODES",
    "SELECT_MODES",
    "STANDARD_GRAVITY",
]

COLLISION_MODES = ("swept", "paper")
#: criterion (e): "any" keeps candidates that hold the part against its load in every direction; "off" skips it
HOLD_MODES = ("any", "off")
#: which member of each final cluster is exported: the medoid (the paper) or the best-scoring member near it
SELECT_MODES = ("medoid", "best-near-medoid")
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
    #: relative guard band of the collision kernels' shortcuts (node bounds, radial bands, the half-turn symmetry):
    #: far beyond the rounding of their arithmetic, so that a shortcut never decides what the exact test would not
    guard: float = 1.0e-9
    #: absolute floor of that band, metres (for a part of zero extent)
    guard_floor: float = 1.0e-15


TOLERANCES = Tolerances()


def _option(
    default: Any,
    help: str,
    *,
    flag: str | None = None,
    choices: tuple[str, ...] | None = None,
    exclusive: str | None = None,
) -> Any:
    """A field that the command line offers (cli.py builds its options from these): `help` says what it is,
    `flag` when the option is not named after the field, `choices` for a closed set, `exclusive` names a group of
    options of which one at most may be given."""
    return field(default=default, metadata={"help": help, "flag": flag, "choices": choices, "exclusive": exclusive})


@dataclass(frozen=True)
class Params:
    """The run parameters (CONTRACT.md `params`), validated; the CLI's options are built from these fields."""

    points: int = _option(10_000, "target number of surface points")
    friction: float | None = _option(None, "friction coefficient (default: the gripper's)")
    safety_factor: float = _option(1.5, "friction cone divisor")
    rolls: int = _option(16, "roll angles about the closing axis")
    k1: int = _option(16, "translation clusters")
    k2: int = _option(4, "direction clusters per translation cluster")
    inside: bool = _option(False, "also inside grasps (fingers opening outwards)")
    collision: str = _option("swept", "collision model", choices=COLLISION_MODES)
    seed: int = _option(0, "seed of the sampling and the clustering")
    # criterion (e) needs the part's mass: given, or its density times the mesh volume
    mass_kg: float | None = _option(
        None, "the part's mass, kg (criterion (e) and --validate)", flag="--mass", exclusive="mass"
    )
    density: float | None = _option(None, "the part's density, kg/m^3 (mass = density x volume)", exclusive="mass")
    accel: float = _option(
        STANDARD_GRAVITY, "acceleration beyond gravity a held part resists in every direction, m/s^2"
    )
    hold: str = _option(
        "any", "criterion (e): any (needs the mass and the gripper's grip_force) or off", choices=HOLD_MODES
    )
    position_tolerance: float = _option(
        1.0e-3, "criterion (c) holds for every surface normal within this distance of a contact, m"
    )

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
        _choice(self, "hold")
        _choice(self, "collision")

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


#: members of its final cluster tried, nearest first, in place of an exported grasp that fails validation. Only
#: failing grasps cost more: a round simulates the next member of each, together, so a set that mostly fails pays
#: up to this many rounds. With 8 every validated export of bench_hold's parts holds (docs/benchmarks_quality.md)
REPAIR_LIMIT = 8


@dataclass(frozen=True)
class QualityOptions:
    """The options beyond the paper's method (docs/QUALITY.md); the defaults leave the export as the paper's method
    makes it. `select`: SELECT_MODES; `validate`: simulate every exported grasp in MuJoCo; `repair_limit`: members of
    its cluster tried in place of a grasp that fails the simulation; `sim_workers`: simulation processes (None: the
    CPUs)."""

    select: str = _option(
        "medoid",
        "medoid (the paper) or the best-scoring member near each medoid (docs/QUALITY.md)",
        choices=SELECT_MODES,
    )
    validate: bool = _option(
        False,
        "simulate every exported grasp in MuJoCo, nominally, at mass x1.5, at friction x0.8 and with soft friction "
        "at mass x1.5, and repair failures (needs the part's mass and the gripper's grip_force)",
    )
    repair_limit: int = REPAIR_LIMIT
    sim_workers: int | None = None

    #: the options a job (HTTP API) and the CLI take; repair_limit and sim_workers are the Python API's only (how a
    #: worker spends its CPUs is its own business)
    JOB_OPTIONS: ClassVar[tuple[str, ...]] = ("validate", "select")

    def __post_init__(self) -> None:
        _choice(self, "select")
        if not isinstance(self.validate, bool):
            raise InvalidParameterError(f"validate must be true or false, got {self.validate!r}", field="validate")
        r = self.repair_limit
        if isinstance(r, bool) or not isinstance(r, int) or not 0 <= r <= 64:
            raise InvalidParameterError(f"repair_limit must be an integer 0..64, got {r!r}", field="repair_limit")
        w = self.sim_workers
        if w is not None and (isinstance(w, bool) or not isinstance(w, int) or w < 1):
            raise InvalidParameterError(f"sim_workers must be a positive integer, got {w!r}", field="sim_workers")

    @property
    def needs_part(self) -> bool:
        """Whether a run needs the part beyond stored candidates: to simulate, or to score for the selection."""
        return self.validate or self.select != "medoid"

    @classmethod
    def split_job(cls, given: dict[str, Any] | None) -> tuple[dict[str, Any], QualityOptions]:
        """(the rest, the quality options) of a job's params, the options checked (InvalidParameterError)."""
        rest = dict(given or {})
        return rest, cls(**{k: rest.pop(k) for k in cls.JOB_OPTIONS if k in rest})

    def job_dict(self) -> dict[str, Any]:
        """The job options that differ from the defaults (how a job stores them: `validate` only when true, `select`
        only when not "medoid")."""
        return {k: getattr(self, k) for k in self.JOB_OPTIONS if getattr(self, k) != getattr(QualityOptions, k)}


def _int(p: Params, name: str, lo: int, hi: int) -> None:
    v = getattr(p, name)
    if isinstance(v, bool) or not isinstance(v, int):
        raise InvalidParameterError(f"{name} must be an integer, got {v!r}", field=name)
    if not lo <= v <= hi:
        raise InvalidParameterError(f"{name} must be between {lo} and {hi}, got {v}", field=name)


def _choice(p: Params | QualityOptions, name: str) -> None:
    """One of the field's `choices` (its metadata)."""
    v, choices = getattr(p, name), p.__dataclass_fields__[name].metadata["choices"]
    if v not in choices:
        raise InvalidParameterError(f"{name} must be one of {', '.join(choices)}, got {v!r}", field=name)


def _num(p: Params, name: str, *, lo: float, hi: float, lo_open: bool = False) -> None:
    v = getattr(p, name)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InvalidParameterError(f"{name} must be a finite number, got {v!r}", field=name)
    if (v <= lo if lo_open else v < lo) or v > hi:
        op = ">" if lo_open else ">="
        raise InvalidParameterError(f"{name} must be {op} {lo} and <= {hi}, got {v}", field=name)
