"""Parts where a cup exports nothing: does the simulation find cups that hold there (issue 33's "no part left without
grasps that the simulation shows can be held")?

    .venv/bin/python bench/bench_suction_unexported.py                       # cup-30, 0.2 kg, 800 points a part
    .venv/bin/python bench/bench_suction_unexported.py --points 3000 --parts tless_04.stl paper/sileane_pepper.stl

For each part (default: the shared meshes on which cup-30 exports nothing at 9ce0834), `--points` surface points
(seeded) with the approach along the inward normal are sealed by the simulation's own seal
(`physics_suction.seal_at`, with its placement error); those that seal are simulated under the 13 settings
(`suction_perturbation_set`); those held under all 13 are judged by the criteria (`suction.judge_cups`: seal at the
pose and within the position tolerance, collision of cup and tool at any roll). Prints a Markdown table; no
assertions.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import graspgen  # noqa: E402
from graspgen import physics_suction as ps  # noqa: E402
from graspgen.suction import SuctionSpec, judge_cups  # noqa: E402
from graspgen.transforms import suction_frames  # noqa: E402

SHARED = ROOT.parent / "shared" / "meshes"
PARTS = (
    "tless_04.stl",
    "tless_10.stl",
    "tless_13.stl",
    "trimesh_angle_block.stl",
    "trimesh_idler_riser.stl",
    "trimesh_round.stl",
    "paper/sileane_pepper.stl",
    "paper/IPAGearShaft.stl",
    "paper/IPARingScrew.stl",
)


def _units(rel: str) -> str:
    folder = (SHARED / rel).parent
    table = json.loads((folder / "units.json").read_text()) if (folder / "units.json").exists() else {}
    return str(table.get(Path(rel).name, "mm"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cup", default=str(ROOT / "examples" / "cup-30.json"))
    ap.add_argument("--points", type=int, default=800)
    ap.add_argument("--mass", type=float, default=0.2)
    ap.add_argument("--parts", nargs="*", default=list(PARTS))
    args = ap.parse_args()
    cup = graspgen.load_gripper(args.cup)
    if not isinstance(cup, SuctionSpec):
        raise SystemExit(f"{args.cup} is not a suction cup")
    print(f"{args.cup}, {args.mass} kg, {args.points} points a part (seed 0)\n")
    print(
        "| part | simulation seals | held (all 13) | held cups, criterion seal at the pose | within the tolerance "
        "| clear of collision (a roll) |"
    )
    print("|---|---|---|---|---|---|")
    for rel in args.parts:
        if not (SHARED / rel).exists():
            print(f"| {rel} | (not found in {SHARED}) | | | | |")
            continue
        part = graspgen.load_part(SHARED / rel, units=_units(rel))
        mesh = part.mesh
        assert mesh is not None  # a mesh file's part
        sim = ps.prepare_suction_part(mesh, mass_kg=args.mass)
        pts, face = mesh.sample(args.points, return_index=True, seed=0)
        nrm = mesh.face_normals[face]
        poses = suction_frames(pts, -nrm, np.zeros(len(pts)))
        c = ps.SuctionCup.of(cup)
        idx = np.array([i for i in range(len(poses)) if ps.seal_at(sim, poses[i], c, key=i).ok], dtype=np.int64)
        if len(idx) == 0:
            print(f"| {rel} | 0 of {len(poses)} | - | - | - | - |")
            continue
        grid = ps.simulate_suction(sim, poses[idx], cup, perturbations=ps.suction_perturbation_set(0), keys=idx)
        kept = idx[ps.held(grid)]
        if len(kept) == 0:
            print(f"| {rel} | {len(idx)} of {len(poses)} | 0 | - | - | - |")
            continue
        at = judge_cups(mesh, cup, pts[kept], -nrm[kept], mass_kg=args.mass, position_tolerance=0.0).seal
        within = judge_cups(mesh, cup, pts[kept], -nrm[kept], mass_kg=args.mass)
        clear = int(np.sum(within.free_rolls.any(axis=1)))

        def tally(a: np.ndarray) -> str:
            names, counts = np.unique(a, return_counts=True)
            return ", ".join(f"{n} {k}" for n, k in zip(names, counts, strict=True))

        print(f"| {rel} | {len(idx)} of {len(poses)} | {len(kept)} | {tally(at)} | {tally(within.seal)} | {clear} |")


if __name__ == "__main__":
    main()
