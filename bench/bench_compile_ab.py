"""Cold compile of `graspgen warmup`: another revision against this tree, alternated, each on an empty numba cache.

    .venv/bin/python bench/bench_compile_ab.py --base 197af76 --pairs 3
    .venv/bin/python bench/bench_compile_ab.py --base 197af76 --this 700afa0 --pairs 3   # two revisions

The base revision's `graspgen/` is exported as the package `graspgen_base` (bench_ab.export_base). Each run is a new
process with NUMBA_CACHE_DIR pointing to a new, empty directory, running `warmup()` of its side: base, this tree,
base, this tree ... `--pairs` times. Compiling is single-threaded, so besides the wall time of each warmup step the
table gives the process's CPU seconds (user + system, imports included), which other work on the host slows less
than it slows the wall clock. "common steps" sums the steps both revisions' warmup runs (a step added since the base
compiles kernels the base does not have).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_ab import ROOT, export_base  # noqa: E402

CHILD = """
import json, resource, sys
sys.path.insert(0, sys.argv[1])
mod = __import__(sys.argv[2] + ".warmup", fromlist=["warmup"])
steps = mod.warmup()["steps"]
ru = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"steps": steps, "cpu": ru.ru_utime + ru.ru_stime}))
"""


def one(root: Path, package: str, cache: Path) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    env.pop("PYTHONPATH", None)
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(root), package], env=env, cwd=root, capture_output=True, check=True, text=True
    ).stdout
    data = json.loads(out.strip().splitlines()[-1])
    steps = data["steps"]
    named = dict(steps) if isinstance(steps, list) else {k: float(v) for k, v in steps.items()}
    return {"steps": named, "cpu": float(data["cpu"])}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", required=True, help="the revision to compare against (e.g. 197af76)")
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--this", default=None, help="a revision in place of this tree (the working tree by default)")
    a = ap.parse_args()
    runs: dict[str, list[dict]] = {"base": [], "this": []}
    with tempfile.TemporaryDirectory(prefix="bench-compile-") as tmp:
        tmp_path = Path(tmp)
        export_base(a.base, tmp_path / "base")
        this_root, this_package = ROOT, "graspgen"
        if a.this is not None:
            this_root, this_package = tmp_path / "this", "graspgen_this"
            export_base(a.this, this_root, this_package)
        sides = (("base", tmp_path / "base", "graspgen_base"), ("this", this_root, this_package))
        for k in range(a.pairs):
            for side, root, package in sides:
                r = one(root, package, tmp_path / f"cache-{side}-{k}")
                runs[side].append(r)
                print(f"# pair {k + 1} {side}: cpu {r['cpu']:.1f} s", file=sys.stderr, flush=True)
    common = [s for s in runs["base"][0]["steps"] if s in runs["this"][0]["steps"]]
    added = [s for s in runs["this"][0]["steps"] if s not in runs["base"][0]["steps"]]

    def med(side: str, fn: Callable[[dict], float]) -> float:
        return statistics.median(fn(r) for r in runs[side])

    def step(name: str) -> Callable[[dict], float]:
        return lambda r: float(r["steps"][name])

    rows: list[tuple[str, Callable[[dict], float]]] = [(s, step(s)) for s in common]
    rows.append(("common steps, wall", lambda r: sum(r["steps"][s] for s in common)))
    rows.append(("all steps, wall", lambda r: sum(r["steps"].values())))
    rows.append(("process CPU (user + system)", lambda r: float(r["cpu"])))
    this = "this tree" if a.this is None else a.this
    print(f"| step (median of {a.pairs} cold runs each) | base {a.base} (s) | {this} (s) | this / base |")
    print("|---|---:|---:|---:|")
    for name, fn in rows:
        b, t = med("base", fn), med("this", fn)
        print(f"| {name} | {b:.1f} | {t:.1f} | {t / b:.2f} |")
    if added:
        print(f"\nsteps only this tree runs: {', '.join(added)}")
    print("\nper run, process CPU s: " + json.dumps({k: [round(r["cpu"], 1) for r in v] for k, v in runs.items()}))
    per_run = {k: [round(sum(r["steps"][s] for s in common), 1) for r in v] for k, v in runs.items()}
    print("per run, common steps s: " + json.dumps(per_run))
    ratios = [t / b for t, b in zip(per_run["this"], per_run["base"], strict=True)]
    print(f"paired ratio of the common steps (this / base, pair by pair): {[round(x, 2) for x in ratios]}")


if __name__ == "__main__":
    main()
