"""Settings fail fast; the Celery app is configured for long, idempotent, one-at-a-time jobs."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from services.cli import main
from services.common.settings import Settings
from services.worker.celery_app import make_celery


def test_settings_read_the_environment_and_default_to_embedded(monkeypatch, tmp_path):
    monkeypatch.setenv("GRASPGEN_STORAGE_DIR", str(tmp_path))
    monkeypatch.setenv("GRASPGEN_MAX_UPLOAD_BYTES", "4096")
    s = Settings()
    assert s.embedded_database and s.embedded_worker and s.max_upload_bytes == 4096
    assert s.sqlalchemy_url == f"sqlite:///{tmp_path.resolve() / 'graspgen.sqlite3'}"
    assert s.tokens_path == tmp_path / "tokens.json"
    monkeypatch.setenv("GRASPGEN_DATABASE_URL", "postgresql+psycopg://u:secret@db/x")
    s = Settings()
    assert not s.embedded_database and "secret" not in repr(s)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"job_soft_time_limit_s": 100, "job_time_limit_s": 100},
        {"job_time_limit_s": 100, "job_soft_time_limit_s": 50, "broker_visibility_timeout_s": 100},
        {"max_upload_bytes": 10},
        {"storage_url": "bucket/prefix"},
        {"queue": "no spaces"},
        {"database_schema": "Robert'); DROP TABLE"},
    ],
)
def test_bad_settings_fail_fast(kwargs):
    with pytest.raises(ValidationError):
        Settings(**kwargs)


def test_cli_reports_bad_settings_with_exit_2(monkeypatch, settings_from_env, capsys):
    monkeypatch.setenv("GRASPGEN_JOB_TIME_LIMIT_S", "1")
    assert main(["migrate"]) == 2
    assert "invalid settings" in capsys.readouterr().err
    assert main(["frobnicate"]) == 2
    assert main(["worker", "--concurrency", "x"]) == 2


def test_worker_without_broker_is_refused(monkeypatch, settings_from_env, tmp_path, capsys):
    monkeypatch.setenv("GRASPGEN_STORAGE_DIR", str(tmp_path))
    monkeypatch.delenv("GRASPGEN_BROKER_URL", raising=False)
    assert main(["worker"]) == 2
    assert "GRASPGEN_BROKER_URL" in capsys.readouterr().err


def test_celery_configuration():
    s = Settings(
        broker_url="redis://127.0.0.1:6379/3",
        broker_key_prefix="p:",
        queue="q1",
        job_soft_time_limit_s=60,
        job_time_limit_s=90,
        broker_visibility_timeout_s=120,
        worker_max_tasks_per_child=7,
    )
    conf = make_celery(s).conf
    assert conf.task_acks_late and conf.task_reject_on_worker_lost
    assert conf.worker_prefetch_multiplier == 1
    assert (conf.task_soft_time_limit, conf.task_time_limit) == (60, 90)
    assert conf.broker_transport_options["visibility_timeout"] == 120 > conf.task_time_limit
    assert conf.broker_transport_options["global_keyprefix"] == "p:"
    assert conf.worker_max_tasks_per_child == 7
    assert conf.task_default_queue == "q1" and conf.task_ignore_result
