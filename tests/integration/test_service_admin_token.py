"""Issue 16 (6): the admin token that `graspgen serve` creates lands in a file only its owner can read, never in the
process's output (container logs)."""

from __future__ import annotations

import stat
import subprocess
from pathlib import Path

import httpx
import pytest
from services_conftest import settings_env, start_serve, stop_process

pytestmark = [pytest.mark.integration]


def _serve(var: Path, out: Path, err: Path) -> tuple[subprocess.Popen, str]:
    """stdout and stderr apart: the token's file is named on stdout, uvicorn logs on stderr."""
    return start_serve(settings_env(storage_dir=var), out, err=err)


def test_serve_writes_the_admin_token_to_an_owner_only_file_and_never_prints_it(tmp_path):
    var = tmp_path / "var"
    proc, url = _serve(var, tmp_path / "out1", tmp_path / "err1")
    try:
        token_file = var / "admin-token"
        assert stat.S_IMODE(token_file.stat().st_mode) == 0o600
        assert token_file.stat().st_uid == Path(tmp_path).stat().st_uid
        token = token_file.read_text().strip()
        assert token.startswith("ggt_") and len(token) > 40
        out, err = (tmp_path / "out1").read_text(), (tmp_path / "err1").read_text()
        assert token not in out and token not in err
        assert str(token_file) in out  # where to find it
        assert token not in (var / "tokens.json").read_text()  # only its hash
        r = httpx.get(url + "/v1/objects", headers={"Authorization": f"Bearer {token}"})
        assert r.status_code == 200
        assert httpx.get(url + "/v1/objects", headers={"Authorization": "Bearer ggt_wrong"}).status_code == 401
    finally:
        stop_process(proc)

    # a restart keeps the token and its file, creates nothing and prints nothing about it
    proc, url = _serve(var, tmp_path / "out2", tmp_path / "err2")
    try:
        assert (var / "admin-token").read_text().strip() == token
        both = (tmp_path / "out2").read_text() + (tmp_path / "err2").read_text()
        assert "created admin token" not in both and token not in both
        r = httpx.get(url + "/v1/objects", headers={"Authorization": f"Bearer {token}"})
        assert r.status_code == 200
    finally:
        stop_process(proc)
