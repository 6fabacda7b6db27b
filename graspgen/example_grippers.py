"""The shipped CAD example grippers (examples/<name>.json with examples/<name>/*.stl): built here from prisms,
written by scripts/make_example_grippers.py, reproduced byte for byte by tests/graspgen/test_example_grippers.py.

Every solid is one or more closed prisms (a simple polygon extruded along an axis) with outward normals, in
millimetres, the unit real CAD exports use; the specs say `"units": "mm"`. A solid made of several prisms (a stepped
finger, a housing with an adapter plate) is several closed shells that touch without overlapping, so it stays
watertight without a boolean engine. STL files are binary with a fixed header and float32 coordinates that are whole
millimetres, so the bytes do not depend on the platform or on trimesh's version.

- `pgn-80-vgroove`: fingers with a 90 deg V-groove along Z (mouth 16 mm, 8 mm deep) that centres round parts: a
  cylinder of radius r seats on both flanks when 8 / sqrt(2) < r <= 8 sqrt(2) mm (12 to 22 mm diameter); a plain
  housing body.
- `pgn-80-stepped`: fingers with a narrow tip (6 mm wide, 18 mm long along Z) that reaches into pockets, on a root
  24 mm wide set back 2 mm from the pad; the pad is the tip's face.
- `pgn-80-housing`: the contract's box fingers (10 x 20 x 30 mm) under a housing 120 x 60 x 50 mm with an adapter
  plate 90 x 90 x 12 mm: far wider than the palm box.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

__all__ = ["EXAMPLE_GRIPPERS", "example_gripper_files", "write_example_grippers", "prism", "stl_bytes"]

Polygon = Sequence[tuple[float, float]]
Solid = tuple[np.ndarray, np.ndarray]  # vertices (n, 3) float64, faces (m, 3) int64

#: axis index -> the (u, v, w) permutation of (x, y, z) that is right-handed with w the extrusion axis
_AXES = {0: (1, 2, 0), 1: (2, 0, 1), 2: (0, 1, 2)}
_HEADER = b"graspgen example gripper (mm)".ljust(80, b" ")


def prism(polygon: Polygon, lo: float, hi: float, axis: int) -> Solid:
    """A closed prism: the simple counter-clockwise `polygon` in the (u, v) plane extruded from w = lo to w = hi,
    where (u, v, w) is (y, z, x), (z, x, y) or (x, y, z) for `axis` 0, 1 or 2. Outward normals."""
    p = np.asarray(polygon, dtype=np.float64)
    n = len(p)
    if _signed_area(p) <= 0:
        raise ValueError("the polygon must be simple and counter-clockwise")
    uvw = np.zeros((2 * n, 3))
    uvw[:n, :2], uvw[n:, :2] = p, p
    uvw[:n, 2], uvw[n:, 2] = lo, hi
    caps = _ear_clip(p)
    faces = [[c, b, a] for a, b, c in caps]  # bottom, facing -w
    faces += [[a + n, b + n, c + n] for a, b, c in caps]  # top, facing +w
    for i in range(n):
        j = (i + 1) % n
        faces += [[i, j, j + n], [i, j + n, i + n]]  # the side right of the edge i -> j: outside a CCW polygon
    vertices = np.zeros_like(uvw)
    for k, dim in enumerate(_AXES[axis]):
        vertices[:, dim] = uvw[:, k]
    return vertices, np.asarray(faces, dtype=np.int64)


def box(lo: Sequence[float], hi: Sequence[float]) -> Solid:
    """An axis-aligned box from corner `lo` to corner `hi` (x, y, z)."""
    return prism([(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])], lo[2], hi[2], axis=2)


def union_of_shells(*solids: Solid) -> Solid:
    """Closed shells side by side in one mesh (they may touch, never overlap)."""
    vertices, faces, offset = [], [], 0
    for v, f in solids:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def stl_bytes(solid: Solid) -> bytes:
    """Binary STL of `solid`: a fixed 80-byte header, float32 facet normals and vertices."""
    vertices, faces = solid
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    rec = np.zeros(len(faces), dtype=[("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["n"], rec["v"] = normal, tri
    return _HEADER + struct.pack("<I", len(faces)) + rec.tobytes()


def _signed_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _ear_clip(p: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangles (counter-clockwise) of a simple counter-clockwise polygon, by ear clipping (small polygons)."""
    idx = list(range(len(p)))
    out: list[tuple[int, int, int]] = []
    while len(idx) > 3:
        for k in range(len(idx)):
            a, b, c = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            if _cross(p[a], p[b], p[c]) <= 0:
                continue  # a reflex or straight corner is no ear
            if any(_inside(p[m], p[a], p[b], p[c]) for m in idx if m not in (a, b, c)):
                continue
            out.append((a, b, c))
            idx.pop(k)
            break
        else:
            raise ValueError("the polygon is not simple")
    out.append((idx[0], idx[1], idx[2]))
    return out


def _cross(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    return float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def _inside(q: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> bool:
    return _cross(a, b, q) >= 0 and _cross(b, c, q) >= 0 and _cross(c, a, q) >= 0


# -- the examples (millimetres) ---------------------------------------------------------------------------------------
def _spec(name: str, stroke: float, geometry: dict[str, object]) -> dict[str, object]:
    return {
        "name": name,
        "kind": "parallel",
        "stroke": stroke,
        "min_width": 0.0,
        "friction": 0.5,
        "pregrasp_clearance": 0.02,
        "grip_force": 20.0,
        "geometry": {"units": "mm", **geometry},
    }


def _vgroove() -> tuple[dict[str, object], dict[str, bytes]]:
    # cross-section in the XY plane: inner face at x = 0 with the groove's mouth |y| <= 8, apex at x = 8
    section = [(0, -12), (14, -12), (14, 12), (0, 12), (0, 8), (8, 0), (0, -8)]
    finger = prism(section, -15, 15, axis=2)
    body = box((-39, -20, -35), (39, 20, -15))
    name = "pgn-80-vgroove"
    spec = _spec(name, 0.05, {"finger": f"{name}/finger.stl", "body": f"{name}/body.stl"})
    return spec, {f"{name}/finger.stl": stl_bytes(finger), f"{name}/body.stl": stl_bytes(body)}


def _stepped() -> tuple[dict[str, object], dict[str, bytes]]:
    tip = box((0, -3, -9), (8, 3, 9))
    root = box((2, -12, -39), (12, 12, -9))  # set back 2 mm: only the tip's face touches
    finger = union_of_shells(tip, root)
    body = box((-42, -15, -59), (42, 15, -39))
    name = "pgn-80-stepped"
    spec = _spec(name, 0.06, {"finger": f"{name}/finger.stl", "body": f"{name}/body.stl"})
    return spec, {f"{name}/finger.stl": stl_bytes(finger), f"{name}/body.stl": stl_bytes(body)}


def _housing() -> tuple[dict[str, object], dict[str, bytes]]:
    finger = box((0, -10, -15), (10, 10, 15))  # the contract's box finger of examples/pgn-80.json
    housing = box((-60, -30, -65), (60, 30, -15))
    plate = box((-45, -45, -77), (45, 45, -65))
    name = "pgn-80-housing"
    spec = _spec(name, 0.08, {"finger": f"{name}/finger.stl", "body": f"{name}/body.stl"})
    return spec, {
        f"{name}/finger.stl": stl_bytes(finger),
        f"{name}/body.stl": stl_bytes(union_of_shells(housing, plate)),
    }


#: name -> builder of (spec dict, {file name relative to the spec's folder: bytes})
EXAMPLE_GRIPPERS: dict[str, Callable[[], tuple[dict[str, object], dict[str, bytes]]]] = {
    "pgn-80-vgroove": _vgroove,
    "pgn-80-stepped": _stepped,
    "pgn-80-housing": _housing,
}


def example_gripper_files(name: str) -> dict[str, bytes]:
    """Every file of example `name`, relative to the examples folder: `<name>.json` and its meshes."""
    spec, meshes = EXAMPLE_GRIPPERS[name]()
    return {f"{name}.json": (json.dumps(spec, indent=2) + "\n").encode(), **meshes}


def write_example_grippers(out_dir: str | Path) -> list[Path]:
    """Write every example gripper into `out_dir` (the repository's examples/); returns the paths written."""
    out = Path(out_dir)
    written = []
    for name in EXAMPLE_GRIPPERS:
        for rel, data in example_gripper_files(name).items():
            path = out / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
            written.append(path)
    return written
