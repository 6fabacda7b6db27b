"""Hostile input (issue 16): readers check declared sizes before inflating; honest files of every format still load."""

from __future__ import annotations

import io
import resource
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from graspgen.errors import InvalidMeshError
from graspgen.limits import MAX_DECODED_BYTES
from graspgen.parts import load_part

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "reliability" / "corpus"))
import make_corpus as mc  # noqa: E402

BOX = trimesh.creation.box(extents=[40.0, 30.0, 20.0])  # millimetres


def _export(ft: str) -> bytes:
    data = BOX.export(file_type=ft)
    return data.encode() if isinstance(data, str) else data


@pytest.mark.parametrize("ft", ["stl", "obj", "ply", "off", "glb"])
def test_honest_meshes_of_every_format_load(ft: str) -> None:
    part = load_part(_export(ft), units="mm", file_type=ft)
    assert part.mesh is not None and len(part.mesh.faces) == 12
    np.testing.assert_allclose(sorted(part.extents), [0.02, 0.03, 0.04])


def test_honest_point_clouds_load_plain_and_compressed() -> None:
    pts, _ = trimesh.sample.sample_surface_even(BOX, 500, seed=1)
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    for save in (np.savez, np.savez_compressed):
        buf = io.BytesIO()
        save(buf, points=pts, normals=nrm, colours=np.zeros((len(pts), 3)))
        part = load_part(buf.getvalue(), units="mm", file_type="npz")
        assert part.points is not None and len(part.points) == len(np.unique(pts, axis=0))
        np.testing.assert_allclose(part.normals, np.tile([0.0, 0.0, 1.0], (len(part.points), 1)))
    # fortran-ordered and float32 arrays are read as numpy would
    buf = io.BytesIO()
    np.savez_compressed(buf, points=np.asfortranarray(pts.astype(np.float32)))
    part = load_part(buf.getvalue(), units="mm", file_type="npz")
    np.testing.assert_allclose(
        np.sort(part.points, axis=0), np.sort(np.unique(pts.astype(np.float32), axis=0) / 1e3, axis=0), rtol=1e-6
    )


def test_the_limit_is_a_parameter() -> None:
    data = _export("stl")  # 12 triangles: 36 vertices and 12 faces, 1,152 bytes decoded
    load_part(data, units="mm", file_type="stl", max_decoded_bytes=2048)
    with pytest.raises(InvalidMeshError, match="12 triangles.*above the limit"):
        load_part(data, units="mm", file_type="stl", max_decoded_bytes=1024)
    buf = io.BytesIO()
    np.savez_compressed(buf, points=np.random.default_rng(0).random((1000, 3)))
    with pytest.raises(
        InvalidMeshError, match="'points' of 24,128 bytes, 24,128 bytes once decoded, above the limit of 20,000 bytes"
    ):
        load_part(buf.getvalue(), units="mm", file_type="npz", max_decoded_bytes=20_000)


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def test_a_1_gib_npz_bomb_is_refused_without_inflating() -> None:
    bomb = mc.npz_zero_bomb(1 << 30)
    assert len(bomb) < 2 << 20  # about 1 MB on the wire
    before = _peak_mb()
    with pytest.raises(InvalidMeshError, match="1,024.0 MiB once decoded, above the limit of 256.0 MiB") as err:
        load_part(bomb, units="mm", file_type="npz")
    assert err.value.field == "file"
    assert _peak_mb() - before < 50  # nothing was inflated (inflating would add 1,024 MB)


def test_a_bomb_within_the_limit_is_read_and_still_bounded() -> None:
    # 48 MiB of zero points: declared honestly and under the limit, so it is inflated (then refused as degenerate)
    bomb = mc.npz_zero_bomb(48 << 20)
    with pytest.raises(InvalidMeshError, match="degenerate|only 1 distinct"):
        load_part(bomb, units="mm", file_type="npz", max_decoded_bytes=64 << 20)


@pytest.mark.parametrize(
    ("name", "data", "says"),
    [
        ("npz forged shape", mc.npz_forged_shape(50_000_000), "above the limit"),
        ("npz member inflating past its declared size", mc.npz_lying_member(64 << 20), "crc"),
        ("npz pickled objects", mc.npz_object_array(), "python objects"),
        ("ply binary, a billion vertices", mc.ply_declaring(10**9, 1, binary=True), "above the limit"),
        ("ply binary, counts its body cannot hold", mc.ply_declaring(2_000_000, 1, binary=True), "truncated or forged"),
        ("ply ascii, counts its body cannot hold", mc.ply_declaring(2_000_000, 10**6, binary=False), "forged"),
        ("glb accessor without buffer", mc.glb_bufferless_accessor(400_000_000), "above the limit"),
        ("glb draco", mc.glb_draco(), "not accepted"),
        ("off, a billion vertices", b"OFF\n1000000000 1 0\n0 0 0\n", "above the limit"),
        ("off, counts its body cannot hold", b"OFF\n2000000 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "truncated"),
    ],
)
def test_hostile_files_are_refused_by_what_they_declare(name: str, data: bytes, says: str) -> None:
    ft = name.split()[0].rstrip(",")
    before = _peak_mb()
    with pytest.raises(InvalidMeshError) as err:
        load_part(data, units="mm", file_type=ft)
    assert says in err.value.message.lower()
    assert _peak_mb() - before < 50


@pytest.mark.parametrize(
    "accessor",
    [
        {"type": ["VEC3"]},  # not hashable: was a TypeError out of the size check
        {"componentType": {"x": 5126}},
        {"byteOffset": "0"},
    ],
    ids=["type-a-list", "component-type-an-object", "byte-offset-a-string"],
)
def test_glb_accessor_fields_of_the_wrong_json_type_are_refused_as_invalid(accessor: dict[str, object]) -> None:
    tree = {
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "buffers": [{"byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 4}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", **accessor}],
    }
    with pytest.raises(InvalidMeshError) as err:
        load_part(mc.glb(tree, bytes(36)), units="mm", file_type="glb")
    assert err.value.field == "file"


def test_the_default_limit_admits_a_binary_stl_at_the_upload_limit() -> None:
    triangles = (50 * 2**20 - 84) // 50  # the API's default 50 MB upload limit
    assert 96 * triangles < MAX_DECODED_BYTES
