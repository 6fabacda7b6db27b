"""The headless preview: a decodable PNG of the requested size, grippers drawn in their cluster colours."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import trimesh
from PIL import Image

import graspgen
from graspgen import render
from graspgen.cli import DEMO_GRIPPER, main
from graspgen.errors import InvalidParameterError
from graspgen.recording import cluster_colours

BOX = (0.04, 0.03, 0.02)


@pytest.fixture(scope="module")
def box_set():
    mesh = trimesh.creation.box(extents=BOX)
    return mesh, graspgen.generate(mesh, DEMO_GRIPPER, units="m", points=1000, k1=3, k2=1).to_json()


def _decode(png: bytes) -> np.ndarray:
    img = Image.open(io.BytesIO(png))
    img.load()
    assert img.format == "PNG" and img.mode == "RGB"
    return np.asarray(img).astype(int)


@pytest.mark.parametrize("size", [(320, 240), (501, 303)])
def test_png_decodes_with_the_requested_size(box_set, size):
    mesh, export = box_set
    img = _decode(render.render_grasp_set(mesh, export, size=size))
    assert img.shape == (size[1], size[0], 3)
    # something is drawn in every view: each quadrant holds non-background pixels
    h, w = img.shape[0] // 2, img.shape[1] // 2
    for q in (img[:h, :w], img[:h, w:], img[h:, :w], img[h:, w:]):
        assert np.sum(np.any(q < 200, axis=2)) > 50


def test_grippers_change_the_pixels_in_their_cluster_colour(box_set):
    mesh, export = box_set
    one = dict(export, grasps=[dict(export["grasps"][0], cluster=[2, 0])])
    none = dict(export, grasps=[])
    a = _decode(render.render_grasp_set(mesh, one, size=(400, 300)))
    b = _decode(render.render_grasp_set(mesh, none, size=(400, 300)))
    diff = np.abs(a - b).sum(axis=2) > 30
    assert diff.sum() > 500
    colour = cluster_colours(np.array([2]))[0].astype(float)
    drawn = a[diff].astype(float)
    # the changed pixels take the gripper's hue: their mean colour correlates with the cluster colour
    mean = drawn.mean(axis=0)
    assert np.corrcoef(mean, colour)[0, 1] > 0.8
    assert np.argmax(mean) == np.argmax(colour)
    # without grippers the part alone is grey: no strongly coloured pixels
    assert np.max(b.max(axis=2) - b.min(axis=2)) < 40


def test_rendering_is_deterministic(box_set):
    mesh, export = box_set
    assert render.render_grasp_set(mesh, export, size=(200, 160)) == render.render_grasp_set(
        mesh, export, size=(200, 160)
    )


def test_bad_sizes_are_refused(box_set):
    mesh, export = box_set
    with pytest.raises(InvalidParameterError):
        render.render_grasp_set(mesh, export, size=(8, 8))
    with pytest.raises(InvalidParameterError):
        render.parse_size("800 by 600")
    assert render.parse_size("640x480") == (640, 480)


def test_cli_render_and_preview(tmp_path, capsys):
    mesh = trimesh.creation.box(extents=[v * 1000 for v in BOX])
    mesh.export(tmp_path / "box.stl")
    (tmp_path / "g.json").write_text(json.dumps(DEMO_GRIPPER))
    code = main(
        [
            "generate",
            str(tmp_path / "box.stl"),
            "--units",
            "mm",
            "--gripper",
            str(tmp_path / "g.json"),
            "--points",
            "800",
            "--k1",
            "2",
            "--k2",
            "1",
            "--out",
            str(tmp_path / "out.json"),
            "--preview",
            str(tmp_path / "p.png"),
            "--quiet",
        ]
    )
    assert code == 0
    assert _decode((tmp_path / "p.png").read_bytes()).shape == (600, 800, 3)
    args = ["render", str(tmp_path / "out.json"), "--mesh", str(tmp_path / "box.stl"), "--units", "mm"]
    assert main([*args, "--out", str(tmp_path / "r.png"), "--size", "300x200"]) == 0
    assert _decode((tmp_path / "r.png").read_bytes()).shape == (200, 300, 3)
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "bad.png"), "--size", "300"]) == 2
    assert "size" in capsys.readouterr().err
    assert not (tmp_path / "bad.png").exists()
