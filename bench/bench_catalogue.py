"""The catalogue's lookups in-process against this machine's PostgreSQL: the query before releases (the newest set
of the pair by version) against the current one (the pair's row in catalogue_pairs), and the fleet page before and
after. Interleaved A/B in rounds, so machine load hits both alike. Prints a table; asserts nothing.

    .venv/bin/python bench/bench_catalogue.py [--objects 1000] [--sets-per-object 3] [--lookups 2000]
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import sys
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PG_URL = os.environ.get("GRASPGEN_BENCH_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def _old_entry(session, object: str, gripper: str):  # type: ignore[no-untyped-def]
    """GET /v1/catalogue/{object}/{gripper} before releases: the pair's highest version, whatever it was made for."""
    from sqlalchemy import select

    from services.common.models import GraspSet, Gripper, ObjectModel

    return session.execute(
        select(GraspSet.id, GraspSet.version, GraspSet.export_key, GraspSet.export_sha256)
        .join(ObjectModel, ObjectModel.id == GraspSet.object_id)
        .join(Gripper, Gripper.id == GraspSet.gripper_id)
        .where(ObjectModel.name == object, Gripper.name == gripper)
        .order_by(GraspSet.version.desc())
        .limit(1)
    ).first()


def _old_page(session, gripper: str, limit: int):  # type: ignore[no-untyped-def]
    """GET /v1/catalogue?gripper= before releases: the newest set of every object by a max(version) subquery."""
    from sqlalchemy import func, select

    from services.api.crud.grasp_sets import summary_out, summary_select
    from services.common.models import GraspSet, Gripper, ObjectModel

    grip_id = session.execute(select(Gripper.id).where(Gripper.name == gripper)).scalar_one()
    newest = (
        select(GraspSet.object_id.label("object_id"), func.max(GraspSet.version).label("version"))
        .where(GraspSet.gripper_id == grip_id)
        .group_by(GraspSet.object_id)
        .subquery()
    )
    q = (
        summary_select()
        .join(newest, (newest.c.object_id == GraspSet.object_id) & (newest.c.version == GraspSet.version))
        .where(GraspSet.gripper_id == grip_id)
    )
    return [summary_out(r) for r in session.execute(q.order_by(ObjectModel.name).limit(limit + 1)).all()]


def seed(db, n: int, per: int) -> list[str]:  # type: ignore[no-untyped-def]
    from services.common import catalogue
    from services.common.jobs import params_key
    from services.common.models import GraspSet, Gripper, GripperVersion, ObjectModel, ObjectVersion

    names = [f"part-{i:05d}" for i in range(n)]
    with db.session() as s:
        g = Gripper(name="pgn-80")
        s.add(g)
        s.flush()
        gv = GripperVersion(gripper_id=g.id, version=1, spec={}, spec_sha256="0" * 64)
        s.add(gv)
        s.flush()
        for name in names:
            o = ObjectModel(name=name)
            s.add(o)
            s.flush()
            ov = ObjectVersion(
                object_id=o.id, version=1, sha256="1" * 64, units="mm", format="stl", size_bytes=1,
                extents=[0.1, 0.1, 0.1], watertight=True, warnings=[], file_key="k",
            )  # fmt: skip
            s.add(ov)
            s.flush()
            for v in range(1, per + 1):
                params = {"seed": v}
                s.add(
                    GraspSet(
                        object_id=o.id,
                        gripper_id=g.id,
                        version=v,
                        object_version_id=ov.id,
                        gripper_version_id=gv.id,
                        params=params,
                        params_key=params_key(params, None),
                        job_id=uuid.uuid4(),
                        stats={},
                        grasp_count=0,
                        export_key="e",
                        export_sha256="2" * 64,
                        export_size=1,
                    )  # fmt: skip
                )
            s.flush()
            catalogue.refresh(s, object_id=o.id, gripper_id=g.id)
    return names


def _pct(xs: list[float], q: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q * len(xs)))]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", type=int, default=1000)
    ap.add_argument("--sets-per-object", type=int, default=3)
    ap.add_argument("--lookups", type=int, default=2000)
    ap.add_argument("--pages", type=int, default=200)
    args = ap.parse_args()

    import psycopg

    from services.api.crud.grasp_sets import catalogue_entry, list_catalogue
    from services.common.db import Database
    from services.common.migrate import upgrade
    from services.common.settings import Settings

    schema = f"ggbench_{uuid.uuid4().hex[:8]}"
    admin = psycopg.connect(PG_URL.replace("postgresql+psycopg", "postgresql"), autocommit=True)
    admin.execute(f'CREATE SCHEMA "{schema}"')
    try:
        settings = Settings(database_url=PG_URL, database_schema=schema)
        upgrade(settings)
        db = Database(settings)
        t0 = time.perf_counter()
        names = seed(db, args.objects, args.sets_per_object)
        print(f"seeded {args.objects} objects x {args.sets_per_object} sets in {time.perf_counter() - t0:.1f} s")
        rng = random.Random(0)
        cases = {
            "entry, before (newest by version)": lambda s: _old_entry(s, rng.choice(names), "pgn-80"),
            "entry, now (catalogue_pairs row)": lambda s: catalogue_entry(s, rng.choice(names), "pgn-80", None),
            "fleet page of 50, before": lambda s: _old_page(s, "pgn-80", 50),
            "fleet page of 50, now": lambda s: list_catalogue(s, gripper="pgn-80", limit=50),
            "fleet since=watermark, nothing changed": lambda s: list_catalogue(
                s, gripper="pgn-80", since=args.objects, limit=50
            ),
        }
        times: dict[str, list[float]] = {k: [] for k in cases}
        rounds = 20
        with db.read_sessions() as s:
            for _ in range(rounds):  # interleaved: load on the machine hits every case alike
                for name, fn in cases.items():
                    n = (args.lookups if name.startswith("entry") else args.pages) // rounds
                    for _ in range(n):
                        t = time.perf_counter()
                        fn(s)
                        times[name].append((time.perf_counter() - t) * 1e6)
        # a new gripper version recomputes every pair of the gripper while holding the change counter
        from sqlalchemy import select

        from services.common import catalogue
        from services.common.models import Gripper, GripperVersion

        with db.sessions() as s:
            s.begin()
            g = s.execute(select(Gripper).where(Gripper.name == "pgn-80")).scalar_one()
            s.add(GripperVersion(gripper_id=g.id, version=2, spec={}, spec_sha256="3" * 64))
            s.flush()
            t = time.perf_counter()
            changed = catalogue.refresh(s, gripper_id=g.id)
            refresh_s = time.perf_counter() - t
            s.rollback()
        print()
        print("| lookup (in-process, one read session, PostgreSQL on loopback) | n | p50 us | p99 us |")
        print("| --- | --- | --- | --- |")
        for name, xs in times.items():
            print(f"| {name} | {len(xs)} | {statistics.median(xs):.0f} | {_pct(xs, 0.99):.0f} |")
        print()
        print(f"new gripper version: {changed} of {args.objects} pairs recomputed in {refresh_s:.2f} s (counter held)")
        db.dispose()
    finally:
        admin.execute(f'DROP SCHEMA "{schema}" CASCADE')
        admin.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
