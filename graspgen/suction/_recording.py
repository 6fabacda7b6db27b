"""Rerun recording (.rrd) of one suction run: the part, the sample, the candidates' contacts by cluster, and the
cup and tool at every exported grasp (graspgen.recording writes the file)."""

from __future__ import annotations

import json
import os
import uuid
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh

from ..recording import cluster_colours, log_sample_and_candidates, write_recording
from ._export import SuctionGraspSet
from ._spec import SuctionSpec

if TYPE_CHECKING:  # pragma: no cover
    import rerun as rr

    from ..parts import Part

__all__ = ["record_suction_run", "cup_meshes"]

_SECTIONS = 32


def cup_meshes(spec: SuctionSpec) -> list[trimesh.Trimesh]:
    """The cup (a cylinder of cup_radius from the lip at z = 0 back to -cup_height) and the tool behind it (its
    cylinder, or its body mesh), in the grasp frame, metres: new meshes."""
    H = spec.cup_height
    cup = trimesh.creation.cylinder(radius=spec.cup_radius, height=H, sections=_SECTIONS)
    cup.apply_translation((0.0, 0.0, -H / 2))
    if spec.tool is not None:
        tool = trimesh.creation.cylinder(radius=spec.tool.radius, height=spec.tool.length, sections=_SECTIONS)
        tool.apply_translation((0.0, 0.0, -H - spec.tool.length / 2))
    else:
        assert spec.geometry is not None  # a spec has a tool or a body
        tool = spec.geometry.body
    return [cup, tool]


def record_suction_run(
    target: str | os.PathLike[str] | rr.RecordingStream,
    result: SuctionGraspSet,
    *,
    part: Part | None,
    sample_points: np.ndarray | None,
    sample_normals: np.ndarray | None,
) -> None:
    """Log one suction run into `target`: a RecordingStream of the caller's, or a path for a new .rrd."""
    rid = uuid.uuid5(
        uuid.NAMESPACE_URL, f"graspgen:{result.object.get('sha256')}:{json.dumps(result.params.to_dict())}:suction"
    )
    write_recording(target, rid, lambda stream: _log(stream, result, part, sample_points, sample_normals))


def _log(
    stream: rr.RecordingStream,
    result: SuctionGraspSet,
    part: Part | None,
    points: np.ndarray | None,
    normals: np.ndarray | None,
) -> None:
    import rerun as rr

    stream.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if part is not None and part.mesh is not None:
        stream.log(
            "part/mesh",
            rr.Mesh3D(
                vertex_positions=np.asarray(part.mesh.vertices),
                triangle_indices=np.asarray(part.mesh.faces),
                albedo_factor=[0.75, 0.75, 0.75, 1.0],
            ),
            static=True,
        )
    log_sample_and_candidates(stream, points, normals, result.candidates, "candidates/contacts")
    verts, faces, cols = [], [], []
    offset = 0
    solids = cup_meshes(result.gripper)
    for g in result.grasps:
        T = np.asarray(g["pose"], dtype=np.float64)
        colour = cluster_colours(np.array([g["cluster"][0]]))[0]
        for m in solids:
            v = np.asarray(m.vertices) @ T[:3, :3].T + T[:3, 3]
            verts.append(v)
            faces.append(np.asarray(m.faces) + offset)
            cols.append(np.tile(colour, (len(v), 1)))
            offset += len(v)
    if verts:
        stream.log(
            "grasps/cups",
            rr.Mesh3D(
                vertex_positions=np.vstack(verts),
                triangle_indices=np.vstack(faces),
                vertex_colors=np.vstack(cols).astype(np.uint8),
            ),
            static=True,
        )
        contacts = np.array([g["contacts"][0] for g in result.grasps])
        approach = np.array([g["approach"] for g in result.grasps])
        stream.log(
            "grasps/approach",
            rr.Arrows3D(origins=contacts - 0.02 * approach, vectors=0.02 * approach, colors=[230, 60, 60]),
            static=True,
        )
    summary: dict[str, Any] = {
        "object": result.object,
        "gripper": result.gripper.to_dict(),
        "params": result.params.to_dict(friction=result.friction, mass_kg=result.mass_kg),
        "stats": result.stats,
        "grasps": len(result.grasps),
    }
    stream.log(
        "stats",
        rr.TextDocument("```json\n" + json.dumps(summary, indent=1) + "\n```", media_type=rr.MediaType.MARKDOWN),
        static=True,
    )
