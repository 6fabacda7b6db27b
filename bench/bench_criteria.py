"""What criterion (e), the position tolerance and the mesh-exact collision check cost (issue 14).

    .venv/bin/python bench/bench_criteria.py                 # thick ring and tless_04 at 10,000 points, 3 runs each
    .venv/bin/python bench/bench_criteria.py --repeat 1 --points 5000

Each run is its own process, warm (it first runs the pipeline on a small box so numba's compiled code is loaded):
`graspgen.generate` with the paper's criteria only (hold off, no position tolerance) and with everything (mass
0.2 kg, grip force 20 N, tolerance 1 mm). The mesh-exact check runs in both (it is not optional). Prints a Markdown
table of the stage timings (medians over the runs) and the candidate counts. Each process also times a fixed
reference run (the thick ring at 2,000 points with (e)) before the measured one: the host's shared cores run 30-40 %
slower in some phases, and that column tells the phases apart.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
GRIPPER = {**json.loads((ROOT / "examples" / "pgn-80.json").read_text()), "grip_force": 20.0}
CONFIGS = {
    "paper (a)-(d)": {"hold": "off", "position_tolerance": 0.0},
    "(a)-(e), tolerance": {"mass_kg": 0.2},
}


def _child(spec: dict) -> dict:
    import time

    import trimesh

    import graspgen
    from graspgen.examples import example_part
    from graspgen.parts import load_part

    graspgen.generate(trimesh.creation.box(extents=[0.03, 0.02, 0.02]), GRIPPER, units="m", points=500, mass_kg=0.1)
    # the host's speed in this process (see the docstring)
    t0 = time.perf_counter()
    graspgen.generate(example_part("thick-ring"), GRIPPER, points=2000, mass_kg=0.2)
    reference = time.perf_counter() - t0
    part = example_part(spec["name"]) if spec["kind"] == "example" else load_part(spec["path"], units="mm")
    t0 = time.perf_counter()
    gs = graspgen.generate(part, GRIPPER, points=spec["points"], **spec["config"])
    wall = time.perf_counter() - t0
    st = gs.stats
    return {
        "wall": wall,
        "reference": reference,
        "timings": st["timings_s"],
        "candidates": st["candidates"],
        "rejected": st["rejected"],
        "exact": st["exact"],
    }


def _run(spec: dict) -> dict:
    code = f"import json, sys; sys.path.insert(0, {str(ROOT / 'bench')!r}); from bench_criteria import _child; "
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
    cols = ("pairs", "collision", "collision_mesh", "hold", "sample_mesh_tree")
    print(f"points {args.points}, median of {args.repeat} processes; seconds\n")
    print(
        "| part | criteria | (a)-(e) s | " + " | ".join(cols) + " | cluster | candidates | rejected hold | "
        "rejected tolerance | mesh rolls removed | host reference s |"
    )
    print("|" + "---|" * (9 + len(cols)))
    for part in parts:
        for label, config in CONFIGS.items():
            runs = [_run({**part, "points": args.points, "config": config}) for _ in range(args.repeat)]

            def med(key, runs=runs):
                return statistics.median(r["timings"].get(key, 0.0) for r in runs)

            core = statistics.median(
                sum(r["timings"].get(k, 0.0) for k in ("pairs", "collision", "hold")) for r in runs
            )
            r0 = runs[0]
            print(
                f"| {part['label']} | {label} | {core:.2f} | "
                + " | ".join(f"{med(k):.3f}" for k in cols)
                + f" | {med('cluster'):.2f} | {r0['candidates']:,} | {r0['rejected'].get('hold', 0):,} | "
                f"{r0['exact']['friction_position_tolerance']:,} | {r0['exact']['collision_mesh_rolls']:,} | "
                f"{statistics.median(r['reference'] for r in runs):.3f} |"
            )


if __name__ == "__main__":
    main()
