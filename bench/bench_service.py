"""Benchmark of the service on this machine's PostgreSQL and Redis, loopback only. Prints tables; asserts nothing.

    .venv/bin/python bench/bench_service.py [--grasp-sets 1000] [--rate 200] [--seconds 10]
                                            [--points 10000] [--bulk 50] [--bulk-points 2000] [--skip ...]

1. catalogue: `graspgen serve --workers N` (`--web-workers` uvicorn processes, default 2) on PostgreSQL with
   `--grasp-sets` objects, each with one grasp set for one gripper (rows and export blobs written directly; the
   exports are a real export renamed). An open-loop client sends `--rate` requests/s for `--seconds` s (bounded
   count) of `GET /v1/catalogue/{object}/{gripper}` (a random object), then `--page-rate` requests/s of
   `GET /v1/catalogue?gripper=` pages (fleet sync); p50/p99 of each.
2. job: time from `POST /v1/jobs` to the job's grasp set being stored (state succeeded), `--job-repeats` jobs of
   `--points` points (seeds 0, 1, ...: no job reuses a stored set) on each of `--job-parts`: a 24 mm x 30 mm cylinder
   (the worst case here: 717 k collision-free candidates), the shipped ring-screw example and tless_04; one warm
   Celery worker (a small job ran first to compile kernels).
3. bulk: jobs per minute through two `graspgen worker` processes for a bulk job of `--bulk` parts at `--bulk-points`.
4. burst: `--burst` separate `POST /v1/jobs` sent at once from as many threads (other parts than the bulk's), the
   same two workers: every job must finish with exactly one grasp set (none lost, none run twice); throughput.

Everything runs in a fresh PostgreSQL schema and under a fresh Redis key prefix, both removed at the end.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import secrets
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PG_URL = os.environ.get("GRASPGEN_BENCH_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")
REDIS_URL = os.environ.get("GRASPGEN_BENCH_REDIS_URL", "redis://127.0.0.1:6379/15")
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


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _pct(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, max(0, round(q / 100 * len(v)) - 1))]


def _cylinder_stl() -> bytes:
    import trimesh

    return trimesh.creation.cylinder(radius=12.0, height=30.0, sections=48).export(file_type="stl")


def _job_part(name: str) -> tuple[bytes, str] | None:
    """STL bytes and units of a job-latency part: the cylinder, a shipped example, or a mesh of ../shared/meshes."""
    from graspgen.examples import EXAMPLES

    if name == "cylinder":
        return _cylinder_stl(), "mm"
    if name in EXAMPLES:
        return EXAMPLES[name]().export(file_type="stl"), "m"
    path = ROOT.parent / "shared" / "meshes" / f"{name}.stl"
    return (path.read_bytes(), "mm") if path.is_file() else None


def _box_stl(i: int) -> bytes:
    import trimesh

    return trimesh.creation.box(extents=(30.0 + i % 20, 20.0 + i % 7, 15.0 + i % 5)).export(file_type="stl")


class Stack:
    """A PostgreSQL schema, a Redis prefix, a tokens file, and the processes started on them."""

    def __init__(self, tmp: Path) -> None:
        import psycopg

        self.tmp = tmp
        self.schema = f"ggbench_{uuid.uuid4().hex[:8]}"
        self.prefix = f"ggbench-{uuid.uuid4().hex[:8]}:"
        with psycopg.connect(PG_URL.replace("+psycopg", ""), autocommit=True) as c:
            c.execute(f'CREATE SCHEMA "{self.schema}"')
        self.token = "ggt_bench_" + secrets.token_urlsafe(16)
        from services.common.tokens import hash_token

        (tmp / "tokens.json").write_text(
            json.dumps({"tokens": [{"name": "bench", "sha256": hash_token(self.token), "scopes": ["admin"]}]})
        )
        self.values = {
            "database_url": PG_URL,
            "database_schema": self.schema,
            "broker_url": REDIS_URL,
            "broker_key_prefix": self.prefix,
            "queue": self.prefix.rstrip(":"),
            "storage_dir": tmp / "var",
            "tokens_file": tmp / "tokens.json",
        }
        self.procs: list[subprocess.Popen] = []
        from services.common.migrate import upgrade
        from services.common.settings import Settings

        self.settings = Settings(**self.values)
        upgrade(self.settings)

    def env(self, log_level: str) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith("GRASPGEN_")}
        env.update({f"GRASPGEN_{k.upper()}": str(v) for k, v in self.values.items()})
        env["GRASPGEN_LOG_LEVEL"] = log_level
        return env

    def start(self, *args: str, log: str, log_level: str = "info") -> subprocess.Popen:
        with open(self.tmp / log, "wb") as out:
            p = subprocess.Popen(
                [sys.executable, "-m", "services.cli", *args],
                env=self.env(log_level),
                stdout=out,
                stderr=subprocess.STDOUT,
            )
        self.procs.append(p)
        return p

    def wait_log(self, log: str, needle: str, timeout: float = 120) -> None:
        end = time.monotonic() + timeout
        while needle not in (self.tmp / log).read_text(errors="replace"):
            if time.monotonic() > end:
                raise TimeoutError(f"{needle!r} not in {log}")
            time.sleep(0.1)

    def serve(self, workers: int = 1) -> str:
        port = _free_port()
        self.start(
            "serve", "--port", str(port), "--workers", str(workers), log="serve.log", log_level="warning"
        )  # warning: no access log
        url = f"http://127.0.0.1:{port}"
        end = time.monotonic() + 60
        while True:
            try:
                httpx.get(url + "/healthz", timeout=1)
                return url
            except httpx.HTTPError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.1)

    def close(self) -> None:
        import psycopg
        import redis

        for p in self.procs:
            p.terminate()
        for p in self.procs:
            try:
                p.wait(60)
            except subprocess.TimeoutExpired:
                p.kill()
        with psycopg.connect(PG_URL.replace("+psycopg", ""), autocommit=True) as c:
            c.execute(f'DROP SCHEMA "{self.schema}" CASCADE')
        r = redis.Redis.from_url(REDIS_URL)
        keys = list(r.scan_iter(match=f"{self.prefix}*"))
        if keys:
            r.delete(*keys)


def seed_catalogue(stack: Stack, n: int, export: dict) -> list[str]:
    """n objects with one grasp set each for one gripper, written directly (rows plus export blobs)."""
    from sqlalchemy import insert, select

    from services.common import catalogue
    from services.common.db import Database
    from services.common.jobs import canonical_json, params_key
    from services.common.models import GraspSet, Gripper, GripperVersion, ObjectModel, ObjectVersion
    from services.common.storage import make_storage

    db, storage = Database(stack.settings), make_storage(stack.settings)
    part = storage.put_bytes(_box_stl(0))
    names = [f"bench-part-{i:05d}" for i in range(n)]
    with db.session() as s:
        # the gripper registered through the API
        g = s.execute(select(Gripper).where(Gripper.name == GRIPPER["name"])).scalar_one()
        gv = s.execute(select(GripperVersion).where(GripperVersion.gripper_id == g.id)).scalars().first()
        for name in names:
            o = ObjectModel(name=name)
            s.add(o)
            s.flush()
            ov = ObjectVersion(
                object_id=o.id,
                version=1,
                sha256=part.sha256,
                units="mm",
                format="stl",
                size_bytes=part.size,
                extents=[0.03, 0.02, 0.015],
                watertight=True,
                warnings=[],
                file_key=part.key,
            )
            s.add(ov)
            s.flush()
            blob = storage.put_bytes(canonical_json({**export, "object": {**export["object"], "name": name}}))
            s.execute(
                insert(GraspSet),
                [
                    dict(
                        object_id=o.id,
                        gripper_id=g.id,
                        version=1,
                        object_version_id=ov.id,
                        gripper_version_id=gv.id,
                        params=export["params"],
                        params_key=params_key(export["params"], None),
                        derived_from_id=None,
                        job_id=uuid.uuid4(),
                        stats=export["stats"],
                        grasp_count=len(export["grasps"]),
                        export_key=blob.key,
                        export_sha256=blob.sha256,
                        export_size=blob.size,
                        candidates_key=None,
                        recording_key=None,
                    )
                ],
            )
            catalogue.refresh(s, object_id=o.id, gripper_id=g.id)  # as the worker does when it stores a set
    db.dispose()
    return names


class _Conn:
    """One keep-alive HTTP/1.1 connection with just enough parsing for GET responses with a Content-Length.

    The load generator shares the machine with the server: httpx spends 2-3 ms of CPU per request, which at 200
    requests/s would measure the client more than the server, so the hot loop speaks HTTP/1.1 directly.
    """

    def __init__(self, host: str, port: int, token: str) -> None:
        self.host, self.port, self.token = host, port, token
        self.reader: asyncio.StreamReader | None = None
        self.writer: asyncio.StreamWriter | None = None

    async def get(self, path: str) -> int:
        if self.writer is None:
            self.reader, self.writer = await asyncio.open_connection(self.host, self.port)
        self.writer.write(
            f"GET {path} HTTP/1.1\r\nHost: {self.host}\r\nAuthorization: Bearer {self.token}\r\n\r\n".encode()
        )
        head = await self.reader.readuntil(b"\r\n\r\n")
        status = int(head[9:12])
        length = 0
        for line in head.split(b"\r\n"):
            if line[:15].lower() == b"content-length:":
                length = int(line[15:])
        if length:
            await self.reader.readexactly(length)
        return status


async def open_loop(url: str, token: str, paths: list[str], rate: float, seconds: float) -> tuple[list[float], int]:
    """GETs at a fixed rate whatever the latency (open loop), at most rate*seconds of them; (latencies ms, errors)."""
    from urllib.parse import urlsplit

    u = urlsplit(url)
    idle: asyncio.Queue[_Conn] = asyncio.Queue()
    for _ in range(32):
        idle.put_nowait(_Conn(u.hostname, u.port, token))
    lat: list[float] = []
    errors = 0

    async def one(path: str, keep: bool) -> None:
        nonlocal errors
        t0 = time.perf_counter()  # from the moment it is due, so waiting for a connection counts as latency
        conn = await idle.get()
        try:
            ok = await conn.get(path) == 200
        except (OSError, asyncio.IncompleteReadError, ValueError):
            ok = False
            conn.writer = None
        idle.put_nowait(conn)
        if keep:
            if ok:
                lat.append((time.perf_counter() - t0) * 1e3)
            else:
                errors += 1

    for i in range(64):  # open connections, warm caches
        await one(paths[i % len(paths)], False)
    tasks = []
    start = time.perf_counter()
    for i in range(int(rate * seconds)):
        delay = start + i / rate - time.perf_counter()
        if delay > 0:
            await asyncio.sleep(delay)
        tasks.append(asyncio.create_task(one(random.choice(paths), True)))
    await asyncio.gather(*tasks)
    while not idle.empty():
        conn = idle.get_nowait()
        if conn.writer is not None:
            conn.writer.close()
    return lat, errors


def burst(c: httpx.Client, stack: Stack, args: argparse.Namespace) -> tuple[str, str, str, str]:
    """`--burst` jobs posted at once by as many threads; waits for all; checks one grasp set per job."""
    from concurrent.futures import ThreadPoolExecutor

    if not (stack.tmp / "worker2.log").exists():
        stack.start("worker", "--concurrency", "1", log="worker2.log")
        stack.wait_log("worker2.log", " ready.")
    names = []
    for i in range(args.burst):
        name = f"burst-part-{i:03d}"
        c.post(
            "/v1/objects", files={"file": (f"{name}.stl", _box_stl(1000 + i))}, data={"name": name, "units": "mm"}
        ).raise_for_status()
        names.append(name)
    barrier_t0 = time.perf_counter()

    def post(name: str) -> tuple[int, str]:
        with httpx.Client(base_url=str(c.base_url), headers=dict(c.headers), timeout=60) as own:
            r = own.post("/v1/jobs", json={"object": name, "gripper": "pgn-80", "params": {"points": args.bulk_points}})
            return r.status_code, r.json().get("id", "")

    with ThreadPoolExecutor(max_workers=args.burst) as pool:
        sent = list(pool.map(post, names))
    accepted = [jid for code, jid in sent if code in (200, 201, 202) and jid]
    states: dict[str, str] = {}
    end = time.monotonic() + args.timeout
    while len(states) < len(accepted) and time.monotonic() < end:
        for jid in accepted:
            if jid not in states:
                job = c.get(f"/v1/jobs/{jid}").json()
                if job["state"] in ("succeeded", "failed", "cancelled"):
                    states[jid] = job["state"]
        time.sleep(0.2)
    secs = time.perf_counter() - barrier_t0
    versions = [len(c.get("/v1/grasp-sets", params={"object": n, "gripper": "pgn-80"}).json()["items"]) for n in names]
    ok = sum(1 for s in states.values() if s == "succeeded")
    lost = len(accepted) - len(states)
    return (
        f"{args.burst} jobs posted at once, two workers",
        f"{args.burst} parts x {args.bulk_points} points",
        f"{secs:.1f} s",
        f"{ok / secs * 60:.1f} jobs/min; accepted {len(accepted)}/{len(sent)}, succeeded {ok}, unfinished {lost}, "
        f"grasp sets per part: {min(versions)}-{max(versions)}",
    )


def submit_and_wait(c: httpx.Client, body: dict, timeout: float, path: str = "/v1/jobs") -> tuple[dict, float]:
    t0 = time.perf_counter()
    r = c.post(path, json=body)
    r.raise_for_status()
    jid = r.json()["id"]
    end = time.monotonic() + timeout
    while True:
        job = c.get(f"/v1/jobs/{jid}").json()
        if job["state"] in ("succeeded", "failed", "cancelled") or time.monotonic() > end:
            return job, time.perf_counter() - t0
        time.sleep(0.05)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--grasp-sets", type=int, default=1000)
    ap.add_argument("--rate", type=float, default=200.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--page-rate", type=float, default=20.0, help="requests/s for catalogue pages (fleet sync)")
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument(
        "--job-parts",
        nargs="*",
        default=["cylinder", "ring-screw", "tless_04"],
        help="parts for the job-latency measurement: cylinder (24 x 30 mm), a shipped example, or a ../shared mesh",
    )
    ap.add_argument("--job-repeats", type=int, default=3, help="jobs per part (other seeds: no cache hit)")
    ap.add_argument("--bulk", type=int, default=50)
    ap.add_argument("--bulk-points", type=int, default=2000)
    ap.add_argument("--web-workers", type=int, default=2, help="API processes (graspgen serve --workers)")
    ap.add_argument("--timeout", type=float, default=600.0, help="per job or bulk, seconds")
    ap.add_argument("--burst", type=int, default=50, help="jobs submitted at once (separate requests)")
    ap.add_argument("--skip", nargs="*", default=[], choices=["catalogue", "job", "bulk", "burst"])
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="graspgen-bench-") as tmp:
        stack = Stack(Path(tmp))
        try:
            url = stack.serve(args.web_workers)
            c = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {stack.token}"}, timeout=30)
            c.post("/v1/grippers", json=GRIPPER).raise_for_status()
            c.post(
                "/v1/objects", files={"file": ("ring.stl", _cylinder_stl())}, data={"name": "ring", "units": "mm"}
            ).raise_for_status()
            stack.start("worker", "--concurrency", "1", log="worker1.log")
            stack.wait_log("worker1.log", " ready.")
            warm, warm_s = submit_and_wait(
                c, {"object": "ring", "gripper": "pgn-80", "params": {"points": 500}}, args.timeout
            )
            print(f"warm-up job ({warm['state']}): {warm_s:.2f} s (includes compiling kernels in the worker)")
            export = c.get(f"/v1/grasp-sets/{warm['grasp_set']}").json()
            rows = []

            if "job" not in args.skip:
                for part_name in args.job_parts:
                    got = _job_part(part_name)
                    if got is None:
                        print(f"(job part {part_name}: not found, skipped)")
                        continue
                    data, units = got
                    c.post(
                        "/v1/objects",
                        files={"file": (f"{part_name}.stl", data)},
                        data={"name": part_name, "units": units},
                    ).raise_for_status()
                    runs = []
                    for rep in range(args.job_repeats):
                        params = {"points": args.points, "seed": rep}
                        job, secs = submit_and_wait(
                            c, {"object": part_name, "gripper": "pgn-80", "params": params}, args.timeout
                        )
                        stats = c.get(f"/v1/grasp-sets/{job['grasp_set']}").json()["stats"] if job["grasp_set"] else {}
                        runs.append((secs, stats.get("timings_s", {}).get("total"), stats.get("candidates"), job))
                    secs_all = sorted(r[0] for r in runs)
                    core_all = sorted(r[1] for r in runs if r[1])
                    rows.append(
                        (
                            f"job submission -> stored grasp set: {part_name}",
                            f"{args.points} points, {runs[0][2]:,} candidates",
                            f"median {statistics.median(secs_all):.2f} s "
                            f"(min {secs_all[0]:.2f}, max {secs_all[-1]:.2f})",
                            f"{len(runs)} jobs, states {sorted({r[3]['state'] for r in runs})}, core median "
                            f"{statistics.median(core_all):.2f} s",
                        )
                    )

            if "bulk" not in args.skip:
                stack.start("worker", "--concurrency", "1", log="worker2.log")
                stack.wait_log("worker2.log", " ready.")
                c.post("/v1/jobs", json={"object": "ring", "gripper": "pgn-80", "params": {"points": 500, "seed": 1}})
                time.sleep(5)  # let the second worker compile on a small job too
                names = []
                for i in range(args.bulk):
                    name = f"bulk-part-{i:03d}"
                    c.post(
                        "/v1/objects", files={"file": (f"{name}.stl", _box_stl(i))}, data={"name": name, "units": "mm"}
                    ).raise_for_status()
                    names.append(name)
                items = [{"object": n, "gripper": "pgn-80", "params": {"points": args.bulk_points}} for n in names]
                parent, secs = submit_and_wait(c, {"items": items}, args.timeout, path="/v1/bulk-jobs")
                done = parent["summary"]["succeeded"]
                rows.append(
                    (
                        "bulk, two workers",
                        f"{args.bulk} parts x {args.bulk_points} points",
                        f"{secs:.1f} s",
                        f"{done / secs * 60:.1f} jobs/min ({parent['summary']})",
                    )
                )

            if "burst" not in args.skip:
                rows.append(burst(c, stack, args))

            if "catalogue" not in args.skip:
                t0 = time.perf_counter()
                names = seed_catalogue(stack, args.grasp_sets, export)
                print(f"seeded {len(names)} grasp sets in {time.perf_counter() - t0:.1f} s")
                entries = [f"/v1/catalogue/{n}/pgn-80" for n in names]
                pages = ["/v1/catalogue?gripper=pgn-80&limit=50"]
                for label, paths, rate in (
                    ("GET /v1/catalogue/{object}/{gripper}", entries, args.rate),
                    ("GET /v1/catalogue?gripper= (first page of 50)", pages, args.page_rate),
                ):
                    v, errors = asyncio.run(open_loop(url, stack.token, paths, rate, args.seconds))
                    rows.append(
                        (
                            label,
                            f"{rate:.0f} req/s, {len(v)} requests, {args.web_workers} API processes",
                            f"p50 {_pct(v, 50):.1f} ms, p99 {_pct(v, 99):.1f} ms",
                            f"mean {statistics.fmean(v):.1f} ms, max {max(v):.1f} ms, errors {errors}",
                        )
                    )

            print()
            print("| measurement | load | result | notes |")
            print("| --- | --- | --- | --- |")
            for r in rows:
                print("| " + " | ".join(r) + " |")
        finally:
            stack.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
