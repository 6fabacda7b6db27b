"""The review page's sources: its JavaScript unit tests (node --test), its NPZ reader against NumPy on the files
graspgen writes, and the checked-in build (services/api/ui/) against a fresh build from ui/ with the locked
dependencies (ui/package-lock.json): the shipped page is what the sources make, byte for byte."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from graspgen.export import npz_bytes

ROOT = Path(__file__).resolve().parents[2]
UI = ROOT / "ui"
BUILT = ROOT / "services" / "api" / "ui"


def _node() -> str:
    node = shutil.which("node")
    if node is None:
        pytest.skip("node not found: the review page's sources cannot be tested or built here (scripts/setup.sh)")
    if not (UI / "node_modules" / "fflate").is_dir():
        pytest.skip("ui/node_modules is missing: run `npm ci` in ui/ (scripts/setup.sh does)")
    return node


def test_javascript_unit_tests_pass():
    node = _node()
    run = subprocess.run([node, "--test", "test/"], cwd=UI, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert "# fail 0" in run.stdout and "# pass " in run.stdout


@pytest.mark.parametrize("reader", ["fflate", "native"])
@pytest.mark.parametrize("writer", ["graspgen", "savez", "savez_compressed"])
def test_the_page_reads_npz_files_as_numpy_does(writer, reader, tmp_path):
    node = _node()
    rng = np.random.default_rng(3)
    arrays = {
        "contacts": rng.normal(size=(5, 2, 3)),
        "free_rolls": rng.random((5, 16)) > 0.5,
        "labels": rng.integers(0, 9, size=(5, 2)).astype(np.int32),
        "medoids": np.array([4, 0, 2], dtype=np.int64),
        "roll_angles_rad": np.linspace(0, 2 * np.pi, 16, endpoint=False),
        "quality_terms": rng.random((5, 3)).astype(np.float32),
    }
    path = tmp_path / "c.npz"
    if writer == "graspgen":
        path.write_bytes(npz_bytes(arrays))
    else:
        getattr(np, writer)(path, **arrays)
    run = subprocess.run(
        [node, str(UI / "scripts" / "npz_dump.mjs"), str(path), "--reader", reader],
        cwd=UI,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    read = json.loads(run.stdout)
    assert set(read) == set(arrays)
    for name, a in arrays.items():
        assert read[name]["shape"] == list(a.shape), name
        assert read[name]["dtype"] == a.dtype.str, name
        np.testing.assert_array_equal(np.array(read[name]["values"], dtype=a.dtype), a.ravel(), err_msg=name)


def test_the_checked_in_build_is_what_the_sources_make(tmp_path):
    node = _node()
    vite = UI / "node_modules" / "vite" / "bin" / "vite.js"
    out = tmp_path / "ui"
    env = {**os.environ, "GRASPGEN_UI_OUT": str(out)}
    run = subprocess.run([node, str(vite), "build"], cwd=UI, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]

    def files(d: Path) -> dict[str, bytes]:
        return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}

    fresh, shipped = files(out), files(BUILT)
    stale = "services/api/ui/ is not the build of ui/: run `npm run build` in ui/ and commit services/api/ui/"
    assert sorted(fresh) == sorted(shipped), stale
    assert all(fresh[k] == shipped[k] for k in fresh), stale


@pytest.mark.parametrize("fmt", ["stl", "obj", "ply", "off", "glb", "npz"])
@pytest.mark.parametrize("units", ["mm", "in"])
def test_the_page_reads_parts_where_graspgen_does(fmt, units, tmp_path):
    """A part file read by the page (src/mesh.js, three.js' loaders) lies where graspgen's loader puts it: the same
    bounds in metres (the grasp poses are drawn on it) and the same triangles."""
    import trimesh

    from graspgen.parts import load_part

    node = _node()
    mesh = trimesh.creation.box(extents=(40.0, 30.0, 20.0))
    mesh.apply_translation((5.0, -3.0, 10.0))
    path = tmp_path / f"part.{fmt}"
    if fmt == "npz":
        np.savez(path, points=np.asarray(mesh.vertices), normals=np.asarray(mesh.vertex_normals))
    else:
        data = mesh.export(file_type=fmt)
        path.write_bytes(data if isinstance(data, bytes) else data.encode())
    part = load_part(path, units=units)
    run = subprocess.run(
        [node, str(UI / "scripts" / "mesh_dump.mjs"), str(path), fmt, units],
        cwd=UI,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    read = json.loads(run.stdout)
    ours = part.points if part.points is not None else np.asarray(part.mesh.vertices)
    np.testing.assert_allclose(read["min"], ours.min(axis=0), atol=1e-7)  # float32 in the browser
    np.testing.assert_allclose(read["max"], ours.max(axis=0), atol=1e-7)
    assert read["points"] == (fmt == "npz")
    assert read["triangles"] == (0 if fmt == "npz" else len(part.mesh.faces))
