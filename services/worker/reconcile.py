"""The reconciler: puts jobs whose broker message was lost back on the broker, and removes what dead worker processes
left in the temp directory. It runs in the main process of every `graspgen worker` (never a kernel, only SQL and
Redis): one pass when the worker is ready, then one every `reconcile_interval_s` on a daemon thread (0: off).

Rules (docs/SERVICE.md, "Faults"):

- **queued**: a job row `queued` for longer than `reconcile_grace_s` whose message is neither in the queue nor in the
  broker's set of unacknowledged messages (Redis flushed, or restarted without persistence) is sent again.
- **running**: a running job is left to the broker. Its message is unacknowledged until the job ends and comes back
  when the worker holding it is lost: at once when a prefork child dies (`task_reject_on_worker_lost`), after
  `broker_visibility_timeout_s` when the whole worker dies. Only when the row has not changed for
  `job_time_limit_s + reconcile_grace_s` (no run outlives the hard limit, so its worker is gone) and no message for it
  is left in the broker either is it sent again.
- **sending twice is safe**: the runner's claim (services/worker/runner.py) runs a `queued` job once, and treats a
  fresh message for a `running` job as a duplicate (no run, attempts unchanged) unless it is a redelivery, a retry, or
  the row is abandoned as above. A duplicate of a finished job does nothing.
- **temp files**: every prefork child writes its temp files (the job's part file, candidates and .rrd before they
  are stored; the storage's own temp copies) under `<tmp>/graspgen-w<pid>/`; a pass removes the directories of
  processes that no longer exist, and `.tmp-*` files older than the hard limit plus the grace in a local storage dir.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import tempfile
import threading
import time
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import select

from services.common.db import Database
from services.common.models import Job, utcnow
from services.common.settings import Settings
from services.jobkinds import CONTAINER_KINDS
from services.worker.runner import abandoned_before

if TYPE_CHECKING:
    from services.worker.dispatch import CeleryDispatcher

__all__ = [
    "Reconciler",
    "Pass",
    "TEMP_PREFIX",
    "abandoned_before",
    "use_private_tempdir",
    "sweep_temp",
    "start",
    "stop",
    "connect_worker_signals",
]

log = logging.getLogger(__name__)

#: a prefork child's temp directory is <tmp>/graspgen-w<pid>
TEMP_PREFIX = "graspgen-w"
#: kombu's Redis transport: priority queues are `<queue><sep><priority>`, unacknowledged messages a hash
_PRIORITY_SEP = "\x06\x16"
_PRIORITY_STEPS = (0, 3, 6, 9)
_UNACKED_KEY = "unacked"
_SCAN_CHUNK = 1000


@dataclass
class Pass:
    """What one reconciler pass saw and did."""

    queued: list[str] = field(default_factory=list)  # queued longer than the grace period
    abandoned: list[str] = field(default_factory=list)  # running, row unchanged past the hard limit plus the grace
    in_broker: int = 0  # of those, how many still have a message in the queue or the unacknowledged set
    sent: list[str] = field(default_factory=list)  # sent again
    removed: list[str] = field(default_factory=list)  # temp directories and files removed


class Reconciler:
    def __init__(self, settings: Settings, db: Database | None = None) -> None:
        if settings.broker_url is None:
            raise ValueError("the reconciler needs a broker (GRASPGEN_BROKER_URL)")
        self.settings = settings
        self.db = db or Database(settings)
        self._owns_db = db is None
        self._dispatcher: CeleryDispatcher | None = None

    # -- one pass -------------------------------------------------------------------------------------------------
    def run_once(self) -> Pass:
        """Send again the jobs whose message is lost; remove dead processes' temp files. Never raises for an
        unreachable database or broker (the next pass tries again)."""
        result = Pass()
        try:
            result.removed = sweep_temp(self.settings)
        except Exception:
            log.warning("reconcile: temp sweep failed", exc_info=True)
        try:
            result.queued, result.abandoned = self.candidates()
            wanted = set(result.queued) | set(result.abandoned)
            if wanted:
                present = self.broker_job_ids()
                result.in_broker = len(wanted & present)
                lost = wanted - present
                if lost:
                    # read again after the broker: a job claimed or finished meanwhile is no longer a candidate
                    still = set().union(*self.candidates(lost))
                    result.sent = [j for j in result.queued + result.abandoned if j in still]
                    self.resend(result.sent)
        except Exception:
            log.warning("reconcile: pass failed; the next one tries again", exc_info=True)
        finally:
            if self._owns_db:
                # no idle connection stays in the worker's main process, whose prefork children are forked from it
                self.db.dispose()
        if result.sent:
            log.warning(
                "reconcile: sent %d job(s) again whose broker message was lost: %s",
                len(result.sent),
                ", ".join(result.sent),
            )
        return result

    def candidates(self, only: Iterable[str] | None = None) -> tuple[list[str], list[str]]:
        """(queued longer than the grace, running and abandoned) job ids, oldest first; bulk parents never."""
        now = utcnow()
        queued_before = now - timedelta(seconds=self.settings.reconcile_grace_s)
        stale = abandoned_before(self.settings, now)
        ids = None if only is None else [uuid.UUID(str(i)) for i in only]
        with self.db.read_sessions() as s:

            def select_ids(*where) -> list[str]:
                q = select(Job.id).where(Job.kind.not_in(CONTAINER_KINDS), *where)
                if ids is not None:
                    q = q.where(Job.id.in_(ids))
                return [str(i) for i in s.execute(q.order_by(Job.created_at)).scalars()]

            queued = select_ids(Job.state == "queued", Job.created_at < queued_before)
            abandoned = select_ids(Job.state == "running", Job.updated_at < stale)
        return queued, abandoned

    def broker_job_ids(self) -> set[str]:
        """Ids of the tasks that have a message in the queue (any priority) or in the unacknowledged set."""
        import redis

        opts = {"socket_timeout": 10, "socket_connect_timeout": 5}
        client = redis.Redis.from_url(self.settings.broker_url.get_secret_value(), **opts)  # type: ignore[union-attr]  # runs with a broker: broker_url is set
        prefix = self.settings.broker_key_prefix
        found: set[str] = set()
        try:
            queues = [self.settings.queue] + [f"{self.settings.queue}{_PRIORITY_SEP}{p}" for p in _PRIORITY_STEPS[1:]]
            for q in queues:
                key = prefix + q
                start = 0
                while True:
                    chunk = client.lrange(key, start, start + _SCAN_CHUNK - 1)
                    found.update(filter(None, map(_task_id, chunk)))
                    if len(chunk) < _SCAN_CHUNK:
                        break
                    start += _SCAN_CHUNK
            for _, raw in client.hscan_iter(prefix + _UNACKED_KEY, count=_SCAN_CHUNK):
                found.update(filter(None, [_task_id(raw, unacked=True)]))
        finally:
            client.close()
        return found

    def resend(self, job_ids: Sequence[str]) -> None:
        """Send a fresh message for each job (the same task id as the API's). Safe for any job: see the module doc."""
        if not job_ids:
            return
        if self._dispatcher is None:
            from services.worker.dispatch import CeleryDispatcher

            self._dispatcher = CeleryDispatcher(self.settings)  # its own Celery app and connections
        for jid in job_ids:  # one message each: a group would make them share a group id
            self._dispatcher.send([jid])

    def close(self) -> None:
        if self._dispatcher is not None:
            self._dispatcher.close()
            self._dispatcher = None
        if self._owns_db:
            self.db.dispose()


def _task_id(raw: bytes | str, unacked: bool = False) -> str | None:
    try:
        doc = json.loads(raw)
        message = doc[0] if unacked else doc
        headers = message.get("headers") or {}
        return str(headers.get("id") or message.get("properties", {}).get("correlation_id") or "") or None
    except (ValueError, TypeError, KeyError, IndexError, AttributeError):
        return None


# -- temp files of dead processes ---------------------------------------------------------------------------------
def use_private_tempdir(base: str | Path | None = None) -> Path:
    """Send this process's temp files to <tmp>/graspgen-w<pid>/ (called in each prefork child), so that what a killed
    child leaves behind can be told apart from the files of live processes and removed."""
    root = Path(base) if base is not None else Path(tempfile.gettempdir())
    own = root / f"{TEMP_PREFIX}{os.getpid()}"
    own.mkdir(mode=0o700, exist_ok=True)
    tempfile.tempdir = str(own)
    return own


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    return True


def sweep_temp(settings: Settings, base: str | Path | None = None) -> list[str]:
    """Remove temp directories of processes that no longer exist and stale `.tmp-*` files of a local storage dir."""
    removed: list[str] = []
    root = Path(base) if base is not None else Path(tempfile.gettempdir())
    with contextlib.suppress(FileNotFoundError):
        for d in root.iterdir():
            pid = d.name.removeprefix(TEMP_PREFIX)
            if d.name.startswith(TEMP_PREFIX) and pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)):
                shutil.rmtree(d, ignore_errors=True)
                removed.append(str(d))
    if not settings.storage_url:
        # an upload killed between its temp file and the rename; no upload lasts as long as a job may
        cutoff = time.time() - (settings.job_time_limit_s + settings.reconcile_grace_s)
        blobs = Path(settings.storage_dir).resolve() / "blobs"
        for f in blobs.glob("*/.tmp-*"):
            with contextlib.suppress(FileNotFoundError):
                if f.stat().st_mtime < cutoff:
                    f.unlink()
                    removed.append(str(f))
    if removed:
        log.info("reconcile: removed %d temp file(s) of dead processes", len(removed))
    return removed


# -- in the worker ------------------------------------------------------------------------------------------------
_stop = threading.Event()
_thread: threading.Thread | None = None


def start(settings: Settings) -> threading.Thread | None:
    """One pass now and then every reconcile_interval_s, on a daemon thread of the calling (main) process."""
    global _thread
    if settings.broker_url is None:
        return None
    if settings.reconcile_interval_s <= 0:
        log.info("reconcile: off (GRASPGEN_RECONCILE_INTERVAL_S=0)")
        return None
    if _thread is not None and _thread.is_alive():
        return _thread
    _stop.clear()

    def loop() -> None:
        reconciler = Reconciler(settings)
        try:
            while not _stop.is_set():
                reconciler.run_once()
                _stop.wait(settings.reconcile_interval_s)
        finally:
            reconciler.close()

    log.info(
        "reconcile: every %s s, grace %s s (lost queued jobs are sent again)",
        settings.reconcile_interval_s,
        settings.reconcile_grace_s,
    )
    _thread = threading.Thread(target=loop, name="graspgen-reconcile", daemon=True)
    _thread.start()
    return _thread


def stop(timeout: float = 5.0) -> None:
    global _thread
    _stop.set()
    if _thread is not None:
        _thread.join(timeout)
        _thread = None


def connect_worker_signals(settings: Settings) -> None:
    """The reconciler in a worker's main process (a pass when it is ready, then periodic ones; stopped at shutdown) and
    a private temp directory in every prefork child. Called where a worker starts (`graspgen worker`,
    services/worker/celery_main.py), never on import; connecting again replaces the earlier connection."""
    from celery.signals import worker_process_init, worker_ready, worker_shutdown

    def on_ready(sender=None, **_kw) -> None:
        start(settings)

    def on_shutdown(sender=None, **_kw) -> None:
        stop()

    def on_child(sender=None, **_kw) -> None:
        use_private_tempdir()

    for signal, handler in ((worker_ready, on_ready), (worker_shutdown, on_shutdown), (worker_process_init, on_child)):
        uid = f"graspgen.reconcile.{handler.__name__}"
        signal.disconnect(dispatch_uid=uid)
        signal.connect(handler, weak=False, dispatch_uid=uid)
