"""The shipped example parts: closed, outward, positive volume, the advertised sizes, deterministic."""

from __future__ import annotations

import numpy as np
import pytest

from graspgen.errors import InvalidParameterError
from graspgen.examples import EXAMPLES, example_part, thick_ring

SIZES = {  # extents in metres
    "ring-screw": (0.021, 0.014, 0.0475),
    "bar": (0.120, 0.020, 0.010),
    "flanged-bushing": (0.032, 0.032, 0.020),
    "thick-ring": (0.060, 0.060, 0.020),
}


def test_the_four_examples_are_registered():
    assert set(EXAMPLES) == set(SIZES)


@pytest.mark.parametrize("name", sorted(SIZES))
def test_example_is_closed_with_positive_volume_and_its_size(name):
    mesh = EXAMPLES[name]()
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.volume > 0.0
    np.testing.assert_allclose(mesh.extents, SIZES[name], atol=1e-9)


@pytest.mark.parametrize("name", sorted(SIZES))
def test_example_normals_point_outward(name, winding_numbers):
    mesh = EXAMPLES[name]()
    rng = np.random.default_rng(0)
    faces = rng.choice(len(mesh.faces), size=min(300, len(mesh.faces)), replace=False)
    centre = mesh.triangles_center[faces]
    eps = 1e-5
    front = winding_numbers(mesh, centre + eps * mesh.face_normals[faces])
    back = winding_numbers(mesh, centre - eps * mesh.face_normals[faces])
    np.testing.assert_allclose(front, 0.0, atol=0.05)
    np.testing.assert_allclose(back, 1.0, atol=0.05)


def test_thick_ring_volume_is_the_annulus_volume():
    volume = np.pi * (0.030**2 - 0.010**2) * 0.020
    assert thick_ring().volume == pytest.approx(volume, rel=1e-3)  # 128 sections


def test_ring_screw_eye_is_a_separate_closed_body_above_the_shank():
    bodies = sorted(EXAMPLES["ring-screw"]().split(only_watertight=True), key=lambda b: b.bounds[0, 2])
    assert len(bodies) == 2
    shank, eye = bodies
    assert shank.bounds[1, 2] < eye.bounds[0, 2]  # no face of one lies inside the other
    assert all(b.volume > 0 for b in bodies)


@pytest.mark.parametrize("name", sorted(SIZES))
def test_example_part_is_deterministic_and_in_metres(name):
    a, b = example_part(name), example_part(name)
    assert a.name == name
    assert a.source_units == "m"
    assert a.watertight and a.warnings == ()
    assert len(a.sha256) == 64 and a.sha256 == b.sha256
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    np.testing.assert_allclose(a.extents, SIZES[name], atol=1e-9)


def test_example_hashes_differ():
    assert len({example_part(name).sha256 for name in EXAMPLES}) == len(EXAMPLES)


def test_unknown_example_is_rejected():
    with pytest.raises(InvalidParameterError, match="unknown example 'gear'.*thick-ring"):
        example_part("gear")
