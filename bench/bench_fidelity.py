"""Does a grasp fail, or does the simulation's collision geometry fail it? (issue 14)

    .venv/bin/python bench/bench_fidelity.py [--parts sileane_pepper tless_13 ...] [--settings 0.08:24 0.04:48]

The simulation represents a non-convex part by CoACD's convex pieces (physics.SimConstants.coacd_threshold, the
concavity CoACD may leave, relative to the part's size, and coacd_max_hulls). A coarse decomposition bridges grooves
and recesses, so the simulated pads touch a hull where the real part has a groove. This bench exports each part's
grasps with criterion (e) (5,000 points, k = 8 x 2, 0.2 kg, 20 N, the bench_hold gripper), then judges the same
grasps with the nominal simulation and every member of `physics.perturbation_set(0)`, once per decomposition
setting `threshold:max_hulls`. Prints a Markdown table: pieces, time to decompose, grasps held nominally and under
every member. No assertions.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import bench_hold  # noqa: E402

import graspgen  # noqa: E402
from graspgen import physics  # noqa: E402
from graspgen.gripper import GripperSpec  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", nargs="*", default=["sileane_pepper", "tless_13", "trimesh_featuretype", "tless_10"])
    ap.add_argument("--settings", nargs="*", default=["0.08:24", "0.04:48"])
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    members = [physics.NOMINAL, *physics.perturbation_set(0)]
    print("| part | threshold | max hulls | pieces | decompose | grasps | held nominally | held under every member |")
    print("|---|---|---|---|---|---|---|---|")
    for label, part in bench_hold.parts(args.parts):
        gripper = bench_hold.gripper_for(part.mesh, 20.0)
        spec = GripperSpec.from_dict(gripper)
        gs = graspgen.generate(part, gripper, points=5000, k1=8, k2=2, seed=0, hold="any", mass_kg=0.2)
        c = gs.candidates
        idx = np.array([g["candidate"] for g in gs.grasps], dtype=np.int64)
        for setting in args.settings:
            const = bench_hold.judge_constants(setting)
            t0 = time.perf_counter()
            sim = physics.prepare_part(part.mesh, spec, mass_kg=0.2, seed=0, constants=const)
            t_prep = time.perf_counter() - t0
            if len(idx):
                grid = bench_hold.judge(sim, c, idx, members, args.workers)
                ok = np.array([[r.success for r in row] for row in grid], dtype=bool)
                nominal, every = int(ok[:, 0].sum()), int(ok.all(axis=1).sum())
            else:
                nominal = every = 0
            print(
                f"| {label} | {const.coacd_threshold:g} | {const.coacd_max_hulls} | {sim.pieces} | {t_prep:.1f} s | "
                f"{len(idx)} | {nominal} | {every} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
