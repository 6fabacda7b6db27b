"""load_part / read_raw_extents: the shared meshes, broken inputs, units, point clouds."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

from graspgen.errors import InvalidMeshError, InvalidUnitsError
from graspgen.parts import Part, load_part, read_raw_extents

GOOD_MESHES = [
    "tless_04.stl",
    "tless_10.stl",
    "tless_13.stl",
    "ycb_mustard_bottle.obj",
    "ycb_sugar_box.obj",
    "ycb_tomato_soup_can.obj",
    "trimesh_featuretype.stl",
    "trimesh_idler_riser.stl",
    "trimesh_angle_block.stl",
    "trimesh_round.stl",
]


def _manifest_rows(folder: Path) -> dict[str, list[str]]:
    rows = {}
    for line in (folder / "MANIFEST.md").read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 10 and cells[0] in GOOD_MESHES:
            rows[cells[0]] = cells
    return rows


def _extents_from_manifest(cell: str) -> np.ndarray:
    return np.array([float(v) for v in re.findall(r"[0-9.]+", cell)])


def _outward_fraction(mesh: trimesh.Trimesh, winding_numbers, n: int = 200, seed: int = 0) -> float:
    """Fraction of sampled faces whose normal points outward: inside behind the face, outside in front of it."""
    rng = np.random.default_rng(seed)
    faces = rng.choice(len(mesh.faces), size=min(n, len(mesh.faces)), replace=False, p=mesh.area_faces / mesh.area)
    centre = mesh.triangles_center[faces]
    eps = 1e-4 * float(mesh.extents.max())
    front = winding_numbers(mesh, centre + eps * mesh.face_normals[faces])
    back = winding_numbers(mesh, centre - eps * mesh.face_normals[faces])
    return float(np.mean((np.abs(front) < 0.5) & (back > 0.5)))


# ----------------------------------------------------------------------------------------------- shared meshes


@pytest.mark.parametrize("filename", GOOD_MESHES)
def test_shared_mesh_loads_in_its_units_with_manifest_extents(shared_meshes, filename):
    units = json.loads((shared_meshes / "units.json").read_text())[filename]
    part = load_part(shared_meshes / filename, units=units)
    expected = _extents_from_manifest(_manifest_rows(shared_meshes)[filename][8])
    assert expected.shape == (3,)
    np.testing.assert_allclose(part.extents, expected, atol=1e-3)
    assert part.name == Path(filename).stem
    assert part.source_units == units
    assert part.mesh is not None and part.points is None
    assert np.isfinite(part.mesh.vertices).all()
    if part.watertight:
        assert part.mesh.volume > 0.0
        assert part.warnings == ()
    else:
        assert any("not watertight" in w for w in part.warnings)


@pytest.mark.parametrize("filename", ["tless_04.stl", "trimesh_idler_riser.stl", "ycb_sugar_box.obj"])
def test_loaded_watertight_meshes_have_outward_normals(shared_meshes, winding_numbers, filename):
    units = json.loads((shared_meshes / "units.json").read_text())[filename]
    part = load_part(shared_meshes / filename, units=units)
    assert part.watertight
    assert _outward_fraction(part.mesh, winding_numbers) > 0.97


def test_ycb_sugar_box_is_watertight_after_merging_uv_seams(shared_meshes):
    raw = trimesh.load(shared_meshes / "ycb_sugar_box.obj", process=False)
    assert not raw.is_watertight  # the file itself duplicates vertices at UV seams
    part = load_part(shared_meshes / "ycb_sugar_box.obj", units="m")
    assert part.watertight
    assert part.warnings == ()
    assert part.mesh.volume > 0.0


def test_sha256_is_of_the_file_bytes_and_same_for_bytes_input(shared_meshes):
    import hashlib

    path = shared_meshes / "tless_04.stl"
    data = path.read_bytes()
    from_path = load_part(path, units="mm")
    from_bytes = load_part(data, units="mm", file_type="stl", name="tless-04")
    assert from_path.sha256 == hashlib.sha256(data).hexdigest() == from_bytes.sha256
    assert from_bytes.name == "tless-04"
    np.testing.assert_array_equal(from_path.mesh.vertices, from_bytes.mesh.vertices)


def test_same_part_in_mm_and_m_gives_the_same_metre_geometry(shared_meshes):
    in_mm = load_part(shared_meshes / "trimesh_angle_block.stl", units="mm")
    raw = trimesh.load(shared_meshes / "trimesh_angle_block.stl", process=False)
    raw.apply_scale(1e-3)
    in_m = load_part(trimesh.exchange.stl.export_stl(raw), units="m", file_type="stl")
    assert in_m.source_units == "m" and in_mm.source_units == "mm"
    assert len(in_m.mesh.vertices) == len(in_mm.mesh.vertices)
    # float32 STL coordinates: the two files agree to ~1e-9 m
    np.testing.assert_allclose(np.sort(in_m.mesh.vertices, axis=0), np.sort(in_mm.mesh.vertices, axis=0), atol=1e-8)
    np.testing.assert_allclose(in_m.extents, in_mm.extents, atol=1e-8)
    assert in_m.mesh.volume == pytest.approx(in_mm.mesh.volume, rel=1e-6)


def test_read_raw_extents_are_in_file_units(shared_meshes):
    np.testing.assert_allclose(read_raw_extents(shared_meshes / "tless_04.stl"), [40.0, 40.0, 78.0], atol=0.05)
    with pytest.raises(InvalidMeshError, match="truncated"):
        read_raw_extents(shared_meshes / "bad" / "truncated_angle_block.stl")


# ----------------------------------------------------------------------------------------------- bad inputs


@pytest.mark.parametrize(
    ("filename", "expected"),
    [
        ("empty.stl", r"is empty \(0 bytes\)"),
        ("truncated_angle_block.stl", r"truncated: its STL header declares 704 triangles .* only 21207 bytes"),
        ("idler_riser_binary_stl.obj", r"is a binary STL but is named \.obj: rename it to \.stl"),
    ],
)
def test_bad_shared_files_raise_with_an_actionable_message(shared_meshes, filename, expected):
    with pytest.raises(InvalidMeshError, match=expected) as info:
        load_part(shared_meshes / "bad" / filename, units="mm")
    assert filename in str(info.value)
    assert info.value.code == "invalid-mesh"


def test_open_surface_loads_with_a_not_watertight_warning(shared_meshes):
    part = load_part(shared_meshes / "bad" / "open_surface_featuretype.stl", units="mm")
    assert not part.watertight
    assert part.warnings == ("mesh is not watertight: outward normals cannot be guaranteed",)
    np.testing.assert_allclose(part.extents, [0.127, 0.0635, 0.0349], atol=1e-3)


def test_every_bad_file_is_either_rejected_or_warned_about(shared_meshes):
    for path in sorted((shared_meshes / "bad").iterdir()):
        try:
            part = load_part(path, units="mm")
        except InvalidMeshError as exc:
            assert path.name in exc.message and len(exc.message) > 40
        else:
            assert path.name == "open_surface_featuretype.stl"
            assert part.warnings


def test_unreadable_path_is_an_invalid_mesh(tmp_path):
    with pytest.raises(InvalidMeshError, match="cannot read .*missing.stl"):
        load_part(tmp_path / "missing.stl", units="mm")
    with pytest.raises(InvalidMeshError, match="cannot read"):
        load_part(tmp_path, units="mm")


def test_non_finite_vertices_are_rejected():
    box = trimesh.creation.box(extents=(0.02, 0.03, 0.04))
    box.vertices[3] = [np.nan, 0.0, 0.0]
    with pytest.raises(InvalidMeshError, match="1 vertices with NaN or infinite"):
        load_part(box, units="m")
    off = "OFF\n4 4 0\n0 0 0\n1 0 0\n0 inf 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n"
    with pytest.raises(InvalidMeshError, match="NaN or infinite"):
        load_part(off.encode(), units="cm", file_type="off")


def test_zero_faces_are_rejected():
    with pytest.raises(InvalidMeshError, match="no triangles"):
        load_part(trimesh.Trimesh(vertices=np.eye(3), faces=np.zeros((0, 3), dtype=int)), units="m")
    with pytest.raises(InvalidMeshError, match="only vertices, no triangles"):
        load_part(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n", units="mm", file_type="obj")


def test_flat_mesh_is_rejected_even_when_tilted():
    square = trimesh.Trimesh(
        vertices=[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], faces=[[0, 1, 2], [0, 2, 3]], process=False
    )
    square.apply_transform(trimesh.transformations.rotation_matrix(0.7, [1, 1, 0]))
    assert (square.extents > 0.1).all()  # not flat along any axis of the bounding box
    with pytest.raises(InvalidMeshError, match="is flat"):
        load_part(square, units="cm")


def test_mesh_whose_faces_all_collapse_is_rejected():
    v = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], dtype=float)
    with pytest.raises(InvalidMeshError, match="no triangles with a non-zero area"):
        load_part(trimesh.Trimesh(v, [[0, 0, 1], [2, 3, 3], [1, 1, 1]], process=False), units="m")


def test_absurd_extents_name_the_plausible_units():
    box = trimesh.creation.box(extents=(40.0, 40.0, 78.0))  # a 78 mm part declared in metres
    with pytest.raises(InvalidMeshError, match=r"it would be plausible in mm, cm, in\b") as info:
        load_part(box, units="m")
    assert info.value.field == "units"
    assert "as mm: 40 x 40 x 78 mm" in info.value.message
    tiny = trimesh.creation.box(extents=(0.05, 0.02, 0.03))  # 0.05 "mm": a 5 cm part in metres
    with pytest.raises(InvalidMeshError, match=r"it would be plausible in cm, m, in\b"):
        load_part(tiny, units="mm")


def test_units_are_required_and_checked(shared_meshes):
    with pytest.raises(InvalidUnitsError):
        load_part(shared_meshes / "tless_04.stl", units=None)
    with pytest.raises(InvalidUnitsError, match="furlong"):
        load_part(shared_meshes / "tless_04.stl", units="furlong")


def test_bytes_need_a_supported_file_type():
    data = trimesh.exchange.stl.export_stl(trimesh.creation.box(extents=(0.01, 0.01, 0.01)))
    with pytest.raises(InvalidMeshError, match="file_type is required"):
        load_part(data, units="m")
    with pytest.raises(InvalidMeshError, match="unsupported file type 'step'"):
        load_part(data, units="m", file_type="step")
    assert load_part(data, units="m", file_type=".STL").watertight


def test_garbage_is_an_invalid_mesh_not_a_crash():
    with pytest.raises(InvalidMeshError, match="no triangles could be read|looks like"):
        load_part(b"this is not a mesh at all\n" * 10, units="mm", file_type="stl")
    with pytest.raises(InvalidMeshError):
        load_part(b"ply\nformat ascii 1.0\nelement vertex 3\n", units="mm", file_type="ply")


def test_inverted_watertight_mesh_is_turned_outward(winding_numbers):
    box = trimesh.creation.box(extents=(0.02, 0.03, 0.04))
    box.invert()
    assert box.volume < 0
    part = load_part(box, units="m")
    assert part.mesh.volume == pytest.approx(0.02 * 0.03 * 0.04)
    assert _outward_fraction(part.mesh, winding_numbers) == 1.0


def test_double_sided_sliver_and_duplicate_faces_are_removed():
    box = trimesh.creation.box(extents=(0.02, 0.03, 0.04))
    v = np.vstack([box.vertices, [[0.05, 0.0, 0.0], [0.06, 0.0, 0.0], [0.05, 0.01, 0.0]]])
    sliver = [[8, 9, 10], [8, 10, 9]]  # the same triangle both ways: zero thickness
    faces = np.vstack([box.faces, box.faces[:2], sliver])  # plus two exact duplicates
    part = load_part(trimesh.Trimesh(v, faces, process=False), units="m")
    assert part.watertight
    assert len(part.mesh.faces) == 12
    np.testing.assert_allclose(part.extents, [0.02, 0.03, 0.04])


def test_glb_scene_is_concatenated_with_its_transforms():
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(extents=(0.01, 0.01, 0.01)))
    scene.add_geometry(
        trimesh.creation.box(extents=(0.01, 0.01, 0.01)),
        transform=trimesh.transformations.translation_matrix([0.05, 0, 0]),
    )
    part = load_part(scene.export(file_type="glb"), units="m", file_type="glb")
    assert part.watertight
    assert len(part.mesh.faces) == 24
    np.testing.assert_allclose(part.extents, [0.06, 0.01, 0.01], atol=1e-9)


@pytest.mark.parametrize("file_type", ["stl", "obj", "ply", "off"])
def test_every_mesh_format_loads(tmp_path, file_type):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    path = tmp_path / f"ball.{file_type}"
    path.write_bytes(
        mesh.export(file_type=file_type).encode() if file_type in ("obj", "off") else mesh.export(file_type=file_type)
    )
    part = load_part(path, units="mm")
    assert part.watertight and part.name == "ball"
    np.testing.assert_allclose(part.extents, mesh.extents * 1e-3, rtol=1e-6)


def test_part_is_frozen():
    part = load_part(trimesh.creation.box(extents=(0.01, 0.02, 0.03)), units="m")
    assert isinstance(part, Part)
    with pytest.raises(AttributeError):
        part.name = "other"  # type: ignore[misc]


# ----------------------------------------------------------------------------------------------- point clouds


def _sphere_cloud(n=2000, radius=0.04, centre=(0.1, -0.2, 0.3), seed=1):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.asarray(centre) + radius * d, d


def _torus_cloud(n=4000, major=0.04, minor=0.012, seed=2):
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, 2 * np.pi, size=(2, n))
    ring = np.stack([np.cos(u), np.sin(u), np.zeros(n)], axis=1)
    normal = np.cos(v)[:, None] * ring + np.sin(v)[:, None] * np.array([0.0, 0.0, 1.0])
    return major * ring + minor * normal, normal


def _ply(points, normals=None) -> bytes:
    props = "property double x\nproperty double y\nproperty double z\n"
    cols = [points]
    if normals is not None:
        props += "property double nx\nproperty double ny\nproperty double nz\n"
        cols.append(normals)
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\n{props}end_header\n"
    return header.encode() + np.hstack(cols).astype("<f8").tobytes()


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@pytest.mark.parametrize("file_type", ["ply", "npz"])
def test_point_cloud_without_normals_gets_outward_normals(file_type):
    points, _ = _sphere_cloud()
    data = _ply(points) if file_type == "ply" else _npz(points=points)
    part = load_part(data, units="m", file_type=file_type)
    assert part.mesh is None and part.points.shape == (2000, 3)
    np.testing.assert_allclose(np.linalg.norm(part.normals, axis=1), 1.0)
    radial = part.points - np.array([0.1, -0.2, 0.3])
    assert (np.einsum("ij,ij->i", part.normals, radial) > 0).all()
    assert any("estimated" in w for w in part.warnings)


def test_estimated_normals_are_outward_on_a_non_convex_cloud():
    points, truth = _torus_cloud()
    part = load_part(_npz(points=points * 1e3), units="mm", file_type="npz")  # in mm on disk
    np.testing.assert_allclose(part.points, points, atol=1e-12)
    cos = np.einsum("ij,ij->i", part.normals, truth)
    assert (cos > 0).all()
    assert np.median(cos) > 0.99


def test_surface_mesh_is_the_mesh_or_the_convex_hull_of_a_cloud(winding_numbers):
    box = load_part(trimesh.creation.box(extents=(0.01, 0.02, 0.03)), units="m")
    assert box.surface_mesh() is box.mesh
    points, _ = _torus_cloud(n=1500)
    cloud = load_part(_npz(points=points), units="m", file_type="npz")
    hull = cloud.surface_mesh()
    assert hull.is_watertight and hull.volume > 0
    assert {tuple(v) for v in hull.vertices} <= {tuple(p) for p in cloud.points}  # its corners are cloud points
    # every point lies inside or on the hull, and the torus' hole is covered (a hull, not a reconstruction)
    assert (winding_numbers(hull, cloud.points * 0.999) > 0.5).all()
    assert winding_numbers(hull, np.zeros((1, 3)))[0] > 0.5


def test_given_normals_are_kept():
    points, radial = _sphere_cloud(n=500)
    rng = np.random.default_rng(5)
    given = radial + 0.3 * rng.normal(size=radial.shape)  # deliberately not what PCA would find
    given /= np.linalg.norm(given, axis=1, keepdims=True)
    for data, ft in ((_npz(points=points, normals=given), "npz"), (_ply(points, given), "ply")):
        part = load_part(data, units="m", file_type=ft)
        np.testing.assert_allclose(part.normals, given, atol=1e-12)
        assert part.warnings == ()
        assert not part.normals.flags.writeable


def test_point_cloud_inputs_are_checked():
    points, normals = _sphere_cloud(n=100)
    with pytest.raises(InvalidMeshError, match="no 'points' array"):
        load_part(_npz(xyz=points), units="m", file_type="npz")
    with pytest.raises(InvalidMeshError, match="'normals' must have the shape"):
        load_part(_npz(points=points, normals=normals[:10]), units="m", file_type="npz")
    bad = points.copy()
    bad[7, 1] = np.inf
    with pytest.raises(InvalidMeshError, match="NaN or infinite"):
        load_part(_npz(points=bad), units="m", file_type="npz")
    zero = normals.copy()
    zero[3] = 0.0
    with pytest.raises(InvalidMeshError, match="zero-length normals"):
        load_part(_npz(points=points, normals=zero), units="m", file_type="npz")
    flat = points.copy()
    flat[:, 2] = 0.0
    with pytest.raises(InvalidMeshError, match="is flat"):
        load_part(_npz(points=flat), units="m", file_type="npz")
    with pytest.raises(InvalidMeshError, match="not a readable NPZ"):
        load_part(b"PK\x03\x04 broken", units="m", file_type="npz")
