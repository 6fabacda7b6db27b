"""Bearer tokens from the tokens file (CONTRACT.md Running): only sha256 hashes are stored, compared in constant time.

Scopes are ordered: `admin` includes `write`, and `write` includes `read`.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import re
import secrets
import threading
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "Principal",
    "TokenStore",
    "TokensFileError",
    "SCOPES",
    "hash_token",
    "bootstrap_tokens_file",
    "write_private_file",
]

SCOPES = ("read", "write", "admin")
_RANK = {s: i for i, s in enumerate(SCOPES)}
_HEX64 = re.compile(r"^[0-9a-f]{64}$")


class TokensFileError(Exception):
    pass


@dataclass(frozen=True)
class Principal:
    name: str
    scopes: frozenset[str]

    def has(self, scope: str) -> bool:
        need = _RANK[scope]
        return any(_RANK[s] >= need for s in self.scopes)


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def _parse(text: str, source: str) -> list[tuple[bytes, Principal]]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise TokensFileError(f"tokens file {source} is not valid JSON: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("tokens"), list):
        raise TokensFileError(f'tokens file {source} must be {{"tokens": [...]}}')
    entries = []
    for i, t in enumerate(data["tokens"]):
        if not isinstance(t, dict):
            raise TokensFileError(f"tokens file {source}: entry {i} is not an object")
        name, digest, scopes = t.get("name"), t.get("sha256"), t.get("scopes")
        if not isinstance(name, str) or not name or len(name) > 100:
            raise TokensFileError(f"tokens file {source}: entry {i} needs a name (1-100 characters)")
        if not isinstance(digest, str) or not _HEX64.match(digest.lower()):
            raise TokensFileError(f"tokens file {source}: entry {name!r} needs sha256, 64 hex digits")
        if not isinstance(scopes, list) or not scopes or any(s not in _RANK for s in scopes):
            raise TokensFileError(f"tokens file {source}: entry {name!r} scopes must be a non-empty subset of {SCOPES}")
        entries.append((bytes.fromhex(digest.lower()), Principal(name, frozenset(scopes))))
    return entries


class TokenStore:
    """Reads the tokens file at start (failing fast) and again whenever it changes, so tokens rotate without restart."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._stamp: tuple[int, int] | None = None
        self._entries: list[tuple[bytes, Principal]] = []
        self._reload(force=True)

    def _reload(self, *, force: bool = False) -> None:
        try:
            st = self.path.stat()
        except OSError as exc:
            if force:
                raise TokensFileError(f"cannot read tokens file {self.path}: {exc.strerror}") from None
            return  # keep the last good set while the file is being replaced
        stamp = (st.st_mtime_ns, st.st_size)
        if stamp == self._stamp and not force:
            return
        with self._lock:
            try:
                entries = _parse(self.path.read_text(encoding="utf-8"), str(self.path))
            except (OSError, TokensFileError):
                if force:
                    raise
                return
            self._entries, self._stamp = entries, stamp

    def authenticate(self, token: str) -> Principal | None:
        self._reload()
        presented = hashlib.sha256(token.encode("utf-8")).digest()
        found = None
        for digest, principal in self._entries:
            # every entry is compared, so the time taken says nothing about which one matched
            if hmac.compare_digest(presented, digest):
                found = principal
        return found


def bootstrap_tokens_file(path: Path, *, name: str = "local-admin", token_file: Path | None = None) -> str | None:
    """Create `path` with one admin token and return the token, or return None when the file exists already.

    With `token_file`, the token itself is also written there, readable only by its owner (mode 0600), so that it
    never has to appear in a log; it is written before the tokens file gets its content, so a crash in between
    leaves no token without a copy.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    token = "ggt_" + secrets.token_urlsafe(32)
    doc = {"tokens": [{"name": name, "sha256": hash_token(token), "scopes": ["admin"]}]}
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return None
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        if token_file is not None:
            write_private_file(token_file, token + "\n")
        json.dump(doc, f, indent=2)
        f.write("\n")
    return token


def write_private_file(path: Path, text: str) -> None:
    """Write `text` to `path` atomically with mode 0600 (whatever the umask), replacing an older file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
