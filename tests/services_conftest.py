"""Fixtures shared by tests/api, tests/worker and tests/integration (imported by their conftest.py).

Real services only: the PostgreSQL at 127.0.0.1:5432 (database `test`, trust auth) and the Redis at 127.0.0.1:6379.
Every test run and every pytest-xdist worker gets its own PostgreSQL schema and its own Redis key prefix (on a Redis
database number of its own), so parallel workers and parallel runs never see each other's rows or messages.
"""

from __future__ import annotations

import contextlib
import os
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.grippers import GRIPPER

PG_URL = os.environ.get("GRASPGEN_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")
REDIS_URL = os.environ.get("GRASPGEN_TEST_REDIS_URL", "redis://127.0.0.1:6379")

_RUN = uuid.uuid4().hex[:8]


def store_grasp_set_row(session, storage, ov, gv, version: int, export: dict) -> int:  # type: ignore[no-untyped-def]
    """A grasp-set row for object version `ov` and gripper version `gv` with `export` stored as its blob, as the
    worker stores a finished set (no candidates, no grasps); returns its id. The caller refreshes the catalogue."""
    import json

    from services.common.jobs import params_key
    from services.common.models import GraspSet

    blob = storage.put_bytes(json.dumps(export).encode())
    params = export["params"]
    gs = GraspSet(
        object_id=ov.object_id,
        gripper_id=gv.gripper_id,
        version=version,
        object_version_id=ov.id,
        gripper_version_id=gv.id,
        params=params,
        params_key=params_key(params, None),
        job_id=uuid.uuid4(),
        stats={},
        grasp_count=0,
        export_key=blob.key,
        export_sha256=blob.sha256,
        export_size=blob.size,
    )
    session.add(gs)
    session.flush()
    return gs.id


def worker_id() -> str:
    return os.environ.get("PYTEST_XDIST_WORKER", "main")


def unique_name(prefix: str) -> str:
    """A PostgreSQL identifier / Redis prefix unique to this run and this xdist worker."""
    return f"{prefix}_{_RUN}_{worker_id()}_{uuid.uuid4().hex[:6]}".lower()


def redis_db() -> int:
    w = worker_id()
    return 8 if w == "main" else 9 + int(w.removeprefix("gw")) % 7


def _pg_admin():  # type: ignore[no-untyped-def]
    import psycopg

    return psycopg.connect(PG_URL.replace("postgresql+psycopg", "postgresql"), autocommit=True)


def pg_available() -> bool:
    try:
        with _pg_admin() as conn:
            conn.execute("SELECT 1")
        return True
    except Exception:
        return False


def create_schema(name: str) -> None:
    with _pg_admin() as conn:
        conn.execute(f'CREATE SCHEMA "{name}"')


def drop_schema(name: str) -> None:
    with contextlib.suppress(Exception), _pg_admin() as conn:
        conn.execute(f'DROP SCHEMA IF EXISTS "{name}" CASCADE')


@pytest.fixture
def fresh_pg_schema() -> Iterator[str]:
    """An empty schema of its own (migration tests)."""
    name = unique_name("ggm")
    create_schema(name)
    try:
        yield name
    finally:
        drop_schema(name)


@pytest.fixture(scope="session")
def pg_schema() -> Iterator[str]:
    """One migrated schema per xdist worker for the whole session; tests create uniquely named rows in it."""
    from services.common.migrate import upgrade
    from services.common.settings import Settings

    name = unique_name("gg")
    create_schema(name)
    upgrade(Settings(database_url=PG_URL, database_schema=name))
    try:
        yield name
    finally:
        drop_schema(name)


@pytest.fixture
def settings_from_env() -> Iterator[None]:
    """services.common.settings.get_settings() reads the environment the test sets (monkeypatch) afresh: its cache is
    cleared before the test and again after it."""
    from services.common.settings import get_settings

    get_settings.cache_clear()
    yield
    get_settings.cache_clear()


@pytest.fixture
def storage_dir(tmp_path: Path) -> Path:
    d = tmp_path / "var"
    d.mkdir()
    return d


# -- test data --------------------------------------------------------------------------------------------------------


def box_stl(extents_mm: tuple[float, float, float] = (40.0, 30.0, 20.0)) -> bytes:
    """A closed box, in millimetres, as binary STL."""
    import trimesh

    return trimesh.creation.box(extents=extents_mm).export(file_type="stl")


def cylinder_stl(radius_mm: float = 12.0, height_mm: float = 30.0) -> bytes:
    import trimesh

    return trimesh.creation.cylinder(radius=radius_mm, height=height_mm, sections=24).export(file_type="stl")


def slug(prefix: str) -> str:
    return f"{prefix}-{uuid.uuid4().hex[:10]}"


# -- a configured service ---------------------------------------------------------------------------------------------
TOKENS = {"reader": ["read"], "writer": ["write"], "writer2": ["write"], "admin": ["admin"]}


def write_tokens_file(path: Path) -> dict[str, str]:
    """A tokens file (hashes only) with one token per entry of TOKENS; returns name -> token."""
    import json
    import secrets

    from services.common.tokens import hash_token

    tokens = {name: "ggt_test_" + secrets.token_urlsafe(16) for name in TOKENS}
    doc = {"tokens": [{"name": n, "sha256": hash_token(t), "scopes": TOKENS[n]} for n, t in tokens.items()]}
    path.write_text(json.dumps(doc))
    return tokens


class Service:
    """A running app (TestClient) plus what tests need to talk about it."""

    def __init__(self, client, settings, tokens: dict[str, str]) -> None:  # type: ignore[no-untyped-def]
        self.client = client
        self.settings = settings
        self.tokens = tokens
        self.app = client.app

    def h(self, who: str = "writer", **extra: str) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.tokens[who]}", **extra}

    def get(self, url: str, who: str = "reader", **kw):  # type: ignore[no-untyped-def]
        return self.client.get(url, headers={**self.h(who), **kw.pop("headers", {})}, **kw)

    def post(self, url: str, who: str = "writer", **kw):  # type: ignore[no-untyped-def]
        return self.client.post(url, headers={**self.h(who), **kw.pop("headers", {})}, **kw)

    def row_counts(self) -> dict[str, int]:
        from sqlalchemy import func, select

        from services.common.models import Base

        with self.app.state.db.session() as s:
            return {
                name: s.execute(select(func.count()).select_from(t)).scalar_one()
                for name, t in Base.metadata.tables.items()
            }

    def upload(
        self, name: str, data: bytes | None = None, units: str = "mm", filename: str = "part.stl", who: str = "writer"
    ):  # type: ignore[no-untyped-def]
        return self.post(
            "/v1/objects",
            who=who,
            files={"file": (filename, data or box_stl(), "model/stl")},
            data={"name": name, "units": units},
        )

    def gripper(self, name: str, **changes: float):  # type: ignore[no-untyped-def]
        return self.post("/v1/grippers", json={**GRIPPER, "name": name, **changes})

    def wait_job(self, job_id: str, timeout: float = 120.0) -> dict:
        import time

        end = time.monotonic() + timeout
        while True:
            body = self.get(f"/v1/jobs/{job_id}").json()
            if body["state"] in ("succeeded", "failed", "cancelled"):
                return body
            if time.monotonic() > end:
                raise AssertionError(f"job {job_id} still {body['state']} after {timeout} s: {body}")
            time.sleep(0.1)


def redis_cleanup(prefix: str) -> None:
    import redis

    r = redis.Redis.from_url(f"{REDIS_URL}/{redis_db()}")
    try:
        keys = list(r.scan_iter(match=f"{prefix}*", count=1000))
        if keys:
            r.delete(*keys)
    finally:
        r.close()


def broker_settings() -> dict[str, str]:
    """A Redis database number of this xdist worker, and a key prefix and queue of this run."""
    prefix = unique_name("ggq") + ":"
    return {"broker_url": f"{REDIS_URL}/{redis_db()}", "broker_key_prefix": prefix, "queue": prefix.rstrip(":")}


@contextlib.contextmanager
def pg_values(
    root: Path, schema: str, *, broker: bool = True, **extra: object
) -> Iterator[tuple[dict[str, object], dict[str, str]]]:
    """Settings values of a service on the PostgreSQL `schema` with its files in `root` (storage root/var, a new
    tokens file root/tokens.json) and, with `broker`, a Redis queue of its own (emptied afterwards); `extra` adds or
    overrides values. Yields (values, tokens); the values go to Settings(**values) or settings_env(**values)."""
    tokens = write_tokens_file(root / "tokens.json")
    queue = broker_settings() if broker else {}
    values = {
        "database_url": PG_URL,
        "database_schema": schema,
        "storage_dir": root / "var",
        "tokens_file": root / "tokens.json",
        **queue,
        **extra,
    }
    try:
        yield values, tokens
    finally:
        if queue:
            redis_cleanup(queue["broker_key_prefix"])


@pytest.fixture(scope="session")
def pg_service(pg_schema, tmp_path_factory) -> Iterator[Service]:
    """The API on the shared PostgreSQL schema, sending jobs to Redis (no worker consumes them here)."""
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.settings import Settings

    with pg_values(tmp_path_factory.mktemp("pg-service"), pg_schema, max_upload_bytes=256 * 1024) as (values, tokens):
        settings = Settings(**values)
        with TestClient(create_app(settings)) as client:
            yield Service(client, settings, tokens)


@pytest.fixture
def pair(pg_service: Service) -> tuple[str, str]:
    """A new object (a box) and a new gripper on pg_service: (object name, gripper name)."""
    obj, grip = slug("part"), slug("grip")
    assert pg_service.upload(obj).status_code == 201
    assert pg_service.gripper(grip).status_code == 201
    return obj, grip


@pytest.fixture(scope="session")
def sqlite_service(tmp_path_factory) -> Iterator[Service]:
    """The embedded default: a SQLite file and the in-process worker (jobs really run), with the test tokens."""
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.migrate import upgrade
    from services.common.settings import Settings

    root = tmp_path_factory.mktemp("sqlite-service")
    tokens = write_tokens_file(root / "tokens.json")
    settings = Settings(storage_dir=root / "var", tokens_file=root / "tokens.json", max_upload_bytes=256 * 1024)
    upgrade(settings)  # as `graspgen serve` does for its SQLite file
    with TestClient(create_app(settings)) as client:
        yield Service(client, settings, tokens)


# -- S3-compatible storage: moto's server on loopback -----------------------------------------------------------------
def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_http(url: str, timeout: float = 30.0) -> None:
    import time
    import urllib.request

    end = time.monotonic() + timeout
    while True:
        try:
            urllib.request.urlopen(url, timeout=1).close()
            return
        except Exception:
            if time.monotonic() > end:
                raise
            time.sleep(0.1)


@pytest.fixture(scope="session")
def s3_server(tmp_path_factory) -> Iterator[dict[str, str]]:
    """moto in server mode (a real HTTP S3 endpoint on 127.0.0.1) with a bucket; yields env for boto3."""
    import subprocess
    import sys

    port = free_port()
    with open(tmp_path_factory.mktemp("moto") / "moto.log", "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    env = {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1"}
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        endpoint = f"http://127.0.0.1:{port}"
        wait_http(endpoint + "/moto-api/")
        import boto3

        bucket = unique_name("gg").replace("_", "-")
        boto3.client("s3", endpoint_url=endpoint, region_name="us-east-1").create_bucket(Bucket=bucket)
        yield {"endpoint": endpoint, "bucket": bucket, **env}
    finally:
        proc.terminate()
        proc.wait(10)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


# -- processes ----------------------------------------------------------------------------------------------------
def wait_for_log(path: Path, needle: str, proc, timeout: float = 90.0) -> None:  # type: ignore[no-untyped-def]
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        text = path.read_text(errors="replace") if path.exists() else ""
        if needle in text:
            return
        if proc.poll() is not None:
            raise RuntimeError(f"process exited with {proc.returncode}:\n{text[-3000:]}")
        time.sleep(0.1)
    raise TimeoutError(f"{needle!r} not in {path} after {timeout} s:\n{path.read_text(errors='replace')[-3000:]}")


def stop_process(proc, timeout: float = 30.0) -> None:  # type: ignore[no-untyped-def]
    """SIGTERM (Celery's warm shutdown, uvicorn's graceful stop), then SIGKILL; only this process and its children."""
    import signal
    import subprocess

    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        import psutil

        for child in psutil.Process(proc.pid).children(recursive=True):
            child.kill()
        proc.kill()
        proc.wait(10)


#: this venv's `graspgen` command
GRASPGEN = str(Path(sys.executable).with_name("graspgen"))


def start_serve(  # type: ignore[no-untyped-def]
    env: dict[str, str],
    log: Path,
    *args: str,
    err: Path | None = None,
    graspgen: str = GRASPGEN,
    cwd: Path | None = None,
    timeout: float = 90.0,
):
    """A real `graspgen serve` (this venv's, or the `graspgen` command given) on a free port with `env` and extra
    `args`, its output in `log` (its stderr, where uvicorn logs, in `err` when given): (process, base URL) once it
    answers /healthz; stopped again if it never does."""
    import subprocess

    port = free_port()
    with open(log, "wb") as out, open(err, "wb") if err else contextlib.nullcontext(subprocess.STDOUT) as errors:
        proc = subprocess.Popen(
            [graspgen, "serve", "--port", str(port), *args], env=env, cwd=cwd, stdout=out, stderr=errors
        )
    try:
        wait_for_log(err or log, "Uvicorn running", proc, timeout)
        wait_http(f"http://127.0.0.1:{port}/healthz")
    except Exception:
        stop_process(proc)
        raise
    return proc, f"http://127.0.0.1:{port}"


def start_worker(  # type: ignore[no-untyped-def]
    env: dict[str, str],
    log: Path,
    *,
    command: list[str] | None = None,
    concurrency: int = 1,
    hostname: str | None = None,
    wait: bool = True,
    **popen: object,
):
    """A Celery worker process (`command worker`; by default `python -m services.cli worker` of this interpreter)
    with `env`, its output in `log`, under a hostname of its own; once its log says it is ready (`wait`), else at
    once (the caller waits: `wait_for_log(log, " ready.", proc)`). Stopped again if it never gets ready."""
    import subprocess

    cmd = command or [sys.executable, "-m", "services.cli"]
    args = ["worker", "--concurrency", str(concurrency), "--hostname", f"{hostname or unique_name('w')}@%h"]
    with open(log, "wb") as out:
        proc = subprocess.Popen([*cmd, *args], env=env, stdout=out, stderr=subprocess.STDOUT, **popen)
    if wait:
        try:
            wait_for_log(log, " ready.", proc)
        except Exception:
            stop_process(proc)
            raise
    return proc


def settings_env(**values: object) -> dict[str, str]:
    """os.environ plus GRASPGEN_* variables for a subprocess.

    The worker's reconciler is off unless `reconcile_interval_s` is given: a session's shared schema holds other tests'
    queued jobs (sent to queues no worker reads), which a reconciler would send again to its own worker's queue.
    """
    values.setdefault("reconcile_interval_s", 0)
    env = {k: v for k, v in os.environ.items() if not k.startswith("GRASPGEN_")}
    env.update({f"GRASPGEN_{k.upper()}": str(v) for k, v in values.items() if v is not None})
    return env


def seed_grasp_sets(
    service: Service, gripper: str, objects: list[str], *, version_of: dict[str, int] | None = None
) -> dict[str, list[int]]:
    """Grasp-set rows and export blobs written directly (no core run), as a catalogue to page through.

    Every object gets an object version and `version_of[name]` (default 1) more grasp sets for `gripper`, numbered
    after any it has; object and gripper are registered through the API first. Returns name -> new ids, oldest first.
    """

    from sqlalchemy import func, select

    from services.common import catalogue
    from services.common.models import GraspSet, Gripper, GripperVersion, ObjectModel, ObjectVersion

    assert service.gripper(gripper).status_code in (200, 201)
    out: dict[str, list[int]] = {}
    state = service.app.state
    for name in objects:
        assert service.upload(name).status_code in (200, 201)
        with state.db.session() as s:
            obj = s.execute(select(ObjectModel).where(ObjectModel.name == name)).scalar_one()
            ov = s.execute(select(ObjectVersion).where(ObjectVersion.object_id == obj.id)).scalars().first()
            g = s.execute(select(Gripper).where(Gripper.name == gripper)).scalar_one()
            gv = s.execute(select(GripperVersion).where(GripperVersion.gripper_id == g.id)).scalars().first()
            ids = []
            have = (
                s.execute(
                    select(func.max(GraspSet.version)).where(GraspSet.object_id == obj.id, GraspSet.gripper_id == g.id)
                ).scalar_one_or_none()
                or 0
            )
            for v in range(have + 1, have + (version_of or {}).get(name, 1) + 1):
                params = {"points": 1000 + v, "seed": v}
                export = {  # a grasp_set/1 document without grasps (the OpenAPI schema GraspSetExport)
                    "format": "graspgen.grasp_set/1",
                    "units": "m",
                    "object": {"name": name, "version": 1},
                    "gripper": gv.spec,
                    "params": params,
                    "stats": {"candidates": 0},
                    "grasps": [],
                }
                ids.append(store_grasp_set_row(s, state.storage, ov, gv, v, export))
            catalogue.refresh(s, object_id=obj.id, gripper_id=g.id)  # as the worker does when it stores a set
            out[name] = ids
    return out
