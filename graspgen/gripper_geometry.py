"""A parallel gripper's fingers and body from CAD meshes (CONTRACT.md, "Gripper geometry from CAD").

A spec's `geometry` names mesh files: `finger` (the +X finger in its finger frame), optional `finger_left` (the -X
finger in its own finger frame; default: the same mesh), optional `body` (everything that does not move with the
fingers, in the grasp frame) and optional `pad` ({width, depth} in metres). `load_geometry` reads and checks them and
returns a `GripperGeometry`: the meshes in metres, immutable, with each file's sha256.

Frames (docs/API.md, "Gripper geometry from CAD", has a picture):
- finger frame: origin at the pad's contact point (the centre of the pad; on a V-groove or a ridge the centre of the
  plane spanning the groove's mouth), the pad's inner face looks along -X, +Z is the approach direction. The finger
  lies at x >= 0. At closing width `w` the +X finger's frame sits at (+w/2, 0, 0) of the grasp frame; the -X finger's
  at (-w/2, 0, 0), turned 180 deg about Z (`finger_pose`).
- body: in the grasp frame itself (it does not move with the fingers).

Checks (each an `InvalidGripperError` with `field` "geometry.<key>" or the name of a file): the keys and units, file
names (relative paths without "..", formats STL/OBJ/PLY/OFF/GLB), every named file given and no other (bytes by
name) or readable (beside the spec), each mesh watertight, consistently wound with outward normals, enclosing a
volume, at most MAX_TRIANGLES triangles, its largest extent between MIN_LENGTH and MAX_LENGTH metres after
conversion; a finger that lies at x >= -FRAME_TOLERANCE with its frame's origin within FRAME_TOLERANCE of the
surface of its convex hull (which, for a V-groove or a ridge, spans the groove's mouth); a given pad no larger than
the finger; given sha256 digests that match the files.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from .errors import GraspgenError, InvalidGripperError
from .parts import MESH_TYPES, load_solid
from .units import UNIT_SCALE

__all__ = [
    "GripperGeometry",
    "BodyGeometry",
    "load_geometry",
    "load_body",
    "BODY_GEOMETRY_KEYS",
    "finger_pose",
    "GEOMETRY_KEYS",
    "MESH_ROLES",
    "FRAME_TOLERANCE",
    "MAX_TRIANGLES",
    "MIN_LENGTH",
    "MAX_LENGTH",
    "file_names",
    "check_file_name",
]

#: the mesh files a geometry may name, in this order
MESH_ROLES = ("finger", "finger_left", "body")
GEOMETRY_KEYS = ("units", *MESH_ROLES, "pad", "sha256")
#: metres: how far the finger may reach below x = 0, and its frame's origin lie off its convex hull's surface
FRAME_TOLERANCE = 1.0e-5
#: triangles per mesh file (CONTRACT.md)
MAX_TRIANGLES = 200_000
#: metres: a finger or body whose largest extent lies outside [MIN_LENGTH, MAX_LENGTH] is in the wrong unit
MIN_LENGTH = 1.0e-3
MAX_LENGTH = 2.0
#: a file name: a relative path of segments that do not start with a dot (so no "..", no hidden files)
_FILE_NAME = re.compile(r"^(?:[A-Za-z0-9_][A-Za-z0-9._-]{0,99}/){0,7}[A-Za-z0-9_][A-Za-z0-9._-]{0,99}$")
_MAX_NAME = 255
_HEX = re.compile(r"^[0-9a-f]{64}$")


@dataclass(frozen=True, eq=False)
class _Mesh:
    """Read-only triangle arrays of one loaded file, metres."""

    vertices: np.ndarray  # (n, 3) float64
    faces: np.ndarray  # (m, 3) int64, outward winding

    @classmethod
    def of(cls, mesh: trimesh.Trimesh) -> _Mesh:
        v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        f = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        v.setflags(write=False)
        f.setflags(write=False)
        return cls(v, f)

    def trimesh(self) -> trimesh.Trimesh:
        # shares the read-only arrays: writing into them raises, apply_transform replaces them on the copy only
        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)


@dataclass(frozen=True, eq=False)
class GripperGeometry:
    """A parallel gripper's finger and body meshes, metres, immutable. Equal when units, file names, digests and the
    given pad are equal (the files' bytes then are).

    - `finger`, `finger_left`: trimesh.Trimesh of the +X and the -X finger, each in its own finger frame (module
      docstring); `finger_left` is the `finger` mesh when the spec names no `finger_left`. `body`: the body in the
      grasp frame, or None. Each access returns a new Trimesh over the same read-only vertex and face arrays: a
      caller's transforms never reach the spec (writing into the arrays raises).
    - `pad_width`, `pad_depth` (m): the contact pad's extent along Y and Z, centred on the finger frame's origin: as
      given, else the extent of the finger's vertices at its minimum x (within FRAME_TOLERANCE) along Y and Z; 0 along
      a direction in which the inner face is a line (a ridge).
    - `files`: role ("finger", "finger_left", "body") -> file name as the spec names it; `sha256`: file name -> hex
      sha256 of its bytes; `units`: the files' unit ("mm", "cm", "m", "in").
    """

    units: str
    files: Mapping[str, str]
    sha256: Mapping[str, str]
    pad_width: float
    pad_depth: float
    #: the pad as the spec gives it ({"width", "depth"}), None when it is the default
    pad_given: tuple[float, float] | None
    _meshes: Mapping[str, _Mesh] = field(repr=False)

    @property
    def finger(self) -> trimesh.Trimesh:
        return self._meshes["finger"].trimesh()

    @property
    def finger_left(self) -> trimesh.Trimesh:
        return self._meshes["finger_left"].trimesh()

    @property
    def body(self) -> trimesh.Trimesh | None:
        m = self._meshes.get("body")
        return m.trimesh() if m is not None else None

    def fingers_at(self, width: float) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
        """The (-X, +X) fingers in the grasp frame at closing width `width` (m): new meshes."""
        left, right = self.finger_left, self.finger
        left.apply_transform(finger_pose(width, -1))
        right.apply_transform(finger_pose(width, +1))
        return left, right

    def to_dict(self) -> dict[str, Any]:
        """The spec's `geometry` as given (units lower-case), with `sha256` {file name: hex} of every file."""
        d: dict[str, Any] = {"units": self.units}
        for role in MESH_ROLES:
            if role in self.files:
                d[role] = self.files[role]
        if self.pad_given is not None:
            d["pad"] = {"width": self.pad_given[0], "depth": self.pad_given[1]}
        d["sha256"] = {name: self.sha256[name] for name in sorted(self.sha256)}
        return d

    def _key(self) -> tuple[object, ...]:
        return (self.units, tuple(sorted(self.files.items())), tuple(sorted(self.sha256.items())), self.pad_given)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, GripperGeometry) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())


#: the keys of a tool's `geometry` (a suction cup's tool: the body behind the cup, graspgen.suction)
BODY_GEOMETRY_KEYS = ("units", "body", "sha256")


@dataclass(frozen=True, eq=False)
class BodyGeometry:
    """One body mesh from CAD in the grasp frame, metres, immutable: a suction tool's everything behind the cup.
    Equal when units, file name and digest are equal.

    - `body`: a new trimesh.Trimesh over the same read-only arrays at each access.
    - `files`: {"body": file name as the spec names it}; `sha256`: file name -> hex sha256 of its bytes.
    """

    units: str
    files: Mapping[str, str]
    sha256: Mapping[str, str]
    _mesh: _Mesh = field(repr=False)

    @property
    def body(self) -> trimesh.Trimesh:
        return self._mesh.trimesh()

    @property
    def vertices(self) -> np.ndarray:
        """(n, 3) float64, metres, read-only."""
        return self._mesh.vertices

    @property
    def faces(self) -> np.ndarray:
        """(m, 3) int64, outward winding, read-only."""
        return self._mesh.faces

    def to_dict(self) -> dict[str, Any]:
        """The spec's `geometry` as given (units lower-case), with `sha256` {file name: hex}."""
        name = self.files["body"]
        return {"units": self.units, "body": name, "sha256": {name: self.sha256[name]}}

    def _key(self) -> tuple[object, ...]:
        return (self.units, tuple(sorted(self.files.items())), tuple(sorted(self.sha256.items())))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, BodyGeometry) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())


def load_body(
    data: Any,
    *,
    files: Mapping[str, bytes] | None = None,
    base_dir: str | Path | None = None,
    max_decoded_bytes: int | None = None,
) -> BodyGeometry:
    """Read and check a `geometry` of one body mesh ({"units", "body", optional "sha256"}): the same file rules and
    mesh checks as a parallel gripper's (module docstring). The file comes as bytes by name (`files`, exactly that
    name) or is read relative to `base_dir`."""
    if not isinstance(data, dict):
        raise InvalidGripperError("geometry must be a JSON object", field="geometry")
    unknown = sorted(set(data) - set(BODY_GEOMETRY_KEYS))
    if unknown:
        raise InvalidGripperError(
            "geometry has unknown fields " + ", ".join(unknown) + " (it takes " + ", ".join(BODY_GEOMETRY_KEYS) + ")",
            field=f"geometry.{unknown[0]}",
        )
    units = _units(data)
    if "body" not in data:
        raise InvalidGripperError("geometry lacks body (the tool's mesh file)", field="geometry.body")
    roles = {"body": check_file_name(data["body"], "geometry.body")}
    loaded = _read_solids(data, roles, files, base_dir, units, max_decoded_bytes)
    mesh, digest = loaded[roles["body"]]
    return BodyGeometry(units=units, files=roles, sha256={roles["body"]: digest}, _mesh=_Mesh.of(mesh))


def finger_pose(width: float, side: int) -> np.ndarray:
    """T_grasp_finger (4, 4): the finger frame of the +X (`side` +1) or -X (`side` -1) finger at closing width
    `width` (m): at (side * width / 2, 0, 0), the -X finger's turned 180 deg about Z."""
    if side not in (1, -1):
        raise ValueError("side is +1 (the +X finger) or -1 (the -X finger)")
    T = np.eye(4)
    T[0, 0] = T[1, 1] = float(side)
    T[0, 3] = side * width / 2.0
    return T


def file_names(geometry: Any) -> list[str]:
    """The distinct file names a spec's `geometry` dict names, in MESH_ROLES order (no checks beyond the types)."""
    if not isinstance(geometry, dict):
        return []
    names = [geometry[r] for r in MESH_ROLES if isinstance(geometry.get(r), str)]
    return list(dict.fromkeys(names))


def check_file_name(name: Any, field: str) -> str:
    """`name` if it is a relative path of plain segments ending in a mesh format's extension, else the error."""
    if not isinstance(name, str) or not name:
        raise InvalidGripperError(f"{field} must be a file name, got {name!r}", field=field)
    if len(name) > _MAX_NAME or not _FILE_NAME.match(name):
        raise InvalidGripperError(
            f"{field} = {name!r} is not a relative file name (segments of letters, digits, '.', '_', '-', not "
            "starting with a dot, separated by '/')",
            field=field,
        )
    ext = name.rsplit(".", 1)[-1].lower() if "." in name else ""
    if ext not in MESH_TYPES:
        raise InvalidGripperError(
            f"{field} = {name!r}: mesh files are " + ", ".join(t.upper() for t in MESH_TYPES) + f", not {ext!r}",
            field=field,
        )
    return name


def load_geometry(
    data: Any,
    *,
    files: Mapping[str, bytes] | None = None,
    base_dir: str | Path | None = None,
    max_decoded_bytes: int | None = None,
) -> GripperGeometry:
    """Read and check a spec's `geometry` (module docstring). The files come as bytes by name (`files`, exactly the
    names the geometry gives) or are read relative to `base_dir`."""
    if not isinstance(data, dict):
        raise InvalidGripperError("geometry must be a JSON object", field="geometry")
    unknown = sorted(set(data) - set(GEOMETRY_KEYS))
    if unknown:
        raise InvalidGripperError(
            "geometry has unknown fields " + ", ".join(unknown) + " (it takes " + ", ".join(GEOMETRY_KEYS) + ")",
            field=f"geometry.{unknown[0]}",
        )
    units = _units(data)
    if "finger" not in data:
        raise InvalidGripperError("geometry lacks finger (the +X finger's mesh file)", field="geometry.finger")
    roles = {r: check_file_name(data[r], f"geometry.{r}") for r in MESH_ROLES if r in data}
    pad = _pad(data.get("pad")) if "pad" in data else None
    loaded = _read_solids(data, roles, files, base_dir, units, max_decoded_bytes)

    finger = loaded[roles["finger"]][0]
    left = loaded[roles.get("finger_left", roles["finger"])][0]
    for role, mesh in (("finger", finger), ("finger_left", left)):
        if role in roles or role == "finger":
            _check_finger_frame(mesh, role, roles.get(role, roles["finger"]), units)
    inner_w, inner_d = _inner_face_extent(finger)
    if pad is not None:
        for name, value, axis in (("width", pad[0], 1), ("depth", pad[1], 2)):
            extent = float(finger.extents[axis])
            if value > extent + FRAME_TOLERANCE:
                raise InvalidGripperError(
                    f"geometry.pad.{name} = {value} m is larger than the finger's extent along {'XYZ'[axis]} "
                    f"({extent:.6g} m)",
                    field=f"geometry.pad.{name}",
                )
        pad_w, pad_d = pad
    else:
        pad_w, pad_d = inner_w, inner_d
    meshes = {"finger": _Mesh.of(finger), "finger_left": _Mesh.of(left)}
    if "body" in roles:
        meshes["body"] = _Mesh.of(loaded[roles["body"]][0])
    return GripperGeometry(
        units=units,
        files=dict(roles),
        sha256={name: digest for name, (_, digest) in loaded.items()},
        pad_width=float(pad_w),
        pad_depth=float(pad_d),
        pad_given=pad,
        _meshes=meshes,
    )


def _units(data: dict[str, Any]) -> str:
    """The geometry's `units`, lower-case, or the error naming the accepted ones."""
    units = data.get("units")
    if not isinstance(units, str) or units.strip().lower() not in UNIT_SCALE:
        raise InvalidGripperError(
            f"geometry.units must be one of {', '.join(UNIT_SCALE)} (the unit of the mesh files), got {units!r}",
            field="geometry.units",
        )
    return units.strip().lower()


def _read_solids(
    data: dict[str, Any],
    roles: dict[str, str],
    files: Mapping[str, bytes] | None,
    base_dir: str | Path | None,
    units: str,
    max_decoded_bytes: int | None,
) -> dict[str, tuple[trimesh.Trimesh, str]]:
    """file name -> (its closed mesh in metres, its sha256) for the files `roles` names (role -> file name), read
    from `files` or beside `base_dir` and checked (load_solid), their digests against a given `data["sha256"]`."""
    names = list(dict.fromkeys(roles.values()))
    given_sha = _given_sha256(data["sha256"], names) if "sha256" in data else None
    blobs = _file_bytes(roles, names, files, base_dir)
    loaded: dict[str, tuple[trimesh.Trimesh, str]] = {}
    for name in names:
        role = next(r for r in MESH_ROLES if roles.get(r) == name)
        what = "a gripper body" if role == "body" else "a gripper finger"
        try:
            loaded[name] = load_solid(
                blobs[name],
                units=units,
                file_type=name.rsplit(".", 1)[-1],
                label=f"{role} file {name!r}",
                what=what,
                max_triangles=MAX_TRIANGLES,
                extent_range=(MIN_LENGTH, MAX_LENGTH),
                **({"max_decoded_bytes": max_decoded_bytes} if max_decoded_bytes else {}),
            )
        except GraspgenError as exc:
            raise InvalidGripperError(exc.message, field=f"geometry.{role}") from None
    if given_sha is not None:
        for name in names:
            digest = loaded[name][1]
            if given_sha[name] != digest:
                raise InvalidGripperError(
                    f"geometry.sha256 gives {given_sha[name][:12]}... for {name!r} but the file's sha256 is "
                    f"{digest[:12]}...: the file is not the one the spec was made with",
                    field="geometry.sha256",
                )
    return loaded


def _pad(value: Any) -> tuple[float, float]:
    if not isinstance(value, dict) or set(value) != {"width", "depth"}:
        raise InvalidGripperError(
            'geometry.pad must be {"width": m, "depth": m} (the contact pad along Y and Z)', field="geometry.pad"
        )
    out = []
    for key in ("width", "depth"):
        v = value[key]
        f = f"geometry.pad.{key}"
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)) or not v > 0:
            raise InvalidGripperError(f"{f} must be a finite number of metres > 0, got {v!r}", field=f)
        if v > MAX_LENGTH:
            raise InvalidGripperError(f"{f} = {v} m is larger than {MAX_LENGTH} m: lengths are in metres", field=f)
        out.append(v)
    return out[0], out[1]


def _given_sha256(value: Any, names: list[str]) -> dict[str, str]:
    if not isinstance(value, dict) or not all(isinstance(v, str) and _HEX.match(v) for v in value.values()):
        raise InvalidGripperError(
            "geometry.sha256 must map each file name to its lower-case hex sha256", field="geometry.sha256"
        )
    if set(value) != set(names):
        raise InvalidGripperError(
            f"geometry.sha256 names {sorted(value)} but the geometry's files are {names}", field="geometry.sha256"
        )
    return dict(value)


def _file_bytes(
    roles: dict[str, str], names: list[str], files: Mapping[str, bytes] | None, base_dir: str | Path | None
) -> dict[str, bytes]:
    role_of = {name: next(r for r in MESH_ROLES if roles.get(r) == name) for name in names}
    if files is not None:
        missing = [n for n in names if n not in files]
        if missing:
            raise InvalidGripperError(
                f"the geometry names {missing[0]!r} ({role_of[missing[0]]}) but no file of that name was given",
                field=f"geometry.{role_of[missing[0]]}",
            )
        extra = sorted(set(files) - set(names))
        if extra:
            raise InvalidGripperError(
                f"file {extra[0]!r} was given but the geometry names no such file (it names {', '.join(names)})",
                field=extra[0],
            )
        return {n: bytes(files[n]) for n in names}
    if base_dir is None:
        raise InvalidGripperError(
            "a spec with geometry needs its mesh files: load it from its file (GripperSpec.load) or give them "
            "(files= by name, or base_dir=)",
            field="geometry",
        )
    out = {}
    for name in names:
        path = Path(base_dir) / name
        try:
            out[name] = path.read_bytes()
        except OSError as exc:
            raise InvalidGripperError(
                f"cannot read the {role_of[name]} file {name!r} (looked for {path}): {exc.strerror or exc}",
                field=f"geometry.{role_of[name]}",
            ) from None
    return out


def _check_finger_frame(mesh: trimesh.Trimesh, role: str, name: str, units: str) -> None:
    """The finger lies at x >= 0 and its frame's origin (the pad's contact point) on its convex hull's surface."""
    f = f"geometry.{role}"
    lo = float(mesh.bounds[0, 0])
    if lo < -FRAME_TOLERANCE:
        raise InvalidGripperError(
            f"the {role} file {name!r} reaches x = {lo * 1e3:.4g} mm: in the finger frame the finger lies at x >= 0 "
            "(its inner face at x = 0 looks along -X, towards the part); move the origin onto the pad",
            field=f,
        )
    hull = mesh.convex_hull
    d = _distance_to_triangles(np.zeros(3), np.asarray(hull.triangles))
    if d > FRAME_TOLERANCE:
        raise InvalidGripperError(
            f"the {role} file {name!r} does not touch its frame's origin ({d * 1e3:.4g} mm away from its hull, whose "
            f"bounds are {_mm(mesh.bounds)} mm): the origin must be the pad's contact point on the inner face (for a "
            "V-groove, on the plane spanning the groove's mouth)",
            field=f,
        )


def _mm(bounds: np.ndarray) -> str:
    return " .. ".join("(" + ", ".join(f"{v * 1e3:.4g}" for v in row) + ")" for row in bounds)


def _inner_face_extent(mesh: trimesh.Trimesh) -> tuple[float, float]:
    """Extent along Y and Z of the vertices at the finger's minimum x (within FRAME_TOLERANCE)."""
    v = np.asarray(mesh.vertices)
    inner = v[v[:, 0] <= v[:, 0].min() + FRAME_TOLERANCE]
    ext = inner.max(axis=0) - inner.min(axis=0)
    return float(ext[1]), float(ext[2])


def _distance_to_triangles(p: np.ndarray, tri: np.ndarray) -> float:
    """Smallest distance from point `p` (3,) to triangles `tri` (m, 3, 3) (Ericson, Real-Time Collision Detection,
    5.1.5, vectorised over the triangles)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp, cp = p - b, p - c
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        closest = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        t_ab = np.clip(np.where(d1 - d3 != 0, d1 / (d1 - d3), 0.0), 0, 1)
        t_ac = np.clip(np.where(d2 - d6 != 0, d2 / (d2 - d6), 0.0), 0, 1)
        t_bc = np.clip(np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) / ((d4 - d3) + (d5 - d6)), 0.0), 0, 1)
    on_ab = a + ab * t_ab[:, None]
    on_ac = a + ac * t_ac[:, None]
    on_bc = b + (c - b) * t_bc[:, None]
    # Ericson's order of the Voronoi regions: vertex a, vertex b, edge ab, vertex c, edge ac, edge bc, else the face
    region = [
        (d1 <= 0) & (d2 <= 0),
        (d3 >= 0) & (d4 <= d3),
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),
        (d6 >= 0) & (d5 <= d6),
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),
        (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
    ]
    choices = [a, b, on_ab, c, on_ac, on_bc]
    out = closest
    for cond, choice in zip(reversed(region), reversed(choices), strict=True):
        out = np.where(cond[:, None], choice, out)
    return float(np.sqrt(((out - p) ** 2).sum(axis=1)).min())
