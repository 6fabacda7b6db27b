"""Loading parts: meshes (STL, OBJ, PLY, OFF, GLB) and point clouds (PLY, NPZ) -> `Part` in metres.

Every input is checked before anything downstream sees it, because trimesh is lenient: it returns an empty
Scene for empty, truncated or misnamed files instead of raising. Each rejection is an `InvalidMeshError` whose
message says what to do about it.

Mesh processing (so that face normals point outwards where that can be known):
- vertices are merged on position alone (YCB OBJs duplicate vertices at UV seams, which opens the surface),
- faces with a repeated vertex are dropped, exact duplicate faces are kept once, and a pair of
  faces over the same three vertices with opposite winding (a zero-thickness double-sided sliver, or the
  shared wall of two touching bodies) is dropped entirely: it encloses no volume,
- a watertight mesh gets `trimesh.repair.fix_normals` and is inverted if its volume is negative. The volume
  test is over the whole mesh, not per body, so that an inner shell (a cavity) keeps its inward-facing normals,
- a mesh that is not watertight keeps its (consistently re-wound) orientation and carries a warning.

Point clouds without normals get normals from PCA over their k nearest neighbours, oriented by propagating a
consistent sign along a minimum spanning tree of the kNN graph (Hoppe et al. 1992, edge weight 1 - |n_i . n_j|),
seeded in every connected component at its point of largest z, whose normal is made to point towards +z (at an
extreme point of a closed surface the outward normal has a non-negative component along that axis).
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numba
import numpy as np
import trimesh
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree
from trimesh.exchange.ply import load_ply

from .errors import InvalidMeshError, InvalidUnitsError
from .limits import MAX_DECODED_BYTES, check_declared, read_npz
from .units import UNIT_SCALE, extents_under_each_unit, to_metres, to_metres_scale

__all__ = [
    "Part",
    "load_part",
    "as_part",
    "load_solid",
    "read_raw_extents",
    "estimate_normals",
    "MESH_TYPES",
    "POINT_CLOUD_TYPES",
    "MAX_EXTENT",
    "MIN_EXTENT",
]

MESH_TYPES = ("stl", "obj", "ply", "off", "glb")
POINT_CLOUD_TYPES = ("ply", "npz")
_FILE_TYPES = tuple(dict.fromkeys(MESH_TYPES + POINT_CLOUD_TYPES))

#: a part whose largest extent (metres) is above this is taken to be in the wrong unit
MAX_EXTENT = 10.0
#: a part whose largest extent (metres) is below this (0.1 mm) is taken to be in the wrong unit
MIN_EXTENT = 1.0e-4
#: a part thinner than this fraction of its largest extent along its thinnest principal axis is flat
_FLAT_RATIO = 1.0e-6
#: a watertight mesh enclosing less than this fraction of its bounding box is degenerate
_MIN_VOLUME_RATIO = 1.0e-9
#: neighbours used for point-cloud normal estimation (including the point itself)
_NORMAL_NEIGHBOURS = 16
_MIN_CLOUD_POINTS = 4
_NOT_WATERTIGHT = "mesh is not watertight: outward normals cannot be guaranteed"


@dataclass(frozen=True, eq=False)
class Part:
    """A rigid part in metres, in its model frame. Arrays are read-only.

    Exactly one of `mesh` (triangle meshes) and `points`/`normals` (point clouds) is set.
    """

    name: str  #: slug-ish name (the file stem by default)
    mesh: trimesh.Trimesh | None  #: metres, model frame; None for point clouds
    points: np.ndarray | None  #: (n, 3) float64 metres, point clouds only
    normals: np.ndarray | None  #: (n, 3) float64 unit, outward, point clouds only
    source_units: str  #: 'mm' | 'cm' | 'm' | 'in'
    sha256: str  #: hex sha256 of the input file bytes (in-memory meshes: of their binary STL export)
    watertight: bool
    extents: tuple[float, float, float]  #: axis-aligned bounding box, metres
    warnings: tuple[str, ...]

    @property
    def is_point_cloud(self) -> bool:
        return self.mesh is None

    def surface_mesh(self) -> trimesh.Trimesh:
        """The part's surface as triangles (metres): its mesh, or for a point cloud, which has no surface of its
        own, the convex hull of its points (what previews draw and the validation simulates)."""
        if self.mesh is not None:
            return self.mesh
        assert self.points is not None  # a part is a mesh or a point cloud
        hull: trimesh.Trimesh = trimesh.convex.convex_hull(self.points)
        return hull


@dataclass(frozen=True)
class _Raw:
    """What a file holds, in file units, before any checks."""

    label: str  # how to name the input in messages
    stem: str
    sha256: str
    vertices: np.ndarray  # (n, 3) float64
    faces: np.ndarray | None  # (m, 3) int64, None for point clouds
    normals: np.ndarray | None  # point clouds only


def load_part(
    source: str | os.PathLike[str] | trimesh.Trimesh | bytes,
    *,
    units: str,
    name: str | None = None,
    file_type: str | None = None,
    max_decoded_bytes: int = MAX_DECODED_BYTES,
) -> Part:
    """Load a mesh or point cloud given in `units` and return it as a checked `Part` in metres.

    `source` is a path, an in-memory `trimesh.Trimesh`, or the bytes of a file (then `file_type` is required:
    one of stl, obj, ply, off, glb, npz). Raises `InvalidUnitsError` for missing/unknown units and
    `InvalidMeshError` for anything wrong with the geometry, and for a file that declares more than
    `max_decoded_bytes` of decoded arrays (checked before anything is inflated: `graspgen.limits`).
    """
    scale = to_metres_scale(units)
    source_units = str(units).strip().lower()
    raw = _read_raw(source, file_type=file_type, max_decoded_bytes=max_decoded_bytes)
    _check_finite(raw)
    _check_plausible_size(raw, scale, source_units)
    part_name = name if name is not None else _slug(raw.stem)
    if raw.faces is None:
        return _point_cloud_part(raw, scale, part_name, source_units)
    return _mesh_part(raw, scale, part_name, source_units)


def as_part(source: Part | str | os.PathLike[str] | trimesh.Trimesh, *, units: str | None, name: str | None) -> Part:
    """`source` as it is when it is a Part already, else loaded by load_part in `units` (required then:
    InvalidUnitsError without them), named `name`: how generate() takes its part, for either gripper kind."""
    if isinstance(source, Part):
        return source
    if units is None:
        raise InvalidUnitsError("units are required (mm, cm, m or in)", field="units")
    return load_part(source, units=units, name=name)


def load_solid(
    source: str | os.PathLike[str] | bytes,
    *,
    units: str,
    file_type: str | None = None,
    label: str | None = None,
    what: str = "a solid",
    max_triangles: int | None = None,
    extent_range: tuple[float, float] = (MIN_EXTENT, MAX_EXTENT),
    max_decoded_bytes: int = MAX_DECODED_BYTES,
) -> tuple[trimesh.Trimesh, str]:
    """A closed solid (a gripper's finger or body) from a mesh file in `units`: (mesh in metres, hex sha256 of the
    file's bytes).

    Stricter than `load_part`, which repairs what it can: the mesh must be watertight, consistently wound with
    outward normals (positive volume: an inside-out mesh is refused, not inverted) and enclose a volume. Vertices are
    merged and faces cleaned as for parts (module docstring). `source` is a path or the file's bytes (then
    `file_type` is required); only mesh formats (MESH_TYPES) are read. `label` names the input in messages;
    `max_triangles` bounds the triangles in the file (a binary STL's header is checked before anything is decoded);
    `extent_range` bounds the largest extent in metres, `what` names the solid in that message. Raises
    `InvalidUnitsError` for bad units, `InvalidMeshError` (field "file" or "units") for anything else.
    """
    to_metres_scale(units)
    source_units = str(units).strip().lower()
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        label = label or str(path)
        if file_type is None:
            file_type = path.suffix
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise InvalidMeshError(f"cannot read {label}: {exc.strerror or exc}", field="file") from exc
    elif isinstance(source, (bytes, bytearray, memoryview)):
        data = bytes(source)
    else:
        raise InvalidMeshError(f"cannot load a solid from a {type(source).__name__}: pass a path or bytes")
    label = label or "the uploaded file"
    ft = str(file_type or "").strip().lower().lstrip(".")
    if ft not in MESH_TYPES:
        raise InvalidMeshError(
            f"{label}: unsupported mesh format {ft or 'without extension'!r}; supported are " + ", ".join(MESH_TYPES),
            field="file_type",
        )
    if max_triangles is not None and ft == "stl" and len(data) >= 84:
        (count,) = struct.unpack_from("<I", data, 80)
        if 84 + 50 * count == len(data) and count > max_triangles:
            raise InvalidMeshError(_too_many(label, count, max_triangles), field="file")
    raw = _read_raw(data, file_type=ft, max_decoded_bytes=max_decoded_bytes, label=label)
    if raw.faces is None:
        raise InvalidMeshError(f"{label} holds points only, no triangles: send a closed mesh", field="file")
    if max_triangles is not None and len(raw.faces) > max_triangles:
        raise InvalidMeshError(_too_many(label, len(raw.faces), max_triangles), field="file")
    _check_finite(raw)
    _check_plausible_size(raw, to_metres_scale(units), source_units, what=what, extent_range=extent_range)
    mesh = _clean_mesh(raw, source_units)
    if not mesh.is_watertight:
        open_edges = len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1))
        raise InvalidMeshError(
            f"{label} is not watertight ({open_edges} edges bound a single face, or more than two faces share an "
            "edge): export it as one closed solid",
            field="file",
        )
    if not mesh.is_winding_consistent:
        raise InvalidMeshError(
            f"{label} has faces wound against their neighbours: its outside cannot be told; repair its normals and "
            "export it again",
            field="file",
        )
    if abs(mesh.volume) <= _MIN_VOLUME_RATIO * float(np.prod(mesh.extents)):
        _check_volume(mesh, label)  # closed but enclosing nothing (or as much inside out as not)
    if mesh.volume < 0.0:
        raise InvalidMeshError(
            f"{label} is inside out: its normals point inwards (volume {mesh.volume:.3g} m^3); flip its faces and "
            "export it again",
            field="file",
        )
    return mesh, raw.sha256


def _too_many(label: str, count: int, limit: int) -> str:
    return f"{label} has {count:,} triangles, more than the limit of {limit:,}: decimate it"


def read_raw_extents(
    path: str | os.PathLike[str] | bytes, *, file_type: str | None = None, max_decoded_bytes: int = MAX_DECODED_BYTES
) -> np.ndarray:
    """Axis-aligned extents (3,) float64 in the file's own units, for the CLI's "which unit?" message.

    Raises `InvalidMeshError` when the file cannot be read or holds no usable geometry.
    """
    raw = _read_raw(path, file_type=file_type, max_decoded_bytes=max_decoded_bytes)
    _check_finite(raw)
    return _extents(_used_vertices(raw))


# ----------------------------------------------------------------------------------------------- reading


def _read_raw(
    source: str | os.PathLike[str] | trimesh.Trimesh | bytes,
    *,
    file_type: str | None,
    max_decoded_bytes: int,
    label: str | None = None,
) -> _Raw:
    if isinstance(source, trimesh.Trimesh):
        data = trimesh.exchange.stl.export_stl(source)
        vertices = np.array(source.vertices, dtype=np.float64)
        faces = np.array(source.faces, dtype=np.int64).reshape(-1, 3)
        label = "the in-memory mesh"
        if len(faces) == 0:
            raise InvalidMeshError(f"{label} has no triangles")
        return _Raw(label, "part", hashlib.sha256(data).hexdigest(), vertices, faces, None)
    if isinstance(source, (bytes, bytearray, memoryview)):
        data = bytes(source)
        if file_type is None:
            raise InvalidMeshError(
                "file_type is required for uploaded bytes: one of " + ", ".join(_FILE_TYPES), field="file_type"
            )
        label, stem = label or "the uploaded file", "part"
    elif isinstance(source, (str, os.PathLike)):
        path = Path(source)
        label, stem = label or str(path), path.stem
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise InvalidMeshError(f"cannot read {label}: {exc.strerror or exc}", field="file") from exc
        if file_type is None:
            file_type = path.suffix
            if not file_type:
                raise InvalidMeshError(
                    f"{label} has no file extension: name it .stl, .obj, .ply, .off, .glb or .npz", field="file"
                )
    else:
        raise InvalidMeshError(f"cannot load a part from a {type(source).__name__}: pass a path, bytes or a Trimesh")

    ft = _normalise_type(file_type, label)
    sha = hashlib.sha256(data).hexdigest()
    if not data:
        raise InvalidMeshError(f"{label} is empty (0 bytes): upload or export the file again", field="file")
    # declared sizes first: nothing is inflated or allocated for a file that declares more than the limit
    check_declared(data, ft, label, max_decoded_bytes)
    if ft == "npz":
        vertices, normals = _read_npz(data, label, max_decoded_bytes)
        return _Raw(label, stem, sha, vertices, None, normals)
    if ft == "ply":
        return _read_ply(data, label, stem, sha)
    vertices, faces = _read_mesh(data, ft, label)
    return _Raw(label, stem, sha, vertices, faces, None)


def _normalise_type(file_type: str, label: str) -> str:
    ft = str(file_type).strip().lower().lstrip(".")
    if ft not in _FILE_TYPES:
        raise InvalidMeshError(
            f"{label}: unsupported file type {ft!r}; supported are " + ", ".join(_FILE_TYPES), field="file_type"
        )
    return ft


def _read_mesh(data: bytes, ft: str, label: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        # materials (textures: PNG/JPEG that PIL would decode) are never used, so never decoded
        extra: dict[str, Any] = {"skip_materials": True} if ft == "glb" else {}
        loaded = trimesh.load(io.BytesIO(data), file_type=ft, process=False, **extra)
    except ImportError:
        raise  # a broken installation is our problem, not the user's
    except IndexError as exc:  # trimesh's OBJ/OFF readers index the vertices with the faces as given
        if _sniff(data) in (None, ft):
            raise InvalidMeshError(
                f"{label} has faces that refer to missing vertices: re-export it", field="file"
            ) from exc
        raise InvalidMeshError(_unreadable(data, ft, label, f"{type(exc).__name__}: {exc}"), field="file") from exc
    except Exception as exc:  # trimesh's parsers raise anything from ValueError to struct.error
        raise InvalidMeshError(_unreadable(data, ft, label, f"{type(exc).__name__}: {exc}"), field="file") from exc
    if isinstance(loaded, trimesh.Scene):
        meshes = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not meshes:
            raise InvalidMeshError(_unreadable(data, ft, label), field="file")
        vertices, faces = _concatenate(meshes)
    elif isinstance(loaded, trimesh.Trimesh):
        vertices = np.asarray(loaded.vertices, dtype=np.float64)
        faces = np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3)
    elif isinstance(loaded, trimesh.PointCloud):
        raise InvalidMeshError(
            f"{label} holds only vertices, no triangles: send point clouds as PLY (with nx, ny, nz) or NPZ",
            field="file",
        )
    else:
        raise InvalidMeshError(f"{label} holds no triangle mesh ({type(loaded).__name__})", field="file")
    if len(faces) == 0:
        raise InvalidMeshError(_unreadable(data, ft, label), field="file")
    return vertices, faces


def _concatenate(meshes: list[trimesh.Trimesh]) -> tuple[np.ndarray, np.ndarray]:
    vertices, faces, offset = [], [], 0
    for m in meshes:
        vertices.append(np.asarray(m.vertices, dtype=np.float64))
        faces.append(np.asarray(m.faces, dtype=np.int64) + offset)
        offset += len(m.vertices)
    return np.concatenate(vertices), np.concatenate(faces)


def _read_ply(data: bytes, label: str, stem: str, sha: str) -> _Raw:
    try:
        kw = load_ply(io.BytesIO(data))
    except ImportError:
        raise
    except Exception as exc:
        raise InvalidMeshError(_unreadable(data, "ply", label, f"{type(exc).__name__}: {exc}"), field="file") from exc
    vertices = np.asarray(kw.get("vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    faces = kw.get("faces")
    if faces is not None and len(faces):
        faces = np.asarray(faces, dtype=np.int64)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise InvalidMeshError(f"{label}: faces must be triangles", field="file")
        return _Raw(label, stem, sha, vertices, faces, None)
    if len(vertices) == 0:
        raise InvalidMeshError(_unreadable(data, "ply", label), field="file")
    normals = kw.get("vertex_normals")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    return _Raw(label, stem, sha, vertices, None, normals)


def _read_npz(data: bytes, label: str, max_decoded_bytes: int) -> tuple[np.ndarray, np.ndarray | None]:
    arrays = read_npz(data, label, max_decoded_bytes)  # bounded: never inflates more than a member declares
    points = arrays["points"]
    if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] == 0 or not np.issubdtype(points.dtype, np.number):
        raise InvalidMeshError(f"{label}: 'points' must be a non-empty (n, 3) numeric array, got {points.shape}")
    normals = arrays.get("normals")
    if normals is not None:
        if normals.shape != points.shape or not np.issubdtype(normals.dtype, np.number):
            raise InvalidMeshError(
                f"{label}: 'normals' must have the shape of 'points' {points.shape}, got {normals.shape}"
            )
        normals = normals.astype(np.float64)
    return points.astype(np.float64), normals


def _unreadable(data: bytes, ft: str, label: str, detail: str | None = None) -> str:
    """Why no triangles came out of `data`, as specifically as the bytes allow."""
    sniffed = _sniff(data)
    if sniffed in _NOT_MESHES:
        return f"{label} is {_NOT_MESHES[sniffed]}, not a 3D model: export the part itself as " + ", ".join(MESH_TYPES)
    if sniffed == "stl-binary":
        (declared,) = struct.unpack_from("<I", data, 80)
        expected = 84 + 50 * declared
        if len(data) == expected and ft != "stl":
            return f"{label} is a binary STL but is named .{ft}: rename it to .stl (or send file_type 'stl')"
        if len(data) < expected:
            return (
                f"{label} is truncated: its STL header declares {declared} triangles ({expected} bytes) but the file "
                f"has only {len(data)} bytes; export or upload it again"
            )
    elif sniffed is not None and sniffed != ft:
        return f"{label} looks like a {sniffed.upper()} file but is named .{ft}: rename it to .{sniffed}"
    msg = (
        f"no triangles could be read from {label}: the file is empty, truncated, or its extension (.{ft}) "
        "does not match its content"
    )
    return f"{msg} ({detail})" if detail else msg


#: files people upload instead of the model (a screenshot, a drawing): recognised by their magic bytes
_OTHER_MAGIC = (
    (b"\x89PNG\r\n\x1a\n", "png"),
    (b"\xff\xd8\xff", "jpeg"),
    (b"GIF87a", "gif"),
    (b"GIF89a", "gif"),
    (b"%PDF-", "pdf"),
)
_NOT_MESHES = {"png": "a PNG image", "jpeg": "a JPEG image", "gif": "a GIF image", "pdf": "a PDF document"}


def _sniff(data: bytes) -> str | None:
    """The format the bytes look like ('stl-binary' for binary STL), or None."""
    for magic, kind in _OTHER_MAGIC:
        if data.startswith(magic):
            return kind
    head = data[:512].lstrip()
    for magic, kind in ((b"glTF", "glb"), (b"ply", "ply"), (b"PK", "npz"), (b"OFF", "off"), (b"COFF", "off")):
        if head.startswith(magic):
            return kind
    body = data[84:4180]
    if len(data) >= 84 and body and sum(b < 9 or 13 < b < 32 or b > 126 for b in body) > 0.1 * len(body):
        return "stl-binary"  # binary after an 80-byte header and a triangle count
    if head.startswith(b"solid") and b"facet" in data[:4096]:
        return "stl"
    if re.search(rb"^v\s+[-+0-9.]", data[:65536], re.MULTILINE):
        return "obj"
    return None


# ----------------------------------------------------------------------------------------------- checks


def _check_finite(raw: _Raw) -> None:
    bad = ~np.isfinite(raw.vertices).all(axis=1)
    if bad.any():
        raise InvalidMeshError(
            f"{raw.label} has {int(bad.sum())} vertices with NaN or infinite coordinates: repair or re-export it",
            field="file",
        )
    if raw.faces is not None and (raw.faces.min() < 0 or raw.faces.max() >= len(raw.vertices)):
        raise InvalidMeshError(f"{raw.label} has faces that refer to missing vertices: re-export it", field="file")
    if raw.normals is not None and not np.isfinite(raw.normals).all():
        raise InvalidMeshError(f"{raw.label} has normals with NaN or infinite components", field="file")


def _used_vertices(raw: _Raw) -> np.ndarray:
    if raw.faces is None:
        return raw.vertices
    used: np.ndarray = raw.vertices[np.unique(raw.faces)]
    return used


def _extents(vertices: np.ndarray) -> np.ndarray:
    if len(vertices) == 0:
        return np.zeros(3)
    extents: np.ndarray = vertices.max(axis=0) - vertices.min(axis=0)
    return extents


def _check_plausible_size(
    raw: _Raw,
    scale: float,
    units: str,
    *,
    what: str = "a part",
    extent_range: tuple[float, float] = (MIN_EXTENT, MAX_EXTENT),
) -> None:
    lo, hi = extent_range
    extents_raw = _extents(_used_vertices(raw))
    largest = float(extents_raw.max()) * scale
    if largest <= 0.0:
        raise InvalidMeshError(f"{raw.label} is degenerate: all its points coincide", field="file")
    if lo <= largest <= hi:
        return
    plausible = [u for u, s in UNIT_SCALE.items() if lo <= extents_raw.max() * s <= hi]
    size = " x ".join(f"{v * scale:.4g}" for v in extents_raw)
    hint = f"it would be plausible in {', '.join(plausible)}" if plausible else "no unit makes it plausible"
    raise InvalidMeshError(
        f"{raw.label} measures {size} m when read in {units}, which is implausible for {what} (the largest extent "
        f"must be between {lo * 1e3:g} mm and {hi:g} m); {hint}. "
        f"Extents under each unit: {extents_under_each_unit(extents_raw)}",
        field="units",
    )


def _check_not_flat(vertices: np.ndarray, label: str) -> None:
    """Reject parts whose points lie on a plane or a line (in any orientation, not just axis-aligned)."""
    centred = vertices - vertices.mean(axis=0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    along = centred @ vt.T
    thickness = along.max(axis=0) - along.min(axis=0)
    if thickness.min() <= _FLAT_RATIO * thickness.max():
        raise InvalidMeshError(
            f"{label} is flat (all its points lie in one plane, thickness {thickness.min():.3g} m): "
            "a parallel-jaw grasp needs a solid part",
            field="file",
        )


# ----------------------------------------------------------------------------------------------- meshes


def _mesh_part(raw: _Raw, scale: float, name: str, units: str) -> Part:
    mesh = _clean_mesh(raw, units)
    warnings: list[str] = []
    watertight = bool(mesh.is_watertight)
    if watertight:
        trimesh.repair.fix_normals(mesh, multibody=False)
        if mesh.volume < 0.0:
            mesh.invert()
        _check_volume(mesh, raw.label)
    else:
        trimesh.repair.fix_winding(mesh)
        warnings.append(_NOT_WATERTIGHT)
    extents = cast(tuple[float, float, float], tuple(float(v) for v in mesh.extents))
    return Part(name, mesh, None, None, units, raw.sha256, watertight, extents, tuple(warnings))


def _check_volume(mesh: trimesh.Trimesh, label: str) -> None:
    box = float(np.prod(mesh.extents))
    if not mesh.volume > _MIN_VOLUME_RATIO * box:
        raise InvalidMeshError(
            f"{label} is closed but encloses no volume ({mesh.volume:.3g} m^3): it is degenerate", field="file"
        )


def _clean_mesh(raw: _Raw, units: str) -> trimesh.Trimesh:
    """The raw triangles in metres, vertices merged on position and faces cleaned (module docstring); refuses a mesh
    without area or a flat one. Winding as given."""
    vertices = to_metres(raw.vertices, units)
    mesh = trimesh.Trimesh(vertices, raw.faces, process=False, validate=False)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    faces = _clean_faces(np.asarray(mesh.faces, dtype=np.int64))
    if len(faces) == 0:
        raise InvalidMeshError(f"{raw.label} has no triangles with a non-zero area", field="file")
    # zero-area slivers with three distinct vertices stay: dropping them would open a closed surface, and
    # area-weighted sampling never picks them
    mesh = trimesh.Trimesh(np.asarray(mesh.vertices), faces, process=False, validate=False)
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0 or mesh.area <= 0.0:
        raise InvalidMeshError(f"{raw.label} has no triangles with a non-zero area", field="file")
    _check_not_flat(np.asarray(mesh.vertices), raw.label)
    return mesh


def _clean_faces(faces: np.ndarray) -> np.ndarray:
    """Drop faces with a repeated vertex, keep exact duplicates once, drop opposite-wound pairs entirely."""
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    if len(faces) == 0:
        return faces
    # canonical rotation (smallest index first) keeps winding: equal rows = same face, same orientation
    roll = np.argmin(faces, axis=1)
    idx = (roll[:, None] + np.arange(3)[None, :]) % 3
    canon = np.take_along_axis(faces, idx, axis=1)
    _, first = np.unique(canon, axis=0, return_index=True)
    first.sort()
    faces, canon = faces[first], canon[first]
    # the same vertex set wound the other way: (a, b, c) vs (a, c, b) -> both enclose nothing together
    key = np.sort(canon, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    kept: np.ndarray = faces[counts[inverse.ravel()] == 1]
    return kept


# ----------------------------------------------------------------------------------------------- point clouds


def _point_cloud_part(raw: _Raw, scale: float, name: str, units: str) -> Part:
    points = to_metres(raw.vertices, units)
    normals = raw.normals
    # exact duplicates carry no information and break neighbourhoods and spacing; keep first occurrences
    _, first = np.unique(points, axis=0, return_index=True)
    first.sort()
    points = points[first]
    if normals is not None:
        normals = normals[first]
    if len(points) < _MIN_CLOUD_POINTS:
        raise InvalidMeshError(
            f"{raw.label} has only {len(points)} distinct points: a point cloud needs at least {_MIN_CLOUD_POINTS}",
            field="file",
        )
    _check_not_flat(points, raw.label)
    warnings: list[str] = []
    if normals is not None:
        length = np.linalg.norm(normals, axis=1)
        if (length < 1e-12).any():
            raise InvalidMeshError(
                f"{raw.label} has {int((length < 1e-12).sum())} zero-length normals: fix them or leave normals out "
                "to have them estimated",
                field="file",
            )
        normals = normals / length[:, None]
    else:
        normals = estimate_normals(points)
        warnings.append(
            "point cloud has no normals: estimated by PCA over nearest neighbours and oriented outwards by "
            "propagation from the topmost point; check them if the cloud is open or noisy"
        )
    points = np.ascontiguousarray(points, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    points.setflags(write=False)
    normals.setflags(write=False)
    extents = cast(tuple[float, float, float], tuple(float(v) for v in _extents(points)))
    return Part(name, None, points, normals, units, raw.sha256, False, extents, tuple(warnings))


def estimate_normals(points: np.ndarray, *, k: int = _NORMAL_NEIGHBOURS) -> np.ndarray:
    """Unit normals (n, 3) for a point cloud (n, 3): kNN PCA, signs made consistent along an MST, outward at top."""
    n = len(points)
    k = min(k, n)
    tree = cKDTree(points)
    # scipy-stubs type query's result as scalars or arrays; with points (n, 3) it is arrays
    dist, nbr = cast(tuple[np.ndarray, np.ndarray], tree.query(points, k=k))
    normals = np.empty_like(points)
    chunk = 65536
    for start in range(0, n, chunk):
        sel = nbr[start : start + chunk]
        local = points[sel] - points[sel].mean(axis=1, keepdims=True)
        cov = np.einsum("nki,nkj->nij", local, local)
        _, vecs = np.linalg.eigh(cov)
        normals[start : start + chunk] = vecs[:, :, 0]  # eigenvector of the smallest eigenvalue
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    _orient_normals(points, normals, nbr)
    return normals


def _orient_normals(points: np.ndarray, normals: np.ndarray, nbr: np.ndarray) -> None:
    n, k = nbr.shape
    rows = np.repeat(np.arange(n), k)
    cols = nbr.ravel()
    off = rows != cols
    rows, cols = rows[off], cols[off]
    lo, hi = np.minimum(rows, cols), np.maximum(rows, cols)
    pairs = np.unique(np.stack([lo, hi], axis=1), axis=0)
    lo, hi = pairs[:, 0], pairs[:, 1]
    # small positive floor: csgraph treats explicit zeros as missing edges
    weight = 1.0 - np.abs(np.einsum("ij,ij->i", normals[lo], normals[hi])) + 1e-6
    graph = sparse.coo_matrix((weight, (lo, hi)), shape=(n, n)).tocsr()
    tree = csgraph.minimum_spanning_tree(graph)
    tree = (tree + tree.T).tocsr()
    n_comp, labels = csgraph.connected_components(tree, directed=False)
    for comp in range(n_comp):
        members = np.flatnonzero(labels == comp)
        seed = int(members[np.argmax(points[members, 2])])
        if normals[seed, 2] < 0.0:
            normals[seed] *= -1.0
        order, pred = csgraph.breadth_first_order(tree, seed, directed=False, return_predecessors=True)
        _propagate_signs(normals, order.astype(np.int64), pred.astype(np.int64))


@numba.njit(cache=True)
def _propagate_signs(normals: np.ndarray, order: np.ndarray, pred: np.ndarray) -> None:
    for t in range(1, order.shape[0]):
        v = order[t]
        p = pred[v]
        d = normals[v, 0] * normals[p, 0] + normals[v, 1] * normals[p, 1] + normals[v, 2] * normals[p, 2]
        if d < 0.0:
            normals[v, 0] = -normals[v, 0]
            normals[v, 1] = -normals[v, 1]
            normals[v, 2] = -normals[v, 2]


def _slug(stem: str) -> str:
    s = re.sub(r"[^a-z0-9._-]+", "-", stem.strip().lower()).strip("-._")
    return s[:63] or "part"
