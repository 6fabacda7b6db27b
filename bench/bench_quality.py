"""Benchmark of grasp selection: coverage, diversity, quality score and simulated success, same k for every method.

    .venv/bin/python bench/bench_quality.py [--points 5000] [--k1 16] [--k2 4] [--parts NAME ...] [--no-sim]
                                            [--out docs/benchmarks_quality.md]

Parts: the shipped examples (graspgen/examples.py) and every mesh in ../shared/meshes (units from units.json; the
bad/ folder is left out). Gripper: the demo's (cli.DEMO_GRIPPER, a PGN-80-like gripper, 80 mm stroke). For each
part the candidates are generated once, then k = k1 * k2 grasps are selected by

- `two-stage`: the paper's two-stage k-medoids (translation, then closing axis), the exported medoids;
- `two-stage+quality`: the same clusters, each medoid replaced by the best-scoring member near it
  (select="best-near-medoid", quality.py);
- `random`: k candidates drawn uniformly (seeded);
- `top-friction`: the k candidates with the largest friction margin;
- `single-stage`: FasterPAM with k medoids on the combined distance |dp| / 1 cm + axis angle / 30 deg, over a seeded
  sample of at most 2,500 candidates (the full n x n matrix does not fit), every candidate then assigned to the
  nearest sampled medoid.

Reported per selection: coverage at (1 cm, 30 deg) and (2 cm, 45 deg), the smallest pairwise combined distance
max(dp / 1 cm, angle / 30 deg) (below 1: two selected grasps cover each other), the mean quality score, and, with
simulation, the share of the k grasps that MuJoCo holds through the lift and shake (20 N per finger, GRIP_FORCE;
no repair) at the exported pose (the roll choose_roll picks). Masses follow the material each part stands for
(`density_of`): the example parts steel (7850 kg/m^3), the T-LESS parts plastic (1200), the trimesh machined parts
aluminium (2700), the YCB objects their published masses (mustard bottle 0.603 kg, sugar box 0.514 kg, soup can
0.349 kg) over their closed volumes. A second table times 64 simulated grasps with
one and two worker threads. No assertions: the numbers are for docs.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import graspgen  # noqa: E402
from graspgen import clustering, physics, quality  # noqa: E402
from graspgen.cli import DEMO_GRIPPER  # noqa: E402
from graspgen.coverage import coverage  # noqa: E402
from graspgen.examples import EXAMPLES, example_part  # noqa: E402
from graspgen.gripper import GripperSpec  # noqa: E402
from graspgen.parts import load_part  # noqa: E402
from graspgen.pipeline import choose_roll  # noqa: E402
from graspgen.transforms import grasp_frames  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
METHODS = ("two-stage", "two-stage+quality", "random", "top-friction", "single-stage")
SINGLE_STAGE_SAMPLE = 2500
#: N per finger, the demo gripper's force in these tables (physics.py has no default)
GRIP_FORCE = 20.0
#: published YCB masses, kg
YCB_MASS = {"ycb_mustard_bottle": 0.603, "ycb_sugar_box": 0.514, "ycb_tomato_soup_can": 0.349}


def density_of(name: str, part) -> float:
    """kg/m^3 for the material the part stands for (see the module docstring)."""
    if name in YCB_MASS:
        return YCB_MASS[name] / abs(float(part.mesh.volume))
    if name.startswith("tless_"):
        return 1200.0
    if name.startswith("trimesh_"):
        return 2700.0
    return physics.DEFAULT_DENSITY


def parts(names: list[str] | None):
    for name in EXAMPLES:
        if not names or name in names:
            yield name, example_part(name)
    units = json.loads((SHARED / "units.json").read_text()) if SHARED.is_dir() else {}
    for file, unit in sorted(units.items()):
        if file.startswith("bad/"):
            continue
        name = Path(file).stem
        if not names or name in names:
            yield name, load_part(SHARED / file, units=unit, name=name)


def single_stage(mids: np.ndarray, axes: np.ndarray, k: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = len(mids)
    sample = np.sort(rng.choice(n, size=min(n, SINGLE_STAGE_SAMPLE), replace=False))
    P, U = mids[sample], axes[sample]
    dt = np.linalg.norm(P[:, None] - P[None], axis=2)
    ang = np.degrees(np.arccos(np.clip(np.abs(U @ U.T), 0.0, 1.0)))
    D = dt / 0.01 + ang / 30.0
    np.fill_diagonal(D, 0.0)
    D = (D + D.T) / 2
    res = clustering.fasterpam(D, min(k, len(sample)), seed=seed)
    return sample[np.asarray(res.medoids, dtype=np.int64)]


def poses_of(cands, idx: np.ndarray) -> np.ndarray:
    rolls = np.array([choose_roll(cands.free_rolls[m]) for m in idx], dtype=np.int64)
    return grasp_frames(cands.midpoints[idx], cands.axes[idx], cands.roll_angles_rad[rolls])


def run_part(name, part, args, spec) -> dict:
    t0 = time.perf_counter()
    gs = graspgen.generate(part, DEMO_GRIPPER, points=args.points, k1=args.k1, k2=args.k2, select="best-near-medoid")
    t_gen = time.perf_counter() - t0
    c = gs.candidates
    n = len(c)
    row = {"part": name, "candidates": n, "generate_s": t_gen, "methods": {}}
    if n == 0:
        return row
    k = args.k1 * args.k2
    score = quality.scores(c.quality_terms)
    mids, axes = c.midpoints, c.axes
    paper = np.array([g.get("medoid", g["candidate"]) for g in gs.grasps], dtype=np.int64)
    sel = {
        "two-stage": paper,
        "two-stage+quality": np.array([g["candidate"] for g in gs.grasps], dtype=np.int64),
        "random": np.sort(np.random.default_rng(0).choice(n, size=min(k, n), replace=False)),
        "top-friction": np.lexsort((np.arange(n), -c.friction_margin_deg))[: min(k, n)],
        "single-stage": single_stage(mids, axes, k, 0),
    }
    sim_part = None
    if not args.no_sim and part.mesh is not None:
        t0 = time.perf_counter()
        row["density"] = density_of(name, part)
        sim_part = physics.prepare_part(part.mesh, spec, density=row["density"], grip_force=GRIP_FORCE, seed=0)
        row["decomposition_s"] = time.perf_counter() - t0
        row["geometry"] = f"{sim_part.geometry} ({sim_part.pieces})"
    for method, idx in sel.items():
        rep = coverage(mids, axes, idx)
        out = {
            "k": len(idx),
            "cov1": rep.shares[0],
            "cov2": rep.shares[1],
            "min_pair": rep.min_pair_combined,
            "score": float(score[idx].mean()),
        }
        if sim_part is not None:
            t0 = time.perf_counter()
            res = physics.simulate_grasps(sim_part, poses_of(c, idx), c.widths[idx], seed=0, keys=idx, workers=2)
            out["sim_s"] = time.perf_counter() - t0
            out["success"] = sum(r.success for r in res) / len(res)
            out["failures"] = physics.summarise(res)["failures"]
        row["methods"][method] = out
    return row


def time_sims(spec) -> list[dict]:
    out = []
    for name in ("bar", "ring-screw"):
        part = example_part(name)
        gs = graspgen.generate(part, DEMO_GRIPPER, points=3000, k1=16, k2=4)
        c = gs.candidates
        idx = c.medoids[:64]
        sim_part = physics.prepare_part(part.mesh, spec, density=density_of(name, part), grip_force=GRIP_FORCE, seed=0)
        poses, widths = poses_of(c, idx), c.widths[idx]
        physics.simulate_grasps(sim_part, poses[:2], widths[:2], workers=1)  # warm
        row = {"part": name, "grasps": len(idx), "geometry": f"{sim_part.geometry} ({sim_part.pieces})"}
        for workers in (1, 2):
            t0 = time.perf_counter()
            physics.simulate_grasps(sim_part, poses, widths, seed=0, keys=idx, workers=workers)
            row[f"workers{workers}_s"] = time.perf_counter() - t0
        out.append(row)
    return out


def fmt(v, pct=False):
    if v is None:
        return "-"
    return f"{100 * v:.1f} %" if pct else f"{v:.2f}"


def markdown(rows, timing, args) -> str:
    lines = [
        "# Benchmark: grasp selection quality",
        "",
        "Made by `.venv/bin/python bench/bench_quality.py"
        + (f" --points {args.points}" if args.points != 5000 else "")
        + "` (see its docstring for the methods). "
        f"{args.points} points, k = {args.k1} x {args.k2} = {args.k1 * args.k2} for every method, gripper `pgn-80` "
        "(80 mm stroke), seed 0. Coverage: share of all candidates within (1 cm, 30 deg) / (2 cm, 45 deg) of a "
        "selected grasp. Min pair: smallest max(dp / 1 cm, angle / 30 deg) between two selected grasps. Score: mean "
        "quality score (quality.py). Held: share of the k grasps MuJoCo holds through lift and shake (20 N per "
        "finger, no repair; densities per material, see the script's docstring).",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores shared with other jobs, Python "
        f"{platform.python_version()}, mujoco {__import__('mujoco').__version__}.",
        "",
        "## Mean over parts",
        "",
        "| method | cov 1 cm / 30 deg | cov 2 cm / 45 deg | min pair | score | held |",
        "|---|---|---|---|---|---|",
    ]
    for m in METHODS:
        vals = [r["methods"][m] for r in rows if m in r["methods"]]
        if not vals:
            continue

        def mean(key, vals=vals):
            xs = [v[key] for v in vals if v.get(key) is not None]
            return float(np.mean(xs)) if xs else None

        lines.append(
            f"| {m} | {fmt(mean('cov1'), True)} | {fmt(mean('cov2'), True)} | {fmt(mean('min_pair'))} | "
            f"{fmt(mean('score'))} | {fmt(mean('success'), True)} |"
        )
    lines += [
        "",
        "## Per part",
        "",
        "| part | candidates | method | k | cov 1 cm / 30 deg | cov 2 cm / 45 deg | min pair | score | held "
        "| failures |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if not r["methods"]:
            lines.append(f"| {r['part']} | 0 | - | - | - | - | - | - | - | no candidates |")
            continue
        for m in METHODS:
            v = r["methods"][m]
            fails = ", ".join(f"{k} {n}" for k, n in (v.get("failures") or {}).items() if n) or "-"
            lines.append(
                f"| {r['part']} | {r['candidates']:,} | {m} | {v['k']} | {fmt(v['cov1'], True)} | "
                f"{fmt(v['cov2'], True)} | {fmt(v['min_pair'])} | {fmt(v['score'])} | "
                f"{fmt(v.get('success'), True)} | {fails} |"
            )
    geo = [
        f"{r['part']}: {r['geometry']}, {r['decomposition_s']:.1f} s, {r['density']:.0f} kg/m^3"
        for r in rows
        if r.get("geometry")
    ]
    if geo:
        lines += [
            "",
            "Collision geometry (method and pieces), the time to build it, and the density: " + "; ".join(geo) + ".",
        ]
    if timing:
        lines += [
            "",
            "## Simulation time",
            "",
            "64 grasps (the two-stage medoids at 3,000 points), warm; wall-clock on the shared machine.",
            "",
            "| part | geometry | grasps | 1 thread | 2 threads |",
            "|---|---|---|---|---|",
        ]
        for t in timing:
            lines.append(
                f"| {t['part']} | {t['geometry']} | {t['grasps']} | {t['workers1_s']:.2f} s | {t['workers2_s']:.2f} s |"
            )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=5000)
    ap.add_argument("--k1", type=int, default=16)
    ap.add_argument("--k2", type=int, default=4)
    ap.add_argument("--parts", nargs="*")
    ap.add_argument("--no-sim", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks_quality.md"))
    args = ap.parse_args()
    spec = GripperSpec.from_dict(DEMO_GRIPPER)
    rows = []
    for name, part in parts(args.parts):
        t0 = time.perf_counter()
        row = run_part(name, part, args, spec)
        rows.append(row)
        summary = {m: (round(v["cov1"], 3), round(v["cov2"], 3), v.get("success")) for m, v in row["methods"].items()}
        print(f"{name}: {row['candidates']} candidates, {time.perf_counter() - t0:.1f} s {summary}", flush=True)
    timing = [] if args.no_sim else time_sims(spec)
    text = markdown(rows, timing, args)
    out = Path(args.out)
    old = out.read_text() if out.is_file() else ""
    if "<!-- bench_hold:start -->" in old:  # keep bench_hold.py's section
        text = text.rstrip("\n") + "\n\n" + "<!-- bench_hold:start -->" + old.split("<!-- bench_hold:start -->", 1)[1]
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
