"""Memory guard (issue 16.4): graspgen.memory's estimate against the measured peak of real runs.

    .venv/bin/python bench/bench_memory.py                         # tless_04 and the thick ring at 5k/10k/30k points
    .venv/bin/python bench/bench_memory.py --points 5000 10000 30000 60000 --parts thick-ring

Each run is its own process, warm: the child first runs the pipeline on the same part at 1,000 points, so every
kernel is compiled or loaded as in a worker's process; then its peak RSS is reset (/proc/self/clear_refs 5, so the
compiler's memory is not counted) and the peak of the measured run read from VmHWM: interpreter, libraries and
numba's code included, as the estimate counts them ("base" is the RSS at the reset). The estimate is made in
another process from the same part and parameters, and timed (a probe run at graspgen.memory.PROBE_POINTS
points). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
GRIPPER = json.loads((ROOT / "examples" / "pgn-80.json").read_text())
PARTS = {"tless_04": ("file", str(SHARED / "tless_04.stl"), "mm"), "thick-ring": ("example", "thick-ring", "m")}


def _part(name: str):  # type: ignore[no-untyped-def]
    from graspgen.examples import example_part
    from graspgen.parts import load_part

    kind, where, units = PARTS[name]
    return example_part(where) if kind == "example" else load_part(where, units=units, name=name)


def _status_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise RuntimeError(field)


def _run(name: str, points: int) -> dict:
    import gc

    import graspgen

    part = _part(name)
    # warm on the same part: every kernel of this path is compiled (or loaded) before the measurement, and the
    # compiler's own memory is not counted: the peak is reset (clear_refs 5) once the process is warm
    graspgen.generate(part, GRIPPER, points=1000, k1=2, k2=1)
    gc.collect()
    Path("/proc/self/clear_refs").write_text("5")
    base = _status_kb("VmRSS") * 1024
    t0 = time.perf_counter()
    gs = graspgen.generate(part, GRIPPER, points=points)
    s = gs.stats
    rej = s["rejected"]
    return {
        "candidates": s["candidates"],
        # in flight through the collision stage: before the position tolerance's finer (c), as the probe counts
        "pairs": s["pairs_total"]
        - rej["stroke"]
        - rej["outside"]
        - rej["friction"]
        + s.get("exact", {}).get("friction_position_tolerance", 0),
        "seconds": time.perf_counter() - t0,
        "base_bytes": base,
        "peak_bytes": _status_kb("VmHWM") * 1024,
    }


def _estimate(name: str, points: list[int]) -> dict:
    import trimesh

    import graspgen
    from graspgen import memory

    graspgen.generate(trimesh.creation.box(extents=[0.03, 0.02, 0.02]), GRIPPER, units="m", points=500, k1=2, k2=1)
    part = _part(name)
    t0 = time.perf_counter()
    pr = memory.probe(part, GRIPPER)
    took = time.perf_counter() - t0
    return {
        "probe_s": took,
        "estimates": {str(n): pr.estimate(n).to_dict() for n in points},
        "max_points": {str(b): pr.max_points(b * 2**30) for b in (2, 4, 8)},
    }


def _child(args: list[str]) -> dict:
    out = subprocess.run(
        [sys.executable, __file__, "--child", json.dumps(args)], capture_output=True, text=True, cwd=ROOT, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, nargs="+", default=[5000, 10000, 30000])
    ap.add_argument("--parts", nargs="+", default=list(PARTS))
    ap.add_argument("--child")
    a = ap.parse_args()
    if a.child:
        kind, name, *rest = json.loads(a.child)
        res = _run(name, rest[0]) if kind == "run" else _estimate(name, rest)
        print(json.dumps(res))
        return
    print(
        "| part | points | pairs in flight est. | pairs | candidates est. | candidates | peak est. (MB) | "
        "base (MB) | peak measured (MB) | est. / measured | job s |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    notes = []
    for name in a.parts:
        est = _child(["estimate", name, *a.points])
        notes.append(
            f"{name}: probe {est['probe_s']:.2f} s; largest point count within 2 / 4 / 8 GiB: "
            + " / ".join(f"{v:,}" for v in est["max_points"].values())
        )
        for n in a.points:
            e = est["estimates"][str(n)]
            m = _child(["run", name, n])
            print(
                f"| {name} | {n:,} | {e['pairs']:,} | {m['pairs']:,} | {e['candidates']:,} | {m['candidates']:,} | "
                f"{e['peak_bytes'] / 2**20:,.0f} | {m['base_bytes'] / 2**20:,.0f} | {m['peak_bytes'] / 2**20:,.0f} | "
                f"{e['peak_bytes'] / m['peak_bytes']:.2f} | {m['seconds']:.1f} |",
                flush=True,
            )
    print()
    for line in notes:
        print(line)


if __name__ == "__main__":
    main()
