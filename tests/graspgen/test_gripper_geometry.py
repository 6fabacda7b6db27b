"""Gripper specs with finger and body meshes (CONTRACT.md "Gripper geometry from CAD"): parsing, the geometry object,
every validation error (with its field), the box spec unchanged, and the CLI's exit 2."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from graspgen import gripper_geometry
from graspgen.cli import main
from graspgen.errors import InvalidGripperError
from graspgen.example_grippers import box, example_gripper_files, prism, stl_bytes, union_of_shells
from graspgen.gripper import GripperSpec
from graspgen.gripper_geometry import FRAME_TOLERANCE, GripperGeometry, finger_pose

BASE = {"name": "cad", "stroke": 0.06, "friction": 0.5, "pregrasp_clearance": 0.02}
FINGER = box((0, -10, -15), (10, 10, 15))  # mm: the contract's box finger, inner face at x = 0
BODY = box((-40, -20, -35), (40, 20, -15))


def _write(tmp_path: Path, spec: dict, files: dict[str, bytes]) -> Path:
    tmp_path.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(data)
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(spec))
    return path


def _spec(**geometry) -> dict:
    return {**BASE, "geometry": {"units": "mm", "finger": "finger.stl", **geometry}}


def _errors(data: dict, files: dict[str, bytes]) -> InvalidGripperError:
    with pytest.raises(InvalidGripperError) as e:
        GripperSpec.from_dict(data, files=files)
    return e.value


def test_geometry_spec_loads_meshes_in_metres_with_digests(tmp_path):
    data = {"finger.stl": stl_bytes(FINGER), "meshes/body.stl": stl_bytes(BODY)}
    path = _write(tmp_path, _spec(body="meshes/body.stl"), data)
    g = GripperSpec.load(path)
    geo = g.geometry
    assert isinstance(geo, GripperGeometry) and geo.units == "mm"
    np.testing.assert_allclose(geo.finger.bounds, [[0, -0.01, -0.015], [0.01, 0.01, 0.015]])
    np.testing.assert_allclose(geo.body.bounds, [[-0.04, -0.02, -0.035], [0.04, 0.02, -0.015]])
    assert geo.finger_left.volume == pytest.approx(geo.finger.volume) == pytest.approx(6e-6)
    # derived box attributes: the finger's bounding box, no palm
    assert (g.finger_thickness, g.finger_width, g.finger_depth) == pytest.approx((0.01, 0.02, 0.03))
    assert g.palm_depth == 0.0 and g.palm_width == g.finger_width
    # default pad: the finger's extent at its inner face
    assert (geo.pad_width, geo.pad_depth) == pytest.approx((0.02, 0.03))
    d = g.to_dict()
    assert d == {
        **BASE,
        "min_width": 0.0,
        "geometry": {
            "units": "mm",
            "finger": "finger.stl",
            "body": "meshes/body.stl",
            "sha256": {n: hashlib.sha256(b).hexdigest() for n, b in sorted(data.items())},
        },
    }
    for forbidden in ("finger_width", "finger_depth", "finger_thickness", "palm_depth", "palm_width"):
        assert forbidden not in d
    # the dict with its digests loads again from the same files, and is the same spec
    assert GripperSpec.from_dict(d, base_dir=tmp_path) == g
    assert GripperSpec.from_dict(d, files=data) == g
    assert g.with_friction(0.3).friction == 0.3 and g.with_friction(0.3).geometry == geo


def test_box_spec_dict_is_unchanged_and_kind_is_kept():
    box_spec = {**BASE, "finger_width": 0.02, "finger_depth": 0.03, "finger_thickness": 0.01}
    # exactly the keys and order the box spec always exported (golden exports depend on it)
    assert list(GripperSpec.from_dict(box_spec).to_dict()) == [
        "name",
        "stroke",
        "finger_width",
        "finger_depth",
        "finger_thickness",
        "friction",
        "pregrasp_clearance",
        "min_width",
        "palm_depth",
        "palm_width",
    ]
    with_kind = GripperSpec.from_dict({**box_spec, "kind": "parallel"}).to_dict()
    assert with_kind["kind"] == "parallel" and list(with_kind)[:2] == ["name", "kind"]
    assert GripperSpec.from_dict(with_kind).to_dict() == with_kind
    e = pytest.raises(InvalidGripperError, GripperSpec.from_dict, {**box_spec, "kind": "suction"}).value
    assert e.field == "kind"


def test_geometry_is_immutable_and_places_the_fingers():
    g = GripperSpec.from_dict(_spec(), files={"finger.stl": stl_bytes(FINGER)})
    m = g.geometry.finger
    m.apply_translation([1.0, 0, 0])  # a caller's copy
    assert g.geometry.finger.bounds[0, 0] == 0.0
    with pytest.raises(ValueError):
        g.geometry.finger.vertices[0, 0] = 5.0
    left, right = g.geometry.fingers_at(0.04)
    np.testing.assert_allclose(right.bounds[:, 0], [0.02, 0.03])
    np.testing.assert_allclose(left.bounds[:, 0], [-0.03, -0.02])
    T = finger_pose(0.04, -1)
    np.testing.assert_allclose(T[:3, :3], np.diag([-1.0, -1.0, 1.0]))
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)


def test_finger_left_differs(tmp_path):
    # a left finger with a 2 mm pad ridge: its own finger frame, same convention
    ridge = union_of_shells(box((0, -1, -15), (2, 1, 15)), box((2, -10, -15), (12, 10, 15)))
    files = {"finger.stl": stl_bytes(FINGER), "left.stl": stl_bytes(ridge)}
    g = GripperSpec.from_dict(_spec(finger_left="left.stl"), files=files)
    assert g.geometry.finger_left.bounds[1, 0] == pytest.approx(0.012)
    assert g.geometry.files == {"finger": "finger.stl", "finger_left": "left.stl"}
    assert set(g.to_dict()["geometry"]["sha256"]) == {"finger.stl", "left.stl"}


def test_v_groove_origin_on_the_mouth_and_stepped_pad():
    for name, pad in (("pgn-80-vgroove", (0.024, 0.03)), ("pgn-80-stepped", (0.006, 0.018))):
        files = example_gripper_files(name)
        spec = json.loads(files.pop(f"{name}.json"))
        g = GripperSpec.from_dict(spec, files=files)
        assert (g.geometry.pad_width, g.geometry.pad_depth) == pytest.approx(pad)


def test_explicit_pad():
    g = GripperSpec.from_dict(_spec(pad={"width": 0.01, "depth": 0.012}), files={"finger.stl": stl_bytes(FINGER)})
    assert (g.geometry.pad_width, g.geometry.pad_depth) == (0.01, 0.012)
    assert g.to_dict()["geometry"]["pad"] == {"width": 0.01, "depth": 0.012}


def _flipped(solid):
    v, f = solid
    return v, f[:, ::-1]


def _open(solid):
    v, f = solid
    return v, f[1:]


def _mm_to(solid, shift):
    v, f = solid
    return v + np.asarray(shift, dtype=float), f


def _tetra(offset):
    v = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], dtype=float) + offset
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


@pytest.mark.parametrize(
    "change, files, field, words",
    [
        ({"finger_width": 0.02}, None, "finger_width", "never both"),
        ({"palm_depth": 0.02}, None, "palm_depth", "never both"),
        ({"geometry": {"finger": "finger.stl"}}, None, "geometry.units", "units"),
        ({"geometry": {"units": "furlong", "finger": "finger.stl"}}, None, "geometry.units", "furlong"),
        ({"geometry": {"units": "mm"}}, None, "geometry.finger", "lacks finger"),
        ({"geometry": {"units": "mm", "finger": "finger.stl", "colour": 1}}, None, "geometry.colour", "unknown"),
        ({"geometry": {"units": "mm", "finger": "finger.step"}}, {"finger.step": b"x"}, "geometry.finger", "STL"),
        ({"geometry": {"units": "mm", "finger": "../finger.stl"}}, None, "geometry.finger", "relative"),
        ({"geometry": {"units": "mm", "finger": "/etc/finger.stl"}}, None, "geometry.finger", "relative"),
        ({"geometry": {"units": "mm", "finger": "a.stl"}}, None, "geometry.finger", "no file of that name"),
        ({}, {"finger.stl": "FINGER", "extra.stl": "FINGER"}, "extra.stl", "names no such file"),
        ({}, {"finger.stl": b""}, "geometry.finger", "empty"),
        ({}, {"finger.stl": b"\x89PNG\r\n\x1a\n" + b"0" * 200}, "geometry.finger", "PNG"),
        ({}, {"finger.stl": b"solid x\nendsolid x\n"}, "geometry.finger", "no triangles"),
        ({}, {"finger.stl": stl_bytes(_open(FINGER))}, "geometry.finger", "not watertight"),
        ({}, {"finger.stl": stl_bytes(_flipped(FINGER))}, "geometry.finger", "inside out"),
        (
            {},
            {"finger.stl": stl_bytes(union_of_shells(_tetra(0), _flipped(_tetra(20))))},
            "geometry.finger",
            "no volume",
        ),
        ({}, {"finger.stl": stl_bytes(_mm_to(FINGER, (-1, 0, 0)))}, "geometry.finger", "x >= 0"),
        ({}, {"finger.stl": stl_bytes(_mm_to(FINGER, (0.5, 0, 0)))}, "geometry.finger", "origin"),
        ({}, {"finger.stl": stl_bytes(_mm_to(FINGER, (0, 25, 0)))}, "geometry.finger", "origin"),
        ({"geometry": {"units": "m", "finger": "finger.stl"}}, None, "geometry.finger", "plausible in mm"),
        (
            {"geometry": {"units": "mm", "finger": "finger.stl", "pad": {"width": 0.05, "depth": 0.01}}},
            None,
            "geometry.pad.width",
            "larger",
        ),
        (
            {"geometry": {"units": "mm", "finger": "finger.stl", "pad": {"width": -1, "depth": 0.01}}},
            None,
            "geometry.pad.width",
            "> 0",
        ),
        ({"geometry": {"units": "mm", "finger": "finger.stl", "pad": [1, 2]}}, None, "geometry.pad", "width"),
        (
            {"geometry": {"units": "mm", "finger": "finger.stl", "sha256": {"finger.stl": "0" * 64}}},
            None,
            "geometry.sha256",
            "not the one",
        ),
        (
            {"geometry": {"units": "mm", "finger": "finger.stl", "sha256": {"other.stl": "0" * 64}}},
            None,
            "geometry.sha256",
            "names",
        ),
        ({"name": "Bad Name"}, None, "name", "slug"),
        ({"stroke": 60}, None, "stroke", "metres"),
        ({"kind": "suction"}, None, "kind", "parallel"),
    ],
)
def test_geometry_spec_errors_name_their_field(change, files, field, words):
    data = {**_spec(), **change}
    given = (
        {"finger.stl": stl_bytes(FINGER)}
        if files is None
        else {k: (stl_bytes(FINGER) if v == "FINGER" else v) for k, v in files.items()}
    )
    e = _errors(data, given)
    assert e.field == field, e.message
    if words:
        assert words in e.message, e.message


def test_zero_volume_and_too_many_triangles(monkeypatch):
    e = _errors(_spec(), {"finger.stl": stl_bytes(union_of_shells(_tetra(0), _flipped(_tetra(20))))})
    assert "encloses no volume" in e.message
    # a binary STL declaring more than the limit is refused from its header, before anything is decoded
    n = gripper_geometry.MAX_TRIANGLES + 1
    header = b"\0" * 80 + n.to_bytes(4, "little") + b"\0" * (50 * n)
    e = _errors(_spec(), {"finger.stl": header})
    assert e.field == "geometry.finger" and f"{n:,} triangles" in e.message
    # any other format is counted once read
    monkeypatch.setattr(gripper_geometry, "MAX_TRIANGLES", 11)
    obj = trimesh.exchange.obj.export_obj(trimesh.Trimesh(*FINGER, process=False)).encode()
    e = _errors({**BASE, "geometry": {"units": "mm", "finger": "finger.obj"}}, {"finger.obj": obj})
    assert "12 triangles, more than the limit of 11" in e.message


def test_a_geometry_dict_without_its_files_is_refused():
    with pytest.raises(InvalidGripperError) as e:
        GripperSpec.from_dict(_spec())
    assert e.value.field == "geometry" and "mesh files" in e.value.message
    box_spec = {**BASE, "finger_width": 0.02, "finger_depth": 0.03, "finger_thickness": 0.01}
    with pytest.raises(InvalidGripperError) as e:
        GripperSpec.from_dict(box_spec, files={"finger.stl": b"x"})
    assert e.value.field == "finger.stl" and "no geometry" in e.value.message


def test_frame_tolerance_is_small():
    # within the tolerance an inner face slightly off x = 0 is accepted, beyond it refused
    ok = _mm_to(FINGER, (FRAME_TOLERANCE * 1e3 / 2, 0, 0))
    GripperSpec.from_dict(_spec(), files={"finger.stl": stl_bytes(ok)})
    bad = _mm_to(FINGER, (FRAME_TOLERANCE * 1e3 * 2, 0, 0))
    assert _errors(_spec(), {"finger.stl": stl_bytes(bad)}).field == "geometry.finger"


def test_cli_refuses_a_bad_geometry_spec_with_exit_2(tmp_path, capsys):
    path = _write(tmp_path, _spec(), {"finger.stl": stl_bytes(_flipped(FINGER))})
    out = tmp_path / "out" / "grasps.json"
    part = tmp_path / "part.stl"
    part.write_bytes(stl_bytes(box((-10, -10, -10), (10, 10, 10))))
    code = main(["generate", str(part), "--units", "mm", "--gripper", str(path), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "inside out" in err[0]
    assert not out.parent.exists()
    missing = _write(tmp_path / "m", _spec(), {})
    code = main(["generate", str(part), "--units", "mm", "--gripper", str(missing), "--out", str(out)])
    assert code == 2 and "cannot read the finger file 'finger.stl'" in capsys.readouterr().err


def test_cli_generates_with_a_geometry_spec(tmp_path):
    path = _write(tmp_path, _spec(body="body.stl"), {"finger.stl": stl_bytes(FINGER), "body.stl": stl_bytes(BODY)})
    part = tmp_path / "part.stl"
    part.write_bytes(stl_bytes(prism([(0, 0), (30, 0), (30, 20), (0, 20)], 0, 15, axis=2)))
    out = tmp_path / "grasps.json"
    code = main(
        [
            "generate",
            str(part),
            "--units",
            "mm",
            "--gripper",
            str(path),
            "--out",
            str(out),
            "--points",
            "800",
            "--k1",
            "3",
            "--k2",
            "2",
            "--quiet",
            "--preview",
            str(tmp_path / "preview.png"),
        ]
    )
    assert code == 0
    assert (tmp_path / "preview.png").read_bytes().startswith(b"\x89PNG")
    gripper = json.loads(out.read_text())["gripper"]
    assert gripper["geometry"]["sha256"]["finger.stl"] == hashlib.sha256(stl_bytes(FINGER)).hexdigest()
    assert "finger_width" not in gripper
