"""Where do the rigid pads of criterion (e)'s exports bear, and does that single out the grasps that fail?

    .venv/bin/python bench/bench_bearing.py [--parts NAME ...] [--failed PART:CANDIDATE ...]

The exports of bench_hold's `hold` configuration (5,000 points, k = 8 x 2, seed 0, 0.2 kg, 20 N, bench_hold's
gripper per part). For each exported grasp, 400,000 samples of the part's surface (seed 1) are taken into the grasp
frame; under each pad's rectangle (|y| <= finger_width / 2, |z| <= finger_depth / 2) a rigid flat pad closing
along x bears where the surface reaches farthest towards it. Per pad: the rise (how far that lies beyond the
contact plane, mm) and the bearing set (samples within 0.05 mm of it, HoldModel.pad_compliance). Per grasp: the
gap between the two bearing sets' convex hulls, projected along x (the squeeze forces cannot lie on one line when
it is above 0: the two grip forces form a couple of grip_force x gap that friction must balance, which needs a
tangential force gap / width x grip_force at each pad, reported as a share of mu x grip_force), and the margin (e)
would have with that share taken off each contact's friction (margin x sqrt(1 - share^2)).

`--failed` names the exports that the simulation drops (default: the two that bench_hold's MuJoCo judge turns out
under the part's mass x1.5, docs/benchmarks_quality.md); the table gives their ranks. Prints Markdown; no
assertions.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_hold  # noqa: E402

from graspgen.gripper import GripperSpec  # noqa: E402
from graspgen.hold import HOLD  # noqa: E402

FAILED = ("meshes/trimesh_featuretype:741", "meshes/trimesh_idler_riser:131")
_ANGLES = np.linspace(0.0, np.pi, 360, endpoint=False)
_DIRS = np.stack([np.cos(_ANGLES), np.sin(_ANGLES)], axis=1)


def hull_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Distance between the convex hulls of 2D point sets a and b (0 when they overlap), from their projections on
    360 directions (the largest gap between the projections; within 0.01 % of the exact distance)."""
    pa, pb = a @ _DIRS.T, b @ _DIRS.T
    gap = np.maximum(pb.min(axis=0) - pa.max(axis=0), pa.min(axis=0) - pb.max(axis=0))
    return max(0.0, float(gap.max()))


def bearing(points: np.ndarray, grasp: dict, spec: GripperSpec) -> dict:
    """The rises (mm) of both pads and the gap (mm) between their bearing sets, for one exported grasp."""
    T = np.asarray(grasp["pose"], dtype=np.float64)
    w = float(grasp["width"])
    q = (points - T[:3, 3]) @ T[:3, :3]
    under = (np.abs(q[:, 1]) <= spec.finger_width / 2) & (np.abs(q[:, 2]) <= spec.finger_depth / 2)
    sets, rises = [], []
    for side in (-1.0, 1.0):
        near = under & (side * q[:, 0] >= w / 2 - 3e-3)  # this side's surface under the pad
        x = side * q[near, 0]
        rises.append((x.max() - w / 2) * 1e3)
        sets.append(q[near][x >= x.max() - HOLD.pad_compliance][:, 1:])
    gap = hull_gap(*sets)
    share = gap / w / spec.friction
    margin = float(grasp["hold_margin"])
    return {
        "rise_mm": max(rises),
        "gap_mm": gap * 1e3,
        "share": share,
        "margin": margin,
        "couple_margin": margin * float(np.sqrt(max(1.0 - share * share, 0.0))),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", nargs="*")
    ap.add_argument("--failed", nargs="*", default=list(FAILED))
    args = ap.parse_args()
    run = argparse.Namespace(points=5000, k1=8, k2=2, mass=0.2, grip_force=20.0)
    failed = {tuple(f.rsplit(":", 1)) for f in args.failed}
    rows = []
    for label, part in bench_hold.parts(args.parts):
        gripper = bench_hold.gripper_for(part.mesh, run.grip_force)
        spec = GripperSpec.from_dict(gripper)
        gs = bench_hold.export(part, gripper, "hold", run)
        points, _ = trimesh.sample.sample_surface(part.mesh, 400_000, seed=1)
        for g in gs.grasps:
            rows.append({"part": label, "candidate": g["candidate"], **bearing(points, g, spec)})
        print(f"{label}: {len(gs.grasps)} exports", file=sys.stderr, flush=True)
    if not rows:
        print("no exports (is ../shared/meshes there?)")
        return
    gap = np.array([r["gap_mm"] for r in rows])
    share = np.array([r["share"] for r in rows])
    couple = np.array([r["couple_margin"] for r in rows])
    rise = np.array([r["rise_mm"] for r in rows])
    print(f"{len(rows)} exports of (e) over {len({r['part'] for r in rows})} parts\n")
    print("| measure | min | 25 % | median | 75 % | 90 % | max |")
    print("|---|---|---|---|---|---|---|")
    for name, v in (
        ("larger rise of the two pads, mm", rise),
        ("gap between the bearing sets, mm", gap),
        ("friction share the couple needs", share),
        ("margin with that share taken off", couple),
    ):
        q = np.percentile(v, [0, 25, 50, 75, 90, 100])
        print(f"| {name} | " + " | ".join(f"{x:.2f}" for x in q) + " |")
    print(
        f"\ngap >= 10 mm: {int(np.sum(gap >= 10))}; share >= 1 (no static equilibrium of rigid bodies at all): "
        f"{int(np.sum(share >= 1))}; margin with the couple below 1: {int(np.sum(couple < 1))}\n"
    )
    by_share = np.argsort(-share)
    by_couple = np.argsort(couple)
    print(
        "| failed export | gap mm | share | margin | with the couple | rank by share | rank by margin with the couple |"
    )
    print("|---|---|---|---|---|---|---|")
    for k, r in enumerate(rows):
        if (r["part"], str(r["candidate"])) in failed:
            print(
                f"| {r['part']} {r['candidate']} | {r['gap_mm']:.1f} | {r['share']:.2f} | {r['margin']:.2f} | "
                f"{r['couple_margin']:.2f} | {int(np.where(by_share == k)[0][0]) + 1} of {len(rows)} | "
                f"{int(np.where(by_couple == k)[0][0]) + 1} of {len(rows)} |"
            )


if __name__ == "__main__":
    main()
