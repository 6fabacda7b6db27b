"""Rerun recording (.rrd) of one run: the sample, the candidates by cluster, the chosen grippers, the stats."""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .transforms import matrix_to_quaternion_xyzw

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr

    from .export import GraspSet

__all__ = [
    "record_run",
    "write_recording",
    "log_sample_and_candidates",
    "MAX_LOGGED_CANDIDATES",
    "cluster_colours",
    "SIM_COLOURS",
]

#: candidate midpoints beyond this many are thinned (evenly by index) to keep recordings small
MAX_LOGGED_CANDIDATES = 200_000


def cluster_colours(labels: np.ndarray) -> np.ndarray:
    """A fixed, well-separated RGB colour (uint8, (n, 3)) per cluster label (golden-angle hues)."""
    import colorsys

    labels = np.asarray(labels, dtype=np.int64)
    if not len(labels):
        return np.zeros((0, 3), dtype=np.uint8)
    # one conversion per distinct label (a few dozen), not per candidate (hundreds of thousands)
    distinct, inverse = np.unique(labels, return_inverse=True)
    hues = (distinct * 0.618033988749895) % 1.0
    rgb = np.array([colorsys.hsv_to_rgb(h, 0.75, 0.95) for h in hues])
    return (rgb * 255).astype(np.uint8)[inverse.reshape(-1)]


def record_run(
    target: str | os.PathLike[str] | rr.RecordingStream,
    result: GraspSet,
    *,
    sample_points: np.ndarray | None,
    sample_normals: np.ndarray | None,
    extra: dict[str, Any] | None = None,
) -> None:
    """Log one run into `target`: a RecordingStream of the caller's, or a path for a new .rrd (written whole)."""
    rid = uuid.uuid5(
        uuid.NAMESPACE_URL, f"graspgen:{result.object.get('sha256')}:{json.dumps(result.params.to_dict())}"
    )
    write_recording(target, rid, lambda stream: _log(stream, result, sample_points, sample_normals, extra))


def write_recording(
    target: str | os.PathLike[str] | rr.RecordingStream,
    recording_id: uuid.UUID,
    log: Callable[[rr.RecordingStream], None],
) -> None:
    """Run `log` on `target`: a RecordingStream of the caller's, or a path for a new .rrd (a stream of its own,
    never the global one, written whole: a temporary file renamed into place)."""
    import rerun as rr

    if isinstance(target, rr.RecordingStream):
        log(target)
        return
    path = Path(target)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    stream = rr.RecordingStream("graspgen", recording_id=recording_id)
    try:
        stream.save(tmp)
        log(stream)
        stream.flush()
        stream.disconnect()
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


#: validation outcome colours: held, failed
SIM_COLOURS = {True: (40, 180, 70), False: (220, 40, 40)}


def _log_validation(stream: rr.RecordingStream, result: GraspSet) -> None:
    """The simulated outcome per grasp: its gripper boxes green (held) or red (failed, labelled with the reason)."""
    import rerun as rr

    if not any("sim" in g for g in result.grasps):
        return
    if result.gripper.geometry is not None:
        outcomes = [SIM_COLOURS[bool(g["sim"]["success"])] if "sim" in g else None for g in result.grasps]
        _log_gripper_meshes(stream, "grasps/validation", result, outcomes)
        return
    centers, half, quats, colours, names = [], [], [], [], []
    for rank, g in enumerate(result.grasps):
        sim = g.get("sim")
        if sim is None:
            continue
        T = np.asarray(g["pose"])
        q = rr.Quaternion(xyzw=matrix_to_quaternion_xyzw(T))
        label = f"#{rank} " + ("held" if sim["success"] else sim["reason"]) + f" slip {sim['slip_mm']:.2f} mm"
        for box in result.gripper.boxes(g["width"]):
            centers.append(T[:3, :3] @ np.asarray(box.center) + T[:3, 3])
            half.append(np.asarray(box.extents) / 2)
            quats.append(q)
            colours.append(SIM_COLOURS[bool(sim["success"])])
            names.append(label)
    stream.log(
        "grasps/validation",
        rr.Boxes3D(centers=centers, half_sizes=half, quaternions=quats, colors=colours, labels=names),
        static=True,
    )


def _log_coverage(stream: rr.RecordingStream, stats: dict[str, Any]) -> None:
    """Coverage and diversity figures as a small table."""
    import rerun as rr

    cov = stats.get("coverage")
    if not cov:
        return
    lines = ["| radius | axis angle | coverage |", "|---|---|---|"]
    lines += [f"| {lv['radius'] * 100:g} cm | {lv['angle_deg']:g} deg | {lv['share']:.1%} |" for lv in cov["levels"]]
    if cov.get("min_pair_translation") is not None:
        lines.append("")
        lines.append(
            f"closest selected pair: {cov['min_pair_translation'] * 1e3:.1f} mm apart, "
            f"axes {cov['min_pair_angle_deg']:.1f} deg apart, combined {cov['min_pair_combined']:.2f}"
        )
    v = stats.get("validation")
    if v:
        lines.append("")
        lines.append(f"validation: {v['succeeded']}/{v['tested']} held, {v['repaired']} repaired")
    stream.log("stats/coverage", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True)


def log_sample_and_candidates(
    stream: rr.RecordingStream, points: np.ndarray | None, normals: np.ndarray | None, cands: Any, path: str
) -> None:
    """The sampled surface (`points`, `normals` (k, 3), static) and up to MAX_LOGGED_CANDIDATES of the candidates'
    `midpoints` (evenly spread over them) at `path`, coloured by translation cluster: what a run's recording shows
    for either gripper kind (`cands`: Candidates or suction's SuctionCandidates)."""
    import rerun as rr

    if points is not None and len(points):
        stream.log("part/points", rr.Points3D(points, radii=0.0004, colors=[170, 170, 170]), static=True)
        if normals is not None:
            stream.log(
                "part/normals", rr.Arrows3D(origins=points, vectors=normals * 0.003, colors=[90, 140, 220]), static=True
            )
    if len(cands):
        idx = np.arange(len(cands))
        if len(idx) > MAX_LOGGED_CANDIDATES:
            idx = np.linspace(0, len(cands) - 1, MAX_LOGGED_CANDIDATES).astype(np.int64)
        labels = cands.labels[idx, 0]
        stream.log(
            path,
            rr.Points3D(cands.midpoints[idx], radii=0.0003, colors=cluster_colours(labels), class_ids=labels),
            static=True,
        )


def _log(
    stream: rr.RecordingStream,
    result: GraspSet,
    points: np.ndarray | None,
    normals: np.ndarray | None,
    extra: dict[str, Any] | None,
) -> None:
    import rerun as rr

    stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    log_sample_and_candidates(stream, points, normals, result.candidates, "candidates/midpoints")
    if result.gripper.geometry is not None:
        _log_gripper_meshes(
            stream, "grasps/grippers", result, [cluster_colours(np.array([g["cluster"][0]]))[0] for g in result.grasps]
        )
        return
    centers, half, quats, colours, names = [], [], [], [], []
    for rank, g in enumerate(result.grasps):
        T = np.asarray(g["pose"])
        q = matrix_to_quaternion_xyzw(T)
        colour = cluster_colours(np.array([g["cluster"][0]]))[0]
        for box in result.gripper.boxes(g["width"]):
            centers.append(T[:3, :3] @ np.asarray(box.center) + T[:3, 3])
            half.append(np.asarray(box.extents) / 2)
            quats.append(rr.Quaternion(xyzw=q))
            colours.append(colour)
            hold = f" hold x{g['hold_margin']:.2f}" if "hold_margin" in g else ""
            names.append(f"#{rank} c{g['cluster'][0]}.{g['cluster'][1]}{hold}")
    if centers:
        stream.log(
            "grasps/grippers",
            rr.Boxes3D(centers=centers, half_sizes=half, quaternions=quats, colors=colours, labels=names),
            static=True,
        )
        axes_o = np.array([g["contacts"][0] for g in result.grasps])
        axes_v = np.array([np.subtract(g["contacts"][1], g["contacts"][0]) for g in result.grasps])
        stream.log(
            "grasps/closing_axes", rr.Arrows3D(origins=axes_o, vectors=axes_v, colors=[230, 60, 60]), static=True
        )
        _log_validation(stream, result)
    _log_coverage(stream, result.stats)
    summary = {
        "object": result.object,
        "params": result.params.to_dict(friction=result.friction, mass_kg=result.mass_kg),
        "stats": result.stats,
        "grasps": len(result.grasps),
        **(extra or {}),
    }
    stream.log(
        "stats",
        rr.TextDocument("```json\n" + json.dumps(summary, indent=1) + "\n```", media_type=rr.MediaType.MARKDOWN),
        static=True,
    )


def _log_gripper_meshes(
    stream: rr.RecordingStream,
    path: str,
    result: GraspSet,
    colours: Sequence[tuple[int, int, int] | np.ndarray | None],
) -> None:
    """A gripper from CAD at every grasp (colour None: left out) as one Mesh3D of its real finger and body meshes."""
    import rerun as rr

    solids = result.gripper.solids()
    verts, faces, cols = [], [], []
    offset = 0
    for g, colour in zip(result.grasps, colours, strict=True):
        if colour is None:
            continue
        T = np.asarray(g["pose"], dtype=np.float64)
        for m in solids.trimeshes(float(g["width"])):
            v = np.asarray(m.vertices) @ T[:3, :3].T + T[:3, 3]
            verts.append(v)
            faces.append(np.asarray(m.faces) + offset)
            cols.append(np.tile(np.asarray(colour)[:3], (len(v), 1)))
            offset += len(v)
    if verts:
        stream.log(
            path,
            rr.Mesh3D(
                vertex_positions=np.vstack(verts),
                triangle_indices=np.vstack(faces),
                vertex_colors=np.vstack(cols).astype(np.uint8),
            ),
            static=True,
        )
