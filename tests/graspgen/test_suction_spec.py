"""Suction cup specs (CONTRACT.md "Suction cups"): parsing, the cylinder and body-mesh tools, every validation error
with its field, and load_gripper's dispatch by kind."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from graspgen import GripperSpec, InvalidGripperError, SuctionSpec, load_gripper
from graspgen.example_grippers import box, stl_bytes
from tests.grippers import CUP

REPO = Path(__file__).resolve().parents[2]
BODY = box((-20, -20, -150), (20, 20, -20))  # mm: a square housing behind a 20 mm cup


def _error(data: dict, **kw) -> InvalidGripperError:
    with pytest.raises(InvalidGripperError) as e:
        SuctionSpec.from_dict(data, **kw)
    return e.value


def _body_spec() -> dict:
    d = {k: v for k, v in CUP.items() if k != "tool"}
    return {**d, "geometry": {"units": "mm", "body": "body.stl"}}


def test_contract_example_round_trips():
    s = SuctionSpec.from_dict(CUP)
    assert s.tool is not None and s.tool.radius == 0.012 and s.geometry is None and s.round_tool
    assert s.to_dict() == CUP
    assert list(s.to_dict()) == list(CUP)  # the contract's key order
    assert s.vacuum_force == pytest.approx(60000 * math.pi * 0.015**2)  # 42.4 N
    assert SuctionSpec.from_dict(s.to_dict()) == s


def test_shipped_example_is_the_contract_cup():
    s = load_gripper(REPO / "examples" / "cup-30.json")
    assert isinstance(s, SuctionSpec) and s.to_dict() == CUP


def test_body_mesh_tool_from_files_or_beside_the_spec(tmp_path):
    s = SuctionSpec.from_dict(_body_spec(), files={"body.stl": stl_bytes(BODY)})
    assert s.tool is None and s.geometry is not None and not s.round_tool
    assert s.geometry.body.bounds[0] == pytest.approx([-0.02, -0.02, -0.15])
    d = s.to_dict()
    assert d["geometry"]["body"] == "body.stl" and len(d["geometry"]["sha256"]["body.stl"]) == 64
    # the exported spec (with its digest) loads again from the same bytes
    assert SuctionSpec.from_dict(d, files={"body.stl": stl_bytes(BODY)}) == s
    (tmp_path / "body.stl").write_bytes(stl_bytes(BODY))
    (tmp_path / "cup.json").write_text(json.dumps(_body_spec()))
    assert load_gripper(tmp_path / "cup.json") == s


def test_load_gripper_dispatches_by_kind():
    assert isinstance(load_gripper(CUP), SuctionSpec)
    jaws = json.loads((REPO / "examples" / "pgn-80.json").read_text())
    assert isinstance(load_gripper(jaws), GripperSpec)
    assert isinstance(load_gripper({**jaws, "kind": "parallel"}), GripperSpec)
    with pytest.raises(InvalidGripperError) as e:
        load_gripper({**CUP, "kind": "magnetic"})
    assert e.value.field == "kind" and "suction" in e.value.message
    # a suction spec is not a parallel one, nor the other way round
    with pytest.raises(InvalidGripperError) as e:
        GripperSpec.from_dict(CUP)
    assert e.value.field == "kind"
    with pytest.raises(InvalidGripperError) as e:
        SuctionSpec.from_dict(jaws)
    assert e.value.field == "kind"


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"colour": "red"}, "colour", "unknown"),
        ({"cup_radius": -0.01}, "cup_radius", "> 0"),
        ({"cup_radius": 0}, "cup_radius", "> 0"),
        ({"cup_radius": 15}, "cup_radius", "metres"),
        ({"cup_height": float("nan")}, "cup_height", "finite"),
        ({"max_strain": 1.0}, "max_strain", "< 1"),
        ({"max_strain": True}, "max_strain", "number"),
        ({"vacuum": 200_000}, "vacuum", "atmosphere"),
        ({"vacuum": 0}, "vacuum", "> 0"),
        ({"friction": -0.5}, "friction", "> 0"),
        ({"pregrasp_clearance": -0.01}, "pregrasp_clearance", ">= 0"),
        ({"name": "Cup 30"}, "name", "slug"),
        ({"tool": {"radius": 0.01}}, "tool", "length"),
        ({"tool": {"radius": -0.01, "length": 0.1}}, "tool.radius", "> 0"),
        ({"tool": {"radius": 0.01, "length": 120}}, "tool.length", "metres"),
        ({"kind": None}, "kind", "suction"),
    ],
)
def test_bad_fields_are_named(change, field, words):
    e = _error({**CUP, **change})
    assert e.field == field and words in e.message


def test_missing_fields_and_tool_are_named():
    e = _error({k: v for k, v in CUP.items() if k != "vacuum"})
    assert e.field == "vacuum" and "lacks" in e.message
    e = _error({k: v for k, v in CUP.items() if k != "tool"})
    assert e.field == "tool" and "neither" in e.message


def test_tool_wider_than_the_cup_is_accepted():
    # a vacuum generator's housing behind a small cup: criterion collision decides where it fits
    s = SuctionSpec.from_dict({**CUP, "tool": {"radius": 0.03, "length": 0.1}})
    assert s.tool is not None and s.tool.radius > s.cup_radius


def test_both_tool_and_geometry_are_refused_before_reading_files():
    e = _error({**_body_spec(), "tool": CUP["tool"]})
    assert e.field == "geometry" and "never both" in e.message


def test_body_file_errors():
    e = _error(_body_spec(), files={})
    assert e.field == "geometry.body" and "no file" in e.message
    e = _error(_body_spec(), files={"body.stl": stl_bytes(BODY), "extra.stl": b"x"})
    assert e.field == "extra.stl"
    e = _error(_body_spec(), base_dir="/nonexistent-dir")
    assert e.field == "geometry.body" and "cannot read" in e.message
    e = _error(_body_spec())
    assert e.field == "geometry" and "mesh files" in e.message
    e = _error({**_body_spec(), "geometry": {"units": "mm", "body": "../body.stl"}}, files={})
    assert e.field == "geometry.body" and "relative" in e.message
    e = _error({**_body_spec(), "geometry": {"units": "mm", "finger": "f.stl", "body": "b.stl"}}, files={})
    assert e.field == "geometry.finger" and "unknown" in e.message
    e = _error({**_body_spec(), "geometry": {"units": "furlong", "body": "body.stl"}}, files={})
    assert e.field == "geometry.units"
    e = _error(CUP, files={"body.stl": b""})
    assert e.field == "body.stl" and "no geometry" in e.message
    open_box = (BODY[0], BODY[1][:-2])  # two missing triangles: not watertight
    e = _error(_body_spec(), files={"body.stl": stl_bytes(open_box)})
    assert e.field == "geometry.body" and "watertight" in e.message


def test_body_in_front_of_the_lip_is_refused():
    ahead = box((-20, -20, -150), (20, 20, 5))  # reaches 5 mm in front of the lip
    e = _error(_body_spec(), files={"body.stl": stl_bytes(ahead)})
    assert e.field == "geometry.body" and "z = 5" in e.message


def test_a_bad_scalar_is_named_before_the_body_is_read():
    e = _error({**_body_spec(), "cup_radius": -1}, files={})
    assert e.field == "cup_radius"


def test_unreadable_spec_file(tmp_path):
    p = tmp_path / "cup.json"
    p.write_text("{not json")
    with pytest.raises(InvalidGripperError, match="not valid JSON"):
        load_gripper(p)
    with pytest.raises(InvalidGripperError, match="cannot read"):
        load_gripper(tmp_path / "missing.json")
