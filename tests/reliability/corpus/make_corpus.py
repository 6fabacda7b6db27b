"""Writes the bad-input corpus (tests/reliability/corpus) and its index.json; run it again after changing CASES.

    .venv/bin/python tests/reliability/corpus/make_corpus.py

Every entry is one test of the CLI (`graspgen generate`, tests/reliability/test_bad_input_cli.py) and one of the
API (POST /v1/objects, /v1/grippers, /v1/jobs; tests/reliability/test_bad_input_api.py): both iterate index.json,
so the two interfaces are held to the same list. An entry says what must happen:

- `expect`: "reject" (CLI exit 2 with one line on stderr, API 4xx problem+json, nothing stored) or "warn"
  (accepted, with a warning that contains every `says` string),
- `code`: the API problem `code`,
- `says`: substrings (case-insensitive) that the CLI's line and the API's `detail` must both contain: the reason
  has to name the problem, not only fail,
- `units`: the unit the mesh is declared in (`null`: not given at all),
- `api_code` / `api_says`: where the API's words differ from the CLI's (the API validates the body's JSON type
  before graspgen sees it).

The files are small and deterministic (fixed vertices, no randomness), so regenerating gives the same bytes.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent

#: a valid gripper (CONTRACT.md example); the gripper cases change one thing each
GRIPPER: dict[str, Any] = {
    "name": "pgn-80",
    "stroke": 0.08,
    "min_width": 0.0,
    "finger_width": 0.02,
    "finger_depth": 0.03,
    "finger_thickness": 0.01,
    "palm_depth": 0.02,
    "friction": 0.5,
    "pregrasp_clearance": 0.02,
}


# -- mesh bytes -------------------------------------------------------------------------------------------------------
def _box(ex: float, ey: float, ez: float) -> tuple[list[tuple[float, float, float]], list[tuple[int, int, int]]]:
    """A closed axis-aligned box centred on the origin, outward winding (1-based faces are made by the writers)."""
    hx, hy, hz = ex / 2, ey / 2, ez / 2
    v = [(sx * hx, sy * hy, sz * hz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    f = [
        (0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5),  # -x, +x
        (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),  # -y, +y
        (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3),  # -z, +z
    ]  # fmt: skip
    return v, f


def binary_stl(vertices, faces) -> bytes:  # type: ignore[no-untyped-def]
    out = io.BytesIO()
    out.write(b"graspgen reliability corpus".ljust(80, b" "))
    out.write(struct.pack("<I", len(faces)))
    for a, b, c in faces:
        out.write(struct.pack("<3f", 0.0, 0.0, 0.0))
        for i in (a, b, c):
            out.write(struct.pack("<3f", *vertices[i]))
        out.write(b"\0\0")
    return out.getvalue()


def obj_text(vertices, faces) -> bytes:  # type: ignore[no-untyped-def]
    lines = ["# graspgen reliability corpus"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return ("\n".join(lines) + "\n").encode()


def ascii_stl(vertices, faces) -> bytes:  # type: ignore[no-untyped-def]
    lines = ["solid corpus"]
    for a, b, c in faces:
        lines += ["  facet normal 0 0 0", "    outer loop"]
        lines += [f"      vertex {vertices[i][0]} {vertices[i][1]} {vertices[i][2]}" for i in (a, b, c)]
        lines += ["    endloop", "  endfacet"]
    lines.append("endsolid corpus")
    return ("\n".join(lines) + "\n").encode()


def png_bytes() -> bytes:
    """A valid 8 x 8 grey PNG (what a user sends when they pick the preview instead of the model)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.new("L", (8, 8), 128).save(buf, format="PNG")
    return buf.getvalue()


# -- hostile files (issue 16): they declare far more than they hold, or inflate far beyond their size ---------------
def npy_header(shape: tuple[int, ...], dtype: str = "<f8") -> bytes:
    """A version 1.0 .npy header (magic, length, dict padded to a multiple of 64 bytes)."""
    d = repr({"descr": dtype, "fortran_order": False, "shape": tuple(shape)}).encode()
    pad = 64 - (10 + len(d) + 1) % 64
    body = d + b" " * pad + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(body)) + body


def _zip_one(name: str, payload_deflated: bytes, size: int, crc: int) -> bytes:
    """A zip archive of one deflated member, written by hand so that its declared size can be anything."""
    fname = name.encode()
    csize = len(payload_deflated)
    extra, ver = b"", 20
    if size >= 0xFFFFFFFF:  # zip64: the sizes move to an extra field
        extra, ver, size32, csize32 = struct.pack("<HHQQ", 1, 16, size, csize), 45, 0xFFFFFFFF, 0xFFFFFFFF
    else:
        size32, csize32 = size, csize
    local = struct.pack("<IHHHHHIIIHH", 0x04034B50, ver, 0, 8, 0, 0, crc, csize32, size32, len(fname), len(extra))
    central = struct.pack(
        "<IHHHHHHIIIHHHHHII", 0x02014B50, ver, ver, 0, 8, 0, 0, crc, csize32, size32, len(fname), len(extra), 0, 0,
        0, 0, 0,
    )  # fmt: skip
    cd = central + fname + extra
    offset = len(local) + len(fname) + len(extra) + csize
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, 1, 1, len(cd), offset, 0)
    return local + fname + extra + payload_deflated + cd + end


def npz_zero_bomb(inflated: int, *, crc: bool = True) -> bytes:
    """An NPZ whose `points` member (float64 zeros, (inflated // 24, 3)) deflates about 1000:1: 1 GiB in ~1 MB.

    The zeros are one deflate block of 1 MiB repeated (a full flush makes each copy independent), so building a
    1 GiB bomb takes a second, not a minute; the CRC is the true one (`crc=False`: 0, for bombs of tens of GiB).
    """
    import zlib

    rows = inflated // 24
    header = npy_header((rows, 3))
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    head = comp.compress(header) + comp.flush(zlib.Z_FULL_FLUSH)
    mib = comp.compress(bytes(1 << 20)) + comp.flush(zlib.Z_FULL_FLUSH)
    n_bytes = rows * 24
    whole, rest = divmod(n_bytes, 1 << 20)
    tail = comp.compress(bytes(rest)) + comp.flush(zlib.Z_FINISH)
    check = zlib.crc32(header)
    zero = bytes(1 << 20)
    for _ in range(whole if crc else 0):
        check = zlib.crc32(zero, check)
    check = zlib.crc32(bytes(rest), check) if crc else 0
    return _zip_one("points.npy", head + mib * whole + tail, len(header) + n_bytes, check)


def npz_forged_shape(rows: int) -> bytes:
    """An NPZ whose `points` header and zip entry declare `rows` x 3 float64 over a few bytes of deflate."""
    import zlib

    header = npy_header((rows, 3))
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    payload = comp.compress(header + bytes(240)) + comp.flush()
    return _zip_one("points.npy", payload, len(header) + 24 * rows, 0)


def npz_lying_member(inflated: int) -> bytes:
    """An NPZ whose `points` entry declares 10 x 3 float64 (368 bytes) but whose deflate stream holds `inflated`."""
    import zlib

    header = npy_header((10, 3))
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    payload = comp.compress(header) + comp.compress(bytes(inflated)) + comp.flush()
    # the CRC is that of the whole stream, as a writer that lied about the size only would leave it
    return _zip_one("points.npy", payload, len(header) + 240, zlib.crc32(bytes(inflated), zlib.crc32(header)))


def npz_object_array() -> bytes:
    """An NPZ whose `points` is a pickled object array (np.load with allow_pickle would run code)."""
    import numpy as np

    buf = io.BytesIO()
    np.savez(buf, points=np.array([[0.0, 1.0, 2.0], "x"], dtype=object))
    return buf.getvalue()


def ply_declaring(vertices: int, faces: int, *, binary: bool) -> bytes:
    fmt = "binary_little_endian" if binary else "ascii"
    head = (
        f"ply\nformat {fmt} 1.0\nelement vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()
    if binary:
        return head + struct.pack("<9f", 0, 0, 0, 30, 0, 0, 0, 30, 0) + struct.pack("<B3i", 3, 0, 1, 2)
    return head + b"0 0 0\n30 0 0\n0 30 0\n3 0 1 2\n"


def glb(tree: dict[str, Any], binary: bytes = b"") -> bytes:
    js = json.dumps(tree).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js
    if binary:
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def glb_bufferless_accessor(count: int) -> bytes:
    """A GLB whose position accessor has `count` items and no buffer view: trimesh would allocate zeros for all."""
    tree = {
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 4}]}],
        "accessors": [{"componentType": 5126, "count": count, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]}],
    }
    return glb(tree)


def glb_draco() -> bytes:
    """A GLB that requires KHR_draco_mesh_compression (its decoded size is not known before decoding)."""
    tree = {
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_draco_mesh_compression"],
        "extensionsRequired": ["KHR_draco_mesh_compression"],
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "buffers": [{"byteLength": 16}],
        "bufferViews": [{"buffer": 0, "byteLength": 16}],
        "meshes": [
            {
                "primitives": [
                    {
                        "attributes": {"POSITION": 0},
                        "extensions": {"KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0}}},
                    }
                ]
            }
        ],
        "accessors": [{"componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]}],
    }
    return glb(tree, bytes(16))


def _mesh_files() -> dict[str, bytes]:
    box_v, box_f = _box(40.0, 30.0, 20.0)  # millimetres
    good = binary_stl(box_v, box_f)
    nan_v = list(box_v)
    nan_v[3] = (float("nan"), nan_v[3][1], nan_v[3][2])
    inf_v = list(box_v)
    inf_v[5] = (inf_v[5][0], float("inf"), inf_v[5][2])
    tetra_v = [(0.0, 0.0, 0.0), (30.0, 0.0, 0.0), (0.0, 30.0, 0.0), (0.0, 0.0, 30.0)]
    return {
        "good_box_mm.stl": good,
        "empty.stl": b"",
        "truncated_box.stl": good[: 84 + 50 * 5 + 17],  # header says 12 triangles, the file stops in the 6th
        "header_only.stl": good[:84],  # 80-byte header and a count of 12, no triangles at all
        "png_image_named.stl": png_bytes(),
        "obj_text_named.stl": obj_text(box_v, box_f),
        "binary_stl_named.obj": good,
        "garbage_text.stl": b"this is not a mesh, it is a note somebody saved with the wrong name\n" * 4,
        "nan_vertex.obj": obj_text(nan_v, box_f).replace(b"v nan", b"v NaN"),
        "nan_vertex_binary.stl": binary_stl(nan_v, box_f),
        "inf_vertex_ascii.stl": ascii_stl(inf_v, box_f),
        "vertices_only.obj": obj_text(box_v, []),
        "collapsed_faces.obj": obj_text(box_v, [(0, 0, 1), (2, 3, 3), (4, 5, 4)]),
        "flat_square.obj": obj_text(
            [(0.0, 0.0, 0.0), (40.0, 0.0, 0.0), (40.0, 40.0, 0.0), (0.0, 40.0, 0.0)], [(0, 1, 2), (0, 2, 3)]
        ),
        "missing_vertex_index.obj": b"v 0 0 0\nv 30 0 0\nv 0 30 0\nv 0 0 30\nf 1 2 3\nf 1 2 9\nf 1 3 4\nf 2 3 4\n",
        "open_tetrahedron.obj": obj_text(tetra_v, [(0, 2, 1), (0, 1, 3), (0, 3, 2)]),  # one face missing
        "box_5m_drawn_in_mm.stl": binary_stl(*_box(5000.0, 3000.0, 2000.0)),
        "box_50um.stl": binary_stl(*_box(5.0e-5, 4.0e-5, 3.0e-5)),
        "unknown_extension.xyz": good,
        # hostile (issue 16): each declares at least 1 GiB decoded in a file of a few hundred bytes
        "bomb_npz_forged_shape.npz": npz_forged_shape(50_000_000),
        "bomb_npz_lying_member.npz": npz_lying_member(64 << 20),
        "bomb_npz_object_array.npz": npz_object_array(),
        "bomb_ply_binary_billion_vertices.ply": ply_declaring(1_000_000_000, 1, binary=True),
        "bomb_ply_ascii_forged_counts.ply": ply_declaring(2_000_000, 1_000_000, binary=False),
        "bomb_glb_bufferless_accessor.glb": glb_bufferless_accessor(400_000_000),
        "bomb_glb_draco.glb": glb_draco(),
        "bomb_off_billion_vertices.off": b"OFF\n1000000000 1 0\n0 0 0\n30 0 0\n0 30 0\n3 0 1 2\n",
    }


def _mesh(id_: str, file: str, units: str | None, code: str, *says: str, expect: str = "reject", field=None):  # type: ignore[no-untyped-def]
    e = {"id": id_, "kind": "mesh", "file": f"meshes/{file}", "units": units, "expect": expect, "code": code}
    e["says"] = list(says)
    if field:
        e["field"] = field
    return e


MESH_CASES = [
    _mesh("mesh-empty", "empty.stl", "mm", "invalid-mesh", "empty", field="file"),
    _mesh("mesh-truncated-binary-stl", "truncated_box.stl", "mm", "invalid-mesh", "truncated", "12 triangles"),
    _mesh("mesh-stl-header-only", "header_only.stl", "mm", "invalid-mesh", "truncated"),
    _mesh("mesh-png-named-stl", "png_image_named.stl", "mm", "invalid-mesh", "png"),
    _mesh("mesh-obj-text-named-stl", "obj_text_named.stl", "mm", "invalid-mesh", "obj", "rename"),
    _mesh("mesh-binary-stl-named-obj", "binary_stl_named.obj", "mm", "invalid-mesh", "binary stl", "rename"),
    _mesh("mesh-garbage-text", "garbage_text.stl", "mm", "invalid-mesh", "no triangles"),
    _mesh("mesh-nan-vertex-obj", "nan_vertex.obj", "mm", "invalid-mesh", "nan"),
    _mesh("mesh-nan-vertex-binary-stl", "nan_vertex_binary.stl", "mm", "invalid-mesh", "nan"),
    _mesh("mesh-inf-vertex-ascii-stl", "inf_vertex_ascii.stl", "mm", "invalid-mesh", "infinite"),
    _mesh("mesh-no-faces", "vertices_only.obj", "mm", "invalid-mesh", "no triangles"),
    _mesh("mesh-all-faces-collapsed", "collapsed_faces.obj", "mm", "invalid-mesh", "non-zero area"),
    _mesh("mesh-flat", "flat_square.obj", "mm", "invalid-mesh", "flat"),
    _mesh("mesh-face-index-out-of-range", "missing_vertex_index.obj", "mm", "invalid-mesh", "missing vertices"),
    _mesh("mesh-unknown-extension", "unknown_extension.xyz", "mm", "invalid-mesh", "unsupported file type"),
    _mesh(
        "mesh-5m-part-declared-m-is-5km",
        "box_5m_drawn_in_mm.stl",
        "m",
        "invalid-mesh",
        "implausible",
        "plausible in mm",
        field="units",
    ),
    _mesh("mesh-50um-part-declared-m", "box_50um.stl", "m", "invalid-mesh", "implausible", field="units"),
    _mesh("mesh-units-missing", "good_box_mm.stl", None, "validation-error", "units"),
    _mesh("mesh-units-unknown", "good_box_mm.stl", "furlong", "invalid-units", "furlong"),
    _mesh("mesh-open-surface", "open_tetrahedron.obj", "mm", "", "not watertight", expect="warn"),
    # hostile input (issue 16): refused from the declared sizes, before anything is inflated
    _mesh("bomb-npz-forged-shape", "bomb_npz_forged_shape.npz", "mm", "invalid-mesh", "declares", "limit"),
    _mesh("bomb-npz-lying-member", "bomb_npz_lying_member.npz", "mm", "invalid-mesh", "npz", "crc"),
    _mesh("bomb-npz-object-array", "bomb_npz_object_array.npz", "mm", "invalid-mesh", "objects"),
    _mesh("bomb-ply-binary-billion", "bomb_ply_binary_billion_vertices.ply", "mm", "invalid-mesh", "declares", "limit"),
    _mesh("bomb-ply-ascii-forged", "bomb_ply_ascii_forged_counts.ply", "mm", "invalid-mesh", "truncated or forged"),
    _mesh("bomb-glb-bufferless", "bomb_glb_bufferless_accessor.glb", "mm", "invalid-mesh", "declares", "limit"),
    _mesh("bomb-glb-draco", "bomb_glb_draco.glb", "mm", "invalid-mesh", "draco", "not accepted"),
    _mesh("bomb-off-billion", "bomb_off_billion_vertices.off", "mm", "invalid-mesh", "declares", "limit"),
]


# -- gripper specs ----------------------------------------------------------------------------------------------------
def _grip(id_: str, change: dict[str, Any] | None, *says: str, drop: tuple[str, ...] = (), raw: str | None = None):  # type: ignore[no-untyped-def]
    spec = {k: v for k, v in {**GRIPPER, **(change or {})}.items() if k not in drop}
    text = raw if raw is not None else json.dumps(spec, indent=2, allow_nan=True) + "\n"
    code = "validation-error" if raw is not None and raw.startswith("{not") else "invalid-gripper"
    return {
        "id": id_,
        "kind": "gripper",
        "file": f"grippers/{id_.removeprefix('gripper-')}.json",
        "text": text,
        "expect": "reject",
        "code": code,
        "says": list(says),
    }


GRIPPER_CASES = [
    _grip("gripper-negative-stroke", {"stroke": -0.08}, "stroke", "> 0"),
    _grip("gripper-negative-finger-width", {"finger_width": -0.02}, "finger_width"),
    _grip("gripper-zero-finger-depth", {"finger_depth": 0.0}, "finger_depth"),
    _grip("gripper-negative-palm-depth", {"palm_depth": -0.01}, "palm_depth"),
    _grip("gripper-negative-clearance", {"pregrasp_clearance": -0.001}, "pregrasp_clearance"),
    _grip("gripper-stroke-below-min-width", {"stroke": 0.02, "min_width": 0.03}, "min_width"),
    _grip("gripper-stroke-equals-min-width", {"stroke": 0.03, "min_width": 0.03}, "min_width"),
    _grip("gripper-friction-zero", {"friction": 0.0}, "friction"),
    _grip("gripper-friction-nan", {"friction": float("nan")}, "friction", "finite"),
    _grip("gripper-missing-stroke", None, "lacks", "stroke", drop=("stroke",)),
    _grip("gripper-missing-name", None, "lacks", "name", drop=("name",)),
    _grip("gripper-unknown-field", {"colour": "blue"}, "unknown", "colour"),
    _grip("gripper-stroke-is-string", {"stroke": "0.08"}, "stroke", "number"),
    _grip("gripper-stroke-is-bool", {"stroke": True}, "stroke", "number"),
    _grip("gripper-name-not-slug", {"name": "PGN 80/../x"}, "slug"),
    _grip("gripper-name-is-number", {"name": 80}, "slug"),
    _grip("gripper-stroke-in-mm", {"stroke": 80.0}, "stroke", "metres"),
    _grip("gripper-finger-depth-1km", {"finger_depth": 1000.0}, "finger_depth", "metres"),
    # the API's body is declared as an object, so FastAPI's validation answers before GripperSpec does
    {
        **_grip("gripper-not-an-object", None, "json object", raw="[0.08, 0.02, 0.03]\n"),
        "api_code": "validation-error",
        "api_says": ["dictionary"],
    },
    _grip("gripper-not-json", None, "json", raw="{not json, 'stroke': 0.08\n"),
]


# -- run parameters ---------------------------------------------------------------------------------------------------
def _params(id_: str, params: dict[str, Any], *says: str):  # type: ignore[no-untyped-def]
    return {
        "id": id_,
        "kind": "params",
        "file": f"params/{id_.removeprefix('params-')}.json",
        "params": params,
        "expect": "reject",
        "code": "invalid-parameter",
        "says": list(says),
    }


PARAMS_CASES = [
    _params("params-points-99", {"points": 99}, "points"),
    _params("params-points-0", {"points": 0}, "points"),
    _params("params-points-not-int", {"points": 1.5}, "points"),
    _params("params-rolls-0", {"rolls": 0}, "rolls"),
    _params("params-rolls-65", {"rolls": 65}, "rolls"),
    _params("params-k1-0", {"k1": 0}, "k1"),
    _params("params-k2-0", {"k2": 0}, "k2"),
    _params("params-safety-factor-below-1", {"safety_factor": 0.9}, "safety"),
    _params("params-friction-0", {"friction": 0.0}, "friction"),
    _params("params-friction-negative", {"friction": -0.3}, "friction"),
    _params("params-seed-negative", {"seed": -1}, "seed"),
    _params("params-collision-unknown", {"collision": "magic"}, "collision"),
    _params("params-unknown-key", {"colour": 3}, "colour"),
]

CASES = MESH_CASES + GRIPPER_CASES + PARAMS_CASES


def main() -> None:
    for name, data in _mesh_files().items():
        path = HERE / "meshes" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    (HERE / "grippers").mkdir(exist_ok=True)
    (HERE / "grippers" / "good.json").write_text(json.dumps(GRIPPER, indent=2) + "\n")
    index = []
    for case in CASES:
        case = dict(case)
        if case["kind"] == "gripper":
            (HERE / case["file"]).write_text(case.pop("text"))
        elif case["kind"] == "params":
            path = HERE / case["file"]
            path.parent.mkdir(exist_ok=True)
            path.write_text(json.dumps(case.pop("params"), indent=2) + "\n")
        index.append(case)
    ids = [c["id"] for c in index]
    assert len(ids) == len(set(ids)), "corpus ids must be unique"
    (HERE / "index.json").write_text(json.dumps(index, indent=1) + "\n")
    print(f"wrote {len(index)} cases to {HERE}")


if __name__ == "__main__":
    main()
