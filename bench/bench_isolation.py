"""Catalogue lookup latency while four clients ask for large previews (issue 16, point 3). Prints a table; asserts
nothing.

    .venv/bin/python bench/bench_isolation.py [--lookups 300] [--clients 4] [--size 2048] [--modes embedded postgres]

For each mode a real `graspgen serve` process (the code of the tree this script lies in) is started: `embedded` (the
SQLite file and in-process jobs) or `postgres` (this machine's PostgreSQL, a fresh schema; Redis as broker, no worker).
One object gets a grasp set in the catalogue. Then `--lookups` sequential `GET /v1/catalogue/{object}/{gripper}`
requests (20 ms apart) are timed twice: alone, and while `--clients` threads keep asking for `--size`-pixel previews,
each of a new size (so every one is a full render, never a cached PNG). Latencies are client-side over loopback.

To measure an older tree, copy this script into its bench/ and run it from there.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _conftest():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("services_conftest", ROOT / "tests" / "services_conftest.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["services_conftest"] = mod
    spec.loader.exec_module(mod)
    return mod


C = _conftest()


def _serve(values: dict, log_path: Path) -> tuple[subprocess.Popen, str]:
    port = C.free_port()
    env = C.settings_env(**values)
    env["PYTHONPATH"] = str(ROOT)
    code = "import sys; from services.cli import main; sys.exit(main(sys.argv[1:]))"
    with open(log_path, "wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-c", code, "serve", "--port", str(port)],
            env=env,
            cwd=ROOT,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    C.wait_for_log(log_path, "Uvicorn running", proc)
    C.wait_http(f"http://127.0.0.1:{port}/healthz")
    return proc, f"http://127.0.0.1:{port}"


def _seed(values: dict, tokens: dict[str, str]) -> tuple[str, str, int]:
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.settings import Settings

    with TestClient(create_app(Settings(**values), recover_jobs=False)) as client:
        svc = C.Service(client, client.app.state.settings, tokens)
        obj, grip = C.slug("iso"), C.slug("grip")
        ids = C.seed_grasp_sets(svc, grip, [obj])
    return obj, grip, ids[obj][0]


def _lookups(url: str, auth: dict, path: str, n: int) -> tuple[list[float], list[int]]:
    times, codes = [], []
    with httpx.Client(base_url=url, headers=auth, timeout=60) as c:
        c.get(path)  # connection and caches warm
        for _ in range(n):
            t = time.perf_counter()
            r = c.get(path)
            times.append(time.perf_counter() - t)
            codes.append(r.status_code)
            time.sleep(0.02)
    return times, codes


def _pct(xs: list[float], q: float) -> float:
    return statistics.quantiles(xs, n=100, method="inclusive")[q - 1] if len(xs) > 1 else xs[0]


def run_mode(mode: str, args: argparse.Namespace) -> list[str]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-iso-") as tmp:
        root = Path(tmp)
        tokens = C.write_tokens_file(root / "tokens.json")
        values: dict = {"storage_dir": root / "var", "tokens_file": root / "tokens.json"}
        schema = broker = None
        if mode == "postgres":
            from services.common.migrate import upgrade
            from services.common.settings import Settings

            schema = C.unique_name("bench_iso")
            C.create_schema(schema)
            upgrade(Settings(database_url=C.PG_URL, database_schema=schema))
            broker = C.broker_settings()
            values.update(database_url=C.PG_URL, database_schema=schema, **broker)
        proc, url = _serve(values, root / "serve.log")
        try:
            obj, grip, gs = _seed(values, tokens)
            auth = {"Authorization": f"Bearer {tokens['reader']}"}
            path = f"/v1/catalogue/{obj}/{grip}"
            for load in ("none", f"{args.clients} x {args.size}px previews"):
                stop = threading.Event()
                outcomes: list[int] = []

                def previews(k: int, stop: threading.Event = stop, outcomes: list[int] = outcomes) -> None:
                    with httpx.Client(base_url=url, headers=auth, timeout=300) as c:
                        n = 0
                        while not stop.is_set():
                            n += 1
                            size = f"{args.size}x{args.size - 4 * n - k}"
                            try:
                                r = c.get(f"/v1/grasp-sets/{gs}/preview.png", params={"size": size})
                                outcomes.append(r.status_code)
                                if r.status_code == 503:
                                    time.sleep(0.2)
                            except httpx.HTTPError:
                                outcomes.append(-1)

                threads = []
                if load != "none":
                    threads = [threading.Thread(target=previews, args=(k,), daemon=True) for k in range(args.clients)]
                    for t in threads:
                        t.start()
                    time.sleep(1.0)
                times, codes = _lookups(url, auth, path, args.lookups)
                stop.set()
                for t in threads:
                    t.join(timeout=300)
                ms = [t * 1000 for t in times]
                bad = sum(1 for c in codes if c != 200)
                five = sum(1 for c in codes if c >= 500)
                ok, busy = outcomes.count(200), outcomes.count(503)
                prev = f"{ok} / {busy} / {len(outcomes) - ok - busy}" if threads else "-"
                rows.append(
                    f"| {mode} | {load} | {len(codes)} | {statistics.median(ms):.1f} | {_pct(ms, 95):.1f} | "
                    f"{_pct(ms, 99):.1f} | {max(ms):.1f} | {bad} ({five} 5xx) | {prev} |"
                )
                print(rows[-1], flush=True)
        finally:
            C.stop_process(proc)
            if schema:
                C.drop_schema(schema)
            if broker:
                C.redis_cleanup(broker["broker_key_prefix"])
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--lookups", type=int, default=300)
    p.add_argument("--clients", type=int, default=4)
    p.add_argument("--size", type=int, default=2048)
    p.add_argument("--modes", nargs="+", default=["embedded", "postgres"], choices=["embedded", "postgres"])
    args = p.parse_args()
    print(f"tree {ROOT}, {os.cpu_count()} CPUs")
    print("| mode | load | lookups | p50 ms | p95 ms | p99 ms | max ms | not 200 | previews 200 / 503 / other |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for mode in args.modes:
        run_mode(mode, args)


if __name__ == "__main__":
    main()
