"""Declared sizes of an input file, checked before anything is inflated or allocated (hostile input, issue 16).

A file can declare far more data than it holds: a 1 MB NPZ whose deflated member inflates to 1 GiB, a PLY header
declaring a billion vertices over a few bytes of body, a GLB accessor of a billion items with no buffer behind it
(trimesh fills it with zeros), a Draco-compressed GLB. Every reader of `parts.py` goes through `check_declared()`
first; NPZ archives are read by `read_npz()`, which never inflates more than a member declares.

The limit is on the *decoded* bytes: the float64 / int64 arrays the reader would make (vertices x 24 + faces x 24
for meshes, points x 24 (+ normals) for clouds), so that it means the same for every format. Uncompressed formats
must also be consistent with their own length (a declared count the bytes cannot hold is a truncated or forged
file). Each refusal is an `InvalidMeshError` (API 422 `invalid-mesh`, CLI exit 2).
"""

from __future__ import annotations

import io
import json
import re
import struct
import zipfile
from typing import Any

import numpy as np
from numpy.lib import format as npformat

from .errors import InvalidMeshError

__all__ = ["MAX_DECODED_BYTES", "check_declared", "read_npz", "decoded_bytes"]

#: default limit on the decoded arrays of one input (a binary STL at the API's 50 MB upload limit decodes to about
#: 96 MB; a point cloud of 10 M points with normals to 480 MB is refused)
MAX_DECODED_BYTES = 256 * 1024 * 1024

#: glTF extensions whose data trimesh cannot bound (or decode: no Draco decoder is installed)
_COMPRESSED_GLTF = ("KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_meshopt_compression")
_GLTF_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_GLTF_ITEMSIZE = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_PLY_SIZES = {
    **dict.fromkeys(("char", "int8", "uchar", "uint8"), 1),
    **dict.fromkeys(("short", "int16", "ushort", "uint16"), 2),
    **dict.fromkeys(("int", "int32", "uint", "uint32", "float", "float32"), 4),
    **dict.fromkeys(("double", "float64"), 8),
}
#: NPZ members read for a point cloud; other members are never inflated
_NPZ_ARRAYS = ("points", "normals")
_CHUNK = 1 << 20


def decoded_bytes(vertices: int, faces: int = 0) -> int:
    """Bytes of the float64 vertex (or point) array and int64 face array of that many rows."""
    return 24 * int(vertices) + 24 * int(faces)


def _too_large(label: str, what: str, n_bytes: int, limit: int) -> InvalidMeshError:
    return InvalidMeshError(
        f"{label} declares {what}, {_mb(n_bytes)} once decoded, above the limit of {_mb(limit)}: "
        "send a smaller or decimated part",
        field="file",
    )


def _mb(n: int) -> str:
    return f"{n / 2**20:,.1f} MiB" if n >= 2**20 else f"{n:,} bytes"


def check_declared(data: bytes, ft: str, label: str, max_bytes: int = MAX_DECODED_BYTES) -> None:
    """Refuse `data` (a file of type `ft`) when what it declares exceeds `max_bytes` decoded or its own length.

    Cheap: reads headers and counts, never the body. NPZ is checked while reading (`read_npz`).
    """
    if ft == "stl":
        _check_stl(data, label, max_bytes)
    elif ft == "ply":
        _check_ply(data, label, max_bytes)
    elif ft == "glb":
        _check_glb(data, label, max_bytes)
    elif ft == "off":
        _check_off(data, label, max_bytes)
    elif ft == "obj":
        _check_obj(data, label, max_bytes)


# ----------------------------------------------------------------------------------------------- meshes


def _check_stl(data: bytes, label: str, max_bytes: int) -> None:
    if len(data) < 84 or data[:512].lstrip().startswith(b"solid") and b"facet" in data[:4096]:
        return  # ASCII: at least ~100 bytes of text per triangle, so bounded by the file's length
    (count,) = struct.unpack_from("<I", data, 80)
    if 84 + 50 * count == len(data):
        # trimesh makes 3 float64 vertices and one int64 face row per triangle
        n = decoded_bytes(3 * count, count)
        if n > max_bytes:
            raise _too_large(label, f"{count:,} triangles", n, max_bytes)


def _check_obj(data: bytes, label: str, max_bytes: int) -> None:
    # counted without a list of matches: a 50 MB file may hold millions of lines
    vertices = sum(data.count(b"\n" + k) for k in (b"v ", b"v\t")) + data.startswith((b"v ", b"v\t"))
    faces = sum(data.count(b"\n" + k) for k in (b"f ", b"f\t")) + data.startswith((b"f ", b"f\t"))
    n = decoded_bytes(vertices, faces)
    if n > max_bytes:
        raise _too_large(label, f"{vertices:,} vertices and {faces:,} faces", n, max_bytes)


def _check_off(data: bytes, label: str, max_bytes: int) -> None:
    tokens = re.sub(rb"#[^\n]*", b"", data[:4096]).split()
    if not tokens or not tokens[0].endswith(b"OFF"):
        return  # trimesh refuses it; _unreadable says why
    try:
        vertices, faces = int(tokens[1]), int(tokens[2])
    except (IndexError, ValueError):
        return
    if vertices < 0 or faces < 0:
        raise InvalidMeshError(f"{label} declares a negative vertex or face count", field="file")
    n = decoded_bytes(vertices, faces)
    if n > max_bytes:
        raise _too_large(label, f"{vertices:,} vertices and {faces:,} faces", n, max_bytes)
    # ASCII OFF: every vertex is at least "0 0 0\n" (6 bytes), every face "3 0 1 2\n" (8 bytes)
    if 6 * vertices + 8 * faces > len(data):
        raise InvalidMeshError(
            f"{label} is truncated: its header declares {vertices:,} vertices and {faces:,} faces but the file has "
            f"only {len(data):,} bytes; export or upload it again",
            field="file",
        )


def _check_ply(data: bytes, label: str, max_bytes: int) -> None:
    end = data.find(b"end_header", 0, 65536)
    if not data.startswith(b"ply") or end < 0:
        return  # trimesh refuses it; _unreadable says why
    nl = data.find(b"\n", end)
    body = len(data) - (nl + 1 if nl >= 0 else len(data))
    lines = data[:end].decode("ascii", "replace").splitlines()
    fmt = "ascii"
    elements: list[tuple[str, int, int, int]] = []  # name, count, minimum bytes per row, decoded values per row
    for line in lines:
        words = line.split()
        if not words:
            continue
        if words[0] == "format" and len(words) > 1:
            fmt = words[1]
        elif words[0] == "element" and len(words) >= 3:
            try:
                count = int(words[2])
            except ValueError:
                return  # trimesh refuses it
            if count < 0:
                raise InvalidMeshError(f"{label} declares a negative count of {words[1]!r}", field="file")
            elements.append((words[1], count, 0, 0))
        elif words[0] == "property" and elements and len(words) >= 3:
            name, count, row, values = elements[-1]
            if words[1] == "list" and len(words) >= 5:
                # a list row holds its length and at least... nothing; faces are triangulated to >= 1 row of 3
                row += _PLY_SIZES.get(words[2], 1) if fmt != "ascii" else 2
                values += 3
            else:
                row += _PLY_SIZES.get(words[1], 1) if fmt != "ascii" else 2
                values += 1
            elements[-1] = (name, count, row, values)
    decoded = sum(8 * count * values for _, count, _, values in elements)
    if decoded > max_bytes:
        what = "elements " + ", ".join(f"{name} x {count:,}" for name, count, _, _ in elements)
        raise _too_large(label, what, decoded, max_bytes)
    # the smallest body that holds every declared row (ASCII: one digit and a separator per value)
    needed = sum(count * row for _, count, row, _ in elements)
    if needed > body:
        what = "elements " + ", ".join(f"{name} x {count:,}" for name, count, _, _ in elements)
        raise InvalidMeshError(
            f"{label} is truncated or forged: its header declares {what} (at least {needed:,} bytes) but its body "
            f"has only {body:,} bytes; export or upload it again",
            field="file",
        )


def _check_glb(data: bytes, label: str, max_bytes: int) -> None:
    if len(data) < 20 or data[:4] != b"glTF":
        return  # trimesh refuses it; _unreadable says why
    _, total = struct.unpack_from("<II", data, 4)
    json_len, json_type = struct.unpack_from("<II", data, 12)
    if json_type != 0x4E4F534A or 20 + json_len > len(data) or total > len(data):
        raise InvalidMeshError(
            f"{label} is a truncated GLB: its header declares {max(total, 20 + json_len):,} bytes but the file has "
            f"{len(data):,}; export or upload it again",
            field="file",
        )
    try:
        tree = json.loads(data[20 : 20 + json_len])
    except (ValueError, UnicodeDecodeError) as exc:
        raise InvalidMeshError(f"{label} is a GLB whose JSON chunk cannot be read ({exc})", field="file") from exc
    if not isinstance(tree, dict):
        raise InvalidMeshError(f"{label} is a GLB whose JSON chunk is not an object", field="file")
    used = set(_names(tree.get("extensionsUsed"))) | set(_names(tree.get("extensionsRequired")))
    compressed = sorted(used & set(_COMPRESSED_GLTF))
    if compressed:
        raise InvalidMeshError(
            f"{label} is compressed with {', '.join(compressed)}, which is not accepted (its decoded size cannot be "
            "checked before decoding): export the GLB without mesh compression",
            field="file",
        )
    # every accessor becomes an array of count x components (trimesh makes zeros for one without a bufferView)
    decoded = 0
    for a in _dicts(tree.get("accessors")):
        # the JSON is the sender's: a type, component type or offset of the wrong JSON type (a list is not even
        # hashable) counts as the largest or as absent, and trimesh refuses the file
        kind, component, offset = a.get("type"), a.get("componentType"), a.get("byteOffset", 0)
        count, comps = a.get("count", 0), _GLTF_COMPONENTS.get(kind, 16) if isinstance(kind, str) else 16
        if not isinstance(count, int) or count < 0:
            raise InvalidMeshError(f"{label} has a GLB accessor with an invalid count {count!r}", field="file")
        decoded += 8 * count * comps
        view = a.get("bufferView")
        views = _dicts(tree.get("bufferViews"))
        if isinstance(view, int) and 0 <= view < len(views):
            length = views[view].get("byteLength", 0)
            item = (_GLTF_ITEMSIZE.get(component, 1) if isinstance(component, int) else 1) * comps
            offset = offset if isinstance(offset, int | float) else 0
            if count and isinstance(length, int) and offset + item * count > max(length, 0) + 3:
                raise InvalidMeshError(
                    f"{label} has a GLB accessor of {count:,} items that its buffer view ({length:,} bytes) cannot "
                    "hold: the file is truncated or forged",
                    field="file",
                )
    if decoded > max_bytes:
        raise _too_large(label, f"GLB accessors of {decoded // 8:,} values", decoded, max_bytes)
    for b in _dicts(tree.get("buffers")):
        length = b.get("byteLength", 0)
        if not isinstance(length, int) or length < 0 or ("uri" not in b and length > len(data)):
            raise InvalidMeshError(
                f"{label} declares a GLB buffer of {length!r} bytes, more than the file's {len(data):,}", field="file"
            )


def _names(v: object) -> list[str]:
    return [x for x in v if isinstance(x, str)] if isinstance(v, list) else []


def _dicts(v: object) -> list[dict[str, Any]]:
    return [x for x in v if isinstance(x, dict)] if isinstance(v, list) else []


# ----------------------------------------------------------------------------------------------- NPZ


def read_npz(data: bytes, label: str, max_bytes: int = MAX_DECODED_BYTES) -> dict[str, np.ndarray]:
    """The `points` / `normals` arrays of an NPZ archive, each checked before it is inflated.

    Each member's declared size (zip directory and .npy header) must fit the limit and agree with each other, and
    a member is inflated in bounded chunks up to its declared size only: a member that inflates to more than it
    declares is refused after at most one chunk beyond. Other members are never read; pickled (object) arrays are
    refused.
    """
    try:
        zf = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise InvalidMeshError(f"{label} is not a readable NPZ archive ({exc})", field="file") from exc
    with zf:
        infos = {i.filename[:-4] if i.filename.endswith(".npy") else i.filename: i for i in zf.infolist()}
        out: dict[str, np.ndarray] = {}
        total = 0
        for name in _NPZ_ARRAYS:
            info = infos.get(name)
            if info is None:
                continue
            total += info.file_size
            if total > max_bytes:
                raise _too_large(label, f"an array {name!r} of {info.file_size:,} bytes", total, max_bytes)
            out[name] = _read_member(zf, info, name, label, max_bytes)
        if "points" not in out:
            raise InvalidMeshError(
                f"{label} has no 'points' array (found: {', '.join(infos) or 'nothing'}): "
                "save the cloud as points=(n, 3) and optionally normals=(n, 3)",
                field="file",
            )
        return out


def _read_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, name: str, label: str, max_bytes: int) -> np.ndarray:
    try:
        with zf.open(info) as f:
            version = npformat.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = npformat.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, fortran, dtype = npformat.read_array_header_2_0(f)
            else:
                raise ValueError(f"unsupported .npy version {version}")
            if dtype.hasobject:
                raise InvalidMeshError(f"{label}: {name!r} holds Python objects; only numeric arrays are read")
            count = int(np.prod(shape, dtype=np.int64)) if shape else 1
            n_bytes = count * dtype.itemsize
            # the decoded float64 copy is what the part holds
            if max(n_bytes, 8 * count) > max_bytes:
                raise _too_large(label, f"{name!r} of shape {shape} ({dtype})", max(n_bytes, 8 * count), max_bytes)
            if f.tell() + n_bytes != info.file_size:
                raise InvalidMeshError(
                    f"{label}: {name!r} declares {n_bytes:,} bytes of data but its archive entry holds "
                    f"{info.file_size - f.tell():,}: the file is truncated or forged",
                    field="file",
                )
            buf = bytearray()
            while len(buf) <= n_bytes:
                chunk = f.read(min(_CHUNK, n_bytes + 1 - len(buf)))
                if not chunk:
                    break
                buf += chunk
    except InvalidMeshError:
        raise
    except Exception as exc:  # zlib.error, BadZipFile (CRC), ValueError from the header parser, EOFError
        raise InvalidMeshError(
            f"{label} is not a readable NPZ archive ({name!r}: {type(exc).__name__}: {exc})", field="file"
        ) from exc
    if len(buf) != n_bytes:
        raise InvalidMeshError(
            f"{label}: {name!r} declares {n_bytes:,} bytes but {'more' if len(buf) > n_bytes else len(buf)} "
            "were stored: the file is truncated or forged",
            field="file",
        )
    arr = np.frombuffer(buf, dtype=dtype)
    return arr.reshape(shape, order="F" if fortran else "C")
