"""Jobs for a gripper with mesh files (CONTRACT.md "Gripper geometry from CAD"): the worker rebuilds the full
GripperSpec, meshes included, from the stored spec and storage, for generate and cluster jobs; a missing or altered
file fails the job with a problem, never a wrong gripper."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from services_conftest import slug

from graspgen.example_grippers import example_gripper_files
from graspgen.gripper import GripperSpec
from services.common.grippers import stored_gripper_spec
from services.common.storage import blob_key
from services.worker.runner import JobRunner

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # runs the core

SMALL = {"points": 600, "k1": 4, "k2": 2}
EXAMPLE = "pgn-80-stepped"


@pytest.fixture
def runner(pg_service):
    state = pg_service.app.state
    return JobRunner(state.db, state.storage, pg_service.settings)


def register(svc, name: str) -> tuple[dict, dict[str, bytes]]:  # type: ignore[no-untyped-def]
    files = example_gripper_files(EXAMPLE)
    spec = {**json.loads(files.pop(f"{EXAMPLE}.json")), "name": name}
    parts = [(n, (Path(n).name, b, "model/stl")) for n, b in files.items()]
    r = svc.post("/v1/grippers", data={"spec": json.dumps(spec)}, files=parts)
    assert r.status_code == 201, r.text
    return r.json(), files


def test_stored_spec_rebuilds_with_its_meshes(pg_service, tmp_path):
    name = slug("cadw")
    out, files = register(pg_service, name)
    storage = pg_service.app.state.storage
    g = stored_gripper_spec(storage, out["spec"])
    for path, data in files.items():
        (tmp_path / path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / path).write_bytes(data)
    (tmp_path / "spec.json").write_text(
        json.dumps({**json.loads(example_gripper_files(EXAMPLE)[f"{EXAMPLE}.json"]), "name": name})
    )
    local = GripperSpec.load(tmp_path / "spec.json")
    assert g == local and g.to_dict() == out["spec"]
    assert (g.geometry.finger.vertices == local.geometry.finger.vertices).all()
    assert g.geometry.pad_width == pytest.approx(0.006)


def test_generate_and_cluster_jobs_use_the_meshes(pg_service, runner):
    obj, grip = slug("part"), slug("cadj")
    assert pg_service.upload(obj).status_code == 201
    out, _ = register(pg_service, grip)
    r = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": SMALL})
    assert r.status_code == 202, r.text  # the memory guard probed with the rebuilt gripper
    jid = r.json()["id"]
    assert runner.run(jid) == "succeeded", pg_service.get(f"/v1/jobs/{jid}").json()
    gs = pg_service.get(f"/v1/jobs/{jid}").json()["grasp_set"]
    export = pg_service.get(f"/v1/grasp-sets/{gs}").json()
    assert export["gripper"] == out["spec"]  # the spec with its files' digests, no box fields
    assert export["grasps"]
    # the pick query loads the gripper with its meshes too
    eye = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
    pick = pg_service.post("/v1/pick", who="reader", json={"grasp_set": gs, "T_world_object": eye, "limit": 3})
    assert pick.status_code == 200 and pick.json()["considered"] > 0, pick.text
    c = pg_service.post("/v1/jobs", json={"kind": "cluster", "grasp_set": gs, "params": {"k1": 2, "k2": 1}})
    assert c.status_code == 202, c.text
    cid = c.json()["id"]
    assert runner.run(cid) == "succeeded", pg_service.get(f"/v1/jobs/{cid}").json()
    derived = pg_service.get(f"/v1/jobs/{cid}").json()["grasp_set"]
    assert pg_service.get(f"/v1/grasp-sets/{derived}").json()["gripper"] == out["spec"]


def test_a_missing_gripper_file_fails_the_job(pg_service, runner):
    obj, grip = slug("part"), slug("cadm")
    assert pg_service.upload(obj).status_code == 201
    out, _ = register(pg_service, grip)
    r = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {**SMALL, "points": 650}})
    assert r.status_code == 202, r.text
    storage = pg_service.app.state.storage
    finger_sha = out["spec"]["geometry"]["sha256"][f"{EXAMPLE}/finger.stl"]
    key = blob_key(finger_sha)
    data = storage.get_bytes(key)
    storage.delete(key)
    try:
        assert runner.run(r.json()["id"]) == "failed"
        job = pg_service.get(f"/v1/jobs/{r.json()['id']}").json()
        assert job["state"] == "failed" and job["error"]["status"] >= 500
    finally:
        storage.put_bytes(data)
