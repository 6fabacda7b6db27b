"""The headless preview: a decodable PNG of the requested size, grippers drawn in their cluster colours."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import trimesh
from PIL import Image

import graspgen
import graspgen.kinds
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


def _cup_export(spec: dict, poses: list[np.ndarray]) -> dict:
    """A suction export (CONTRACT.md "Suction cups") with a grasp at each pose, all in translation cluster 1."""
    grasps = [
        {
            "pose": T.tolist(),
            "contacts": [T[:3, 3].tolist()],
            "normals": [(-T[:3, 2]).tolist()],
            "approach": T[:3, 2].tolist(),
            "free_rolls_deg": [0.0],
            "cluster": [1, 0],
            "cluster_size": 1,
        }
        for T in poses
    ]
    return {"format": "graspgen.grasp_set/1", "units": "m", "object": {"name": "plate"}, "gripper": spec,
            "params": {}, "stats": {}, "grasps": grasps}  # fmt: skip


def _from_above(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # +Z down into the plate's top face
    T[:3, 3] = (x, y, z)
    return T


def _coloured(img: np.ndarray) -> np.ndarray:
    return (img.max(axis=2) - img.min(axis=2)) > 40


def _runs(mask: np.ndarray) -> list[int]:
    """The widths of the coloured pixels in each row that has some."""
    return [int(np.ptp(np.flatnonzero(r))) + 1 for r in mask if r.any()]


@pytest.mark.parametrize("tool", ["cylinder", "body"])
def test_a_suction_cup_is_drawn_as_cup_and_tool(tool):
    """A 30 mm cup from above the centre of a 100 mm plate: in the front view the coloured pixels stand on the plate,
    as wide as the cup next to it and as wide as the tool (12 mm: a cylinder; 60 mm: a body) above the cup."""
    from graspgen.example_grippers import box, stl_bytes

    from ..grippers import CUP

    mesh = trimesh.creation.box(extents=(0.1, 0.1, 0.01))
    spec = dict(CUP, cup_height=0.03, tool={"radius": 0.006, "length": 0.09})
    gripper = None
    if tool == "body":
        spec = {k: v for k, v in spec.items() if k != "tool"}
        spec["geometry"] = {"units": "mm", "body": "body.stl"}
        gripper = graspgen.kinds.gripper_from_dict(
            spec, files={"body.stl": stl_bytes(box((-30, -30, -120), (30, 30, -30)))}
        )
    export = _cup_export(spec, [_from_above(0.0, 0.0, 0.005)])
    img = _decode(render.render_grasp_set(mesh, export, size=(800, 800), gripper=gripper))
    front = img[:400, 400:]  # the top-right tile: the front view (-Y), object +Z up
    mask = _coloured(front)
    rows = np.flatnonzero(mask.any(axis=1))
    assert len(rows) > 50, "the cup and tool are drawn"
    widths = _runs(mask)
    # the cup (30 mm) sits below the tool: its rows are the lowest ones; the tool's the highest
    cup, top = np.median(widths[-10:]), np.median(widths[:10])
    expected = 12 / 30 if tool == "cylinder" else 60 / 30
    assert top / cup == pytest.approx(expected, rel=0.15)
    # the whole stack is 120 mm tall and the cup 30 mm wide: heights follow the same scale
    assert (rows.max() - rows.min() + 1) / cup == pytest.approx(120 / 30, rel=0.1)
    colour = cluster_colours(np.array([1]))[0].astype(float)
    assert np.argmax(front[mask].mean(axis=0)) == np.argmax(colour)
