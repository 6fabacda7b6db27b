"""Physics validation of grasps in MuJoCo: close the gripper on the part, lift it against gravity, shake it.

The simulation runs in the gripper's frame, which is the grasp frame of the contract (origin at the contact
midpoint, +X the closing axis, +Z the approach direction, palm at -Z). The gripper stays put; the part is a free body
placed at `inv(T_object_grasp)`. Lifting and shaking the gripper with an acceleration `a(t)` is, in the gripper's
frame, the same as loading the part with the fictitious force `-m a(t)` (translations only, so there are no
rotational fictitious forces); together with gravity the part feels `m (g - a(t))` at its centre of mass. That keeps
one static MuJoCo model per part and gripper, with exact contact kinematics, and lets every grasp run on its own
`MjData` in a thread of its own (mj_step releases the GIL).

At the pick gravity acts along the grasp frame's +Z: the gripper came down along +Z onto the part and lifts it
along -Z, the usual top-down pick. Each grasp goes through

1. approach: the open gripper (pre-grasp width) comes in along +Z from clear of the part; any penetration deeper
   than `approach_tolerance` on the way or at the pose -> `collision`, confirmed against the part's own surface
   when the geometry is a decomposition (its pieces are larger than the part in the concavities);
2. close: both fingers pushed with the grip force (coupled like a real parallel gripper); either finger without a
   contact afterwards -> `no_contact`;
3. lift: the load ramps up to gravity plus the lift acceleration, then holds;
4. turn (only under a `Perturbation` with another gravity direction): the robot turns the part, so the load m g
   swings from +Z to that direction of the grasp frame over `turn_time` (slowly: the rotational fictitious forces,
   well under 1 m/s^2 at a few cm from the wrist, are left out), then rests there;
5. shake: one sine period of acceleration along each of the shake directions;

losing either finger's contact (or the part moving more than `drop_distance`) -> `dropped`; the contact midpoint
moving more than `slip_limit` or the part turning more than `rotation_limit_deg` relative to the fingers ->
`slipped`; otherwise a success. Every constant is a field of `SimConstants`. Friction is MuJoCo's elliptic cone
with its no-slip iterations: without them the soft contacts let a held part creep at a steady rate under any
sustained load inside the cone (grasps turned 10-13 degrees in a second), which static friction does not.

Collision geometry of the part: a convex decomposition (CoACD), or the part itself when it is convex; if the
decomposition is unavailable or fails, the convex hull, and `SimPart.note` says so. A grasp whose pads bear on the
decomposition's slack (a piece bridging a groove: `SimResult.bearing_gap_mm` above `bearing_tolerance`) runs again on
a decomposition twice as fine (`SimPart.refined`, in `simulate_perturbed`). The centre of mass and the shape
of the inertia come from the mesh volume (trimesh's mass properties), scaled to the part's real mass (`mass_kg`) or to
a density; the grip force is the gripper's (`GripperSpec.grip_force`) or given. Neither has a default: a validation
with a guessed mass or force tells nothing about the real pick.

The gripper: box fingers and a box palm from the spec's box fields; for a spec with `geometry` (CONTRACT.md "Gripper
geometry from CAD") its meshes (`SimGripper`). Each finger body is the finger frame and carries the convex pieces of
its mesh (each closed shell of the mesh on its own: a convex shell is one piece, any other is decomposed by CoACD as
the part is), the -X finger's turned 180 degrees about Z; the body's pieces are static geoms of the grasp frame that
take the palm's role (the approach, a piece of the part reaching into them at the grasp). The approach starts below
the gripper's highest point and confirms a collision against the exact meshes (meshsweep.SweptMesh: each surface
sample against the open fingers and the body moved along +Z into place, eroded by `approach_tolerance`). Friction,
torsion and the joints are the box gripper's.

A `Perturbation` (mass scale, friction, gravity direction after the pick, shake amplitude and directions) changes one
simulation; `perturbation_set(seed)` is the standard set the quality benchmark checks every exported grasp against.
"""

from __future__ import annotations

import hashlib
import math
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Protocol, TypeVar, cast

import numpy as np
import numpy.typing as npt
import trimesh

from .errors import InvalidParameterError
from .gripper import GripperSpec
from .meshsweep import SweptMesh

__all__ = [
    "shake_directions_across",
    "SimConstants",
    "SIM",
    "DEFAULT_DENSITY",
    "REASONS",
    "Perturbation",
    "NOMINAL",
    "perturbation_set",
    "SimPart",
    "SimGripper",
    "SimResult",
    "prepare_part",
    "mass_properties",
    "placement_error",
    "load_schedule",
    "simulate_grasp",
    "simulate_grasps",
    "simulate_perturbed",
    "first_failures",
    "check_validation_inputs",
    "validation_set",
    "summarise",
]

#: kg/m^3; steel. Not a default of this module (prepare_part needs the real mass or a density): the pipeline's
#: fallback while it still passes a density
DEFAULT_DENSITY = 7850.0

#: failure reasons, in the order the stages can produce them
REASONS = ("collision", "no_contact", "dropped", "slipped")


@dataclass(frozen=True)
class SimConstants:
    """Every constant of the simulation in one place (SI units: m, s, kg, N)."""

    #: integration step; 1 ms keeps the stiff pad contacts of gram-scale parts stable
    timestep: float = 1.0e-3
    #: mass of each finger (kg)
    finger_mass: float = 0.05
    #: viscous damping of the finger joints (N s/m): closing speed grip_force / finger_damping = 0.2 m/s
    finger_damping: float = 100.0
    #: standard gravity (m/s^2), along the grasp frame's +Z at the pick
    gravity: float = 9.81
    #: time to close the fingers and let the part settle (s)
    close_time: float = 0.25
    #: the lift's acceleration on top of gravity (m/s^2) and the time over which the load ramps up (s)
    lift_acceleration: float = 3.0
    lift_time: float = 0.2
    #: time holding the part at rest after the lift (s)
    hold_time: float = 0.2
    #: time the robot takes to turn the part when a perturbation moves gravity away from +Z (s, for 90 degrees;
    #: a half turn takes twice as long), followed by another hold_time at rest
    turn_time: float = 0.3
    #: shaking: peak acceleration (m/s^2) and frequency (Hz) of one sine period per direction
    shake_acceleration: float = 5.0
    shake_frequency: float = 4.0
    #: shake directions in the grasp frame: along the closing axis, across it, along the approach, and a diagonal
    shake_directions: tuple[tuple[float, float, float], ...] = (
        (1.0, 0.0, 0.0),
        (0.0, 1.0, 0.0),
        (0.0, 0.0, 1.0),
        (0.0, 0.7071067811865476, -0.7071067811865476),
    )
    #: Coulomb friction pad/part is the gripper's (or the job's) coefficient; torsional friction models a pad
    #: patch of this radius (m): MuJoCo's torsional coefficient is friction * radius
    patch_radius: float = 2.0e-3
    #: contact softness (MuJoCo solref time constant, s, and damping ratio): twice the time step, the stiffest MuJoCo
    #: keeps stable; softer contacts let gram-scale parts (a 1 g pin under 20 N) spin out between the pads
    solref: tuple[float, float] = (0.002, 1.0)
    #: MuJoCo's no-slip post-processing iterations (0: off): the soft contact model lets a part creep slowly under
    #: any sustained tangential load inside the friction cone, which static friction does not
    noslip_iterations: int = 20
    #: approach: step of the sweep (m) and the penetration forgiven (m): the decomposition is a little larger
    #: than the part, and the candidates' own collision check has already been exact on the sampled surface
    approach_step: float = 1.0e-3
    approach_tolerance: float = 1.0e-3
    #: a convex piece reaching deeper than this into the palm at the grasp, before the fingers close, is the
    #: decomposition's slack (the exported grasp's palm is clear of the part's own triangles): the grasp runs on
    #: without the palm. MuJoCo resolves any such penetration at once: 0.58 mm flung a tless_13 part 2.8 mm and
    #: 3.7 degrees before either finger touched it (tests/graspgen/test_physics.py checks a 0.5 mm piece)
    palm_start_tolerance: float = 0.05e-3
    #: samples of the part's surface that confirm an approach collision with a convex piece (about 0.2 mm apart on
    #: a 100 cm^2 part)
    surface_samples: int = 200_000
    #: outcome thresholds: contact midpoint displacement (m), rotation (deg), displacement that means dropped (m)
    slip_limit: float = 5.0e-3
    rotation_limit_deg: float = 10.0
    drop_distance: float = 0.02
    #: either finger out of contact for longer than this (s) after closing -> dropped
    lost_contact_time: float = 0.02
    #: the outcome is checked (and the load updated) every this many steps
    check_steps: int = 5
    #: seeded placement error of the part at the start (m, deg), as a real robot's pose error
    pose_noise: float = 2.0e-4
    pose_noise_deg: float = 0.2
    #: convex decomposition (CoACD): concavity threshold, hull limit and a fast search
    coacd_threshold: float = 0.08
    coacd_max_hulls: int = 24
    #: the pads must bear on the part, not on the decomposition's slack: a grasp whose pads bear farther than this
    #: (m) outside the part's own surface (SimResult.bearing_gap_mm) under any perturbation is simulated again on a
    #: finer decomposition (threshold halved, twice the hulls), at most `coacd_refinements` times. The pieces of a
    #: grooved part bridge its grooves: the pepper's pads bore up to 1.5 mm outside it at 0.08, within 0.3 mm at
    #: 0.04 (docs/HOLD.md, "The simulation's part")
    bearing_tolerance: float = 0.5e-3
    coacd_refinements: int = 1
    coacd_options: tuple[tuple[str, int], ...] = (
        ("mcts_iterations", 40),
        ("mcts_nodes", 10),
        ("mcts_max_depth", 2),
        ("resolution", 1000),
        ("preprocess_resolution", 30),
    )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


SIM = SimConstants()

_AXES = {"+X": (1.0, 0.0, 0.0), "-X": (-1.0, 0.0, 0.0), "+Y": (0.0, 1.0, 0.0), "-Y": (0.0, -1.0, 0.0)}
_AXES.update({"+Z": (0.0, 0.0, 1.0), "-Z": (0.0, 0.0, -1.0)})


@dataclass(frozen=True)
class Perturbation:
    """One variation of the simulation, to check that a grasp does not hold only at one setting.

    `mass_scale` multiplies the part's mass and inertia; `friction` replaces the pad/part coefficient (None: the
    part's); `gravity` is the direction of the load m g in the grasp frame after the pick (unit 3-vector: +Z is the
    top-down pick itself, -Z the part resting on the palm after a half turn, +-X along the closing axis (one finger
    carries the part), +-Y across it); `shake_acceleration` (m/s^2) and `shake_directions` (grasp frame) replace
    SimConstants' shaking when given. `soft_friction` turns MuJoCo's no-slip iterations off: friction becomes the
    soft constraint that many simulator set-ups use, under which a part creeps slowly under any steady load inside
    the cone; a grasp with little friction to spare creeps past the limits."""

    name: str = "nominal"
    mass_scale: float = 1.0
    friction: float | None = None
    gravity: tuple[float, float, float] = (0.0, 0.0, 1.0)
    shake_acceleration: float | None = None
    shake_directions: tuple[tuple[float, float, float], ...] | None = None
    soft_friction: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mass_scale) and self.mass_scale > 0):
            raise InvalidParameterError(f"mass_scale must be positive, got {self.mass_scale!r}", field="mass_scale")
        if self.friction is not None and not (math.isfinite(self.friction) and self.friction > 0):
            raise InvalidParameterError(f"friction must be positive, got {self.friction!r}", field="friction")
        g = np.asarray(self.gravity, dtype=np.float64).reshape(-1)
        if g.shape != (3,) or not np.all(np.isfinite(g)) or np.linalg.norm(g) < 1e-9:
            raise InvalidParameterError(f"gravity must be a non-zero 3-vector, got {self.gravity!r}", field="gravity")
        object.__setattr__(self, "gravity", tuple(float(v) for v in g / np.linalg.norm(g)))
        if self.shake_acceleration is not None and not (
            math.isfinite(self.shake_acceleration) and self.shake_acceleration >= 0
        ):
            raise InvalidParameterError("shake_acceleration must be >= 0", field="shake_acceleration")
        if self.shake_directions is not None:
            dirs = []
            for v in self.shake_directions:
                u = np.asarray(v, dtype=np.float64).reshape(-1)
                if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) < 1e-9:
                    raise InvalidParameterError(f"bad shake direction {v!r}", field="shake_directions")
                dirs.append(tuple(float(x) for x in u / np.linalg.norm(u)))
            object.__setattr__(self, "shake_directions", tuple(dirs))


NOMINAL = Perturbation()


def shake_directions_across(
    gravity: tuple[float, ...], angle: float
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Two perpendicular unit directions across the unit `gravity` (3,), turned by `angle` (rad) about it from
    (gravity x helper, gravity x that), the helper +X unless gravity lies along X (then +Y): the shake of the
    perturbation sets' seeded mixture, which draws the angle."""
    g = np.asarray(gravity, dtype=np.float64)
    helper = np.array([1.0, 0.0, 0.0]) if abs(g[0]) < 0.5 else np.array([0.0, 1.0, 0.0])
    u = np.cross(g, helper)
    u /= np.linalg.norm(u)
    v = np.cross(g, u)
    first = math.cos(angle) * u + math.sin(angle) * v
    second = -math.sin(angle) * u + math.cos(angle) * v
    return (float(first[0]), float(first[1]), float(first[2])), (float(second[0]), float(second[1]), float(second[2]))


def perturbation_set(seed: int = 0) -> tuple[Perturbation, ...]:
    """The standard perturbations (11), each changing the nominal simulation in one way, plus one seeded mixture:

    - mass x0.5 and x1.5 (mass and inertia), friction 0.4 and 0.6 (absolute), all with the top-down pick;
    - gravity turned to -Z, +X, -X, +Y, -Y of the grasp frame after the pick (+Z, the pick itself, is in every
      member: each one starts with the nominal lift);
    - a lateral shake: 1 g (9.81 m/s^2) along two perpendicular directions across gravity (seeded angle);
    - a mixture: seeded mass scale in [0.5, 1.5], friction in [0.4, 0.6], one of the six gravity directions and a
      lateral shake of 1 g.
    """
    rng = np.random.default_rng([int(seed), 1414])
    members = [
        Perturbation("mass x0.5", mass_scale=0.5),
        Perturbation("mass x1.5", mass_scale=1.5),
        Perturbation("friction 0.4", friction=0.4),
        Perturbation("friction 0.6", friction=0.6),
    ]
    members += [Perturbation(f"gravity {k}", gravity=_AXES[k]) for k in ("-Z", "+X", "-X", "+Y", "-Y")]
    a = float(rng.uniform(0.0, math.pi))
    lateral = ((math.cos(a), math.sin(a), 0.0), (-math.sin(a), math.cos(a), 0.0))
    members.append(Perturbation("lateral shake 1 g", shake_acceleration=9.81, shake_directions=lateral))
    g_key = str(rng.choice(list(_AXES)))
    g = np.asarray(_AXES[g_key])
    shake = shake_directions_across(tuple(g), float(rng.uniform(0.0, math.pi)))
    ms, mu = float(rng.uniform(0.5, 1.5)), float(rng.uniform(0.4, 0.6))
    members.append(
        Perturbation(
            f"mixed (mass x{ms:.2f}, friction {mu:.2f}, gravity {g_key}, shake 1 g)",
            mass_scale=ms,
            friction=mu,
            gravity=tuple(g),
            shake_acceleration=9.81,
            shake_directions=shake,
        )
    )
    return tuple(members)


def check_validation_inputs(mass: float | None, engines: tuple[str, ...] = ("coacd", "mujoco")) -> None:
    """InvalidParameterError naming the field when `validate` cannot run: a module of the `validate` extra missing
    (the library alone does not install them; `engines`: what this validation imports) or no mass for the part."""
    import importlib

    for name in engines:
        try:
            importlib.import_module(name)
        except ImportError:
            raise InvalidParameterError(
                f"validate needs {name}: pip install 'graspgen[validate]'", field="validate"
            ) from None
    if mass is None:
        raise InvalidParameterError("validate needs the part's mass: give mass_kg or density", field="mass_kg")


def validation_set(friction: float) -> tuple[Perturbation, ...]:
    """What `validate` simulates every grasp under: the nominal pick; the two ends of the uncertainty that a hold
    depends on most, each alone: the part 50 % heavier (mass x1.5) and the pads' friction 20 % lower (x0.8 of the
    run's `friction`); and MuJoCo's soft friction (no no-slip iterations), the friction model of many simulator
    set-ups, with the heavier part: under soft friction a grasp resting on one or two contact points (an edge, a
    curved spot) creeps round the closing axis even under a small torque, and more under more load. A validated
    grasp holds in all four: one simulator setting is not the truth (bench_hold's perturbed failures of nominally
    held grasps were almost all under these)."""
    return (
        NOMINAL,
        Perturbation("mass x1.5", mass_scale=1.5),
        Perturbation("friction x0.8", friction=0.8 * float(friction)),
        Perturbation("soft friction, mass x1.5", mass_scale=1.5, soft_friction=True),
    )


class _Outcome(Protocol):
    """A simulated grasp's outcome (SimResult, physics_suction.SuctionSimResult): a dataclass with these fields."""

    @property
    def success(self) -> bool: ...

    @property
    def member(self) -> str | None: ...


_R = TypeVar("_R", bound=_Outcome)


def first_failures(grid: Sequence[Sequence[_R]], members: Sequence[Perturbation]) -> list[_R]:
    """One outcome per grasp of a simulation `grid` (grasp i under member j, members as simulated: validation_set
    or physics_suction.suction_validation_set): the first member's (the nominal) result when the grasp held in all
    of them, else the result of the first member it failed, named in its `member`."""
    names = [p.name for p in members]
    out = []
    for row in grid:
        failed = next((j for j, r in enumerate(row) if not r.success), None)
        # dataclasses.replace: each outcome type is a dataclass (the protocol names the fields read here)
        out.append(row[0] if failed is None else cast(_R, replace(cast(Any, row[failed]), member=names[failed])))
    return out


@dataclass(frozen=True)
class SimResult:
    """The outcome of one simulated grasp."""

    success: bool
    reason: str | None  # None on success, else one of REASONS
    slip_mm: float  # largest displacement of the contact midpoint relative to the fingers after closing
    rotation_deg: float  # largest rotation of the part relative to the fingers after closing
    contacts: int  # part-finger contacts at the end of the closing stage
    #: the perturbation this outcome was simulated under (validation_set: the first member that failed), or None
    member: str | None = None
    #: how far (mm) outside the part's own surface the pads bore once closed: the largest distance of a pad contact
    #: from the part's surface samples. 0 for a convex part (its one piece is the part); None without contacts on
    #: both pads or without surface samples (the convex hull as the fallback). A convex decomposition stands proud
    #: of the part across its concavities; where a pad bears on such a bridge, the simulation judges a grasp on a
    #: surface the part does not have (docs/HOLD.md, "The simulation's part")
    bearing_gap_mm: float | None = None
    #: how many times the part's decomposition was refined for this outcome (SimConstants.coacd_refinements)
    refinements: int = 0

    def to_json(self) -> dict[str, Any]:
        out = {
            "success": self.success,
            "reason": self.reason,
            "slip_mm": round(self.slip_mm, 4),
            "rotation_deg": round(self.rotation_deg, 4),
        }
        if self.member is not None:
            out["member"] = self.member
        return out


@dataclass
class SimPart:
    """One MuJoCo model of a part and a gripper, shared read-only by every simulated grasp."""

    model: Any  # mujoco.MjModel
    spec: GripperSpec
    friction: float
    mass: float  # kg
    center_of_mass: np.ndarray  # (3,) object frame
    geometry: str  # "convex" | "coacd" | "convex-hull"
    pieces: int
    note: str | None
    vertices: np.ndarray  # (v, 3) the part's vertices, object frame (for the approach distance)
    constants: SimConstants = field(default_factory=SimConstants)
    grip_force: float = 0.0  # N per finger
    inertia: np.ndarray | None = None  # (3, 3) about the centre of mass, kg m^2
    #: the convex pieces, kept to build the models of perturbations (another mass or friction)
    hulls: list[trimesh.Trimesh] = field(default_factory=list, repr=False)
    #: dense samples (object frame) of the part's own surface when the pieces are larger than the part (CoACD, in
    #: its concavities): an approach that meets a piece collides only if the gripper's path meets this surface
    surface_points: np.ndarray | None = field(default=None, repr=False)
    _variants: dict[tuple[float, float, bool, bool], Any] = field(default_factory=dict, repr=False, compare=False)
    _lock: Any = field(default_factory=threading.Lock, repr=False, compare=False)
    _surface_tree: Any = field(default=None, repr=False, compare=False)
    #: the part's mesh and the seed of its decomposition, to build a finer one (refined)
    mesh: Any = field(default=None, repr=False, compare=False)
    seed: int = 0
    #: refinements of the decomposition from the first one (0 for the first)
    refinements: int = 0
    _refined: Any = field(default=None, repr=False, compare=False)
    #: the fingers' and the body's convex pieces and exact meshes for a gripper from CAD (None: the spec's boxes)
    gripper: SimGripper | None = field(default=None, repr=False, compare=False)

    def refined(self) -> SimPart | None:
        """The same part (mass, inertia, gripper) on a decomposition twice as fine, built once; None when its
        geometry is not a decomposition, the refinements (SimConstants.coacd_refinements) are used up or the finer
        decomposition failed."""
        c = self.constants
        if self.geometry != "coacd" or self.mesh is None or self.refinements >= c.coacd_refinements:
            return None
        with self._lock:
            if self._refined is None:
                assert self.inertia is not None  # _assemble sets it
                finer = replace(c, coacd_threshold=c.coacd_threshold / 2, coacd_max_hulls=2 * c.coacd_max_hulls)
                part = _assemble(
                    self.mesh,
                    self.spec,
                    self.friction,
                    (self.mass, self.center_of_mass, self.inertia),
                    self.grip_force,
                    finer,
                    self.seed,
                    surface_points=self.surface_points,
                    gripper=self.gripper,
                )
                part.refinements = self.refinements + 1
                part._surface_tree = self._surface_tree  # the same samples: no second tree
                self._refined = part if part.geometry == "coacd" else False
        return self._refined or None

    def surface_distance(self, points: np.ndarray) -> np.ndarray | None:
        """Distance (m) of object-frame points from the part's surface samples (0 for a convex part, whose pieces
        are the part; None without samples)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self.geometry == "convex":
            return np.zeros(len(points))
        if self.surface_points is None:
            return None
        with self._lock:
            if self._surface_tree is None:
                from scipy.spatial import cKDTree

                self._surface_tree = cKDTree(self.surface_points)
        distance: np.ndarray = self._surface_tree.query(points)[0]
        return distance

    def describe(self) -> dict[str, Any]:
        out = {
            "geometry": self.geometry,
            "pieces": self.pieces,
            "mass_kg": round(self.mass, 9),
            "grip_force_n": self.grip_force,
        }
        if self.note:
            out["note"] = self.note
        if self.gripper is not None:
            out["gripper"] = self.gripper.describe()
        if self._refined:
            out["refined"] = {
                "pieces": self._refined.pieces,
                "coacd_threshold": self._refined.constants.coacd_threshold,
            }
        return out

    def model_for(self, p: Perturbation, *, palm: bool = True) -> Any:
        """The MjModel for perturbation `p`: the shared one unless it changes the mass or the friction, or `palm` is
        False (the palm, or every piece of a CAD gripper's body, collides with nothing), each built once per setting,
        then shared read-only like the nominal one."""
        mu = self.friction if p.friction is None else float(p.friction)
        soft = bool(p.soft_friction) and self.constants.noslip_iterations > 0
        if p.mass_scale == 1.0 and mu == self.friction and not soft and palm:
            return self.model
        key = (float(p.mass_scale), mu, soft, bool(palm))
        with self._lock:
            if key not in self._variants:
                import mujoco

                assert self.inertia is not None  # _assemble sets it
                xml = _xml(
                    self.hulls,
                    self.spec,
                    mu,
                    self.mass * p.mass_scale,
                    self.center_of_mass,
                    self.inertia * p.mass_scale,
                    replace(self.constants, noslip_iterations=0) if soft else self.constants,
                    self.grip_force,
                    palm_collides=palm,
                    gripper=self.gripper,
                )
                self._variants[key] = mujoco.MjModel.from_xml_string(xml)
            return self._variants[key]


# --------------------------------------------------------------------------------------------------------------------
# model


#: decompositions kept per process (CoACD takes seconds to a minute a part; a worker validates the same object for
#: several grippers and jobs): key -> (pieces, method, note), the pieces read-only
_DECOMPOSITIONS: OrderedDict[tuple[object, ...], tuple[list[trimesh.Trimesh], str, str | None]] = OrderedDict()
_DECOMPOSITIONS_KEPT = 8
_DECOMPOSITIONS_LOCK = threading.Lock()


def _decompose(mesh: trimesh.Trimesh, c: SimConstants, seed: int) -> tuple[list[trimesh.Trimesh], str, str | None]:
    """Convex pieces of the part, the method used and a note when it fell back; the last few are remembered, keyed
    by the mesh's bytes, CoACD's settings and the seed."""
    h = hashlib.sha1(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    key = (h.hexdigest(), c.coacd_threshold, c.coacd_max_hulls, c.coacd_options, int(seed))
    with _DECOMPOSITIONS_LOCK:
        if key in _DECOMPOSITIONS:
            _DECOMPOSITIONS.move_to_end(key)
            return _DECOMPOSITIONS[key]
    out = _decompose_once(mesh, c, seed)
    with _DECOMPOSITIONS_LOCK:
        _DECOMPOSITIONS[key] = out
        while len(_DECOMPOSITIONS) > _DECOMPOSITIONS_KEPT:
            _DECOMPOSITIONS.popitem(last=False)
    return out


def _decompose_once(mesh: trimesh.Trimesh, c: SimConstants, seed: int) -> tuple[list[trimesh.Trimesh], str, str | None]:
    if mesh.is_convex:
        return [mesh.convex_hull], "convex", None
    try:
        import coacd
    except ImportError:
        return [mesh.convex_hull], "convex-hull", "coacd is not installed: the part is simulated as its convex hull"
    coacd.set_log_level("error")

    def run(preprocess: str) -> Any:  # coacd is untyped: its (vertices, faces) pieces
        return coacd.run_coacd(
            coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
            threshold=c.coacd_threshold,
            max_convex_hull=c.coacd_max_hulls,
            seed=int(seed),
            preprocess_mode=preprocess,
            **dict(c.coacd_options),
        )

    try:
        # CoACD's preprocessing remeshes the part (a manifold rebuild at `preprocess_resolution`); a closed mesh does
        # not need it, and the rebuild can move the surface outwards (up to 1.5 mm on tless_10), so that the pads
        # bear on pieces standing proud of the part
        closed = mesh.is_watertight and mesh.is_winding_consistent
        try:
            parts = run("off" if closed else "auto")
        except Exception:
            if not closed:
                raise
            parts = run("auto")
    except Exception as exc:  # the decomposition is a best effort: fall back and say so
        return [mesh.convex_hull], "convex-hull", f"convex decomposition failed ({exc}): simulated as the convex hull"
    pieces = []
    for v, f in parts:
        try:
            hull = trimesh.Trimesh(np.asarray(v, dtype=np.float64), np.asarray(f)).convex_hull
        except Exception:  # a degenerate piece (flat or a few points) adds nothing to the contact geometry
            continue
        if hull.volume > 1e-12 and len(hull.vertices) >= 4:
            pieces.append(hull)
    if not pieces:
        return [mesh.convex_hull], "convex-hull", "convex decomposition gave no pieces: simulated as the convex hull"
    return pieces, "coacd", None


# --------------------------------------------------------------------------------------------------------------------
# a gripper from CAD


@dataclass(frozen=True, eq=False)
class SimGripper:
    """A gripper from CAD as the simulation holds it (CONTRACT.md "Gripper geometry from CAD").

    - `fingers`: the convex pieces of the -X and the +X finger, each in its finger body's frame, which is the finger
      frame (the -X finger's turned 180 degrees about Z into the grasp frame's axes: (x, y, z) -> (-x, -y, z));
    - `body`: the body's convex pieces in the grasp frame (empty without a body);
    - `swept`: the exact meshes in the same frames (-X finger, +X finger, body or None), for the approach's check
      against the part's own surface (eroded by SimConstants.approach_tolerance);
    - `top_z`: the gripper's highest z (its leading edge along the approach), grasp frame;
    - `notes`: what was approximated (a mesh simulated as its convex hull)."""

    fingers: tuple[list[trimesh.Trimesh], list[trimesh.Trimesh]]
    body: list[trimesh.Trimesh]
    swept: tuple[SweptMesh, SweptMesh, SweptMesh | None]
    top_z: float
    notes: tuple[str, ...] = ()

    def describe(self) -> dict[str, Any]:
        return {
            "finger_pieces": [len(self.fingers[0]), len(self.fingers[1])],
            "body_pieces": len(self.body),
        }


#: a gripper mesh of more closed shells than this is decomposed as a whole (_solid_pieces)
_MAX_SHELLS = 32
#: SimGripper per geometry (its files' digests) and decomposition setting
_GRIPPERS: OrderedDict[tuple[object, ...], SimGripper] = OrderedDict()
_GRIPPERS_KEPT = 4


def _turned(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """`mesh` turned 180 degrees about Z: (x, y, z) -> (-x, -y, z) (a rotation: the winding stays outward)."""
    return trimesh.Trimesh(np.asarray(mesh.vertices) * [-1.0, -1.0, 1.0], np.asarray(mesh.faces), process=False)


def _sim_gripper(spec: GripperSpec, c: SimConstants) -> SimGripper | None:
    """The SimGripper of `spec`'s CAD geometry (None for the contract's boxes), built once per geometry and setting:
    the convex pieces of each closed shell of each mesh (a convex shell is one piece, others CoACD under `c`'s
    settings, as the part) and the exact meshes."""
    g = spec.geometry
    if g is None:
        return None
    key = (g, c.coacd_threshold, c.coacd_max_hulls, c.coacd_options, c.approach_tolerance)
    with _DECOMPOSITIONS_LOCK:
        if key in _GRIPPERS:
            _GRIPPERS.move_to_end(key)
            return _GRIPPERS[key]
    notes: list[str] = []
    right = _solid_pieces(g.finger, c, "the +X finger", notes)
    same = "finger_left" not in g.files  # the -X finger is the +X finger's mesh
    left = [_turned(p) for p in (right if same else _solid_pieces(g.finger_left, c, "the -X finger", notes))]
    body_mesh = g.body
    body = _solid_pieces(body_mesh, c, "the body", notes) if body_mesh is not None else []
    tol = c.approach_tolerance
    swept = (
        SweptMesh.of(_turned(g.finger_left).triangles, tol),
        SweptMesh.of(g.finger.triangles, tol),
        SweptMesh.of(body_mesh.triangles, tol) if body_mesh is not None else None,
    )
    top = max(float(g.finger.bounds[1, 2]), float(g.finger_left.bounds[1, 2]))
    if body_mesh is not None:
        top = max(top, float(body_mesh.bounds[1, 2]))
    out = SimGripper((left, right), body, swept, top, tuple(dict.fromkeys(notes)))
    with _DECOMPOSITIONS_LOCK:
        _GRIPPERS[key] = out
        while len(_GRIPPERS) > _GRIPPERS_KEPT:
            _GRIPPERS.popitem(last=False)
    return out


def _solid_pieces(mesh: trimesh.Trimesh, c: SimConstants, what: str, notes: list[str]) -> list[trimesh.Trimesh]:
    """Convex pieces of a closed gripper mesh: each closed shell on its own (shells of a CAD export that touch, e.g.
    a stepped finger's tip and root, are convex more often than their union), convex ones as they are, the others
    decomposed by CoACD (seed 0: the gripper's pieces do not depend on the run's seed). An inward shell bounds a
    cavity, which nothing can reach: the outer shell's pieces fill it. The whole mesh is decomposed at once when its
    shells are not all closed or more than _MAX_SHELLS face outwards (an assembly of many small parts: one
    decomposition rather than a geom or more per screw)."""
    shells = mesh.split(only_watertight=True)
    closed = sum(len(s.faces) for s in shells) == len(mesh.faces)
    shells = [s for s in shells if s.volume > 0]
    if not closed or not shells or len(shells) > _MAX_SHELLS:
        shells = [mesh]
    pieces: list[trimesh.Trimesh] = []
    for shell in shells:
        parts, method, note = _decompose_once(shell, c, 0)
        if note:
            notes.append(f"{what}: {note.replace('the part', 'it')}")
        pieces += parts
    return pieces


def _surface_points(mesh: trimesh.Trimesh, c: SimConstants, seed: int) -> np.ndarray:
    """`c.surface_samples` seeded points of the part's own surface (object frame)."""
    pts, _ = trimesh.sample.sample_surface(mesh, int(c.surface_samples), seed=int(seed))
    return np.ascontiguousarray(pts, dtype=np.float64)


def mass_properties(
    mesh: trimesh.Trimesh, density: float | None, mass_kg: float | None
) -> tuple[float, np.ndarray, np.ndarray, str | None]:
    """Mass (kg), centre of mass (3,) object frame and inertia about the centre of mass (3, 3) kg m^2 from the volume
    of `mesh` (metres), at `density` (kg/m^3) or scaled to `mass_kg` (uniform material; exactly one of the two is
    given, the caller checks them), and a note when the mesh is not a closed volume (then its convex hull's)."""
    note = None
    body = mesh
    if not (mesh.is_watertight and mesh.volume > 0):
        body = mesh.convex_hull
        note = "the mesh is not a closed volume: mass and inertia from its convex hull"
    props = body.mass_properties
    volume = float(props["volume"])
    com = np.asarray(props["center_mass"], dtype=np.float64)
    if mass_kg is not None:
        density = mass_kg / volume
    assert density is not None  # prepare_part requires mass_kg or density
    inertia = np.asarray(props["inertia"], dtype=np.float64) * density  # trimesh's is for unit density
    return volume * density, com, inertia, note


def _fmt(values: npt.ArrayLike) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.asarray(values).ravel())


def _xml(
    pieces: list[trimesh.Trimesh],
    spec: GripperSpec,
    friction: float,
    mass: float,
    com: np.ndarray,
    inertia: np.ndarray,
    c: SimConstants,
    grip_force: float,
    *,
    palm_collides: bool = True,
    gripper: SimGripper | None = None,
) -> str:
    t, fw, fd = spec.finger_thickness, spec.finger_width, spec.finger_depth
    half_stroke = spec.stroke / 2
    torsion = friction * c.patch_radius
    fric = f"{friction:.9g} {torsion:.9g} 0.0001"
    solref = _fmt(c.solref)
    assets = "\n".join(
        f'<mesh name="piece{k}" vertex="{_fmt(p.vertices)}" face="{_fmt(p.faces.astype(int))}"/>'
        for k, p in enumerate(pieces)
    )
    part_geoms = "\n".join(
        f'<geom type="mesh" mesh="piece{k}" contype="2" conaffinity="1" condim="4" friction="{fric}" '
        f'solref="{solref}" mass="0"/>'
        for k in range(len(pieces))
    )
    palm = ""
    fingers: Sequence[str]  # the two fingers' geoms: the -X finger's, then the +X finger's
    if gripper is None:
        # inner faces at x = -+stroke/2 when the joints are at 0 (fully open); a joint value q closes each finger by q
        finger = (
            f'<geom type="box" size="{t / 2:.9g} {fw / 2:.9g} {fd / 2:.9g}" contype="1" conaffinity="2" condim="4" '
            f'friction="{fric}" solref="{solref}"/>'
        )
        fingers = (finger, finger)
        finger_pos = half_stroke + t / 2
        box = spec.palm_box()
        if box is not None:
            palm = (
                f'<geom name="palm" type="box" pos="{_fmt(box.center)}" size="{_fmt(np.asarray(box.extents) / 2)}" '
                f'contype="{int(palm_collides)}" conaffinity="{2 * int(palm_collides)}" condim="4" friction="{fric}" '
                f'solref="{solref}"/>'
            )
    else:
        # each finger body is its finger frame, at x = -+stroke/2 when the joints are at 0 (fully open), carrying
        # the finger's convex pieces; the body's pieces are static geoms of the grasp frame in the palm's role
        extra = []
        fingers = []
        for side, parts in zip(("f0_", "f1_"), gripper.fingers, strict=True):
            extra += [_mesh_asset(f"{side}{k}", p) for k, p in enumerate(parts)]
            fingers.append(
                "\n      ".join(
                    f'<geom type="mesh" mesh="{side}{k}" contype="1" conaffinity="2" condim="4" friction="{fric}" '
                    f'solref="{solref}"/>'
                    for k in range(len(parts))
                )
            )
        extra += [_mesh_asset(f"body{k}", p) for k, p in enumerate(gripper.body)]
        assets = "\n".join([assets, *extra])
        palm = "\n    ".join(
            f'<geom name="body{k}" type="mesh" mesh="body{k}" contype="{int(palm_collides)}" '
            f'conaffinity="{2 * int(palm_collides)}" condim="4" friction="{fric}" solref="{solref}"/>'
            for k in range(len(gripper.body))
        )
        finger_pos = half_stroke
    close_range = max(half_stroke - spec.min_width / 2, 0.0)
    I = inertia
    full = _fmt([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])
    fm = c.finger_mass
    return f"""
<mujoco model="graspgen-validation">
  <compiler angle="radian" autolimits="true" boundmass="1e-9" boundinertia="1e-15"/>
  <option timestep="{c.timestep:.9g}" gravity="0 0 0" integrator="implicitfast" cone="elliptic" impratio="10"
          noslip_iterations="{c.noslip_iterations:d}"/>
  <asset>
{assets}
  </asset>
  <worldbody>
    {palm}
    <body name="finger0" pos="{-finger_pos:.9g} 0 0">
      <joint name="close0" type="slide" axis="1 0 0" range="0 {close_range:.9g}" damping="{c.finger_damping:.9g}"/>
      <inertial pos="0 0 0" mass="{fm:.9g}" diaginertia="1e-5 1e-5 1e-5"/>
      {fingers[0]}
    </body>
    <body name="finger1" pos="{finger_pos:.9g} 0 0">
      <joint name="close1" type="slide" axis="-1 0 0" range="0 {close_range:.9g}" damping="{c.finger_damping:.9g}"/>
      <inertial pos="0 0 0" mass="{fm:.9g}" diaginertia="1e-5 1e-5 1e-5"/>
      {fingers[1]}
    </body>
    <body name="part">
      <freejoint name="part"/>
      <inertial pos="{_fmt(com)}" mass="{mass:.9g}" fullinertia="{full}"/>
{part_geoms}
    </body>
  </worldbody>
  <equality>
    <joint joint1="close1" joint2="close0" polycoef="0 1 0 0 0"/>
  </equality>
  <actuator>
    <motor name="grip0" joint="close0" ctrlrange="{-grip_force:.9g} {grip_force:.9g}"/>
    <motor name="grip1" joint="close1" ctrlrange="{-grip_force:.9g} {grip_force:.9g}"/>
  </actuator>
</mujoco>
"""


def _mesh_asset(name: str, mesh: trimesh.Trimesh) -> str:
    return f'<mesh name="{name}" vertex="{_fmt(mesh.vertices)}" face="{_fmt(np.asarray(mesh.faces).astype(int))}"/>'


def prepare_part(
    mesh: trimesh.Trimesh,
    spec: GripperSpec,
    *,
    friction: float | None = None,
    mass_kg: float | None = None,
    density: float | None = None,
    grip_force: float | None = None,
    seed: int = 0,
    constants: SimConstants = SIM,
) -> SimPart:
    """Build the MuJoCo model of `mesh` (metres, object frame) held by `spec`'s gripper; once per part.

    The part's mass is `mass_kg` (kg; inertia from the mesh's shape, uniform material) or its volume times `density`
    (kg/m^3): exactly one is required. The grip force (N per finger) is `grip_force`, else the gripper's
    `grip_force`; without either the validation is refused. InvalidParameterError on a missing or bad value."""

    def positive(v: object) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0

    if mass_kg is None and density is None:
        raise InvalidParameterError(
            "physics validation needs the part's mass (mass_kg, kg) or its density (kg/m^3)", field="mass_kg"
        )
    if mass_kg is not None and density is not None:
        raise InvalidParameterError("give the part's mass_kg or its density, not both", field="mass_kg")
    if mass_kg is not None and not positive(mass_kg):
        raise InvalidParameterError(f"mass_kg must be a positive number (kg), got {mass_kg!r}", field="mass_kg")
    if density is not None and not positive(density):
        raise InvalidParameterError(f"density must be a positive number (kg/m^3), got {density!r}", field="density")
    force = grip_force if grip_force is not None else spec.grip_force
    if force is None:
        raise InvalidParameterError(
            "physics validation needs the gripper's grip force (grip_force, N per finger)", field="grip_force"
        )
    if not positive(force):
        raise InvalidParameterError(f"grip_force must be a positive number (N), got {force!r}", field="grip_force")
    mu = spec.friction if friction is None else float(friction)
    mass, com, inertia, mass_note = mass_properties(
        mesh, None if density is None else float(density), None if mass_kg is None else float(mass_kg)
    )
    return _assemble(mesh, spec, mu, (mass, com, inertia), float(force), constants, seed, mass_note=mass_note)


def _assemble(
    mesh: trimesh.Trimesh,
    spec: GripperSpec,
    mu: float,
    mass_properties: tuple[float, np.ndarray, np.ndarray],
    force: float,
    constants: SimConstants,
    seed: int,
    *,
    mass_note: str | None = None,
    surface_points: np.ndarray | None = None,
    gripper: SimGripper | None = None,
) -> SimPart:
    """The SimPart of a checked part: its decomposition under `constants` and the MuJoCo model (`gripper`: the CAD
    gripper's pieces when already built, e.g. for a finer decomposition of the same part)."""
    import mujoco

    mass, com, inertia = mass_properties
    if gripper is None:
        gripper = _sim_gripper(spec, constants)
    pieces, geometry, note = _decompose(mesh, constants, seed)
    notes = [n for n in (note, mass_note, *(gripper.notes if gripper else ())) if n]
    model = mujoco.MjModel.from_xml_string(
        _xml(pieces, spec, mu, mass, com, inertia, constants, force, gripper=gripper)
    )
    if geometry == "coacd" and surface_points is None:
        surface_points = _surface_points(mesh, constants, seed)
    return SimPart(
        model=model,
        spec=spec,
        friction=mu,
        mass=mass,
        center_of_mass=com,
        geometry=geometry,
        pieces=len(pieces),
        note="; ".join(notes) or None,
        vertices=np.asarray(mesh.vertices, dtype=np.float64),
        constants=constants,
        grip_force=force,
        inertia=inertia,
        hulls=pieces,
        surface_points=surface_points if geometry == "coacd" else None,
        mesh=mesh,
        seed=int(seed),
        gripper=gripper,
    )


# --------------------------------------------------------------------------------------------------------------------
# one grasp


def _matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=np.float64).ravel())
    return q


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    R: np.ndarray = trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]
    return R


def placement_error(rng: np.random.Generator, c: SimConstants = SIM) -> tuple[np.ndarray, np.ndarray]:
    """A seeded placement error of the part, as a real robot's pose error: a rotation (3, 3) about a random axis by
    up to `c.pose_noise_deg` and a translation (3,) of up to `c.pose_noise` (m) per axis, drawn from `rng` in this
    order (axis, angle, translation). The part's pose in the gripper's frame becomes `R_err @ R, R_err @ p + t_err`."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R_err = _rotation(axis, math.radians(c.pose_noise_deg) * rng.uniform(-1.0, 1.0))
    t_err = rng.uniform(-1.0, 1.0, size=3) * c.pose_noise
    return R_err, t_err


def load_schedule(c: SimConstants, p: Perturbation, dt: float) -> Iterator[np.ndarray]:
    """The acceleration (3,) m/s^2, grasp frame, that the part feels in each interval of `dt` seconds after the grasp
    is made: gravity minus the gripper's acceleration (the part's load is its mass times this, at its centre of mass).

    The lift (gravity along +Z plus `c.lift_acceleration` ramped up over `c.lift_time`), a hold at rest
    (`c.hold_time`), under a perturbation whose gravity is not +Z the turn (gravity swings to `p.gravity` about a
    fixed axis over `c.turn_time` per 90 degrees) and another hold, then one sine period (`c.shake_frequency`) of
    `c.shake_acceleration` along each of `c.shake_directions` (or the perturbation's shake)."""
    g = np.array([0.0, 0.0, c.gravity])
    n_ramp = max(1, int(round(c.lift_time / dt)))
    for k in range(n_ramp):  # lifting along -Z with a growing acceleration loads the part along +Z
        yield g + np.array([0.0, 0.0, c.lift_acceleration]) * (k + 1) / n_ramp
    n_hold = int(round(c.hold_time / dt))
    for _ in range(n_hold):
        yield g
    target = np.asarray(p.gravity, dtype=np.float64)
    angle = math.acos(min(1.0, max(-1.0, float(target[2]))))
    if angle > 1e-6:  # the robot turns the part: gravity swings from +Z to the target about a fixed axis
        axis = np.cross([0.0, 0.0, 1.0], target)
        axis = np.array([1.0, 0.0, 0.0]) if np.linalg.norm(axis) < 1e-9 else axis / np.linalg.norm(axis)
        n_turn = max(1, int(round(c.turn_time * angle / (math.pi / 2) / dt)))
        for k in range(n_turn):
            yield _rotation(axis, angle * (k + 1) / n_turn) @ g
        g = c.gravity * target
        for _ in range(n_hold):
            yield g
    accel = c.shake_acceleration if p.shake_acceleration is None else p.shake_acceleration
    directions = c.shake_directions if p.shake_directions is None else p.shake_directions
    n_shake = max(1, int(round(1.0 / c.shake_frequency / dt)))
    for v in directions:
        u = np.asarray(v, dtype=np.float64) / np.linalg.norm(v)
        for k in range(n_shake):
            yield g - u * (accel * math.sin(2 * math.pi * (k + 0.5) / n_shake))


class _Grasp:
    """The state of one simulated grasp on its own MjData."""

    def __init__(
        self,
        sim: SimPart,
        T_object_grasp: np.ndarray,
        width: float,
        inside: bool,
        rng: np.random.Generator,
        perturbation: Perturbation = NOMINAL,
    ) -> None:
        import mujoco

        self.mj = mujoco
        self.sim = sim
        self.c = sim.constants
        self.p = perturbation
        self.mass = sim.mass * perturbation.mass_scale
        m = sim.model_for(perturbation)
        self.m = m
        self.d = mujoco.MjData(m)
        self.part_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "part")
        self.finger_bodies = (
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "finger0"),
            mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "finger1"),
        )
        # the static geoms that take the palm's role: the palm box, or every piece of a CAD gripper's body
        names = ["palm"] if sim.gripper is None else [f"body{k}" for k in range(len(sim.gripper.body))]
        ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name) for name in names]
        self.palm_geoms = np.array([g for g in ids if g >= 0], dtype=np.int64)
        T = np.asarray(T_object_grasp, dtype=np.float64)
        # T_grasp_object, with a small seeded placement error
        T_go = np.linalg.inv(T)
        R_err, t_err = placement_error(rng, self.c)
        self.R0 = R_err @ T_go[:3, :3]
        self.p0 = R_err @ T_go[:3, 3] + t_err
        self.midpoint_object = T[:3, 3].copy()  # the contact midpoint in the object frame
        spec = sim.spec
        self.inside = bool(inside)
        if self.inside and sim.gripper is not None:
            raise InvalidParameterError(
                "inside grasps need box fingers: a CAD finger's pad is on its inner face", field="inside"
            )
        if not self.inside:  # inner faces at the pre-grasp opening, closing inwards
            self.q_open = max((spec.stroke - spec.open_width(width)) / 2, 0.0)
        else:  # inside grasps mirror the fingers: outer faces at the narrower pre-grasp width, opening outwards
            o = spec.solids().open_width(width, inside=True)
            self.q_open = min(max(spec.stroke / 2 - (o / 2 - spec.finger_thickness), 0.0), spec.stroke / 2)
        # the approach starts where the fingers' leading edge (z = +finger_depth / 2; a CAD gripper's highest z) is
        # below the part's lowest point
        top = spec.finger_depth / 2 if sim.gripper is None else sim.gripper.top_z
        z = (sim.vertices @ self.R0.T + self.p0)[:, 2]
        self.approach_distance = max(top - float(z.min()) + self.c.approach_step, 0.0)

    # -- helpers ---------------------------------------------------------------------------------------------------
    def _set_part(self, p: np.ndarray) -> None:
        adr = self.m.jnt_qposadr[self.m.body_jntadr[self.part_body]]
        self.d.qpos[adr : adr + 3] = p
        self.d.qpos[adr + 3 : adr + 7] = _matrix_to_quat_wxyz(self.R0)

    def _part_pose(self) -> tuple[np.ndarray, np.ndarray]:
        return self.d.xpos[self.part_body].copy(), self.d.xmat[self.part_body].reshape(3, 3).copy()

    def _part_contacts(self) -> tuple[np.ndarray, np.ndarray]:
        """Which of the current contacts touch the part (mask over the first ncon), and the other body of each."""
        n = self.d.ncon
        con = self.d.contact
        b1 = self.m.geom_bodyid[con.geom1[:n]]
        b2 = self.m.geom_bodyid[con.geom2[:n]]
        mine = (b1 == self.part_body) | (b2 == self.part_body)
        return mine, np.where(b1 == self.part_body, b2, b1)[mine]

    def _contacts(self) -> tuple[int, int, float]:
        """Contacts of the part with finger 0, finger 1, and the deepest penetration (m, >= 0)."""
        if self.d.ncon == 0:
            return 0, 0, 0.0
        mine, other = self._part_contacts()
        if not mine.any():
            return 0, 0, 0.0
        deepest = max(0.0, -float(np.min(self.d.contact.dist[: self.d.ncon][mine])))
        return int(np.sum(other == self.finger_bodies[0])), int(np.sum(other == self.finger_bodies[1])), deepest

    # -- stages ----------------------------------------------------------------------------------------------------
    def approach_collides(self) -> bool:
        mj, d = self.mj, self.d
        d.qpos[:] = 0.0
        for j in ("close0", "close1"):
            d.qpos[self.m.jnt_qposadr[mj.mj_name2id(self.m, mj.mjtObj.mjOBJ_JOINT, j)]] = self.q_open
        steps = int(math.ceil(self.approach_distance / self.c.approach_step))
        # the gripper moving along +Z onto the part is the part moving along -Z onto the gripper
        for k in range(steps, -1, -1):
            self._set_part(self.p0 + np.array([0.0, 0.0, k * self.c.approach_step]))
            mj.mj_kinematics(self.m, d)
            mj.mj_collision(self.m, d)
            if self._contacts()[2] > self.c.approach_tolerance:
                return self._path_meets_the_part()
        return False

    def _path_meets_the_part(self) -> bool:
        """Does the gripper's way in meet the part's own surface (not only a convex piece)? The approach is a
        translation along +Z, so each of the palm's and the open fingers' boxes sweeps a box, from where it starts
        to the grasp; a surface sample inside one (shrunk by the approach tolerance) is a collision. A CAD gripper's
        solids are its exact meshes (the open fingers and the body), each eroded by the approach tolerance and moved
        along +Z into place (meshsweep.SweptMesh). Without surface samples (a convex part, or the hull as the
        fallback) the pieces are the part."""
        pts = self.sim.surface_points
        if pts is None:
            return True
        mj, m, d = self.mj, self.m, self.d
        self._set_part(self.p0)
        mj.mj_kinematics(m, d)
        p, R = self._part_pose()
        q = pts @ R.T + p  # the part at the grasp, in the gripper's frame
        tol = self.c.approach_tolerance
        gripper = self.sim.gripper
        if gripper is not None:
            left, right, body = gripper.swept
            for solid, b in ((left, self.finger_bodies[0]), (right, self.finger_bodies[1])):
                if solid.any_hit(q - d.xpos[b], self.approach_distance):  # the finger's frame, fingers open
                    return True
            return body is not None and body.any_hit(q, self.approach_distance)
        for g in range(m.ngeom):
            if m.geom_bodyid[g] == self.part_body or m.geom_type[g] != mj.mjtGeom.mjGEOM_BOX:
                continue
            lo = d.geom_xpos[g] - m.geom_size[g] + tol
            hi = d.geom_xpos[g] + m.geom_size[g] - tol
            lo = lo - np.array([0.0, 0.0, self.approach_distance])  # where the box starts, below the grasp
            if np.any(np.all((q > lo) & (q < hi), axis=1)):
                return True
        return False

    def _bearing_gap_mm(self) -> float | None:
        """SimResult.bearing_gap_mm in the current state: the pad contacts' largest distance from the part's own
        surface."""
        mine, other = self._part_contacts()
        pads = np.isin(other, self.finger_bodies)
        if not pads.any():
            return None
        p, R = self._part_pose()
        at = (self.d.contact.pos[: self.d.ncon][mine][pads] - p) @ R  # object frame
        dist = self.sim.surface_distance(at)
        return None if dist is None else float(np.max(dist)) * 1e3

    def _palm_penetration(self) -> float:
        """The deepest penetration (m, >= 0) of the part's pieces into the palm (or any piece of a CAD gripper's
        body) in the current state."""
        if len(self.palm_geoms) == 0:
            return 0.0
        n = self.d.ncon
        con = self.d.contact
        palm = np.isin(con.geom1[:n], self.palm_geoms) | np.isin(con.geom2[:n], self.palm_geoms)
        return max(0.0, -float(np.min(con.dist[:n][palm]))) if palm.any() else 0.0

    def _without_palm(self) -> None:
        """Go on in the model whose palm (a CAD gripper's body) collides with nothing, from the same state."""
        m = self.sim.model_for(self.p, palm=False)
        d = self.mj.MjData(m)
        d.qpos[:] = self.d.qpos
        self.m, self.d = m, d

    def run(self) -> SimResult:
        if self.approach_collides():
            return SimResult(False, "collision", 0.0, 0.0, 0, refinements=self.sim.refinements)
        self.d.qvel[:] = 0.0
        self.mj.mj_forward(self.m, self.d)
        if self._palm_penetration() > self.c.palm_start_tolerance:
            # the approach check forgave a convex piece reaching into the palm (up to approach_tolerance, or deeper
            # where the part's own surface is clear of it): MuJoCo would push the part out of that penetration at
            # once and fling it, turned and shifted, from between the open fingers
            self._without_palm()
            self.mj.mj_forward(self.m, self.d)
        mj, m, d, c = self.mj, self.m, self.d, self.c
        d.ctrl[:] = -self.sim.grip_force if self.inside else self.sim.grip_force
        mj.mj_step(m, d, nstep=max(1, int(round(c.close_time / c.timestep))))
        n0, n1, _ = self._contacts()
        if n0 == 0 or n1 == 0:
            return SimResult(False, "no_contact", 0.0, 0.0, n0 + n1, refinements=self.sim.refinements)
        contacts = n0 + n1
        gap = self._bearing_gap_mm()
        refined = self.sim.refinements
        p_ref, R_ref = self._part_pose()
        mid_ref = R_ref @ self.midpoint_object + p_ref
        slip = rot = lost = 0.0
        dt = c.timestep * c.check_steps
        for a in load_schedule(c, self.p, dt):
            # the load is constant over one check interval (a few ms, short against the shake period)
            d.xfrc_applied[self.part_body, :3] = self.mass * a
            mj.mj_step(m, d, nstep=c.check_steps)
            p, R = self._part_pose()
            slip = max(slip, float(np.linalg.norm(R @ self.midpoint_object + p - mid_ref)))
            cos = (np.trace(R_ref.T @ R) - 1.0) / 2.0
            rot = max(rot, math.degrees(math.acos(min(1.0, max(-1.0, cos)))))
            n0, n1, _ = self._contacts()
            lost = lost + dt if (n0 == 0 or n1 == 0) else 0.0
            if slip > c.drop_distance or lost > c.lost_contact_time:
                return SimResult(False, "dropped", slip * 1e3, rot, contacts, bearing_gap_mm=gap, refinements=refined)
        if slip > c.slip_limit or rot > c.rotation_limit_deg:
            return SimResult(False, "slipped", slip * 1e3, rot, contacts, bearing_gap_mm=gap, refinements=refined)
        return SimResult(True, None, slip * 1e3, rot, contacts, bearing_gap_mm=gap, refinements=refined)


def simulate_grasp(
    sim: SimPart,
    T_object_grasp: np.ndarray,
    width: float,
    *,
    inside: bool = False,
    seed: int = 0,
    key: int = 0,
    perturbation: Perturbation | None = None,
) -> SimResult:
    """Simulate one grasp (pose (4, 4) in the object frame, contact distance `width` m; `inside`: the fingers open
    outwards onto the contacts) under `perturbation` (None: the nominal simulation). `key` (e.g. the candidate index)
    and `seed` pick the placement error, the same under every perturbation, so a grasp's outcome does not depend on
    what else runs."""
    rng = np.random.default_rng([int(seed), int(key)])
    return _Grasp(sim, T_object_grasp, float(width), inside, rng, perturbation or NOMINAL).run()


def simulate_grasps(
    sim: SimPart,
    poses: np.ndarray,
    widths: np.ndarray,
    *,
    seed: int = 0,
    keys: np.ndarray | None = None,
    workers: int | None = None,
    inside: np.ndarray | None = None,
    perturbation: Perturbation | None = None,
) -> list[SimResult]:
    """Simulate grasps (poses (n, 4, 4), widths (n,), inside (n,) bool or None) in parallel threads under one
    perturbation (None: nominal); results in input order."""
    out = simulate_perturbed(
        sim, poses, widths, [perturbation or NOMINAL], seed=seed, keys=keys, workers=workers, inside=inside
    )
    return [row[0] for row in out]


def simulate_perturbed(
    sim: SimPart,
    poses: np.ndarray,
    widths: np.ndarray,
    perturbations: Iterable[Perturbation],
    *,
    seed: int = 0,
    keys: np.ndarray | None = None,
    workers: int | None = None,
    inside: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[list[SimResult]]:
    """Simulate every grasp (poses (n, 4, 4), widths (n,)) under every perturbation (a sequence of p), all pairs in
    one thread pool; `out[i][j]` is grasp i under perturbation j. A grasp holds under the perturbations when every
    `out[i][j].success`. A grasp whose pads bear on the decomposition's slack under any perturbation (bearing gap
    above SimConstants.bearing_tolerance) is simulated again, under every perturbation, on the part's finer
    decomposition (SimPart.refined), and those outcomes replace its row.

    `progress(done, total)`, if given, is called in the calling thread after each simulation ends, and before the
    finer decomposition is built (total grows by the simulations that adds). If it raises, the simulations not yet
    started are dropped, the running ones end, and the exception propagates (a cancelled job stops within one
    simulation, not after all of them)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    widths = np.asarray(widths, dtype=np.float64).reshape(-1)
    keys = np.arange(len(poses)) if keys is None else np.asarray(keys).reshape(-1)
    n = len(poses)
    inside = np.zeros(n, dtype=bool) if inside is None else np.asarray(inside, dtype=bool).reshape(-1)
    members = list(perturbations)
    if n == 0 or not members:
        return [[] for _ in range(n)]
    count = [0, n * len(members)]  # simulations done, and to do

    def step(done: int) -> None:
        if progress is not None:
            progress(count[0] + done, count[1])

    out = _simulate_all(sim, poses, widths, members, seed, keys, workers, inside, step)
    count[0] += n * len(members)
    limit_mm = sim.constants.bearing_tolerance * 1e3
    while True:
        rows = [i for i, row in enumerate(out) if any((r.bearing_gap_mm or 0.0) > limit_mm for r in row)]
        if rows:
            count[1] += len(rows) * len(members)
            step(0)
        finer = sim.refined() if rows else None
        if finer is None:
            return out
        again = _simulate_all(finer, poses[rows], widths[rows], members, seed, keys[rows], workers, inside[rows], step)
        count[0] += len(rows) * len(members)
        for i, row in zip(rows, again, strict=True):
            out[i] = row
        sim = finer


def _simulate_all(
    sim: SimPart,
    poses: np.ndarray,
    widths: np.ndarray,
    members: list[Perturbation],
    seed: int,
    keys: np.ndarray,
    workers: int | None,
    inside: np.ndarray,
    step: Callable[[int], None],
) -> list[list[SimResult]]:
    """simulate_perturbed on one geometry: every grasp under every member, in one thread pool; step(k) after the
    k-th simulation ends (in the calling thread)."""
    n = len(poses)
    for p in members:  # build the perturbed models before the threads share them
        sim.model_for(p)
    jobs = [(i, j) for i in range(n) for j in range(len(members))]

    def one(job: tuple[int, int]) -> SimResult:
        i, j = job
        return simulate_grasp(
            sim, poses[i], widths[i], inside=bool(inside[i]), seed=seed, key=int(keys[i]), perturbation=members[j]
        )

    workers = min(len(jobs), workers or os.cpu_count() or 1)
    flat: list[SimResult | None] = [None] * len(jobs)
    if workers <= 1:
        for k, job in enumerate(jobs):
            flat[k] = one(job)
            step(k + 1)
    else:
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="graspgen-sim") as pool:
            futures = {pool.submit(one, job): k for k, job in enumerate(jobs)}
            try:
                for done, fut in enumerate(as_completed(futures), start=1):
                    flat[futures[fut]] = fut.result()
                    step(done)
            except BaseException:
                for fut in futures:
                    fut.cancel()
                raise
    m = len(members)
    results = cast(list[SimResult], flat)  # every job has its result: each one ended or the pool raised
    return [results[i * m : (i + 1) * m] for i in range(n)]


def summarise(results: list[SimResult]) -> dict[str, Any]:
    """Counts for stats: tested, succeeded, success rate, failures by reason, mean slip of the successes."""
    n = len(results)
    ok = [r for r in results if r.success]
    return {
        "tested": n,
        "succeeded": len(ok),
        "success_rate": round(len(ok) / n, 6) if n else None,
        "failures": {reason: sum(r.reason == reason for r in results) for reason in REASONS},
        "mean_slip_mm": round(float(np.mean([r.slip_mm for r in ok])), 4) if ok else None,
    }
