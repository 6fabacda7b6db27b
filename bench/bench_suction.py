"""What the suction method costs (issue 33): 10,000 sample points of a part through seal, tilt, hold and collision,
then the two-stage clustering, with the shipped 30 mm cup (examples/cup-30.json; it seals nowhere on tless_04, a
40 mm round part, so most candidates stop at the seal's first probes) and the same cup at 20 mm (cup-20), a 0.2 kg
part; and a 200 x 200 x 20 mm plate, where most candidates seal (every probe cast, then hold, collision and
clustering).

    .venv/bin/python bench/bench_suction.py                  # tless_04, tless_20 and a plate, 3 runs each
    .venv/bin/python bench/bench_suction.py --repeat 1 --points 5000

Each run is its own process, warm (a small suction job first, so numba's compiled code is loaded from its cache).
Prints a Markdown table: criteria = seal + tilt + hold + collision (the per-candidate kernels), + cluster = the
issue's target (<= 1 s), total = generate() from the loaded part to the export (sampling and the triangle tree
included); medians over the runs; the candidates after each criterion; the process's peak resident memory (imports
and the compiled code included) and the growth of the peak during the measured run.
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


def _child(spec: dict) -> dict:
    import resource
    import time

    import trimesh

    import graspgen
    from graspgen.parts import load_part

    cup = graspgen.load_gripper(ROOT / "examples" / "cup-30.json")
    assert isinstance(cup, graspgen.SuctionSpec)
    if spec["cup"] != cup.name:  # the 20 mm cup: the same cup and vacuum, smaller
        cup = graspgen.SuctionSpec.from_dict(
            {**cup.to_dict(), "name": spec["cup"], "cup_radius": 0.01, "tool": {"radius": 0.008, "length": 0.12}}
        )
    warm = trimesh.creation.box(extents=[0.06, 0.06, 0.02])
    graspgen.generate(warm, cup, units="m", points=300, mass_kg=0.2, max_tilt_deg=spec.get("max_tilt_deg"))
    if spec["path"] == "plate":
        part = load_part(trimesh.creation.box(extents=[0.2, 0.2, 0.02]), units="m", name="plate")
    else:
        part = load_part(spec["path"], units="mm")
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    gs = graspgen.generate(part, cup, points=spec["points"], mass_kg=0.2, max_tilt_deg=spec.get("max_tilt_deg"))
    wall = time.perf_counter() - t0
    st = gs.stats
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {
        "wall": wall,
        "timings": st["timings_s"],
        "total": st["candidates_total"],
        "rejected": st["rejected"],
        "candidates": st["candidates"],
        "grasps": len(gs.grasps),
        "peak_mb": peak,
        "growth_mb": peak - before,
    }


def _run(spec: dict) -> dict:
    code = f"import json, sys; sys.path.insert(0, {str(ROOT / 'bench')!r}); from bench_suction import _child; "
    code += f"print(json.dumps(_child(json.loads({json.dumps(json.dumps(spec))}))))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    parts = [(name, SHARED / rel) for name, rel in (("tless_04", "tless_04.stl"), ("tless_20", "paper/tless_20.stl"))]
    found: list[tuple[str, Path | str]] = [(n, p) for n, p in parts if p.exists()]
    # a part where most candidates seal: the full seal (every probe), hold, collision and clustering run
    found.append(("plate 200x200x20 mm", "plate"))
    for n, p in parts:
        if not p.exists():
            print(f"({n} skipped: {p} not found)")
    print(f"{args.points} points, mass 0.2 kg, median of {args.repeat} processes\n")
    print(
        "| part | cup | tilt | approaches | seal | tilt | hold | collision | candidates | grasps | criteria s "
        "| + cluster s | total s | peak MB | growth MB |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, path in found:
        for cup, tilt in (("cup-30", None), ("cup-20", None), ("cup-20", 10.0)):
            spec = {"path": str(path), "points": args.points, "max_tilt_deg": tilt, "cup": cup}
            runs = [_run(spec) for _ in range(args.repeat)]

            def med(f, runs=runs):
                return statistics.median(f(r) for r in runs)

            crit = med(lambda r: sum(r["timings"].get(k, 0.0) for k in ("seal", "hold", "collision")))
            with_cluster = med(
                lambda r: sum(r["timings"].get(k, 0.0) for k in ("seal", "hold", "collision", "cluster"))
            )
            r0 = runs[0]
            rej = r0["rejected"]
            print(
                f"| {name} | {cup} | {'-' if tilt is None else f'{tilt:g} deg'} | {r0['total']:,} | {rej['seal']:,} | "
                f"{rej['tilt']:,} | {rej['hold']:,} | {rej['collision']:,} | {r0['candidates']:,} | {r0['grasps']} | "
                f"{crit:.3f} | {with_cluster:.3f} | {med(lambda r: r['timings']['total']):.3f} | "
                f"{med(lambda r: r['peak_mb']):.0f} | {med(lambda r: r['growth_mb']):.0f} |"
            )


if __name__ == "__main__":
    main()
