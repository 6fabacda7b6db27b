"""The embedded default, as a newcomer runs it: `graspgen serve` with nothing configured (SQLite file, local
artifacts, jobs run in-process by the same Celery task), over real HTTP on loopback."""

from __future__ import annotations

import subprocess
import sys
import time

import httpx
import pytest
from services_conftest import (
    GRIPPER,
    box_stl,
    cylinder_stl,
    settings_env,
    start_serve,
    stop_process,
)

pytestmark = [pytest.mark.integration, pytest.mark.slow]

SMALL = {"points": 800, "k1": 4, "k2": 2}


def start(storage_dir, log_path):  # type: ignore[no-untyped-def]
    return start_serve(settings_env(storage_dir=storage_dir), log_path)


def wait_job(c: httpx.Client, job_id: str, timeout: float = 120) -> dict:
    end = time.monotonic() + timeout
    while True:
        body = c.get(f"/v1/jobs/{job_id}").json()
        if body["state"] in ("succeeded", "failed", "cancelled") or time.monotonic() > end:
            return body
        time.sleep(0.1)


def test_graspgen_serve_embedded_whole_flow(tmp_path):
    var = tmp_path / "var"
    proc, url = start(var, tmp_path / "serve1.log")
    try:
        log = (tmp_path / "serve1.log").read_text()
        assert "created admin token" in log
        token = (var / "admin-token").read_text().strip()
        assert token.startswith("ggt_") and token not in log
        assert (var / "graspgen.sqlite3").is_file() and token not in (var / "tokens.json").read_text()
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=30) as c:
            assert httpx.get(url + "/readyz").json()["checks"]["broker"] == "ok"
            assert httpx.get(url + "/v1/objects").status_code == 401
            up = c.post(
                "/v1/objects", files={"file": ("ring.stl", cylinder_stl())}, data={"name": "ring", "units": "mm"}
            )
            assert up.status_code == 201, up.text
            assert c.post("/v1/grippers", json=GRIPPER).status_code == 201
            job = c.post("/v1/jobs", json={"object": "ring", "gripper": "pgn-80", "params": SMALL})
            assert job.status_code == 202 and job.headers["location"].startswith("/v1/jobs/")
            done = wait_job(c, job.json()["id"])
            assert done["state"] == "succeeded", done
            gs = c.get(f"/v1/grasp-sets/{done['grasp_set']}")
            assert gs.json()["format"] == "graspgen.grasp_set/1" and gs.headers["etag"]
            cat = c.get("/v1/catalogue?gripper=pgn-80").json()
            assert [i["object"] for i in cat["items"]] == ["ring"]

            # one in-process worker thread: a long job runs while the next one waits in the queue
            assert (
                c.post(
                    "/v1/objects", files={"file": ("b.stl", box_stl())}, data={"name": "box", "units": "mm"}
                ).status_code
                == 201
            )
            slow = c.post("/v1/jobs", json={"object": "box", "gripper": "pgn-80", "params": {"points": 20000}}).json()
            waiting = c.post("/v1/jobs", json={"object": "box", "gripper": "pgn-80", "params": SMALL}).json()
            assert c.post(f"/v1/jobs/{waiting['id']}/cancel").json()["state"] == "cancelled"
            end = time.monotonic() + 60
            while c.get(f"/v1/jobs/{slow['id']}").json()["state"] == "queued" and time.monotonic() < end:
                time.sleep(0.02)
            assert c.post(f"/v1/jobs/{slow['id']}/cancel").status_code in (200, 202)
            assert wait_job(c, slow["id"])["state"] == "cancelled"
            assert wait_job(c, waiting["id"])["state"] == "cancelled"

            bulk = c.post(
                "/v1/bulk-jobs",
                json={
                    "items": [
                        {"object": "box", "gripper": "pgn-80", "params": SMALL},
                        {"object": "box", "gripper": "no-such-gripper"},
                    ]
                },
            ).json()
            parent = wait_job(c, bulk["id"])
            assert parent["state"] == "failed" and [i["state"] for i in parent["items"]] == ["succeeded", "failed"]
            assert parent["error"]["code"] == "items-failed" and parent["summary"]["failed"] == 1

        # the scripted demo client against the same server
        demo = subprocess.run(
            [sys.executable, "-m", "services.demo_client", "--url", url, "--token", token, "--points", "800"],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert demo.returncode == 0, demo.stderr
        assert "grasps" in demo.stdout and "demo-box v1" in demo.stdout
    finally:
        stop_process(proc)

    # a restart keeps data and tokens, and prints no new token
    proc, url = start(var, tmp_path / "serve2.log")
    try:
        assert "created admin token" not in (tmp_path / "serve2.log").read_text()
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=30) as c:
            assert c.get(f"/v1/grasp-sets/{done['grasp_set']}").status_code == 200
    finally:
        stop_process(proc)
