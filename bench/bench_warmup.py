"""No cold start (issue 16.5): the first 10,000-point tless_04 job of a fresh install, without and with warmup.

    .venv/bin/python bench/bench_warmup.py [--skip-cold]

A fresh install is simulated by an empty numba cache (NUMBA_CACHE_DIR pointing to a new directory). Each line is
one new process, timed end to end from the outside (`graspgen generate` with interpreter start, imports, loading
the part, the job and writing the export): first on the empty cache; then `graspgen warmup` on another empty cache
(what scripts/setup.sh and the Dockerfile run), followed by the same job twice in new processes. Prints a Markdown
table; `core s` is the job's own time (stats.timings_s.total: load to export, without imports).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GRASPGEN = str(Path(sys.executable).with_name("graspgen"))
MESH = ROOT.parent / "shared" / "meshes" / "tless_04.stl"


def _timed(args: list[str], cache: Path, out: Path | None = None) -> tuple[float, float | None]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    t0 = time.perf_counter()
    subprocess.run(args, env=env, check=True, capture_output=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    core = None
    if out is not None:
        core = float(json.loads(out.read_text())["stats"]["timings_s"]["total"])
    return wall, core


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--skip-cold", action="store_true", help="leave out the first job on an empty cache")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-warmup-") as tmp:
        tmp = Path(tmp)
        out = tmp / "grasps.json"
        job = [GRASPGEN, "generate", str(MESH), "--units", "mm", "--gripper", str(ROOT / "examples" / "pgn-80.json")]
        job += ["--points", "10000", "--out", str(out), "--quiet"]
        rows = []
        if not a.skip_cold:
            wall, core = _timed(job, tmp / "cold", out)
            rows.append(("first job, empty cache (fresh install, no warmup)", wall, core))
        wall, _ = _timed([GRASPGEN, "warmup", "--quiet"], tmp / "warm")
        rows.append(("`graspgen warmup` on an empty cache (set-up)", wall, None))
        for k in (1, 2):
            wall, core = _timed(job, tmp / "warm", out)
            rows.append((f"job {k} after warmup, new process", wall, core))
    print("| run (tless_04, 10,000 points, new process) | wall s, end to end | core s |")
    print("|---|---:|---:|")
    for name, wall, core in rows:
        print(f"| {name} | {wall:.1f} | {'' if core is None else f'{core:.2f}'} |")


if __name__ == "__main__":
    main()
