"""A service stack of its own for fault tests: a redis-server on a free port (no persistence) that a test may kill,
restart or flush, a migrated PostgreSQL schema, local artifact storage, the API in this process (TestClient) and
Celery worker subprocesses with their own temp directory. Nothing here touches the machine's shared Redis.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from services_conftest import (
    PG_URL,
    Service,
    create_schema,
    drop_schema,
    free_port,
    settings_env,
    slug,
    start_worker,
    stop_process,
    unique_name,
    wait_for_log,
    write_tokens_file,
)

REPO = Path(__file__).resolve().parents[2]
REDIS_SERVER = shutil.which("redis-server") or "/usr/bin/redis-server"
HERE = Path(__file__).resolve().parent

#: a small real job: a few seconds in a fresh worker process
SMALL = {"points": 800, "k1": 4, "k2": 2}


class RedisServer:
    """A redis-server of this test only, without persistence: a restart loses every message."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self.port = free_port()
        self.proc: subprocess.Popen | None = None
        self.starts = 0

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        self.starts += 1
        log = open(self.workdir / f"redis-{self.starts}.log", "wb")  # noqa: SIM115 - kept open by the child
        self.proc = subprocess.Popen(
            [REDIS_SERVER, "--port", str(self.port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no"]
            + ["--daemonize", "no", "--dir", str(self.workdir)],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        log.close()
        end = time.monotonic() + 20
        while True:
            try:
                if self.client().ping():
                    return
            except Exception:
                if self.proc.poll() is not None or time.monotonic() > end:
                    raise
                time.sleep(0.05)

    def kill(self) -> None:
        """A crash: SIGKILL, nothing saved."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)

    def restart(self) -> None:
        self.kill()
        self.start()

    def client(self):  # type: ignore[no-untyped-def]
        import redis

        return redis.Redis(host="127.0.0.1", port=self.port, socket_timeout=5)


@dataclass
class Worker:
    proc: subprocess.Popen
    log: Path
    own_group: bool

    def text(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def children(self) -> list:  # type: ignore[type-arg]
        import psutil

        return psutil.Process(self.proc.pid).children()

    def kill_child(self) -> int:
        """SIGKILL the one prefork child (the process running the job); returns its pid."""
        (child,) = self.children()
        child.kill()
        return child.pid

    def kill_group(self) -> None:
        """SIGKILL the whole worker: main process and prefork children (its own process group)."""
        assert self.own_group
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.own_group and self.proc.poll() is None:
            stop_process(self.proc)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)  # children left behind by a failed stop
        else:
            stop_process(self.proc)


@dataclass
class Stack:
    svc: Service
    values: dict[str, object]
    root: Path
    redis: RedisServer
    tmp: Path
    workers: list[Worker] = field(default_factory=list)

    @property
    def storage_dir(self) -> Path:
        return Path(str(self.values["storage_dir"]))

    def start_worker(
        self, *, concurrency: int = 1, own_group: bool = False, shim: bool = False, **overrides: object
    ) -> Worker:
        """`graspgen worker` with the stack's settings (plus overrides); `shim` preloads tests/reliability/
        stuck_kernel.py; `own_group` puts it in a process group of its own, so the test can kill all of it."""
        n = len(self.workers) + 1
        boot = (
            f"import sys; sys.path.insert(0, {str(HERE)!r}); import stuck_kernel; stuck_kernel.install(); "
            "from services.cli import main; sys.exit(main(sys.argv[1:]))"
        )
        env = settings_env(**{**self.values, **overrides})
        env["TMPDIR"] = str(self.tmp)
        log = self.root / f"worker-{n}.log"
        proc = start_worker(
            env,
            log,
            command=[sys.executable, "-c", boot] if shim else None,
            concurrency=concurrency,
            hostname=f"{unique_name('w')}-{n}",
            wait=False,
            cwd=REPO,
            start_new_session=own_group,
        )
        w = Worker(proc, log, own_group)
        self.workers.append(w)
        wait_for_log(log, " ready.", proc)
        return w

    def stop_workers(self) -> None:
        """Stop every worker a test started (tests call this from an autouse fixture, so a failed test leaves no
        worker consuming the next test's messages)."""
        while self.workers:
            self.workers.pop().stop()

    # -- the service ------------------------------------------------------------------------------------------------
    def pair(self, part: bytes) -> tuple[str, str]:
        obj, grip = slug("part"), slug("pgn")
        assert self.svc.upload(obj, part).status_code == 201
        assert self.svc.gripper(grip).status_code == 201
        return obj, grip

    def submit(self, obj: str, grip: str, params: dict) -> str:  # type: ignore[type-arg]
        r = self.svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": params})
        assert r.status_code == 202, r.text
        return r.json()["id"]

    def wait_state(self, jid: str, states: tuple[str, ...], timeout: float = 60.0) -> dict:  # type: ignore[type-arg]
        end = time.monotonic() + timeout
        while True:
            body = self.svc.get(f"/v1/jobs/{jid}").json()
            if body["state"] in states:
                return body
            assert time.monotonic() < end, f"job {jid} still {body['state']} after {timeout} s"
            time.sleep(0.02)

    def grasp_sets(self, obj: str) -> list[tuple[int, str]]:
        """(version, job id) of every grasp set of the object."""
        from sqlalchemy import select

        from services.common.models import GraspSet, ObjectModel

        with self.svc.app.state.db.session() as s:
            rows = s.execute(
                select(GraspSet.version, GraspSet.job_id)
                .join(ObjectModel, ObjectModel.id == GraspSet.object_id)
                .where(ObjectModel.name == obj)
                .order_by(GraspSet.version)
            ).all()
        return [(v, str(j)) for v, j in rows]

    def set_job(self, jid: str, **values: object) -> None:
        from sqlalchemy import update

        from services.common.models import Job

        with self.svc.app.state.db.session() as s:
            s.execute(update(Job).where(Job.id == uuid.UUID(jid)).values(**values))

    # -- what a crash may leave behind ------------------------------------------------------------------------------
    def unreferenced_files(self) -> list[str]:
        """Files under the storage dir that no row references (temp files included), and referenced keys that have
        no file."""
        from sqlalchemy import select

        from services.common.models import GraspSet, ObjectVersion

        blobs = self.storage_dir.resolve() / "blobs"
        files = {str(p.relative_to(blobs)) for p in blobs.rglob("*") if p.is_file()}
        with self.svc.app.state.db.session() as s:
            keys = set(s.execute(select(ObjectVersion.file_key)).scalars())
            for column in (GraspSet.export_key, GraspSet.candidates_key, GraspSet.recording_key):
                keys.update(k for k in s.execute(select(column)).scalars() if k)
        referenced = {k.removeprefix("sha256/") for k in keys}
        return sorted(files - referenced) + sorted(f"missing:{k}" for k in referenced - files)

    def leftover_temp(self) -> list[str]:
        """What the workers' temp directory holds besides the (empty) private directories of live processes and
        multiprocessing's own empty `pymp-*` directories (billiard's, of a worker's main process)."""
        import psutil

        left = []
        for p in self.tmp.iterdir():
            pid = p.name.removeprefix("graspgen-w")
            live = p.name.startswith("graspgen-w") and pid.isdigit() and psutil.pid_exists(int(pid))
            if live or (p.name.startswith("pymp-") and p.is_dir()):
                left += [str(q) for q in p.rglob("*")]
            else:
                left.append(str(p))
        return left

    def wait_no_leftovers(self, timeout: float = 30.0) -> None:
        """The reconciler's next pass removes what a killed process left; fail with the list if it does not."""
        end = time.monotonic() + timeout
        while True:
            left = self.unreferenced_files() + self.leftover_temp()
            if not left:
                return
            assert time.monotonic() < end, f"left behind after {timeout} s: {left}"
            time.sleep(0.2)


@contextlib.contextmanager
def make_stack(root: Path, **overrides: object) -> Iterator[Stack]:
    """Schema, redis-server and API of their own; worker subprocesses are started by the tests."""
    from fastapi.testclient import TestClient

    from services.api.app import create_app
    from services.common.migrate import upgrade
    from services.common.settings import Settings

    schema = unique_name("ggr")
    create_schema(schema)
    redis = RedisServer(root)
    workers: list[Worker] = []
    try:
        upgrade(Settings(database_url=PG_URL, database_schema=schema))
        redis.start()
        tokens = write_tokens_file(root / "tokens.json")
        tmp = root / "tmp"
        tmp.mkdir()
        values: dict[str, object] = {
            "database_url": PG_URL,
            "database_schema": schema,
            "db_pool_size": 4,
            "storage_dir": root / "var",
            "tokens_file": root / "tokens.json",
            "broker_url": redis.url,
            "queue": "graspgen",
            "progress_interval_s": 0.1,
            "reconcile_interval_s": 1,
            "reconcile_grace_s": 1,
            **overrides,
        }
        settings = Settings(**values)
        with TestClient(create_app(settings)) as client:
            stack = Stack(Service(client, settings, tokens), values, root, redis, tmp, workers)
            yield stack
    finally:
        while workers:
            workers.pop().stop()
        redis.kill()
        drop_schema(schema)


def stack_fixture(name: str, **overrides: object):  # type: ignore[no-untyped-def]
    """A test module's `stack` fixture: make_stack(**overrides) once for the module (`stack = stack_fixture(...)`)."""

    @pytest.fixture(scope="module", name="stack")
    def stack(tmp_path_factory):  # type: ignore[no-untyped-def]
        with make_stack(tmp_path_factory.mktemp(name), **overrides) as s:
            yield s

    return stack


def stopping_workers():  # type: ignore[no-untyped-def]
    """An autouse fixture that stops the workers each test started, so that a failed test leaves no worker consuming
    the next test's messages (`_stop_workers = stopping_workers()`)."""

    @pytest.fixture(autouse=True, name="_stop_workers")
    def _stop_workers(stack):  # type: ignore[no-untyped-def]
        yield
        stack.stop_workers()

    return _stop_workers
