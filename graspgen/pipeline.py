"""generate() and recluster(): the only orchestration of the method (sample, pairs, collision, cluster, export)."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import trimesh

from . import antipodal, clustering, sampling
from . import collision as _collision
from .errors import InvalidParameterError, InvalidUnitsError
from .export import Candidates, GraspSet
from .gripper import GripperSpec
from .params import Params
from .parts import Part, load_part
from .transforms import grasp_frames, roll_angles_rad

__all__ = ["generate", "recluster", "STAGES", "choose_roll"]

#: the stages reported to progress callbacks, in order
STAGES = ("load", "sample", "pairs", "collision", "cluster", "export")
#: the collision stage reports progress this many times
_COLLISION_BATCHES = 10

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
) -> GraspSet:
    """Grasps for one part and one gripper (see CONTRACT.md, Python API).

    `recording` is a path for a Rerun .rrd or a `rerun.RecordingStream` to log into. `progress(stage, fraction)`
    is called within and between stages; raising `graspgen.errors.Cancelled` from it stops the run.
    """
    report = progress or _noop
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
    report("load", 1.0)

    report("sample", 0.0)
    t0 = time.perf_counter()
    sample = sampling.sample_surface(part, params.points, seed=params.seed)
    cell = antipodal.pair_cell_size(spec.stroke, params.inside, spec.finger_thickness)
    order = antipodal.grid_order(sample.points, cell)
    pts, nrm = sample.points[order], sample.normals[order]
    timings["sample"] = time.perf_counter() - t0
    report("sample", 1.0)

    report("pairs", 0.0)
    t0 = time.perf_counter()
    half_angle = antipodal.cone_half_angle_rad(mu, params.safety_factor)
    pairs = antipodal.antipodal_pairs(
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
    t0 = time.perf_counter()
    d = pts[pairs.j] - pts[pairs.i]
    widths = np.linalg.norm(d, axis=1)
    axes = d / widths[:, None] if len(d) else np.zeros((0, 3))
    mids = 0.5 * (pts[pairs.i] + pts[pairs.j])
    model = _collision.collision_model(spec, params.collision)
    free = np.zeros((len(mids), params.rolls), dtype=bool)
    # in batches, so that progress (and a cancel) is reported within the longest stage
    bounds = np.linspace(0, len(mids), _COLLISION_BATCHES + 1).astype(np.int64)
    for b, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        if hi > lo:
            sl = slice(lo, hi)
            free[sl] = _collision.free_rolls(
                pts, nrm, mids[sl], axes[sl], widths[sl], pairs.inside[sl], model, params.rolls
            )
        report("collision", (b + 1) / _COLLISION_BATCHES)
    keep = free.any(axis=1)
    timings["collision"] = time.perf_counter() - t0

    ci, cj = pairs.i[keep], pairs.j[keep]
    cands = Candidates(
        contacts=np.stack([pts[ci], pts[cj]], axis=1).reshape(-1, 2, 3),
        normals=np.stack([nrm[ci], nrm[cj]], axis=1).reshape(-1, 2, 3),
        free_rolls=free[keep],
        roll_angles_rad=roll_angles_rad(params.rolls),
        friction_margin_deg=antipodal.friction_margin_deg(pts, nrm, ci, cj, pairs.inside[keep], half_angle),
        inside=pairs.inside[keep],
        labels=np.full((int(keep.sum()), 2), -1, dtype=np.int32),
        medoids=np.zeros(0, dtype=np.int64),
    )
    rejected = {
        "stroke": pairs.rejected_stroke,
        "outside": pairs.rejected_outside,
        "friction": pairs.rejected_friction,
        "collision": int(len(keep) - keep.sum()),
    }
    stats: dict[str, Any] = {
        "points": len(pts),
        "pairs_total": pairs.pairs_total,
        "rejected": rejected,
        "candidates": len(cands),
        "timings_s": timings,
        "spacing_mean": float(sample.spacing),
        "spacing_min": float(sample.min_spacing),
        "watertight": bool(part.watertight),
        "warnings": list(part.warnings),
    }
    if len(cands) == 0:
        stats["empty_reason"] = _empty_reason(rejected, pairs.pairs_total, spec, params, mu, pts, nrm)

    obj = {
        "name": object_name or part.name,
        "version": object_version,
        "sha256": part.sha256,
        "source_units": part.source_units,
    }
    result = _cluster_and_export(cands, obj, spec, params, mu, stats, report, t_all, list(part.warnings))
    if recording is not None:
        from .recording import record_run

        record_run(recording, result, sample_points=pts, sample_normals=nrm)
    return result


def recluster(
    candidates: str | os.PathLike | Candidates,
    previous_export: dict[str, Any],
    *,
    k1: int,
    k2: int,
    seed: int = 0,
    recording: Any = None,
    progress: Progress | None = None,
) -> GraspSet:
    """A new selection from stored candidates with other k1 / k2 / seed, without regenerating them."""
    from .export import load_candidates

    report = progress or _noop
    t_all = time.perf_counter()
    cands = candidates if isinstance(candidates, Candidates) else load_candidates(candidates)
    spec = GripperSpec.from_dict(previous_export["gripper"])
    old = dict(previous_export["params"])
    mu = float(old.get("friction") or spec.friction)
    params = Params.from_dict({**old, "k1": k1, "k2": k2, "seed": seed, "friction": mu})
    if len(cands.roll_angles_rad) != params.rolls:
        raise InvalidParameterError("the candidates' roll count differs from the export's params.rolls")
    prev = previous_export.get("stats", {})
    stats = {k: v for k, v in prev.items() if k not in ("timings_s", "cluster_note")}
    stats["timings_s"] = {}
    stats["candidates"] = len(cands)
    result = _cluster_and_export(cands, dict(previous_export["object"]), spec, params, mu, stats, report, t_all, [])
    if recording is not None:
        from .recording import record_run

        record_run(recording, result, sample_points=None, sample_normals=None)
    return result


def _cluster_and_export(cands, obj, spec, params, mu, stats, report, t_all, warnings) -> GraspSet:
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
    # best first within each translation cluster: larger friction margin, then candidate index
    order = np.lexsort((medoids, -cands.friction_margin_deg[medoids], clusters[:, 0])) if len(medoids) else medoids
    medoids, clusters, sizes = medoids[order], clusters[order], sizes[order]
    cands = Candidates(
        **{**cands.__dict__, "labels": np.asarray(res.labels, dtype=np.int32).reshape(-1, 2), "medoids": medoids}
    )
    grasps = _grasps(cands, medoids, clusters, sizes)
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


def _empty_reason(rejected, total, spec: GripperSpec, params: Params, mu: float, pts, nrm) -> dict[str, str]:
    """Which criterion removed the last pairs, and what to change.

    Pairs on one face or adjacent faces fail (b) or (c) whatever the stroke, so when (b) or (c) removed the last
    pairs, the pairs are judged once more without the stroke limit: if antipodal pairs exist but all are wider
    than the stroke, the stroke is what to change.
    """
    left = total
    criterion = "stroke"
    for criterion in ("stroke", "outside", "friction", "collision"):
        left -= rejected[criterion]
        if left <= 0:
            break
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
