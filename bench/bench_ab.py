"""graspgen.generate of another revision against this tree's, alternated in one process (same host phase, same
inputs): the before/after of a change to the kernels.

    .venv/bin/python bench/bench_ab.py --base 197af76            # thick ring and tless_04, 10,000 points, 7 pairs
    .venv/bin/python bench/bench_ab.py --base HEAD~3 --repeat 3 --points 5000

The base revision's `graspgen/` is exported with `git archive` into a temporary directory as the package
`graspgen_base` (its absolute imports rewritten), compiled into its own numba cache there, and warmed like this
tree's. Then each configuration runs base, this tree, base, this tree ... `--repeat` times. The cores are shared and
their speed drifts by tens of percent within minutes, so the table gives each side's minimum (the run least slowed
by other work) and the median of the paired ratios; the candidate and grasp counts must agree (the same answer).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
CONFIGS = {"paper (a)-(d)": {"hold": "off", "position_tolerance": 0.0}, "(a)-(e), tolerance": {"mass_kg": 0.2}}
STAGES = ("pairs", "collision", "hold")


def export_base(rev: str, into: Path, package: str = "graspgen_base") -> None:
    """The revision's graspgen/ as the package `package` under `into`."""
    data = subprocess.run(["git", "archive", rev, "graspgen"], cwd=ROOT, capture_output=True, check=True).stdout
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(into, filter="data")
    (into / "graspgen").rename(into / package)
    pattern = re.compile(r"\b(from|import) graspgen\b(?=[. \n])")
    for path in (into / package).rglob("*.py"):
        path.write_text(pattern.sub(rf"\1 {package}", path.read_text()))


def run(points: int, repeat: int) -> dict:
    import importlib

    import graspgen_base  # type: ignore[import-not-found]
    import trimesh

    import graspgen

    gripper = {**json.loads((ROOT / "examples" / "pgn-80.json").read_text()), "grip_force": 20.0}
    sides = {"base": graspgen_base, "this": graspgen}
    parts = {}
    for side, mod in sides.items():
        mod.generate(trimesh.creation.box(extents=[0.03, 0.02, 0.02]), gripper, units="m", points=500, mass_kg=0.1)
        examples = importlib.import_module(f"{mod.__name__}.examples")
        loading = importlib.import_module(f"{mod.__name__}.parts")
        parts[side] = {"thick ring": examples.example_part("thick-ring")}
        if (SHARED / "tless_04.stl").exists():
            parts[side]["tless_04"] = loading.load_part(SHARED / "tless_04.stl", units="mm")
    out: dict = {}
    for name in parts["this"]:
        for label, config in CONFIGS.items():
            rows: dict[str, list] = {"base": [], "this": []}
            for side, mod in sides.items():  # warm this configuration's code paths
                mod.generate(parts[side][name], gripper, points=points, **config)
            for _ in range(repeat):
                for side, mod in sides.items():
                    gs = mod.generate(parts[side][name], gripper, points=points, **config)
                    t = gs.stats["timings_s"]
                    rows[side].append(
                        {
                            "core": sum(t.get(k, 0.0) for k in STAGES),
                            "mesh": t.get("collision_mesh", 0.0),
                            "answer": (gs.stats["candidates"], len(gs.grasps)),
                        }
                    )
            out[f"{name} | {label}"] = rows
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", required=True, help="the revision to compare against (git rev)")
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        export_base(args.base, Path(tmp))
        sys.path[:0] = [tmp, str(ROOT)]
        res = run(args.points, args.repeat)
    rev = subprocess.run(["git", "rev-parse", "--short", args.base], cwd=ROOT, capture_output=True, text=True)
    print(f"base {rev.stdout.strip()} against this tree; {args.points} points, {args.repeat} alternated pairs\n")
    print(
        "| part | criteria | (a)-(e) base min s | this min s | this/base (min) | paired ratio median | "
        "mesh-exact base / this min s | same answer |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for key, rows in res.items():
        b, t = rows["base"], rows["this"]
        bmin, tmin = min(r["core"] for r in b), min(r["core"] for r in t)
        paired = statistics.median(y["core"] / x["core"] for x, y in zip(b, t, strict=True))
        same = all(r["answer"] == b[0]["answer"] for r in b + t)
        print(
            f"| {key} | {bmin:.3f} | {tmin:.3f} | {tmin / bmin:.2f} | {paired:.2f} | "
            f"{min(r['mesh'] for r in b):.3f} / {min(r['mesh'] for r in t):.3f} | {'yes' if same else 'NO'} |"
        )


if __name__ == "__main__":
    main()
