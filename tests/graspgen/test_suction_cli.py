"""`graspgen generate` with a suction cup, end to end: the shipped examples/cup-30.json on a shared mesh (export, NPZ,
recording), the grasp frame of the export, the same bytes again, and bad specs refused with exit 2 and no output."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from graspgen.cli import main

REPO = Path(__file__).resolve().parents[2]
CUP = REPO / "examples" / "cup-30.json"
PART = REPO.parent / "shared" / "meshes" / "paper" / "tless_20.stl"  # 83 x 75.5 x 47 mm, flat faces larger than 30 mm


def _without_timings(export: dict) -> dict:
    export = json.loads(json.dumps(export))
    export["stats"]["timings_s"] = {}
    return export


@pytest.mark.skipif(not PART.exists(), reason=f"shared mesh {PART} not found")
def test_generate_with_the_shipped_cup_on_a_shared_mesh(tmp_path, capsys):
    out, npz, rrd = tmp_path / "g.json", tmp_path / "c.npz", tmp_path / "r.rrd"
    args = ["generate", str(PART), "--units", "mm", "--gripper", str(CUP), "--mass", "0.2", "--points", "2000"]
    assert main([*args, "--out", str(out), "--candidates", str(npz), "--recording", str(rrd)]) == 0
    text = capsys.readouterr().out
    assert "rejected: seal" in text and "cup 30 mm" in text
    export = json.loads(out.read_text())
    assert export["format"] == "graspgen.grasp_set/1" and export["units"] == "m"
    assert export["gripper"] == json.loads(CUP.read_text()) and export["gripper"]["kind"] == "suction"
    assert set(export["stats"]["rejected"]) == {"seal", "tilt", "hold", "collision"}
    assert export["grasps"] and export["params"]["mass_kg"] == 0.2
    for g in export["grasps"]:
        T = np.asarray(g["pose"])
        R = T[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(T[:3, 3], g["contacts"][0], atol=1e-15)  # origin at the contact
        np.testing.assert_allclose(R[:, 2], g["approach"], atol=1e-15)  # +Z the approach, into the part
        np.testing.assert_allclose(R[:, 2], -np.asarray(g["normals"][0]), atol=1e-12)
        assert g["hold_margin"] >= 1 and g["seal_strain"] <= 0.1 + 1e-9 and len(g["free_rolls_deg"]) == 16
        # roll 0: X is the object's +X made orthogonal to Z (its +Y when |X . Z| > 0.9)
        ref = np.array([0.0, 1.0, 0.0]) if abs(R[0, 2]) > 0.9 else np.array([1.0, 0.0, 0.0])
        x0 = ref - (ref @ R[:, 2]) * R[:, 2]
        np.testing.assert_allclose(R[:, 0], x0 / np.linalg.norm(x0), atol=1e-12)
    with np.load(npz) as z:
        n = len(z["contacts"])
        assert (
            n == export["stats"]["candidates"] and z["contacts"].shape == (n, 1, 3) and z["normals"].shape == (n, 1, 3)
        )
        assert z["axes"].shape == (n, 3) and z["free_rolls"].shape == (n, 16) and z["hold_margin"].shape == (n,)
        np.testing.assert_allclose(np.linalg.norm(z["axes"], axis=1), 1.0)
        assert list(z["medoids"]) == [g["candidate"] for g in export["grasps"]]
    assert rrd.stat().st_size > 1000
    # the same input, parameters and seed: the same export but for the timings
    again = tmp_path / "again.json"
    assert main([*args, "--out", str(again), "--quiet"]) == 0
    assert _without_timings(json.loads(again.read_text())) == _without_timings(export)


@pytest.mark.parametrize(
    ("change", "words"),
    [({"cup_radius": -0.015}, "cup_radius must be > 0"), ({"vacuum": 6e5}, "atmosphere"), ({"colour": 1}, "unknown")],
)
def test_a_bad_spec_exits_2_and_writes_nothing(tmp_path, capsys, change, words):
    spec = tmp_path / "bad.json"
    spec.write_text(json.dumps({**json.loads(CUP.read_text()), **change}))
    part = tmp_path / "plate.stl"
    import trimesh

    trimesh.creation.box((100, 100, 10)).export(part)
    out = tmp_path / "out" / "g.json"
    code = main(["generate", str(part), "--units", "mm", "--gripper", str(spec), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_suction_refuses_a_preview_and_jaw_only_options(tmp_path, capsys):
    import trimesh

    part = tmp_path / "plate.stl"
    trimesh.creation.box((100, 100, 10)).export(part)
    base = ["generate", str(part), "--units", "mm", "--gripper", str(CUP), "--out", str(tmp_path / "g.json")]
    assert main([*base, "--preview", str(tmp_path / "p.png")]) == 2
    assert main([*base, "--inside"]) == 2
    assert "inside grasps are for jaws" in capsys.readouterr().err
    jaws = str(REPO / "examples" / "pgn-80.json")
    assert (
        main(
            [
                "generate",
                str(part),
                "--units",
                "mm",
                "--gripper",
                jaws,
                "--out",
                str(tmp_path / "j.json"),
                "--max-tilt-deg",
                "5",
            ]
        )
        == 2
    )
    assert not list(tmp_path.glob("*.json")) and not list(tmp_path.glob("*.png"))
