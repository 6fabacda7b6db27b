"""Engine and sessions for one `Settings`: PostgreSQL in production, a SQLite file in the embedded mode."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from sqlalchemy import Engine, create_engine, event, text
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

from .settings import Settings

__all__ = ["Database", "redacted_url"]


class Database:
    """An engine and its session factory; one per process (API) or per worker process."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.url = settings.sqlalchemy_url
        self.engine = _make_engine(self.url, settings)
        self.sessions = sessionmaker(self.engine, expire_on_commit=False)
        if self.is_sqlite:
            self.read_sessions = self.sessions
        else:
            # reads need no transaction: in autocommit a lookup is one round trip instead of BEGIN, SELECT, ROLLBACK;
            # the option engine shares the pool and sets autocommit per checkout
            self.read_sessions = sessionmaker(
                self.engine.execution_options(isolation_level="AUTOCOMMIT"), expire_on_commit=False
            )

    @property
    def is_sqlite(self) -> bool:
        return self.engine.dialect.name == "sqlite"

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A session whose transaction commits on success and rolls back on any exception."""
        with self.sessions() as session, session.begin():
            yield session

    def ping(self) -> None:
        with self.engine.connect() as conn:
            conn.execute(text("SELECT 1"))

    def dispose(self) -> None:
        self.engine.dispose()


def redacted_url(url: str) -> str:
    """The URL with its password hidden, for logs."""
    return make_url(url).render_as_string(hide_password=True)


def _make_engine(url: str, settings: Settings) -> Engine:
    u = make_url(url)
    if u.get_backend_name() == "sqlite":
        if u.database and u.database != ":memory:":
            settings.storage_dir.mkdir(parents=True, exist_ok=True)
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30})
        _sqlite_pragmas(engine)
        return engine
    connect_args: dict[str, object] = {}
    if settings.database_schema and u.get_backend_name() == "postgresql":
        # the schema isolates an installation (or a test run) inside a shared database
        connect_args["options"] = f"-csearch_path={settings.database_schema}"
    # no pool_pre_ping: it doubles the round trips of every short read; a dropped connection instead fails one
    # statement, SQLAlchemy then invalidates the pool, and recycling bounds the age of idle connections
    # sized for the API's thread pool: an overflow connection is opened and closed per request, which costs a
    # PostgreSQL backend each time
    return create_engine(
        url,
        pool_size=settings.db_pool_size,
        max_overflow=settings.db_pool_size // 2,
        pool_recycle=1800,
        connect_args=connect_args,
    )


def _sqlite_pragmas(engine: Engine) -> None:
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn, _record):  # type: ignore[no-untyped-def]
        # the driver's own transaction handling is off so that BEGIN IMMEDIATE below is the only one: writers then
        # queue on the busy timeout instead of failing when a read transaction tries to upgrade to a write
        dbapi_conn.isolation_level = None
        cur = dbapi_conn.cursor()
        cur.execute("PRAGMA journal_mode=WAL")
        cur.execute("PRAGMA foreign_keys=ON")
        cur.execute("PRAGMA busy_timeout=30000")
        cur.execute("PRAGMA synchronous=NORMAL")
        cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn):  # type: ignore[no-untyped-def]
        conn.exec_driver_sql("BEGIN IMMEDIATE")
