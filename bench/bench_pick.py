"""Benchmark of the pick query on this machine. Prints tables; asserts nothing.

    .venv/bin/python bench/bench_pick.py [--pairs 300000] [--rolls 16] [--repeat 300] [--database-url URL]

A candidate set with `--pairs` (candidate, free roll) pairs: random antipodal pairs on a 60 mm part, `--rolls` roll
angles, about 60 % of them free, quality terms present (synthetic: the pick's cost depends on the pair count, not
on where the pairs came from). Scenes, each over every pair:

- `floor+cone`: the part on a floor, approach within 30 degrees of straight down, limit 10 (the plant's query);
- `bin`: a floor and four walls of a 0.3 m bin, approach within 45 degrees, flange given, limit 10;
- `open`: no cone, no planes, limit 10 (every pair feasible: ranking only);
- `limit 1000`: `floor+cone` with limit 1000 (response building dominates);
- `empty`: the part below the floor (nothing feasible; the reason is counted).

1. library: `PickQuery.parse(...).run(index)` on a prepared PickIndex (what the API holds in its cache), and the
   one-off `PickIndex.build` from the Candidates (what the first query of a set in a process pays).
2. HTTP: `graspgen serve` (a subprocess, embedded SQLite unless `--database-url`) with the set stored through the
   service's own storage and tables; `POST /v1/pick` by grasp set id from one client over loopback, sequentially,
   after one warm-up request (which loads the NPZ into the cache); client-side wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from graspgen.export import Candidates, npz_bytes  # noqa: E402
from graspgen.gripper import GripperSpec  # noqa: E402
from graspgen.pick import PickIndex, PickQuery  # noqa: E402

GRIPPER = {
    "name": "pgn-80",
    "stroke": 0.08,
    "finger_width": 0.02,
    "finger_depth": 0.03,
    "finger_thickness": 0.01,
    "palm_depth": 0.02,
    "friction": 0.5,
    "pregrasp_clearance": 0.02,
}
T_FLOOR = [[0.0, -1.0, 0.0, 0.4], [1.0, 0.0, 0.0, 0.1], [0.0, 0.0, 1.0, 0.03], [0.0, 0.0, 0.0, 1.0]]
FLANGE = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -0.1], [0.0, 0.0, 0.0, 1.0]]
FLOOR = {"point": [0, 0, 0], "normal": [0, 0, 1]}
SCENES: dict[str, dict] = {
    "floor+cone": dict(T_world_object=T_FLOOR, approach={"direction": [0, 0, -1], "max_angle_deg": 30}, planes=[FLOOR]),
    "bin": dict(
        T_world_object=T_FLOOR,
        approach={"direction": [0, 0, -1], "max_angle_deg": 45},
        planes=[
            FLOOR,
            {"point": [0.25, 0, 0], "normal": [1, 0, 0]},
            {"point": [0.55, 0, 0], "normal": [-1, 0, 0]},
            {"point": [0, -0.05, 0], "normal": [0, 1, 0]},
            {"point": [0, 0.25, 0], "normal": [0, -1, 0]},
        ],
        T_tcp_flange=FLANGE,
    ),
    "open": dict(T_world_object=T_FLOOR),
    "limit 1000": dict(
        T_world_object=T_FLOOR, approach={"direction": [0, 0, -1], "max_angle_deg": 30}, planes=[FLOOR], limit=1000
    ),
    "empty": dict(
        T_world_object=[[1.0, 0, 0, 0.4], [0, 1.0, 0, 0], [0, 0, 1.0, -0.3], [0, 0, 0, 1.0]],
        approach={"direction": [0, 0, -1], "max_angle_deg": 30},
        planes=[FLOOR],
    ),
}


def synthetic(pairs: int, rolls: int, seed: int = 0) -> Candidates:
    rng = np.random.default_rng(seed)
    n = int(np.ceil(pairs / (0.6 * rolls)))
    free = np.zeros((n, rolls), dtype=bool)
    flat = rng.choice(n * rolls, size=pairs, replace=False)
    free.flat[flat] = True
    free = free[free.any(axis=1)]
    n = len(free)
    mid = rng.uniform(-0.03, 0.03, (n, 3))
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    half = rng.uniform(0.002, 0.035, (n, 1))
    return Candidates(
        contacts=np.stack([mid - half * axis, mid + half * axis], axis=1),
        normals=np.stack([-axis, axis], axis=1),
        free_rolls=free,
        roll_angles_rad=2 * np.pi * np.arange(rolls) / rolls,
        friction_margin_deg=rng.uniform(0, 20, n),
        inside=np.zeros(n, dtype=bool),
        labels=rng.integers(0, 64, (n, 2)).astype(np.int32),
        medoids=np.arange(64, dtype=np.int64),
        quality_terms=rng.uniform(0, 1, (n, 3)),
    )


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


def bench_library(cands: Candidates, repeat: int) -> tuple[PickIndex, list[tuple]]:
    spec = GripperSpec.from_dict(GRIPPER)
    builds = []
    for _ in range(3):
        t = time.perf_counter()
        index = PickIndex.build(cands, spec)
        builds.append(time.perf_counter() - t)
    rows = [("PickIndex.build (once per set)", "-", 1e3 * min(builds), 1e3 * max(builds), "-", "-")]
    for name, scene in SCENES.items():
        times, cpu, feasible = [], [], 0
        for _ in range(repeat):
            t, c = time.perf_counter(), time.process_time()
            result = PickQuery.parse(**scene).run(index)
            times.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
            feasible = result.feasible
        rows.append(
            (name, f"{feasible:,}", 1e3 * pct(times, 50), 1e3 * pct(times, 95), 1e3 * pct(cpu, 50), len(result.grasps))
        )
    return index, rows


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bench_http(cands: Candidates, repeat: int, database_url: str | None) -> list[tuple]:
    import httpx

    from services.common.tokens import hash_token

    root = Path(tempfile.mkdtemp(prefix="bench-pick-"))
    token = "ggt_bench_" + secrets.token_urlsafe(16)
    (root / "tokens.json").write_text(
        json.dumps({"tokens": [{"name": "bench", "sha256": hash_token(token), "scopes": ["admin"]}]})
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("GRASPGEN_")}
    env.update({"GRASPGEN_STORAGE_DIR": str(root / "var"), "GRASPGEN_TOKENS_FILE": str(root / "tokens.json")})
    schema = None
    if database_url:
        schema = "bench_pick_" + uuid.uuid4().hex[:8]
        env.update({"GRASPGEN_DATABASE_URL": database_url, "GRASPGEN_DATABASE_SCHEMA": schema})
        env["GRASPGEN_BROKER_URL"] = os.environ.get("GRASPGEN_BENCH_REDIS_URL", "redis://127.0.0.1:6379/15")
        _create_schema(database_url, schema)
    port = _free_port()
    log = open(root / "serve.log", "wb")  # noqa: SIM115
    graspgen = str(Path(sys.executable).with_name("graspgen"))
    if database_url:
        subprocess.run([graspgen, "migrate"], env=env, check=True, stdout=log, stderr=subprocess.STDOUT)
    proc = subprocess.Popen([graspgen, "serve", "--port", str(port)], env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        _wait(url)
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=60) as c:
            gs = _store_set(c, env, cands)
            rows = []
            for name, scene in SCENES.items():
                body = {"grasp_set": gs, **scene}
                first = c.post("/v1/pick", json=body)
                first.raise_for_status()
                times = []
                for _ in range(repeat):
                    t = time.perf_counter()
                    r = c.post("/v1/pick", json=body)
                    times.append(time.perf_counter() - t)
                    r.raise_for_status()
                out = r.json()
                rows.append((name, f"{out['feasible']:,}", 1e3 * pct(times, 50), 1e3 * pct(times, 95), len(r.content)))
            return rows
    finally:
        proc.terminate()
        proc.wait(30)
        log.close()
        if schema:
            _drop_schema(database_url, schema)


def _wait(url: str) -> None:
    import httpx

    end = time.monotonic() + 60
    while time.monotonic() < end:
        try:
            if httpx.get(url + "/healthz").status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise TimeoutError("graspgen serve did not start")


def _store_set(c, env: dict[str, str], cands: Candidates) -> int:  # type: ignore[no-untyped-def]
    """Object and gripper through the API; the grasp-set row and its NPZ and export written as the worker would."""
    import trimesh
    from sqlalchemy import select

    from services.common import catalogue
    from services.common.db import Database
    from services.common.jobs import params_key
    from services.common.models import GraspSet, Gripper, GripperVersion, ObjectModel, ObjectVersion
    from services.common.settings import Settings
    from services.common.storage import make_storage

    part = trimesh.creation.cylinder(radius=12.0, height=30.0, sections=24).export(file_type="stl")
    c.post("/v1/objects", files={"file": ("part.stl", part)}, data={"name": "bench-part", "units": "mm"})
    c.post("/v1/grippers", json=GRIPPER).raise_for_status()
    saved = dict(os.environ)
    os.environ.update({k: v for k, v in env.items() if k.startswith("GRASPGEN_")})
    try:
        settings = Settings()
    finally:
        os.environ.clear()
        os.environ.update(saved)
    db, storage = Database(settings), make_storage(settings)
    npz = storage.put_bytes(npz_bytes(cands.arrays()))
    export = {"format": "graspgen.grasp_set/1", "units": "m", "object": {"name": "bench-part", "version": 1}}
    blob = storage.put_bytes(
        json.dumps({**export, "gripper": GRIPPER, "params": {}, "stats": {}, "grasps": []}).encode()
    )
    with db.session() as s:
        obj = s.execute(select(ObjectModel).where(ObjectModel.name == "bench-part")).scalar_one()
        ov = s.execute(select(ObjectVersion).where(ObjectVersion.object_id == obj.id)).scalars().first()
        g = s.execute(select(Gripper).where(Gripper.name == "pgn-80")).scalar_one()
        gv = s.execute(select(GripperVersion).where(GripperVersion.gripper_id == g.id)).scalars().first()
        gs = GraspSet(
            object_id=obj.id,
            gripper_id=g.id,
            version=1,
            object_version_id=ov.id,
            gripper_version_id=gv.id,
            params={},
            params_key=params_key({}, None),
            job_id=uuid.uuid4(),
            stats={},
            grasp_count=0,
            export_key=blob.key,
            export_sha256=blob.sha256,
            export_size=blob.size,
            candidates_key=npz.key,
        )
        s.add(gs)
        s.flush()
        catalogue.refresh(s, object_id=obj.id, gripper_id=g.id)
        gs_id = gs.id
    db.dispose()
    return gs_id


def _create_schema(url: str, name: str) -> None:
    import sqlalchemy

    engine = sqlalchemy.create_engine(url, isolation_level="AUTOCOMMIT")
    with engine.connect() as conn:
        conn.execute(sqlalchemy.text(f'CREATE SCHEMA "{name}"'))
    engine.dispose()


def _drop_schema(url: str, name: str) -> None:
    import sqlalchemy

    engine = sqlalchemy.create_engine(url, isolation_level="AUTOCOMMIT")
    with engine.connect() as conn:
        conn.execute(sqlalchemy.text(f'DROP SCHEMA IF EXISTS "{name}" CASCADE'))
    engine.dispose()


def table(title: str, header: tuple[str, ...], rows: list[tuple]) -> None:
    print(f"\n{title}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---" if i == 0 else "---:" for i in range(len(header))) + "|")
    for row in rows:
        cells = [f"{v:.2f}" if isinstance(v, float) else str(v) for v in row]
        print("| " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=300_000)
    ap.add_argument("--rolls", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=300)
    ap.add_argument("--database-url", default=None, help="PostgreSQL URL for the HTTP part (default: embedded)")
    ap.add_argument("--skip-http", action="store_true")
    args = ap.parse_args()
    cands = synthetic(args.pairs, args.rolls)
    pairs = int(cands.free_rolls.sum())
    print(f"{len(cands):,} candidates, {args.rolls} rolls, {pairs:,} candidate rolls; {os.cpu_count()} CPUs")
    print("load average at start: " + " ".join(f"{v:.1f}" for v in os.getloadavg()))
    index, rows = bench_library(cands, args.repeat)
    print(f"prepared pairs: {index.nbytes / 1e6:.1f} MB in the cache")
    table(
        f"library: PickQuery.parse + run, {args.repeat} runs",
        ("scene", "feasible", "p50 ms", "p95 ms", "CPU p50 ms", "grasps"),
        rows,
    )
    if not args.skip_http:
        where = "PostgreSQL" if args.database_url else "embedded SQLite"
        rows = bench_http(cands, args.repeat, args.database_url)
        table(
            f"HTTP: POST /v1/pick by id, graspgen serve ({where}), {args.repeat} sequential requests, warm cache",
            ("scene", "feasible", "p50 ms", "p95 ms", "response bytes"),
            rows,
        )
    print("\nload average at end: " + " ".join(f"{v:.1f}" for v in os.getloadavg()))


if __name__ == "__main__":
    main()
