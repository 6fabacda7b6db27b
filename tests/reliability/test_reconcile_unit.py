"""The reconciler's pieces without a broker or database: settings, the abandoned-job cut-off, reading task ids from
kombu's Redis messages, and the sweep of what dead processes left in the temp and storage directories."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from datetime import UTC, datetime, timedelta

import pytest
from pydantic import ValidationError

from services.common.settings import Settings
from services.worker.reconcile import TEMP_PREFIX, _task_id, abandoned_before, start, sweep_temp, use_private_tempdir


def test_settings_defaults_and_bounds():
    s = Settings()
    assert s.reconcile_interval_s == 60 and s.reconcile_grace_s == 60
    assert Settings(reconcile_interval_s=0).reconcile_interval_s == 0
    for bad in ({"reconcile_interval_s": -1}, {"reconcile_grace_s": -1}):
        with pytest.raises(ValidationError):
            Settings(**bad)


def test_a_running_job_is_abandoned_only_after_the_hard_limit_and_the_grace():
    s = Settings(job_soft_time_limit_s=5, job_time_limit_s=10, broker_visibility_timeout_s=20, reconcile_grace_s=3)
    now = datetime(2030, 1, 1, tzinfo=UTC)
    assert abandoned_before(s, now) == now - timedelta(seconds=13)


def test_task_ids_are_read_from_queue_and_unacked_entries():
    message = {"body": "W10=", "headers": {"id": "abc", "task": "graspgen.run_job"}, "properties": {}}
    assert _task_id(json.dumps(message)) == "abc"
    assert _task_id(json.dumps([message, "", "graspgen"]), unacked=True) == "abc"
    assert _task_id(b"not json") is None and _task_id(json.dumps({"x": 1})) is None


def test_the_reconciler_is_off_without_a_broker_or_with_interval_zero():
    assert start(Settings()) is None
    assert start(Settings(broker_url="redis://127.0.0.1:1/0", reconcile_interval_s=0)) is None


def test_sweep_removes_dead_processes_temp_dirs_and_stale_storage_temp_files(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    gone = tmp_path / f"{TEMP_PREFIX}{dead.pid}"
    (gone / "graspgen-job-x").mkdir(parents=True)
    (gone / "graspgen-job-x" / "run.rrd").write_bytes(b"x")
    live = tmp_path / f"{TEMP_PREFIX}{os.getpid()}"
    live.mkdir()
    other = tmp_path / "something-else"
    other.mkdir()

    settings = Settings(
        storage_dir=tmp_path / "var",
        job_soft_time_limit_s=5,
        job_time_limit_s=10,
        broker_visibility_timeout_s=20,
        reconcile_grace_s=1,
    )
    shard = tmp_path / "var" / "blobs" / "ab"
    shard.mkdir(parents=True)
    stale, fresh = shard / ".tmp-stale", shard / ".tmp-fresh"
    stale.write_bytes(b"x")
    fresh.write_bytes(b"x")
    old = time.time() - 60
    os.utime(stale, (old, old))

    removed = sweep_temp(settings, base=tmp_path)
    assert sorted(removed) == sorted([str(gone), str(stale.resolve())])
    assert live.is_dir() and other.is_dir() and fresh.exists() and not gone.exists()


def test_a_private_tempdir_is_named_after_the_process(tmp_path, monkeypatch):
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    own = use_private_tempdir(tmp_path)
    assert own == tmp_path / f"{TEMP_PREFIX}{os.getpid()}" and tempfile.gettempdir() == str(own)
