"""Engine and sessions for one `Settings`: PostgreSQL in production, a SQLite file in the embedded mode.

Dropped connections (a restarted or failed-over server, `pg_terminate_backend`, an idle timeout in a proxy):

* a pooled connection the server has closed while it sat idle is noticed at checkout without a round trip (the
  socket is readable: the server sent its FATAL error and closed) and replaced, so the next request succeeds;
* a connection that drops under a running statement fails that statement; SQLAlchemy then invalidates the whole pool
  (every connection older than the failure is replaced at its next checkout). The API answers such a request with a
  503 problem, after one transparent retry for GET/HEAD (services/api/problems.py); the worker retries its
  transactions (`Database.transaction`).
"""

from __future__ import annotations

import logging
import select as _select
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

from sqlalchemy import Engine, create_engine, event, exc, text
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

from .settings import Settings

__all__ = ["Database", "redacted_url", "is_disconnect", "is_unavailable"]

log = logging.getLogger(__name__)

T = TypeVar("T")

#: pauses before the 2nd, 3rd, ... attempt of `Database.transaction` after a transient database error
RETRY_PAUSES_S = (0.0, 0.5, 2.0)


def is_disconnect(error: BaseException) -> bool:
    """The statement failed because its connection dropped (SQLAlchemy has invalidated it and the pool)."""
    return isinstance(error, exc.DBAPIError) and bool(error.connection_invalidated)


def is_unavailable(error: BaseException) -> bool:
    """The database, not the request, failed: a dropped or refused connection, an operational error on the server
    (shutdown, failover, serialization or deadlock abort), or no pooled connection free in time."""
    return is_disconnect(error) or isinstance(error, exc.OperationalError | exc.TimeoutError)


class Database:
    """An engine and its session factory; one per process (API) or per worker process."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.url = settings.sqlalchemy_url
        self.engine = _make_engine(self.url, settings)
        self.sessions = sessionmaker(self.engine, expire_on_commit=False)
        if self.is_sqlite:
            # a plain (deferred) BEGIN: in WAL mode readers then never wait for the writer's lock (see _on_begin)
            self.read_sessions = sessionmaker(
                self.engine.execution_options(graspgen_read_only=True), expire_on_commit=False
            )
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

    def transaction(self, work: Callable[[Session], T], *, retry_on: tuple[type[BaseException], ...] = ()) -> T:
        """Run `work(session)` in one transaction, again from the start (new session, new connection) when the
        database failed transiently (`is_unavailable`) or with one of `retry_on`; the last failure propagates.

        `work` must be safe to repeat: a commit that failed may have been applied, so it should first look at the
        rows it is about to write (the worker locks the job row and returns early if the job already finished).
        """
        for attempt, pause in enumerate(RETRY_PAUSES_S):
            if pause:
                time.sleep(pause)
            try:
                with self.session() as s:
                    return work(s)
            except Exception as error:
                last = attempt == len(RETRY_PAUSES_S) - 1
                if last or not (is_unavailable(error) or isinstance(error, retry_on)):
                    raise
                log.warning(
                    "transaction failed (%s); attempt %d of %d", type(error).__name__, attempt + 2, len(RETRY_PAUSES_S)
                )
        raise AssertionError("unreachable")

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
    # no pool_pre_ping: it costs a round trip per checkout, i.e. doubles the round trips of a catalogue read (one
    # autocommit SELECT): on loopback 35 us on top of a 130 us checkout + SELECT 1, on a network a whole RTT.
    # Instead `_drop_closed_on_checkout` replaces connections the server closed while they were idle, at the cost
    # of one poll() (3 us, no round trip), and a statement that hits a connection dropped under it fails
    # with an invalidated connection (is_disconnect): SQLAlchemy then marks the whole pool stale, the API retries a
    # GET once and answers anything else with a 503 problem, the worker retries the transaction. pool_recycle bounds
    # the age of idle connections (proxies and firewalls that drop them silently, which no poll can see).
    # sized for the API's thread pool: an overflow connection is opened and closed per request, which costs a
    # PostgreSQL backend each time
    engine = create_engine(
        url,
        pool_size=settings.db_pool_size,
        max_overflow=settings.db_pool_size // 2,
        pool_recycle=1800,
        connect_args=connect_args,
    )
    if u.get_backend_name() == "postgresql":
        event.listen(engine, "checkout", _drop_closed_on_checkout)
    return engine


def _drop_closed_on_checkout(dbapi_conn, _record, _proxy) -> None:
    """Replace a pooled connection whose server side is gone, without a round trip.

    An idle PostgreSQL connection has nothing to read: every reply was consumed up to ReadyForQuery. A readable (or
    hung-up) socket therefore means the server sent something unasked, which for us is the FATAL error of a
    terminated backend followed by the close. DisconnectionError makes the pool discard it and connect anew.
    """
    try:
        fd = dbapi_conn.fileno()
    except Exception as error:  # already closed on our side
        raise exc.DisconnectionError("connection closed") from error
    poller = _select.poll()
    poller.register(fd, _select.POLLIN | _select.POLLPRI)
    if poller.poll(0):
        raise exc.DisconnectionError("the server closed the connection while it was idle")


def _sqlite_pragmas(engine: Engine) -> None:
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn, _record):
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
    def _on_begin(conn):
        # read sessions (API GETs) read a WAL snapshot and take no lock, so a long read never makes lookups or
        # writers wait; everything else may write, so it takes the write lock up front
        read_only = conn.get_execution_options().get("graspgen_read_only", False)
        conn.exec_driver_sql("BEGIN" if read_only else "BEGIN IMMEDIATE")
