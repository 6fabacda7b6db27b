"""A thread-safe least-recently-used map bounded by the bytes of its values (the API's in-memory caches)."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from typing import Generic, TypeVar

__all__ = ["SizedLRU"]

V = TypeVar("V")


class SizedLRU(Generic[V]):
    """Values with a size in bytes, least recently used evicted first once the sizes pass `max_bytes`.

    A value larger than the whole budget is not kept. Values are never invalidated: callers key immutable things
    (content hashes, grasp-set ids).
    """

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._items: OrderedDict[Hashable, tuple[V, int]] = OrderedDict()
        self._size = 0
        self._lock = threading.Lock()

    def get(self, key: Hashable) -> V | None:
        with self._lock:
            item = self._items.get(key)
            if item is None:
                return None
            self._items.move_to_end(key)
            return item[0]

    def put(self, key: Hashable, value: V, nbytes: int) -> None:
        if nbytes > self.max_bytes:
            return
        with self._lock:
            if key in self._items:
                return
            self._items[key] = (value, nbytes)
            self._size += nbytes
            while self._size > self.max_bytes:
                _, (_, old) = self._items.popitem(last=False)
                self._size -= old

    @property
    def size(self) -> int:
        return self._size

    def __len__(self) -> int:
        return len(self._items)
