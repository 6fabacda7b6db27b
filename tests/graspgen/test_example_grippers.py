"""The shipped CAD example grippers (examples/*.json, examples/<name>/*.stl) and the frames picture: reproduced byte
for byte by scripts/make_example_grippers.py, valid specs, and the shapes they claim to be."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from graspgen.example_grippers import EXAMPLE_GRIPPERS
from graspgen.gripper import GripperSpec

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("make_example_grippers", ROOT / "scripts/make_example_grippers.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_script_reproduces_the_committed_files_byte_for_byte():
    expected = _script().expected_files()
    assert len(expected) == 1 + 3 * len(EXAMPLE_GRIPPERS)
    for path, data in expected.items():
        assert path.is_file(), f"{path} is missing: run scripts/make_example_grippers.py"
        assert path.read_bytes() == data, f"{path} differs from what scripts/make_example_grippers.py writes"
    # and nothing else lies in the examples' mesh folders
    for name in EXAMPLE_GRIPPERS:
        on_disk = {p for p in (ROOT / "examples" / name).iterdir()}
        assert on_disk == {p for p in expected if p.parent == ROOT / "examples" / name}


@pytest.mark.parametrize("name", sorted(EXAMPLE_GRIPPERS))
def test_example_specs_load_from_their_folder(name):
    g = GripperSpec.load(ROOT / "examples" / f"{name}.json")
    assert g.name == name and g.geometry.units == "mm" and g.geometry.body is not None
    assert set(g.to_dict()["geometry"]["sha256"]) == {f"{name}/finger.stl", f"{name}/body.stl"}


def test_v_groove_seats_round_parts_of_12_to_22_mm_on_both_flanks():
    finger = GripperSpec.load(ROOT / "examples/pgn-80-vgroove.json").geometry.finger
    # a cylinder along Z of radius r, centred at (x_c, 0) in the finger frame with x_c = 8 - r sqrt(2) mm, touches
    # both flanks and nothing else: every vertex lies at or beyond r from the axis, and the two flank contact points
    # (at y = +-r / sqrt(2)) lie on the finger's surface
    for r in (0.0060, 0.0080, 0.0110):
        xc = 0.008 - r * np.sqrt(2)
        surface = finger.sample(20000, seed=0)
        d = np.hypot(surface[:, 0] - xc, surface[:, 1])
        assert d.min() >= r - 1e-4  # the part does not cut into the finger
        contacts = np.array([[xc + r / np.sqrt(2), s * r / np.sqrt(2), 0.0] for s in (1, -1)])
        _, dist, _ = finger.nearest.on_surface(contacts)
        np.testing.assert_allclose(dist, 0.0, atol=1e-9)


def test_stepped_finger_pad_is_the_narrow_tip():
    g = GripperSpec.load(ROOT / "examples/pgn-80-stepped.json")
    assert (g.geometry.pad_width, g.geometry.pad_depth) == pytest.approx((0.006, 0.018))
    assert g.finger_width == pytest.approx(0.024)  # the root's width, which the bounding box sees


def test_housing_is_wider_than_the_palm_box_of_the_same_fingers():
    g = GripperSpec.load(ROOT / "examples/pgn-80-housing.json")
    box = GripperSpec.load(ROOT / "examples/pgn-80.json")
    np.testing.assert_allclose(g.geometry.finger.extents, [box.finger_thickness, box.finger_width, box.finger_depth])
    palm = box.palm_box()
    assert g.geometry.body.extents[1] > 2.5 * palm.extents[1]
    assert g.geometry.body.bounds[1, 2] == pytest.approx(-box.finger_depth / 2)
