"""Cross-check of the exported grasps in a second, independent simulator: PyBullet (bench/crosscheck_bullet.py).

    PYTHONUNBUFFERED=1 .venv/bin/python bench/bench_crosscheck.py [--parts NAME ...] [--configs paper hold validate]
                                                                  [--workers 2] [--out docs/benchmarks_quality.md]
                                                                  [--json rows.json] [--render rows.json]

The exports are bench_hold.py's: its parts (../shared/meshes and ../shared/meshes/paper), its gripper choice
(pgn-80, or pgn-80-wide for parts wider than 70 mm in every direction) and its generate call per configuration
(`paper` = criteria (a)-(d), `hold` = with (e), `validate` = with (e) and MuJoCo validation + repair), at 5,000
points, k = 8 x 2, seed 0, every part 0.2 kg, grip force 20 N per finger, friction 0.5. Every exported grasp is
then simulated in Bullet nominally and under each member of `physics.perturbation_set(0)`, and in MuJoCo the same way
(bench_hold's judge: physics.simulate_perturbed with the same mass, force and friction), so the two simulators'
verdicts on the same grasps can be compared. Parts run in a process pool (`--workers`, one Bullet client and one
MuJoCo thread per process); hold and validate share the simulations of the grasps they both export.

The markdown goes between the `bench_crosscheck` markers of `--out` (appended when absent); no assertions.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.metadata
import json
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import bench_hold  # noqa: E402
import crosscheck_bullet as cb  # noqa: E402

from graspgen import physics  # noqa: E402
from graspgen.gripper import GripperSpec  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
START, END = "<!-- bench_crosscheck:start -->", "<!-- bench_crosscheck:end -->"
CONFIGS = bench_hold.CONFIGS
pct = bench_hold.pct


def _key(pose: np.ndarray, width: float) -> str:
    """The same exported grasp in two configurations simulates the same: key by pose and width."""
    return hashlib.sha1(
        np.ascontiguousarray(pose, dtype=np.float64).tobytes() + np.float64(width).tobytes()
    ).hexdigest()


def run_part(label: str, args) -> dict:
    """Generate the configurations' exports of one part, then judge every exported grasp in Bullet and MuJoCo."""
    name = label.split("/")[-1]
    part = next(p for lab, p in bench_hold.parts([name]) if lab == label)
    gripper = bench_hold.gripper_for(part.mesh, args.grip_force)
    spec = GripperSpec.from_dict(gripper)
    members = cb.members(0)  # nominal first, then physics.perturbation_set(0)
    row: dict = {"part": label, "gripper": gripper["name"], "configs": {}}
    t0 = time.perf_counter()
    bpart = cb.prepare_part(part.mesh, spec, mass_kg=args.mass, grip_force=args.grip_force, friction=args.friction)
    row["bullet_geometry"], row["bullet_prepare_s"] = bpart.describe(), time.perf_counter() - t0
    t0 = time.perf_counter()
    sim = physics.prepare_part(
        part.mesh,
        spec,
        mass_kg=args.mass,
        grip_force=args.grip_force,
        friction=args.friction,
        seed=0,
        constants=bench_hold.judge_constants(f"{physics.SIM.coacd_threshold:g}:{physics.SIM.coacd_max_hulls}"),
    )
    row["mujoco_geometry"], row["mujoco_prepare_s"] = f"{sim.geometry} ({sim.pieces})", time.perf_counter() - t0
    bullet_cache: dict = {}
    mujoco_cache: dict = {}
    row["bullet_s"] = row["mujoco_s"] = 0.0
    with cb.BulletJudge(bpart) as judge:
        for config in args.configs:
            t0 = time.perf_counter()
            gs = bench_hold.export(part, gripper, config, args)
            if gs is None:
                print(f"  {label} {config}: not supported by this checkout's generate(), skipped", flush=True)
                continue
            out = {"generate_s": time.perf_counter() - t0, "candidates": len(gs.candidates), "grasps": []}
            c = gs.candidates
            cset = hashlib.sha1(np.ascontiguousarray(c.contacts).tobytes()).hexdigest()
            for g in gs.grasps:
                pose, width = np.asarray(g["pose"], dtype=np.float64), float(g["width"])
                key = _key(pose, width)
                if key not in bullet_cache:
                    t1 = time.perf_counter()
                    if g.get("mode", "outside") != "outside":  # the Bullet gripper closes inwards only
                        bullet_cache[key] = None
                    else:
                        bullet_cache[key] = [r.to_json() for r in judge.simulate_members(pose, width, members)]
                    row["bullet_s"] += time.perf_counter() - t1
                mkey = (cset, int(g["candidate"]))
                if mkey not in mujoco_cache:
                    t1 = time.perf_counter()
                    grid = bench_hold.judge(sim, c, np.array([g["candidate"]]), members, workers=1)[0]
                    mujoco_cache[mkey] = [{**r.to_json(), "member": m.name} for r, m in zip(grid, members, strict=True)]
                    row["mujoco_s"] += time.perf_counter() - t1
                out["grasps"].append(
                    {
                        "candidate": int(g["candidate"]),
                        "width": width,
                        "hold_margin": g.get("hold_margin"),
                        "bullet": bullet_cache[key],
                        "mujoco": mujoco_cache[mkey],
                    }
                )
            row["configs"][config] = out
            s = summary(out)
            print(
                f"  {label} {config}: {s['n']} grasps, Bullet nominal {s['b_nom']} all {s['b_all']}, MuJoCo nominal "
                f"{s['m_nom']} all {s['m_all']} ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    return row


# --------------------------------------------------------------------------------------------------------------------
# tables


def _held(results) -> np.ndarray:
    return np.array([bool(r["success"]) for r in results], dtype=bool)


def summary(out: dict) -> dict:
    """Counts of one configuration of one part (grasps Bullet could not judge are left out of its columns)."""
    grasps = [g for g in out["grasps"] if g["bullet"] is not None]
    n = len(grasps)
    if not n:
        return {"n": 0, "b_nom": 0, "b_all": 0, "b_mean": None, "m_nom": 0, "m_all": 0, "both": np.zeros((2, 2), int)}
    b = np.array([_held(g["bullet"]) for g in grasps])  # (n, 1 + members)
    m = np.array([_held(g["mujoco"]) for g in grasps])
    both = np.zeros((2, 2), dtype=int)  # [mujoco held?][bullet held?], nominal
    both_all = np.zeros((2, 2), dtype=int)  # held under every member
    for i in range(n):
        both[int(not m[i, 0]), int(not b[i, 0])] += 1
        both_all[int(not m[i].all()), int(not b[i].all())] += 1
    return {
        "n": n,
        "b_nom": int(b[:, 0].sum()),
        "b_all": int(b.all(axis=1).sum()),
        "b_mean": float(b[:, 1:].mean()),
        "m_nom": int(m[:, 0].sum()),
        "m_all": int(m.all(axis=1).sum()),
        "m_mean": float(m[:, 1:].mean()),
        "both": both,
        "both_all": both_all,
        "b_fails": (~b[:, 1:]).sum(axis=0),
        "m_fails": (~m[:, 1:]).sum(axis=0),
        "b_reasons": {r: sum(g["bullet"][0]["reason"] == r for g in grasps) for r in cb.REASONS},
        "overlaps": sum(g["bullet"][0].get("start_overlap") is not None for g in grasps),
    }


def markdown(rows: list[dict], args, wall_s: float) -> str:
    members = cb.members(0)[1:]
    configs = [c for c in CONFIGS if any(c in r["configs"] for r in rows)]
    cmd = args.command or " ".join(
        [
            "PYTHONUNBUFFERED=1 .venv/bin/python bench/bench_crosscheck.py",
            *bench_hold._run_arguments(("--out", "--json", "--render")),
        ]
    )
    c = cb.BULLET
    try:
        import mujoco

        mj_version = mujoco.__version__
    except ImportError:
        mj_version = "-"
    lines = [
        START,
        "## Cross-check in a second simulator: PyBullet",
        "",
        f"Made by `{cmd}` ({wall_s / 60:.0f} min; see its docstring and `bench/crosscheck_bullet.py`). The exports of "
        f"bench_hold's configurations ({args.points} points, k = {args.k1} x {args.k2}, seed 0, every part "
        f"{args.mass} kg, grip force {args.grip_force:g} N per finger, friction {args.friction:g}, gripper pgn-80 or "
        "pgn-80-wide as there) are simulated in Bullet, an engine with another contact and friction model, written "
        "independently of physics.py: the part as Bullet's own V-HACD decomposition, pads and palm as boxes with "
        "separating-axis contact polygons, fingers coupled by a gear and closed by velocity motors capped at the grip "
        f"force, time step {c.timestep * 1e3:g} ms, {c.solver_iterations} solver iterations, constraint force "
        f"mixing {c.global_cfm:g}, torsional friction of a {c.patch_radius * 1e3:g} mm patch; the same stages and "
        "limits as physics.py (close, lift, hold, turn, shake; slip 5 mm / 10 deg, drop 20 mm) but no approach and "
        "no placement error: the part starts at its grasp pose between the open pads, and V-HACD pieces reaching "
        "more than 1 mm into a pad or the palm are `collision` when samples of the part's own surface confirm it; "
        "where only the pieces do (V-HACD bridging a groove: 'pieces-only start overlap' below), the palm collides "
        "with nothing for that grasp, as in physics.py, or the pad overlap is simulated as it is. Known answers "
        "(a cube at rest between the pads stays put, friction carries up to 2 mu F, a bar held near its end turns "
        f"out) are in tests/bench. Every grasp runs nominally and under the {len(members)} members of "
        "`physics.perturbation_set(0)`, in Bullet and in MuJoCo (bench_hold's judge, the same mass, force and "
        "friction). nominal = held in the nominal simulation; all = held under every member; mean = mean share of "
        f"members held. Machine: {platform.machine()}, {os.cpu_count()} cores shared with other jobs, "
        f"{args.workers} worker processes, pybullet {importlib.metadata.version('pybullet')}, mujoco {mj_version}.",
        "",
        "### Total",
        "",
        "| configuration | parts | grasps | Bullet nominal | Bullet all members | Bullet mean share | MuJoCo nominal | "
        "MuJoCo all members | MuJoCo mean share |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    sums = {}
    for config in configs:
        ss = [summary(r["configs"][config]) for r in rows if config in r["configs"]]
        n = sum(s["n"] for s in ss)
        tot = {
            "n": n,
            "b_nom": sum(s["b_nom"] for s in ss),
            "b_all": sum(s["b_all"] for s in ss),
            "m_nom": sum(s["m_nom"] for s in ss),
            "m_all": sum(s["m_all"] for s in ss),
            "both": sum(s["both"] for s in ss),
            "both_all": sum((s["both_all"] for s in ss if s["n"]), np.zeros((2, 2), int)),
            "b_fails": sum((s["b_fails"] for s in ss if s["n"]), np.zeros(len(members), int)),
            "m_fails": sum((s["m_fails"] for s in ss if s["n"]), np.zeros(len(members), int)),
            "b_reasons": {r: sum(s["b_reasons"][r] for s in ss if s["n"]) for r in cb.REASONS},
        }
        b_mean = sum(s["b_mean"] * s["n"] for s in ss if s["n"]) / n if n else None
        m_mean = sum(s["m_mean"] * s["n"] for s in ss if s["n"]) / n if n else None
        sums[config] = tot
        lines.append(
            f"| {config} | {len(ss)} | {n} | {pct(tot['b_nom'], n)} | {pct(tot['b_all'], n)} | "
            f"{'-' if b_mean is None else f'{100 * b_mean:.1f} %'} | {pct(tot['m_nom'], n)} | "
            f"{pct(tot['m_all'], n)} | {'-' if m_mean is None else f'{100 * m_mean:.1f} %'} |"
        )
    lines += [
        "",
        "Bullet's nominal failures by reason: "
        + "; ".join(
            f"{config}: " + (", ".join(f"{r} {n}" for r, n in sums[config]["b_reasons"].items() if n) or "none")
            for config in configs
        )
        + ".",
        "",
        "### Agreement with MuJoCo on the same grasps",
        "",
        "| configuration | simulations | MuJoCo | Bullet held | Bullet not held | agree |",
        "|---|---|---|---|---|---|",
    ]
    for config in configs:
        for what, key in (("nominal", "both"), ("all members", "both_all")):
            t = sums[config][key]
            n = int(t.sum())
            for k, mj in enumerate(("held", "not held")):
                first = (config, what, pct(int(t[0, 0] + t[1, 1]), n)) if k == 0 else ("", "", "")
                lines.append(f"| {first[0]} | {first[1]} | {mj} | {t[k, 0]} | {t[k, 1]} | {first[2]} |")
    lines += [
        "",
        "### Per part",
        "",
        "| part | gripper | Bullet / MuJoCo geometry | configuration | grasps | Bullet nominal | Bullet all | "
        "Bullet mean | MuJoCo nominal | MuJoCo all | Bullet nominal failures |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for config in configs:
            out = r["configs"].get(config)
            if out is None:
                continue
            s = summary(out)
            n = s["n"]
            fails = ", ".join(f"{why} {k}" for why, k in s.get("b_reasons", {}).items() if k) or "-"
            if s.get("overlaps"):
                fails += f" (pieces-only start overlap: {s['overlaps']})"
            mean = "-" if s["b_mean"] is None else f"{100 * s['b_mean']:.1f} %"
            lines.append(
                f"| {r['part']} | {r['gripper']} | {r['bullet_geometry']} / {r['mujoco_geometry']} | {config} | {n} | "
                f"{pct(s['b_nom'], n)} | {pct(s['b_all'], n)} | {mean} | {pct(s['m_nom'], n)} | "
                f"{pct(s['m_all'], n)} | {fails} |"
            )
    lines += [
        "",
        "### Failures per perturbation (exported grasps, all parts): Bullet / MuJoCo",
        "",
        "| perturbation | " + " | ".join(configs) + " |",
        "|---|" + "---|" * len(configs),
    ]
    for j, p in enumerate(members):
        cells = []
        for config in configs:
            worst = []
            for r in rows:
                out = r["configs"].get(config)
                if out is not None and summary(out)["n"]:
                    worst.append((int(summary(out)["b_fails"][j]), r["part"].split("/")[-1]))
            worst = [f"{name} {k}" for k, name in sorted(worst, reverse=True)[:3] if k]
            cells.append(
                f"{sums[config]['b_fails'][j]} / {sums[config]['m_fails'][j]}"
                + (f" (Bullet: {', '.join(worst)})" if worst else "")
            )
        lines.append(f"| {p.name} | " + " | ".join(cells) + " |")
    disagree = []
    for r in rows:
        for config in configs:
            for g in r["configs"].get(config, {}).get("grasps", []):
                if g["bullet"] is None:
                    continue
                b, m = g["bullet"][0], g["mujoco"][0]
                if b["success"] != m["success"]:
                    disagree.append((r["part"], config, g, b, m))
    if disagree:
        lines += [
            "",
            "### Nominal disagreements",
            "",
            "| part | configuration | candidate | hold margin | MuJoCo | Bullet | Bullet slip / rotation | "
            "Bullet pad contact points |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for part, config, g, b, m in disagree:
            hm = g.get("hold_margin")
            lines.append(
                f"| {part} | {config} | {g['candidate']} | {'-' if hm is None else f'{hm:.2f}'} | "
                f"{m['reason'] or 'held'} | {b['reason'] or 'held'} | {b['slip_mm']:.1f} mm / "
                f"{b['rotation_deg']:.1f} deg | {b['contacts']} |"
            )
    timing = "; ".join(
        f"{r['part'].split('/')[-1]} {r['bullet_prepare_s']:.0f} s + {r['bullet_s']:.0f} s" for r in rows
    )
    lines += ["", f"Bullet: V-HACD and simulation time per part: {timing}.", END]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=5000)
    ap.add_argument("--k1", type=int, default=8)
    ap.add_argument("--k2", type=int, default=2)
    ap.add_argument("--mass", type=float, default=0.2)
    ap.add_argument("--grip-force", type=float, default=20.0)
    ap.add_argument("--friction", type=float, default=0.5)
    ap.add_argument("--workers", type=int, default=2, help="processes over parts")
    bench_hold.add_run_arguments(ap, CONFIGS, "also write the raw rows (every grasp's outcomes) here")
    args = ap.parse_args()
    if not cb.available():
        sys.exit("pybullet is not installed: .venv/bin/python -m pip install -c constraints.txt pybullet")
    t_all = time.perf_counter()
    if args.render:
        rows = json.loads(Path(args.render).read_text())
    else:
        labels = [label for label, _ in bench_hold.parts(args.parts)]
        rows = []
        with ProcessPoolExecutor(max_workers=max(1, args.workers)) as pool:
            futures = {label: pool.submit(run_part, label, args) for label in labels}
            for label in labels:
                rows.append(futures[label].result())
                print(f"{label}: done ({time.perf_counter() - t_all:.0f} s)", flush=True)
                if args.json:
                    Path(args.json).write_text(json.dumps(rows, indent=1, default=str))
    block = markdown(rows, args, args.wall or time.perf_counter() - t_all)
    if args.out:
        bench_hold.write_block(Path(args.out), block, START, END)
    print(block)


if __name__ == "__main__":
    main()
