"""preview.png rendering off the request path: a small pool of render processes, a bounded wait, a PNG cache.

Why processes: a render is seconds of numpy and numba work on large arrays. In the API's own threads it would hold the
GIL against every other request (and, drawn inside the request's session, a database connection for its whole
duration): four clients asking for large previews would stall catalogue lookups for tens of seconds. Here:

* the route reads what it needs from the database in a short session and closes it before anything is drawn;
* renders run in `preview_workers` spawned processes at a lower CPU priority (nice 10), so lookups win the CPU;
* at most `preview_queue` more wait; any further preview request is refused at once with a 503 problem and
  `Retry-After` (the client retries later), never queued without bound;
* identical requests in flight share one render; finished PNGs stay in an LRU cache (a grasp set never changes).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any

from .cache import SizedLRU

__all__ = ["PreviewCache", "PreviewRenderer", "PreviewsBusy", "render_png"]

log = logging.getLogger(__name__)

#: renders a process makes before it is replaced (numba, trimesh and numpy caches do not grow without bound)
RENDERS_PER_PROCESS = 200
#: nice increment of render processes: lookups in the API process are scheduled first on a busy host
RENDER_NICE = 10


class PreviewsBusy(Exception):  # noqa: N818 - a state, answered as a 503 problem
    """Every render process is busy and the waiting line is full."""


class PreviewCache(SizedLRU[bytes]):
    """PNG bytes by (grasp set id, width, height), least recently used evicted first (the API's one LRU, cache.py)."""

    def put(self, key: tuple[int, int, int], data: bytes) -> None:  # type: ignore[override]  # the size is the PNG's length, not the caller's
        super().put(key, data, len(data))


def _init_render_process() -> None:
    with contextlib.suppress(OSError):  # not permitted on some hosts; the bound on concurrency still holds
        os.nice(RENDER_NICE)


def render_png(
    part_bytes: bytes,
    units: str,
    file_type: str,
    export_json: bytes,
    size: tuple[int, int],
    gripper_files: dict[str, bytes] | None = None,
) -> bytes:  # pragma: no cover - runs in a render process (tested through the API)
    """Draw one preview (runs in a render process): the part from its stored bytes, the export's grippers of either
    kind (a gripper from CAD or a suction tool's body with its mesh files, `gripper_files` by the names its geometry
    gives)."""
    import json

    from graspgen.kinds import gripper_from_dict
    from graspgen.parts import load_part
    from graspgen.render import render_grasp_set

    part = load_part(part_bytes, units=units, file_type=file_type)
    export = json.loads(export_json)
    gripper = gripper_from_dict(export["gripper"], files=gripper_files) if gripper_files else None
    return render_grasp_set(part.surface_mesh(), export, size=size, gripper=gripper)


class PreviewRenderer:
    """Runs `render_png` in a pool of spawned processes with a bounded number of renders in flight."""

    def __init__(self, *, workers: int, queue: int) -> None:
        self.workers = workers
        self.capacity = workers + queue
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self._in_flight: dict[Any, Future[bytes]] = {}

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is not None and getattr(self._pool, "_broken", False):
            # a render process died (killed, out of memory): the pool refuses all work from then on, so start anew
            log.warning("a preview render process died; starting a new pool")
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
        if self._pool is None:
            import multiprocessing

            # spawn: the API process has threads and an event loop that a fork would copy in a broken state
            self._pool = ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_render_process,
                max_tasks_per_child=RENDERS_PER_PROCESS,
            )
        return self._pool

    @property
    def in_flight(self) -> int:
        with self._lock:
            return len(self._in_flight)

    def submit(self, key: Any, make_args: Callable[[], tuple[Any, ...]]) -> Future[bytes]:
        """The render of `key`: the one already in flight, or a new one with `render_png(*make_args())`.

        Raises PreviewsBusy when `capacity` renders are in flight. `make_args` runs in the caller's thread (it reads
        the part and the export from storage; no database)."""
        from services.common.metrics import PREVIEWS_IN_FLIGHT

        with self._lock:
            fut = self._in_flight.get(key)
            if fut is not None:
                return fut
            if len(self._in_flight) >= self.capacity:
                raise PreviewsBusy()
            fut = Future()
            self._in_flight[key] = fut
            PREVIEWS_IN_FLIGHT.inc()

        def done(_: Future[bytes]) -> None:
            with self._lock:
                self._in_flight.pop(key, None)
            PREVIEWS_IN_FLIGHT.dec()

        fut.add_done_callback(done)
        try:
            args = make_args()
            with self._lock:
                pool = self._executor()
            inner = pool.submit(render_png, *args)
        except BaseException as exc:
            fut.set_exception(exc)
            raise
        _chain(inner, fut)
        return fut

    async def render(self, key: Any, make_args: Callable[[], tuple[Any, ...]]) -> bytes:
        from starlette.concurrency import run_in_threadpool

        fut = await run_in_threadpool(self.submit, key, make_args)
        # shielded: a client that goes away does not free the slot of a render that is still running
        return await asyncio.shield(asyncio.wrap_future(fut))

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)


def _chain(inner: Future[bytes], outer: Future[bytes]) -> None:
    def copy(f: Future[bytes]) -> None:
        if f.cancelled():
            outer.cancel()
        elif f.exception() is not None:
            outer.set_exception(f.exception())
        else:
            outer.set_result(f.result())

    inner.add_done_callback(copy)
