"""Fixtures shared by every test directory.

`shared_meshes` is the folder of permissive test meshes handed to developers and CI (`../shared/meshes` beside
the repository, see its MANIFEST.md). Tests that need it skip, with the path in the reason, when it is missing.

The service tests' fixtures (tests/services_conftest.py) are loaded here as the module `services_conftest`, without
putting tests/ on sys.path, where tests/graspgen/ would shadow the graspgen package; the conftest.py of tests/api,
integration, reliability and worker import its fixtures from it.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

# a hook: keeps --dist loadgroup's groups on one worker under pytest >= 9.2 (tests/xdist_groups.py says why)
from tests.xdist_groups import pytest_collection_modifyitems  # noqa: F401

if "services_conftest" not in sys.modules:
    _spec = importlib.util.spec_from_file_location("services_conftest", Path(__file__).parent / "services_conftest.py")
    _module = importlib.util.module_from_spec(_spec)
    sys.modules["services_conftest"] = _module
    _spec.loader.exec_module(_module)

#: ../shared/meshes relative to the repository root (this file is tests/conftest.py)
SHARED_MESHES = (Path(__file__).resolve().parents[1].parent / "shared" / "meshes").resolve()


def shared_meshes_dir() -> Path:
    """The shared mesh folder, or skip the calling test with a clear reason when it is not there."""
    if not SHARED_MESHES.is_dir():
        pytest.skip(f"shared test meshes not found at {SHARED_MESHES} (expected ../shared/meshes beside the repo)")
    return SHARED_MESHES


@pytest.fixture(scope="session")
def shared_meshes() -> Path:
    """Path to ../shared/meshes; skips the test when the folder is missing."""
    return shared_meshes_dir()


def _winding_numbers(mesh, queries):
    """Generalised winding numbers (k,) of a closed triangle mesh at query points (k, 3).

    About 1 inside and 0 outside when the faces are wound with outward normals, about -1 inside when inverted
    (van Oosterom & Strackee solid angles). Independent of trimesh's own orientation logic.
    """
    import numpy as np

    tri = np.asarray(mesh.triangles)[None, :, :, :] - np.asarray(queries, dtype=float)[:, None, None, :]
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
    det = np.einsum("...i,...i->...", a, np.cross(b, c))
    div = (
        la * lb * lc
        + np.einsum("...i,...i->...", a, b) * lc
        + np.einsum("...i,...i->...", b, c) * la
        + np.einsum("...i,...i->...", c, a) * lb
    )
    return (2.0 * np.arctan2(det, div)).sum(axis=1) / (4.0 * np.pi)


@pytest.fixture(scope="session")
def winding_numbers():
    """`f(mesh, queries) -> (k,)` generalised winding numbers: ~1 inside, ~0 outside for outward normals."""
    return _winding_numbers
