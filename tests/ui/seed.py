"""What the review page's browser tests serve: a real `graspgen serve` (embedded SQLite, in-process worker) with a
box part, a jaw gripper, two versions of the pair computed by real jobs, and a failed bulk job."""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
from services_conftest import GRIPPER, box_stl, settings_env, start_serve, stop_process, write_tokens_file

#: a job of a few seconds
SMALL = {"points": 600, "k1": 4, "k2": 2}


def wait_job(c: httpx.Client, job_id: str, timeout: float = 300) -> dict:
    end = time.monotonic() + timeout
    while (body := c.get(f"/v1/jobs/{job_id}").json())["state"] in ("queued", "running"):
        assert time.monotonic() < end, body
        time.sleep(0.2)
    return body


@contextmanager
def seeded_serve(root: Path) -> Iterator[dict]:
    """{url, tokens (name -> token), sets [version 1, version 2], jobs {ok, failed}}; the server stops afterwards."""
    tokens = write_tokens_file(root / "tokens.json")
    env = settings_env(storage_dir=root / "var", tokens_file=root / "tokens.json")
    proc, url = start_serve(env, root / "serve.log")
    try:
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {tokens['writer']}"}, timeout=60) as c:
            up = c.post(
                "/v1/objects",
                files={"file": ("box.stl", box_stl((40.0, 30.0, 20.0)))},
                data={"name": "ui-box", "units": "mm", "mass_kg": "0.05"},
            )
            assert up.status_code == 201, up.text
            assert c.post("/v1/grippers", json={**GRIPPER, "name": "ui-jaw", "grip_force": 20.0}).status_code == 201
            first = c.post("/v1/jobs", json={"object": "ui-box", "gripper": "ui-jaw", "params": SMALL}).json()
            second = c.post(
                "/v1/jobs", json={"object": "ui-box", "gripper": "ui-jaw", "params": {**SMALL, "points": 900}}
            ).json()
            bulk = c.post("/v1/bulk-jobs", json={"items": [{"object": "ui-box", "gripper": "no-such-gripper"}]}).json()
            done = [wait_job(c, j["id"]) for j in (first, second, bulk)]
            assert [d["state"] for d in done] == ["succeeded", "succeeded", "failed"], done
        yield {
            "root": root,
            "url": url,
            "tokens": tokens,
            "sets": [done[0]["grasp_set"], done[1]["grasp_set"]],
            "jobs": {"ok": first["id"], "failed": bulk["id"]},
        }
    finally:
        stop_process(proc)


def add_pairs(root: Path, prefix: str, n: int, gripper: str = "ui-jaw") -> list[str]:
    """`n` more pairs of `gripper` (objects `prefix-000`...), written into the served instance's SQLite file as the
    API and the worker would leave them (an object version, a grasp set, the catalogue refreshed): enough pairs to
    page through without computing them. Returns the object names."""
    import json

    from sqlalchemy import select

    from services.common import catalogue
    from services.common.db import Database
    from services.common.models import GraspSet, Gripper, GripperVersion, ObjectModel, ObjectVersion
    from services.common.settings import Settings
    from services.common.storage import make_storage

    settings = Settings(storage_dir=root / "var", tokens_file=root / "tokens.json")
    db = Database(settings)
    storage = make_storage(settings)
    names = [f"{prefix}-{i:03d}" for i in range(n)]
    try:
        with db.session() as s:
            g = s.execute(select(Gripper).where(Gripper.name == gripper)).scalar_one()
            gv = s.execute(select(GripperVersion).where(GripperVersion.gripper_id == g.id)).scalars().first()
            for name in names:
                obj = ObjectModel(name=name)
                s.add(obj)
                s.flush()
                ov = ObjectVersion(
                    object_id=obj.id,
                    version=1,
                    sha256=name.encode().hex().ljust(64, "0")[:64],
                    units="mm",
                    format="stl",
                    size_bytes=0,
                    extents=[0.01, 0.01, 0.01],
                    watertight=True,
                    warnings=[],
                    file_key="-",
                )
                s.add(ov)
                s.flush()
                export = {
                    "format": "graspgen.grasp_set/1",
                    "units": "m",
                    "object": {"name": name, "version": 1},
                    "gripper": gv.spec,
                    "params": {"points": 1},
                    "stats": {},
                    "grasps": [],
                }
                blob = storage.put_bytes(json.dumps(export).encode())
                s.add(
                    GraspSet(
                        object_id=obj.id,
                        gripper_id=g.id,
                        version=1,
                        object_version_id=ov.id,
                        gripper_version_id=gv.id,
                        params={"points": 1},
                        params_key=name,
                        job_id=uuid.uuid4(),
                        stats={},
                        grasp_count=0,
                        export_key=blob.key,
                        export_sha256=blob.sha256,
                        export_size=blob.size,
                    )
                )
                s.flush()
                catalogue.refresh(s, object_id=obj.id, gripper_id=g.id)
            s.commit()
    finally:
        db.dispose()
    return names
