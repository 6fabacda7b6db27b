"""Run parameters (CONTRACT.md `params`), each declared once as a field with its type, default, range, choices and
help, and the named tolerances of the kernels."""

from __future__ import annotations

import functools
import inspect
import math
import types
from dataclasses import asdict, dataclass, field, fields
from typing import Any, ClassVar, Union, get_args, get_origin, get_type_hints

from .errors import InvalidParameterError

__all__ = [
    "Params",
    "QualityOptions",
    "ParamOption",
    "param_options",
    "param_option",
    "keyword_parameters",
    "from_keywords",
    "from_job",
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
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
) -> Any:
    """A run parameter, declared once: its type is the field's annotation (`T | None`: None is accepted and means the
    default's rule), `help` says what it is, `flag` names the CLI option when it is not named after the field,
    `choices` a closed set, `exclusive` a group of options of which one at most may be given, `ge` / `gt` and `le` its
    range (closed or open below, closed above). `__post_init__` checks these; the CLI's options (cli.py), the job
    params schema of the OpenAPI document (services/api/contract_schemas.py) and generate()'s keywords are built from
    them."""
    meta = {"help": help, "flag": flag, "choices": choices, "exclusive": exclusive, "ge": ge, "gt": gt, "le": le}
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class ParamOption:
    """One declared run parameter (a field made with `_option`) as the CLI, the API schema and validation read it."""

    name: str
    #: int, float, bool or str (the field's annotation without None)
    kind: type
    #: None is a value of the parameter (friction: the gripper's; mass_kg, density: not given)
    optional: bool
    default: Any
    help: str
    flag: str | None
    choices: tuple[str, ...] | None
    exclusive: str | None
    ge: float | None
    gt: float | None
    le: float | None


def param_options(cls: type) -> tuple[ParamOption, ...]:
    """The declared run parameters of a Params or QualityOptions (or a subclass), in field order."""
    return _param_options(cls)


# behind a typed function: functools.cache takes Hashable arguments, and mypy does not see a `type[Params]` as one
@functools.cache
def _param_options(cls: type) -> tuple[ParamOption, ...]:
    hints = get_type_hints(cls)
    out = []
    for f in fields(cls):
        if "help" not in f.metadata:
            continue  # a Python-API-only field (QualityOptions.repair_limit, sim_workers), checked by its class
        hint = hints[f.name]
        members = get_args(hint) if get_origin(hint) in (Union, types.UnionType) else (hint,)
        kinds = [t for t in members if t is not type(None)]
        if len(kinds) != 1 or kinds[0] not in (int, float, bool, str):
            raise TypeError(
                f"{cls.__name__}.{f.name}: a run parameter is int, float, bool or str (or None), not {hint}"
            )
        m = f.metadata
        out.append(
            ParamOption(
                name=f.name,
                kind=kinds[0],
                optional=len(kinds) < len(members),
                default=f.default,
                help=m["help"],
                flag=m["flag"],
                choices=m["choices"],
                exclusive=m["exclusive"],
                ge=m["ge"],
                gt=m["gt"],
                le=m["le"],
            )
        )
    return tuple(out)


def param_option(cls: type, name: str) -> ParamOption:
    """The declared run parameter `name` of `cls` (KeyError when there is none)."""
    for o in param_options(cls):
        if o.name == name:
            return o
    raise KeyError(name)


@dataclass(frozen=True)
class Params:
    """The run parameters (CONTRACT.md `params`), validated. Each field is declared once (`_option`): the CLI's
    options, the job params schema of the HTTP API, generate()'s keywords and the worker's run are built from them."""

    points: int = _option(10_000, "target number of surface points", ge=100, le=1_000_000)
    friction: float | None = _option(None, "friction coefficient (default: the gripper's)", gt=0, le=10)
    safety_factor: float = _option(1.5, "friction cone half-angle divisor", ge=1, le=100)
    # at most 64: one 64-bit roll mask per candidate
    rolls: int = _option(16, "roll angles 2 pi k / rolls about the closing axis tested per pair", ge=1, le=64)
    k1: int = _option(16, "translation clusters", ge=1, le=10_000)
    k2: int = _option(4, "direction clusters per translation cluster", ge=1, le=1_000)
    inside: bool = _option(False, "also inside grasps (bores: fingers opening outwards)")
    collision: str = _option("swept", "collision model of criterion (d)", choices=COLLISION_MODES)
    seed: int = _option(0, "seed of the sampling and the clustering", ge=0, le=2**32 - 1)
    # criterion (e) needs the part's mass: given, or its density times the mesh volume
    mass_kg: float | None = _option(
        None, "the part's mass, kg (criterion (e) and validation)", flag="--mass", exclusive="mass", gt=0, le=100_000
    )
    density: float | None = _option(
        None, "the part's density, kg/m^3 (mass = density x volume)", exclusive="mass", ge=1, le=100_000
    )
    accel: float = _option(
        STANDARD_GRAVITY, "acceleration beyond gravity a held part resists in every direction, m/s^2", ge=0, le=1_000
    )
    hold: str = _option(
        "any", "criterion (e): any (needs the mass and the gripper's grip_force) or off", choices=HOLD_MODES
    )
    position_tolerance: float = _option(
        1.0e-3, "criterion (c) holds for every surface normal within this distance of a contact, m", ge=0, le=0.05
    )
    # suction cups only (CONTRACT.md "Suction cups"): None keeps the approaches along the surface normals
    max_tilt_deg: float | None = _option(
        None,
        "suction cups: also approaches tilted up to this angle from the surface normal, deg (criterion tilt)",
        ge=0,
        le=45,
    )

    def __post_init__(self) -> None:
        _check_options(self)

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
        coefficient, density x volume). `max_tilt_deg` only when given (a parallel gripper's export stays as it was
        before suction cups)."""
        d = asdict(self)
        if d["max_tilt_deg"] is None:
            del d["max_tilt_deg"]
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
        _check_options(self)
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


def keyword_parameters(*classes: type) -> list[inspect.Parameter]:
    """Keyword-only parameters, one per field of these dataclasses, with the field's annotation and default: the
    run-parameter keywords of generate()'s signature."""
    return [
        inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default, annotation=f.type)
        for cls in classes
        for f in fields(cls)
    ]


def from_keywords(caller: str, given: dict[str, Any], *ready: tuple[type, Any]) -> list[Any]:
    """For each (dataclass, ready instance or None): the ready instance, or the dataclass built from its fields among
    the keyword arguments `given` (the others keep their defaults). A keyword that is no field of any of them, or
    fields given beside a ready instance, is a TypeError naming `caller`, as Python says it of a keyword a function
    does not take."""
    known = {f.name: cls for cls, _ in ready for f in fields(cls)}
    unknown = [k for k in given if k not in known]
    if unknown:
        raise TypeError(f"{caller}() got an unexpected keyword argument {unknown[0]!r}")
    out = []
    for cls, obj in ready:
        mine = {k: v for k, v in given.items() if known[k] is cls}
        if obj is not None and mine:
            raise TypeError(
                f"{caller}() takes a ready {cls.__name__} or its fields as keywords, not both: {', '.join(mine)}"
            )
        out.append(obj if obj is not None else cls(**mine))
    return out


def from_job(
    stored: dict[str, Any] | None,
    params_cls: type[Params] = Params,
    options_cls: type[QualityOptions] = QualityOptions,
) -> tuple[Params, QualityOptions]:
    """A job's params dict (as the job service stores it: the Params fields and the job options) as Params and
    QualityOptions; a parameter the dict lacks (a job stored before it existed) takes its default. Unknown names and
    bad values raise InvalidParameterError."""
    rest, options = options_cls.split_job(stored)
    return params_cls.from_dict(rest), options


def _check_options(obj: Params | QualityOptions) -> None:
    """Every declared run parameter of `obj` against its type, choices and range; then the exclusive groups."""
    groups: dict[str, list[str]] = {}
    for o in param_options(type(obj)):
        v = getattr(obj, o.name)
        if v is None and o.optional:
            continue
        if o.exclusive:
            groups.setdefault(o.exclusive, []).append(o.name)
        if o.choices is not None:
            if v not in o.choices:
                raise InvalidParameterError(f"{o.name} must be one of {', '.join(o.choices)}, got {v!r}", field=o.name)
        elif o.kind is bool:
            if not isinstance(v, bool):
                raise InvalidParameterError(f"{o.name} must be true or false, got {v!r}", field=o.name)
        elif o.kind is int:
            _int(o, v)
        elif o.kind is float:
            _num(o, v)
        elif not isinstance(v, str):
            raise InvalidParameterError(f"{o.name} must be a string, got {v!r}", field=o.name)
    for names in groups.values():
        if len(names) > 1:
            raise InvalidParameterError(f"give {' or '.join(names)}, not both", field=names[-1])


def _int(o: ParamOption, v: Any) -> None:
    if isinstance(v, bool) or not isinstance(v, int):
        raise InvalidParameterError(f"{o.name} must be an integer, got {v!r}", field=o.name)
    if not _in_range(o, v):
        if o.ge is not None and o.le is not None:
            raise InvalidParameterError(f"{o.name} must be between {o.ge} and {o.le}, got {v}", field=o.name)
        raise InvalidParameterError(f"{o.name} must be {_range_text(o, int)}, got {v}", field=o.name)


def _num(o: ParamOption, v: Any) -> None:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InvalidParameterError(f"{o.name} must be a finite number, got {v!r}", field=o.name)
    if not _in_range(o, v):
        raise InvalidParameterError(f"{o.name} must be {_range_text(o, float)}, got {v}", field=o.name)


def _in_range(o: ParamOption, v: float) -> bool:
    return (o.ge is None or v >= o.ge) and (o.gt is None or v > o.gt) and (o.le is None or v <= o.le)


def _range_text(o: ParamOption, kind: type) -> str:
    """The bounds as the parameter's type shows them: '>= 1.0 and <= 100.0'."""
    parts = [f"{op} {kind(b)}" for op, b in ((">=", o.ge), (">", o.gt), ("<=", o.le)) if b is not None]
    return " and ".join(parts)
