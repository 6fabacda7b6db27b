"""Opaque cursors for keyset pagination: base64url of the last row's sort key."""

from __future__ import annotations

import base64
import json
from typing import Any

from .problems import ApiError

__all__ = ["encode_cursor", "decode_cursor"]


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
