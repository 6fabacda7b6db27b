"""Issue 16 (2): decompression bombs against a real `graspgen serve` process (PostgreSQL, Redis).

The API's peak resident memory (VmHWM of the server process, read from /proc) is taken after a first honest upload
has loaded every import, then compared after each bomb: the issue's 1 MB NPZ that inflates to 1 GiB, a 16 MB one
that inflates to 16 GiB (tens of GiB fit under the 50 MB upload limit), and the corpus's forged headers. Each must
be a 422 problem+json, store nothing, and grow the peak by less than 100 MB.
"""

from __future__ import annotations

import io
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest
from services_conftest import box_stl, pg_values, settings_env, slug, start_serve, stop_process

sys.path.insert(0, str(Path(__file__).resolve().parent / "corpus"))
import make_corpus as mc  # noqa: E402

pytestmark = [pytest.mark.integration, pytest.mark.slow]

#: growth of the API process's peak memory that a refused upload may cause (the issue's bound)
MAX_GROWTH_MB = 100


def _peak_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


@pytest.fixture
def server(tmp_path, pg_schema):
    with pg_values(tmp_path, pg_schema) as (values, tokens):
        proc, url = start_serve(settings_env(**values), tmp_path / "serve.log")
        try:
            with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {tokens['writer']}"}, timeout=120) as c:
                yield proc, c
        finally:
            stop_process(proc)


def _upload(c: httpx.Client, name: str, filename: str, data: bytes) -> httpx.Response:
    return c.post("/v1/objects", files={"file": (filename, data)}, data={"name": name, "units": "mm"})


def test_bombs_are_refused_without_growing_the_api(server):
    proc, c = server
    # warm: an honest mesh and an honest point cloud go through the same code first
    assert _upload(c, slug("box"), "box.stl", box_stl()).status_code == 201
    pts = np.random.default_rng(0).random((2000, 3)) * 40.0
    buf = io.BytesIO()
    np.savez_compressed(buf, points=pts)
    assert _upload(c, slug("cloud"), "cloud.npz", buf.getvalue()).status_code == 201

    bombs = {
        "npz-1gib.npz": mc.npz_zero_bomb(1 << 30),
        "npz-16gib.npz": mc.npz_zero_bomb(16 << 30, crc=False),
        "npz-lying.npz": mc.npz_lying_member(64 << 20),
        "ply-billion.ply": mc.ply_declaring(10**9, 1, binary=True),
        "glb-bufferless.glb": mc.glb_bufferless_accessor(400_000_000),
        "glb-draco.glb": mc.glb_draco(),
    }
    assert len(bombs["npz-1gib.npz"]) < 1.1e6 and len(bombs["npz-16gib.npz"]) < 17e6
    before = _peak_mb(proc.pid)
    for filename, data in bombs.items():
        name = slug("bomb")
        r = _upload(c, name, filename, data)
        assert r.status_code == 422, (filename, r.text)
        assert r.headers["content-type"].startswith("application/problem+json")
        body = r.json()
        assert body["code"] == "invalid-mesh" and body["field"] == "file", body
        assert c.get(f"/v1/objects/{name}").status_code == 404  # nothing stored
        growth = _peak_mb(proc.pid) - before
        print(f"{filename}: {len(data):,} bytes, 422 in {r.elapsed.total_seconds():.2f} s, peak growth {growth:.1f} MB")
        assert growth < MAX_GROWTH_MB, f"{filename}: the API's peak memory grew by {growth:.0f} MB"
    assert "1,024.0 MiB once decoded" in _upload(c, slug("b"), "a.npz", bombs["npz-1gib.npz"]).json()["detail"]
    assert proc.poll() is None  # the API is still up
