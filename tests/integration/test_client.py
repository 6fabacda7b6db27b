"""graspgen.client.Client against the real server, as a plant runs it: `graspgen serve` on PostgreSQL with a Celery
worker on Redis, and `graspgen serve` in its embedded default (SQLite, in-process jobs), over HTTP on loopback.

One flow per stack: upload, gripper, job (Idempotency-Key, wait honouring Retry-After), export, catalogue with its
ETag cache (304 reuse, also from a cache directory after a restart of the client), release, pick (the same answer as
graspgen.pick on the downloaded candidates), an empty pick with its reason, refusals as ProblemError, withdraw.
"""

from __future__ import annotations

import numpy as np
import pytest
from services_conftest import (
    GRIPPER,
    cylinder_stl,
    pg_values,
    settings_env,
    slug,
    start_serve,
    start_worker,
    stop_process,
)

import graspgen
from graspgen.client import Client, ProblemError
from graspgen.gripper import GripperSpec

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.xdist_group("client")]

SMALL = {"points": 800, "k1": 4, "k2": 2}
FLOOR = [{"point": [0, 0, 0], "normal": [0, 0, 1]}]
DOWN = {"direction": [0, 0, -1], "max_angle_deg": 60}


@pytest.fixture(scope="module")
def postgres_stack(pg_schema, tmp_path_factory):
    """`graspgen serve` and `graspgen worker` (subprocesses) on PostgreSQL and Redis, sharing a storage directory."""
    root = tmp_path_factory.mktemp("client-pg")
    with pg_values(root, pg_schema, progress_interval_s=0.1) as (values, tokens):
        env = settings_env(**values)
        worker = start_worker(env, root / "worker.log")
        server = None
        try:
            server, url = start_serve(env, root / "serve.log")
            yield url, tokens["writer"]
        finally:
            if server is not None:
                stop_process(server)
            stop_process(worker)


@pytest.fixture(scope="module")
def embedded_stack(tmp_path_factory):
    """`graspgen serve` with nothing configured: SQLite, local files, jobs in-process, a created admin token."""
    root = tmp_path_factory.mktemp("client-embedded")
    proc, url = start_serve(settings_env(storage_dir=root / "var"), root / "serve.log")
    try:
        yield url, (root / "var" / "admin-token").read_text().strip()
    finally:
        stop_process(proc)


@pytest.fixture(params=["postgres", "embedded"])
def stack(request):
    return request.getfixturevalue(f"{request.param}_stack")


def test_plant_flow_through_the_client(stack, tmp_path):
    url, token = stack
    obj, grip = slug("ring"), slug("pgn")
    # a long read timeout: the first submission of a process may compile the memory probe (tens of seconds here)
    with Client(url, token, cache_dir=tmp_path / "cache", timeout=300) as gg:
        up = gg.upload_object(cylinder_stl(), name=obj, units="mm", filename="ring.stl")
        assert up["version"] == 1
        assert gg.upload_object(cylinder_stl(), name=obj, units="mm", filename="ring.stl")["version"] == 1
        spec = {**GRIPPER, "name": grip}
        assert gg.create_gripper(spec)["version"] == 1
        assert gg.create_gripper(GripperSpec.from_dict(spec))["version"] == 1  # identical: the same version

        job = gg.submit_job(obj, grip, params=SMALL, idempotency_key=f"plant-7-{obj}")
        again = gg.submit_job(obj, grip, params=SMALL, idempotency_key=f"plant-7-{obj}")
        assert again["id"] == job["id"] and job["state"] in ("queued", "running", "succeeded")
        done = gg.wait(job, timeout=300)
        assert done["state"] == "succeeded" and done["grasp_set"]
        gs = done["grasp_set"]

        export = gg.grasp_set(gs)
        assert export["format"] == "graspgen.grasp_set/1" and export["grasps"]
        from services.api.contract_schemas import GraspSetExport

        GraspSetExport.model_validate(export)  # the typed document describes a real export

        first = gg.catalogue(obj, grip)
        assert (first.grasp_set, first.released, first.from_cache) == (gs, False, False)
        second = gg.catalogue(obj, grip)
        assert second.from_cache and second.export == first.export and second.etag == first.etag

        assert gg.release(gs)["released"] == gs
        released = gg.catalogue(obj, grip)
        assert released.released and released.grasp_set == gs

        T = np.array([[0, -1, 0, 0.4], [1, 0, 0, 0.1], [0, 0, 1, 0.015], [0, 0, 0, 1.0]])
        flange = np.eye(4)
        flange[2, 3] = -0.12
        answer = gg.pick(T, object=obj, gripper=grip, approach=DOWN, planes=FLOOR, T_tcp_flange=flange, limit=20)
        assert answer["grasp_set"] == gs and answer["grasps"], answer
        assert answer["considered"] == int(gg.candidates(gs).free_rolls.sum())
        local = graspgen.pick(
            gg.candidates(gs),
            T,
            approach=DOWN,
            planes=FLOOR,
            T_tcp_flange=flange,
            limit=20,
            gripper=GripperSpec.from_dict(export["gripper"]),
        )
        assert [(g["candidate"], g["roll_index"]) for g in answer["grasps"]] == [
            (g["candidate"], g["roll_index"]) for g in local.grasps
        ]
        np.testing.assert_allclose(
            [g["T_world_flange"] for g in answer["grasps"]], [g["T_world_flange"] for g in local.grasps], atol=1e-12
        )
        for g in answer["grasps"]:
            assert g["approach_angle_deg"] <= 60 + 1e-9
            assert np.asarray(g["T_world_pregrasp"])[2, 3] > np.asarray(g["T_world_grasp"])[2, 3]  # retreat upwards

        sunk = T.copy()
        sunk[2, 3] = -0.3
        empty = gg.pick(sunk, grasp_set=gs, approach=DOWN, planes=FLOOR)
        assert empty["grasps"] == [] and empty["reason"]["planes"] + empty["reason"]["approach"] == empty["considered"]

        with pytest.raises(ProblemError) as bad:
            gg.pick(np.diag([1.0, 1.0, -1.0, 1.0]), grasp_set=gs)
        assert bad.value.status == 422 and bad.value.problem["field"] == "T_world_object"

    # a new client (a restarted plant cell) revalidates from its cache directory: 304, nothing downloaded again
    with Client(url, token, cache_dir=tmp_path / "cache") as gg:
        kept = gg.catalogue(obj, grip)
        assert kept.from_cache and kept.released and kept.export == first.export
        gg.withdraw(gs)
        with pytest.raises(ProblemError) as gone:
            gg.catalogue(obj, grip)
        assert gone.value.status == 404
        with pytest.raises(ProblemError) as unknown:
            gg.pick(np.eye(4), object=slug("nope"), gripper=grip)
        assert unknown.value.status == 404 and unknown.value.code == "not-found"


def test_the_client_needs_no_token_to_fail_clearly(embedded_stack):
    url, _ = embedded_stack
    with Client(url, None) as gg, pytest.raises(ProblemError) as err:
        gg.object("anything")
    assert err.value.status == 401 and err.value.problem["code"] == "unauthorized"


def test_a_gripper_with_mesh_files_through_the_client(embedded_stack, tmp_path):
    """upload_gripper sends the spec and the files it names; the same files again give the same version; a job on
    the embedded worker runs with the meshes; the files come back as uploaded."""
    from pathlib import Path

    examples = Path(__file__).resolve().parents[2] / "examples"
    url, token = embedded_stack
    with Client(url, token, timeout=300) as gg:  # the first submission of a process may compile the memory probe
        first = gg.upload_gripper(examples / "pgn-80-vgroove.json")
        assert first["version"] >= 1 and len(first["files"]) == 2
        assert gg.upload_gripper(examples / "pgn-80-vgroove.json")["version"] == first["version"]
        finger = gg.gripper_file("pgn-80-vgroove", first["version"], "pgn-80-vgroove/finger.stl")
        assert finger == (examples / "pgn-80-vgroove" / "finger.stl").read_bytes()
        spec = GripperSpec.load(examples / "pgn-80-vgroove.json")
        files = {"pgn-80-vgroove/finger.stl": finger, "pgn-80-vgroove/body.stl": examples / "pgn-80-vgroove/body.stl"}
        assert gg.create_gripper(spec, files=files)["version"] == first["version"]  # a GripperSpec with its files
        with pytest.raises(ProblemError) as e:
            gg.create_gripper({**spec.to_dict(), "name": slug("cadc")}, files={**files, "extra.stl": finger})
        assert e.value.status == 422 and e.value.problem["field"] == "extra.stl"
        obj = slug("cyl")
        gg.upload_object(cylinder_stl(), name=obj, units="mm", filename="cyl.stl")
        job = gg.wait(gg.submit_job(obj, "pgn-80-vgroove", params=SMALL), timeout=300)
        assert gg.grasp_set(job["grasp_set"])["gripper"] == first["spec"]
        # the preview draws the CAD gripper: the render process rebuilds it from the files in storage
        import io

        from PIL import Image

        png = gg._http.get(f"/v1/grasp-sets/{job['grasp_set']}/preview.png", params={"size": "320x240"})
        assert png.status_code == 200, png.text
        assert Image.open(io.BytesIO(png.content)).size == (320, 240)
        # the pick query's planes read the meshes: a floor far below the part leaves grasps, one through it none
        far = gg.pick(np.eye(4), grasp_set=job["grasp_set"], planes=[{"point": [0, 0, -1], "normal": [0, 0, 1]}])
        assert far["grasps"]
        cut = gg.pick(np.eye(4), grasp_set=job["grasp_set"], planes=[{"point": [0, 0, 0], "normal": [0, 0, 1]}])
        assert len(cut["grasps"]) < len(far["grasps"]) or cut["feasible"] < far["feasible"]


def test_a_suction_cup_through_the_client(embedded_stack, tmp_path):
    """A cup from the shipped example (a file), as a SuctionSpec and with a body mesh (files=); a job on the embedded
    worker; the candidates come back as a suction set, and the server's pick equals graspgen.pick on them."""
    from pathlib import Path

    from services_conftest import box_stl

    from graspgen.example_grippers import box, stl_bytes
    from graspgen.kinds import load_gripper
    from graspgen.suction import SuctionCandidates

    examples = Path(__file__).resolve().parents[2] / "examples"
    url, token = embedded_stack
    with Client(url, token, timeout=300) as gg:
        first = gg.upload_gripper(examples / "cup-30.json")
        assert first["spec"]["kind"] == "suction" and first["files"] == []
        spec = load_gripper(examples / "cup-30.json")
        assert gg.create_gripper(spec)["version"] == first["version"]  # the same spec as a SuctionSpec
        body = {k: v for k, v in spec.to_dict().items() if k != "tool"} | {"name": slug("cupb")}
        body["geometry"] = {"units": "mm", "body": "tool.stl"}
        made = gg.create_gripper(body, files={"tool.stl": stl_bytes(box((-20, -20, -150), (20, 20, -20)))})
        assert [f["path"] for f in made["files"]] == ["tool.stl"]
        with pytest.raises(ProblemError) as e:
            gg.create_gripper({**spec.to_dict(), "name": slug("cupx"), "vacuum": 2e5})
        assert e.value.status == 422 and e.value.problem["field"] == "vacuum"
        obj = slug("box")
        gg.upload_object(box_stl((80.0, 60.0, 30.0)), name=obj, units="mm", filename="box.stl")
        job = gg.wait(gg.submit_job(obj, "cup-30", params={**SMALL, "mass_kg": 0.2}), timeout=300)
        gs = job["grasp_set"]
        assert gg.grasp_set(gs)["gripper"] == first["spec"]
        cands = gg.candidates(gs)
        assert isinstance(cands, SuctionCandidates) and cands.contacts.shape[1] == 1
        floor = [{"point": [0, 0, -0.015], "normal": [0, 0, 1]}]
        answer = gg.pick(np.eye(4), object=obj, gripper="cup-30", approach=DOWN, planes=floor, limit=10)
        local = graspgen.pick(cands, np.eye(4), approach=DOWN, planes=floor, limit=10, gripper=spec)
        assert answer["grasps"] and [g["candidate"] for g in answer["grasps"]] == [g["candidate"] for g in local.grasps]
