"""How fast and how close to the continuous minimum criterion (e)'s margin kernel is (issue 14).

    .venv/bin/python bench/bench_hold_margin.py                       # thick ring, 10,000 points
    .venv/bin/python bench/bench_hold_margin.py --sample 5000 --repeat 3

Takes the candidates that criterion (e) sees in `graspgen.generate` on the thick ring (0.2 kg, 20 N, mu 0.5), then
times `hold.hold_margins_of_pairs` over all of them with the default `HoldModel` and a few other settings, and
compares each setting's margins on a random sample of candidates with a fine search (2,048 directions, four
refinement rounds), the closest to the continuous minimum this kernel gets. The margin is a minimum over
directions, so a search that misses the worst direction reports too high a margin: the "above" columns are the
error that matters. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GRIPPER = {**json.loads((ROOT / "examples" / "pgn-80.json").read_text()), "grip_force": 20.0}


def _inputs(points: int) -> dict:
    """The arguments criterion (e) passes to the kernel, caught from a real run."""
    import graspgen
    import graspgen.pipeline as pipeline
    from graspgen import hold
    from graspgen.examples import example_part

    caught: dict = {}
    real = hold.hold_margins_of_pairs

    def catch(*args, **kw):
        caught.setdefault("args", args)
        caught.setdefault("kw", {k: v for k, v in kw.items() if k != "floor"})
        return real(*args, **kw)

    pipeline._hold.hold_margins_of_pairs = catch
    try:
        graspgen.generate(example_part("thick-ring"), GRIPPER, points=points, mass_kg=0.2)
    finally:
        pipeline._hold.hold_margins_of_pairs = real
    return caught


def main() -> None:
    from graspgen import hold

    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--sample", type=int, default=20_000, help="candidates compared with the fine search")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    caught = _inputs(args.points)
    (pts, nrm, rho, i, j, com), kw = caught["args"], caught["kw"]
    rng = np.random.default_rng(0)
    pick = np.sort(rng.choice(len(i), min(args.sample, len(i)), replace=False))
    fine = hold.hold_margins_of_pairs(
        pts, nrm, rho, i[pick], j[pick], com, model=replace(hold.HOLD, directions=2048, refinements=4), **kw
    )
    settings = {
        "default": hold.HOLD,
        "14 directions, 2 rounds": replace(hold.HOLD, directions=14),
        "56 directions, 1 round": replace(hold.HOLD, directions=56, refinements=1),
        "28 directions, 3 rounds": replace(hold.HOLD, refinements=3),
        "56 directions, 2 rounds": replace(hold.HOLD, directions=56),
    }
    print(f"thick ring, {args.points:,} points: {len(i):,} candidates; {len(pick):,} compared with 2,048 directions")
    print(f"default: {hold.HOLD.directions} directions, {hold.HOLD.refinements} rounds; kernel seconds, median of")
    print(f"{args.repeat} (floor 1, as criterion (e) runs it)\n")
    print("| setting | kernel s | max above fine | 99th pct above | median above | candidates >= 1 |")
    print("|---|---|---|---|---|---|")
    for name, model in settings.items():
        times = []
        for _ in range(args.repeat + 1):  # the first call compiles nothing new but warms the caches
            t0 = time.perf_counter()
            full = hold.hold_margins_of_pairs(pts, nrm, rho, i, j, com, model=model, floor=1.0, **kw)
            times.append(time.perf_counter() - t0)
        got = hold.hold_margins_of_pairs(pts, nrm, rho, i[pick], j[pick], com, model=model, **kw)
        above = (got - fine) / fine
        print(
            f"| {name} | {statistics.median(times[1:]):.3f} | {100 * above.max():.3f} % | "
            f"{100 * np.quantile(above, 0.99):.3f} % | {100 * np.median(above):.4f} % | {int(np.sum(full >= 1)):,} |"
        )


if __name__ == "__main__":
    main()
