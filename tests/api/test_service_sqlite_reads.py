"""Issue 16 (3): the embedded SQLite mode serves reads while a write transaction holds the database (WAL): read
sessions begin a deferred transaction and never queue behind the writer's lock; writers still serialise."""

from __future__ import annotations

import threading

from sqlalchemy import text


def _db(tmp_path):  # type: ignore[no-untyped-def]
    from services.common.db import Database
    from services.common.settings import Settings

    db = Database(Settings(storage_dir=tmp_path))
    with db.session() as s:
        s.execute(text("CREATE TABLE t (x INTEGER)"))
        s.execute(text("INSERT INTO t VALUES (1)"))
    return db


def test_a_read_completes_while_a_writer_holds_the_lock(tmp_path):
    db = _db(tmp_path)
    try:
        read_done = threading.Event()
        seen: list[int] = []

        def reader() -> None:
            with db.read_sessions() as s:
                seen.append(s.execute(text("SELECT count(*) FROM t")).scalar_one())
            read_done.set()

        with db.session() as w:  # BEGIN IMMEDIATE: the write lock is held until this block ends
            w.execute(text("INSERT INTO t VALUES (2)"))
            t = threading.Thread(target=reader)
            t.start()
            # a reader queued behind the lock would only finish after this block, i.e. never within the wait
            assert read_done.wait(20), "the read waited for the writer"
        t.join()
        assert seen == [1]  # the snapshot before the uncommitted insert
        with db.read_sessions() as s:
            assert s.execute(text("SELECT count(*) FROM t")).scalar_one() == 2
    finally:
        db.dispose()


def test_writers_still_take_the_lock_up_front(tmp_path):
    """A second writer waits for the first (BEGIN IMMEDIATE) instead of failing later on a lock upgrade."""
    db = _db(tmp_path)
    try:
        second_started, second_done = threading.Event(), threading.Event()

        def writer() -> None:
            second_started.set()
            with db.session() as s:
                s.execute(text("INSERT INTO t VALUES (3)"))
            second_done.set()

        with db.session() as w:
            w.execute(text("INSERT INTO t VALUES (2)"))
            t = threading.Thread(target=writer)
            t.start()
            assert second_started.wait(10)
            assert not second_done.wait(0.5)  # held at BEGIN IMMEDIATE while the first writes
        t.join(30)
        assert second_done.is_set()
        with db.read_sessions() as s:
            assert sorted(s.execute(text("SELECT x FROM t")).scalars()) == [1, 2, 3]
    finally:
        db.dispose()
