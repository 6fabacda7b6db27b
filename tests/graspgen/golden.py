"""Golden outputs: the CLI's export JSON and candidate NPZ for the shipped examples, reduced to content hashes.

The contract promises that the same input, parameters and seed give a byte-identical export, apart from the
wall-clock figures in `stats.timings_s`. Each case runs `graspgen generate` (or `graspgen demo`) in-process on a
shipped example part (graspgen/examples.py, written to STL or sampled into a point cloud) with the shipped gripper
(examples/pgn-80.json), and `digest()` reduces the outputs to hashes: the export with every timing set to 0, per
section and whole, and every NPZ array by name, dtype, shape and bytes. tests/golden/<case>.json holds the expected
digests; tests/graspgen/test_golden.py compares, scripts/regen_golden.py rewrites them (tests/golden/README.md).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[2]
GOLDEN_DIR = REPO / "tests" / "golden"
GRIPPER_FILE = REPO / "examples" / "pgn-80.json"


@dataclass(frozen=True)
class Case:
    """One CLI run: `part` is an example part name (or `cloud:NAME`, a point cloud sampled from it, in mm);
    `args`: the options after the part."""

    name: str
    command: str  # "generate" | "demo"
    part: str
    args: str  # the options, split at spaces


# small and fast (1,000-2,000 points), covering criterion (e) on (removing some, all or none) and off, mass and
# density, both collision modes, inside grasps, quality selection, a point cloud, and the demo's own part and gripper
CASES = (
    Case("demo-ring-screw", "demo", "ring-screw", "--points 1000"),
    Case("ring-screw-no-mass", "generate", "ring-screw", "--points 1500"),
    Case("ring-screw-mass", "generate", "ring-screw", "--points 1500 --mass 0.02"),
    Case("ring-screw-too-heavy", "generate", "ring-screw", "--points 1500 --mass 0.6"),  # (e) removes every one
    Case(
        "bar-density-paper",
        "generate",
        "bar",
        "--points 1200 --density 30000 --collision paper --rolls 8 --k1 6 --k2 3 --seed 7",
    ),
    Case(
        "thick-ring-best-near-medoid",
        "generate",
        "thick-ring",
        "--points 1000 --mass 0.5 --friction 0.4 --select best-near-medoid --k1 8 --k2 2",
    ),
    Case(
        "flanged-bushing-inside-hold-off",
        "generate",
        "flanged-bushing",
        "--points 1000 --inside --mass 0.01 --hold off --safety-factor 1.2 --position-tolerance 0 --accel 5",
    ),
    Case("cloud-thick-ring-density", "generate", "cloud:thick-ring", "--points 1200 --density 8000"),
)


def write_part(part: str, folder: Path) -> tuple[Path, str]:
    """The case's input file in `folder` and its units: an example part as binary STL (metres), or `cloud:NAME`
    as an NPZ point cloud (points and outward normals sampled from the example with a fixed seed, millimetres)."""
    import trimesh

    from graspgen.examples import EXAMPLES

    if part.startswith("cloud:"):
        mesh = EXAMPLES[part.removeprefix("cloud:")]()
        points, faces = trimesh.sample.sample_surface_even(mesh, 3000, seed=0)
        path = folder / f"{part.removeprefix('cloud:')}-cloud.npz"
        np.savez(path, points=points * 1000.0, normals=mesh.face_normals[faces])
        return path, "mm"
    path = folder / f"{part}.stl"
    EXAMPLES[part]().export(path)
    return path, "m"


def run_case(case: Case, folder: Path) -> tuple[Path, Path]:
    """Run the case's CLI command in-process; returns (export JSON, candidate NPZ). Raises if it fails."""
    from graspgen.cli import main

    folder.mkdir(parents=True, exist_ok=True)
    if case.command == "demo":
        out = folder / "demo"
        argv = ["demo", "--part", case.part, *case.args.split(), "--out-dir", str(out)]
        export, candidates = out / "grasps.json", out / "candidates.npz"
    else:
        mesh, units = write_part(case.part, folder)
        export, candidates = folder / "grasps.json", folder / "candidates.npz"
        argv = ["generate", str(mesh), "--units", units, "--gripper", str(GRIPPER_FILE), *case.args.split()]
        argv += ["--out", str(export), "--candidates", str(candidates), "--quiet"]
    code = main(argv)
    if code != 0:
        raise RuntimeError(f"golden case {case.name}: graspgen {' '.join(argv)} exited {code}")
    return export, candidates


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _dump(value: Any) -> str:
    """As GraspSet.to_json_bytes writes the export."""
    return json.dumps(value, indent=1, allow_nan=False)


def digest(export: Path, candidates: Path) -> dict[str, Any]:
    """Content hashes of one run's outputs: the export with its timings set to 0, and every NPZ array."""
    raw = export.read_bytes()
    doc = json.loads(raw)
    # parsing and dumping again gives the file's own bytes, so hashing the dump is hashing the file (timings aside)
    if (_dump(doc) + "\n").encode("utf-8") != raw:
        raise AssertionError(f"{export} is not in the export's canonical form (json.dumps(indent=1))")
    timings = doc["stats"]["timings_s"]
    doc["stats"]["timings_s"] = {k: 0.0 for k in timings}
    arrays = {}
    with np.load(candidates, allow_pickle=False) as z:
        for name in z.files:
            a = np.ascontiguousarray(z[name])
            arrays[name] = {"dtype": a.dtype.str, "shape": list(a.shape), "sha256": _sha(a.tobytes())}
    return {
        "export": {
            "sha256": _sha((_dump(doc) + "\n").encode("utf-8")),
            "sections": {k: _sha(_dump(v).encode("utf-8")) for k, v in doc.items()},
            "timing_keys": list(timings),
            "grasps": len(doc["grasps"]),
            "candidates": doc["stats"]["candidates"],
        },
        "candidates": arrays,
    }


def golden_path(case: Case) -> Path:
    return GOLDEN_DIR / f"{case.name}.json"


def golden_document(case: Case, folder: Path) -> dict[str, Any]:
    """What tests/golden/<case>.json holds: the case and its digest."""
    export, candidates = run_case(case, folder)
    return {
        "case": case.name,
        "command": case.command,
        "part": case.part,
        "args": case.args,
        **digest(export, candidates),
    }


def differences(expected: dict[str, Any], actual: dict[str, Any]) -> list[str]:
    """What differs between two golden documents, by name (empty when they are equal)."""
    out = []
    e, a = expected["export"], actual["export"]
    for key in sorted(set(e["sections"]) | set(a["sections"])):
        if e["sections"].get(key) != a["sections"].get(key):
            out.append(f"export section {key!r}")
    for key in ("timing_keys", "grasps", "candidates", "sha256"):
        if e[key] != a[key] and not out:
            out.append(f"export {key}: {e[key]} -> {a[key]}")
    if list(expected["candidates"]) != list(actual["candidates"]):
        out.append(f"NPZ members {list(expected['candidates'])} -> {list(actual['candidates'])}")
    for name in expected["candidates"]:
        if name in actual["candidates"] and expected["candidates"][name] != actual["candidates"][name]:
            out.append(f"NPZ array {name!r}")
    return out
