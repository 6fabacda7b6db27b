"""No cold start (issue 16.5): `graspgen warmup` fills numba's on-disk cache, and a later job compiles nothing."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: the CLI of whatever `graspgen` package is first on the path
CLI = [sys.executable, "-c", "import sys; from graspgen.cli import main; sys.exit(main())"]
#: modules whose kernels a generate job, a re-cluster or a preview runs
MODULES = ("antipodal", "_points", "_triangles", "clustering", "sampling", "quality", "coverage", "render", "parts")

pytestmark = pytest.mark.slow  # compiles every kernel from scratch (a minute or two)


def _cache_files(root: Path) -> dict[str, float]:
    return {str(p.relative_to(root)): p.stat().st_mtime for p in root.rglob("*") if p.suffix in (".nbi", ".nbc")}


def test_warmup_fills_an_empty_cache_and_a_job_afterwards_compiles_nothing(tmp_path):
    # a snapshot of the package: numba keys its cache on each source file's path and mtime, and this working tree
    # may be edited while the test runs; both processes import the snapshot
    src = tmp_path / "src"
    shutil.copytree(ROOT / "graspgen", src / "graspgen", ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "numba-cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(src)}
    run = subprocess.run([*CLI, "warmup"], env=env, capture_output=True, text=True, timeout=1800, cwd=src)
    assert run.returncode == 0, run.stderr
    assert (
        f"{src}/graspgen/warmup.py"
        in subprocess.run(
            [sys.executable, "-c", "import graspgen.warmup as w; print(w.__file__)"],
            env=env,
            capture_output=True,
            text=True,
            cwd=src,
        ).stdout
    )
    assert str(cache) in run.stdout and "index files" in run.stdout
    files = _cache_files(cache)
    for module in MODULES:
        assert any(Path(f).name.startswith(f"{module}.") and f.endswith(".nbi") for f in files), module
    assert sum(f.endswith(".nbc") for f in files) >= 25

    # a real job on another part, in a new process: every kernel comes from the cache, none is compiled again
    out = tmp_path / "grasps.json"
    job = subprocess.run(
        [
            *CLI,
            "generate",
            str(ROOT / "tests" / "reliability" / "corpus" / "meshes" / "good_box_mm.stl"),
            "--units",
            "mm",
            "--gripper",
            str(ROOT / "examples" / "pgn-80.json"),
            # enough candidates for the parallel cluster assignment, and criterion (e) on
            "--points",
            "8000",
            "--mass",
            "0.1",
            "--out",
            str(out),
            "--quiet",
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        cwd=src,
    )
    assert job.returncode == 0, job.stderr
    assert out.is_file()
    assert _cache_files(cache) == files  # no new or rewritten cache file: nothing was compiled
