"""GripperSpec, Params, units and the grasp-frame helpers."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from graspgen.errors import InvalidGripperError, InvalidParameterError, InvalidUnitsError
from graspgen.gripper import GripperSpec
from graspgen.params import Params, QualityOptions
from graspgen.transforms import (
    grasp_frames,
    matrix_to_quaternion_xyzw,
    quaternion_xyzw_to_matrix,
    roll_angles_rad,
    roll_basis,
)
from graspgen.units import extents_under_each_unit, to_metres_scale

SPEC = {
    "name": "pgn-80",
    "stroke": 0.08,
    "finger_width": 0.02,
    "finger_depth": 0.03,
    "finger_thickness": 0.01,
    "friction": 0.5,
    "pregrasp_clearance": 0.02,
}


def test_gripper_defaults_and_round_trip(tmp_path):
    g = GripperSpec.from_dict(SPEC)
    assert g.min_width == 0.0 and g.palm_depth == 0.0 and g.palm_width == 0.02
    p = tmp_path / "g.json"
    p.write_text(json.dumps(g.to_dict()))
    assert GripperSpec.load(p) == g
    assert g.with_friction(0.3).friction == 0.3 and g.with_friction(None) is g


def test_gripper_boxes_follow_the_contract():
    g = GripperSpec.from_dict({**SPEC, "palm_depth": 0.02})
    f0, f1 = g.finger_boxes(0.03)
    # inner faces at x = -+w/2, centred at y = z = 0
    assert f0.center[0] + f0.extents[0] / 2 == pytest.approx(-0.015)
    assert f1.center[0] - f1.extents[0] / 2 == pytest.approx(0.015)
    assert f1.extents == (0.01, 0.02, 0.03)
    palm = g.palm_box()
    assert palm.center[2] + palm.extents[2] / 2 == pytest.approx(-0.015)  # z top at -finger_depth/2
    assert palm.extents[0] == pytest.approx(0.08 + 0.02)
    assert g.open_width(0.07) == 0.08 and g.open_width(0.03) == pytest.approx(0.05)
    assert GripperSpec.from_dict(SPEC).palm_box() is None


@pytest.mark.parametrize(
    "change, field",
    [
        ({"stroke": 0}, "stroke"),
        ({"stroke": float("nan")}, "stroke"),
        ({"stroke": "0.08"}, "stroke"),
        ({"min_width": 0.09}, "stroke"),
        ({"friction": 0}, "friction"),
        ({"finger_width": -0.01}, "finger_width"),
        ({"pregrasp_clearance": -0.001}, "pregrasp_clearance"),
        ({"finger_depth": 30}, "finger_depth"),
        ({"name": "../etc"}, "name"),
        ({"name": "Ünïcode"}, "name"),
        ({"extra": 1}, "extra"),
    ],
)
def test_gripper_rejects(change, field):
    with pytest.raises(InvalidGripperError) as e:
        GripperSpec.from_dict({**SPEC, **change})
    assert e.value.field == field


def test_gripper_missing_fields_and_bad_files(tmp_path):
    with pytest.raises(InvalidGripperError, match="lacks stroke"):
        GripperSpec.from_dict({k: v for k, v in SPEC.items() if k != "stroke"})
    with pytest.raises(InvalidGripperError, match="JSON object"):
        GripperSpec.from_dict([1, 2])
    (tmp_path / "bad.json").write_text("{nope")
    with pytest.raises(InvalidGripperError, match="not valid JSON"):
        GripperSpec.load(tmp_path / "bad.json")
    with pytest.raises(InvalidGripperError, match="cannot read"):
        GripperSpec.load(tmp_path / "missing.json")


def test_params_validation():
    assert Params().to_dict()["points"] == 10_000
    assert Params.from_dict({"k1": 3}).k1 == 3
    for bad in (
        {"points": 99},
        {"rolls": 0},
        {"rolls": 65},
        {"k1": 0},
        {"k2": 0},
        {"safety_factor": 0.99},
        {"friction": 0.0},
        {"collision": "x"},
        {"inside": "yes"},
        {"points": 1.5},
        {"seed": -1},
        {"nope": 1},
    ):
        with pytest.raises(InvalidParameterError):
            Params.from_dict(bad)


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"select": "best"}, "select must be one of medoid, best-near-medoid, got 'best'"),
        ({"select": 3}, "select must be one of medoid, best-near-medoid, got 3"),
        ({"validate": "yes"}, "validate must be true or false, got 'yes'"),
        ({"validate": 1}, "validate must be true or false, got 1"),
        ({"repair_limit": 65}, "repair_limit must be an integer 0..64, got 65"),
        ({"repair_limit": True}, "repair_limit must be an integer 0..64, got True"),
        ({"sim_workers": 0}, "sim_workers must be a positive integer, got 0"),
        ({"sim_workers": 2.0}, "sim_workers must be a positive integer, got 2.0"),
    ],
)
def test_quality_options_refuse_bad_values_naming_the_field(bad, message):
    with pytest.raises(InvalidParameterError) as err:
        QualityOptions(**bad)
    assert err.value.message == message and err.value.field == next(iter(bad))


def test_quality_options_of_a_job():
    rest, q = QualityOptions.split_job({"points": 600, "select": "best-near-medoid", "validate": False})
    assert rest == {"points": 600} and q == QualityOptions(select="best-near-medoid")
    assert q.job_dict() == {"select": "best-near-medoid"}  # only what differs from the defaults is stored
    assert QualityOptions(validate=True).job_dict() == {"validate": True}
    assert QualityOptions().job_dict() == {} and not QualityOptions().needs_part
    assert QualityOptions(select="best-near-medoid").needs_part and QualityOptions(validate=True).needs_part
    # repair_limit and sim_workers are not job options: they stay with the rest (and Params refuses them)
    assert QualityOptions.split_job({"repair_limit": 2})[0] == {"repair_limit": 2}


def test_units():
    assert to_metres_scale("mm") == 1e-3 and to_metres_scale(" IN ") == 0.0254
    for bad in (None, "", "km", "millimetre"):
        with pytest.raises(InvalidUnitsError):
            to_metres_scale(bad)
    line = extents_under_each_unit(np.array([40.0, 30.0, 20.0]))
    assert line.startswith("as mm: 40 x 30 x 20 mm") and "as m: 4e+04" in line


def test_roll_angles_and_basis():
    assert np.allclose(np.degrees(roll_angles_rad(16))[:3], [0, 22.5, 45])
    x = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, 0.6, 0.8]])
    y0, z0 = roll_basis(x)
    assert np.allclose(z0[0], [0, 0, 1])  # object +Z made orthogonal to X
    assert np.allclose(z0[1], [1, 0, 0])  # |X.z| > 0.9: object +X instead
    assert np.allclose(np.sum(y0 * x, axis=1), 0) and np.allclose(np.sum(z0 * x, axis=1), 0)
    assert np.allclose(y0, np.cross(z0, x))


@given(st.lists(st.floats(-1, 1), min_size=3, max_size=3), st.floats(0, 2 * np.pi))
def test_frames_are_right_handed_and_quaternions_round_trip(v, psi):
    x = np.array(v)
    if np.linalg.norm(x) < 1e-3:
        x = np.array([0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    T = grasp_frames(np.zeros((1, 3)), x[None], np.array([psi]))[0]
    R = T[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R[:, 0], x) and np.allclose(R[:, 1], np.cross(R[:, 2], R[:, 0]))
    q = matrix_to_quaternion_xyzw(R)
    assert q[3] >= 0 and np.isclose(np.linalg.norm(q), 1.0)
    assert np.allclose(quaternion_xyzw_to_matrix(q), R, atol=1e-12)
