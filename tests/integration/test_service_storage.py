"""Artifact storage: the same interface over a local directory and a real S3-compatible server (moto, loopback)."""

from __future__ import annotations

import hashlib
import threading

import pytest

from services.common.settings import Settings
from services.common.storage import LocalStorage, S3Storage, blob_key, make_storage

pytestmark = pytest.mark.integration


@pytest.fixture(params=["local", "s3"])
def storage(request, tmp_path):
    if request.param == "local":
        return LocalStorage(tmp_path)
    s3 = request.getfixturevalue("s3_server")
    return make_storage(
        Settings(
            storage_dir=tmp_path, storage_url=f"s3://{s3['bucket']}/run/{tmp_path.name}", s3_endpoint_url=s3["endpoint"]
        )
    )


def test_content_addressed_put_get(storage, tmp_path):
    data = b"grasp" * 1000
    blob = storage.put_bytes(data)
    assert blob.sha256 == hashlib.sha256(data).hexdigest() and blob.size == len(data)
    assert blob.key == blob_key(blob.sha256)
    assert storage.exists(blob.key) and storage.size(blob.key) == len(data)
    assert storage.get_bytes(blob.key) == data
    assert b"".join(storage.iter_chunks(blob.key, 777)) == data
    f = tmp_path / "f.bin"
    f.write_bytes(data)
    assert storage.put_file(f) == blob  # the same bytes, the same key, stored once
    out = storage.download(blob.key, tmp_path / "out.bin")
    assert out.read_bytes() == data
    storage.ping()


def test_missing_and_invalid_keys(storage):
    missing = blob_key("0" * 64)
    assert not storage.exists(missing)
    with pytest.raises(FileNotFoundError):
        storage.get_bytes(missing)
    with pytest.raises(FileNotFoundError):
        storage.size(missing)
    for bad in ("../../etc/passwd", "sha256/00/../../x", "sha256/zz/" + "z" * 64):
        with pytest.raises(ValueError):
            storage.exists(bad)


def test_s3_backend_is_selected_by_url(s3_server, tmp_path):
    st = make_storage(
        Settings(
            storage_dir=tmp_path, storage_url=f"s3://{s3_server['bucket']}/p", s3_endpoint_url=s3_server["endpoint"]
        )
    )
    assert isinstance(st, S3Storage) and st.bucket == s3_server["bucket"] and st.prefix == "p"
    blob = st.put_bytes(b"x")
    import boto3

    client = boto3.client("s3", endpoint_url=s3_server["endpoint"], region_name="us-east-1")
    assert client.get_object(Bucket=s3_server["bucket"], Key=f"p/{blob.key}")["Body"].read() == b"x"
    with pytest.raises(ValueError):
        Settings(storage_url="http://bucket/x")


def test_local_writes_are_atomic_under_concurrent_readers(tmp_path):
    """Readers polling for a key while it is written see nothing or the whole blob, never a prefix."""
    st = LocalStorage(tmp_path)
    data = bytes(range(256)) * 40_000  # 10 MB
    key = blob_key(hashlib.sha256(data).hexdigest())
    seen: list[int] = []
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            if st.exists(key):
                seen.append(len(st.get_bytes(key)))

    threads = [threading.Thread(target=reader) for _ in range(2)]
    for t in threads:
        t.start()
    st.put_bytes(data)
    stop.set()
    for t in threads:
        t.join()
    assert all(n == len(data) for n in seen)
    assert not [p for p in (tmp_path / "blobs").rglob(".tmp-*")]  # no temp file left behind
