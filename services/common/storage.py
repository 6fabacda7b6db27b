"""Content-addressed artifact storage: a local directory or an S3-compatible bucket, behind one interface.

Keys are `sha256/<2 hex>/<64 hex>` and are derived from the bytes only, never from user input. A blob appears whole or
not at all: the local backend writes a temp file in the same directory, fsyncs and renames it; S3 makes an object
visible only once its upload completed.

Writes that fail (no space, read-only or unreachable storage) raise StorageError and leave no temp file behind. A blob
is never changed once written; `delete` exists so that a job whose results were not committed can remove the blobs
it created (services/worker/runner.py), and anything left unreferenced by a crash is safe to garbage-collect.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, cast
from urllib.parse import urlsplit

from .settings import Settings

__all__ = [
    "Storage",
    "LocalStorage",
    "S3Storage",
    "StoredBlob",
    "StorageError",
    "make_storage",
    "sha256_file",
    "blob_key",
    "check_key",
]

_CHUNK = 1024 * 1024


class StorageError(Exception):
    """A blob could not be written: the storage is full, read-only or unreachable. The message names the cause
    (e.g. "No space left on device"), never a path or a bucket."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def _reason(error: BaseException) -> str:
    if isinstance(error, OSError) and error.errno:
        return os.strerror(error.errno)
    return type(error).__name__


@dataclass(frozen=True)
class StoredBlob:
    key: str
    sha256: str
    size: int
    #: this call uploaded the bytes (they were not stored before); not part of the blob's identity
    created: bool = field(default=False, compare=False)


def blob_key(sha256: str) -> str:
    if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
        raise ValueError("not a sha256 hex digest")
    return f"sha256/{sha256[:2]}/{sha256}"


def check_key(key: str) -> str:
    """Accept only keys that blob_key() produces, so no path or object name is ever built from anything else."""
    if not isinstance(key, str) or blob_key(key.rsplit("/", 1)[-1]) != key:
        raise ValueError("invalid storage key")
    return key


def sha256_file(path: str | Path) -> tuple[str, int]:
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
            size += len(chunk)
    return h.hexdigest(), size


class Storage(ABC):
    """put_* return the blob's key; the same bytes always give the same key and are stored once."""

    def put_file(self, path: str | Path) -> StoredBlob:
        """Store a local file; raises StorageError when the storage cannot take it."""
        digest, size = sha256_file(path)
        key = blob_key(digest)
        try:
            if self.exists(key):
                return StoredBlob(key, digest, size)
            self._upload(Path(path), key)
        except StorageError:
            raise
        except Exception as error:
            raise StorageError(_reason(error)) from error
        return StoredBlob(key, digest, size, created=True)

    def put_bytes(self, data: bytes) -> StoredBlob:
        """Store bytes; raises StorageError when the storage cannot take them."""
        digest = hashlib.sha256(data).hexdigest()
        key = blob_key(digest)
        try:
            if self.exists(key):
                return StoredBlob(key, digest, len(data))
            self._upload_bytes(data, key)
        except StorageError:
            raise
        except Exception as error:
            raise StorageError(_reason(error)) from error
        return StoredBlob(key, digest, len(data), created=True)

    def _upload_bytes(self, data: bytes, key: str) -> None:
        fd, tmp = tempfile.mkstemp(prefix="graspgen-put-")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            self._upload(Path(tmp), key)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(tmp)

    def get_bytes(self, key: str) -> bytes:
        with self.open(key) as f:
            return f.read()

    def download(self, key: str, dest: str | Path) -> Path:
        """Copy a blob to a local file (the worker reads meshes and candidates from paths)."""
        dest = Path(dest)
        with self.open(key) as src, open(dest, "wb") as out:
            shutil.copyfileobj(src, out, _CHUNK)
        return dest

    def iter_chunks(self, key: str, chunk_size: int = 256 * 1024) -> Iterator[bytes]:
        with self.open(key) as f:
            while chunk := f.read(chunk_size):
                yield chunk

    @abstractmethod
    def exists(self, key: str) -> bool: ...

    @abstractmethod
    def open(self, key: str) -> BinaryIO:
        """A readable binary file object; raises FileNotFoundError for a missing key."""

    @abstractmethod
    def size(self, key: str) -> int: ...

    @abstractmethod
    def ping(self) -> None:
        """Raise when the storage cannot be reached."""

    @abstractmethod
    def delete(self, key: str) -> None:
        """Remove a blob (a missing one is no error). Only for blobs no row references."""

    @abstractmethod
    def _upload(self, path: Path, key: str) -> None: ...


class LocalStorage(Storage):
    def __init__(self, root: str | Path) -> None:
        self.root = Path(root).resolve() / "blobs"
        self.root.mkdir(parents=True, exist_ok=True)

    def _path(self, key: str) -> Path:
        _, shard, digest = check_key(key).split("/")
        return self.root / shard / digest

    def exists(self, key: str) -> bool:
        return self._path(key).is_file()

    def open(self, key: str) -> BinaryIO:
        return open(self._path(key), "rb")

    def size(self, key: str) -> int:
        return self._path(key).stat().st_size

    def ping(self) -> None:
        if not os.access(self.root, os.W_OK):
            raise OSError(f"storage directory {self.root} is not writable")

    def delete(self, key: str) -> None:
        # the shard directory stays: removing it could race with an upload that has just created it
        self._path(key).unlink(missing_ok=True)

    def _upload(self, path: Path, key: str) -> None:
        with open(path, "rb") as src:
            self._write(key, lambda out: shutil.copyfileobj(src, out, _CHUNK))

    def _upload_bytes(self, data: bytes, key: str) -> None:
        self._write(key, lambda out: out.write(data))  # no intermediate temp file: the bytes go to the final shard

    def _write(self, key: str, fill) -> None:
        """A temp file in the blob's own directory, filled, fsynced and renamed into place; removed on any error."""
        final = self._path(key)
        final.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=final.parent)
        try:
            with os.fdopen(fd, "wb") as out:
                fill(out)
                out.flush()
                os.fsync(out.fileno())
            os.replace(tmp, final)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise


class S3Storage(Storage):
    """s3://bucket/prefix through boto3; works with AWS S3 and S3-compatible servers (MinIO, moto, Ceph)."""

    def __init__(self, url: str, *, endpoint_url: str | None = None, region: str = "us-east-1") -> None:
        import boto3
        from botocore.config import Config

        parts = urlsplit(url)
        self.bucket = parts.netloc
        self.prefix = parts.path.strip("/")
        self.client = boto3.client(
            "s3",
            endpoint_url=endpoint_url,
            region_name=region,
            config=Config(retries={"max_attempts": 5, "mode": "standard"}, connect_timeout=5, read_timeout=60),
        )

    def _name(self, key: str) -> str:
        check_key(key)
        return f"{self.prefix}/{key}" if self.prefix else key

    def exists(self, key: str) -> bool:
        from botocore.exceptions import ClientError

        try:
            self.client.head_object(Bucket=self.bucket, Key=self._name(key))
            return True
        except ClientError as exc:
            if exc.response.get("Error", {}).get("Code") in ("404", "NoSuchKey", "NotFound"):
                return False
            raise

    def open(self, key: str) -> BinaryIO:
        from botocore.exceptions import ClientError

        try:
            obj = self.client.get_object(Bucket=self.bucket, Key=self._name(key))
        except ClientError as exc:
            if exc.response.get("Error", {}).get("Code") in ("404", "NoSuchKey", "NotFound"):
                raise FileNotFoundError(key) from None
            raise
        return cast(BinaryIO, obj["Body"])  # a StreamingBody: read(n), close(), context manager

    def size(self, key: str) -> int:
        from botocore.exceptions import ClientError

        try:
            return int(self.client.head_object(Bucket=self.bucket, Key=self._name(key))["ContentLength"])
        except ClientError as exc:
            if exc.response.get("Error", {}).get("Code") in ("404", "NoSuchKey", "NotFound"):
                raise FileNotFoundError(key) from None
            raise

    def ping(self) -> None:
        self.client.head_bucket(Bucket=self.bucket)

    def delete(self, key: str) -> None:
        self.client.delete_object(Bucket=self.bucket, Key=self._name(key))

    def _upload(self, path: Path, key: str) -> None:
        # upload_file switches to multipart for large files; either way the object appears only when complete
        self.client.upload_file(str(path), self.bucket, self._name(key))


def make_storage(settings: Settings) -> Storage:
    if settings.storage_url:
        return S3Storage(settings.storage_url, endpoint_url=settings.s3_endpoint_url, region=settings.s3_region)
    return LocalStorage(settings.storage_dir)
