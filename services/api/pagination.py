"""Keyset pagination: opaque cursors (base64url of the last row's sort key), one page of rows, the next link."""

from __future__ import annotations

import base64
import json
from collections.abc import Callable, Sequence
from typing import Any

from sqlalchemy import Select
from sqlalchemy.orm import Session

from .problems import ApiError

__all__ = ["encode_cursor", "decode_cursor", "fetch_page", "next_link"]


def encode_cursor(key: list[Any]) -> str:
    raw = json.dumps(key, separators=(",", ":")).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def decode_cursor(cursor: str | None, types: tuple[type, ...]) -> list[Any] | None:
    """The key, checked against `types` (one per element); a malformed cursor is a 422, never a 500."""
    if cursor is None or cursor == "":
        return None
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        key = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        key = None
    if (
        not isinstance(key, list)
        or len(key) != len(types)
        or not all(isinstance(v, t) and not isinstance(v, bool) for v, t in zip(key, types, strict=True))
    ):
        raise ApiError(422, "invalid-cursor", "the cursor is not one this endpoint issued")
    return key


def fetch_page(
    session: Session, q: Select, limit: int, key_of: Callable[[Any], list[Any]], *, scalars: bool = False
) -> tuple[Sequence[Any], str | None]:
    """Up to `limit` rows of `q` (already filtered past the cursor and ordered) and the cursor of the next page, None
    on the last: one row more than the page is read to know whether another follows. `key_of(last row)` is its key."""
    result = session.execute(q.limit(limit + 1))
    rows = (result.scalars() if scalars else result).all()
    more = len(rows) > limit
    rows = rows[:limit]
    return rows, (encode_cursor(key_of(rows[-1])) if more and rows else None)


def next_link(path: str, cursor: str | None, limit: int, query: str = "") -> str | None:
    """The `links.next` of a page: `path?cursor=..&limit=..` and the request's filters (`query`, "&k=v..."), or None."""
    return f"{path}?cursor={cursor}&limit={limit}{query}" if cursor else None
