"""`graspgen gripper import HAND.urdf --out DIR` on URDFs written here (no download): a Franka-like hand whose second
finger joint mimics the first, the frames, stroke and meshes it gives, and every refusal (exit 2, nothing written)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from graspgen.cli import main
from graspgen.errors import InvalidGripperError
from graspgen.example_grippers import box, stl_bytes
from graspgen.gripper import GripperSpec
from graspgen.urdf import import_urdf

JOINT2_MIMIC = '<mimic joint="finger_joint1" multiplier="1"/>'


def hand_urdf(
    *,
    joint1_type: str = "prismatic",
    joint2: bool = True,
    joint2_axis: str = "0 -1 0",
    joint2_extra: str = JOINT2_MIMIC,
    joint1_limit: str = '<limit lower="0" upper="0.04" effort="70" velocity="0.2"/>',
    plate: str = "package://hand_pkg/meshes/plate.stl",
    right_geometry: bool = True,
) -> str:
    """Fingers slide along the root's Y; at q = 0 they are closed with 2 mm between the pads; the body is a housing
    box and an adapter plate (a mesh in millimetres, scale 0.001) below it; the fingers point along +Z."""
    right = (
        '<collision><origin xyz="0 -0.006 0.02"/><geometry><box size="0.02 0.01 0.04"/></geometry></collision>'
        if right_geometry
        else ""
    )
    second = (
        f"""
  <joint name="finger_joint2" type="prismatic">
    <parent link="hand"/><child link="rightfinger"/><origin xyz="0 0 0.06"/><axis xyz="{joint2_axis}"/>
    <limit lower="0" upper="0.04" effort="70" velocity="0.2"/>{joint2_extra}
  </joint>
  <link name="rightfinger">{right}</link>"""
        if joint2
        else ""
    )
    return f"""<?xml version="1.0"?>
<robot name="Test Hand">
  <link name="hand">
    <collision><origin xyz="0 0 0.025"/><geometry><box size="0.06 0.2 0.05"/></geometry></collision>
    <collision><geometry><mesh filename="{plate}" scale="0.001 0.001 0.001"/></geometry></collision>
  </link>
  <joint name="finger_joint1" type="{joint1_type}">
    <parent link="hand"/><child link="leftfinger"/><origin xyz="0 0 0.06"/><axis xyz="0 1 0"/>
    {joint1_limit}
  </joint>
  <link name="leftfinger">
    <collision><origin xyz="0 0.006 0.02"/><geometry><box size="0.02 0.01 0.04"/></geometry></collision>
  </link>{second}
</robot>
"""


def write_hand(tmp_path: Path, **kw) -> Path:
    pkg = tmp_path / "hand_pkg"
    (pkg / "meshes").mkdir(parents=True, exist_ok=True)
    (pkg / "urdf").mkdir(exist_ok=True)
    # adapter plate 80 x 80 x 10 mm under the housing (z from -10 to 0 mm in the root frame)
    (pkg / "meshes" / "plate.stl").write_bytes(stl_bytes(box((-40, -40, -10), (40, 40, 0))))
    path = pkg / "urdf" / "hand.urdf"
    path.write_text(hand_urdf(**kw))
    return path


def test_import_a_mimic_hand(tmp_path):
    out = tmp_path / "out"
    spec_path = import_urdf(write_hand(tmp_path), out)
    assert spec_path == out / "test-hand.json"
    data = json.loads(spec_path.read_text())
    assert data["stroke"] == pytest.approx(0.082) and data["min_width"] == pytest.approx(0.002)
    assert data["grip_force"] == 70 and data["kind"] == "parallel"
    # both fingers are the same box in their own frames: one file; the body holds the housing and the plate
    assert data["geometry"] == {"units": "m", "finger": "test-hand-finger.stl", "body": "test-hand-body.stl"}
    assert sorted(p.name for p in out.iterdir()) == ["test-hand-body.stl", "test-hand-finger.stl", "test-hand.json"]
    g = GripperSpec.load(spec_path)
    # X = the root's +Y (joint 1's axis), Z = the root's +Z, Y = Z x X = the root's -X
    np.testing.assert_allclose(g.geometry.finger.bounds, [[0, -0.01, -0.02], [0.01, 0.01, 0.02]], atol=1e-9)
    # the grasp origin is the midpoint of the pad centres, at the root's (0, 0, 0.08)
    body = g.geometry.body
    np.testing.assert_allclose(body.bounds, [[-0.1, -0.04, -0.09], [0.1, 0.04, -0.03]], atol=1e-9)
    assert body.volume == pytest.approx(0.06 * 0.2 * 0.05 + 0.08 * 0.08 * 0.01)


def test_independent_joints_with_equal_travel_and_a_given_approach(tmp_path):
    path = write_hand(tmp_path, joint2_extra="")
    spec_path = import_urdf(path, tmp_path / "out", name="hand-b", approach=(0.0, 0.0, 2.0))
    g = GripperSpec.load(spec_path)
    assert g.name == "hand-b" and g.stroke == pytest.approx(0.082)


def test_cli_import_then_generate(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["gripper", "import", str(write_hand(tmp_path)), "--out", str(out), "--friction", "0.6"]) == 0
    said = capsys.readouterr().out
    assert "test-hand.json" in said and "stroke 82 mm" in said
    assert json.loads((out / "test-hand.json").read_text())["friction"] == 0.6
    part = tmp_path / "part.stl"
    part.write_bytes(stl_bytes(box((-15, -10, 0), (15, 10, 20))))
    grasps = tmp_path / "grasps.json"
    args = ["generate", str(part), "--units", "mm", "--gripper", str(out / "test-hand.json"), "--out", str(grasps)]
    assert main([*args, "--points", "600", "--k1", "3", "--k2", "2", "--quiet"]) == 0
    assert json.loads(grasps.read_text())["gripper"]["geometry"]["units"] == "m"


REFUSALS = [
    ({"joint1_type": "revolute"}, "is revolute"),
    ({"joint2": False}, "only one prismatic joint"),
    ({"joint2_axis": "1 0 0"}, "90.0 deg apart"),
    ({"plate": "package://hand_pkg/meshes/missing.stl"}, "is missing"),
    ({"plate": "package://hand_pkg/meshes/plate.dae"}, "is missing"),
    ({"joint2_extra": '<mimic joint="finger_joint1" multiplier="2"/>'}, "do not close symmetrically"),
    ({"joint2_extra": '<mimic joint="nothing"/>'}, "no such joint"),
    ({"joint1_limit": ""}, "no limits"),
    ({"joint1_limit": '<limit lower="zero" upper="0.04" effort="70"/>'}, "limit lower = 'zero'"),
    ({"joint2_extra": '<mimic joint="finger_joint1" multiplier="one"/>'}, "mimic multiplier = 'one'"),
    ({"right_geometry": False}, "has no collision or visual geometry"),
]


@pytest.mark.parametrize("kw, words", REFUSALS, ids=[w for _, w in REFUSALS])
def test_refusals_exit_2_and_write_nothing(tmp_path, capsys, kw, words):
    path = write_hand(tmp_path, **kw)
    out = tmp_path / "out"
    with pytest.raises(InvalidGripperError) as e:
        import_urdf(path, out)
    assert words in e.value.message
    assert main(["gripper", "import", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]
    assert not out.exists()


def test_refuses_other_mesh_formats_and_bad_xml(tmp_path, capsys):
    path = write_hand(tmp_path, plate="package://hand_pkg/meshes/plate.dae")
    (path.parents[1] / "meshes" / "plate.dae").write_text("<COLLADA/>")
    with pytest.raises(InvalidGripperError, match="convert it to STL"):
        import_urdf(path, tmp_path / "out")
    bad = tmp_path / "bad.urdf"
    bad.write_text("<robot><link")
    assert main(["gripper", "import", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "not valid XML" in capsys.readouterr().err
    assert main(["gripper", "import", str(tmp_path / "none.urdf"), "--out", str(tmp_path / "o")]) == 2
    assert main(["gripper", "import", str(path), "--out", str(tmp_path / "o"), "--approach", "1,2"]) == 2
