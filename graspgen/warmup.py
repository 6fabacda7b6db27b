"""Compile every numba kernel into numba's on-disk cache before the first real job (issue 16.5, no cold start).

After a fresh install the first `generate()` compiles about thirty kernels (50-90 s on the project's machines);
every kernel is declared with `cache=True`, so once compiled it is loaded from disk by any later process. `warmup()`
runs the code paths that production runs, on small inputs, so that each kernel is compiled with the argument types
it will see: `generate()` on a mesh in both collision modes, inside grasps, quality selection, the hold criterion
(when this version of graspgen has it), a point cloud without normals (normal estimation), re-clustering, the
renderer, the memory probe and the validation's approach test of a CAD gripper's solids. `graspgen warmup`
(scripts/setup.sh, services/Dockerfile) calls it.

Where the cache lives: `NUMBA_CACHE_DIR` when set, otherwise `__pycache__` beside each module. The cache is valid
for this CPU and these sources (numba checks both), so build it on the machine, or the image, that runs the jobs.
"""

from __future__ import annotations

import dataclasses
import inspect
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

__all__ = ["warmup", "cache_dir"]


def cache_dir() -> Path:
    """Where numba writes this package's cache files."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    return Path(env) if env else Path(__file__).resolve().parent / "__pycache__"


def _cache_files(root: Path) -> int:
    return sum(1 for _ in root.rglob("*.nbi")) if root.is_dir() else 0


def warmup(*, log: Any = None) -> dict[str, Any]:
    """Run every kernel once on small inputs; returns {"seconds", "cache_dir", "index_files", "steps"}.

    `log(message)` is called before each step.
    """
    from .examples import EXAMPLE_GRIPPER, example_part
    from .gripper import GripperSpec
    from .memory import probe
    from .parts import load_part
    from .pipeline import generate, recluster
    from .render import render_grasp_set

    say = log or (lambda message: None)
    t_all = time.perf_counter()
    steps: list[tuple[str, float]] = []

    def step(name: str, fn: Any) -> Any:
        say(name)
        t0 = time.perf_counter()
        out = fn()
        steps.append((name, time.perf_counter() - t0))
        return out

    part = example_part("ring-screw")
    small: dict[str, Any] = {"points": 600, "k1": 3, "k2": 2}
    gs = step("generate, swept", lambda: generate(part, EXAMPLE_GRIPPER, **small))
    step("generate, paper, inside", lambda: generate(part, EXAMPLE_GRIPPER, collision="paper", inside=True, **small))
    step("generate, best-near-medoid", lambda: generate(part, EXAMPLE_GRIPPER, select="best-near-medoid", **small))
    # criterion (e) hold, where this version of graspgen has it
    has_force = "grip_force" in {f.name for f in dataclasses.fields(GripperSpec)}
    if has_force and "mass_kg" in inspect.signature(generate).parameters:
        gripper = {**EXAMPLE_GRIPPER, "grip_force": 20.0}  # hold is off without a grip force
        step("generate, hold", lambda: generate(part, gripper, mass_kg=0.2, **small))
    rng = np.random.default_rng(0)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.02)
    cloud, _ = trimesh.sample.sample_surface_even(sphere, 800, seed=rng)
    step("point cloud", lambda: generate(load_part(_npz(cloud), units="m", file_type="npz"), EXAMPLE_GRIPPER, **small))
    step("recluster", lambda: recluster(gs.candidates, gs.to_json(), k1=2, k2=2, select="best-near-medoid", mesh=part))
    step("render", lambda: render_grasp_set(part.surface_mesh(), gs.to_json(), size=(64, 48)))
    step("memory probe", lambda: probe(part, EXAMPLE_GRIPPER))
    # the small runs above assign clusters serially; a real part's candidates take the parallel kernel
    from .clustering import compile_parallel_kernels

    step("clustering, parallel assignment", compile_parallel_kernels)
    step("validation, a CAD gripper's approach", _sweep)
    step("generate, a gripper from CAD", lambda: generate(part, _cad_gripper(), mass_kg=0.2, **small))
    plate = trimesh.creation.box(extents=[0.08, 0.08, 0.02])
    cup_run: dict[str, Any] = {"units": "m", "mass_kg": 0.2, "max_tilt_deg": 5, **small}
    for label, cup in (("a suction cup", _cup(body=False)), ("a suction cup with a body", _cup(body=True))):
        step(f"generate, {label}", lambda cup=cup: generate(plate, cup, **cup_run))
    root = cache_dir()
    return {
        "seconds": time.perf_counter() - t_all,
        "cache_dir": str(root),
        "index_files": _cache_files(root),
        "steps": steps,
    }


def _cad_gripper() -> Any:
    """A small gripper from CAD (box-shaped finger and body meshes, made here): its collision, seat and hold
    kernels are the ones a CAD job runs."""
    import io

    from .gripper import GripperSpec

    def stl(extents: list[float], centre: list[float]) -> bytes:
        box = trimesh.creation.box(extents=extents)
        box.apply_translation(centre)
        buf = io.BytesIO()
        box.export(buf, file_type="stl")
        return buf.getvalue()

    spec = {
        "name": "warmup-cad",
        "stroke": 0.08,
        "friction": 0.5,
        "pregrasp_clearance": 0.02,
        "grip_force": 20.0,
        "geometry": {"units": "m", "finger": "finger.stl", "body": "body.stl"},
    }
    files = {"finger.stl": stl([0.01, 0.02, 0.03], [0.005, 0, 0]), "body.stl": stl([0.1, 0.03, 0.02], [0, 0, -0.025])}
    return GripperSpec.from_dict(spec, files=files)


def _cup(*, body: bool) -> Any:
    """A 30 mm suction cup with a cylinder tool, or with a box-shaped body mesh (made here): the suction kernels a
    job runs, the per-roll body test included."""
    import io

    from .examples import EXAMPLE_CUP
    from .suction import SuctionSpec

    if not body:
        return SuctionSpec.from_dict(dict(EXAMPLE_CUP))
    spec = {k: v for k, v in EXAMPLE_CUP.items() if k != "tool"}
    box = trimesh.creation.box(extents=[0.03, 0.02, 0.1])
    box.apply_translation([0.005, 0, -0.07])
    buf = io.BytesIO()
    box.export(buf, file_type="stl")
    geometry = {"units": "m", "body": "body.stl"}
    return SuctionSpec.from_dict({**spec, "geometry": geometry}, files={"body.stl": buf.getvalue()})


def _sweep() -> None:
    """The kernels that test a CAD gripper's solids on their way in (physics validation)."""
    from .meshsweep import SweptMesh

    solid = SweptMesh.of(trimesh.creation.box(extents=(0.01, 0.02, 0.03)).triangles, 0.001)
    points = np.random.default_rng(0).uniform(-0.02, 0.02, size=(64, 3))
    solid.hits(points, 0.01)
    solid.contains(points)


def _npz(points: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, points=points)
    return buf.getvalue()
