"""Runs one job: claim the row, fetch inputs, run its kind (services/jobkinds), store artifacts, commit the result in
one transaction.

Idempotent by job id: a finished job is never run again, and the grasp set is tied to the job by a unique column, so
a redelivered message can never add a second grasp-set version. Artifacts go to storage before the transaction that
makes them visible commits, so a reader never sees a grasp set whose files are missing.
"""

from __future__ import annotations

import functools
import json
import logging
import socket
import tempfile
import time
import uuid
from collections.abc import Callable
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from celery.exceptions import SoftTimeLimitExceeded
from sqlalchemy import func, insert, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from services.common import catalogue, jobs
from services.common.db import Database, is_unavailable
from services.common.grippers import stored_gripper_spec
from services.common.models import (
    TERMINAL_STATES,
    Grasp,
    GraspSet,
    Gripper,
    GripperFile,
    GripperVersion,
    Job,
    ObjectModel,
    ObjectVersion,
    utcnow,
)
from services.common.settings import Settings
from services.common.storage import Storage, StorageError, StoredBlob, make_storage
from services.jobkinds import RUNNABLE, JobInputs, JobKind, RunContext, is_container

__all__ = ["JobRunner", "abandoned_before"]

log = logging.getLogger(__name__)


def abandoned_before(settings: Settings, now: datetime | None = None) -> datetime:
    """A running job whose row last changed before this has no live worker: no run outlives the hard time limit
    (the claim below and the reconciler, services/worker/reconcile.py, both use it)."""
    return (now or utcnow()) - timedelta(seconds=settings.job_time_limit_s + settings.reconcile_grace_s)


def _time_limit_in(exc: BaseException) -> bool:
    """Did the soft time limit or the runner's deadline end the job? Also when the signal landed inside compiled
    code that called back into Python (numba unpickling a constant), which re-raises it wrapped in a SystemError:
    the limit is then the exception's cause or context."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, (SoftTimeLimitExceeded, _TimeLimitError)):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


class _TimeLimitError(Exception):
    pass


class JobRunner:
    def __init__(self, db: Database, storage: Storage, settings: Settings) -> None:
        self.db = db
        self.storage = storage
        self.settings = settings

    @classmethod
    def from_settings(cls, settings: Settings) -> JobRunner:
        return cls(Database(settings), make_storage(settings), settings)

    # -- entry point ----------------------------------------------------------------------------------------------
    def run(self, job_id: str, *, redelivered: bool = True) -> str:
        """`redelivered=False`: a fresh message, which must not take over a job another worker is running."""
        jid = uuid.UUID(str(job_id))
        claimed = self._claim(jid, redelivered)
        if isinstance(claimed, str):
            return claimed
        inputs = claimed
        started = time.monotonic()
        try:
            with tempfile.TemporaryDirectory(prefix="graspgen-job-") as tmp:
                result = self._execute(inputs, Path(tmp))
                return self._commit_result(inputs, *result)
        except Exception as exc:
            from graspgen.errors import Cancelled, GraspgenError

            if _time_limit_in(exc):
                limit = self.settings.job_soft_time_limit_s
                return self._end(
                    jid,
                    "failed",
                    jobs.problem("time-limit", "Time limit exceeded", f"the job ran longer than {limit} s"),
                )
            if isinstance(exc, Cancelled):
                return self._end(jid, "cancelled")
            if is_unavailable(exc):
                raise  # the database, not the job, failed (after retries): the task retries and the job runs again
            if isinstance(exc, GraspgenError):
                from graspgen.memory import MemoryLimitError
                from services.common.memory_guard import problem_extra

                fields: dict[str, Any] = {"field": exc.field} if exc.field else {}
                if isinstance(exc, MemoryLimitError):
                    fields.update(problem_extra(exc))  # the largest point count that fits, the estimate, the budget
                err = jobs.problem(exc.code, "Invalid input", exc.message, **fields)
                return self._end(jid, "failed", err)
            log.exception("job %s failed after %.1f s", jid, time.monotonic() - started)
            return self._end(
                jid,
                "failed",
                jobs.problem("internal-error", "Internal error", "the job failed; see the worker log", status=500),
            )

    def fail_time_limit(self, job_id: str) -> None:
        limit = self.settings.job_time_limit_s
        self._end(
            uuid.UUID(job_id),
            "failed",
            jobs.problem("time-limit", "Time limit exceeded", f"the job was killed after {limit} s"),
        )

    # -- claim ----------------------------------------------------------------------------------------------------
    def _abandoned(self, job: Job) -> bool:
        return job.updated_at < abandoned_before(self.settings)

    def _claim(self, jid: uuid.UUID, redelivered: bool = True) -> JobInputs | str:
        with self.db.session() as s:
            job = s.execute(select(Job).where(Job.id == jid).with_for_update()).scalar_one_or_none()
            if job is None:
                log.warning("job %s does not exist; message dropped", jid)
                return "missing"
            if job.state in TERMINAL_STATES:
                return job.state  # a redelivery of a finished job
            if is_container(job.kind):
                return job.state  # parents are aggregates, never run
            if job.state == "running" and not redelivered and not self._abandoned(job):
                # a duplicate message (services/worker/reconcile.py) while another worker runs the job: not a new run
                log.info("job %s is running elsewhere; duplicate message dropped", jid)
                return "running"
            if job.cancel_requested:
                jobs.finish(job, "cancelled")
                self._parent(s, job)
                return "cancelled"
            if job.attempts >= self.settings.job_max_attempts:
                jobs.finish(
                    job,
                    "failed",
                    jobs.problem(
                        "worker-lost",
                        "Worker lost",
                        f"the job was started {job.attempts} times and never finished",
                        status=500,
                    ),
                )
                self._parent(s, job)
                return "failed"
            ov = s.get(ObjectVersion, job.object_version_id)
            gv = s.get(GripperVersion, job.gripper_version_id)
            if ov is None or gv is None or job.params is None:
                jobs.finish(job, "failed", jobs.problem("invalid-job", "Invalid job", "the job lacks its inputs"))
                self._parent(s, job)
                return "failed"
            source = s.get(GraspSet, job.source_grasp_set_id) if job.source_grasp_set_id else None
            key = jobs.params_key(job.params, job.source_grasp_set_id)
            existing = s.execute(
                select(GraspSet.id).where(
                    GraspSet.object_version_id == ov.id,
                    GraspSet.gripper_version_id == gv.id,
                    GraspSet.params_key == key,
                )
            ).scalar_one_or_none()
            if existing is not None:
                # the same inputs were computed before: one grasp set per object x gripper x parameters
                job.grasp_set_id = existing
                job.attempts += 1
                job.started_at = job.started_at or utcnow()
                jobs.finish(job, "succeeded")
                self._parent(s, job)
                return "succeeded"
            job.state = "running"
            job.attempts += 1
            job.started_at = job.started_at or utcnow()
            job.stage = "load"
            job.progress = 0.0
            job.error = None
            self._parent(s, job)
            obj_name = s.execute(select(ObjectModel.name).where(ObjectModel.id == ov.object_id)).scalar_one()
            grip_name = s.execute(select(Gripper.name).where(Gripper.id == gv.gripper_id)).scalar_one()
            return JobInputs(
                job_id=jid,
                kind=job.kind,
                attempt=job.attempts,
                params=dict(job.params),
                object_name=obj_name,
                object_version=ov.version,
                object_version_id=ov.id,
                object_id=ov.object_id,
                object_sha256=ov.sha256,
                object_file_key=ov.file_key,
                object_format=ov.format,
                units=ov.units,
                gripper_name=grip_name,
                gripper_version=gv.version,
                gripper_version_id=gv.id,
                gripper_id=gv.gripper_id,
                spec=dict(gv.spec),
                source_grasp_set_id=source.id if source else None,
                source_export_key=source.export_key if source else None,
                source_candidates_key=source.candidates_key if source else None,
                params_key=key,
            )

    # -- execution ------------------------------------------------------------------------------------------------
    def _execute(self, inp: JobInputs, tmp: Path) -> tuple[bytes, dict[str, Any], list[dict[str, Any]], bytes, Path]:
        import rerun as rr

        kind = RUNNABLE.get(inp.kind)
        if kind is None:
            raise ValueError(f"unknown job kind {inp.kind!r}")
        progress = _Progress(self, inp, kind)
        gripper = functools.cache(
            lambda: stored_gripper_spec(self.storage, inp.spec, max_decoded_bytes=self.settings.max_decoded_bytes)
        )
        rrd = tmp / "run.rrd"
        rec = rr.RecordingStream("graspgen", recording_id=str(inp.job_id))
        rec.save(rrd)
        try:
            rec.log("job", rr.TextDocument(self._metadata_markdown(inp), media_type=rr.MediaType.MARKDOWN), static=True)
            progress("load", 0.0)
            gs = kind.run(
                RunContext(
                    inputs=inp,
                    storage=self.storage,
                    tmp=tmp,
                    recording=rec,
                    progress=progress,
                    load_part=lambda path: self._check_memory(inp, path, gripper),
                    gripper=gripper,
                )
            )
            progress("export", 1.0)
            export_bytes = gs.to_json_bytes()
            # the NPZ goes to storage from memory: a temp file would be written, read back for its sha256 and
            # copied (56 MB for a 700 k-candidate set)
            candidates = gs.candidates_npz_bytes()
            rec.log(
                "job/result",
                rr.TextDocument(json.dumps({"grasps": len(gs.grasps), "stats": gs.stats}, indent=2, default=str)),
                static=True,
            )
            progress._timed(None, time.monotonic())  # the export stage ends here
        finally:
            rec.flush()
            rec.disconnect()  # finalises the .rrd (footer) now rather than at garbage collection
        return export_bytes, gs.stats, gs.grasps, candidates, rrd

    def _check_memory(self, inp: JobInputs, path: Path, gripper: Callable[[], Any]):
        """The part, loaded once, after the job's estimated peak memory was checked against this worker's budget
        (with the job's gripper, `gripper()`, when no probe of the part and gripper is cached)."""
        from graspgen.parts import load_part
        from services.common.memory_guard import check_generate

        part = load_part(
            str(path), units=inp.units, name=inp.object_name, max_decoded_bytes=self.settings.max_decoded_bytes
        )
        check_generate(
            budget_bytes=self.settings.job_memory_budget,
            part_sha256=inp.object_sha256,
            units=inp.units,
            spec=inp.spec,
            params=inp.params,
            load_part=lambda: part,
            load_gripper=gripper,
        )
        return part

    def _metadata_markdown(self, inp: JobInputs) -> str:
        meta = {
            "job": str(inp.job_id),
            "kind": inp.kind,
            "attempt": inp.attempt,
            "object": {
                "name": inp.object_name,
                "version": inp.object_version,
                "sha256": inp.object_sha256,
                "source_units": inp.units,
            },
            "gripper": {"name": inp.gripper_name, "version": inp.gripper_version},
            "params": inp.params,
            "derived_from": inp.source_grasp_set_id,
            "host": socket.gethostname(),
            "started_at": utcnow().isoformat(),
        }
        return "# graspgen job\n\n```json\n" + json.dumps(meta, indent=2) + "\n```\n"

    # -- result ---------------------------------------------------------------------------------------------------
    def _commit_result(
        self,
        inp: JobInputs,
        export_bytes: bytes,
        stats: dict[str, Any],
        grasps: list[dict[str, Any]],
        candidates: bytes,
        rrd: Path,
    ) -> str:
        puts = (
            lambda: self.storage.put_bytes(export_bytes),
            lambda: self.storage.put_bytes(candidates),
            lambda: self.storage.put_file(rrd),
        )
        blobs: list[StoredBlob] = []
        try:
            for put in puts:
                blobs.append(put())
        except StorageError as exc:
            return self._storage_failed(inp, blobs, exc)

        def commit(s: Session) -> tuple[str, bool]:
            """(final state, whether the new grasp set uses this run's blobs); safe to run again."""
            job = s.execute(select(Job).where(Job.id == inp.job_id).with_for_update()).scalar_one_or_none()
            if job is None or job.state in TERMINAL_STATES:
                # finished by another delivery, or a commit that failed on the wire went through after all; either
                # way _discard keeps whatever a grasp set references
                return (job.state if job else "missing"), False
            if job.cancel_requested:
                jobs.finish(job, "cancelled")
                self._parent(s, job)
                return "cancelled", False
            existing = (
                s.execute(
                    select(GraspSet.id).where(
                        (GraspSet.job_id == inp.job_id)
                        | (
                            (GraspSet.object_version_id == inp.object_version_id)
                            & (GraspSet.gripper_version_id == inp.gripper_version_id)
                            & (GraspSet.params_key == inp.params_key)
                        )
                    )
                )
                .scalars()
                .first()
            )
            used = existing is None
            if existing is None:
                existing = self._insert_grasp_set(s, inp, blobs, puts, stats, grasps)
            job.grasp_set_id = existing
            jobs.finish(job, "succeeded")
            self._parent(s, job)
            return "succeeded", used

        # a dropped connection (before or at COMMIT) or a concurrent identical job committing first (IntegrityError):
        # run the transaction again; it re-reads the job row, so a commit that did go through is not repeated
        try:
            state, used = self.db.transaction(commit, retry_on=(IntegrityError,))
        except StorageError as exc:  # a blob deleted meanwhile could not be written again
            return self._storage_failed(inp, blobs, exc)
        if not used:
            self._discard(inp, blobs)  # cancelled, or linked to an identical job's grasp set: our files are orphans
        return state

    def _storage_failed(self, inp: JobInputs, blobs: list[StoredBlob], exc: StorageError) -> str:
        """Fail the job without a grasp set, after removing the blobs it wrote that nothing refers to."""
        log.warning("job %s: storage failed while writing its results: %s", inp.job_id, exc.reason)
        self._discard(inp, blobs)
        return self._end(
            inp.job_id,
            "failed",
            jobs.problem(
                "storage-unavailable",
                "Storage unavailable",
                f"the job's results could not be written to storage ({exc.reason}); nothing was kept",
                status=503,
            ),
        )

    def _discard(self, inp: JobInputs, blobs: list[StoredBlob]) -> None:
        """Delete the blobs this run created that no row references, under the object row's lock, which
        `_insert_grasp_set` also holds while it checks its blobs exist (so a concurrent job that found the same bytes
        already stored either is seen here as a reference, or sees them gone and writes them again)."""
        mine = {b.key for b in blobs if b.created}
        if not mine:
            return
        try:
            with self.db.session() as s:
                s.execute(select(ObjectModel.id).where(ObjectModel.id == inp.object_id).with_for_update())
                used: set[str | None] = set()  # the columns are nullable; `in_(mine)` matches no NULL
                for column in (GraspSet.export_key, GraspSet.candidates_key, GraspSet.recording_key):
                    used.update(s.execute(select(column).where(column.in_(mine))).scalars())
                used.update(s.execute(select(ObjectVersion.file_key).where(ObjectVersion.file_key.in_(mine))).scalars())
                used.update(s.execute(select(GripperFile.file_key).where(GripperFile.file_key.in_(mine))).scalars())
                for key in sorted(mine - used):
                    self.storage.delete(key)
        except Exception:
            # unreferenced content-addressed blobs are harmless and safe to garbage-collect later
            log.warning("job %s: could not delete %d unreferenced blob(s)", inp.job_id, len(mine), exc_info=True)

    def _insert_grasp_set(
        self,
        s: Session,
        inp: JobInputs,
        blobs: list[StoredBlob],
        puts: tuple[Callable[[], StoredBlob], ...],
        stats: dict[str, Any],
        grasps: list[dict[str, Any]],
    ) -> int:
        # the object row serialises version numbering for all of its grasp sets, and blob deletion (_discard)
        s.execute(select(ObjectModel.id).where(ObjectModel.id == inp.object_id).with_for_update())
        for blob, put in zip(blobs, puts, strict=True):
            if not self.storage.exists(blob.key):
                put()  # deleted by a failed job that had written the same bytes: store them again
        export_blob, candidates_blob, rrd_blob = blobs
        version = (
            s.execute(
                select(func.max(GraspSet.version)).where(
                    GraspSet.object_id == inp.object_id, GraspSet.gripper_id == inp.gripper_id
                )
            ).scalar_one_or_none()
            or 0
        ) + 1
        gs = GraspSet(
            object_id=inp.object_id,
            gripper_id=inp.gripper_id,
            version=version,
            object_version_id=inp.object_version_id,
            gripper_version_id=inp.gripper_version_id,
            params=inp.params,
            params_key=inp.params_key,
            derived_from_id=inp.source_grasp_set_id,
            job_id=inp.job_id,
            stats=stats,
            grasp_count=len(grasps),
            export_key=export_blob.key,
            export_sha256=export_blob.sha256,
            export_size=export_blob.size,
            candidates_key=candidates_blob.key,
            recording_key=rrd_blob.key,
        )
        s.add(gs)
        s.flush()
        if grasps:
            s.execute(insert(Grasp), [_grasp_row(gs.id, rank, g) for rank, g in enumerate(grasps)])
        catalogue.refresh(s, object_id=inp.object_id, gripper_id=inp.gripper_id)  # last: it locks the counter
        return gs.id

    def _end(self, jid: uuid.UUID, state: str, error: dict[str, Any] | None = None) -> str:
        def end(s: Session) -> str:
            job = s.execute(select(Job).where(Job.id == jid).with_for_update()).scalar_one_or_none()
            if job is None:
                return "missing"
            if job.state in TERMINAL_STATES:
                return job.state
            jobs.finish(job, state, error=error)
            self._parent(s, job)
            return state

        return self.db.transaction(end)

    def _parent(self, s: Session, job: Job) -> None:
        if job.parent_id is not None:
            s.flush()
            jobs.refresh_parent(s, job.parent_id)

    # -- progress -------------------------------------------------------------------------------------------------
    def write_progress(self, jid: uuid.UUID, stage: str, progress: float) -> bool:
        """Store stage and progress; return whether cancellation was requested."""

        def write(s: Session) -> bool:
            row = s.execute(
                update(Job)
                .where(Job.id == jid, Job.state == "running")
                .values(stage=stage, progress=progress, updated_at=utcnow())
                .returning(Job.cancel_requested)
            ).first()
            if row is None:
                # no longer running: cancelled while queued-and-claimed, or finished by another delivery
                return True
            return bool(row[0])

        return self.db.transaction(write)  # an idempotent update: a dropped connection costs a retry, not the job


class _Progress:
    """The core's progress callback: throttled writes to the job row, the cancel flag and the deadline."""

    def __init__(self, runner: JobRunner, inp: JobInputs, kind: JobKind) -> None:
        self.runner = runner
        self.jid = inp.job_id
        self.weights = kind.progress_weights(validate=bool(inp.params.get("validate")))
        self.interval = runner.settings.progress_interval_s
        self.deadline = time.monotonic() + runner.settings.job_soft_time_limit_s
        self.last_stage: str | None = None
        self.last_write = 0.0
        self.value = 0.0
        self.kind = inp.kind
        self.stage: str | None = None  # for graspgen_job_stage_duration_seconds
        self.stage_started = 0.0

    def _timed(self, stage: str | None, now: float) -> None:
        """Observe the wall time of the stage that ends now (a new one starts, or `stage` None: the run ends)."""
        if stage == self.stage:
            return
        if self.stage is not None:
            from services.common.metrics import STAGE_DURATION

            STAGE_DURATION.labels(self.kind, self.stage).observe(now - self.stage_started)
        self.stage, self.stage_started = stage, now

    def _overall(self, stage: str, fraction: float) -> float:
        if stage not in self.weights:
            return self.value
        before = 0.0
        for name, w in self.weights.items():
            if name == stage:
                return before + w * min(max(float(fraction), 0.0), 1.0)
            before += w
        return self.value

    def __call__(self, stage: str, fraction: float) -> None:
        from graspgen.errors import Cancelled

        now = time.monotonic()
        self._timed(stage, now)
        if now > self.deadline:
            raise _TimeLimitError()
        self.value = max(self.value, min(self._overall(stage, fraction), 0.99))
        if stage == self.last_stage and now - self.last_write < self.interval:
            return
        self.last_stage, self.last_write = stage, now
        if self.runner.write_progress(self.jid, stage, round(self.value, 4)):
            raise Cancelled(f"job {self.jid} was cancelled")


def _grasp_row(grasp_set_id: int, rank: int, g: dict[str, Any]) -> dict[str, Any]:
    """The grasps row of an exported grasp of either kind (a suction grasp has no width or friction margin)."""
    cluster = g.get("cluster") or [0, 0]
    width, margin = g.get("width"), g.get("friction_margin_deg")
    return {
        "grasp_set_id": grasp_set_id,
        "rank": rank,
        "pose": g["pose"],
        "width": None if width is None else float(width),
        "contacts": g["contacts"],
        "normals": g["normals"],
        "friction_margin_deg": None if margin is None else float(margin),
        "free_rolls_deg": g["free_rolls_deg"],
        "cluster_translation": int(cluster[0]),
        "cluster_direction": int(cluster[1]),
        "cluster_size": int(g.get("cluster_size", 1)),
    }
