"""Benchmark of graspgen.clustering.two_stage: time, peak memory, and loss against the `kmedoids` package.

    .venv/bin/python bench/bench_clustering.py [--sizes 10000 100000 1000000] [--quality 1000 3000 10000]
                                               [--heavy 100000 1000000] [--reps 3]

Synthetic candidates shaped like real ones: a 120 x 80 x 50 mm box with a 15 mm radius, 40 mm boss on top. Box
candidates pair opposite faces (by face area), their axes tilted inside a 15 degree friction cone and their midpoints
halfway between the contacts; boss candidates are radial pairs through the cylinder axis. Contacts come in either
order, so the axes come with either sign.

Each size runs in its own process, so that the peak resident memory (ru_maxrss) belongs to that size alone; the
kernels are compiled (or loaded from numba's cache) and warmed on 5,000 candidates first, so times are warm. The
quality rows compare each stage with the `kmedoids` package (GPL-3, used here only as a yardstick) on the full
dissimilarity matrix: stage one on all midpoints, stage two on each of our translation clusters, best of 3 seeds.
Where that matrix does not fit, the heavy rows compare with our own CLARA at 4,000-point samples and 10 draws (an
estimate of what the default 1,000 + 50 k samples and 5 draws leave on the table, not a bound).
No assertions: the numbers are for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

K1, K2 = 16, 4


def synthetic_candidates(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) midpoints in metres and (n, 3) unit closing axes of grasp-like candidates."""
    rng = np.random.default_rng(seed)
    size = np.array([0.12, 0.08, 0.05])
    n_boss = int(0.3 * n)
    n_box = n - n_boss

    # box: the axis of a face pair plus a tilt inside the friction cone; contact 0 on the - face, 1 on the + face
    areas = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
    face = rng.choice(3, size=n_box, p=areas / areas.sum())
    axes = np.eye(3)[face]
    tilt = rng.normal(scale=np.tan(np.radians(15.0)) / 2, size=(n_box, 3))
    tilt[np.arange(n_box), face] = 0.0
    axes = axes + tilt
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    c0 = rng.random((n_box, 3)) * size
    c0[np.arange(n_box), face] = 0.0
    depth = size[face]
    c1 = c0 + axes * (depth / axes[np.arange(n_box), face])[:, None]
    box_mid = np.clip((c0 + c1) / 2, 0.0, size)

    # boss on top of the box: radial pairs through the cylinder axis, slightly off-centre
    r, h = 0.015, 0.04
    phi = rng.uniform(0, np.pi, n_boss)
    boss_axes = np.column_stack([np.cos(phi), np.sin(phi), rng.normal(scale=0.05, size=n_boss)])
    boss_axes /= np.linalg.norm(boss_axes, axis=1, keepdims=True)
    offset = rng.normal(scale=0.1 * r, size=(n_boss, 2))
    boss_mid = np.column_stack(
        [size[0] / 2 + offset[:, 0], size[1] / 2 + offset[:, 1], size[2] + rng.uniform(0, h, n_boss)]
    )

    midpoints = np.concatenate([box_mid, boss_mid])
    axes = np.concatenate([axes, boss_axes]) * rng.choice([-1.0, 1.0], size=(n, 1))
    perm = rng.permutation(n)
    return np.ascontiguousarray(midpoints[perm]), np.ascontiguousarray(axes[perm])


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


def run_timing(n: int, reps: int) -> dict:
    from graspgen.clustering import two_stage

    P, A = synthetic_candidates(n)
    two_stage(P[:5000], A[:5000], K1, K2)  # compile / load the cache, start the thread pools
    base = _rss_mb()
    times, cpu = [], []
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        r = two_stage(P, A, K1, K2, seed=0)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return {
        "n": n,
        "median_s": float(np.median(times)),
        "min_s": float(min(times)),
        "cpu_s": float(np.median(cpu)),
        "peak_rss_mb": _peak_mb(),
        "rss_before_mb": base,
        "medoids": int(r.medoids.size),
        "loss_translation": r.loss_translation,
        "loss_direction": r.loss_direction,
    }


def run_quality(n: int) -> dict:
    import kmedoids as reference

    from graspgen.clustering import dissimilarities, two_stage

    P, A = synthetic_candidates(n, seed=1)
    t0 = time.perf_counter()
    r = two_stage(P, A, K1, K2, seed=0)
    ours_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref_t = min(reference.fasterpam(dissimilarities(P), K1, random_state=s).loss for s in range(3))
    ref_d = 0.0
    for t in range(r.translation_medoids.size):
        members = np.flatnonzero(r.labels[:, 0] == t)
        if members.size > K2:
            D = dissimilarities(A[members], metric="axis")
            ref_d += min(reference.fasterpam(D, K2, random_state=s).loss for s in range(3))
    ref_s = time.perf_counter() - t0
    return {
        "n": n,
        "ratio_translation": r.loss_translation / ref_t,
        "ratio_direction": r.loss_direction / ref_d,
        "ours_s": ours_s,
        "reference_s": ref_s,
    }


def run_heavy(n: int) -> dict:
    """Where no exact reference fits in memory: the defaults against CLARA with 4,000-point samples and 10 draws."""
    from graspgen.clustering import kmedoids, two_stage

    P, A = synthetic_candidates(n, seed=1)
    r = two_stage(P, A, K1, K2, seed=0)
    t0 = time.perf_counter()
    heavy_t = kmedoids(P, K1, seed=1, sample_size=4000, draws=10).loss
    heavy_d = 0.0
    for t in range(r.translation_medoids.size):
        members = np.flatnonzero(r.labels[:, 0] == t)
        heavy_d += kmedoids(A[members], K2, metric="axis", seed=1, sample_size=4000, draws=10).loss
    return {
        "n": n,
        "ratio_translation": r.loss_translation / heavy_t,
        "ratio_direction": r.loss_direction / heavy_d,
        "heavy_s": time.perf_counter() - t0,
    }


def _child(kind: str, n: int, reps: int) -> dict:
    cmd = [sys.executable, __file__, "--child", kind, str(n), "--reps", str(reps)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--quality", type=int, nargs="*", default=[1_000, 3_000, 10_000])
    ap.add_argument("--heavy", type=int, nargs="*", default=[100_000, 1_000_000])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--child", nargs=2, metavar=("KIND", "N"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        kind, n = args.child[0], int(args.child[1])
        if kind == "timing":
            print(json.dumps(run_timing(n, args.reps)))
        else:
            print(json.dumps(run_quality(n) if kind == "quality" else run_heavy(n)))
        return

    import numba

    print(
        f"two_stage k1={K1} k2={K2}; {os.cpu_count()} cores, numba {numba.__version__} "
        f"({numba.config.NUMBA_NUM_THREADS} threads), load average {os.getloadavg()[0]:.1f} at start"
    )
    print()
    print("| candidates | wall, median of reps (s) | wall, best (s) | CPU (s) | peak RSS (MB) | RSS before (MB) |")
    print("|---:|---:|---:|---:|---:|---:|")
    for n in args.sizes:
        r = _child("timing", n, args.reps)
        print(
            f"| {n:,} | {r['median_s']:.2f} | {r['min_s']:.2f} | {r['cpu_s']:.2f} | {r['peak_rss_mb']:.0f} "
            f"| {r['rss_before_mb']:.0f} |",
            flush=True,
        )
    print()
    print("| candidates | loss / kmedoids.fasterpam, translation | direction | two_stage (s) | reference (s) |")
    print("|---:|---:|---:|---:|---:|")
    for n in args.quality:
        q = _child("quality", n, 1)
        print(
            f"| {n:,} | {q['ratio_translation']:.4f} | {q['ratio_direction']:.4f} | {q['ours_s']:.2f} "
            f"| {q['reference_s']:.1f} |",
            flush=True,
        )
    print()
    print("| candidates | loss / CLARA 4,000 x 10 draws, translation | direction | heavy run (s) |")
    print("|---:|---:|---:|---:|")
    for n in args.heavy:
        h = _child("heavy", n, 1)
        print(
            f"| {n:,} | {h['ratio_translation']:.4f} | {h['ratio_direction']:.4f} | {h['heavy_s']:.1f} |",
            flush=True,
        )
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
