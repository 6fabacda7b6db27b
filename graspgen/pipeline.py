"""generate() and recluster(): the only orchestration of the method (sample, pairs, collision, cluster, export)."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import trimesh

from . import antipodal, clustering, meshtree, quality, sampling
from . import collision as _collision
from . import hold as _hold
from .coverage import coverage
from .errors import InvalidParameterError, InvalidUnitsError
from .export import Candidates, GraspSet
from .gripper import GripperSpec
from .params import Params, QualityOptions
from .parts import Part, load_part
from .transforms import grasp_frames, roll_angles_rad

__all__ = ["generate", "recluster", "STAGES", "MAX_CANDIDATES", "choose_roll"]

#: the stages reported to progress callbacks, in order ("validate" only with validate=True)
STAGES = ("load", "sample", "pairs", "collision", "cluster", "validate", "export")
#: the collision stage reports progress at least this many times
_COLLISION_BATCHES = 10
#: pairs passing (a)-(c) are made and collision-checked this many at a time (about 120 bytes each while in flight),
#: so memory is bounded by the candidates that survive, not by the pairs: at 10,000 points one block holds them all
_PAIR_BLOCK = 4_000_000
#: collision-free candidates beyond this stop the run with a clear error (about 130 bytes each are kept, and
#: clustering, coverage and the candidate export work on all of them: 50 M is about 10 GB at the peak)
MAX_CANDIDATES = 50_000_000

Progress = Callable[[str, float], None]


def _noop(stage: str, fraction: float) -> None:
    return None


def generate(
    mesh_or_path: str | os.PathLike | trimesh.Trimesh | Part,
    gripper: GripperSpec | dict[str, Any],
    *,
    units: str | None = None,
    points: int = 10_000,
    friction: float | None = None,
    safety_factor: float = 1.5,
    rolls: int = 16,
    k1: int = 16,
    k2: int = 4,
    inside: bool = False,
    collision: str = "swept",
    seed: int = 0,
    recording: Any = None,
    progress: Progress | None = None,
    object_name: str | None = None,
    object_version: int | None = None,
    select: str = "medoid",
    validate: bool = False,
    mass_kg: float | None = None,
    density: float | None = None,
    accel: float = 9.81,
    hold: str = "any",
    position_tolerance: float = 0.001,
    repair_limit: int = 4,
    sim_workers: int | None = None,
) -> GraspSet:
    """Grasps for one part and one gripper (see CONTRACT.md, Python API).

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
    the mesh's triangles (meshtree.py).
    """
    report = progress or _noop
    options = QualityOptions(select=select, validate=validate, repair_limit=repair_limit, sim_workers=sim_workers)
    spec = gripper if isinstance(gripper, GripperSpec) else GripperSpec.from_dict(gripper)
    params = Params(
        points=points,
        friction=friction,
        safety_factor=safety_factor,
        rolls=rolls,
        k1=k1,
        k2=k2,
        inside=inside,
        collision=collision,
        seed=seed,
        mass_kg=mass_kg,
        density=density,
        accel=accel,
        hold=hold,
        position_tolerance=position_tolerance,
    )
    mu = spec.friction if params.friction is None else params.friction
    timings: dict[str, float] = {}
    t_all = time.perf_counter()

    report("load", 0.0)
    t0 = time.perf_counter()
    if isinstance(mesh_or_path, Part):
        part = mesh_or_path
    else:
        if units is None:
            raise InvalidUnitsError("units are required (mm, cm, m or in)", field="units")
        part = load_part(mesh_or_path, units=units, name=object_name)
    timings["load"] = time.perf_counter() - t0
    mass, mass_note = _hold.part_mass(part, params.mass_kg, params.density)
    if options.validate:
        _check_validation_inputs(mass, spec)
    report("load", 1.0)

    report("sample", 0.0)
    t0 = time.perf_counter()
    sample = sampling.sample_surface(part, params.points, seed=params.seed)
    cell = antipodal.pair_cell_size(spec.stroke, params.inside, spec.finger_thickness)
    order = antipodal.grid_order(sample.points, cell)
    pts, nrm = sample.points[order], sample.normals[order]
    t1 = time.perf_counter()
    tree = meshtree.build_tree(part.mesh.vertices, part.mesh.faces) if part.mesh is not None else None
    spread = _normal_spread(tree, pts, nrm, params.position_tolerance)
    timings["sample"] = time.perf_counter() - t0
    timings["sample_mesh_tree"] = time.perf_counter() - t1
    report("sample", 1.0)

    report("pairs", 0.0)
    t0 = time.perf_counter()
    half_angle = antipodal.cone_half_angle_rad(mu, params.safety_factor)
    plan = antipodal.pair_plan(
        pts,
        nrm,
        stroke=spec.stroke,
        min_width=spec.min_width,
        friction=mu,
        safety_factor=params.safety_factor,
        inside=params.inside,
        finger_thickness=spec.finger_thickness,
    )
    timings["pairs"] = time.perf_counter() - t0
    report("pairs", 1.0)

    report("collision", 0.0)
    ci, cj, free, inside, n_tolerance = _collide_in_blocks(
        plan, pts, nrm, spec, params, timings, report, spread=spread, half_angle=half_angle
    )
    n_point_free = len(ci)

    # criterion (e), then the mesh-exact check of the free rolls: both only on what is left
    t0 = time.perf_counter()
    com = quality.center_of_mass(part.mesh, part.points)
    hold_on, hold_warning = _hold_active(params, spec, mass)
    margins = None
    hold_diag = None
    n_hold = 0
    if hold_on:
        rho = _hold.torsion_radii(pts, nrm, _patch_radius(spec))
        load = _hold.hold_load(mass, params.accel)
        hold_args = dict(load=load, grip_force=spec.grip_force, friction=mu)
        contacts_all = np.stack([pts[ci], pts[cj]], axis=1)
        radii_all = np.stack([rho[ci], rho[cj]], axis=1)
        margins = _hold.hold_margins(contacts_all, radii_all, com, floor=1.0, **hold_args)
        keep = margins >= 1.0
        n_hold = int(np.sum(~keep))
        if n_point_free and not keep.any():
            best = float(np.max(_hold.hold_margins(contacts_all, radii_all, com, **hold_args)))
            hold_diag = _hold_diagnosis(best, spec, mass, params)
        ci, cj, free, inside, margins = ci[keep], cj[keep], free[keep], inside[keep], margins[keep]
    timings["hold"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    n_mesh_rolls = 0
    if tree is not None and len(ci):
        model = _collision.collision_model(spec, params.collision, reach=_collision.approach_reach(pts))
        d = pts[cj] - pts[ci]
        w = np.linalg.norm(d, axis=1)
        exact = meshtree.mesh_free_rolls(tree, 0.5 * (pts[ci] + pts[cj]), d / w[:, None], w, inside, free, model)
        n_mesh_rolls = int(free.sum() - exact.sum())
        keep = exact.any(axis=1)
        ci, cj, free, inside = ci[keep], cj[keep], exact[keep], inside[keep]
        margins = margins[keep] if margins is not None else None
    timings["collision_mesh"] = time.perf_counter() - t0
    timings["collision"] += timings["collision_mesh"]

    fm = antipodal.friction_margin_deg(pts, nrm, ci, cj, inside, half_angle)
    contacts = np.stack([pts[ci], pts[cj]], axis=1).reshape(-1, 2, 3)
    normals = np.stack([nrm[ci], nrm[cj]], axis=1).reshape(-1, 2, 3)
    # every candidate is scored (quality.py): it orders the export, and `best-near-medoid` selects by it. The
    # contacts are sample points, so the patch flatness is computed once per point
    flat = quality.point_flatness(pts, nrm, _patch_radius(spec))
    terms = quality.quality_terms(
        contacts,
        normals,
        fm,
        half_angle_deg=quality.half_angle_deg(mu, params.safety_factor),
        center_of_mass=com,
        length_scale=_length_scale(part),
        flatness=np.stack([flat[ci], flat[cj]], axis=1),
    )
    cands = Candidates(
        contacts=contacts,
        normals=normals,
        free_rolls=free,
        roll_angles_rad=roll_angles_rad(params.rolls),
        friction_margin_deg=fm,
        inside=inside,
        labels=np.full((len(ci), 2), -1, dtype=np.int32),
        medoids=np.zeros(0, dtype=np.int64),
        quality_terms=terms,
        center_of_mass=com,
        hold_margin=margins,
    )
    # the mesh-exact check ran after (e): what it removed counts as collision, with the point test's
    n_mesh = n_point_free - n_hold - len(cands)
    rejected = {
        "stroke": plan.rejected_stroke,
        "outside": plan.rejected_outside,
        "friction": plan.rejected_friction + n_tolerance,
        "collision": plan.accepted - n_tolerance - n_point_free + n_mesh,
        "hold": n_hold,
    }
    stats: dict[str, Any] = {
        "points": len(pts),
        "pairs_total": plan.pairs_total,
        "rejected": rejected,
        "candidates": len(cands),
        "timings_s": timings,
        "spacing_mean": float(sample.spacing),
        "spacing_min": float(sample.min_spacing),
        "watertight": bool(part.watertight),
        "warnings": list(part.warnings),
        "exact": {
            "friction_position_tolerance": n_tolerance,
            "collision_mesh_rolls": n_mesh_rolls,
            "collision_mesh_candidates": n_mesh,
        },
    }
    if hold_on:
        stats["hold"] = {
            "mass_kg": mass,
            "load_n": load,
            "grip_force": spec.grip_force,
            "friction": mu,
            "center_of_mass": [float(v) for v in com],
            "min_margin": float(np.min(margins)) if len(cands) else None,
        }
    for note in (hold_warning, mass_note):
        if note:
            stats["warnings"].append(note)
    if len(cands) == 0:
        stats["empty_reason"] = _empty_reason(rejected, plan.pairs_total, spec, params, mu, pts, nrm, hold_diag)

    obj = {
        "name": object_name or part.name,
        "version": object_version,
        "sha256": part.sha256,
        "source_units": part.source_units,
    }
    extras = _Extras(options, part, mass, (pts, nrm))
    params = replace(params, hold="any" if hold_on else "off")
    result = _cluster_and_export(cands, obj, spec, params, mu, stats, report, t_all, list(part.warnings), extras)
    if recording is not None:
        from .recording import record_run

        record_run(recording, result, sample_points=pts, sample_normals=nrm)
    return result


def _collide_in_blocks(plan, pts, nrm, spec: GripperSpec, params: Params, timings, report, *, spread, half_angle):
    """Criterion (c) with the position tolerance, then (d), for every pair of `plan`, streamed in blocks of
    `_PAIR_BLOCK` pairs.

    Returns the surviving pairs (ci, cj), their free-roll masks and inside flags, in the order of
    `antipodal_pairs`, and how many pairs the position tolerance removed. Filling the pairs counts as the pairs
    stage, the rest as the collision stage.
    """
    model = _collision.collision_model(spec, params.collision, reach=_collision.approach_reach(pts))
    m = plan.accepted
    # progress (and a cancel) at least every m / _COLLISION_BATCHES pairs, within the longest stage
    step = max(-(-m // _COLLISION_BATCHES), 1)
    kept_i: list[np.ndarray] = []
    kept_j: list[np.ndarray] = []
    kept_free: list[np.ndarray] = []
    kept_inside: list[np.ndarray] = []
    n_kept = 0
    n_tolerance = 0
    t_fill = t_coll = 0.0
    for r0, r1 in plan.blocks(_PAIR_BLOCK):
        t0 = time.perf_counter()
        bi, bj, bins = plan.fill(r0, r1)
        p0 = int(plan.offsets[r0])
        block = len(bi)
        pos = np.arange(block)  # each pair's place in the block, for progress
        if spread is not None:
            ok = antipodal.within_spread(pts, nrm, bi, bj, bins, spread, half_angle)
            if not ok.all():
                n_tolerance += int(np.sum(~ok))
                bi, bj, bins, pos = bi[ok], bj[ok], bins[ok], pos[ok]
        t_fill += time.perf_counter() - t0
        t0 = time.perf_counter()
        free = np.zeros((len(bi), params.rolls), dtype=bool)
        # segment boundaries: the block's ends and every multiple of `step` inside it
        cuts = np.unique(np.r_[0, np.searchsorted(pos, np.arange(-p0 % step, block, step)), len(bi)])
        for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
            sl = slice(int(lo), int(hi))
            free[sl] = _collision.free_rolls_of_pairs(pts, bi[sl], bj[sl], bins[sl], model, params.rolls, normals=nrm)
            report("collision", (p0 + (block if hi == len(bi) else int(pos[hi]))) / m)
        if len(bi) == 0 and m:
            report("collision", (p0 + block) / m)
        keep = free.any(axis=1)
        n_kept += int(keep.sum())
        if n_kept > MAX_CANDIDATES:
            raise InvalidParameterError(
                f"more than {MAX_CANDIDATES:,} collision-free candidates at {len(pts):,} points (after "
                f"{p0 + len(bi):,} of the {m:,} pairs that pass criteria (a)-(c)), more than this run may hold: use "
                f"fewer points (candidates grow with the square of the points)",
                field="points",
            )
        kept_i.append(bi[keep])
        kept_j.append(bj[keep])
        kept_free.append(free[keep])
        kept_inside.append(bins[keep])
        t_coll += time.perf_counter() - t0
    timings["pairs"] += t_fill
    timings["collision"] = t_coll
    if m == 0:
        report("collision", 1.0)  # otherwise the last segment reported it
    if not kept_i:
        e = np.zeros(0, dtype=np.int64)
        return e, e.copy(), np.zeros((0, params.rolls), dtype=bool), np.zeros(0, dtype=bool), n_tolerance
    cat = np.concatenate
    return cat(kept_i), cat(kept_j), cat(kept_free), cat(kept_inside), n_tolerance


def _normal_spread(tree, pts, nrm, tolerance: float) -> np.ndarray | None:
    """Per sample point, the largest angle (rad) between its normal and a surface normal within `tolerance`: of
    the mesh's triangles, or for a point cloud of the other sample points; None when nothing is near."""
    if tolerance <= 0 or len(pts) == 0:
        return None
    if tree is not None:
        spread = meshtree.normal_spread_rad(tree, pts, nrm, tolerance)
    else:
        from scipy.spatial import cKDTree

        spread = np.zeros(len(pts))
        for a, hood in enumerate(cKDTree(pts).query_ball_point(pts, r=tolerance)):
            spread[a] = float(np.arccos(np.clip(np.min(nrm[hood] @ nrm[a]), -1.0, 1.0)))
    return spread if np.any(spread > 0) else None


def _check_validation_inputs(mass: float | None, spec: GripperSpec) -> None:
    try:  # the `validate` extra: the library alone does not install them
        import coacd  # noqa: F401
        import mujoco  # noqa: F401
    except ImportError as exc:
        raise InvalidParameterError(
            f"validate needs {exc.name}: pip install 'graspgen[validate]'", field="validate"
        ) from None
    if mass is None:
        raise InvalidParameterError("validate needs the part's mass: give mass_kg or density", field="mass_kg")
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


def recluster(
    candidates: str | os.PathLike | Candidates,
    previous_export: dict[str, Any],
    *,
    k1: int,
    k2: int,
    seed: int = 0,
    recording: Any = None,
    progress: Progress | None = None,
    select: str = "medoid",
    validate: bool = False,
    mass_kg: float | None = None,
    density: float | None = None,
    repair_limit: int = 4,
    sim_workers: int | None = None,
    mesh: str | os.PathLike | trimesh.Trimesh | Part | None = None,
    units: str | None = None,
) -> GraspSet:
    """A new selection from stored candidates with other k1 / k2 / seed, without regenerating them.

    `select` and `validate` as in generate(); validation, and quality scoring of candidates stored without
    quality terms, need the part: `mesh` (a Part, a mesh in metres, or a path with `units`).
    """
    from .export import load_candidates

    report = progress or _noop
    options = QualityOptions(select=select, validate=validate, repair_limit=repair_limit, sim_workers=sim_workers)
    t_all = time.perf_counter()
    cands = candidates if isinstance(candidates, Candidates) else load_candidates(candidates)
    spec = GripperSpec.from_dict(previous_export["gripper"])
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


def _cluster_and_export(cands, obj, spec, params, mu, stats, report, t_all, warnings, extras=None) -> GraspSet:
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
    sim = None
    if extras.options.validate and len(medoids) == 0:
        from .physics import summarise

        stats["validation"] = {**summarise([]), "repaired": 0, "simulated": 0}
    elif extras.options.validate:
        t0 = time.perf_counter()
        medoids, sim = _validate(cands, labels, medoids, clusters, spec, mu, params, extras, stats, report)
        stats["timings_s"]["validate"] = time.perf_counter() - t0
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


def choose_roll(free: np.ndarray) -> int:
    """The roll at the middle of the widest circular run of free rolls.

    Ties go to the run whose middle is closest to half a turn (approach from the object's +Z side, palm up),
    then to the smaller index; with every roll free, half a turn itself.
    """
    R = len(free)
    if free.all():
        return R // 2
    if not free.any():
        raise ValueError("no free roll")
    start = int(np.argmin(free))  # a blocked roll: runs do not wrap past it
    best = None
    k = 0
    while k < R:
        idx = (start + k) % R
        if free[idx]:
            length = 0
            while k < R and free[(start + k) % R]:
                length += 1
                k += 1
            middle = (idx + (length - 1) // 2) % R
            dist = min(abs(middle - R // 2), R - abs(middle - R // 2))
            key = (-length, dist, middle)
            if best is None or key < best:
                best = key
        else:
            k += 1
    return int(best[2])


def _grasps(cands: Candidates, medoids, clusters, sizes) -> list[dict[str, Any]]:
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


def _empty_reason(rejected, total, spec: GripperSpec, params: Params, mu: float, pts, nrm, hold_diag=None) -> dict:
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
    out = {"criterion": criterion, "message": hints[criterion]}
    if narrowest is not None:
        out["narrowest_antipodal_width"] = narrowest
    return out


# --------------------------------------------------------------------------------------------------------------------
# quality-aware selection and physics validation (docs/QUALITY.md)


@dataclass(frozen=True)
class _Extras:
    """The quality options and what a run resolved for them: the part (to score and simulate), its mass (kg) for
    the validation, and its sampled surface (points, normals) for the flatness term when the run has it."""

    options: QualityOptions = QualityOptions()
    part: Part | None = None
    mass_kg: float | None = None
    surface: tuple[np.ndarray, np.ndarray] | None = None


def _mean(values: np.ndarray) -> float | None:
    return round(float(np.mean(values)), 6) if len(values) else None


def _surface_for_quality(part: Part, params: Params) -> tuple[np.ndarray, np.ndarray]:
    sample = sampling.sample_surface(part, params.points, seed=params.seed)
    return sample.points, sample.normals


def _with_quality(cands: Candidates, part: Part, pts, nrm, spec: GripperSpec, mu: float, params: Params) -> Candidates:
    """The candidates with their quality terms (quality.py) and the part's centre of mass."""
    com = quality.center_of_mass(part.mesh, part.points)
    terms = _quality_terms(cands, np.arange(len(cands)), part, com, pts, nrm, spec, mu, params)
    return replace(cands, quality_terms=terms, center_of_mass=com)


def _quality_terms(cands: Candidates, idx, part: Part, com, pts, nrm, spec: GripperSpec, mu: float, params: Params):
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
    return min(spec.finger_width, spec.finger_depth) / 2


def _export_terms(cands: Candidates, idx, extras: _Extras, spec: GripperSpec, mu: float, params: Params):
    """Quality terms of the exported grasps `idx`, to order the export: from the candidates when they were
    scored, else computed for these few grasps (cheap); None without the part (recluster without `mesh`)."""
    if cands.quality_terms is not None:
        return cands.quality_terms[idx]
    if extras.part is None:
        return None
    pts, nrm = extras.surface if extras.surface is not None else _surface_for_quality(extras.part, params)
    com = quality.center_of_mass(extras.part.mesh, extras.part.points)
    return _quality_terms(cands, idx, extras.part, com, pts, nrm, spec, mu, params)


def _poses(cands: Candidates, idx: np.ndarray) -> np.ndarray:
    """The export's pose (T_object_grasp, (m, 4, 4)) of candidates `idx`, at the roll choose_roll picks."""
    rolls = np.array([choose_roll(cands.free_rolls[m]) for m in idx], dtype=np.int64)
    return grasp_frames(cands.midpoints[idx], cands.axes[idx], cands.roll_angles_rad[rolls])


def _validate(cands, labels, selected, clusters, spec, mu, params, extras: _Extras, stats, report):
    """Simulate the selected grasps; replace each failing one by the first of up to `repair_limit` members of its
    final cluster (nearest to it first) that succeeds. Returns the new selection and its SimResults."""
    from . import physics

    report("validate", 0.0)
    part = extras.part
    note = None
    if part.is_point_cloud:
        note = "a point cloud has no surface to simulate: simulated as the convex hull of its points"
    sim_part = physics.prepare_part(part.surface_mesh(), spec, friction=mu, mass_kg=extras.mass_kg, seed=params.seed)
    report("validate", 0.1)
    widths = cands.widths
    run = lambda idx: physics.simulate_grasps(  # noqa: E731
        sim_part,
        _poses(cands, idx),
        widths[idx],
        seed=params.seed,
        keys=idx,
        workers=extras.options.sim_workers,
        inside=cands.inside[idx],
    )
    results = run(selected)
    first = list(results)
    simulated = len(selected)
    final = selected.copy()
    alternatives = {}
    mids, axes = cands.midpoints, cands.axes
    for r, res in enumerate(results):
        if res.success or extras.options.repair_limit == 0:
            continue
        t, k = clusters[r]
        members = np.flatnonzero((labels[:, 0] == t) & (labels[:, 1] == k))
        members = members[members != selected[r]]
        ordered, _ = quality.members_by_distance(members, int(selected[r]), mids, axes)
        alternatives[r] = ordered[: extras.options.repair_limit]
    for j in range(extras.options.repair_limit):
        rows = [r for r, alts in alternatives.items() if not results[r].success and j < len(alts)]
        if not rows:
            break
        idx = np.array([alternatives[r][j] for r in rows], dtype=np.int64)
        simulated += len(idx)
        for r, m, res in zip(rows, idx, run(idx), strict=True):
            if res.success:
                final[r], results[r] = m, res
        report("validate", 0.1 + 0.9 * (j + 1) / extras.options.repair_limit)
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
        "mass_kg": extras.mass_kg,
        "grip_force": spec.grip_force,
        "part": part_info,
        "engine": f"mujoco {mujoco.__version__}",
    }
    return final, results
