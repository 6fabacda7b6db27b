"""Core benchmark (issue 3): the pipeline per part at 10,000 points, (a)-(c) against plain numpy, and scaling.

    .venv/bin/python bench/bench_core.py                  # everything (tens of minutes)
    .venv/bin/python bench/bench_core.py --quick          # example parts and tless_04 only, no 100k run
    .venv/bin/python bench/bench_core.py --kernels-only   # only the kernel tables (criteria (a)-(d)), see below
    .venv/bin/python bench/bench_core.py --kernels-only --no-scaling --repeat 3   # 10,000 points, median of 3
    .venv/bin/python bench/bench_core.py --scaling-only   # the pipeline at 10,000, 30,000 and 100,000 points
    git show <commit>:graspgen/collision.py > /tmp/collision_base.py
    .venv/bin/python bench/bench_core.py --kernels-only --baseline /tmp/collision_base.py   # that kernel beside this

Each measurement runs in its own process (peak memory = that process's ru_maxrss), warm: the process first runs the
pipeline once on a small part so numba's compiled code is loaded. Prints Markdown tables.

The kernel tables call the kernels directly (antipodal_pairs, free_rolls) the way the pipeline does, on tless_04
and the issue's thick ring (annulus 10-30 mm, 20 mm high, 64 sections), in `swept` and `paper` mode, and report CPU
time (time.process_time, summed over numba's threads) beside wall time, because the machine's cores are shared,
plus the work counts of the collision kernel (tree nodes visited and points tested per candidate). At 100,000
points the kernel table times the collision kernel on an evenly spread subset of the candidates (contiguous blocks,
so their order stays the pipeline's), marked "subset", to bound the benchmark's time; the scaling table runs the
whole pipeline there, which streams the pairs through collision in blocks (pipeline._PAIR_BLOCK).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
GRIPPER = json.loads((ROOT / "examples" / "pgn-80.json").read_text())


def _child(spec: dict) -> dict:
    import resource

    import numpy as np
    import trimesh

    import graspgen
    from graspgen import antipodal
    from graspgen.examples import example_part
    from graspgen.parts import load_part

    warm = trimesh.creation.box(extents=[0.03, 0.02, 0.02])
    graspgen.generate(warm, GRIPPER, units="m", points=500, k1=2, k2=1)
    if spec["kind"] == "example":
        part = example_part(spec["name"])
    else:
        part = load_part(spec["path"], units=spec["units"], name=spec["name"])
    t0, c0 = time.perf_counter(), time.process_time()
    gs = graspgen.generate(part, GRIPPER, points=spec["points"], collision=spec.get("collision", "swept"))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    out = {
        "name": spec["name"],
        "points": gs.stats["points"],
        "pairs": gs.stats["pairs_total"],
        "rejected": gs.stats["rejected"],
        "candidates": gs.stats["candidates"],
        "grasps": len(gs.grasps),
        "timings": gs.stats["timings_s"],
        "wall": wall,
        "cpu": cpu,
    }
    if spec.get("numpy"):
        from graspgen.sampling import sample_surface

        s = sample_surface(part, spec["points"], seed=0)
        p, n = s.points, s.normals
        cos_lim = math.cos(antipodal.cone_half_angle_rad(GRIPPER["friction"], 1.5))
        t0 = time.perf_counter()
        accepted = 0
        for i0 in range(0, len(p), 256):  # plain numpy, row blocks against all later points
            for i in range(i0, min(i0 + 256, len(p))):
                d = p[i + 1 :] - p[i]
                dist = np.linalg.norm(d, axis=1)
                a = d @ n[i]
                b = np.sum(n[i + 1 :] * d, axis=1)
                ok = (dist <= GRIPPER["stroke"]) & (a < 0) & (b > 0) & (-a >= cos_lim * dist) & (b >= cos_lim * dist)
                accepted += int(ok.sum())
        out["numpy_abc_s"] = time.perf_counter() - t0
        out["numpy_accepted"] = accepted
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


#: the issue's thick ring (the example part "thick-ring" has 128 sections)
RING_SPEC = {"kind": "ring", "name": "ring (issue)", "units": "m"}
#: the collision kernel runs on at most this many candidates per measurement (memory: ~60 bytes each)
KERNEL_MAX_CANDIDATES = 16_000_000


def _numpy_abc(p, n, stroke, cos_lim, rows=128):
    """Criteria (a)-(c) in plain numpy, blocks of rows against all later points: per-criterion counts."""
    import numpy as np

    total = acc = rej_stroke = rej_outside = 0
    for i0 in range(0, len(p), rows):
        i1 = min(i0 + rows, len(p))
        d = p[None, :, :] - p[i0:i1, None, :]  # (rows, n, 3): d[r, j] = p[j] - p[i0 + r]
        later = np.arange(len(p))[None, :] > np.arange(i0, i1)[:, None]
        dist = np.sqrt(np.einsum("rjk,rjk->rj", d, d))
        u = np.einsum("rjk,rk->rj", d, n[i0:i1])
        v = np.einsum("rjk,jk->rj", d, n)
        in_stroke = later & (dist <= stroke)
        oriented = in_stroke & (u < 0) & (v > 0)
        ok = oriented & (-u >= cos_lim * dist) & (v >= cos_lim * dist)
        total += int(later.sum())
        rej_stroke += int((later & ~in_stroke).sum())
        rej_outside += int((in_stroke & ~oriented).sum())
        acc += int(ok.sum())
    return {"total": total, "accepted": acc, "stroke": rej_stroke, "outside": rej_outside}


def _kernel_child(spec: dict) -> dict:
    import resource

    import numpy as np
    import trimesh

    from graspgen import antipodal, collision
    from graspgen.gripper import GripperSpec
    from graspgen.parts import load_part
    from graspgen.sampling import sample_surface

    gripper = GripperSpec(**{k: v for k, v in GRIPPER.items() if k not in ("min_width", "palm_width")})
    if spec["kind"] == "ring":
        part = load_part(trimesh.creation.annulus(r_min=0.01, r_max=0.03, height=0.02, sections=64), units="m")
    else:
        part = load_part(spec["path"], units=spec["units"], name=spec["name"])
    kw = dict(
        stroke=gripper.stroke,
        min_width=gripper.min_width,
        friction=gripper.friction,
        safety_factor=1.5,
        inside=False,
        finger_thickness=gripper.finger_thickness,
    )

    def clock():
        return time.perf_counter(), time.process_time()

    t0 = clock()
    s = sample_surface(part, spec["points"], seed=0)
    order = antipodal.grid_order(s.points, antipodal.pair_cell_size(gripper.stroke, False, gripper.finger_thickness))
    pts, nrm = s.points[order], s.normals[order]
    t1 = clock()
    out = {"name": spec["name"], "points": len(pts), "sample_wall": t1[0] - t0[0], "sample_cpu": t1[1] - t0[1]}
    # warm: load the compiled kernels on a small slice
    # (points spread over the whole part, so that some pairs pass and the collision kernel really runs)
    wp, wn = pts[:: max(1, len(pts) // 400)], nrm[:: max(1, len(pts) // 400)]
    small = antipodal.antipodal_pairs(wp, wn, **kw)
    assert len(small.i) > 0, "warm-up without pairs"
    sm = 0.5 * (wp[small.i] + wp[small.j])
    sd = wp[small.j] - wp[small.i]
    for mode in ("swept", "paper"):
        model = collision.collision_model(gripper, mode)
        w = np.linalg.norm(sd, axis=1)
        collision.free_rolls_stats(wp, wn, sm, sd / w[:, None], w, small.inside, model, 16)
    t0 = clock()
    res = antipodal.antipodal_pairs(pts, nrm, **kw)
    t1 = clock()
    out.update(
        pairs_total=res.pairs_total,
        rej_stroke=res.rejected_stroke,
        rej_outside=res.rejected_outside,
        rej_friction=res.rejected_friction,
        pairs=len(res.i),
        pairs_wall=t1[0] - t0[0],
        pairs_cpu=t1[1] - t0[1],
    )
    sel = np.arange(len(res.i))
    if len(sel) > KERNEL_MAX_CANDIDATES:  # evenly spread contiguous blocks
        blocks = np.arange(0, len(sel), 4096)
        keep = blocks[:: int(math.ceil(len(sel) / KERNEL_MAX_CANDIDATES))]
        sel = (keep[:, None] + np.arange(4096)[None, :]).ravel()
        sel = sel[sel < len(res.i)]
    out["collision_candidates"] = len(sel)
    ci, cj, inside = res.i[sel], res.j[sel], res.inside[sel]
    del res
    for mode in ("swept", "paper"):
        model = collision.collision_model(gripper, mode)
        t0 = clock()
        # as the pipeline calls it: point index pairs, the kernel derives midpoints, axes and widths
        fr, work = collision.free_rolls_stats(pts, nrm, None, None, None, inside, model, 16, pairs=(ci, cj))
        t1 = clock()
        out[mode] = {
            "wall": t1[0] - t0[0],
            "cpu": t1[1] - t0[1],
            "free": int(fr.any(axis=1).sum()),
            "free_rolls": int(fr.sum()),
            "work": {k: v / max(len(sel), 1) for k, v in work.items()},
        }
        if spec.get("baseline"):  # another version of graspgen/collision.py, e.g. from git history: same inputs
            import hashlib
            import importlib.util

            # numba names its cache files by module, function and line: two different files loaded in turn
            # under one module name from one folder were seen to give wrong masks, so the name carries a hash
            # of the file's content
            digest = hashlib.blake2b(Path(spec["baseline"]).read_bytes(), digest_size=6).hexdigest()
            name = f"graspgen._collision_baseline_{digest}"
            mod = sys.modules.get(name)
            if mod is None:
                mspec = importlib.util.spec_from_file_location(name, spec["baseline"])
                mod = importlib.util.module_from_spec(mspec)
                sys.modules[name] = mod
                mspec.loader.exec_module(mod)
            d = pts[cj] - pts[ci]
            w = np.linalg.norm(d, axis=1)
            args = (
                pts,
                nrm,
                0.5 * (pts[ci] + pts[cj]),
                d / w[:, None],
                w,
                inside,
                mod.collision_model(gripper, mode),
                16,
            )
            mod.free_rolls(*args[:2], *(a[:2000] for a in args[2:6]), *args[6:])  # compile / load
            t0 = clock()
            base = mod.free_rolls(*args)
            t1 = clock()
            out[mode]["baseline"] = {
                "wall": t1[0] - t0[0],
                "cpu": t1[1] - t0[1],
                "equal": bool(np.array_equal(base, fr)),
            }
            del base, args, d, w
        del fr
    if spec.get("numpy"):
        t0 = clock()
        npy = _numpy_abc(pts, nrm, gripper.stroke, math.cos(antipodal.cone_half_angle_rad(gripper.friction, 1.5)))
        t1 = clock()
        out["numpy"] = {**npy, "wall": t1[0] - t0[0], "cpu": t1[1] - t0[1]}
    out["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def _kernel_tables(quick: bool, baseline: str | None = None, no_scaling: bool = False, repeat: int = 1) -> None:
    parts = [RING_SPEC]
    if (SHARED / "tless_04.stl").is_file():
        parts.insert(0, {"kind": "file", "name": "tless_04", "path": str(SHARED / "tless_04.stl"), "units": "mm"})
    else:
        print(f"(tless_04 not found at {SHARED}: the ring only)")
    print(
        "\nKernels (a)-(d) at 10,000 points, swept and paper collision (CPU = process time over both threads; "
        "work = per candidate):\n"
    )
    print(
        "| part | pairs total | rej. stroke | rej. outside | rej. friction | (a)-(c) pass | sample s | pairs s (CPU) | "
        "swept: free | swept s (CPU) | paper: free | paper s (CPU) | (a)-(d) swept s (CPU) | swept work: nodes f+p, "
        "points f+p, probes | peak MB | numpy (a)-(c) s (x) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|")
    rows = {}
    for spec in parts:
        runs = [
            _run({**spec, "points": 10_000, "numpy": k == 0, "baseline": baseline}, kernels=True)
            for k in range(max(repeat, 1))
        ]
        runs.sort(key=lambda r: r["pairs_wall"] + r["swept"]["wall"])
        r = runs[len(runs) // 2]
        r["numpy"] = next(x["numpy"] for x in runs if "numpy" in x)
        if repeat > 1:
            spread = [f"{x['pairs_wall'] + x['swept']['wall']:.2f}" for x in runs]
            print(f"({spec['name']}: (a)-(d) swept s over {repeat} processes: {', '.join(spread)}; the median shown)")
        rows[(spec["name"], 10_000)] = r
        sw, pa, wk, npy = r["swept"], r["paper"], r["swept"]["work"], r["numpy"]
        same = "" if npy["accepted"] == r["pairs"] and npy["outside"] == r["rej_outside"] else " MISMATCH"
        print(
            f"| {r['name']} | {r['pairs_total']:,} | {r['rej_stroke']:,} | {r['rej_outside']:,} | "
            f"{r['rej_friction']:,} | {r['pairs']:,} | {r['sample_wall']:.2f} | {r['pairs_wall']:.2f} "
            f"({r['pairs_cpu']:.2f}) | {sw['free']:,} | {sw['wall']:.2f} ({sw['cpu']:.2f}) | {pa['free']:,} | "
            f"{pa['wall']:.2f} ({pa['cpu']:.2f}) | {r['pairs_wall'] + sw['wall']:.2f} "
            f"({r['pairs_cpu'] + sw['cpu']:.2f}) | {wk['finger_nodes']:.0f}+{wk['palm_nodes']:.0f}, "
            f"{wk['finger_points']:.1f}+{wk['palm_points']:.1f}, {wk['cache_tests'] + wk['memo_tests']:.1f} | "
            f"{r['peak_mb']:.0f} | {npy['wall']:.1f} ({npy['wall'] / r['pairs_wall']:.0f}x){same} |",
            flush=True,
        )
    if baseline:
        print(f"\nCollision kernel against {baseline} on the same candidates (s, CPU in brackets):\n")
        print("| part | mode | baseline s (CPU) | this s (CPU) | CPU ratio | masks equal |")
        print("|---|---|---:|---:|---:|---|")
        for spec in parts:
            r = rows[(spec["name"], 10_000)]
            for mode in ("swept", "paper"):
                m, b = r[mode], r[mode]["baseline"]
                print(
                    f"| {r['name']} | {mode} | {b['wall']:.2f} ({b['cpu']:.2f}) | {m['wall']:.2f} ({m['cpu']:.2f}) | "
                    f"{b['cpu'] / max(m['cpu'], 1e-9):.1f}x | {b['equal']} |",
                    flush=True,
                )
    print("\nKernel scaling (swept; collision per candidate in microseconds of CPU; subset = see docstring):\n")
    print(
        "| part | points | (a)-(c) pass | pairs s (CPU) | collided | swept s (CPU) | us CPU / candidate | "
        "nodes / candidate | peak MB |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    sizes = (10_000, 30_000) if quick else (10_000, 30_000, 100_000)
    if no_scaling:
        sizes = (10_000,)
    for spec in parts:
        got = []
        for n in sizes:
            r = rows.get((spec["name"], n)) or _run({**spec, "points": n}, kernels=True)
            got.append(r)
            sw = r["swept"]
            sub = " (subset)" if r["collision_candidates"] < r["pairs"] else ""
            print(
                f"| {r['name']} | {r['points']:,} | {r['pairs']:,} | {r['pairs_wall']:.2f} ({r['pairs_cpu']:.2f}) | "
                f"{r['collision_candidates']:,}{sub} | {sw['wall']:.2f} ({sw['cpu']:.2f}) | "
                f"{1e6 * sw['cpu'] / max(r['collision_candidates'], 1):.2f} | "
                f"{sw['work']['finger_nodes'] + sw['work']['palm_nodes']:.0f} | {r['peak_mb']:.0f} |",
                flush=True,
            )
        if len(got) < 2:
            continue
        x = [math.log(r["points"]) for r in got]
        for key, f in (
            ("pairs CPU", lambda r: r["pairs_cpu"]),
            ("(a)-(c) pairs", lambda r: r["pairs"]),
            ("collision CPU per candidate", lambda r: r["swept"]["cpu"] / max(r["collision_candidates"], 1)),
            (
                "collision CPU, all candidates",
                lambda r: r["swept"]["cpu"] * r["pairs"] / max(r["collision_candidates"], 1),
            ),
        ):
            y = [math.log(max(f(r), 1e-12)) for r in got]
            slope = (y[-1] - y[0]) / (x[-1] - x[0])
            print(f"\n{spec['name']}: {key} grows as points^{slope:.2f} ({sizes[0]:,} -> {sizes[-1]:,})")


def _machine() -> str:
    """Cores, load and the CPU as numba's compiler sees it: kernel times are only comparable between runs on the same
    CPU (two 2-core hosts of this project differed 1.7-1.9x on the collision kernel)."""
    import llvmlite.binding as llvm

    llvm.initialize_native_target()
    flags = ""
    with contextlib.suppress(OSError, StopIteration):
        flags = next(ln for ln in Path("/proc/cpuinfo").read_text().splitlines() if ln.startswith("flags"))
    simd = "AVX-512" if " avx512f" in flags else "AVX2" if " avx2" in flags else "no AVX2"
    return f"{os.cpu_count()} cores ({llvm.get_host_cpu_name()}, {simd}), load {os.getloadavg()[0]:.1f}"


def _run(spec: dict, kernels: bool = False) -> dict:
    r = subprocess.run(
        [sys.executable, __file__, "--kernel-child" if kernels else "--child", json.dumps(spec)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=3600,
    )
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-2000:])
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scaling-only", action="store_true")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--kernels-only", action="store_true")
    ap.add_argument("--no-scaling", action="store_true", help="the 10,000-point table(s) only")
    ap.add_argument(
        "--repeat", type=int, default=1, help="kernel table: processes per part; the one with the median (a)-(d) time"
    )
    ap.add_argument("--baseline", help="another graspgen/collision.py (e.g. from git show) to time on the same input")
    ap.add_argument("--child")
    ap.add_argument("--kernel-child")
    args = ap.parse_args()
    if args.child:
        print(json.dumps(_child(json.loads(args.child))))
        return
    if args.kernel_child:
        print(json.dumps(_kernel_child(json.loads(args.kernel_child))))
        return
    if args.kernels_only:
        print(f"machine: {_machine()}; gripper pgn-80, 16 rolls")
        _kernel_tables(args.quick, args.baseline and str(Path(args.baseline).resolve()), args.no_scaling, args.repeat)
        return
    from graspgen.examples import EXAMPLES

    parts = [{"kind": "example", "name": n} for n in EXAMPLES]
    if SHARED.is_dir():
        units = json.loads((SHARED / "units.json").read_text())
        names = ["tless_04.stl"] if args.quick else sorted(f for f in units if not f.startswith("bad/"))
        parts += [{"kind": "file", "name": Path(f).stem, "path": str(SHARED / f), "units": units[f]} for f in names]
    else:
        print(f"(../shared/meshes not found at {SHARED}: example parts only)")
    print(f"machine: {_machine()}; gripper pgn-80 (examples/pgn-80.json), swept collision, 16 rolls, k1=16 k2=4\n")
    print(
        "| part | points | pairs | rej. stroke | rej. outside | rej. friction | rej. collision | candidates | "
        "sample s | pairs s | collision s | cluster s | total s | CPU s | peak MB | numpy (a)-(c) s |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for spec in [] if args.scaling_only else parts:
        spec = {**spec, "points": 10_000, "numpy": spec["name"] in ("thick-ring", "tless_04")}
        r = _run(spec)
        t, rej = r["timings"], r["rejected"]
        npy = f"{r['numpy_abc_s']:.1f} ({r['numpy_abc_s'] / t['pairs']:.0f}x)" if "numpy_abc_s" in r else ""
        print(
            f"| {r['name']} | {r['points']} | {r['pairs']:,} | {rej['stroke']:,} | {rej['outside']:,} | "
            f"{rej['friction']:,} | {rej['collision']:,} | {r['candidates']:,} | {t['sample']:.2f} | "
            f"{t['pairs']:.2f} | {t['collision']:.2f} | {t['cluster']:.2f} | {r['wall']:.2f} | {r['cpu']:.2f} | "
            f"{r['peak_mb']:.0f} | {npy} |",
            flush=True,
        )
    if args.no_scaling:
        return
    print("\nScaling (pairs + collision + cluster, wall):\n")
    print("| part | points | candidates | pairs s | collision s | cluster s | total s | peak MB |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    sizes = (10_000, 30_000) if args.quick else (10_000, 30_000, 100_000)
    scale_parts = [p for p in parts if p["name"] in ("thick-ring", "tless_04")]
    for spec in scale_parts:
        rows = []
        for n in sizes:
            try:
                r = _run({**spec, "points": n})
            except RuntimeError as exc:  # refused (MAX_CANDIDATES) or failed: say so in the table
                reason = str(exc).strip().splitlines()[-1][:160]
                print(f"| {spec['name']} | {n} | refused: {reason} |||||||", flush=True)
                continue
            rows.append(r)
            t = r["timings"]
            print(
                f"| {r['name']} | {r['points']} | {r['candidates']:,} | {t['pairs']:.2f} | {t['collision']:.2f} | "
                f"{t['cluster']:.2f} | {r['wall']:.2f} | {r['peak_mb']:.0f} |",
                flush=True,
            )
        if len(rows) < 2:
            continue
        x = [math.log(r["points"]) for r in rows]
        for key in ("pairs", "collision"):
            y = [math.log(max(r["timings"][key], 1e-6)) for r in rows]
            slope = (y[-1] - y[0]) / (x[-1] - x[0])
            span = f"{rows[0]['points']} -> {rows[-1]['points']}"
            print(f"\n{spec['name']}: {key} time grows as points^{slope:.2f} ({span})")
    if not args.scaling_only:
        _kernel_tables(args.quick, args.baseline and str(Path(args.baseline).resolve()))


if __name__ == "__main__":
    main()
