"""Benchmark of the pick query on suction sets, in the library. Prints a table; asserts nothing.

    .venv/bin/python bench/bench_pick_suction.py [--candidates 200000] [--rolls 16] [--repeat 100]

Synthetic suction candidates (the pick's cost depends on the pair count, not on where the candidates came from):
`--candidates` cups at random contacts on a 60 mm part with random approaches, hold margins present. Two grippers:
the shipped cup-30 (a cylinder tool: one pair per candidate) and the same cup on a 80 x 20 mm body mesh (a pair per
free roll, about 60 % of `--rolls` free). Scenes as in bench_pick.py: `floor+cone` (the part on a floor, approach
within 30 degrees of straight down, limit 10), `bin` (a floor and four walls, 45 degrees, flange, limit 10), `open`
(no cone, no planes: ranking only), `limit 1000`. Columns: `PickIndex.build` once per set, then the median and worst
query time over `--repeat` runs of `PickQuery.parse(...).run(index)`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from graspgen.example_grippers import box, stl_bytes  # noqa: E402
from graspgen.kinds import gripper_from_dict  # noqa: E402
from graspgen.pick import PickIndex, PickQuery  # noqa: E402

T_FLOOR = [[0.0, -1.0, 0.0, 0.4], [1.0, 0.0, 0.0, 0.1], [0.0, 0.0, 1.0, 0.03], [0.0, 0.0, 0.0, 1.0]]
FLANGE = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -0.1], [0.0, 0.0, 0.0, 1.0]]
FLOOR = {"point": [0, 0, 0], "normal": [0, 0, 1]}
WALLS = [
    {"point": [0.25, 0, 0], "normal": [1, 0, 0]},
    {"point": [0.55, 0, 0], "normal": [-1, 0, 0]},
    {"point": [0, -0.05, 0], "normal": [0, 1, 0]},
    {"point": [0, 0.25, 0], "normal": [0, -1, 0]},
]
DOWN30 = {"direction": [0, 0, -1], "max_angle_deg": 30}
SCENES: dict[str, dict] = {
    "floor+cone": dict(T_world_object=T_FLOOR, approach=DOWN30, planes=[FLOOR]),
    "bin": dict(
        T_world_object=T_FLOOR,
        approach={"direction": [0, 0, -1], "max_angle_deg": 45},
        planes=[FLOOR, *WALLS],
        T_tcp_flange=FLANGE,
    ),
    "open": dict(T_world_object=T_FLOOR),
    "limit 1000": dict(T_world_object=T_FLOOR, approach=DOWN30, planes=[FLOOR], limit=1000),
}


def cups(n: int, rolls: int, seed: int = 0) -> SimpleNamespace:
    rng = np.random.default_rng(seed)
    z = rng.normal(size=(n, 3))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    free = rng.random((n, rolls)) < 0.6
    free[np.arange(n), rng.integers(0, rolls, n)] = True
    return SimpleNamespace(
        contacts=rng.uniform(-0.03, 0.03, (n, 1, 3)),
        axes=z,
        free_rolls=free,
        roll_angles_rad=2 * np.pi * np.arange(rolls) / rolls,
        seal_strain=rng.uniform(0, 0.1, n),
        tilt_deg=np.zeros(n),
        hold_margin=np.round(rng.uniform(1, 4, n), 2),
        labels=np.zeros((n, 2), dtype=np.int32),
        medoids=np.arange(16, dtype=np.int64),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--candidates", type=int, default=200_000)
    ap.add_argument("--rolls", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=100)
    args = ap.parse_args()
    spec = json.loads((ROOT / "examples" / "cup-30.json").read_text())
    body = {k: v for k, v in spec.items() if k != "tool"} | {"geometry": {"units": "mm", "body": "body.stl"}}
    grippers = {
        "cup-30 (cylinder)": gripper_from_dict(spec),
        "cup-30 (body mesh)": gripper_from_dict(
            body, files={"body.stl": stl_bytes(box((-40, -10, -150), (40, 10, -20)))}
        ),
    }
    c = cups(args.candidates, args.rolls)
    print(f"{args.candidates:,} suction candidates, {args.rolls} rolls, {args.repeat} queries per scene\n")
    print("| gripper | pairs | build (ms) | scene | feasible | median (ms) | worst (ms) |")
    print("|---|---:|---:|---|---:|---:|---:|")
    for name, gripper in grippers.items():
        t0 = time.perf_counter()
        index = PickIndex.build(c, gripper)
        build = 1e3 * (time.perf_counter() - t0)
        for scene, kw in SCENES.items():
            kw = dict(kw)
            T = kw.pop("T_world_object")
            times, feasible = [], 0
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                feasible = PickQuery.parse(T, **kw).run(index).feasible
                times.append(1e3 * (time.perf_counter() - t0))
            print(
                f"| {name} | {len(index):,} | {build:.0f} | {scene} | {feasible:,} | {np.median(times):.2f} | "
                f"{max(times):.2f} |"
            )


if __name__ == "__main__":
    main()
