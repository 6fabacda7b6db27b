"""Benchmark of suction grasps in the project's own simulation (issue 33): do exported suction grasps hold, and how
well does the `hold` criterion predict the simulation?

    .venv/bin/python bench/bench_suction_hold.py [--cup examples/cup-30.json] [--points 3000] [--k1 8] [--k2 2]
                                                 [--mass 0.2] [--sample 40] [--workers 2] [--parts NAME ...]
                                                 [--json rows.json] [--render rows.json] [--out FILE.md]

Parts: every mesh in ../shared/meshes (units from its units.json; bad/ left out) and ../shared/meshes/paper. Cup:
the contract's cup-30 (30 mm lip, 60 kPa, friction 0.5, 10 % stretch); every part weighs `--mass` (0.2 kg).

1. `graspgen.generate(part, cup, mass_kg=mass, points, k1, k2, seed 0)` exports the suction grasp set; every exported
   grasp is simulated (graspgen.physics_suction) nominally and under each member of `suction_perturbation_set(0)`
   (mass x0.5 / x1.5, vacuum x0.7, friction 0.3 / 0.6, gravity turned to -Z, +-X, +-Y, a lateral shake of 1 g, a
   seeded mixture). Held = held under all 13. Reported per part: exported grasps, held fraction, failures by reason.
2. The confusion table of `hold`: generate() again with hold off (the candidates that pass seal and collision),
   `graspgen.suction.judge_cups` gives each its hold margin (the same mass, accel, safety factor and centre of mass
   as generate()); up to `--sample` candidates per part with margin >= 1 and as many with margin < 1 (seeded) are
   simulated under the same 13, against the simulation's verdict (held under all / nominal only).

The markdown goes between the `bench_suction_hold` markers of `--out` (appended when absent); no assertions.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import graspgen  # noqa: E402
from graspgen import physics_suction as ps  # noqa: E402
from graspgen.examples import EXAMPLE_CUP  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_hold import parts  # noqa: E402  (the shared meshes with their units, as bench_hold reads them)

ROOT = Path(__file__).resolve().parents[1]
START, END = "<!-- bench_suction_hold:start -->", "<!-- bench_suction_hold:end -->"


def load_cup(path: str | None) -> dict:
    """The suction spec's fields (generate() takes the dict; the contract's cup-30 by default)."""
    return json.loads(Path(path).read_text()) if path else dict(EXAMPLE_CUP)


def frames(contacts: np.ndarray, approaches: np.ndarray) -> np.ndarray:
    """T_object_grasp (n, 4, 4) of cups at `contacts` (n, 3) approaching along `approaches` (n, 3), roll 0 (the
    contract: X0 = object +X made orthogonal to Z, +Y when |X . Z| > 0.9)."""
    z = approaches / np.linalg.norm(approaches, axis=1, keepdims=True)
    ref = np.zeros_like(z)
    use_y = np.abs(z[:, 0]) > 0.9
    ref[~use_y, 0] = 1.0
    ref[use_y, 1] = 1.0
    x = ref - np.sum(ref * z, axis=1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    T = np.zeros((len(z), 4, 4))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = x, np.cross(z, x), z, contacts
    T[:, 3, 3] = 1.0
    return T


def constants(args) -> ps.SuctionSimConstants:
    """The judge's constants: the defaults, or the lip stiffness and gap limit given (a sensitivity run)."""
    return dataclasses.replace(ps.SUCTION_SIM, lip_stiffness=args.lip_stiffness, gap_limit=args.gap_limit)


def simulate(part, poses, cup, args, members, keys=None):
    sim_part = ps.prepare_suction_part(part.mesh, mass_kg=args.mass)
    return ps.simulate_suction(
        sim_part, poses, cup, perturbations=members, workers=args.workers, keys=keys, constants=constants(args)
    )


SHIFTS_MM = (0.05, 0.1, 0.2, 0.5, 1.0, 2.0)


def seal_shift_mm(part, T: np.ndarray, cup, args) -> float | None:
    """How far (mm) the cup of pose T may be moved across its axis before the simulation's lip ring loses the seal:
    the first of SHIFTS_MM at which a shift in any of 16 directions does, without the placement error (0: no seal
    even at the pose itself; None: sealed at every shift tried)."""
    still = dataclasses.replace(
        constants(args), motion=dataclasses.replace(ps.SUCTION_SIM.motion, pose_noise=0.0, pose_noise_deg=0.0)
    )
    sim_part = ps.prepare_suction_part(part.mesh, mass_kg=args.mass)
    if not ps.seal_at(sim_part, T, cup, constants=still).ok:
        return 0.0
    for d in SHIFTS_MM:
        for k in range(16):
            a = 2 * np.pi * k / 16
            moved = T.copy()
            moved[:3, 3] += d * 1e-3 * (np.cos(a) * T[:3, 0] + np.sin(a) * T[:3, 1])
            if not ps.seal_at(sim_part, moved, cup, constants=still).ok:
                return d
    return None


def failures(grid) -> dict[str, int]:
    out: dict[str, int] = {}
    for row in grid:
        for r in row:
            if not r.success:
                key = f"{r.reason} ({r.member})"
                out[key] = out.get(key, 0) + 1
    return out


def run_part(label, part, spec: dict, args, members) -> dict:
    row: dict = {"part": label}
    t0 = time.perf_counter()
    gs = graspgen.generate(part, spec, points=args.points, k1=args.k1, k2=args.k2, seed=0, mass_kg=args.mass)
    row["generate_s"] = time.perf_counter() - t0
    cup = ps.SuctionCup.of(gs.gripper)
    poses = np.array([np.asarray(g["pose"], dtype=np.float64) for g in gs.grasps]).reshape(-1, 4, 4)
    row["rejected"] = gs.stats.get("rejected")
    row["empty_reason"] = (gs.stats.get("empty_reason") or {}).get("criterion")
    t1 = time.perf_counter()
    grid = simulate(part, poses, cup, args, members) if len(poses) else []
    row["simulate_s"] = time.perf_counter() - t1
    row["grasps"] = len(poses)
    held = ps.held(grid) if grid else np.zeros(0, dtype=bool)
    row["held"] = int(held.sum())
    row["nominal_held"] = int(sum(r[0].success for r in grid))
    row["failures"] = failures(grid)
    row["failed"] = [
        {
            "grasp": i,
            "hold_margin": gs.grasps[i].get("hold_margin"),
            "outcomes": [r.to_json() for r in g if not r.success],
            "seal_shift_mm": seal_shift_mm(part, poses[i], cup, args) if g[0].reason == "no_seal" else None,
        }
        for i, g in enumerate(grid)
        if not held[i]
    ]
    row["confusion"] = confusion(part, spec, cup, args, members)
    return row


def confusion(part, spec: dict, cup, args, members) -> dict:
    """hold's verdict (margin >= 1) against the simulation on up to args.sample candidates of each class, among the
    candidates that pass every other criterion."""
    from graspgen.suction import judge_cups

    off = graspgen.generate(part, spec, points=args.points, k1=args.k1, k2=args.k2, seed=0, hold="off")
    c = off.candidates
    contacts = np.asarray(c.contacts, dtype=np.float64).reshape(-1, 3)
    approach = np.asarray(c.axes, dtype=np.float64).reshape(-1, 3)
    margin = judge_cups(part.mesh, off.gripper, contacts, approach, mass_kg=args.mass).hold_margin
    assert margin is not None
    rng = np.random.default_rng(1)
    out = {}
    for name, mask in (("pass", margin >= 1.0), ("fail", margin < 1.0)):
        idx = np.flatnonzero(mask)
        idx = np.sort(rng.choice(idx, min(args.sample, len(idx)), replace=False)) if len(idx) else idx
        grid = simulate(part, frames(contacts[idx], approach[idx]), cup, args, members, keys=idx) if len(idx) else []
        held = ps.held(grid) if grid else np.zeros(0, dtype=bool)
        out[name] = {
            "candidates": int(mask.sum()),
            "simulated": len(idx),
            "held_all": int(held.sum()),
            "held_nominal": int(sum(r[0].success for r in grid)),
            "no_seal": int(sum(r[0].reason == "no_seal" for r in grid)),
            "margins": [round(float(margin[i]), 3) for i in idx],
            "held": held.tolist(),
            "reasons": failures(grid),
        }
    return out


def describe(f: dict) -> str:
    """A failed export: its first failure's reason, hold margin and, for no_seal, how far the cup could move."""
    notes = [] if f["hold_margin"] is None else [f"{f['hold_margin']:.2f}"]
    shift = f.get("seal_shift_mm")
    if f["outcomes"][0]["reason"] == "no_seal":
        notes.append("no seal at the pose" if shift == 0 else f"seal lost {shift:g} mm off the pose")
    return f"{f['outcomes'][0]['reason']} ({'; '.join(notes)})"


def markdown(rows, members, args, wall) -> str:
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout
    lines = [
        START,
        "## Suction cups in the simulation (issue 33): `bench_suction_hold.py`",
        "",
        f"`{args.command or ' '.join(['.venv/bin/python', *sys.argv])}` at {commit.strip()}; cup-30 (30 mm lip, "
        f"60 kPa: 42.4 N, friction 0.5), {args.mass:g} kg, {args.points} points, k = {args.k1} x {args.k2}, seed 0; "
        f"{platform.machine()}, {os.cpu_count()} cores, {wall:.0f} s. Judge: `graspgen/physics_suction.py` "
        '(docs/HOLD.md, "Suction: physics validation"), nominal and the 12 members of '
        "`suction_perturbation_set(0)`; held = held in all 13."
        + (
            ""
            if constants(args) == ps.SUCTION_SIM
            else f" Judge's lip stiffness {args.lip_stiffness:g} N/m per m, gap limit {args.gap_limit * 1e3:g} mm."
        ),
        "",
    ]
    lines += [
        "| part | exported | held (all 13) | held nominally | not held: first failure (hold margin; seal) |",
        "|---|---|---|---|---|",
    ]
    n_all = h_all = nom_all = 0
    empty = []
    for r in rows:
        n, h = r["grasps"], r["held"]
        if not n:
            empty.append(f"{r['part'].split('/')[-1]} ({r.get('empty_reason') or '-'})")
            continue
        n_all, h_all, nom_all = n_all + n, h_all + h, nom_all + r["nominal_held"]
        fails = ", ".join(describe(f) for f in r["failed"])
        lines.append(f"| {r['part']} | {n} | {h} ({100 * h / n:.0f} %) | {r['nominal_held']} | {fails or '-'} |")
    if n_all:
        held_all, held_nominal = f"{h_all} ({100 * h_all / n_all:.1f} %)", f"{nom_all} ({100 * nom_all / n_all:.1f} %)"
        lines.append(f"| **all** | {n_all} | **{held_all}** | {held_nominal} | |")
    if empty:
        lines += ["", "No export (the criterion that removed the last candidates): " + ", ".join(empty) + "."]
    conf = [r["confusion"] for r in rows if r.get("confusion")]
    if conf:
        keys = ("candidates", "simulated", "held_all", "held_nominal", "no_seal")
        tot = {k: dict.fromkeys(keys, 0) for k in ("pass", "fail")}
        for cf in conf:
            for k in tot:
                for f in keys:
                    tot[k][f] += cf[k][f]
        lines += [
            "",
            f"`hold` against the simulation: up to {args.sample} candidates per part and class (margin >= 1: pass, "
            "< 1: fail; seeded) among those that pass seal and collision; `no_seal` (the simulation finds no seal "
            "after its placement error: not hold's question) counted apart.",
            "",
            "| hold | candidates | simulated | no_seal | held (all 13) | dropped or slipped | held nominally |",
            "|---|---|---|---|---|---|---|",
        ]
        for k in ("pass", "fail"):
            t = tot[k]
            lost = t["simulated"] - t["no_seal"] - t["held_all"]
            lines.append(
                f"| {k} | {t['candidates']} | {t['simulated']} | {t['no_seal']} | {t['held_all']} | {lost} "
                f"| {t['held_nominal']} |"
            )
        sealed = {k: tot[k]["simulated"] - tot[k]["no_seal"] for k in tot}
        share = {k: 100 * tot[k]["held_all"] / sealed[k] if sealed[k] else float("nan") for k in tot}
        lines += [
            "",
            f"Of the sealed candidates hold passes, {share['pass']:.1f} % are held under all 13; of those it rejects, "
            f"{share['fail']:.1f} %.",
        ]
    lines.append(END)
    return "\n".join(lines) + "\n"


def write_block(path: Path, block: str) -> None:
    text = path.read_text() if path.is_file() else ""
    if START in text and END in text:
        head, rest = text.split(START, 1)
        text = head + block.rstrip("\n") + rest.split(END, 1)[1]
    else:
        text = text.rstrip("\n") + "\n\n" + block
    path.write_text(text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cup", help="a suction spec file (default: the contract's cup-30)")
    ap.add_argument("--points", type=int, default=3000)
    ap.add_argument("--k1", type=int, default=8)
    ap.add_argument("--k2", type=int, default=2)
    ap.add_argument("--mass", type=float, default=0.2)
    ap.add_argument("--sample", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--parts", nargs="*")
    ap.add_argument("--lip-stiffness", type=float, default=ps.SUCTION_SIM.lip_stiffness, help="N/m per m of lip")
    ap.add_argument("--gap-limit", type=float, default=ps.SUCTION_SIM.gap_limit, help="m")
    ap.add_argument("--json", help="also write the raw rows here")
    ap.add_argument("--render", help="only write the markdown of the rows (--json) of an earlier run")
    ap.add_argument("--wall", type=float, default=None)
    ap.add_argument("--command", help="with --render: the earlier run's command line")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks_quality.md"))
    args = ap.parse_args()
    spec = load_cup(args.cup)
    members = (ps.SUCTION_NOMINAL, *ps.suction_perturbation_set(0))
    rows = json.loads(Path(args.render).read_text()) if args.render else []
    t_all = time.perf_counter()
    for label, part in [] if args.render else parts(args.parts):
        t0 = time.perf_counter()
        rows.append(run_part(label, part, spec, args, members))
        r = rows[-1]
        print(f"{label}: {r['held']}/{r['grasps']} held, {time.perf_counter() - t0:.0f} s", flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1, default=str))
    block = markdown(rows, members, args, args.wall or time.perf_counter() - t_all)
    if args.out:
        write_block(Path(args.out), block)
    print(block)


if __name__ == "__main__":
    main()
