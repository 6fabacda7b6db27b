"""The `graspgen` CLI: exit 0 / 2 / 1, one-line reasons, no output files on bad input, a readable recording."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh

from graspgen.cli import DEMO_GRIPPER, main
from graspgen.params import COLLISION_MODES, HOLD_MODES, SELECT_MODES, Params, QualityOptions

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "meshes"


@pytest.fixture()
def files(tmp_path):
    mesh = tmp_path / "box.stl"
    trimesh.creation.box(extents=[40, 30, 20]).export(mesh)  # millimetres
    gripper = tmp_path / "gripper.json"
    gripper.write_text(json.dumps(DEMO_GRIPPER))
    return tmp_path, mesh, gripper


def _run(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_generate_writes_all_outputs(files, capsys):
    tmp, mesh, gripper = files
    code, out, err = _run(
        [
            "generate",
            mesh,
            "--units",
            "mm",
            "--gripper",
            gripper,
            "--points",
            800,
            "--k1",
            3,
            "--k2",
            2,
            "--out",
            tmp / "g.json",
            "--candidates",
            tmp / "c.npz",
            "--recording",
            tmp / "r.rrd",
        ],
        capsys,
    )
    assert code == 0, err
    d = json.loads((tmp / "g.json").read_text())
    assert d["format"] == "graspgen.grasp_set/1" and len(d["grasps"]) == 6
    assert d["object"]["source_units"] == "mm" and d["object"]["name"] == "box"
    assert (tmp / "c.npz").stat().st_size > 0
    assert "candidates" in out and "rejected: friction" in out
    assert not list(tmp.glob(".*.tmp"))  # no temporary left behind
    # the recording reads back
    rerun = shutil.which("rerun", path=str(Path(sys.executable).parent))
    assert rerun, "the rerun CLI ships with rerun-sdk"
    r = subprocess.run(
        [rerun, "rrd", "verify", str(tmp / "r.rrd")],
        capture_output=True,
        text=True,
        env={"RERUN_ANALYTICS": "off", "PATH": "/usr/bin:/bin"},
        timeout=120,
    )
    assert r.returncode == 0, r.stderr


def test_missing_units_shows_extents_under_each_unit(files, capsys):
    tmp, mesh, gripper = files
    code, out, err = _run(["generate", mesh, "--gripper", gripper, "--out", tmp / "g.json"], capsys)
    assert code == 2
    line = err.strip()
    assert "\n" not in line and "--units is required" in line
    assert "as mm: 40 x 30 x 20 mm" in line and "as in: 1016 x 762 x 508 mm" in line
    assert not (tmp / "g.json").exists()


@pytest.mark.parametrize(
    "change, message",
    [
        ({"stroke": -1}, "stroke must be > 0"),
        ({"stroke": 80}, "lengths are in metres"),
        ({"name": "Bad Name"}, "not a slug"),
        ({"strok": 0.1}, "unknown fields strok"),
    ],
)
def test_bad_gripper_exits_2_and_writes_nothing(files, capsys, change, message):
    tmp, mesh, gripper = files
    gripper.write_text(json.dumps({**DEMO_GRIPPER, **change}))
    code, out, err = _run(
        [
            "generate",
            mesh,
            "--units",
            "mm",
            "--gripper",
            gripper,
            "--out",
            tmp / "g.json",
            "--candidates",
            tmp / "c.npz",
        ],
        capsys,
    )
    assert code == 2 and message in err and err.count("\n") == 1
    assert not (tmp / "g.json").exists() and not (tmp / "c.npz").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--points", "10"], "points must be between"),
        (["--rolls", "100"], "rolls must be between"),
        (["--safety-factor", "0.9"], "safety_factor must be"),
        (["--friction", "0"], "friction must be"),
        (["--collision", "magic"], "invalid choice"),
    ],
)
def test_bad_parameters_exit_2(files, capsys, args, message):
    tmp, mesh, gripper = files
    code, out, err = _run(
        ["generate", mesh, "--units", "mm", "--gripper", gripper, "--out", tmp / "g.json", *args], capsys
    )
    assert code == 2 and message in err
    assert not (tmp / "g.json").exists()


def test_run_options_are_the_params_fields_with_their_defaults():
    from graspgen.cli import _parser, _quality_kwargs, _run_kwargs

    for command in (["generate", "part.stl", "--gripper", "g.json", "--out", "o.json"], ["demo"]):
        args = _parser().parse_args(command)
        assert Params(**_run_kwargs(args)) == Params()
        assert QualityOptions(**_quality_kwargs(args)) == QualityOptions()
    args = _parser().parse_args(["demo", "--mass", "0.2", "--position-tolerance", "0", "--inside", "--k2", "3"])
    assert Params(**_run_kwargs(args)) == Params(mass_kg=0.2, position_tolerance=0.0, inside=True, k2=3)


@pytest.mark.parametrize(
    "flag, modes", [("--collision", COLLISION_MODES), ("--hold", HOLD_MODES), ("--select", SELECT_MODES)]
)
def test_choices_are_the_modules_own(files, capsys, flag, modes):
    tmp, mesh, gripper = files
    code, out, err = _run(
        ["generate", mesh, "--units", "mm", "--gripper", gripper, "--out", tmp / "g.json", flag, "x"], capsys
    )
    assert code == 2 and "invalid choice" in err and err.count("\n") == 1
    assert all(repr(m) in err for m in modes)


def test_mass_and_density_exclude_each_other(files, capsys):
    tmp, mesh, gripper = files
    argv = ["generate", mesh, "--units", "mm", "--gripper", gripper, "--out", tmp / "g.json"]
    code, out, err = _run([*argv, "--mass", "0.1", "--density", "1000"], capsys)
    assert code == 2 and "not allowed with argument --mass" in err and err.count("\n") == 1
    assert not (tmp / "g.json").exists()


def test_unreadable_mesh_exits_2(files, capsys):
    tmp, mesh, gripper = files
    bad = tmp / "bad.stl"
    bad.write_bytes(b"")
    code, out, err = _run(["generate", bad, "--units", "mm", "--gripper", gripper, "--out", tmp / "g.json"], capsys)
    assert code == 2 and err.startswith("graspgen: error:")
    assert not (tmp / "g.json").exists()
    code, out, err = _run(
        ["generate", tmp / "missing.stl", "--units", "mm", "--gripper", gripper, "--out", tmp / "g.json"], capsys
    )
    assert code == 2


@pytest.mark.skipif(not (SHARED / "bad").is_dir(), reason="../shared/meshes/bad is not present")
@pytest.mark.parametrize("name", ["empty.stl", "truncated_angle_block.stl", "idler_riser_binary_stl.obj"])
def test_shared_bad_meshes_exit_2(files, capsys, name):
    tmp, _, gripper = files
    code, out, err = _run(
        ["generate", SHARED / "bad" / name, "--units", "mm", "--gripper", gripper, "--out", tmp / "g.json"], capsys
    )
    assert code == 2 and err.count("\n") == 1
    assert not (tmp / "g.json").exists()


def test_no_grasps_says_why(tmp_path, capsys):
    mesh = tmp_path / "big.stl"
    trimesh.creation.box(extents=[120, 110, 100]).export(mesh)
    g = tmp_path / "g.json"
    g.write_text(json.dumps(DEMO_GRIPPER))
    code, out, err = _run(
        ["generate", mesh, "--units", "mm", "--gripper", g, "--points", 500, "--out", tmp_path / "o.json"], capsys
    )
    assert code == 0
    assert "no grasps: the part is wider than the stroke (80.0 mm) everywhere" in err
    assert json.loads((tmp_path / "o.json").read_text())["grasps"] == []


def test_console_script_runs(files):
    tmp, mesh, gripper = files
    exe = Path(sys.executable).parent / "graspgen"
    r = subprocess.run(
        [
            str(exe),
            "generate",
            str(mesh),
            "--units",
            "mm",
            "--gripper",
            str(gripper),
            "--points",
            "400",
            "--out",
            str(tmp / "x.json"),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout == "" and "[" not in r.stderr  # quiet, and no progress bar off a terminal
    r = subprocess.run([str(exe), "generate"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2


def test_service_commands_without_the_service_exit_2(capsys):
    from graspgen.cli import _service_main

    code = _service_main(["migrate"], group="graspgen.no-such-service")  # what an install without the service sees
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.strip() == "graspgen: the service is not installed: pip install 'graspgen[service]'"


def test_service_commands_without_the_service_extra_exit_2(tmp_path, monkeypatch, capsys):
    import services.cli

    # the package is there (one distribution) but a dependency of the `service` extra is not
    monkeypatch.setattr(services.cli, "_REQUIRED", ("sqlalchemy", "graspgen_no_such_module"))
    monkeypatch.setenv("GRASPGEN_STORAGE_DIR", str(tmp_path / "var"))
    assert main(["migrate"]) == 2
    out, err = capsys.readouterr()
    assert "graspgen_no_such_module missing" in err and "pip install 'graspgen[service]'" in err
    assert not (tmp_path / "var").exists()  # nothing written


def test_the_service_is_found_through_its_entry_point():
    from importlib.metadata import entry_points

    from graspgen.cli import SERVICE_GROUP

    (ep,) = entry_points(group=SERVICE_GROUP, name="cli")
    assert ep.value == "services.cli:main"


_BLOCK_VALIDATE_EXTRA = """
import sys
class _Block:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("mujoco", "coacd", "services", "fastapi", "sqlalchemy", "celery"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, _Block())
from graspgen.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_the_library_runs_without_the_validate_and_service_extras(files):
    tmp, mesh, gripper = files
    argv = [mesh, "--units", "mm", "--gripper", gripper, "--points", 400, "--out", tmp / "x.json", "--quiet"]
    r = subprocess.run(
        [sys.executable, "-c", _BLOCK_VALIDATE_EXTRA, "generate", *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp,
    )
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp / "x.json").read_text())["format"] == "graspgen.grasp_set/1"
    r = subprocess.run(
        [sys.executable, "-c", _BLOCK_VALIDATE_EXTRA, "serve"], capture_output=True, text=True, timeout=60, cwd=tmp
    )
    assert r.returncode == 2 and "pip install 'graspgen[service]'" in r.stderr
    argv[-2:-1] = [tmp / "v.json", "--validate"]
    r = subprocess.run(
        [sys.executable, "-c", _BLOCK_VALIDATE_EXTRA, "generate", *map(str, argv), "--mass", "0.1"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp,
    )
    assert r.returncode == 2 and not (tmp / "v.json").exists()
    assert "validate needs coacd: pip install 'graspgen[validate]'" in r.stderr
