"""`graspgen serve | worker | migrate` (graspgen/cli.py delegates here). Exit status: 0 ok, 2 bad input or settings,
1 internal error.

With nothing configured, `serve` is the embedded default: a SQLite file and artifacts under GRASPGEN_STORAGE_DIR
(./var/graspgen), the schema migrated on start, jobs run in-process by the same Celery task, and an admin token created
on first start (written to admin-token beside the tokens file, mode 0600; the log shows only its path).
"""

from __future__ import annotations

import argparse
import logging
import sys

__all__ = ["main", "build_parser", "app_factory", "COMMANDS"]

COMMANDS = ("serve", "worker", "migrate")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="graspgen", description="graspgen service commands")
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("serve", help="run the HTTP API (embedded database and worker unless configured)")
    s.add_argument("--host", default=None, help="bind address (default GRASPGEN_HOST or 127.0.0.1)")
    s.add_argument("--port", type=int, default=None, help="port (default GRASPGEN_PORT or 8000)")
    s.add_argument("--workers", type=int, default=None, help="API processes (default GRASPGEN_WEB_WORKERS or 1)")
    w = sub.add_parser("worker", help="run a Celery worker for the configured broker")
    w.add_argument(
        "--concurrency", type=int, default=None, help="worker processes (default GRASPGEN_WORKER_CONCURRENCY)"
    )
    w.add_argument("--hostname", default=None, help="Celery node name, e.g. worker1@%%h")
    m = sub.add_parser("migrate", help="upgrade the database schema (to head unless given)")
    m.add_argument("--revision", default="head")
    return p


def _settings():
    from pydantic import ValidationError

    from services.common.settings import get_settings

    try:
        return get_settings()
    except ValidationError as exc:
        errors = "; ".join(f"GRASPGEN_{'_'.join(map(str, e['loc'])).upper()}: {e['msg']}" for e in exc.errors())
        print(f"graspgen: invalid settings: {errors}", file=sys.stderr)
        return None


def _logging(level: str, fmt: str = "text") -> None:
    from services.common.logs import configure_logging

    configure_logging(level, fmt)  # request and job ids on every line; JSON lines with GRASPGEN_LOG_FORMAT=json


def _metrics_dir(settings) -> None:
    """prometheus-client's multiprocess mode for a command whose processes share numbers (serve --workers N, the
    Celery prefork pool): it reads PROMETHEUS_MULTIPROC_DIR when first imported, so this runs before that import."""
    import os
    import tempfile
    from pathlib import Path

    path = settings.metrics_dir or Path(tempfile.mkdtemp(prefix="graspgen-metrics-"))
    path.mkdir(parents=True, exist_ok=True)
    for old in path.glob("*.db"):  # a previous run's values
        old.unlink()
    os.environ["PROMETHEUS_MULTIPROC_DIR"] = str(path)


def _metrics_server(settings, dispatcher=None) -> None:
    """The unauthenticated /metrics listener of GRASPGEN_METRICS_PORT, in a daemon thread of this process."""
    if settings.metrics_port is None:
        return
    from services.api.observability import queue_depth_reader
    from services.common.metrics import QueueDepthCollector, scrape_registry, start_metrics_server

    registry = scrape_registry([QueueDepthCollector(queue_depth_reader(settings, dispatcher))])
    start_metrics_server(settings.metrics_port, settings.metrics_host, registry)


def _serve(args: argparse.Namespace) -> int:
    settings = _settings()
    if settings is None:
        return 2
    _logging(settings.log_level, settings.log_format)
    from services.common.migrate import upgrade
    from services.common.tokens import TokensFileError, bootstrap_tokens_file

    if settings.embedded_database:
        upgrade(settings)  # the SQLite file is ours: bring it to the current schema
    if settings.tokens_file is None:
        token_file = settings.tokens_path.with_name("admin-token")
        if bootstrap_tokens_file(settings.tokens_path, token_file=token_file) is not None:
            # never the token itself: container logs are read by more people than the data directory
            print(f"graspgen: created admin token local-admin in {token_file} (mode 0600)", flush=True)
    elif not settings.tokens_file.is_file():
        print(f"graspgen: tokens file {settings.tokens_file} does not exist", file=sys.stderr)
        return 2
    import uvicorn

    from services.api.app import create_app

    workers = args.workers or settings.web_workers
    if workers > 1 and settings.embedded_worker:
        print(
            "graspgen: --workers above 1 needs GRASPGEN_BROKER_URL (in-process jobs would run once per process)",
            file=sys.stderr,
        )
        return 2
    if workers > 1:
        _metrics_dir(settings)  # before create_app imports the metrics
    try:
        app = create_app(settings)  # also checks the tokens file before any worker process starts
    except TokensFileError as exc:
        print(f"graspgen: {exc}", file=sys.stderr)
        return 2
    options = dict(
        host=args.host or settings.host,
        port=args.port or settings.port,
        log_level=settings.log_level,
        log_config=None,
        server_header=False,
    )
    _metrics_server(settings, app.state.dispatcher if workers == 1 else None)
    if workers > 1:
        # each process builds its own app from the same environment; importing it (numba, trimesh, mujoco) can take
        # 9 s on a busy 2-core host, past uvicorn's default 5 s start-up health check, which would kill the children
        # in a loop
        options["timeout_worker_healthcheck"] = 120
        uvicorn.run("services.cli:app_factory", factory=True, workers=workers, **options)
    else:
        uvicorn.run(app, **options)
    return 0


def app_factory():
    """The app of one `serve --workers N` process: a spawned interpreter, so it sets up its own logging first."""
    from services.api.app import create_app
    from services.common.settings import get_settings

    settings = get_settings()
    _logging(settings.log_level, settings.log_format)
    return create_app(settings)


def _worker(args: argparse.Namespace) -> int:
    settings = _settings()
    if settings is None:
        return 2
    if settings.broker_url is None:
        print(
            "graspgen: `graspgen worker` needs GRASPGEN_BROKER_URL (without one, `graspgen serve` runs jobs "
            "in-process)",
            file=sys.stderr,
        )
        return 2
    _logging(settings.log_level, settings.log_format)
    if settings.metrics_port is not None:
        _metrics_dir(settings)  # the prefork children count jobs; the main process serves their sum
    from services.worker.celery_app import make_celery
    from services.worker.reconcile import connect_worker_signals

    celery_app = make_celery(settings)
    connect_worker_signals(settings)  # the reconciler in the main process, a temp directory per prefork child
    _metrics_server(settings)

    argv = [
        "worker",
        f"--loglevel={settings.log_level.upper()}",
        f"--concurrency={args.concurrency or settings.worker_concurrency}",
        f"--queues={settings.queue}",
        "--without-gossip",
        "--without-mingle",
    ]
    if args.hostname:
        argv.append(f"--hostname={args.hostname}")
    celery_app.worker_main(argv)
    return 0


def _migrate(args: argparse.Namespace) -> int:
    settings = _settings()
    if settings is None:
        return 2
    _logging(settings.log_level, settings.log_format)
    from services.common.db import redacted_url
    from services.common.migrate import upgrade

    upgrade(settings, args.revision)
    print(f"graspgen: {redacted_url(settings.sqlalchemy_url)} is at {args.revision}")
    return 0


#: modules of the `service` extra every command needs (an install without the extra has this package, not them)
_REQUIRED = ("fastapi", "uvicorn", "sqlalchemy", "alembic", "celery", "pydantic_settings")


def missing_dependencies() -> list[str]:
    import importlib.util

    return [m for m in _REQUIRED if importlib.util.find_spec(m) is None]


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits 2 on bad usage, 0 on --help
        return int(exc.code or 0)
    missing = missing_dependencies()
    if missing:
        print(
            f"graspgen: the service is not installed ({', '.join(missing)} missing): pip install 'graspgen[service]'",
            file=sys.stderr,
        )
        return 2
    try:
        return {"serve": _serve, "worker": _worker, "migrate": _migrate}[args.command](args)
    except KeyboardInterrupt:
        return 0
    except Exception as exc:
        logging.getLogger("graspgen").exception("graspgen %s failed", args.command)
        print(f"graspgen: {args.command} failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
