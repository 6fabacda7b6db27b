"""Physics validation of suction grasps in MuJoCo: seal a cup on the part, lift it against gravity, turn it, shake it.

A check of the suction criteria that shares none of their code. Criterion `hold`'s wrench model is not used at
all: the vacuum, the lip's compliance, friction and peel act as bodies and contacts. The seal at setup is the cup's
spring model (Dex-Net 3.0's, as criterion `seal`; the cup's walls are its springs), found on the part's triangles by
its own rays after the placement error, with its own discretisation of the springs. The simulation runs
in the grasp frame of the contract's suction cups (origin at the contact, the lip's centre on the surface; +Z the
approach, into the part along the cup's axis; the cup behind the lip at -Z). The cup stays put; the part is a free
body placed at `inv(T_object_grasp)` with the same seeded placement error as the jaw validation
(`physics.placement_error`), and it is loaded with `m (g - a(t))` at its centre of mass by the same schedule
(`physics.load_schedule`: lift along the pick's +Z, hold, turn gravity to the perturbation's direction, shake).

The cup (every constant in `SuctionSimConstants`):

1. setup, on the part's own triangles: rays along +Z from the cup's base (z = -cup_height) through `ring_rays` points
   of the lip circle (radius `cup_radius`) and through points inside it. The lip ring must meet the surface within
   the cup's travel (z in [-cup_height, +cup_height]) at every ray, in front of the part's material. The cup's wall
   then takes the shape of the contact ring: its springs may strain by at most `max_strain`. Around the lip, each of
   the `perimeter_springs` is a chord between two ring rays (a step or an edge between them lengthens it); across the
   wall, each cone spring runs from the cup's mount, `cup_height` behind the point where the axis meets the surface
   (the tool stops the cup there, whatever the placement error along the axis), to a ray's hit on the ring,
   stretched where the surface falls away and compressed where it rises. A ray between a spring's ends that meets
   the surface more than `gap_limit` deeper than both is a slot or pit crossing under the lip, which the lip does not
   bridge. Every ray inside the ring must meet the part (a ray that passes through is a hole the vacuum leaks
   through). Otherwise the outcome is `no_seal`.
2. the lip: `lips` small spheres on the ring, each on its own slide joint along the cup's axis with a spring (the
   bellows' and lip's axial compliance, at rest where the lip met the surface). Each sphere touches only a patch of
   the part's surface where it met it: a thin box in the tangent plane of the triangle hit there, fixed to the part.
   The part's mesh is exact under the lip (no convex decomposition: its slack, up to 1.5 mm on the shared parts, is
   the size of the seal's gap limit). Contacts lip/patch carry compression and Coulomb friction (the cup's
   `friction`, MuJoCo's elliptic cone with no-slip iterations); torsion about the axis and the moments about the
   tangential axes arise from the ring's geometry alone.
3. the vacuum: the pressure difference times the vector area of the lip polygon (scaled so that a flat ring gives
   exactly `vacuum x pi cup_radius^2`), pulling the part towards the cup at the ring's centroid, ramped up over
   `seal_time` and let settle for `settle_time` before the load.
4. the seal breaks when any lip point stands more than `gap_limit` off its patch for `seal_loss_time`: the vacuum
   collapses and the part falls -> `dropped` (peel: a moment lifts one side of the ring off the surface; pull-off:
   the whole ring). With the seal intact, the contact point moving more than the slip limit or the part turning
   more than the rotation limit relative to the cup -> `slipped` (sliding along the lip, twisting about the axis).

A `SuctionPerturbation` is a `physics.Perturbation` with a `vacuum_scale`; `suction_perturbation_set(seed)` is the
standard set (mass x0.5 / x1.5, vacuum x0.7, friction 0.3 / 0.6, gravity turned to the five other directions, a
lateral shake of 1 g, a seeded mixture).
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from typing import Any, cast

import numpy as np
import numpy.typing as npt
import trimesh

from .errors import InvalidMeshError, InvalidParameterError
from .physics import (
    SIM,
    Perturbation,
    SimConstants,
    load_schedule,
    mass_properties,
    placement_error,
    shake_directions_across,
)

__all__ = [
    "SuctionSimConstants",
    "SUCTION_SIM",
    "SUCTION_REASONS",
    "SuctionCup",
    "SuctionPerturbation",
    "SUCTION_NOMINAL",
    "suction_perturbation_set",
    "suction_validation_set",
    "SuctionSimPart",
    "SuctionSeal",
    "SuctionSimResult",
    "prepare_suction_part",
    "seal_at",
    "simulate_suction",
    "held",
    "summarise_suction",
]

#: failure reasons, in the order the stages can produce them
SUCTION_REASONS = ("no_seal", "dropped", "slipped")


def _positive(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


@dataclass(frozen=True)
class SuctionSimConstants:
    """Every constant of the suction simulation (SI units: m, s, kg, N, Pa)."""

    #: the jaw validation's constants used here as they are: timestep, gravity, the lift, hold, turn and shakes
    #: (physics.load_schedule), the placement error, the slip and rotation limits, the contact softness and the
    #: no-slip iterations; both validations judge a grasp under the same motion
    motion: SimConstants = SIM
    #: lip points simulated around the ring: 16 put one every 5.9 mm on a 30 mm cup, closer than the 1 mm gap limit
    #: lets a point-wise ring miss a peel (the tilt that opens 1 mm at one point opens at least 0.92 mm at the
    #: nearest simulated one)
    lips: int = 16
    #: rays through the lip circle at setup (a multiple of `lips`: every (ring_rays / lips)-th is a simulated lip
    #: point): one every 1.5 mm on a 30 mm cup, so an edge or a slot crossing the ring is found
    ring_rays: int = 64
    #: rays inside the ring at setup: (count, radius as a fraction of the cup radius) per circle; a hole wider than
    #: a third of the radius (5 mm in a 30 mm cup) meets at least one
    interior_rays: tuple[tuple[int, float], ...] = ((1, 0.0), (8, 1.0 / 3.0), (16, 2.0 / 3.0))
    #: the cup's lip as springs at setup (a divisor of `ring_rays`): each is the chord between two ring rays, rest
    #: length the flat ring's (2.9 mm on a 30 mm cup). A spring's length is the scale on which the lip bends: a step
    #: s between its ends strains it by sqrt(1 + (s / c0)^2) - 1, so 32 springs tolerate a 1.35 mm step at 10 %. It
    #: is the cup model's, the same 32-gon lip as criterion `seal`'s (Dex-Net 3.0's cup is an n-gon of springs):
    #: the two judge one cup (declared here too, as this module shares no code with the criteria; a test holds them
    #: equal)
    perimeter_springs: int = 32
    #: radius of each lip point's sphere: small against the cup, large enough that a tilted patch is met smoothly
    lip_sphere_radius: float = 1.0e-3
    #: mass of each lip point (kg): the lip and bellows of a 30 mm cup weigh a few grams in all; with the stiffness
    #: below one lip point oscillates at about 120 Hz, eight time steps per period
    lip_mass: float = 2.0e-3
    #: the lip's axial stiffness per metre of lip (N/m per m): a 30 mm cup's lip (94 mm) gets 19 kN/m, so 42 N of
    #: vacuum force (60 kPa) compresses it by 2.2 mm, the few millimetres a flat or 1.5-fold bellows cup gives under
    #: full vacuum. A stiffer lip keeps the part flatter under a moment; the moment at which the far side of the ring
    #: unloads (half the vacuum force times the radius) does not depend on it
    lip_stiffness: float = 2.0e5
    #: the lip's damping as a Kelvin-Voigt relaxation time (s): damping = stiffness x this. 10 ms is a loss factor
    #: of 0.3 at 5 Hz, where a part rocks on the lip, the order of the nitrile and silicone elastomers' (0.1-0.5);
    #: the lip points' own motion is then overdamped
    lip_relaxation_time: float = 0.01
    #: a lip point farther than this off the surface breaks the seal: an elastomer lip bridges a gap of about its own
    #: thickness (1 mm) before air rushes in; at setup, a slot or pit deeper than this under the lip is a leak
    gap_limit: float = 1.0e-3
    #: the gap must stay open this long (s): a leak that short does not let the cup's pressure rise (and one check
    #: interval of contact noise is no leak)
    seal_loss_time: float = 0.01
    #: the vacuum ramps up over this time (s) after the cup touches (a pump evacuates a small cup in well under
    #: 0.1 s), then the part settles for `settle_time` (s) before the load
    seal_time: float = 0.05
    settle_time: float = 0.05
    #: half the side of the surface patch under each lip point (m): larger than the slip limit (5 mm), so a part
    #: sliding along the cup is reported as slipped before a lip point runs off its patch
    patch_half_size: float = 8.0e-3
    #: thickness of the patch (m), behind the surface
    patch_thickness: float = 2.0e-3
    #: a surface met at a lip point more steeply than this (|cos| between the approach and the triangle's normal) is
    #: no seal: the lip would slide down a near-vertical wall
    min_facing: float = 0.2

    def __post_init__(self) -> None:
        if self.lips < 3 or self.ring_rays % self.lips:
            raise InvalidParameterError("ring_rays must be a multiple of lips (>= 3)", field="lips")
        if self.perimeter_springs < 3 or self.ring_rays % self.perimeter_springs:
            raise InvalidParameterError(
                "ring_rays must be a multiple of perimeter_springs (>= 3)", field="perimeter_springs"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


SUCTION_SIM = SuctionSimConstants()


@dataclass(frozen=True)
class SuctionCup:
    """The cup as the simulation needs it (a `SuctionSpec` has these fields): lip radius and the cup's height (m),
    the largest strain of its springs (0.1 = 10 %), the pressure difference (Pa) and the Coulomb coefficient
    lip/part."""

    cup_radius: float
    cup_height: float
    vacuum: float
    friction: float
    max_strain: float

    def __post_init__(self) -> None:
        for name in ("cup_radius", "cup_height", "vacuum", "friction", "max_strain"):
            v = getattr(self, name)
            if not _positive(v):
                raise InvalidParameterError(f"{name} must be a positive number, got {v!r}", field=name)
            object.__setattr__(self, name, float(v))

    @classmethod
    def of(cls, spec: Any) -> SuctionCup:
        """The cup of anything with the five attributes (a SuctionSpec, this class)."""
        if isinstance(spec, SuctionCup):
            return spec
        names = ("cup_radius", "cup_height", "vacuum", "friction", "max_strain")
        missing = [n for n in names if not hasattr(spec, n)]
        if missing:
            raise InvalidParameterError(f"a suction cup needs {', '.join(missing)}", field=missing[0])
        return cls(*(getattr(spec, n) for n in names))

    @property
    def vacuum_force(self) -> float:
        """vacuum x pi cup_radius^2 (N)."""
        return self.vacuum * math.pi * self.cup_radius**2


@dataclass(frozen=True)
class SuctionPerturbation(Perturbation):
    """A `physics.Perturbation` that may also lower the vacuum: `vacuum_scale` multiplies the cup's pressure
    difference (a weaker pump, a leaky hose)."""

    vacuum_scale: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (math.isfinite(self.vacuum_scale) and self.vacuum_scale > 0):
            raise InvalidParameterError(
                f"vacuum_scale must be positive, got {self.vacuum_scale!r}", field="vacuum_scale"
            )


SUCTION_NOMINAL = SuctionPerturbation()

_AXES = {"+X": (1.0, 0.0, 0.0), "-X": (-1.0, 0.0, 0.0), "+Y": (0.0, 1.0, 0.0), "-Y": (0.0, -1.0, 0.0)}
_AXES.update({"+Z": (0.0, 0.0, 1.0), "-Z": (0.0, 0.0, -1.0)})


def suction_perturbation_set(seed: int = 0) -> tuple[SuctionPerturbation, ...]:
    """The standard perturbations of a suction grasp (12), each changing the nominal simulation in one way, plus one
    seeded mixture:

    - mass x0.5 and x1.5 (mass and inertia); vacuum x0.7 (-30 %); friction 0.3 and 0.6 (absolute);
    - gravity turned to -Z, +X, -X, +Y, -Y of the grasp frame after the pick (+Z, the pick itself, is in every
      member): +-X and +-Y load the lip in shear and peel it, -Z rests the part on the cup;
    - a lateral shake: 1 g along two perpendicular directions across the cup's axis (seeded angle);
    - a mixture: seeded mass scale in [0.5, 1.5], vacuum scale in [0.7, 1], friction in [0.3, 0.6], one of the six
      gravity directions and a lateral shake of 1 g across it.
    """
    rng = np.random.default_rng([int(seed), 3333])
    members = [
        SuctionPerturbation("mass x0.5", mass_scale=0.5),
        SuctionPerturbation("mass x1.5", mass_scale=1.5),
        SuctionPerturbation("vacuum x0.7", vacuum_scale=0.7),
        SuctionPerturbation("friction 0.3", friction=0.3),
        SuctionPerturbation("friction 0.6", friction=0.6),
    ]
    members += [SuctionPerturbation(f"gravity {k}", gravity=_AXES[k]) for k in ("-Z", "+X", "-X", "+Y", "-Y")]
    a = float(rng.uniform(0.0, math.pi))
    lateral = ((math.cos(a), math.sin(a), 0.0), (-math.sin(a), math.cos(a), 0.0))
    members.append(SuctionPerturbation("lateral shake 1 g", shake_acceleration=9.81, shake_directions=lateral))
    g_key = str(rng.choice(list(_AXES)))
    g = np.asarray(_AXES[g_key])
    shake = shake_directions_across(tuple(g), float(rng.uniform(0.0, math.pi)))
    ms, vs, mu = float(rng.uniform(0.5, 1.5)), float(rng.uniform(0.7, 1.0)), float(rng.uniform(0.3, 0.6))
    members.append(
        SuctionPerturbation(
            f"mixed (mass x{ms:.2f}, vacuum x{vs:.2f}, friction {mu:.2f}, gravity {g_key}, shake 1 g)",
            mass_scale=ms,
            vacuum_scale=vs,
            friction=mu,
            gravity=(float(g[0]), float(g[1]), float(g[2])),
            shake_acceleration=9.81,
            shake_directions=shake,
        )
    )
    return tuple(members)


def suction_validation_set(friction: float) -> tuple[SuctionPerturbation, ...]:
    """What `validate` simulates every suction grasp under: the nominal pick and the ends of the uncertainty a cup's
    hold depends on most, each alone: the part 50 % heavier (mass x1.5), the pump 30 % weaker (vacuum x0.7), the
    lip's friction 20 % lower (x0.8 of the run's `friction`), and the load turned across the cup's axis after the
    pick (gravity along the grasp frame's +X: shear on the lip and a peel moment). A validated cup holds in all
    five (the jaws' validation_set, for a cup)."""
    return (
        SUCTION_NOMINAL,
        SuctionPerturbation("mass x1.5", mass_scale=1.5),
        SuctionPerturbation("vacuum x0.7", vacuum_scale=0.7),
        SuctionPerturbation("friction x0.8", friction=0.8 * float(friction)),
        SuctionPerturbation("gravity +X", gravity=_AXES["+X"]),
    )


@dataclass
class SuctionSimPart:
    """The part as the suction simulation holds it: its mesh (metres, object frame; rays are cast on its triangles)
    and its mass properties (kg, centre of mass (3,) object frame, inertia (3, 3) about it, kg m^2)."""

    mesh: trimesh.Trimesh
    mass: float
    center_of_mass: np.ndarray
    inertia: np.ndarray
    note: str | None = None
    #: the mesh's faces are wound consistently around a closed volume: a ray's first hit tells inside from outside
    closed: bool = False
    _lock: Any = field(default_factory=threading.Lock, repr=False, compare=False)

    def rays(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every hit of rays (origins (n, 3), unit directions (n, 3), object frame) with the part's triangles:
        (ray index (h,), distance along the ray (h,) m, triangle index (h,)), sorted by ray, then distance."""
        with self._lock:  # trimesh's intersector builds its tree on first use
            loc, ray, tri = self.mesh.ray.intersects_location(origins, directions, multiple_hits=True)
        ray = np.asarray(ray, dtype=np.int64).reshape(-1)
        tri = np.asarray(tri, dtype=np.int64).reshape(-1)
        loc = np.asarray(loc, dtype=np.float64).reshape(-1, 3)
        t = np.einsum("ij,ij->i", loc - origins[ray], directions[ray])
        order = np.lexsort((t, ray))
        return ray[order], t[order], tri[order]


def prepare_suction_part(
    mesh: trimesh.Trimesh, *, mass_kg: float | None = None, density: float | None = None
) -> SuctionSimPart:
    """The part for `simulate_suction`: `mesh` in metres, object frame; its mass `mass_kg` (kg) or its volume times
    `density` (kg/m^3), exactly one of them (the inertia from the mesh's shape, uniform material, as
    physics.prepare_part). InvalidParameterError on a missing or bad value, InvalidMeshError on an empty mesh."""
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InvalidMeshError("the suction simulation needs a triangle mesh with faces")
    if (mass_kg is None) == (density is None):
        raise InvalidParameterError(
            "the suction simulation needs the part's mass_kg (kg) or its density (kg/m^3), exactly one",
            field="mass_kg",
        )
    for name, v in (("mass_kg", mass_kg), ("density", density)):
        if v is not None and not _positive(v):
            raise InvalidParameterError(f"{name} must be a positive number, got {v!r}", field=name)
    mass, com, inertia, note = mass_properties(
        mesh, None if density is None else float(density), None if mass_kg is None else float(mass_kg)
    )
    closed = bool(mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0)
    return SuctionSimPart(mesh, mass, com, inertia, note, closed)


def _as_part(part: Any, mass_kg: float | None, density: float | None) -> SuctionSimPart:
    """A SuctionSimPart from a mesh (with mass_kg or density), a SuctionSimPart, or a physics.SimPart (its mesh and
    mass properties); mass_kg rescales a prepared part's mass and inertia."""
    if isinstance(part, trimesh.Trimesh):
        return prepare_suction_part(part, mass_kg=mass_kg, density=density)
    if density is not None:
        raise InvalidParameterError("density applies to a mesh, not to a prepared part", field="density")
    if not isinstance(part, SuctionSimPart):
        mesh = getattr(part, "mesh", None)
        inertia = getattr(part, "inertia", None)
        if not isinstance(mesh, trimesh.Trimesh) or inertia is None:
            raise InvalidParameterError("part must be a trimesh, a SuctionSimPart or a physics.SimPart", field="part")
        closed = bool(mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0)
        com = np.asarray(part.center_of_mass, dtype=np.float64)
        part = SuctionSimPart(mesh, float(part.mass), com, np.asarray(inertia, dtype=np.float64), None, closed)
    if mass_kg is None:
        return cast(SuctionSimPart, part)
    if not _positive(mass_kg):
        raise InvalidParameterError(f"mass_kg must be a positive number, got {mass_kg!r}", field="mass_kg")
    k = float(mass_kg) / part.mass
    return SuctionSimPart(part.mesh, float(mass_kg), part.center_of_mass, part.inertia * k, part.note, part.closed)


# --------------------------------------------------------------------------------------------------------------------
# the seal at setup


@dataclass(frozen=True)
class SuctionSeal:
    """Where the cup's lip meets the part for one grasp, at the placement (with its placement error).

    `R`, `p`: the part's pose in the grasp frame (the cup's); `ok` and, when not, `detail` (why there is no seal);
    `strain`: the largest strain of the cup's perimeter and cone springs (`_lip_strain`); `lip_z` (lips,) the height
    of each simulated lip point where it meets the surface (grasp frame z, m), `lip_points` (lips, 3) and
    `lip_normals` (lips, 3) the surface there (object frame, normals towards the cup), `centre` (3,) the contact point
    on the cup's axis (object frame)."""

    R: np.ndarray
    p: np.ndarray
    ok: bool
    detail: str | None
    strain: float
    lip_z: np.ndarray
    lip_points: np.ndarray
    lip_normals: np.ndarray
    centre: np.ndarray


def _ring(count: int, radius: float) -> np.ndarray:
    """(count, 2) points on a circle, the first on +X, counter-clockwise about +Z."""
    return np.array(
        [(radius * math.cos(2 * math.pi * k / count), radius * math.sin(2 * math.pi * k / count)) for k in range(count)]
    ).reshape(-1, 2)


def _lip_strain(xy: np.ndarray, z: np.ndarray, height: float, springs: int) -> float:
    """The largest strain of the cup's springs when the ring points `xy` (n, 2) of the cup's plane meet the surface
    at heights `z` (n,) (m, along the axis from where the axis meets the surface): `springs` perimeter springs, the
    chords between every (n / springs)-th ring point against the flat ring's, and the cone springs from the cup's
    mount, `height` behind that point on the axis, to every ring point, stretched or compressed."""
    ring = np.column_stack([xy, z])
    ends = ring[:: len(xy) // springs]
    chord = np.linalg.norm(np.roll(ends, -1, axis=0) - ends, axis=1)
    chord0 = np.linalg.norm(np.roll(ends[:, :2], -1, axis=0) - ends[:, :2], axis=1)  # the flat ring's
    perimeter = float(np.max(chord / chord0)) - 1.0
    mount = np.array([0.0, 0.0, -height])
    cone = np.linalg.norm(ring - mount, axis=1) / math.hypot(float(np.linalg.norm(xy[0])), height) - 1.0
    return max(perimeter, float(np.max(np.abs(cone))))


def seal_at(
    part: SuctionSimPart,
    T_object_grasp: np.ndarray,
    cup: SuctionCup,
    *,
    seed: int = 0,
    key: int = 0,
    constants: SuctionSimConstants = SUCTION_SIM,
) -> SuctionSeal:
    """The lip ring of `cup` at the grasp (pose (4, 4), object frame) on the part's triangles, after the seeded
    placement error that `key` and `seed` pick (the same under every perturbation)."""
    c = constants
    rng = np.random.default_rng([int(seed), int(key)])
    R_err, t_err = placement_error(rng, c.motion)
    T = np.asarray(T_object_grasp, dtype=np.float64)
    T_go = np.linalg.inv(T)
    R0 = R_err @ T_go[:3, :3]
    p0 = R_err @ T_go[:3, 3] + t_err
    R_og, p_og = R0.T, -R0.T @ p0  # the cup's frame in the object frame
    r, hgt = cup.cup_radius, cup.cup_height
    rings = [_ring(c.ring_rays, r)] + [_ring(n, f * r) if f > 0 else np.zeros((n, 2)) for n, f in c.interior_rays]
    xy = np.concatenate(rings)
    n_ring = c.ring_rays
    origins_g = np.column_stack([xy, np.full(len(xy), -hgt)])
    origins = origins_g @ R_og.T + p_og
    direction = R_og[:, 2]
    directions = np.tile(direction, (len(xy), 1))
    ray, t, tri = part.rays(origins, directions)
    first = np.full(len(xy), -1, dtype=np.int64)
    idx = np.flatnonzero(np.r_[True, ray[1:] != ray[:-1]]) if len(ray) else np.zeros(0, dtype=np.int64)
    first[ray[idx]] = idx
    normals = np.asarray(part.mesh.face_normals, dtype=np.float64)
    empty = np.zeros((0, 3))
    lip_every = n_ring // c.lips

    def fail(detail: str, strain: float = math.inf) -> SuctionSeal:
        return SuctionSeal(R0, p0, False, detail, strain, np.zeros(0), empty, empty, T[:3, 3].copy())

    z = np.full(len(xy), math.nan)
    hit = first >= 0
    z[hit] = t[first[hit]] - hgt
    facing = np.zeros(len(xy))
    facing[hit] = normals[tri[first[hit]]] @ direction
    if part.closed and np.any(facing[hit] > 0):
        return fail("the part reaches behind the lip into the cup")
    ring_z = z[:n_ring]
    missing = int(np.sum(~(ring_z <= hgt)))  # no hit, or beyond the cup's reach
    if missing:
        return fail(f"the lip ring misses the surface at {missing} of {n_ring} points")
    if not np.all(hit[n_ring:]):
        return fail(f"{int(np.sum(~hit[n_ring:]))} rays inside the ring pass through the part (a hole)")
    centre_z = float(z[n_ring])  # the first interior ray is the axis: the tool stops the cup's mount h behind it
    strain = _lip_strain(xy[:n_ring], ring_z - centre_z, hgt, c.perimeter_springs)
    if strain > cup.max_strain:
        return fail(
            f"the lip's springs would strain {100 * strain:.1f} % (max_strain {100 * cup.max_strain:.1f} %)", strain
        )
    per = n_ring // c.perimeter_springs
    ends = ring_z[::per]
    bridge = np.maximum(ends, np.roll(ends, -1)).repeat(per)  # the deeper end of the spring over each ray
    pits = int(np.sum(ring_z > bridge + c.gap_limit))
    if pits:
        return fail(f"a slot or pit crosses under the lip at {pits} of {n_ring} points (deeper than the gap limit)")
    lips = np.arange(0, n_ring, lip_every)
    n_lip = normals[tri[first[lips]]]
    n_lip = np.where((n_lip @ direction)[:, None] > 0, -n_lip, n_lip)  # towards the cup (an open mesh's winding)
    if np.any(-(n_lip @ direction) < c.min_facing):
        return fail("the lip meets a surface nearly parallel to the approach", strain)
    points = origins[lips] + directions[lips] * t[first[lips]][:, None]
    centre = origins[n_ring] + direction * t[first[n_ring]]
    return SuctionSeal(R0, p0, True, None, strain, ring_z[lips].copy(), points, n_lip, centre)


# --------------------------------------------------------------------------------------------------------------------
# the model


def _fmt(values: npt.ArrayLike) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.asarray(values).ravel())


def _xml(part: SuctionSimPart, seal: SuctionSeal, cup: SuctionCup, p: Perturbation, c: SuctionSimConstants) -> str:
    """The MuJoCo model of one grasp under perturbation `p`: the lip points on their springs, the part with a patch
    under each, one contact pair per lip point."""
    m = c.motion
    mu = cup.friction if p.friction is None else float(p.friction)
    noslip = 0 if p.soft_friction else m.noslip_iterations
    rho = c.lip_sphere_radius
    k = c.lip_stiffness * 2 * math.pi * cup.cup_radius / c.lips
    damping = k * c.lip_relaxation_time
    xy = _ring(c.lips, cup.cup_radius)
    facing = -(seal.lip_normals @ seal.R.T)[:, 2]  # |cos| of each patch's normal with the axis, grasp frame
    # each sphere rests touching its patch's plane: its tip at the hit's height, less what the tilt lifts it by
    q0 = seal.lip_z + rho - rho / facing
    lips = []
    for i in range(c.lips):
        lips.append(
            f'<body name="lip{i}" pos="{xy[i, 0]:.9g} {xy[i, 1]:.9g} 0">'
            f'<joint name="lip{i}" type="slide" axis="0 0 1" stiffness="{k:.9g}" springref="{q0[i]:.9g}" '
            f'damping="{damping:.9g}" range="{q0[i] - cup.cup_height:.9g} {q0[i] + cup.cup_height:.9g}"/>'
            f'<inertial pos="0 0 0" mass="{c.lip_mass:.9g}" diaginertia="1e-8 1e-8 1e-8"/>'
            f'<geom name="lip{i}" type="sphere" size="{rho:.9g}" pos="0 0 {-rho:.9g}" contype="0" conaffinity="0"/>'
            "</body>"
        )
    s, h = c.patch_half_size, c.patch_thickness / 2
    patches = []
    for i in range(c.lips):
        n = seal.lip_normals[i]
        patches.append(
            f'<geom name="patch{i}" type="box" size="{s:.9g} {s:.9g} {h:.9g}" pos="{_fmt(seal.lip_points[i] - n * h)}" '
            f'zaxis="{_fmt(n)}" contype="0" conaffinity="0" mass="0"/>'
        )
    pairs = "\n    ".join(
        f'<pair geom1="lip{i}" geom2="patch{i}" condim="3" friction="{mu:.9g} {mu:.9g} 0.005 0.0001 0.0001" '
        f'solref="{_fmt(m.solref)}"/>'
        for i in range(c.lips)
    )
    mass = part.mass * p.mass_scale
    I = part.inertia * p.mass_scale  # noqa: E741 - the inertia tensor's usual name
    full = _fmt([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])
    lip_bodies = "\n    ".join(lips)
    patch_geoms = "\n      ".join(patches)
    return f"""
<mujoco model="graspgen-suction">
  <compiler angle="radian" autolimits="true" boundmass="1e-9" boundinertia="1e-15"/>
  <option timestep="{m.timestep:.9g}" gravity="0 0 0" integrator="implicitfast" cone="elliptic" impratio="10"
          noslip_iterations="{noslip:d}"/>
  <worldbody>
    {lip_bodies}
    <body name="part">
      <freejoint name="part"/>
      <inertial pos="{_fmt(part.center_of_mass)}" mass="{mass:.9g}" fullinertia="{full}"/>
      {patch_geoms}
    </body>
  </worldbody>
  <contact>
    {pairs}
  </contact>
</mujoco>
"""


# --------------------------------------------------------------------------------------------------------------------
# one grasp


@dataclass(frozen=True)
class SuctionSimResult:
    """The outcome of one simulated suction grasp."""

    success: bool
    reason: str | None  # None on success, else one of SUCTION_REASONS
    slip_mm: float  # largest displacement of the contact point relative to the cup after sealing
    rotation_deg: float  # largest rotation of the part relative to the cup after sealing
    #: lip points touching the part once sealed (0 for no_seal)
    lips: int
    #: the largest strain of the lip's perimeter and cone springs at setup (inf when the ring misses the surface)
    strain: float
    #: the largest gap (mm) any lip point opened while the seal held (capped at twice the gap limit)
    peak_gap_mm: float = 0.0
    #: simulated time (s) at the failure (the end for a success)
    time_s: float = 0.0
    #: why there is no seal, or which lip point opened
    detail: str | None = None
    #: the perturbation this outcome was simulated under (its name)
    member: str | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "success": self.success,
            "reason": self.reason,
            "slip_mm": round(self.slip_mm, 4),
            "rotation_deg": round(self.rotation_deg, 4),
            "peak_gap_mm": round(self.peak_gap_mm, 4),
        }
        if self.detail is not None:
            out["detail"] = self.detail
        if self.member is not None:
            out["member"] = self.member
        return out


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=np.float64).ravel())
    return q


def _simulate_one(
    part: SuctionSimPart, seal: SuctionSeal, cup: SuctionCup, p: Perturbation, c: SuctionSimConstants
) -> SuctionSimResult:
    """One grasp whose seal is `seal` under perturbation `p`."""
    if not seal.ok:
        return SuctionSimResult(False, "no_seal", 0.0, 0.0, 0, seal.strain, detail=seal.detail, member=p.name)
    import mujoco

    mc = c.motion
    m = mujoco.MjModel.from_xml_string(_xml(part, seal, cup, p, c))
    d = mujoco.MjData(m)
    body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "part")
    adr = m.jnt_qposadr[m.body_jntadr[body]]
    joints = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"lip{i}") for i in range(c.lips)]
    lip_adr = np.array([m.jnt_qposadr[j] for j in joints])
    d.qpos[lip_adr] = m.qpos_spring[lip_adr]
    d.qpos[adr : adr + 3] = seal.p
    d.qpos[adr + 3 : adr + 7] = _quat_wxyz(seal.R)
    mujoco.mj_forward(m, d)

    xy = _ring(c.lips, cup.cup_radius)
    flat_area = 0.5 * c.lips * cup.cup_radius**2 * math.sin(2 * math.pi / c.lips)
    vacuum = cup.vacuum * getattr(p, "vacuum_scale", 1.0) * math.pi * cup.cup_radius**2 / flat_area
    mass = part.mass * p.mass_scale
    dt = mc.timestep * c.motion.check_steps
    torque0 = np.zeros(3)

    def pull(scale: float) -> None:
        """The vacuum's force on the part: the pressure times the lip polygon's vector area, at its centroid."""
        P = np.column_stack([xy, d.qpos[lip_adr]])
        area = 0.5 * np.sum(np.cross(P, np.roll(P, -1, axis=0)), axis=0)
        d.qfrc_applied[:] = 0.0
        if scale > 0.0:
            force = -scale * vacuum * area
            mujoco.mj_applyFT(m, d, force, torque0, P.mean(axis=0), body, d.qfrc_applied)

    rho, s_half = c.lip_sphere_radius, c.patch_half_size

    def gaps() -> np.ndarray:
        """Each lip point's distance (m, >= 0) from its patch of the surface: the sphere's clearance from the patch's
        plane; 2 x gap_limit for a sphere beside its patch (run off the surface the lip met)."""
        pos, R = pose()
        P = seal.lip_points @ R.T + pos  # the patches' surface points and normals, grasp frame
        N = seal.lip_normals @ R.T
        centres = np.column_stack([xy, d.qpos[lip_adr] - rho])
        off = centres - P
        normal = np.einsum("ij,ij->i", off, N)
        lateral = np.linalg.norm(off - normal[:, None] * N, axis=1)
        out: np.ndarray = np.maximum(normal - rho, 0.0)
        out[lateral > s_half] = 2 * c.gap_limit
        return out

    def pose() -> tuple[np.ndarray, np.ndarray]:
        return d.xpos[body].copy(), d.xmat[body].reshape(3, 3).copy()

    open_for = 0.0
    peak = 0.0
    t_sim = 0.0
    n_seal = max(1, int(round(c.seal_time / dt)))
    n_settle = int(round(c.settle_time / dt))

    def step(scale: float) -> int:
        """One check interval; the lip point that has stood open for seal_loss_time, else -1."""
        nonlocal open_for, peak, t_sim
        pull(scale)
        mujoco.mj_step(m, d, nstep=mc.check_steps)
        t_sim += dt
        g = gaps()
        worst = int(np.argmax(g))
        if g[worst] > c.gap_limit:
            open_for += dt
            if open_for >= c.seal_loss_time - 1e-12:
                return worst
        else:
            open_for = 0.0
            peak = max(peak, float(g[worst]))
        return -1

    def dropped(lip: int, slip: float, rot: float) -> SuctionSimResult:
        detail = f"lip point {lip} opened more than {c.gap_limit * 1e3:g} mm: the seal broke"
        return SuctionSimResult(False, "dropped", slip * 1e3, rot, lips, seal.strain, peak * 1e3, t_sim, detail, p.name)

    lips = c.lips
    for k in range(n_seal + n_settle):
        lost = step(min(1.0, (k + 1) / n_seal))
        if lost >= 0:
            return dropped(lost, 0.0, 0.0)
    lips = int(np.sum(gaps() <= 0.0))
    p_ref, R_ref = pose()
    ring_ref = (seal.lip_points @ R_ref.T + p_ref)[:, :2]
    slip = rot = 0.0
    for a in load_schedule(mc, p, dt):
        d.xfrc_applied[body, :3] = mass * a  # at the centre of mass, constant over one check interval
        lost = step(1.0)
        pos, R = pose()
        # sliding along the lip: the ring's material points moving across the cup's axis (a twist moves them too;
        # a tilt on the compliant lip hardly does, and the gap judges it)
        ring = (seal.lip_points @ R.T + pos)[:, :2]
        slip = max(slip, float(np.max(np.linalg.norm(ring - ring_ref, axis=1))))
        cos = (np.trace(R_ref.T @ R) - 1.0) / 2.0
        rot = max(rot, math.degrees(math.acos(min(1.0, max(-1.0, cos)))))
        if lost >= 0:
            return dropped(lost, slip, rot)
        if slip > mc.slip_limit:
            return SuctionSimResult(
                False, "slipped", slip * 1e3, rot, lips, seal.strain, peak * 1e3, t_sim, None, p.name
            )
    return SuctionSimResult(True, None, slip * 1e3, rot, lips, seal.strain, peak * 1e3, t_sim, None, p.name)


def simulate_suction(
    part: SuctionSimPart | trimesh.Trimesh | Any,
    poses: np.ndarray,
    cup: SuctionCup | Any,
    *,
    mass_kg: float | None = None,
    density: float | None = None,
    perturbations: Iterable[Perturbation] | None = None,
    seed: int = 0,
    keys: np.ndarray | None = None,
    workers: int | None = None,
    constants: SuctionSimConstants = SUCTION_SIM,
    progress: Callable[[int, int], None] | None = None,
) -> list[list[SuctionSimResult]]:
    """Simulate every suction grasp (poses (n, 4, 4) T_object_grasp, metres) under every perturbation; `out[i][j]` is
    grasp i under perturbation j (None: the nominal simulation alone). A grasp holds when every `out[i][j].success`.

    `part`: a trimesh (metres, object frame; then `mass_kg` or `density` is required), a prepared `SuctionSimPart`
    or a `physics.SimPart` (its mesh and mass properties; `mass_kg` rescales them). `cup`: a `SuctionCup` or anything
    with its five attributes (a SuctionSpec). `key` (default the grasp's index) and `seed` pick each grasp's
    placement error, the same under every perturbation. The seals are found in the calling thread, the simulations
    run in `workers` threads (default: the CPU count). `progress(done, total)` is called in the calling thread after
    each simulation; if it raises, the simulations not yet started are dropped and the exception propagates."""
    sim_part = _as_part(part, mass_kg, density)
    spec = SuctionCup.of(cup)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not np.all(np.isfinite(poses)):
        raise InvalidParameterError(f"poses must be finite (n, 4, 4) transforms, not {poses.shape}", field="poses")
    n = len(poses)
    keys = np.arange(n) if keys is None else np.asarray(keys).reshape(-1)
    if len(keys) != n:
        raise InvalidParameterError("keys must give one key per pose", field="keys")
    members: Sequence[Perturbation] = list(perturbations) if perturbations is not None else [SUCTION_NOMINAL]
    if n == 0 or not members:
        return [[] for _ in range(n)]
    seals = [seal_at(sim_part, poses[i], spec, seed=seed, key=int(keys[i]), constants=constants) for i in range(n)]
    jobs = [(i, j) for i in range(n) for j in range(len(members))]

    def one(job: tuple[int, int]) -> SuctionSimResult:
        i, j = job
        return _simulate_one(sim_part, seals[i], spec, members[j], constants)

    flat: list[SuctionSimResult | None] = [None] * len(jobs)
    workers = min(len(jobs), workers or os.cpu_count() or 1)
    if workers <= 1:
        for k, job in enumerate(jobs):
            flat[k] = one(job)
            if progress is not None:
                progress(k + 1, len(jobs))
    else:
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="graspgen-suction") as pool:
            futures = {pool.submit(one, job): k for k, job in enumerate(jobs)}
            try:
                for done, fut in enumerate(as_completed(futures), start=1):
                    flat[futures[fut]] = fut.result()
                    if progress is not None:
                        progress(done, len(jobs))
            except BaseException:
                for fut in futures:
                    fut.cancel()
                raise
    results = cast(list[SuctionSimResult], flat)  # every job has its result: each one ended or the pool raised
    m = len(members)
    return [results[i * m : (i + 1) * m] for i in range(n)]


def held(grid: list[list[SuctionSimResult]]) -> np.ndarray:
    """(n,) bool: grasp i of simulate_suction's `grid` held under every perturbation it was simulated under."""
    return np.array([bool(row) and all(r.success for r in row) for row in grid], dtype=bool)


def summarise_suction(results: list[SuctionSimResult]) -> dict[str, Any]:
    """Counts: tested, succeeded, success rate, failures by reason, mean slip of the successes (mm)."""
    n = len(results)
    ok = [r for r in results if r.success]
    return {
        "tested": n,
        "succeeded": len(ok),
        "success_rate": round(len(ok) / n, 6) if n else None,
        "failures": {reason: sum(r.reason == reason for r in results) for reason in SUCTION_REASONS},
        "mean_slip_mm": round(float(np.mean([r.slip_mm for r in ok])), 4) if ok else None,
    }
