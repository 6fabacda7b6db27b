"""The review page's catalogue with 10,000 object x gripper pairs: `GET /v1/pairs` page by page (keyset cursors over
the two names), on PostgreSQL (127.0.0.1:5432, database `test`, a schema of its own, dropped afterwards).

    .venv/bin/python bench/bench_pairs.py [--objects 2500] [--grippers 4] [--limit 50]

Rows are inserted directly (objects, versions, grasp sets, catalogue pairs, a release event on every 10th pair), as
the API and the worker would leave them; requests go through the app in-process (FastAPI's TestClient), so the
figures are the route's own cost: the page query, the count, the summaries and last events of the page. Prints a
table; docs/benchmarks.md ("Review page") has the figures.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PG_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"


def seed(db, n_objects: int, n_grippers: int) -> None:  # type: ignore[no-untyped-def]
    from sqlalchemy import insert

    from services.common.models import (
        CatalogueEvent,
        CataloguePair,
        GraspSet,
        Gripper,
        GripperVersion,
        ObjectModel,
        ObjectVersion,
        utcnow,
    )

    now = utcnow()
    with db.session() as s:
        s.execute(
            insert(ObjectModel),
            [{"id": i + 1, "name": f"part-{i:05d}", "created_at": now, "updated_at": now} for i in range(n_objects)],
        )
        s.execute(
            insert(ObjectVersion),
            [
                {
                    "id": i + 1,
                    "object_id": i + 1,
                    "version": 1,
                    "sha256": f"{i:064x}",
                    "units": "mm",
                    "format": "stl",
                    "size_bytes": 1,
                    "extents": [0.01, 0.01, 0.01],
                    "watertight": True,
                    "warnings": [],
                    "file_key": "x",
                    "created_at": now,
                }
                for i in range(n_objects)
            ],
        )
        s.execute(
            insert(Gripper),
            [{"id": g + 1, "name": f"jaw-{g}", "created_at": now, "updated_at": now} for g in range(n_grippers)],
        )
        s.execute(
            insert(GripperVersion),
            [
                {
                    "id": g + 1,
                    "gripper_id": g + 1,
                    "version": 1,
                    "spec": {"name": f"jaw-{g}"},
                    "spec_sha256": f"{g:064x}",
                    "created_at": now,
                }
                for g in range(n_grippers)
            ],
        )
        sets, pairs, events = [], [], []
        k = 0
        for o in range(n_objects):
            for g in range(n_grippers):
                k += 1
                sets.append(
                    {
                        "id": k,
                        "object_id": o + 1,
                        "gripper_id": g + 1,
                        "version": 1,
                        "object_version_id": o + 1,
                        "gripper_version_id": g + 1,
                        "params": {"points": 10000},
                        "params_key": f"{k:064x}",
                        "job_id": uuid.uuid4(),
                        "stats": {},
                        "grasp_count": 64,
                        "export_key": "x",
                        "export_sha256": f"{k:064x}",
                        "export_size": 1,
                        "created_at": now,
                    }
                )
                released = k % 10 == 0
                pairs.append(
                    {
                        "object_id": o + 1,
                        "gripper_id": g + 1,
                        "current_id": k,
                        "released_id": k if released else None,
                        "stale": False,
                        "change_seq": k,
                        "updated_at": now,
                    }
                )
                if released:
                    events.append(
                        {
                            "object_id": o + 1,
                            "gripper_id": g + 1,
                            "grasp_set_id": k,
                            "action": "release",
                            "at": now,
                            "by": "bench",
                        }
                    )
        s.execute(insert(GraspSet), sets)
        s.execute(insert(CataloguePair), pairs)
        s.execute(insert(CatalogueEvent), events)
        s.commit()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--objects", type=int, default=2500)
    ap.add_argument("--grippers", type=int, default=4)
    ap.add_argument("--limit", type=int, default=50)
    args = ap.parse_args()

    import psycopg
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.db import Database
    from services.common.migrate import upgrade
    from services.common.settings import Settings
    from tests.services_conftest import write_tokens_file

    schema = f"bench_pairs_{uuid.uuid4().hex[:8]}"
    admin = PG_URL.replace("postgresql+psycopg", "postgresql")
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'CREATE SCHEMA "{schema}"')
    try:
        with tempfile.TemporaryDirectory() as tmp:
            tokens = write_tokens_file(Path(tmp) / "tokens.json")
            settings = Settings(
                database_url=PG_URL,
                database_schema=schema,
                storage_dir=Path(tmp) / "var",
                tokens_file=Path(tmp) / "tokens.json",
                broker_url="redis://127.0.0.1:6379/15",
            )
            upgrade(settings)
            db = Database(settings)
            t = time.perf_counter()
            seed(db, args.objects, args.grippers)
            db.dispose()
            n = args.objects * args.grippers
            print(f"seeded {n:,} pairs in {time.perf_counter() - t:.1f} s (PostgreSQL, schema {schema})\n")
            with TestClient(create_app(settings)) as c:
                h = {"Authorization": f"Bearer {tokens['reader']}"}

                def get(url: str) -> tuple[dict, float]:
                    t0 = time.perf_counter()
                    r = c.get(url, headers=h)
                    assert r.status_code == 200, r.text
                    return r.json(), (time.perf_counter() - t0) * 1000

                get(f"/v1/pairs?limit={args.limit}")  # warm-up
                walk, cursor, items = [], None, 0
                while True:
                    body, ms = get(f"/v1/pairs?limit={args.limit}" + (f"&cursor={cursor}" if cursor else ""))
                    walk.append(ms)
                    items += len(body["items"])
                    cursor = body["next_cursor"]
                    if not cursor:
                        break
                assert items == n and body["total"] == n
                rows = [
                    (f"every page of {len(walk)} (walked by cursor)", walk),
                    ("first page", [get(f"/v1/pairs?limit={args.limit}")[1] for _ in range(20)]),
                    ("one gripper", [get(f"/v1/pairs?limit={args.limit}&gripper=jaw-1")[1] for _ in range(20)]),
                    (
                        "object name contains '12'",
                        [get(f"/v1/pairs?limit={args.limit}&object_contains=12")[1] for _ in range(20)],
                    ),
                    ("released only", [get(f"/v1/pairs?limit={args.limit}&released=true")[1] for _ in range(20)]),
                ]
    finally:
        with psycopg.connect(admin, autocommit=True) as conn:
            conn.execute(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE')
    print(f"GET /v1/pairs, {n:,} pairs, pages of {args.limit}, in-process (TestClient)\n")
    print(f"| {'request':<40} | median ms | p95 ms | max ms |")
    print(f"|{'-' * 42}|-----------|--------|--------|")
    for label, v in rows:
        p95 = sorted(v)[max(0, round(0.95 * len(v)) - 1)]
        print(f"| {label:<40} | {statistics.median(v):9.1f} | {p95:6.1f} | {max(v):6.1f} |")


if __name__ == "__main__":
    main()
