"""Every corpus entry through `graspgen generate` in a subprocess (CONTRACT.md, CLI): bad input exits 2 with exactly
one line on stderr that names the problem and writes no output file or directory; an accepted-with-warning mesh
exits 0 and prints the warning."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from corpus_cases import GOOD_GRIPPER, GOOD_MESH, corpus_params, says

GRASPGEN = str(Path(sys.executable).with_name("graspgen"))
#: the smallest run the parameters allow, for entries the CLI accepts
SMALL_RUN = ["--points", "200", "--k1", "2", "--k2", "1", "--rolls", "8"]


def _argv(case: dict[str, Any], out: Path) -> list[str]:
    mesh, gripper, extra = GOOD_MESH, GOOD_GRIPPER, list(SMALL_RUN)
    units: list[str] = ["--units", "mm"]
    if case["kind"] == "mesh":
        mesh = case["path"]
        units = [] if case["units"] is None else ["--units", case["units"]]
    elif case["kind"] == "gripper":
        gripper = case["path"]
    else:
        extra = []
        for key, value in case["params"].items():
            extra += [f"--{key.replace('_', '-')}", str(value)]
    return [
        GRASPGEN,
        "generate",
        str(mesh),
        *units,
        "--gripper",
        str(gripper),
        *extra,
        "--out",
        str(out / "grasps.json"),
        "--candidates",
        str(out / "candidates.npz"),
        "--recording",
        str(out / "run.rrd"),
        "--quiet",
    ]


def _tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


@pytest.mark.parametrize("case", corpus_params(slow_warn=True))
def test_cli(case, tmp_path):
    work = tmp_path / "cwd"
    work.mkdir()
    out = tmp_path / "out"  # does not exist: a refused run must not create it
    before = _tree(tmp_path)
    proc = subprocess.run(_argv(case, out), cwd=work, capture_output=True, text=True, timeout=300)
    err = proc.stderr
    assert "Traceback" not in err and 'File "' not in err, err
    if case["expect"] == "warn" or (case["expect"] == "reject-or-warn" and proc.returncode == 0):
        assert proc.returncode == 0, err
        assert all(s.lower() in err.lower() for s in says(case, api=False)), err
        assert (out / "grasps.json").is_file()
        return
    assert proc.returncode == 2, (proc.returncode, err)
    lines = err.rstrip("\n").split("\n")
    assert len(lines) == 1 and lines[0].startswith("graspgen: error: "), err
    for s in says(case, api=False):
        assert s.lower() in lines[0].lower(), (s, lines[0])
    assert proc.stdout == ""
    assert _tree(tmp_path) == before, "a refused run wrote files"
