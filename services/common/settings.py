"""One `Settings` object for API, worker and migrations (environment prefix `GRASPGEN_`).

Read once with `get_settings()`, validated at start-up: a bad value stops the process before it serves anything.
Nothing set means the embedded default: a SQLite file and local artifacts under `storage_dir`, jobs run in-process.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["Settings", "get_settings"]


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="GRASPGEN_", extra="ignore", frozen=True)

    # -- where things live ----------------------------------------------------------------------------------------
    #: SQLAlchemy URL (postgresql+psycopg://...); unset: SQLite file `graspgen.sqlite3` under storage_dir
    database_url: SecretStr | None = None
    #: pooled database connections per process (plus half as many again for bursts)
    db_pool_size: int = Field(default=20, ge=1, le=500)
    #: PostgreSQL schema holding the tables (tests isolate runs with it); unset: the server's default search_path
    database_schema: str | None = Field(default=None, pattern=r"^[a-z_][a-z0-9_]{0,62}$")
    #: Celery broker (redis://host:6379/0); unset: jobs run on an in-process thread pool with the same task
    broker_url: SecretStr | None = None
    #: every Redis key the broker writes starts with this (several installations can share one Redis)
    broker_key_prefix: str = ""
    #: Celery queue the API sends jobs to and the worker consumes
    queue: str = Field(default="graspgen", pattern=r"^[A-Za-z0-9._-]{1,100}$")
    #: local artifacts, the embedded SQLite file and the generated tokens file
    storage_dir: Path = Path("./var/graspgen")
    #: S3-compatible storage for artifacts, s3://bucket/prefix; unset: storage_dir
    storage_url: str | None = None
    #: endpoint of a non-AWS S3-compatible server (MinIO, moto); credentials come from the usual AWS_* variables
    s3_endpoint_url: str | None = None
    s3_region: str = "us-east-1"
    #: JSON tokens file (CONTRACT.md Running); unset: storage_dir/tokens.json, created with an admin token
    tokens_file: Path | None = None

    # -- limits ---------------------------------------------------------------------------------------------------
    max_upload_bytes: int = Field(default=50 * 1024 * 1024, ge=1024)
    max_json_bytes: int = Field(default=2 * 1024 * 1024, ge=1024)
    max_bulk_items: int = Field(default=1000, ge=1, le=100_000)
    #: largest decoded arrays one uploaded part may declare (graspgen.limits): checked from headers and counts
    #: before anything is inflated, so a compressed NPZ/GLB/PLY cannot inflate past it
    max_decoded_bytes: int = Field(default=256 * 1024 * 1024, ge=1024)
    #: memory one job may take at its peak (graspgen.memory's estimate, interpreter included); a generate job whose
    #: estimate exceeds it is refused at submission (422 naming the largest point count that fits) and by the
    #: worker before it runs. Unset: 75 % of this machine's memory divided by worker_concurrency, at most 8 GiB
    worker_memory_bytes: int | None = Field(default=None, ge=64 * 1024 * 1024)
    page_size_default: int = Field(default=50, ge=1, le=1000)
    page_size_max: int = Field(default=500, ge=1, le=10_000)
    #: grasp-set exports and views of candidate NPZs (GET .../candidates?max_rows=) kept in the API's memory (they are
    #: immutable, so the cache is never invalidated)
    export_cache_bytes: int = Field(default=64 * 1024 * 1024, ge=0)
    #: prepared candidate pairs of grasp sets kept for the pick query (about 150 bytes per candidate roll)
    pick_cache_bytes: int = Field(default=512 * 1024 * 1024, ge=0)

    # -- jobs -----------------------------------------------------------------------------------------------------
    job_soft_time_limit_s: int = Field(default=900, ge=1)
    job_time_limit_s: int = Field(default=960, ge=1)
    #: Redis redelivers an unacknowledged job after this; above the hard limit so a running job is never doubled
    broker_visibility_timeout_s: int = Field(default=1200, ge=1)
    #: a job whose worker died this many times is failed instead of being run again
    job_max_attempts: int = Field(default=3, ge=1, le=100)
    #: prefork children are replaced after this many jobs (numba/trimesh caches do not grow without bound)
    worker_max_tasks_per_child: int = Field(default=50, ge=1)
    worker_concurrency: int = Field(default=1, ge=1, le=256)
    #: threads running jobs in the embedded mode
    embedded_workers: int = Field(default=1, ge=1, le=64)
    #: progress is written to the job row at most this often (stage changes always)
    progress_interval_s: float = Field(default=0.5, ge=0.0)
    #: seconds between reconciler passes in each `graspgen worker` (services/worker/reconcile.py; one pass also runs
    #: when the worker is ready); 0 turns the reconciler off
    reconcile_interval_s: float = Field(default=60.0, ge=0.0)
    #: a queued job younger than this is never sent again (its message may still be on its way); and the margin
    #: (clock skew, a slow final commit) added to job_time_limit_s before a running job whose row stopped changing
    #: counts as abandoned by a dead worker
    reconcile_grace_s: int = Field(default=60, ge=0)

    # -- serving --------------------------------------------------------------------------------------------------
    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=1, le=65535)
    #: API processes (uvicorn workers); more than one needs a broker, since in-process jobs would run per process
    web_workers: int = Field(default=1, ge=1, le=64)
    log_level: Literal["debug", "info", "warning", "error"] = "info"

    # -- observability and isolation (docs/SERVICE.md Observability) ----------------------------------------------
    #: `json`: one JSON object per log line (time, level, logger, message, request_id, job_id)
    log_format: Literal["text", "json"] = "text"
    #: an unauthenticated plain-HTTP /metrics on this port, besides the API's `GET /metrics` (scope admin); the only
    #: way to read a `graspgen worker`'s metrics; unset: none
    metrics_port: int | None = Field(default=None, ge=1, le=65535)
    metrics_host: str = "127.0.0.1"
    #: where the processes of `serve --workers N` or of a worker's prefork pool share metric values; unset: a new
    #: temporary directory per start
    metrics_dir: Path | None = None
    #: preview.png renders at a time, each in its own process at a lower CPU priority (never on the request's thread)
    preview_workers: int = Field(default=2, ge=1, le=16)
    #: previews waiting for a render process; beyond this a preview request gets a 503 with Retry-After at once
    preview_queue: int = Field(default=4, ge=0, le=1000)
    #: largest preview in pixels (width x height); larger sizes are a 422 problem
    preview_max_pixels: int = Field(default=2048 * 2048, ge=16 * 16, le=4096 * 4096)
    #: rendered previews kept in the API's memory (immutable, least recently used evicted first)
    preview_cache_bytes: int = Field(default=32 * 1024 * 1024, ge=0)
    #: per-token request rate (requests per second, token bucket); 0 turns rate limiting off
    rate_limit_per_s: float = Field(default=0.0, ge=0.0)
    #: requests a token may make at once above its rate (the bucket's size)
    rate_limit_burst: int = Field(default=20, ge=1)

    @field_validator("storage_url")
    @classmethod
    def _check_storage_url(cls, v: str | None) -> str | None:
        if v is None or v == "":
            return None
        parts = urlsplit(v)
        if parts.scheme != "s3" or not parts.netloc:
            raise ValueError("storage_url must look like s3://bucket/prefix")
        return v

    @field_validator("database_url", "broker_url", mode="before")
    @classmethod
    def _empty_is_unset(cls, v: object) -> object:
        return None if v == "" else v

    @model_validator(mode="after")
    def _check_limits(self) -> Settings:
        if not self.job_soft_time_limit_s < self.job_time_limit_s:
            raise ValueError("job_soft_time_limit_s must be below job_time_limit_s")
        if not self.broker_visibility_timeout_s > self.job_time_limit_s:
            raise ValueError(
                "broker_visibility_timeout_s must be above job_time_limit_s, or a running job would be delivered twice"
            )
        if self.page_size_default > self.page_size_max:
            raise ValueError("page_size_default must not exceed page_size_max")
        return self

    # -- derived --------------------------------------------------------------------------------------------------
    @property
    def embedded_database(self) -> bool:
        return self.database_url is None

    @property
    def embedded_worker(self) -> bool:
        return self.broker_url is None

    @property
    def sqlalchemy_url(self) -> str:
        if self.database_url is not None:
            return self.database_url.get_secret_value()
        return f"sqlite:///{(self.storage_dir / 'graspgen.sqlite3').resolve()}"

    @property
    def job_memory_budget(self) -> int:
        """Bytes one job may take at its peak (worker_memory_bytes, or derived from this machine's memory)."""
        if self.worker_memory_bytes is not None:
            return self.worker_memory_bytes
        import os

        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        return min(8 * 1024**3, int(0.75 * total) // self.worker_concurrency)

    @property
    def tokens_path(self) -> Path:
        return self.tokens_file if self.tokens_file is not None else self.storage_dir / "tokens.json"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
