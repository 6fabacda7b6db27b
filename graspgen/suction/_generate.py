"""The suction method (CONTRACT.md "Suction cups"): sample the surface evenly, one candidate per sample point with the
approach along its inward normal (and, with max_tilt_deg, tilted approaches on a cone), the criteria cheapest first
(seal, tilt, hold, collision), then the paper's two-stage k-medoids over contact positions and signed approaches.

`generate_suction` is what graspgen.generate runs for a SuctionSpec; it reports the stages load, sample, pairs (the
per-candidate criteria seal, tilt and hold), collision, cluster and export to the progress callback, as the jaws do.
`recluster_suction` (what graspgen.recluster runs for a suction set) clusters a set's stored candidates again with new
k1 / k2 / seed through the same clustering and export, reporting cluster and export.
"""

from __future__ import annotations

import copy
import math
import os
import time
from dataclasses import dataclass, replace
from typing import IO, Any

import numpy as np
import trimesh

from .. import clustering, sampling
from ..collision import MeshTree, TriangleTree, build_tree, mesh_solid
from ..coverage import coverage
from ..errors import InvalidCandidatesError, InvalidMeshError, InvalidParameterError
from ..hold import hold_load, part_mass
from ..params import Params, QualityOptions
from ..parts import Part, as_part
from ..quality import center_of_mass
from ..transforms import approach_basis, choose_roll, roll_angles_rad, suction_frames
from ._collision import CollisionRule, body_frame, collision_kernel
from ._export import SuctionCandidates, SuctionGraspSet, load_suction_candidates
from ._hold import LIMITS, HoldRule, hold_kernel
from ._model import SUCTION, SuctionModel, depth_limits, inner_probes, lip_points, lip_slot_probes
from ._seal import PASS, REASONS, SealPart, SealRule, seal_kernel
from ._spec import MAX_VACUUM, SuctionSpec
from ._validate import Progress, Validator, check_validation_inputs, suction_validator

__all__ = [
    "generate_suction",
    "recluster_suction",
    "suction_candidates",
    "judge_cups",
    "check_params",
    "seal_within",
    "CupJudgement",
    "CRITERIA",
]

#: the criteria in the order they run (and the keys of stats.rejected)
CRITERIA = ("seal", "tilt", "hold", "collision")


def _noop(stage: str, fraction: float) -> None:
    return None


@dataclass(frozen=True)
class _Survivors:
    """Candidates (indices into the sample, approaches) that passed the criteria so far, with what they carry."""

    point: np.ndarray  # (n,) int64
    approach: np.ndarray  # (n, 3)
    strain: np.ndarray  # (n,)
    tilt: np.ndarray  # (n,) rad
    depth_min: np.ndarray  # (n,)
    margin: np.ndarray | None = None  # (n,)
    limit: np.ndarray | None = None  # (n,) int8

    def keep(self, mask: np.ndarray) -> _Survivors:
        idx = np.flatnonzero(mask)
        m = self.margin.take(idx) if self.margin is not None else None
        lim = self.limit.take(idx) if self.limit is not None else None
        return _Survivors(
            self.point.take(idx),
            self.approach.take(idx, axis=0),
            self.strain.take(idx),
            self.tilt.take(idx),
            self.depth_min.take(idx),
            m,
            lim,
        )

    def __len__(self) -> int:
        return len(self.point)


def suction_candidates(normals: np.ndarray, max_tilt_deg: float | None, model: SuctionModel = SUCTION) -> np.ndarray:
    """(n * (1 + T), 3) unit approaches for the points with outward `normals` (n, 3), point-major: the inward normal,
    then, with max_tilt_deg > 0, T = model.tilt_azimuths approaches at that angle from it, at azimuths 2 pi j / T
    from the normal's roll-0 X (CONTRACT.md suction grasp frame)."""
    inward = -np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    if not max_tilt_deg:
        return np.ascontiguousarray(inward)
    theta = math.radians(max_tilt_deg)
    x0, y0 = approach_basis(inward)
    rows = [inward]
    for j in range(model.tilt_azimuths):
        phi = 2.0 * math.pi * j / model.tilt_azimuths
        side = math.cos(phi) * x0 + math.sin(phi) * y0
        rows.append(math.cos(theta) * inward + math.sin(theta) * side)
    out = np.stack(rows, axis=1).reshape(-1, 3)
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    return np.ascontiguousarray(out)


@dataclass(frozen=True)
class CupJudgement:
    """Every criterion's outcome for given cups (judge_cups), arrays over n candidates."""

    seal: np.ndarray  # (n,) str: "pass" or why the seal fails (reach, depth, stretch, hole; position: not when
    # the cup is moved by the position tolerance, seal_within)
    seal_strain: np.ndarray  # (n,): the largest spring strain found (0 when the lip failed before its springs)
    tilt_deg: np.ndarray  # (n,): the lip plane's angle to the approach (0 when the lip failed)
    hold_margin: np.ndarray | None  # (n,), None without a mass
    hold_limit: np.ndarray | None  # (n,) str: friction, peel or pull
    free_rolls: np.ndarray  # (n, R) bool: the rolls at which cup and tool are clear


def judge_cups(
    mesh: trimesh.Trimesh,
    spec: SuctionSpec,
    points: np.ndarray,
    approach: np.ndarray,
    *,
    mass_kg: float | None = None,
    center_of_mass: np.ndarray | None = None,
    accel: float = Params.accel,
    safety_factor: float = Params.safety_factor,
    friction: float | None = None,
    rolls: int = Params.rolls,
    position_tolerance: float = Params.position_tolerance,
) -> CupJudgement:
    """Each criterion of the suction method on its own, for cups at contacts `points` (n, 3) with unit approaches
    `approach` (n, 3) on the closed `mesh` (metres): what generate() decides, without removing a candidate when an
    earlier criterion fails (a cup whose lip failed is tested for collision from the contact's plane). The centre of
    mass defaults to the mesh's."""
    P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    A = np.asarray(approach, dtype=np.float64).reshape(-1, 3)
    A = np.ascontiguousarray(A / np.linalg.norm(A, axis=1, keepdims=True))
    tree = build_tree(mesh.vertices, mesh.faces)
    seal_part, seal_rule = SealPart(tree.record(), tree.normals), _seal_rule(spec)
    sealed = seal_kernel(seal_part, P, A, seal_rule)
    names = np.array(["pass", *REASONS.values(), "position"])
    seal = names[sealed.status]
    if position_tolerance > 0.0:
        ok = np.flatnonzero(sealed.status == PASS)
        steady = seal_within(seal_part, P[ok], A[ok], seal_rule, position_tolerance)
        seal[ok[~steady]] = "position"
    margin = limit = None
    if mass_kg is not None:
        com = center_of_mass if center_of_mass is not None else _center_of_mass(mesh)
        load = safety_factor * hold_load(mass_kg, accel)
        mu = spec.friction if friction is None else friction
        held = hold_kernel(P, A, HoldRule(spec.cup_radius, spec.vacuum_force, mu, load, np.asarray(com, float)))
        margin, limit = held.margin, np.array(LIMITS)[held.limit]
    crule, body = _collision_rule(spec, tree, Params(rolls=rolls))
    free = collision_kernel(tree.record(), P, A, np.nan_to_num(sealed.depth_min, nan=0.0), crule, body)
    return CupJudgement(
        seal=seal,
        seal_strain=sealed.strain,
        tilt_deg=np.degrees(sealed.tilt),
        hold_margin=margin,
        hold_limit=limit,
        free_rolls=free,
    )


def _center_of_mass(mesh: trimesh.Trimesh) -> np.ndarray:
    return center_of_mass(mesh, None)


def generate_suction(
    mesh_or_path: str | os.PathLike[str] | trimesh.Trimesh | Part,
    spec: SuctionSpec,
    *,
    params: Params,
    options: QualityOptions,
    units: str | None = None,
    recording: Any = None,
    progress: Progress | None = None,
    object_name: str | None = None,
    object_version: int | None = None,
) -> SuctionGraspSet:
    """Suction grasps for one part (module docstring); the arguments as graspgen.generate takes them."""
    report = progress or _noop
    started = time.perf_counter()
    check_params(params, options)
    run = _Run(spec, params, spec.friction if params.friction is None else params.friction, report, {})
    loaded = _load(run, mesh_or_path, units, object_name)
    validator = None
    if options.validate:
        check_validation_inputs(loaded.mass)
        assert loaded.mass is not None  # checked
        validator = suction_validator(
            loaded.part.surface_mesh(),
            spec,
            mass_kg=loaded.mass,
            friction=run.mu,
            seed=params.seed,
            options=options,
            poses=_poses,
        )
    surface = _sample(run, loaded.part)
    sealed = _seal(run, surface)
    held = _hold(run, loaded, surface, sealed.survivors)
    s, free = _collide(run, surface, held.survivors)
    cands = SuctionCandidates(
        contacts=surface.points[s.point].reshape(-1, 1, 3),
        normals=surface.normals[s.point].reshape(-1, 1, 3),
        approach=np.ascontiguousarray(s.approach),
        free_rolls=free,
        roll_angles_rad=roll_angles_rad(params.rolls),
        seal_strain=s.strain,
        tilt_deg=np.degrees(s.tilt),
        labels=np.full((len(s), 2), -1, dtype=np.int32),
        medoids=np.zeros(0, dtype=np.int64),
        hold_margin=s.margin,
        hold_limit=s.limit,
    )
    stats = _stats(run, loaded, surface, sealed, held, s)
    part = loaded.part
    obj = {
        "name": object_name or part.name,
        "version": object_version,
        "sha256": part.sha256,
        "source_units": part.source_units,
    }
    result = _cluster_and_export(
        cands,
        stats,
        _Selection(obj, spec, params, run.mu, loaded.mass, list(part.warnings)),
        report,
        started,
        validator,
    )
    if recording is not None:
        from ._recording import record_suction_run

        record_suction_run(
            recording, result, part=loaded.part, sample_points=surface.points, sample_normals=surface.normals
        )
    return result


def recluster_suction(
    candidates: str | os.PathLike[str] | IO[bytes] | SuctionCandidates,
    previous_export: dict[str, Any],
    *,
    k1: int,
    k2: int,
    seed: int = Params.seed,
    options: QualityOptions | None = None,
    recording: Any = None,
    progress: Progress | None = None,
    gripper: SuctionSpec | None = None,
) -> SuctionGraspSet:
    """A new selection from a suction set's stored candidates (its NPZ, or SuctionCandidates) and its export
    (`gripper.kind` "suction"), clustered with k1 / k2 / seed: the export a fresh generate_suction of the same part,
    cup and parameters with these k1 / k2 / seed makes (but for stats.timings_s). `gripper`: the spec the set was
    made with, required when it has a body mesh (the export names its file and digest, not its contents); its
    to_dict() must be the export's `gripper`. `options` as generate's: best-near-medoid selection is refused
    (check_params), and so is validate (the simulation needs the part, which the candidates do not hold: generate
    the set again with validate)."""
    report = progress or _noop
    started = time.perf_counter()
    cands = candidates if isinstance(candidates, SuctionCandidates) else load_suction_candidates(candidates)
    if gripper is None:
        spec = SuctionSpec.from_dict(previous_export["gripper"])
    elif gripper.to_dict() == previous_export["gripper"]:
        spec = gripper
    else:
        raise InvalidParameterError("gripper is not the spec the grasp set was made with", field="gripper")
    old = dict(previous_export["params"])
    mu = float(old.get("friction") or spec.friction)
    # the export carries the mass the run resolved (given, or density x volume) beside the density it came from
    mass = old.pop("mass_kg", None)
    params = Params.from_dict({**old, "k1": k1, "k2": k2, "seed": seed, "friction": mu})
    check_params(params, options or QualityOptions(), recluster=True)
    if len(cands.roll_angles_rad) != params.rolls:
        raise InvalidParameterError("the candidates' roll count differs from the export's params.rolls", field="rolls")
    prev = copy.deepcopy(previous_export.get("stats", {}))
    if prev.get("candidates", len(cands)) != len(cands):
        raise InvalidCandidatesError(
            f"the candidates ({len(cands)}) are not the export's ({prev['candidates']}): not this set's NPZ"
        )
    # the export's stats in their order, but for what clustering makes again
    stats = {k: v for k, v in prev.items() if k not in ("cluster_note", "coverage", "export_order")}
    stats["timings_s"] = {}
    cands = _with_hold_limits(cands, spec, stats.get("hold"))
    obj = dict(previous_export["object"])
    result = _cluster_and_export(cands, stats, _Selection(obj, spec, params, mu, mass, []), report, started)
    if recording is not None:
        from ._recording import record_suction_run

        record_suction_run(recording, result, part=None, sample_points=None, sample_normals=None)
    return result


def _with_hold_limits(cands: SuctionCandidates, spec: SuctionSpec, hold: Any) -> SuctionCandidates:
    """The candidates with their hold_limit: as stored, or (an NPZ written without it) the hold kernel run again on
    the contacts and approaches with the cup and the load, friction and centre of mass the export's stats.hold
    records (the same inputs, so the same limits and margins as the run's)."""
    if cands.hold_margin is None or cands.hold_limit is not None:
        return cands
    try:
        rule = HoldRule(
            float(spec.cup_radius),
            float(spec.vacuum_force),
            float(hold["friction"]),
            float(hold["load_n"]),
            np.asarray(hold["center_of_mass"], dtype=np.float64).reshape(3),
        )
    except (KeyError, TypeError, ValueError):
        raise InvalidCandidatesError(
            "the candidates have hold margins but no hold_limit, and the export's stats.hold lacks the load to "
            "compute them again",
            field="hold_limit",
        ) from None
    held = hold_kernel(np.ascontiguousarray(cands.contacts[:, 0]), np.ascontiguousarray(cands.approach), rule)
    return replace(cands, hold_limit=held.limit)


# --------------------------------------------------------------------------------------------------------------------
# the stages of generate_suction(), each a function of the run and the earlier stages' results


@dataclass(frozen=True)
class _Run:
    """One run's checked inputs; `timings`: stage -> seconds (the export's stats.timings_s), in order."""

    spec: SuctionSpec
    params: Params
    #: the friction coefficient the run uses: the parameter, else the cup's
    mu: float
    report: Progress
    timings: dict[str, float]


@dataclass(frozen=True)
class _Loaded:
    """The part in metres (a mesh), its mass (kg; None without mass_kg or density) and centre of mass (3,)."""

    part: Part
    mass: float | None
    mass_note: str | None
    com: np.ndarray


@dataclass(frozen=True)
class _Surface:
    """The sampled surface and the part's triangle tree."""

    points: np.ndarray  # (k, 3) metres
    normals: np.ndarray  # (k, 3) unit, outward
    spacing: float
    min_spacing: float
    tree: MeshTree


@dataclass(frozen=True)
class _Sealed:
    """The candidates made, those that seal (and pass tilt), and the counts."""

    total: int
    survivors: _Survivors
    rejected_seal: int
    rejected_tilt: int
    #: seal failures by reason (REASONS' names)
    counts: dict[str, int]
    rule: SealRule


@dataclass(frozen=True)
class _Held:
    """Criterion hold: the survivors that hold (all of them when it did not run)."""

    survivors: _Survivors
    active: bool
    removed: int
    load: float | None
    #: when hold removed every candidate: what would make the best one hold
    diagnosis: dict[str, Any] | None


def _load(
    run: _Run, mesh_or_path: str | os.PathLike[str] | trimesh.Trimesh | Part, units: str | None, name: str | None
) -> _Loaded:
    run.report("load", 0.0)
    t0 = time.perf_counter()
    part = as_part(mesh_or_path, units=units, name=name)
    if part.mesh is None:
        raise InvalidMeshError(
            "a suction cup's seal is judged on the part's triangles, and a point cloud has none: give the part as a "
            "mesh (a scan meshed, or the CAD model)",
            field="file",
        )
    mass, mass_note = part_mass(part, run.params.mass_kg, run.params.density)
    com = center_of_mass(part.mesh, part.points)
    run.timings["load"] = time.perf_counter() - t0
    run.report("load", 1.0)
    return _Loaded(part, mass, mass_note, com)


def _sample(run: _Run, part: Part) -> _Surface:
    assert part.mesh is not None  # _load refuses point clouds
    run.report("sample", 0.0)
    t0 = time.perf_counter()
    sample = sampling.sample_surface(part, run.params.points, seed=run.params.seed)
    tree = build_tree(part.mesh.vertices, part.mesh.faces)
    run.timings["sample"] = time.perf_counter() - t0
    run.report("sample", 1.0)
    return _Surface(sample.points, sample.normals, float(sample.spacing), float(sample.min_spacing), tree)


def _seal(run: _Run, surface: _Surface) -> _Sealed:
    """The candidates (every point, its approaches), then criteria seal and tilt."""
    run.report("pairs", 0.0)
    t0 = time.perf_counter()
    pts, tree = surface.points, surface.tree
    approach = suction_candidates(surface.normals, run.params.max_tilt_deg)
    point = np.repeat(np.arange(len(pts), dtype=np.int64), len(approach) // max(len(pts), 1))
    rule = _seal_rule(run.spec)
    seal_part = SealPart(tree.record(), tree.normals)
    sealed = seal_kernel(seal_part, pts[point], approach, rule)
    counts = {name: int(np.count_nonzero(sealed.status == code)) for code, name in REASONS.items()}
    s = _Survivors(point, approach, sealed.strain, sealed.tilt, sealed.depth_min).keep(sealed.status == PASS)
    tol = run.params.position_tolerance
    if tol > 0.0 and len(s):
        steady = seal_within(seal_part, pts[s.point], s.approach, rule, tol)
        counts["position"] = int(np.count_nonzero(~steady))
        s = s.keep(steady)
    rejected_seal = len(point) - len(s)
    rejected_tilt = 0
    if run.params.max_tilt_deg is not None:
        within = s.tilt <= math.radians(run.params.max_tilt_deg) + SUCTION.tilt_slack
        rejected_tilt = len(s) - int(np.count_nonzero(within))
        s = s.keep(within)
    run.timings["seal"] = time.perf_counter() - t0
    run.report("pairs", 0.5)
    return _Sealed(len(point), s, rejected_seal, rejected_tilt, counts, rule)


def seal_within(part: SealPart, points: np.ndarray, approach: np.ndarray, rule: SealRule, tol: float) -> np.ndarray:
    """(n,) bool: the seal also holds with the cup's axis moved by `tol` (m) across the approach, in each of four
    directions (+-X0, +-Y0 of approach_basis), for cups that sealed at `points` (n, 3) with unit `approach` (n, 3).

    A robot places a cup a fraction of a millimetre off its pose; a lip that seals only where it lies (its rim
    tangent to an edge, a gear tooth's flank between two probes) loses its seal there (bench_suction_hold: every
    exported cup the simulation saw lose its seal lay within 0.1 mm of one). An edge at distance e from the lip is
    found for e < tol cos 45 deg whatever its direction. The moved cup is cast along the same approach from the
    moved point, so on a curved surface its depth differs by about tol^2 / 2R, far inside the depth limits."""
    x0, y0 = approach_basis(approach)
    keep = np.ones(len(points), dtype=bool)
    for d in (x0, -x0, y0, -y0):
        idx = np.flatnonzero(keep)
        moved = np.ascontiguousarray(points[idx] + tol * d[idx])
        status = seal_kernel(part, moved, np.ascontiguousarray(approach[idx]), rule).status
        keep[idx[status != PASS]] = False
    return keep


def _hold(run: _Run, loaded: _Loaded, surface: _Surface, s: _Survivors) -> _Held:
    """Criterion hold, with the part's mass (`hold` "off" or no mass: every candidate stays)."""
    t0 = time.perf_counter()
    params, spec = run.params, run.spec
    if params.hold == "off" or loaded.mass is None:
        run.timings["hold"] = time.perf_counter() - t0
        run.report("pairs", 1.0)
        return _Held(s, False, 0, None, None)
    load = params.safety_factor * hold_load(loaded.mass, params.accel)
    rule = HoldRule(spec.cup_radius, spec.vacuum_force, run.mu, load, loaded.com)
    held = hold_kernel(surface.points[s.point], s.approach, rule)
    keep = held.margin >= 1.0
    diagnosis = None
    if len(s) and not keep.any():
        best = int(np.argmax(held.margin))
        limit = LIMITS[int(held.limit[best])]
        diagnosis = _hold_diagnosis(float(held.margin[best]), limit, spec, loaded.mass, params)
    kept = replace(s, margin=held.margin, limit=held.limit).keep(keep)
    run.timings["hold"] = time.perf_counter() - t0
    run.report("pairs", 1.0)
    return _Held(kept, True, len(s) - len(kept), load, diagnosis)


def _collide(run: _Run, surface: _Surface, s: _Survivors) -> tuple[_Survivors, np.ndarray]:
    """Criterion collision: the survivors with a free roll, and their free rolls (n, R)."""
    run.report("collision", 0.0)
    t0 = time.perf_counter()
    crule, body = _collision_rule(run.spec, surface.tree, run.params)
    free = collision_kernel(surface.tree.record(), surface.points[s.point], s.approach, s.depth_min, crule, body)
    clear = np.asarray(free.any(axis=1), dtype=bool)
    run.timings["collision"] = time.perf_counter() - t0
    run.report("collision", 1.0)
    return s.keep(clear), free[clear]


def _stats(
    run: _Run, loaded: _Loaded, surface: _Surface, sealed: _Sealed, held: _Held, s: _Survivors
) -> dict[str, Any]:
    """The export's stats of the criteria (clustering adds its own)."""
    params, spec = run.params, run.spec
    rejected = {
        "seal": sealed.rejected_seal,
        "tilt": sealed.rejected_tilt,
        "hold": held.removed,
        "collision": len(held.survivors) - len(s),
    }
    rule = sealed.rule
    stats: dict[str, Any] = {
        "points": len(surface.points),
        "candidates_total": sealed.total,
        "rejected": rejected,
        "candidates": len(s),
        "timings_s": run.timings,
        "spacing_mean": surface.spacing,
        "spacing_min": surface.min_spacing,
        "watertight": bool(loaded.part.watertight),
        "warnings": list(loaded.part.warnings),
        "seal": {
            **sealed.counts,
            "lip_points": len(rule.lip),
            "lip_slot_probes": len(rule.slot) - len(rule.lip),
            "interior_probes": len(rule.inner),
        },
    }
    if held.active:
        stats["hold"] = {
            "mass_kg": loaded.mass,
            "load_n": held.load,
            "safety_factor": params.safety_factor,
            "vacuum_force_n": spec.vacuum_force,
            "friction": run.mu,
            "center_of_mass": [float(v) for v in loaded.com],
            "min_margin": float(np.min(s.margin)) if len(s) and s.margin is not None else None,
            "limits": {name: int(np.count_nonzero(s.limit == k)) for k, name in enumerate(LIMITS)}
            if s.limit is not None
            else {},
        }
    elif params.hold != "off":
        stats["warnings"].append("criterion hold is off: it needs the part's mass (mass_kg or density)")
    if loaded.mass_note:
        stats["warnings"].append(loaded.mass_note)
    if len(s) == 0:
        stats["empty_reason"] = _empty_reason(rejected, sealed.total, spec, params, sealed.counts, held.diagnosis)
    return stats


def check_params(params: Params, options: QualityOptions, *, recluster: bool = False) -> None:
    """The run parameters and options that have no meaning for a suction cup are refused, not ignored; `recluster`:
    for a new selection from a set's stored candidates, which cannot be validated (the simulation needs the part,
    and the candidates do not hold it)."""
    if recluster and options.validate:
        raise InvalidParameterError(
            "validating a suction set needs the part, which its candidates do not hold: generate it again with "
            "validate",
            field="validate",
        )
    if params.inside:
        raise InvalidParameterError("inside grasps are for jaws: a suction cup seals on an outer face", field="inside")
    if params.collision != "swept":
        raise InvalidParameterError(
            "a suction cup's collision is the cup and tool swept from the pre-grasp pose (mode 'swept'); the paper's "
            "mode is for jaws",
            field="collision",
        )
    if options.select != "medoid":
        raise InvalidParameterError(
            "suction grasps are selected as the clusters' medoids (select 'medoid')", field="select"
        )


def _seal_rule(spec: SuctionSpec, model: SuctionModel = SUCTION) -> SealRule:
    lo, hi = depth_limits(spec.cup_radius, spec.cup_height, spec.max_strain)
    return SealRule(
        float(spec.cup_radius),
        float(spec.cup_height),
        float(spec.max_strain),
        lo,
        hi,
        model.recess_depth,
        lip_points(spec.cup_radius, model),
        lip_slot_probes(spec.cup_radius, model),
        inner_probes(spec.cup_radius, model),
        model.guard,
    )


def _collision_rule(
    spec: SuctionSpec, tree: MeshTree, params: Params, model: SuctionModel = SUCTION
) -> tuple[CollisionRule, TriangleTree]:
    """The collision kernel's rule and the body's tree (in body_frame; without triangles for a cylinder tool)."""
    c, H = float(spec.pregrasp_clearance), float(spec.cup_height)
    size = float(np.max(np.abs(tree.triangles))) if len(tree) else 1.0
    guard = model.guard * (size + H + c)
    angles = roll_angles_rad(params.rolls)
    cos = np.array([math.cos(t) for t in angles])
    sin = np.array([math.sin(t) for t in angles])
    tool_r = tool_z0 = tool_z1 = 0.0
    body = build_tree(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)).record()
    body_r = body_z0 = body_z1 = 0.0
    if spec.tool is not None:
        tool_r = float(spec.tool.radius)
        tool_z0, tool_z1 = -(H + float(spec.tool.length) + c), -H
    else:
        assert spec.geometry is not None  # a spec has a tool or a body
        v = spec.geometry.vertices
        body = mesh_solid(body_frame(v), spec.geometry.faces).record()
        body_r = float(np.max(np.hypot(v[:, 0], v[:, 1])))
        body_z0, body_z1 = float(v[:, 2].min()) - c, float(v[:, 2].max())
    rule = CollisionRule(
        float(spec.cup_radius),
        -(H + c),
        model.lip_clearance,
        tool_r,
        tool_z0,
        tool_z1,
        body_r,
        body_z0,
        body_z1,
        c,
        cos,
        sin,
        guard,
    )
    return rule, body


@dataclass(frozen=True)
class _Selection:
    """What a suction set's export carries beside its candidates and stats: the object, the cup, the run's parameters,
    its friction coefficient and the part's mass (kg, None without one), and the run's warnings."""

    obj: dict[str, Any]
    spec: SuctionSpec
    params: Params
    mu: float
    mass_kg: float | None
    warnings: list[str]


def _cluster_and_export(
    cands: SuctionCandidates,
    stats: dict[str, Any],
    sel: _Selection,
    report: Progress,
    started: float,
    validator: Validator | None = None,
) -> SuctionGraspSet:
    """Two-stage k-medoids (contacts, then signed approaches) with sel.params' k1, k2 and seed, the export's grasps
    best first within each translation cluster (validated cups first, then the larger hold margin, else the smaller
    seal strain, then the candidate index). Without a `validator` a function of the candidates alone:
    generate_suction and recluster_suction share it, so the same candidates and k1 / k2 / seed give the same
    grasps. A validator simulates the selected cups and may replace one by another member of its cluster; each
    grasp then carries its outcome (`sim`)."""
    params = sel.params
    report("cluster", 0.0)
    t0 = time.perf_counter()
    res = clustering.two_stage(cands.midpoints, cands.approach, params.k1, params.k2, seed=params.seed, signed=True)
    stats["timings_s"]["cluster"] = time.perf_counter() - t0
    if res.note:
        stats["cluster_note"] = res.note
    report("cluster", 1.0)

    report("export", 0.0)
    medoids = np.asarray(res.medoids, dtype=np.int64)
    clusters = np.asarray(res.medoid_clusters, dtype=np.int64).reshape(-1, 2)
    sizes = np.asarray(res.cluster_sizes, dtype=np.int64)
    labels = np.asarray(res.labels, dtype=np.int32).reshape(-1, 2)
    sim = None
    if validator is not None:
        t1 = time.perf_counter()
        medoids, sim = validator(cands, labels, medoids, clusters, stats, report)
        stats["timings_s"]["validate"] = time.perf_counter() - t1
    key = cands.hold_margin[medoids] if cands.hold_margin is not None else -cands.seal_strain[medoids]
    keys = [medoids, -key]
    if sim is not None:
        keys.append(np.array([not r.success for r in sim], dtype=bool))
    order = np.lexsort((*keys, clusters[:, 0])) if len(medoids) else medoids
    medoids, clusters, sizes = medoids[order], clusters[order], sizes[order]
    cands = replace(cands, labels=labels, medoids=medoids)
    stats["export_order"] = "hold_margin" if cands.hold_margin is not None else "seal_strain"
    grasps = _grasps(cands, medoids, clusters, sizes)
    if sim is not None:
        for r, g in enumerate(grasps):
            g["sim"] = sim[order[r]].to_json()
    stats["coverage"] = coverage(cands.midpoints, cands.approach, medoids).to_json()
    stats["timings_s"]["total"] = time.perf_counter() - started
    report("export", 1.0)
    return SuctionGraspSet(
        object=sel.obj,
        gripper=sel.spec,
        params=params,
        friction=sel.mu,
        stats=stats,
        grasps=grasps,
        candidates=cands,
        warnings=sel.warnings,
        mass_kg=sel.mass_kg,
    )


def _grasps(
    cands: SuctionCandidates, medoids: np.ndarray, clusters: np.ndarray, sizes: np.ndarray
) -> list[dict[str, Any]]:
    """The exported grasps: pose at roll 0 when every roll is free (a round tool), else at the middle of the widest
    run of free rolls (graspgen.transforms.choose_roll)."""
    if len(medoids) == 0:
        return []
    psi = _rolls(cands, medoids)
    T = suction_frames(cands.contacts[medoids, 0], cands.approach[medoids], psi)
    out = []
    for r, m in enumerate(medoids):
        g: dict[str, Any] = {
            "pose": T[r].tolist(),
            "contacts": cands.contacts[m].tolist(),
            "normals": cands.normals[m].tolist(),
            "approach": cands.approach[m].tolist(),
            "free_rolls_deg": [round(float(v), 9) for v in np.degrees(cands.roll_angles_rad[cands.free_rolls[m]])],
            "cluster": [int(clusters[r, 0]), int(clusters[r, 1])],
            "cluster_size": int(sizes[r]),
            "roll_deg": round(float(np.degrees(psi[r])), 9),
            "candidate": int(m),
            "seal_strain": round(float(cands.seal_strain[m]), 9),
            "tilt_deg": round(float(cands.tilt_deg[m]), 9),
        }
        if cands.hold_margin is not None and cands.hold_limit is not None:
            g["hold_margin"] = round(float(cands.hold_margin[m]), 6)
            g["hold_limit"] = LIMITS[int(cands.hold_limit[m])]
        out.append(g)
    return out


def _rolls(cands: SuctionCandidates, idx: np.ndarray) -> np.ndarray:
    """(k,) radians: the exported roll of candidates idx: 0 when every roll is free (a round tool), else the middle
    of the widest run of free rolls (graspgen.transforms.choose_roll)."""
    rolls = np.array([0 if cands.free_rolls[m].all() else choose_roll(cands.free_rolls[m]) for m in idx], dtype=int)
    return np.asarray(cands.roll_angles_rad[rolls], dtype=np.float64)


def _poses(cands: SuctionCandidates, idx: np.ndarray) -> np.ndarray:
    """(k, 4, 4): the exported poses (T_object_grasp) of candidates idx."""
    return suction_frames(cands.contacts[idx, 0], cands.approach[idx], _rolls(cands, idx))


def _hold_diagnosis(best: float, limit: str, spec: SuctionSpec, mass: float, params: Params) -> dict[str, Any]:
    """What would make the best sealing cup hold: its margin grows with the vacuum and falls with the mass."""
    need = spec.vacuum / best if best > 0 else math.inf
    max_mass = mass * best
    more = (
        f"a vacuum of at least {need:.0f} Pa (the cup has {spec.vacuum:g} Pa)"
        if need <= MAX_VACUUM
        else f"more than any vacuum gives ({need:.0f} Pa, above one atmosphere): a larger cup or several cups"
    )
    return {
        "best_margin": best,
        "limit": limit,
        "vacuum_needed": need,
        "max_mass_kg": max_mass,
        "message": (
            f"no sealing cup holds the part (criterion hold): the best resists {best:.2f} of the load ({mass:g} kg at "
            f"{params.accel:g} m/s^2 beyond gravity, safety factor {params.safety_factor:g}), limited by {limit}; it "
            f"needs {more}, or a part under {max_mass:.3f} kg"
        ),
    }


def _empty_reason(
    rejected: dict[str, int],
    total: int,
    spec: SuctionSpec,
    params: Params,
    seal_counts: dict[str, int],
    hold_diag: dict[str, Any] | None,
) -> dict[str, Any]:
    """Which criterion removed the last candidates, and what to change."""
    left = total
    criterion = "seal"
    for criterion in CRITERIA:
        left -= rejected[criterion]
        if left <= 0:
            break
    if criterion == "hold" and hold_diag is not None:
        return {"criterion": "hold", **hold_diag}
    cup = f"{2 * spec.cup_radius * 1e3:.0f} mm"
    if criterion == "seal":
        why = max(seal_counts, key=lambda k: seal_counts[k]) if any(seal_counts.values()) else "reach"
        message = {
            "reach": f"the lip (a {cup} cup) runs off the part or off its curve wherever it is put: the part's "
            "faces are narrower or more curved than the cup; use a smaller cup",
            "depth": f"the surface under the lip (a {cup} cup) is too curved or stepped for max_strain "
            f"{spec.max_strain:g}: use a smaller cup or a softer lip (a larger max_strain, a taller bellows)",
            "stretch": f"the lip (a {cup} cup) crosses an edge or a crease wherever it is put: use a smaller cup or "
            "a softer lip (a larger max_strain)",
            "hole": f"every spot the lip (a {cup} cup) seals on spans a hole, slot or gap, or has a groove crossing "
            "under the lip: use a smaller cup",
        }[why]
        return {"criterion": "seal", "seal_failure": why, "message": message}
    if criterion == "tilt":
        return {
            "criterion": "tilt",
            "message": f"no sealing approach lies within max_tilt_deg = {params.max_tilt_deg:g} of the surface's "
            "normal under the lip: raise max_tilt_deg, or leave it out (approaches along the normals)",
        }
    if criterion == "hold":
        return {"criterion": "hold", "message": "no sealing cup holds the part (criterion hold)"}
    return {
        "criterion": "collision",
        "message": "the cup or the tool meets the part on the way in wherever the cup seals: use a narrower or "
        "shorter tool, or a smaller pregrasp_clearance",
    }
