"""Benchmark of criterion (e) `hold` and of the perturbed physics validation (issue 14): does an exported grasp hold?

    .venv/bin/python bench/bench_hold.py [--points 5000] [--k1 8] [--k2 2] [--mass 0.2] [--grip-force 20]
                                         [--gripper SPEC.json] [--sample 200] [--workers 2] [--parts NAME ...]
                                         [--configs paper hold validate] [--out docs/benchmarks_quality.md]

Parts: every mesh in ../shared/meshes (*.stl, *.obj; units from its units.json; bad/ left out) and
../shared/meshes/paper (units from its units.json); a missing folder is skipped with a message. Gripper: the PGN-80 of
examples/pgn-80.json (80 mm stroke) with `grip_force` 20 N per finger; a part whose oriented bounding box is wider
than 70 mm in every direction (the 80 mm stroke minus a 10 mm opening margin) gets the same gripper with a 140 mm
stroke (`pgn-80-wide`), and the table says so. `--gripper SPEC.json` takes that spec for every part instead (a
gripper from CAD is simulated with its meshes). Every part weighs `--mass` (0.2 kg).

Three configurations of graspgen.generate at `--points`, k = k1 x k2, seed 0:

- `paper`: the paper's criteria (a)-(d) only (hold="off");
- `hold`: with criterion (e) (hold="any", mass_kg);
- `validate`: with (e) and the MuJoCo validation with cluster-aware repair (validate=True).

Every exported grasp is then simulated (physics.py, the same mass and grip force) nominally and under each member of
`physics.perturbation_set(0)` (mass x0.5 / x1.5, friction 0.4 / 0.6, gravity turned to -Z, +-X, +-Y of the grasp
frame after the pick, a lateral shake of 1 g, one seeded mixture). Reported: nominal success, success under every
member ("all"), the mean share of members held, failures per member, coverage (stats.coverage at 1 cm / 30 deg) and
generate's wall time. A confusion table compares (e)'s verdict (hold margin >= 1) with the nominal simulation on
`--sample` random candidates per part of the paper configuration (seeded).

The markdown goes between the `bench_hold` markers of `--out` (appended when absent); no assertions.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import inspect
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import graspgen  # noqa: E402
from graspgen import physics  # noqa: E402
from graspgen.gripper import GripperSpec  # noqa: E402
from graspgen.params import Params  # noqa: E402
from graspgen.parts import load_part  # noqa: E402
from graspgen.pipeline import _poses  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
FOLDERS = (SHARED, SHARED / "paper")
START, END = "<!-- bench_hold:start -->", "<!-- bench_hold:end -->"
WIDE_STROKE = 0.14
#: a part wider than this in every direction does not fit the 80 mm stroke with a useful opening margin
WIDE_ABOVE = 0.07
CONFIGS = ("paper", "hold", "validate")
MEAN = "mean_fraction"


def gripper_for(mesh: trimesh.Trimesh, grip_force: float) -> dict:
    g = json.loads((ROOT / "examples" / "pgn-80.json").read_text())
    g["grip_force"] = grip_force
    if min(mesh.bounding_box_oriented.primitive.extents) > WIDE_ABOVE:
        g["name"], g["stroke"] = "pgn-80-wide", WIDE_STROKE
    return g


def parts(names: list[str] | None):
    for folder in FOLDERS:
        units_file = folder / "units.json"
        if not units_file.is_file():
            print(f"skipped: {folder} (missing, or no units.json)", flush=True)
            continue
        units = json.loads(units_file.read_text())
        for file in sorted(units):
            path = folder / file
            if "/" in file or path.suffix.lower() not in (".stl", ".obj") or not path.is_file():
                continue
            name = path.stem
            if not names or name in names:
                yield f"{folder.name}/{name}", load_part(path, units=units[file], name=name)


def _supports(name: str) -> bool:
    return name in inspect.signature(graspgen.generate).parameters


def config_kwargs(config: str, mass: float) -> dict | None:
    """generate()'s keywords for a configuration; None when this checkout's generate cannot run it."""
    if config == "paper":
        return {"hold": "off"} if _supports("hold") else {}
    if not (_supports("hold") and _supports("mass_kg")):
        return None
    kw = {"hold": "any", "mass_kg": mass}
    if config == "validate":
        kw["validate"] = True
    return kw


def export(part, gripper: dict, config: str, args):
    """The grasp set generate() exports for `part` under `config` (args.points, k = args.k1 x args.k2, seed 0,
    args.mass), or None when this checkout's generate cannot run the configuration."""
    kw = config_kwargs(config, args.mass)
    if kw is None:
        return None
    return graspgen.generate(part, gripper, points=args.points, k1=args.k1, k2=args.k2, seed=0, **kw)


def hold_margins_of(part, gs, idx: np.ndarray, spec: GripperSpec, args) -> np.ndarray | None:
    """(e)'s hold margin of candidates `idx`: the candidate set's own when it has them, else computed with
    graspgen.hold the way criterion (e) does (None when this checkout has no graspgen.hold)."""
    c = gs.candidates
    own = getattr(c, "hold_margin", None)
    if own is not None and np.all(np.isfinite(np.asarray(own)[idx])):
        return np.asarray(own, dtype=np.float64)[idx]
    try:
        from graspgen import hold, quality, sampling
    except ImportError:
        return None
    sample = sampling.sample_surface(part, args.points, seed=0)
    pad_radius = min(spec.solids().pad) / 2  # the box finger's face, or a CAD finger's pad
    rho = hold.torsion_radii(sample.points, sample.normals, pad_radius)
    from scipy.spatial import cKDTree

    contacts = c.contacts[idx]
    _, nearest = cKDTree(sample.points).query(contacts.reshape(-1, 3))
    radii = rho[nearest].reshape(-1, 2)
    com = quality.center_of_mass(part.mesh, part.points)
    return hold.hold_margins(
        contacts,
        radii,
        com,
        normals=c.normals[idx],
        load=hold.hold_load(args.mass, 9.81),
        grip_force=args.grip_force,
        friction=spec.friction,
    )


def judge_constants(coacd: str, noslip: int = physics.SIM.noslip_iterations) -> physics.SimConstants:
    """The judging simulations' constants: CoACD's `threshold:max_hulls` and the no-slip iterations (0: MuJoCo's
    soft friction); everything else is the validation's."""
    threshold, hulls = coacd.split(":")
    return dataclasses.replace(
        physics.SIM, noslip_iterations=noslip, coacd_threshold=float(threshold), coacd_max_hulls=int(hulls)
    )


def judge(sim, c, idx: np.ndarray, members, workers: int) -> list[list]:
    """Candidates `idx` of candidate set `c`, each simulated at its exported pose under every member."""
    return physics.simulate_perturbed(
        sim, _poses(c, idx), c.widths[idx], members, seed=0, keys=idx, workers=workers, inside=c.inside[idx]
    )


def run_part(label: str, part, args, members) -> dict:
    if args.gripper:  # a spec file (a CAD gripper's meshes beside it), with --grip-force
        spec = dataclasses.replace(GripperSpec.load(args.gripper), grip_force=args.grip_force)
        gripper: dict | GripperSpec = spec
    else:
        gripper = gripper_for(part.mesh, args.grip_force)
        spec = GripperSpec.from_dict(gripper)
    row = {"part": label, "gripper": spec.name, "configs": {}}
    t0 = time.perf_counter()
    # the judge's simulation; --noslip changes only its friction model (the pipeline's own validation keeps the default)
    sim = physics.prepare_part(
        part.mesh, spec, mass_kg=args.mass, seed=0, constants=judge_constants(args.judge_coacd, args.noslip)
    )
    row["prepare_s"] = time.perf_counter() - t0
    row["geometry"] = f"{sim.geometry} ({sim.pieces})"
    paper_gs = None
    cache: dict = {}
    for config in args.configs:
        if config_kwargs(config, args.mass) is None:
            print(f"  {label} {config}: generate() has no hold/mass_kg in this checkout, skipped", flush=True)
            continue
        t0 = time.perf_counter()
        gs = export(part, gripper, config, args)
        t_gen = time.perf_counter() - t0
        if config == "paper":
            paper_gs = gs
        c = gs.candidates
        idx = np.array([g["candidate"] for g in gs.grasps], dtype=np.int64)
        out = {
            "candidates": len(c),
            "exported": len(idx),
            "generate_s": t_gen,
            "coverage": next(
                (lv["share"] for lv in gs.stats.get("coverage", {}).get("levels", []) if lv["radius"] == 0.01), None
            ),
        }
        if "validation" in gs.stats:
            v = gs.stats["validation"]
            out["validation"] = {k: v.get(k) for k in ("tested", "succeeded", "repaired", "simulated")}
        if len(idx):
            t0 = time.perf_counter()
            # a grasp's outcome depends only on the part, its pose, width, key and the seed: configurations with the
            # same candidate set (hold and validate) share the simulations of the grasps they both export
            cset = hashlib.sha1(np.ascontiguousarray(c.contacts).tobytes()).hexdigest()
            todo = np.array([i for i in idx if (cset, int(i)) not in cache], dtype=np.int64)
            if len(todo):
                new = judge(sim, c, todo, [physics.NOMINAL, *members], args.workers)
                cache.update({(cset, int(i)): g for i, g in zip(todo, new, strict=True)})
            grid = [cache[(cset, int(i))] for i in idx]
            out["sim_s"] = time.perf_counter() - t0
            out["simulated_new"] = len(todo)
            ok = np.array([[r.success for r in g] for g in grid], dtype=bool)  # (k, 1 + members)
            # rows the judge ran again on its finer decomposition (the pads bore on the coarser one's slack), and
            # how far outside the part the pads bore in the nominal outcome that counts
            out["refined"] = sum(g[0].refinements > 0 for g in grid)
            gaps = [g[0].bearing_gap_mm for g in grid if g[0].bearing_gap_mm is not None]
            out["max_bearing_gap_mm"] = max(gaps) if gaps else None
            out["nominal"] = int(ok[:, 0].sum())
            out["all"] = int(ok.all(axis=1).sum())
            out["mean_fraction"] = float(ok[:, 1:].mean())
            out["member_fails"] = {p.name: int((~ok[:, j + 1]).sum()) for j, p in enumerate(members)}
            out["nominal_reasons"] = {
                reason: sum(g[0].reason == reason for g in grid) for reason in physics.REASONS if reason
            }
            margins = [g.get("hold_margin") for g in gs.grasps]
            if any(m is not None for m in margins):
                out["min_hold_margin"] = float(min(m for m in margins if m is not None))
            # each failed grasp with its hold margin: a failure under a load beyond (e)'s design load (mass x1.5
            # with the nominal shake) is expected at a margin near 1, one at a large margin is (e)'s error
            names = [physics.NOMINAL.name, *(p.name for p in members)]
            out["failed"] = [
                {
                    "candidate": int(i),
                    "hold_margin": margins[n],
                    "width_mm": round(1000.0 * float(c.widths[i]), 1),
                    "failed": {names[j]: grid[n][j].reason for j in range(len(names)) if not ok[n, j]},
                }
                for n, i in enumerate(idx)
                if not ok[n].all()
            ]
        row["configs"][config] = out
        print(f"  {label} {config}: {json.dumps(out, default=str)}", flush=True)
    if args.sample > 0 and paper_gs is None:  # the confusion table needs the paper configuration's candidates
        paper_gs = export(part, gripper, "paper", args)
    if args.sample > 0 and len(paper_gs.candidates):
        c = paper_gs.candidates
        n = len(c)
        idx = np.sort(np.random.default_rng(0).choice(n, size=min(args.sample, n), replace=False))
        margins = hold_margins_of(part, paper_gs, idx, spec, args)
        if margins is not None:
            m = min(args.sample_perturbed, len(idx))  # the first m of the sample also under every perturbation
            rest = [physics.NOMINAL] + list(members)
            grid = judge(sim, c, idx, rest[:1], args.workers)
            if m:
                pert = judge(sim, c, idx[:m], rest[1:], args.workers)
                grid = [g + pert[i] if i < m else g for i, g in enumerate(grid)]
            passed = margins >= 1.0
            row["margins_sample"] = [round(float(x), 4) for x in margins]
            for key, sel, cols in (
                ("confusion", slice(None), slice(0, 1)),
                ("confusion_perturbed", slice(0, m), slice(None)),
            ):
                g = grid[sel]
                if not g:
                    continue
                held = np.array([all(r.success for r in row_[cols]) for row_ in g])
                geometric = np.array([row_[0].reason in ("collision", "no_contact") for row_ in g])
                ps = passed[sel]
                row[key] = {
                    "sampled": len(g),
                    "tp": int(np.sum(ps & held)),
                    "fp": int(np.sum(ps & ~held & ~geometric)),
                    "fn": int(np.sum(~ps & held)),
                    "tn": int(np.sum(~ps & ~held & ~geometric)),
                    "geometric": int(np.sum(geometric)),
                }
                print(f"  {label} {key}: {row[key]}", flush=True)
    finer = sim.describe().get("refined")
    if finer is not None:
        row["geometry"] += f", refined coacd ({finer['pieces']})"
    return row


def pct(a, b):
    return "-" if not b else f"{100.0 * a / b:.1f} %"


def _run_arguments(drop: tuple[str, ...] = ("--out", "--json")) -> list[str]:
    """This run's command-line arguments for the text, without the options `drop` (where it wrote) and their values."""
    out, skip = [], False
    for a in sys.argv[1:]:
        if skip:
            skip = False
        elif a in drop:
            skip = True
        elif not a.startswith(tuple(f"{d}=" for d in drop)):
            out.append(a)
    return out


def markdown(rows, members, args, wall_s) -> str:
    cmd = args.command or " ".join(["PYTHONUNBUFFERED=1 .venv/bin/python bench/bench_hold.py", *_run_arguments()])
    lines = [
        START,
        "## Criterion (e) and perturbed validation (issue 14)",
        "",
        f"Made by `{cmd}` ({wall_s / 60:.0f} min; see its docstring). {args.points} points, k = {args.k1} x "
        f"{args.k2}, seed 0, every part {args.mass} kg, grip force {args.grip_force:g} N per finger, friction 0.5, "
        + (
            f"gripper {args.gripper}. "
            if getattr(args, "gripper", None)
            else "gripper pgn-80 (80 mm stroke; `pgn-80-wide`, 140 mm, where the part is wider than 70 mm in every "
            "direction). "
        )
        + "Configurations: `paper` = criteria (a)-(d) (hold off); `hold` = with (e); `validate` = with "
        "(e) and MuJoCo validation + repair. Every exported grasp is simulated nominally and under the "
        f"{len(members)} members of `physics.perturbation_set(0)`: nominal = held in the nominal simulation; all = "
        "held under every member; mean = mean share of members held; cov = stats.coverage at 1 cm / 30 deg. "
        f"Judging simulations with {args.noslip} MuJoCo no-slip iterations (0: MuJoCo's soft friction) and the "
        f"part decomposed by CoACD at threshold:max hulls {args.judge_coacd} (the validation: "
        f"{physics.SIM.coacd_threshold:g}:{physics.SIM.coacd_max_hulls}). "
        f"Machine: {platform.machine()}, {os.cpu_count()} cores shared with other jobs, {args.workers} simulation "
        f"threads, mujoco {__import__('mujoco').__version__}.",
        "",
        "### Total",
        "",
        "| configuration | parts | grasps | nominal | all members | mean share | mean cov | generate time |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for config in args.configs:
        vals = [r["configs"][config] for r in rows if config in r["configs"]]
        if not vals:
            continue
        k = sum(v["exported"] for v in vals)
        nom = sum(v.get("nominal", 0) for v in vals)
        allm = sum(v.get("all", 0) for v in vals)
        mean = sum(v.get("mean_fraction", 0.0) * v["exported"] for v in vals) / k if k else None
        covs = [v["coverage"] for v in vals if v.get("coverage") is not None]
        lines.append(
            f"| {config} | {len(vals)} | {k} | {pct(nom, k)} | {pct(allm, k)} | "
            f"{'-' if mean is None else f'{100 * mean:.1f} %'} | "
            f"{f'{100 * np.mean(covs):.1f} %' if covs else '-'} | {sum(v['generate_s'] for v in vals):.0f} s |"
        )
    lines += [
        "",
        "### Per part",
        "",
        "| part | gripper | configuration | candidates | grasps | nominal | all members | mean share | cov | "
        "generate | validation (held / tested, repaired) | nominal failures |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for config in args.configs:
            v = r["configs"].get(config)
            if v is None:
                continue
            val = v.get("validation")
            vtxt = f"{val['succeeded']} / {val['tested']}, {val['repaired']}" if val else "-"
            k = v["exported"]
            cov = v.get("coverage")
            lines.append(
                f"| {r['part']} | {r['gripper']} | {config} | {v['candidates']:,} | {k} | "
                f"{pct(v.get('nominal', 0), k)} | {pct(v.get('all', 0), k)} | "
                f"{'-' if not k else f'{100 * v.get(MEAN, 0.0):.1f} %'} | "
                f"{'-' if cov is None else f'{100 * cov:.1f} %'} | {v['generate_s']:.1f} s | {vtxt} | "
                + (", ".join(f"{why} {n}" for why, n in v.get("nominal_reasons", {}).items() if n) or "-")
                + " |"
            )
    lines += [
        "",
        "### Failures per perturbation (exported grasps, all parts)",
        "",
        "| perturbation | " + " | ".join(c for c in args.configs if any(c in r["configs"] for r in rows)) + " |",
        "|---|" + "---|" * sum(any(c in r["configs"] for r in rows) for c in args.configs),
    ]
    shown = [c for c in args.configs if any(c in r["configs"] for r in rows)]
    for p in members:
        cells = []
        for config in shown:
            vals = [r["configs"][config] for r in rows if config in r["configs"]]
            fails = sum(v.get("member_fails", {}).get(p.name, 0) for v in vals)
            worst = sorted(
                ((v.get("member_fails", {}).get(p.name, 0), r["part"]) for r, v in zip(rows, vals, strict=False)),
                reverse=True,
            )
            parts_txt = ", ".join(f"{name.split('/')[-1]} {n}" for n, name in worst[:3] if n)
            cells.append(f"{fails}" + (f" ({parts_txt})" if parts_txt else ""))
        lines.append(f"| {p.name} | " + " | ".join(cells) + " |")
    failed = [
        (r["part"], config, f)
        for config in shown
        for r in rows
        if config in r["configs"]
        for f in r["configs"][config].get("failed", [])
    ]
    if failed:
        g, shake = physics.SIM.gravity, physics.SIM.shake_acceleration
        peak = (g + shake) / g  # the nominal simulation's largest load, in g: gravity and the shake along it
        heavy = max(p.mass_scale for p in members)
        design = (g + Params().accel) / g  # what (e) guarantees at margin 1, in g of the nominal weight
        lines += [
            "",
            "### Failed exports and their hold margins",
            "",
            f"Every exported grasp that failed the nominal simulation or a member. The nominal simulation peaks at "
            f"about {peak:.2f} g (gravity and the {shake:g} m/s^2 shake along it), so under mass x{heavy:g} it asks "
            f"for {heavy * peak:.2f} g of the part's nominal weight where (e) guarantees {design:.2f} g: a failure "
            f"there is beyond (e)'s design load below a margin of about {heavy * peak / design:.2f}.",
            "",
            "| part | configuration | candidate | width | hold margin | failed under |",
            "|---|---|---|---|---|---|",
        ]
        for part, config, f in failed:
            m = f.get("hold_margin")
            why = ", ".join(f"{name} ({reason})" for name, reason in f["failed"].items())
            lines.append(
                f"| {part} | {config} | {f['candidate']} | {f['width_mm']} mm | "
                f"{'-' if m is None else f'{m:.2f}'} | {why} |"
            )
    for key, title, what in (
        (
            "confusion",
            "the nominal simulation",
            f"A seeded random sample of the `paper` configuration's candidates per part ({args.sample} unless the "
            "`sampled` column says otherwise); held = held in the nominal simulation.",
        ),
        (
            "confusion_perturbed",
            "the perturbed simulations",
            f"The first {args.sample_perturbed} of that sample per part (unless `sampled` says otherwise); held = "
            "held under the nominal simulation and every member of the perturbation set.",
        ),
    ):
        conf = [r for r in rows if key in r]
        if not conf:
            continue
        tot = {k: sum(r[key][k] for r in conf) for k in ("sampled", "tp", "fp", "fn", "tn", "geometric")}
        lines += [
            "",
            f"### How well (e) predicts {title}",
            "",
            what + " (e) passes: hold margin >= 1 (graspgen.hold.hold_margins with the same mass, grip force and "
            "friction). Candidates the simulation rejects for geometric reasons (collision on the approach, no "
            "contact: not (e)'s question) are counted apart.",
            "",
            "| part | sampled | (e) pass, held | (e) pass, not held | (e) fail, held | (e) fail, not held | "
            "collision / no contact |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in conf + [{"part": "**total**", key: tot}]:
            q = r[key]
            lines.append(
                f"| {r['part']} | {q['sampled']} | {q['tp']} | {q['fp']} | {q['fn']} | {q['tn']} | {q['geometric']} |"
            )
        lines += [
            "",
            f"Of the candidates (e) passes (and the simulation can grip), {pct(tot['tp'], tot['tp'] + tot['fp'])} "
            f"are held; of those it rejects, {pct(tot['fn'], tot['fn'] + tot['tn'])} are held anyway.",
        ]
    geo = [f"{r['part'].split('/')[-1]} {r['geometry']} {r['prepare_s']:.0f} s" for r in rows]
    lines += ["", "Collision geometry of the simulation and time to build it: " + "; ".join(geo) + "."]
    refined = [
        f"{r['part'].split('/')[-1]} {config} {v['refined']}"
        for r in rows
        for config, v in r["configs"].items()
        if v.get("refined")
    ]
    gaps = [v["max_bearing_gap_mm"] for r in rows for v in r["configs"].values() if v.get("max_bearing_gap_mm")]
    lines += [
        "",
        "Exported grasps judged on the part's finer decomposition, because their pads bore more than "
        f"{physics.SIM.bearing_tolerance * 1e3:g} mm outside the part on the first (`SimConstants.bearing_tolerance`"
        "): "
        + (", ".join(refined) or "none")
        + "."
        + (f" Largest bearing gap left in a nominal outcome: {max(gaps):.2f} mm." if gaps else ""),
        END,
    ]
    return "\n".join(lines) + "\n"


def write_block(path: Path, block: str, start: str = START, end: str = END) -> None:
    """Put `block` (which begins with `start` and ends with `end`) in place of the file's block between those
    markers, or append it when the file has none."""
    text = path.read_text() if path.is_file() else ""
    if start in text and end in text:
        head, rest = text.split(start, 1)
        tail = rest.split(end, 1)[1]
        text = head + block.rstrip("\n") + tail
    else:
        text = text.rstrip("\n") + "\n\n" + block
    path.write_text(text)


def add_run_arguments(ap: argparse.ArgumentParser, configs: tuple[str, ...], json_help: str) -> None:
    """The options this bench shares with bench_crosscheck: which parts and configurations, where the markdown and
    the raw rows go, and --render (with --wall and --command) to write the markdown of an earlier run's rows."""
    ap.add_argument("--parts", nargs="*")
    ap.add_argument("--configs", nargs="*", default=list(configs), choices=configs)
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks_quality.md"))
    ap.add_argument("--json", help=json_help)
    ap.add_argument("--render", help="only write the markdown of the rows (--json) of an earlier run")
    ap.add_argument("--wall", type=float, default=None, help="with --render: the earlier run's wall time (s)")
    ap.add_argument("--command", help="with --render: the command line(s) of the earlier run, for the text")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=5000)
    ap.add_argument("--k1", type=int, default=8)
    ap.add_argument("--k2", type=int, default=2)
    ap.add_argument("--mass", type=float, default=0.2)
    ap.add_argument("--grip-force", type=float, default=20.0)
    ap.add_argument(
        "--gripper",
        help="a gripper spec file for every part instead of pgn-80 (e.g. examples/pgn-80-vgroove.json: a gripper "
        "from CAD is simulated with its finger and body meshes); its grip force is --grip-force",
    )
    ap.add_argument(
        "--noslip",
        type=int,
        default=physics.SIM.noslip_iterations,
        help="MuJoCo no-slip iterations of the judging simulations (0: MuJoCo's soft friction, which creeps)",
    )
    ap.add_argument(
        "--judge-coacd",
        default=f"{physics.SIM.coacd_threshold:g}:{physics.SIM.coacd_max_hulls}",
        help="CoACD threshold:max_hulls of the judging simulations (default the validation's; finer = closer to the "
        "part, slower to build)",
    )
    ap.add_argument("--sample", type=int, default=200)
    ap.add_argument("--sample-perturbed", type=int, default=30)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--merge", help="rows (--json) of an earlier run: its configurations are kept, this run's added")
    add_run_arguments(ap, CONFIGS, "also write the raw rows here")
    args = ap.parse_args()
    members = physics.perturbation_set(0)
    earlier = {r["part"]: r for r in json.loads(Path(args.merge).read_text())} if args.merge else {}
    rows = []
    t_all = time.perf_counter()
    for label, part in [] if args.render else parts(args.parts):
        t0 = time.perf_counter()
        row = run_part(label, part, args, members)
        old = earlier.pop(label, None)
        if old is not None:
            row = {
                **old,
                **{k: v for k, v in row.items() if k != "configs"},
                "configs": {**old["configs"], **row["configs"]},
            }
        rows.append(row)
        print(f"{label}: {time.perf_counter() - t0:.0f} s", flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1, default=str))
    rows += list(earlier.values())
    if args.render:
        rows = json.loads(Path(args.render).read_text())
    args.configs = [c for c in CONFIGS if any(c in r["configs"] for r in rows)]
    block = markdown(rows, members, args, args.wall or time.perf_counter() - t_all)
    if args.out:
        write_block(Path(args.out), block)
    print(block)


if __name__ == "__main__":
    main()
