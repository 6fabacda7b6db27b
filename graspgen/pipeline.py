"""generate() and recluster(): the only orchestration of the method (sample, pairs, collision, cluster, export)."""

from __future__ import annotations

import inspect
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, overload

import numpy as np
import trimesh

from . import antipodal, clustering, libm, quality, sampling
from . import collision as _collision
from . import hold as _hold
from .coverage import coverage
from .errors import InvalidMeshError, InvalidParameterError
from .export import Candidates, GraspSet
from .gripper import KIND as PARALLEL
from .gripper import GripperSpec
from .kinds import check_params_for_kind, gripper_from_dict
from .params import Params, QualityOptions, from_keywords, keyword_parameters
from .parts import Part, as_part, load_part
from .seating import SEAT_TRIES, Seated, SeatHold, SeatJudge, nearest_members
from .suction import KIND as SUCTION
from .suction import SuctionCandidates, SuctionGraspSet, SuctionSpec, generate_suction, recluster_suction
from .transforms import choose_roll, grasp_frames, roll_angles_rad

if TYPE_CHECKING:
    from .physics import SimResult

__all__ = ["generate", "recluster", "STAGES", "MAX_CANDIDATES", "choose_roll"]

#: the stages reported to progress callbacks, in order ("validate" only with validate=True)
STAGES = ("load", "sample", "pairs", "collision", "cluster", "validate", "export")
#: the collision stage reports progress (and so sees a cancel) after its first tenth of the pairs, then about every
#: _COLLISION_REPORT_S seconds. Each report ends a call of the parallel kernel (its threads wait for the slowest),
#: so reports are spaced by time: a short stage makes few calls, and a cancel waits about that long in a long one
_COLLISION_BATCHES = 10
_COLLISION_REPORT_S = 0.5
_MIN_SEGMENT = 4096
#: pairs passing (a)-(c) are made and collision-checked this many at a time (about 120 bytes each while in flight),
#: so memory is bounded by the candidates that survive, not by the pairs: at 10,000 points one block holds them all
_PAIR_BLOCK = 4_000_000
#: collision-free candidates beyond this stop the run with a clear error (about 130 bytes each are kept, and
#: clustering, coverage and the candidate export work on all of them: 50 M is about 10 GB at the peak)
MAX_CANDIDATES = 50_000_000

Progress = Callable[[str, float], None]


def _noop(stage: str, fraction: float) -> None:
    return None


def _signature_with_fields(func: Callable[..., Any], *classes: type) -> inspect.Signature:
    """`func`'s signature with its `**keywords` replaced by one keyword per field of `classes`, with the field's
    default: what inspect.signature and help() show of generate() and recluster() (params.py declares them once)."""
    sig = inspect.signature(func)
    own = [p for p in sig.parameters.values() if p.kind is not inspect.Parameter.VAR_KEYWORD]
    return sig.replace(parameters=[*own, *keyword_parameters(*classes)])


@overload
def generate(
    mesh_or_path: str | os.PathLike[str] | trimesh.Trimesh | Part,
    gripper: GripperSpec,
    *,
    units: str | None = None,
    recording: Any = None,
    progress: Progress | None = None,
    object_name: str | None = None,
    object_version: int | None = None,
    params: Params | None = None,
    options: QualityOptions | None = None,
    **run_params: Any,
) -> GraspSet: ...


@overload
def generate(
    mesh_or_path: str | os.PathLike[str] | trimesh.Trimesh | Part,
    gripper: SuctionSpec,
    *,
    units: str | None = None,
    recording: Any = None,
    progress: Progress | None = None,
    object_name: str | None = None,
    object_version: int | None = None,
    params: Params | None = None,
    options: QualityOptions | None = None,
    **run_params: Any,
) -> SuctionGraspSet: ...


@overload
def generate(
    mesh_or_path: str | os.PathLike[str] | trimesh.Trimesh | Part,
    gripper: dict[str, Any],
    *,
    units: str | None = None,
    recording: Any = None,
    progress: Progress | None = None,
    object_name: str | None = None,
    object_version: int | None = None,
    params: Params | None = None,
    options: QualityOptions | None = None,
    **run_params: Any,
) -> GraspSet | SuctionGraspSet: ...


def generate(
    mesh_or_path: str | os.PathLike[str] | trimesh.Trimesh | Part,
    gripper: GripperSpec | SuctionSpec | dict[str, Any],
    *,
    units: str | None = None,
    recording: Any = None,
    progress: Progress | None = None,
    object_name: str | None = None,
    object_version: int | None = None,
    params: Params | None = None,
    options: QualityOptions | None = None,
    **run_params: Any,
) -> GraspSet | SuctionGraspSet:
    """Grasps for one part and one gripper (see CONTRACT.md, Python API).

    The run parameters are the fields of `Params` and `QualityOptions` (params.py), each a keyword argument with the
    field's default (the signature lists them), or given ready as `params=` / `options=` (not both ways at once).

    `recording` is a path for a Rerun .rrd or a `rerun.RecordingStream` to log into. `progress(stage, fraction)`
    is called within and between stages; raising `graspgen.errors.Cancelled` from it stops the run.

    Quality and validation (docs/QUALITY.md), all off by default: `select="best-near-medoid"` scores every
    candidate (quality.py) and exports, per final cluster, the best-scoring member near the medoid, best first;
    `validate=True` simulates every exported grasp in MuJoCo (physics.py, with the part's mass and the gripper's
    grip force) and replaces a failing one by up to `repair_limit` members of its cluster, nearest first.

    Holding the part (CONTRACT.md, criterion (e), hold.py): with the part's mass (`mass_kg`, or `density` in
    kg/m^3 times the mesh volume) and the gripper's `grip_force`, only candidates that hold the part against its
    weight plus `accel` in every direction are kept (`hold="off"` skips it). `position_tolerance` (m): criterion
    (c) holds for every surface normal within this distance of each contact. Every free roll is checked against
    the mesh's triangles (graspgen.collision).

    A suction cup (a SuctionSpec, or a spec dict of kind "suction") runs the suction method instead
    (graspgen.suction, docs/HOLD.md "Suction cups: the model") and returns a SuctionGraspSet.
    """
    report = progress or _noop
    params, options = from_keywords("generate", run_params, (Params, params), (QualityOptions, options))
    spec = gripper if isinstance(gripper, (GripperSpec, SuctionSpec)) else gripper_from_dict(gripper)
    if isinstance(spec, SuctionSpec):
        return generate_suction(
            mesh_or_path,
            spec,
            params=params,
            options=options,
            units=units,
            recording=recording,
            progress=progress,
            object_name=object_name,
            object_version=object_version,
        )
    check_params_for_kind(PARALLEL, params, options)
    _check_geometry_params(spec, params)
    mu = spec.friction if params.friction is None else params.friction
    run = _Run(spec, params, options, mu, report, timings={}, started=time.perf_counter())

    loaded = _load(run, mesh_or_path, units, object_name)
    _check_geometry_part(spec, loaded.part)
    surface = _sample(run, loaded.part)
    pairs = _pairs(run, surface)
    collided = _collide(run, surface, pairs)  # (d) against the points
    held = _hold_part(run, loaded, surface, collided)  # (e)
    checked = _check_mesh(run, surface, pairs, held.survivors)  # (d) again, against the triangles
    cands = _candidates(run, loaded, surface, pairs, checked.survivors)
    stats = _stats(run, loaded, surface, pairs, collided, held, checked, cands)

    part = loaded.part
    obj = {
        "name": object_name or part.name,
        "version": object_version,
        "sha256": part.sha256,
        "source_units": part.source_units,
    }
    extras = _Extras(options, part, loaded.mass_kg, (surface.points, surface.normals), surface.tree)
    params = replace(params, hold="any" if held.active else "off")
    result = _cluster_and_export(cands, obj, spec, params, mu, stats, report, run.started, list(part.warnings), extras)
    if recording is not None:
        from .recording import record_run

        record_run(recording, result, sample_points=surface.points, sample_normals=surface.normals)
    return result


generate.__signature__ = _signature_with_fields(generate, Params, QualityOptions)  # type: ignore[attr-defined]  # inspect reads it; mypy does not model function attributes

# --------------------------------------------------------------------------------------------------------------------
# the stages of generate(), each a function of the run and the earlier stages' results


@dataclass(frozen=True)
class _Run:
    """One generate() call's checked inputs, and where the stages report progress and record their timings."""

    spec: GripperSpec
    params: Params
    options: QualityOptions
    #: the friction coefficient the run uses: the parameter, else the gripper's
    mu: float
    report: Progress
    #: stage -> seconds, in the order the stages ran (the export's stats.timings_s)
    timings: dict[str, float]
    started: float


@dataclass(frozen=True)
class _Loaded:
    """The part in metres, its mass (kg; None when neither mass_kg nor density was given) and centre of mass."""

    part: Part
    mass_kg: float | None
    #: why the mass is the convex hull's (an open mesh or a point cloud has no volume of its own)
    mass_note: str | None
    center_of_mass: np.ndarray  # (3,) metres


@dataclass(frozen=True)
class _Surface:
    """The sampled surface in the pair grid's order, and what the exact checks need of the part's triangles."""

    points: np.ndarray  # (k, 3) float64, metres
    normals: np.ndarray  # (k, 3) float64, unit, outward
    spacing: float  # mean nearest-neighbour distance, metres
    min_spacing: float
    tree: _collision.MeshTree | None  # None for a point cloud
    #: per point, the largest angle (rad) to a surface normal within the position tolerance; None: nothing near
    spread: np.ndarray | None


@dataclass(frozen=True)
class _Pairs:
    """Criteria (a)-(c) counted over all pairs (the plan fills them in blocks), and the collision model."""

    plan: antipodal.PairPlan
    half_angle: float  # friction cone half-angle over the safety factor, rad
    model: _collision.CollisionModel


@dataclass(frozen=True)
class _Survivors:
    """Pairs (i, j: indices into the surface) that passed every criterion so far, with their free rolls."""

    i: np.ndarray  # (n,) int64
    j: np.ndarray  # (n,) int64
    free: np.ndarray  # (n, R) bool
    inside: np.ndarray  # (n,) bool
    hold_margin: np.ndarray | None = None  # (n,) once criterion (e) ran

    def __len__(self) -> int:
        return len(self.i)

    def keep(self, mask: np.ndarray, free: np.ndarray | None = None) -> _Survivors:
        """The pairs where `mask` holds (with the free rolls `free` instead of their own when given)."""
        # the indices once, then a gather per array: a boolean mask per array would search the mask again each time
        idx = np.flatnonzero(mask)
        margin = self.hold_margin.take(idx) if self.hold_margin is not None else None
        rolls = self.free if free is None else free
        return _Survivors(self.i.take(idx), self.j.take(idx), rolls.take(idx, axis=0), self.inside.take(idx), margin)


@dataclass(frozen=True)
class _Held:
    """Criterion (e): the survivors that hold the part (all of them when it did not run)."""

    survivors: _Survivors
    active: bool
    removed: int
    load_n: float | None
    #: why (e) is off although asked for (no mass or no grip force)
    warning: str | None
    #: when (e) removed every candidate: what would make the best one hold
    diagnosis: dict[str, Any] | None


@dataclass(frozen=True)
class _MeshChecked:
    survivors: _Survivors
    #: free rolls the triangles blocked, and the candidates left with none
    removed_rolls: int
    removed: int


def _load(
    run: _Run, mesh_or_path: str | os.PathLike[str] | trimesh.Trimesh | Part, units: str | None, object_name: str | None
) -> _Loaded:
    run.report("load", 0.0)
    t0 = time.perf_counter()
    part = as_part(mesh_or_path, units=units, name=object_name)
    run.timings["load"] = time.perf_counter() - t0
    mass, mass_note = _hold.part_mass(part, run.params.mass_kg, run.params.density)
    if run.options.validate:
        _check_validation_inputs(mass, run.spec)
    run.report("load", 1.0)
    return _Loaded(part, mass, mass_note, quality.center_of_mass(part.mesh, part.points))


def _sample(run: _Run, part: Part) -> _Surface:
    spec, params = run.spec, run.params
    run.report("sample", 0.0)
    t0 = time.perf_counter()
    sample = sampling.sample_surface(part, params.points, seed=params.seed)
    cell = antipodal.pair_cell_size(spec.stroke, params.inside, spec.finger_thickness)
    order = antipodal.grid_order(sample.points, cell)
    pts, nrm = sample.points[order], sample.normals[order]
    t1 = time.perf_counter()
    tree = _collision.build_tree(part.mesh.vertices, part.mesh.faces) if part.mesh is not None else None
    spread = _normal_spread(tree, pts, nrm, params.position_tolerance)
    run.timings["sample"] = time.perf_counter() - t0
    run.timings["sample_mesh_tree"] = time.perf_counter() - t1
    run.report("sample", 1.0)
    return _Surface(pts, nrm, float(sample.spacing), float(sample.min_spacing), tree, spread)


def _pairs(run: _Run, surface: _Surface) -> _Pairs:
    spec, params = run.spec, run.params
    run.report("pairs", 0.0)
    t0 = time.perf_counter()
    plan = antipodal.pair_plan(
        surface.points,
        surface.normals,
        stroke=spec.stroke,
        min_width=spec.min_width,
        friction=run.mu,
        safety_factor=params.safety_factor,
        inside=params.inside,
        finger_thickness=spec.finger_thickness,
        spread=surface.spread,
    )
    run.timings["pairs"] = time.perf_counter() - t0
    run.report("pairs", 1.0)
    model = _collision.collision_model(spec, params.collision, reach=_collision.approach_reach(surface.points))
    return _Pairs(plan, antipodal.cone_half_angle_rad(run.mu, params.safety_factor), model)


def _collide(run: _Run, surface: _Surface, pairs: _Pairs) -> _Survivors:
    """Criterion (d) for every pair of the plan (which already judged (c) within the position tolerance),
    streamed in blocks of `_PAIR_BLOCK` pairs.

    The survivors come in the order of `antipodal_pairs`. Filling the pairs counts as the pairs stage, the rest as
    the collision stage.
    """
    run.report("collision", 0.0)
    plan, rolls = pairs.plan, run.params.rolls
    pts, nrm = surface.points, surface.normals
    m = plan.accepted
    segment = max(-(-m // _COLLISION_BATCHES), 1)  # pairs per kernel call, then set by the measured rate
    kept: list[_Survivors] = []
    n_kept = 0
    t_fill = t_coll = 0.0
    for r0, r1 in plan.blocks(_PAIR_BLOCK):
        t0 = time.perf_counter()
        bi, bj, bins = plan.fill(r0, r1)
        p0 = int(plan.offsets[r0])
        t_fill += time.perf_counter() - t0
        t0 = time.perf_counter()
        free = np.empty((len(bi), rolls), dtype=bool)
        lo = 0
        while lo < len(bi):
            hi = min(lo + segment, len(bi))
            sl = slice(lo, hi)
            t_seg = time.perf_counter()
            free[sl] = _collision.free_rolls_of_pairs(pts, bi[sl], bj[sl], bins[sl], pairs.model, rolls, normals=nrm)
            rate = (hi - lo) / max(time.perf_counter() - t_seg, 1e-6)
            segment = max(int(rate * _COLLISION_REPORT_S), _MIN_SEGMENT)
            run.report("collision", (p0 + hi) / m)
            lo = hi
        block_kept = _Survivors(bi, bj, free, bins).keep(_collision.any_free(free))
        n_kept += len(block_kept)
        if n_kept > MAX_CANDIDATES:
            raise InvalidParameterError(
                f"more than {MAX_CANDIDATES:,} collision-free candidates at {len(pts):,} points (after "
                f"{p0 + len(bi):,} of the {m:,} pairs that pass criteria (a)-(c)), more than this run may hold: use "
                f"fewer points (candidates grow with the square of the points)",
                field="points",
            )
        kept.append(block_kept)
        t_coll += time.perf_counter() - t0
    run.timings["pairs"] += t_fill
    run.timings["collision"] = t_coll
    if m == 0:
        run.report("collision", 1.0)  # otherwise the last segment reported it
    if not kept:
        e = np.zeros(0, dtype=np.int64)
        return _Survivors(e, e.copy(), np.zeros((0, rolls), dtype=bool), np.zeros(0, dtype=bool))
    if len(kept) == 1:
        return kept[0]  # one block (most runs): its arrays are already the survivors' own, no copy
    cat = np.concatenate
    return _Survivors(*(cat([getattr(s, k) for s in kept]) for k in ("i", "j", "free", "inside")))


def _hold_part(run: _Run, loaded: _Loaded, surface: _Surface, survivors: _Survivors) -> _Held:
    """Criterion (e) on the pairs that passed (a)-(d) against the points (CONTRACT.md, hold.py)."""
    spec, params = run.spec, run.params
    t0 = time.perf_counter()
    com = loaded.center_of_mass
    active, warning = _hold_active(params, spec, loaded.mass_kg)
    load = diagnosis = None
    removed = 0
    if active:
        assert loaded.mass_kg is not None and spec.grip_force is not None  # _hold_active checked both
        pts, s = surface.points, survivors
        rho = _hold.torsion_radii(pts, surface.normals, _patch_radius(spec))
        load = _hold.hold_load(loaded.mass_kg, params.accel)
        pair = (pts, surface.normals, rho, s.i, s.j, com)
        hold_args: dict[str, Any] = dict(load=load, grip_force=spec.grip_force, friction=run.mu)
        margins = _hold.hold_margins_of_pairs(*pair, floor=1.0, **hold_args)
        keep = margins >= 1.0
        removed = int(np.sum(~keep))
        if len(s) and not keep.any():
            best = float(np.max(_hold.hold_margins_of_pairs(*pair, **hold_args)))
            diagnosis = _hold_diagnosis(best, spec, loaded.mass_kg, params)
        survivors = replace(s, hold_margin=margins).keep(keep)
    run.timings["hold"] = time.perf_counter() - t0
    return _Held(survivors, active, removed, load, warning, diagnosis)


def _check_mesh(run: _Run, surface: _Surface, pairs: _Pairs, survivors: _Survivors) -> _MeshChecked:
    """Every free roll tested again against the part's triangles (mesh-exact criterion (d), graspgen.collision), only on
    what (e) left. A point cloud has no triangles: its survivors stay as they are."""
    t0 = time.perf_counter()
    removed_rolls = 0
    checked = survivors
    if surface.tree is not None and len(survivors):
        s = survivors
        exact = _collision.mesh_free_rolls_of_pairs(
            surface.tree, surface.points, s.i, s.j, s.inside, s.free, pairs.model
        )
        removed_rolls = int(np.count_nonzero(s.free)) - int(np.count_nonzero(exact))
        checked = s.keep(_collision.any_free(exact), free=exact)
    run.timings["collision_mesh"] = time.perf_counter() - t0
    run.timings["collision"] += run.timings["collision_mesh"]
    return _MeshChecked(checked, removed_rolls, len(survivors) - len(checked))


def _candidates(run: _Run, loaded: _Loaded, surface: _Surface, pairs: _Pairs, s: _Survivors) -> Candidates:
    """The survivors as candidates, each scored (quality.py): the score orders the export, and `best-near-medoid`
    selects by it."""
    spec, params = run.spec, run.params
    pts, nrm = surface.points, surface.normals
    fm = antipodal.friction_margin_deg(pts, nrm, s.i, s.j, s.inside, pairs.half_angle)
    contacts = np.stack([pts[s.i], pts[s.j]], axis=1).reshape(-1, 2, 3)
    normals = np.stack([nrm[s.i], nrm[s.j]], axis=1).reshape(-1, 2, 3)
    # the contacts are sample points, so the patch flatness is computed once per point
    flat = quality.point_flatness(pts, nrm, _patch_radius(spec))
    terms = quality.quality_terms(
        contacts,
        normals,
        fm,
        half_angle_deg=quality.half_angle_deg(run.mu, params.safety_factor),
        center_of_mass=loaded.center_of_mass,
        length_scale=_length_scale(loaded.part),
        flatness=np.stack([flat[s.i], flat[s.j]], axis=1),
    )
    return Candidates(
        contacts=contacts,
        normals=normals,
        free_rolls=s.free,
        roll_angles_rad=roll_angles_rad(params.rolls),
        friction_margin_deg=fm,
        inside=s.inside,
        labels=np.full((len(s), 2), -1, dtype=np.int32),
        medoids=np.zeros(0, dtype=np.int64),
        quality_terms=terms,
        center_of_mass=loaded.center_of_mass,
        hold_margin=s.hold_margin,
    )


def _stats(
    run: _Run,
    loaded: _Loaded,
    surface: _Surface,
    pairs: _Pairs,
    collided: _Survivors,
    held: _Held,
    checked: _MeshChecked,
    cands: Candidates,
) -> dict[str, Any]:
    """The export's stats of the stages so far (clustering, selection and validation add theirs)."""
    plan, part = pairs.plan, loaded.part
    n_point_free = len(collided)
    # the mesh-exact check ran after (e): what it removed counts as collision, with the point test's
    rejected = {
        "stroke": plan.rejected_stroke,
        "outside": plan.rejected_outside,
        "friction": plan.rejected_friction + plan.rejected_tolerance,
        "collision": plan.accepted - n_point_free + checked.removed,
        "hold": held.removed,
    }
    stats: dict[str, Any] = {
        "points": len(surface.points),
        "pairs_total": plan.pairs_total,
        "rejected": rejected,
        "candidates": len(cands),
        "timings_s": run.timings,
        "spacing_mean": surface.spacing,
        "spacing_min": surface.min_spacing,
        "watertight": bool(part.watertight),
        "warnings": list(part.warnings),
        "exact": {
            "friction_position_tolerance": plan.rejected_tolerance,
            "collision_mesh_rolls": checked.removed_rolls,
            "collision_mesh_candidates": checked.removed,
        },
    }
    if held.active:
        stats["hold"] = {
            "mass_kg": loaded.mass_kg,
            "load_n": held.load_n,
            "grip_force": run.spec.grip_force,
            "friction": run.mu,
            "center_of_mass": [float(v) for v in loaded.center_of_mass],
            "min_margin": float(np.min(cands.hold_margin)) if len(cands) and cands.hold_margin is not None else None,
        }
    for note in (held.warning, loaded.mass_note):
        if note:
            stats["warnings"].append(note)
    if len(cands) == 0:
        stats["empty_reason"] = _empty_reason(
            rejected, plan.pairs_total, run.spec, run.params, run.mu, surface.points, surface.normals, held.diagnosis
        )
    return stats


def _normal_spread(
    tree: _collision.MeshTree | None, pts: np.ndarray, nrm: np.ndarray, tolerance: float
) -> np.ndarray | None:
    """Per sample point, the largest angle (rad) between its normal and a surface normal within `tolerance`: of
    the mesh's triangles, or for a point cloud of the other sample points; None when nothing is near."""
    if tolerance <= 0 or len(pts) == 0:
        return None
    if tree is not None:
        spread = _collision.normal_spread_rad(tree, pts, nrm, tolerance)
    else:
        from scipy.spatial import cKDTree

        lowest = np.ones(len(pts))
        for a, hood in enumerate(cKDTree(pts).query_ball_point(pts, r=tolerance)):
            lowest[a] = np.min(nrm[hood] @ nrm[a])
        spread = libm.arccos(np.clip(lowest, -1.0, 1.0))
    return spread if np.any(spread > 0) else None


def _check_validation_inputs(mass: float | None, spec: GripperSpec) -> None:
    from .physics import check_validation_inputs

    check_validation_inputs(mass)
    if spec.grip_force is None:
        raise InvalidParameterError("validate needs the gripper's grip_force (N per finger)", field="grip_force")


def _hold_active(params: Params, spec: GripperSpec, mass: float | None) -> tuple[bool, str | None]:
    """Whether criterion (e) runs, and the warning when it was asked for but cannot."""
    if params.hold == "off":
        return False, None
    missing = [
        what
        for what, absent in (
            ("the part's mass (mass_kg or density)", mass is None),
            ("the gripper's grip_force", spec.grip_force is None),
        )
        if absent
    ]
    if missing:
        return False, "criterion (e) hold is off: it needs " + " and ".join(missing)
    return True, None


def _hold_diagnosis(best: float, spec: GripperSpec, mass: float, params: Params) -> dict[str, Any]:
    """What would make the best candidate hold: the margin scales with the grip force over the load."""
    assert spec.grip_force is not None  # criterion (e) runs only with a grip force
    need_force = spec.grip_force / best if best > 0 else math.inf
    max_mass = mass * best
    return {
        "best_margin": best,
        "grip_force_needed": need_force,
        "max_mass_kg": max_mass,
        "message": (
            f"no candidate holds the part (criterion (e)): the best resists {best:.2f} of the load "
            f"({mass:g} kg at {params.accel:g} m/s^2 beyond gravity); it needs at least {need_force:.1f} N per finger "
            f"(the gripper has {spec.grip_force:g} N), or a part under {max_mass:.3f} kg"
        ),
    }


@overload
def recluster(
    candidates: Candidates,
    previous_export: dict[str, Any],
    *,
    k1: int,
    k2: int,
    seed: int = ...,
    recording: Any = None,
    progress: Progress | None = None,
    mass_kg: float | None = None,
    density: float | None = None,
    mesh: str | os.PathLike[str] | trimesh.Trimesh | Part | None = None,
    units: str | None = None,
    gripper: GripperSpec | None = None,
    options: QualityOptions | None = None,
    **quality: Any,
) -> GraspSet: ...


@overload
def recluster(
    candidates: SuctionCandidates,
    previous_export: dict[str, Any],
    *,
    k1: int,
    k2: int,
    seed: int = ...,
    recording: Any = None,
    progress: Progress | None = None,
    mass_kg: float | None = None,
    density: float | None = None,
    mesh: str | os.PathLike[str] | trimesh.Trimesh | Part | None = None,
    units: str | None = None,
    gripper: SuctionSpec | None = None,
    options: QualityOptions | None = None,
    **quality: Any,
) -> SuctionGraspSet: ...


@overload
def recluster(
    candidates: str | os.PathLike[str],
    previous_export: dict[str, Any],
    *,
    k1: int,
    k2: int,
    seed: int = ...,
    recording: Any = None,
    progress: Progress | None = None,
    mass_kg: float | None = None,
    density: float | None = None,
    mesh: str | os.PathLike[str] | trimesh.Trimesh | Part | None = None,
    units: str | None = None,
    gripper: GripperSpec | SuctionSpec | None = None,
    options: QualityOptions | None = None,
    **quality: Any,
) -> GraspSet | SuctionGraspSet: ...


def recluster(
    candidates: str | os.PathLike[str] | Candidates | SuctionCandidates,
    previous_export: dict[str, Any],
    *,
    k1: int,
    k2: int,
    seed: int = Params.seed,
    recording: Any = None,
    progress: Progress | None = None,
    mass_kg: float | None = None,
    density: float | None = None,
    mesh: str | os.PathLike[str] | trimesh.Trimesh | Part | None = None,
    units: str | None = None,
    gripper: GripperSpec | SuctionSpec | None = None,
    options: QualityOptions | None = None,
    **quality: Any,
) -> GraspSet | SuctionGraspSet:
    """A new selection from stored candidates with other k1 / k2 / seed, without regenerating them.

    The quality options (select, validate, repair_limit, sim_workers: the fields of `QualityOptions`) as in
    generate(), as keywords or a ready `options=`; validation, and quality scoring of candidates stored without
    quality terms, need the part: `mesh` (a Part, a mesh in metres, or a path with `units`). `gripper`: the spec the
    set was made with, required when it has geometry (the export names its mesh files and their digests, not their
    contents); its to_dict() must be the export's `gripper`.

    A suction set (the export's `gripper.kind` "suction", its candidates a suction NPZ or SuctionCandidates) is
    clustered again as generate() clusters it (graspgen.suction.recluster_suction): the same candidates and
    k1 / k2 / seed give the same grasps. Its candidates were judged with the set's mass and need no part, so `mass_kg`,
    `density`, `mesh` and `units` are refused for it, and so are validate and best-near-medoid selection (as generate
    refuses them for a cup); the result is a SuctionGraspSet.
    """
    from .export import load_candidates

    report = progress or _noop
    (options,) = from_keywords("recluster", quality, (QualityOptions, options))
    if _export_kind(previous_export, candidates) == SUCTION:
        return _recluster_suction(
            candidates,
            previous_export,
            k1=k1,
            k2=k2,
            seed=seed,
            recording=recording,
            progress=progress,
            gripper=gripper,
            options=options,
            part_inputs={"mass_kg": mass_kg, "density": density, "mesh": mesh, "units": units},
        )
    assert not isinstance(candidates, SuctionCandidates)  # _export_kind refused them for a parallel set
    if isinstance(gripper, SuctionSpec):
        raise InvalidParameterError("a suction cup's spec for a parallel set", field="gripper")
    t_all = time.perf_counter()
    cands = candidates if isinstance(candidates, Candidates) else load_candidates(candidates)
    if gripper is None:
        spec = GripperSpec.from_dict(previous_export["gripper"])
    elif gripper.to_dict() == previous_export["gripper"]:
        spec = gripper
    else:
        raise InvalidParameterError("gripper is not the spec the grasp set was made with", field="gripper")
    old = dict(previous_export["params"])
    mu = float(old.get("friction") or spec.friction)
    # the export carries the mass the run resolved beside the density it may have come from
    run_mass = old.pop("mass_kg", None)
    old.pop("density", None)
    params = Params.from_dict({**old, "k1": k1, "k2": k2, "seed": seed, "friction": mu})
    if len(cands.roll_angles_rad) != params.rolls:
        raise InvalidParameterError("the candidates' roll count differs from the export's params.rolls")
    prev = previous_export.get("stats", {})
    stats = {
        k: v for k, v in prev.items() if k not in ("timings_s", "cluster_note", "coverage", "selection", "validation")
    }
    stats["timings_s"] = {}
    stats["candidates"] = len(cands)
    part = None
    if mesh is not None:
        part = mesh if isinstance(mesh, Part) else load_part(mesh, units=units or "m")
    elif options.validate or (options.select != "medoid" and cands.quality_terms is None):
        raise InvalidParameterError(
            "validation, and quality selection of candidates stored without quality terms, need the part (mesh=)",
            field="mesh",
        )
    if mass_kg is not None or density is not None:
        Params(mass_kg=mass_kg, density=density)  # the same checks as generate's
        run_mass, _ = _hold.part_mass(part, mass_kg, density) if part is not None else (mass_kg, None)
    if options.validate:
        _check_validation_inputs(run_mass, spec)
    surface = None
    if options.select != "medoid" and cands.quality_terms is None:
        assert part is not None  # refused above without the part
        surface = _surface_for_quality(part, params)
        cands = _with_quality(cands, part, *surface, spec, mu, params)
    extras = _Extras(options, part, run_mass, surface)
    result = _cluster_and_export(
        cands, dict(previous_export["object"]), spec, params, mu, stats, report, t_all, [], extras
    )
    if recording is not None:
        from .recording import record_run

        record_run(recording, result, sample_points=None, sample_normals=None)
    return result


def _export_kind(previous_export: dict[str, Any], candidates: object) -> str:
    """The gripper kind of a grasp set's export ("parallel" without `gripper.kind`); InvalidParameterError when the
    candidates given as an object are of the other kind."""
    grip = previous_export.get("gripper")
    kind = grip.get("kind", PARALLEL) if isinstance(grip, dict) else PARALLEL
    if isinstance(candidates, SuctionCandidates if kind != SUCTION else Candidates):
        raise InvalidParameterError(f"the candidates are not of the export's gripper kind ({kind})", field="candidates")
    return str(kind)


def _recluster_suction(
    candidates: str | os.PathLike[str] | Candidates | SuctionCandidates,
    previous_export: dict[str, Any],
    *,
    gripper: GripperSpec | SuctionSpec | None,
    part_inputs: dict[str, Any],
    **keywords: Any,
) -> SuctionGraspSet:
    """recluster() of a suction set: refuses what a cup's clustering cannot use, then recluster_suction."""
    for name, value in part_inputs.items():
        if value is not None:
            raise InvalidParameterError(
                f"{name} is not taken when re-clustering a suction set: its candidates were judged with the set's "
                "mass and clustering needs no part (generate again for another mass)",
                field=name,
            )
    if isinstance(gripper, GripperSpec):
        raise InvalidParameterError("a parallel gripper's spec for a suction set", field="gripper")
    assert not isinstance(candidates, Candidates)  # _export_kind refused a parallel set's candidates
    return recluster_suction(candidates, previous_export, gripper=gripper, **keywords)


recluster.__signature__ = _signature_with_fields(recluster, QualityOptions)  # type: ignore[attr-defined]  # inspect reads it; mypy does not model function attributes


def _cluster_and_export(
    cands: Candidates,
    obj: dict[str, Any],
    spec: GripperSpec,
    params: Params,
    mu: float,
    stats: dict[str, Any],
    report: Progress,
    t_all: float,
    warnings: list[str],
    extras: _Extras | None = None,
) -> GraspSet:
    extras = extras or _Extras()
    report("cluster", 0.0)
    t0 = time.perf_counter()
    res = clustering.two_stage(cands.midpoints, cands.axes, params.k1, params.k2, seed=params.seed)
    stats["timings_s"]["cluster"] = time.perf_counter() - t0
    if res.note:
        stats["cluster_note"] = res.note
    report("cluster", 1.0)

    report("export", 0.0)
    medoids = np.asarray(res.medoids, dtype=np.int64)
    clusters = np.asarray(res.medoid_clusters, dtype=np.int64).reshape(-1, 2)
    sizes = np.asarray(res.cluster_sizes, dtype=np.int64)
    labels = np.asarray(res.labels, dtype=np.int32).reshape(-1, 2)
    medoid_of = medoids.copy()
    score = None
    if extras.options.select != "medoid":
        assert cands.quality_terms is not None  # generate scores every run; recluster scored them above
        score = quality.scores(cands.quality_terms)
        medoids = quality.select_best_near_medoid(labels, medoids, clusters, score, cands.midpoints, cands.axes)
        stats["selection"] = {
            "mode": extras.options.select,
            "replaced": int(np.sum(medoids != medoid_of)),
            "mean_score_medoids": _mean(score[medoid_of]),
            "mean_score_selected": _mean(score[medoids]),
            "weights": quality.WEIGHTS.to_dict(),
            "near": {"radius": quality.NEAR.radius, "angle_deg": quality.NEAR.angle_deg},
        }
    seated: dict[int, Seated] = {}
    judge = _seat_judge(spec, extras, mu, params)
    if judge is not None:
        t0 = time.perf_counter()
        medoids, keep, seated, stats["seat"] = _seat_choose(judge, cands, labels, medoids, clusters)
        stats["timings_s"]["seat"] = time.perf_counter() - t0
        clusters, sizes, medoid_of = clusters[keep], sizes[keep], medoid_of[keep]
    sim = None
    if extras.options.validate and len(medoids) == 0:
        from .physics import summarise

        stats["validation"] = {**summarise([]), "repaired": 0, "simulated": 0}
    elif extras.options.validate:
        t0 = time.perf_counter()
        medoids, sim = _validate(cands, labels, medoids, clusters, spec, mu, params, extras, stats, report)
        stats["timings_s"]["validate"] = time.perf_counter() - t0
    if judge is not None:  # a grasp the validation repaired with another member: its seat for the export
        for m in medoids:
            if int(m) not in seated and (s := judge.seat(_poses(cands, np.array([m]))[0], float(cands.widths[m]))):
                seated[int(m)] = s
    # best first within each translation cluster: (validated grasps first,) larger quality score, then candidate
    # index; the score needs only the exported grasps' terms. Without the part (recluster without `mesh` of
    # candidates stored unscored) the friction margin orders them
    terms = _export_terms(cands, medoids, extras, spec, mu, params) if len(medoids) else None
    if terms is not None:
        key = quality.scores(terms)
        stats["export_order"] = "quality"
    else:
        key = cands.friction_margin_deg[medoids]
        stats["export_order"] = "friction_margin"
    keys = [medoids, -key]
    if sim is not None:
        keys.append(np.array([not r.success for r in sim], dtype=bool))
    order = np.lexsort((*keys, clusters[:, 0])) if len(medoids) else medoids
    medoids, clusters, sizes, medoid_of = medoids[order], clusters[order], sizes[order], medoid_of[order]
    if terms is not None:
        terms, key = terms[order], key[order]
    cands = replace(cands, labels=labels, medoids=medoids)
    grasps = _grasps(cands, medoids, clusters, sizes)
    for r, g in enumerate(grasps):
        m = int(medoids[r])
        if terms is not None:
            g["quality"] = quality.describe(terms[r], key[r])
        if m != medoid_of[r]:
            g["medoid"] = int(medoid_of[r])  # the cluster's medoid this grasp stands in for
        if cands.hold_margin is not None:
            g["hold_margin"] = round(float(cands.hold_margin[m]), 6)
        if sim is not None:
            g["sim"] = sim[order[r]].to_json()
    _seat_grasps(grasps, seated)
    stats["coverage"] = coverage(cands.midpoints, cands.axes, medoids).to_json()
    stats["timings_s"]["total"] = time.perf_counter() - t_all
    report("export", 1.0)
    return GraspSet(
        object=obj,
        gripper=spec,
        params=params,
        friction=mu,
        stats=stats,
        grasps=grasps,
        candidates=cands,
        warnings=warnings,
        mass_kg=extras.mass_kg,
    )


def _grasps(cands: Candidates, medoids: np.ndarray, clusters: np.ndarray, sizes: np.ndarray) -> list[dict[str, Any]]:
    if len(medoids) == 0:
        return []
    rolls = np.array([choose_roll(cands.free_rolls[m]) for m in medoids], dtype=np.int64)
    psi = cands.roll_angles_rad[rolls]
    T = grasp_frames(cands.midpoints[medoids], cands.axes[medoids], psi)
    widths = cands.widths
    out = []
    for r, m in enumerate(medoids):
        out.append(
            {
                "pose": T[r].tolist(),
                "width": float(widths[m]),
                "contacts": cands.contacts[m].tolist(),
                "normals": cands.normals[m].tolist(),
                "friction_margin_deg": float(cands.friction_margin_deg[m]),
                # rounded to 1e-9 deg so that 247.5 prints as 247.5, not 247.49999999999997
                "free_rolls_deg": [round(float(v), 9) for v in np.degrees(cands.roll_angles_rad[cands.free_rolls[m]])],
                "cluster": [int(clusters[r, 0]), int(clusters[r, 1])],
                "cluster_size": int(sizes[r]),
                "roll_deg": round(float(np.degrees(psi[r])), 9),
                "mode": "inside" if cands.inside[m] else "outside",
                "candidate": int(m),
            }
        )
    return out


def _seat_judge(spec: GripperSpec, extras: _Extras, mu: float, params: Params) -> SeatJudge | None:
    """The judge of exported grasps on their seats (graspgen.seating) for a gripper from CAD with the part's mesh;
    None for box fingers (they touch where the pair was sampled) or without the mesh (recluster without it)."""
    part = extras.part
    if spec.geometry is None or part is None or part.mesh is None:
        return None
    hold = None
    if params.hold != "off" and extras.mass_kg is not None and spec.grip_force is not None:
        com = quality.center_of_mass(part.mesh, part.points)
        hold = SeatHold(com, _hold.hold_load(extras.mass_kg, params.accel), spec.grip_force, mu)
    tree = extras.tree if extras.tree is not None else _collision.build_tree(part.mesh.vertices, part.mesh.faces)
    half = quality.half_angle_deg(mu, params.safety_factor)
    return SeatJudge(tree, spec.solids(), half, hold, _collision.triangle_bounds(tree))


def _seat_choose(
    judge: SeatJudge, cands: Candidates, labels: np.ndarray, medoids: np.ndarray, clusters: np.ndarray
) -> tuple[np.ndarray, np.ndarray, dict[int, Seated], dict[str, Any]]:
    """Each grasp to export (`medoids`, final clusters `clusters` (m, 2)) seated and judged by (c) and (e) on its
    seat; one that fails is replaced by the nearest member of its cluster that passes (at most SEAT_TRIES tried),
    a cluster without one is left out. Returns the chosen candidates, which rows of `medoids` kept one, their seats
    by candidate index, and the counts for stats.seat."""
    queues = [
        [int(m), *nearest_members(labels, clusters[r], int(m), cands.midpoints, cands.axes)[: SEAT_TRIES - 1]]
        for r, m in enumerate(medoids)
    ]
    chosen = np.full(len(medoids), -1, dtype=np.int64)
    seated: dict[int, Seated] = {}
    failed = {"unseated": 0, "friction": 0, "hold": 0}
    tried = 0
    for attempt in range(SEAT_TRIES):  # one round seats the next member of every cluster still without a grasp
        rows = [r for r in range(len(medoids)) if chosen[r] < 0 and attempt < len(queues[r])]
        if not rows:
            break
        idx = np.array([queues[r][attempt] for r in rows], dtype=np.int64)
        tried += len(idx)
        for r, t, s in zip(rows, idx, judge.seat_many(_poses(cands, idx), cands.widths[idx]), strict=True):
            if s is not None and s.passes:
                chosen[r] = t
                seated[int(t)] = s
            elif s is None:
                failed["unseated"] += 1
            elif s.friction_margin_deg < 0.0:
                failed["friction"] += 1
            else:
                failed["hold"] += 1
    keep = chosen >= 0
    counts = {
        "grasps": int(np.sum(keep)),
        "replaced": int(np.sum(keep & (chosen != medoids))),
        "dropped": int(np.sum(~keep)),
        "tried": tried,
    }
    return chosen[keep], keep, seated, {**counts, "failed": failed}


def _seat_grasps(grasps: list[dict[str, Any]], seated: dict[int, Seated]) -> None:
    """Fingers from CAD close until they touch (CONTRACT.md): each exported grasp's `width`, `contacts`, `normals`,
    `friction_margin_deg` and `hold_margin` become its seat's (graspgen.seating): `contacts` holds, per finger, its
    contact nearest the finger's closing line, `finger_contacts` and `finger_normals` all of them (a V-groove's two
    flanks); the pose stays the candidate's (the gripper's body was checked there)."""
    for g in grasps:
        s = seated.get(int(g["candidate"]))
        if s is None:
            continue
        g["width"] = float(s.seat.width)
        g["contacts"] = s.contacts.tolist()
        g["normals"] = s.normals.tolist()
        g["friction_margin_deg"] = s.friction_margin_deg
        if s.hold_margin is not None:
            g["hold_margin"] = round(s.hold_margin, 6)
        g["finger_contacts"] = [s.seat.points[k].tolist() for k in range(2)]
        g["finger_normals"] = [s.seat.normals[k].tolist() for k in range(2)]


def _empty_reason(
    rejected: dict[str, int],
    total: int,
    spec: GripperSpec,
    params: Params,
    mu: float,
    pts: np.ndarray,
    nrm: np.ndarray,
    hold_diag: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Which criterion removed the last pairs, and what to change.

    Pairs on one face or adjacent faces fail (b) or (c) whatever the stroke, so when (b) or (c) removed the last
    pairs, the pairs are judged once more without the stroke limit: if antipodal pairs exist but all are wider
    than the stroke, the stroke is what to change.
    """
    left = total
    criterion = "stroke"
    for criterion in ("stroke", "outside", "friction", "collision", "hold"):
        left -= rejected[criterion]
        if left <= 0:
            break
    if criterion == "hold" and hold_diag is not None:
        return {"criterion": "hold", **hold_diag}
    narrowest = None
    if criterion in ("outside", "friction") and len(pts) > 1:
        diag = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
        wide = antipodal.antipodal_pairs(
            pts,
            nrm,
            stroke=diag * 1.001 + 1e-9,
            min_width=0.0,
            friction=mu,
            safety_factor=params.safety_factor,
            inside=params.inside,
            finger_thickness=spec.finger_thickness,
        )
        if len(wide.i):
            narrowest = float(np.min(np.linalg.norm(pts[wide.j] - pts[wide.i], axis=1)))
            criterion = "stroke"
    hints = {
        "stroke": (
            f"the part is wider than the stroke ({spec.stroke * 1e3:.1f} mm) everywhere"
            + (f": its narrowest antipodal width is {narrowest * 1e3:.1f} mm" if narrowest else "")
            + "; use a gripper with a larger stroke"
            + (f" or a smaller min_width ({spec.min_width * 1e3:.1f} mm)" if spec.min_width > 0 else "")
        ),
        "outside": (
            "no pair within the stroke has normals pointing away from each other: check that the mesh normals "
            "point outwards (a closed, consistently oriented mesh), or allow inside grasps"
        ),
        "friction": (
            f"no pair lies within the friction cone (arctan({mu:g}) / {params.safety_factor:g} = "
            f"{math.degrees(math.atan(mu) / params.safety_factor):.1f} deg): raise the friction coefficient, lower "
            "the safety factor, or sample more points"
        ),
        "collision": (
            "every antipodal pair collides at every roll: the fingers or palm do not fit the part; try smaller "
            "fingers, a smaller pregrasp_clearance, collision mode 'paper', or more rolls"
        ),
    }
    out: dict[str, Any] = {"criterion": criterion, "message": hints[criterion]}
    if narrowest is not None:
        out["narrowest_antipodal_width"] = narrowest
    return out


# --------------------------------------------------------------------------------------------------------------------
# quality-aware selection and physics validation (docs/QUALITY.md)


@dataclass(frozen=True)
class _Extras:
    """The quality options and what a run resolved for them: the part (to score and simulate), its mass (kg) for
    the validation, its sampled surface (points, normals) for the flatness term when the run has it, and the part's
    triangle tree when the run built one (the seats of a gripper from CAD walk it)."""

    options: QualityOptions = QualityOptions()
    part: Part | None = None
    mass_kg: float | None = None
    surface: tuple[np.ndarray, np.ndarray] | None = None
    tree: _collision.MeshTree | None = None


def _mean(values: np.ndarray) -> float | None:
    return round(float(np.mean(values)), 6) if len(values) else None


def _surface_for_quality(part: Part, params: Params) -> tuple[np.ndarray, np.ndarray]:
    sample = sampling.sample_surface(part, params.points, seed=params.seed)
    return sample.points, sample.normals


def _with_quality(
    cands: Candidates, part: Part, pts: np.ndarray, nrm: np.ndarray, spec: GripperSpec, mu: float, params: Params
) -> Candidates:
    """The candidates with their quality terms (quality.py) and the part's centre of mass."""
    com = quality.center_of_mass(part.mesh, part.points)
    terms = _quality_terms(cands, np.arange(len(cands)), part, com, pts, nrm, spec, mu, params)
    return replace(cands, quality_terms=terms, center_of_mass=com)


def _quality_terms(
    cands: Candidates,
    idx: np.ndarray,
    part: Part,
    com: np.ndarray,
    pts: np.ndarray,
    nrm: np.ndarray,
    spec: GripperSpec,
    mu: float,
    params: Params,
) -> np.ndarray:
    """Quality terms (len(idx), 3) of candidates `idx`; a row depends on its own candidate only."""
    return quality.quality_terms(
        cands.contacts[idx],
        cands.normals[idx],
        cands.friction_margin_deg[idx],
        half_angle_deg=quality.half_angle_deg(mu, params.safety_factor),
        center_of_mass=com,
        length_scale=_length_scale(part),
        surface_points=pts,
        surface_normals=nrm,
        patch_radius=_patch_radius(spec),
    )


def _length_scale(part: Part) -> float:
    return 0.5 * float(np.linalg.norm(part.extents))


def _patch_radius(spec: GripperSpec) -> float:
    """The radius of the disc the pad presses with: half the pad's smaller side."""
    return min(spec.solids().pad) / 2


def _check_geometry_params(spec: GripperSpec, params: Params) -> None:
    """A gripper from CAD grasps from outside: the contract's finger frame describes the pad on the inner face only."""
    if spec.geometry is not None and params.inside:
        raise InvalidParameterError(
            "inside grasps need box fingers: a CAD finger's pad is on its inner face (CONTRACT.md, finger frame), "
            "and what touches the part from inside is not described",
            field="inside",
        )


def _check_geometry_part(spec: GripperSpec, part: Part) -> None:
    """Criterion (d) with CAD fingers tests them against the part's triangles: a point cloud has none."""
    if spec.geometry is not None and part.mesh is None:
        raise InvalidMeshError(
            "a gripper from CAD is checked against the part's triangles, and a point cloud has none: give the part "
            "as a mesh (a scan meshed, or the CAD model)",
            field="file",
        )


def _export_terms(
    cands: Candidates, idx: np.ndarray, extras: _Extras, spec: GripperSpec, mu: float, params: Params
) -> np.ndarray | None:
    """Quality terms of the exported grasps `idx`, to order the export: from the candidates when they were
    scored, else computed for these few grasps (cheap); None without the part (recluster without `mesh`)."""
    if cands.quality_terms is not None:
        stored: np.ndarray = cands.quality_terms[idx]
        return stored
    if extras.part is None:
        return None
    pts, nrm = extras.surface if extras.surface is not None else _surface_for_quality(extras.part, params)
    com = quality.center_of_mass(extras.part.mesh, extras.part.points)
    return _quality_terms(cands, idx, extras.part, com, pts, nrm, spec, mu, params)


def _poses(cands: Candidates, idx: np.ndarray) -> np.ndarray:
    """The export's pose (T_object_grasp, (m, 4, 4)) of candidates `idx`, at the roll choose_roll picks."""
    rolls = np.array([choose_roll(cands.free_rolls[m]) for m in idx], dtype=np.int64)
    return grasp_frames(cands.midpoints[idx], cands.axes[idx], cands.roll_angles_rad[rolls])


def _validate(
    cands: Candidates,
    labels: np.ndarray,
    selected: np.ndarray,
    clusters: np.ndarray,
    spec: GripperSpec,
    mu: float,
    params: Params,
    extras: _Extras,
    stats: dict[str, Any],
    report: Progress,
) -> tuple[np.ndarray, list[SimResult]]:
    """Simulate the selected grasps under every member of physics.validation_set: a grasp passes when it holds in
    all of them. Replace each failing one by the first of up to `repair_limit` members of its final cluster (nearest
    to it first) that passes. Returns the new selection and its SimResults (physics.first_failures)."""
    from . import physics

    report("validate", 0.0)
    part = extras.part
    assert part is not None  # validation is refused without the part
    note = None
    if part.is_point_cloud:
        note = "a point cloud has no surface to simulate: simulated as the convex hull of its points"
    sim_part = physics.prepare_part(part.surface_mesh(), spec, friction=mu, mass_kg=extras.mass_kg, seed=params.seed)
    report("validate", 0.1)
    widths = cands.widths
    checks = physics.validation_set(mu)
    limit = extras.options.repair_limit

    def run(idx: np.ndarray, lo: float, hi: float) -> list[SimResult]:
        """The first failure (or the success) of each grasp idx; progress runs from lo to hi meanwhile (each
        simulation reports, so a cancel or the time limit stops the stage within one simulation)."""
        sims = physics.simulate_perturbed(
            sim_part,
            _poses(cands, idx),
            widths[idx],
            checks,
            seed=params.seed,
            keys=idx,
            workers=extras.options.sim_workers,
            inside=cands.inside[idx],
            progress=lambda done, total: report("validate", lo + (hi - lo) * done / max(total, 1)),
        )
        return physics.first_failures(sims, checks)

    # the first pass gets half of the stage's progress after the part's model, the repair rounds the rest
    rep = quality.repair_by_simulation(selected, clusters, labels, (cands.midpoints, cands.axes), limit, run)
    final, results, first, simulated = rep.selected, rep.results, rep.first, rep.simulated
    report("validate", 1.0)
    import mujoco

    part_info = sim_part.describe()
    notes = [n for n in (note, sim_part.note) if n]
    if notes:
        part_info["note"] = "; ".join(notes)
        stats.setdefault("warnings", []).extend(f"validation: {n}" for n in notes)
    stats["validation"] = {
        **physics.summarise(results),
        "first_pass": physics.summarise(first),
        "repaired": int(np.sum(final != selected)),
        "repair_limit": extras.options.repair_limit,
        "simulated": simulated,
        "members": [p.name for p in checks],
        "failed_under": {p.name: sum(r.member == p.name for r in results) for p in checks},
        "mass_kg": extras.mass_kg,
        "grip_force": spec.grip_force,
        "part": part_info,
        "engine": f"mujoco {mujoco.__version__}",
    }
    return final, results
