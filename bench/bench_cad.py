"""What a gripper from CAD costs against the contract's boxes (issue 32): criteria (a)-(e) on the same parts.

    .venv/bin/python bench/bench_cad.py                  # thick ring and tless_04 at 10,000 points, 3 runs each
    .venv/bin/python bench/bench_cad.py --repeat 1 --points 5000

Grippers: the box gripper (examples/pgn-80.json with a grip force of 20 N), the V-groove example
(examples/pgn-80-vgroove.json) and the same V-groove with its finger subdivided to about 24,000 triangles (written to
a temporary folder). Each run is its own process, warm (a small job first, so numba's compiled code is loaded), with
mass 0.2 kg and the position tolerance on. Prints a Markdown table: (a)-(e) = pairs + collision (point test and
mesh-exact check) + hold, medians over the runs, the ratio to the box gripper on the same part, the candidates, the
time to seat the grasps to export and judge them on their seats (graspgen.seating; CAD grippers only), the grasps
exported and the process's peak resident memory. The gripper's meshes are loaded and prepared in the measured run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"


def _fine_vgroove(folder: Path) -> Path:
    """The V-groove example with its finger subdivided (every triangle into 4, five times): same shape, ~24 k faces."""
    import trimesh

    spec = json.loads((ROOT / "examples" / "pgn-80-vgroove.json").read_text())
    src = ROOT / "examples"
    finger = trimesh.load(src / spec["geometry"]["finger"], force="mesh")
    for _ in range(5):
        finger = finger.subdivide()
    finger.export(folder / "finger.stl")
    body = trimesh.load(src / spec["geometry"]["body"], force="mesh")
    body.export(folder / "body.stl")
    spec["name"] = "pgn-80-vgroove-fine"
    spec["geometry"] = {**spec["geometry"], "finger": "finger.stl", "body": "body.stl"}
    (folder / "spec.json").write_text(json.dumps(spec))
    return folder / "spec.json"


def _child(spec: dict) -> dict:
    import resource
    import time

    import trimesh

    import graspgen
    from graspgen.examples import example_part
    from graspgen.gripper import GripperSpec
    from graspgen.parts import load_part

    gripper = GripperSpec.load(spec["gripper"])
    if gripper.grip_force is None:
        gripper = GripperSpec.from_dict({**gripper.to_dict(), "grip_force": 20.0})
    warm = trimesh.creation.box(extents=[0.03, 0.02, 0.02])
    graspgen.generate(warm, GripperSpec.load(ROOT / "examples" / "pgn-80.json"), units="m", points=500)
    part = example_part(spec["name"]) if spec["kind"] == "example" else load_part(spec["path"], units="mm")
    gripper = GripperSpec.load(spec["gripper"])  # loaded again: its meshes prepared in the measured run
    if gripper.grip_force is None:
        gripper = GripperSpec.from_dict({**gripper.to_dict(), "grip_force": 20.0})
    t0 = time.perf_counter()
    gs = graspgen.generate(part, gripper, points=spec["points"], mass_kg=0.2)
    wall = time.perf_counter() - t0
    st = gs.stats
    return {
        "wall": wall,
        "timings": st["timings_s"],
        "candidates": st["candidates"],
        "grasps": len(gs.grasps),
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _run(spec: dict) -> dict:
    code = f"import json, sys; sys.path.insert(0, {str(ROOT / 'bench')!r}); from bench_cad import _child; "
    code += f"print(json.dumps(_child(json.loads({json.dumps(json.dumps(spec))}))))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    parts = [{"kind": "example", "name": "thick-ring", "label": "thick ring"}]
    if (SHARED / "tless_04.stl").exists():
        parts.append({"kind": "file", "path": str(SHARED / "tless_04.stl"), "name": "tless_04", "label": "tless_04"})
    else:
        print(f"(tless_04 skipped: {SHARED} not found)")
    with tempfile.TemporaryDirectory() as tmp:
        grippers = {
            "boxes (pgn-80)": str(ROOT / "examples" / "pgn-80.json"),
            "V-groove (24 triangles)": str(ROOT / "examples" / "pgn-80-vgroove.json"),
            "V-groove (24,576 triangles)": str(_fine_vgroove(Path(tmp))),
        }
        print(f"points {args.points}, mass 0.2 kg, grip force 20 N, median of {args.repeat} processes; seconds\n")
        print(
            "| part | gripper | (a)-(e) s | x boxes | pairs | collision | of it mesh-exact | hold | candidates "
            "| seat s | grasps | peak MB |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for part in parts:
            base = None
            for label, path in grippers.items():
                runs = [_run({**part, "points": args.points, "gripper": path}) for _ in range(args.repeat)]

                def med(key, runs=runs):
                    return statistics.median(r["timings"].get(key, 0.0) for r in runs)

                core = statistics.median(
                    sum(r["timings"].get(k, 0.0) for k in ("pairs", "collision", "hold")) for r in runs
                )
                base = core if base is None else base
                peak = statistics.median(r["peak_mb"] for r in runs)
                print(
                    f"| {part['label']} | {label} | {core:.2f} | {core / base:.2f} | {med('pairs'):.3f} | "
                    f"{med('collision'):.3f} | {med('collision_mesh'):.3f} | {med('hold'):.3f} | "
                    f"{runs[0]['candidates']:,} | {med('seat'):.2f} | {runs[0]['grasps']} | {peak:.0f} |"
                )


if __name__ == "__main__":
    main()
