"""Suction jobs through the service (CONTRACT.md "Suction cups"): a generate job with a cup runs in the worker and its
set is served like any other (export, grasp rows, candidate NPZ, recording, preview, catalogue, release, pick, bulk);
a cup on a body mesh is rebuilt with its file; params a kind cannot use are refused at submission, as graspgen refuses
them at run time; a cluster job reclusters a suction set's stored candidates into a new version."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from services_conftest import box_stl, slug

import graspgen
from graspgen.example_grippers import box, stl_bytes
from graspgen.suction import load_suction_candidates
from services.worker.runner import JobRunner
from tests.grippers import CUP, GRIPPER

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # runs the core

SMALL = {"points": 800, "k1": 4, "k2": 2, "mass_kg": 0.2}
#: an 80 x 60 x 30 mm box: the 30 mm cup seals on its two large faces and its 80 x 30 mm sides
PART = box_stl((80.0, 60.0, 30.0))
EYE = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
FLOOR = [{"point": [0, 0, -0.015], "normal": [0, 0, 1]}]  # the box's bottom face
DOWN = {"direction": [0, 0, -1], "max_angle_deg": 20}


@pytest.fixture
def runner(pg_service):
    state = pg_service.app.state
    return JobRunner(state.db, state.storage, pg_service.settings)


def run_job(svc, runner, body: dict) -> dict:  # type: ignore[no-untyped-def]
    r = svc.post("/v1/jobs", json=body)
    assert r.status_code == 202, r.text
    jid = r.json()["id"]
    assert runner.run(jid) == "succeeded", svc.get(f"/v1/jobs/{jid}").json()
    return svc.get(f"/v1/jobs/{jid}").json()


def test_a_suction_job_makes_a_set_that_is_served_released_and_picked(pg_service, runner):
    obj, cup = slug("plate"), slug("cup")
    assert pg_service.upload(obj, PART).status_code == 201
    spec = pg_service.post("/v1/grippers", json={**CUP, "name": cup}).json()["spec"]
    job = run_job(pg_service, runner, {"object": obj, "gripper": cup, "params": SMALL})
    gs = job["grasp_set"]
    export = pg_service.get(f"/v1/grasp-sets/{gs}").json()
    assert export["format"] == "graspgen.grasp_set/1" and export["gripper"] == spec
    assert export["gripper"]["kind"] == "suction" and export["params"]["mass_kg"] == 0.2
    grasps = export["grasps"]
    assert grasps and all(len(g["contacts"]) == 1 and g["hold_margin"] >= 1 for g in grasps)
    for g in grasps:  # the pose's origin is the contact and its +Z the approach
        T = np.array(g["pose"])
        assert np.allclose(T[:3, 3], g["contacts"][0]) and np.allclose(T[:3, 2], g["approach"])
    # the grasp rows: one contact, no width or friction margin
    rows = pg_service.get(f"/v1/grasp-sets/{gs}/grasps?limit=100").json()["items"]
    assert len(rows) == len(grasps) and rows[0]["width"] is None and rows[0]["friction_margin_deg"] is None
    assert rows[0]["contacts"] == grasps[0]["contacts"] and rows[0]["pose"] == grasps[0]["pose"]
    # the candidate NPZ is a suction set's; the recording and the preview are served
    npz = pg_service.get(f"/v1/grasp-sets/{gs}/candidates")
    assert npz.status_code == 200
    cands = load_suction_candidates(io.BytesIO(npz.content))
    assert cands.contacts.shape[1:] == (1, 3) and len(cands) == export["stats"]["candidates"]
    rrd = pg_service.get(f"/v1/grasp-sets/{gs}/recording")
    assert rrd.status_code == 200 and b"grasps/cups" in rrd.content  # the run logged the cup and tool at each grasp
    png = pg_service.get(f"/v1/grasp-sets/{gs}/preview.png?size=320x240")
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    # the catalogue serves it; a release pins it
    cat = pg_service.get(f"/v1/catalogue/{obj}/{cup}")
    assert cat.status_code == 200 and cat.headers["graspgen-set-id"] == str(gs)
    assert cat.headers["graspgen-released"] == "false"
    assert pg_service.post(f"/v1/grasp-sets/{gs}/release").status_code == 200
    assert pg_service.get(f"/v1/catalogue/{obj}/{cup}").headers["graspgen-released"] == "true"
    listed = pg_service.get(f"/v1/catalogue?gripper={cup}").json()["items"]
    assert [i["id"] for i in listed] == [gs]
    # the pick query: cups from above on the top face, the same answer as graspgen.pick on the NPZ
    body = {"object": obj, "gripper": cup, "T_world_object": EYE, "approach": DOWN, "planes": FLOOR, "limit": 5}
    pick = pg_service.post("/v1/pick", who="reader", json=body)
    assert pick.status_code == 200, pick.text
    out = pick.json()
    assert out["grasp_set"] == gs and out["score"] == "hold_margin" and out["grasps"]
    assert all(g["position"][2] == pytest.approx(0.015) and g["any_roll"] for g in out["grasps"])
    local = graspgen.pick(
        cands, np.eye(4), approach=DOWN, planes=FLOOR, limit=5, gripper=graspgen.kinds.gripper_from_dict(spec)
    )
    assert out["grasps"] == json.loads(json.dumps(local.grasps)) and out["feasible"] == local.feasible


def test_a_cup_with_a_body_mesh_runs_with_its_file(pg_service, runner):
    obj, cup = slug("plate"), slug("cupbody")
    assert pg_service.upload(obj, PART).status_code == 201
    spec = {k: v for k, v in CUP.items() if k != "tool"} | {"name": cup}
    spec["geometry"] = {"units": "mm", "body": "body.stl"}
    body = stl_bytes(box((-20, -20, -150), (20, 20, -20)))
    r = pg_service.post("/v1/grippers", data={"spec": json.dumps(spec)}, files=[("body.stl", ("body.stl", body))])
    assert r.status_code == 201, r.text
    job = run_job(pg_service, runner, {"object": obj, "gripper": cup, "params": SMALL})
    export = pg_service.get(f"/v1/grasp-sets/{job['grasp_set']}").json()
    assert export["gripper"] == r.json()["spec"] and export["grasps"]
    pick = pg_service.post(
        "/v1/pick",
        who="reader",
        json={"grasp_set": job["grasp_set"], "T_world_object": EYE, "planes": FLOOR, "limit": 3},
    )
    assert pick.status_code == 200 and pick.json()["grasps"], pick.text
    assert "any_roll" not in pick.json()["grasps"][0]  # a body turns with the roll
    png = pg_service.get(f"/v1/grasp-sets/{job['grasp_set']}/preview.png?size=320x240")
    assert png.status_code == 200, png.text
    # a cluster job rebuilds the cup with its body file too (the export holds only its digest)
    again = run_job(pg_service, runner, {"kind": "cluster", "grasp_set": job["grasp_set"], "params": {"k1": 2}})
    assert pg_service.get(f"/v1/grasp-sets/{again['grasp_set']}").json()["gripper"] == r.json()["spec"]


def test_bulk_jobs_mix_cups_and_jaws(pg_service, runner):
    obj, cup, jaw = slug("plate"), slug("cup"), slug("jaw")
    assert pg_service.upload(obj, PART).status_code == 201
    assert pg_service.post("/v1/grippers", json={**CUP, "name": cup}).status_code == 201
    assert pg_service.gripper(jaw).status_code == 201
    items = [{"object": obj, "gripper": g, "params": {"points": 600, "k1": 2, "k2": 1}} for g in (cup, jaw)]
    parent = pg_service.post("/v1/bulk-jobs", json={"items": items})
    assert parent.status_code == 202, parent.text
    for item in parent.json()["items"]:
        assert runner.run(item["id"]) == "succeeded", pg_service.get(item["links"]["self"]).json()
    done = pg_service.get(f"/v1/jobs/{parent.json()['id']}").json()
    assert done["state"] == "succeeded" and done["summary"]["succeeded"] == 2
    kinds = {pg_service.get(f"/v1/catalogue/{obj}/{g}").json()["gripper"].get("kind") for g in (cup, jaw)}
    assert kinds == {"suction", None}


def test_a_suction_job_with_validate_simulates_every_exported_cup(pg_service, runner):
    obj, cup = slug("plate"), slug("cup")
    assert pg_service.upload(obj, PART).status_code == 201
    assert pg_service.post("/v1/grippers", json={**CUP, "name": cup}).status_code == 201
    params = {"points": 600, "k1": 2, "k2": 1, "mass_kg": 0.2, "validate": True}
    job = run_job(pg_service, runner, {"object": obj, "gripper": cup, "params": params})
    export = pg_service.get(f"/v1/grasp-sets/{job['grasp_set']}").json()
    v = export["stats"]["validation"]
    assert export["params"]["mass_kg"] == 0.2 and v["tested"] == len(export["grasps"]) > 0
    assert all(g["sim"]["success"] for g in export["grasps"]) and v["succeeded"] == v["tested"]
    assert "validate" in export["stats"]["timings_s"]


#: (gripper, params, field): job params a kind cannot use, refused at submission with the field named
NOT_FOR_KIND = [
    ("cup", {"inside": True}, "inside"),
    ("cup", {"collision": "paper"}, "collision"),
    ("cup", {"select": "best-near-medoid"}, "select"),
    ("jaw", {"max_tilt_deg": 10.0}, "max_tilt_deg"),
]


@pytest.mark.parametrize("which, params, field", NOT_FOR_KIND)
def test_params_a_kind_cannot_use_are_refused_at_submission(pg_service, which, params, field):
    obj, grip = slug("plate"), slug(which)
    assert pg_service.upload(obj, PART).status_code == 201
    made = pg_service.post("/v1/grippers", json={**CUP, "name": grip}) if which == "cup" else pg_service.gripper(grip)
    assert made.status_code == 201
    before = pg_service.row_counts()
    r = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": params})
    assert r.status_code == 422 and r.json()["field"] == field, r.text
    bulk = pg_service.post("/v1/bulk-jobs", json={"items": [{"object": obj, "gripper": grip, "params": params}]})
    assert bulk.json()["items"][0]["error"]["field"] == field  # a bulk item fails alone, as every bad item does
    assert pg_service.row_counts()["grasp_sets"] == before["grasp_sets"]


@pytest.mark.parametrize("which, params, field", NOT_FOR_KIND)
def test_graspgen_refuses_the_same_params(which, params, field):
    """graspgen.generate refuses them when the run starts, with the check the service runs at submission
    (graspgen.kinds.check_params_for_kind)."""
    import trimesh

    from graspgen.errors import InvalidParameterError

    spec = CUP if which == "cup" else GRIPPER
    with pytest.raises(InvalidParameterError) as e:
        graspgen.generate(trimesh.creation.box(extents=(0.08, 0.06, 0.03)), spec, units="m", points=200, **params)
    assert e.value.field == field


def test_a_cluster_job_reclusters_a_suction_set_into_a_new_version(pg_service, runner):
    """The worker reclusters the stored NPZ (graspgen.recluster, the export's gripper.kind "suction"): the new version
    holds what graspgen.recluster makes of the same NPZ and export, and the catalogue serves it as the pair's newest."""
    obj, cup = slug("plate"), slug("cup")
    assert pg_service.upload(obj, PART).status_code == 201
    assert pg_service.post("/v1/grippers", json={**CUP, "name": cup}).status_code == 201
    src = run_job(pg_service, runner, {"object": obj, "gripper": cup, "params": SMALL})["grasp_set"]
    job = run_job(pg_service, runner, {"kind": "cluster", "grasp_set": src, "params": {"k1": 3, "k2": 1, "seed": 2}})
    assert job["kind"] == "cluster" and job["source_grasp_set"] == src and job["grasp_set"] != src
    gs = job["grasp_set"]
    summary = next(i for i in pg_service.get(f"/v1/grasp-sets?object={obj}").json()["items"] if i["id"] == gs)
    assert summary["derived_from"] == src and summary["version"] == 2
    export = pg_service.get(f"/v1/grasp-sets/{gs}").json()
    source = pg_service.get(f"/v1/grasp-sets/{src}").json()
    assert export["gripper"] == source["gripper"] and export["gripper"]["kind"] == "suction"
    assert export["params"] == {**source["params"], "k1": 3, "k2": 1, "seed": 2}  # the mass kept, nothing added
    assert export["grasps"] and all(g["hold_margin"] >= 1 and g["hold_limit"] for g in export["grasps"])
    # the same as graspgen.recluster of the source's NPZ and export
    npz = pg_service.get(f"/v1/grasp-sets/{src}/candidates").content
    local = graspgen.recluster(load_suction_candidates(io.BytesIO(npz)), source, k1=3, k2=1, seed=2)
    assert export["grasps"] == json.loads(json.dumps(local.grasps))
    cands = load_suction_candidates(io.BytesIO(pg_service.get(f"/v1/grasp-sets/{gs}/candidates").content))
    assert np.array_equal(cands.medoids, local.candidates.medoids) and cands.hold_limit is not None
    rows = pg_service.get(f"/v1/grasp-sets/{gs}/grasps?limit=100").json()["items"]
    assert len(rows) == len(export["grasps"]) and rows[0]["width"] is None
    assert pg_service.get(f"/v1/grasp-sets/{gs}/recording").status_code == 200
    # the catalogue serves the newest set of the pair: the new version
    assert pg_service.get(f"/v1/catalogue/{obj}/{cup}").headers["graspgen-set-id"] == str(gs)
    # what a cup's clustering cannot use: 422 at submission with the field named, nothing stored
    before = pg_service.row_counts()
    for params, field in (({"validate": True}, "validate"), ({"select": "best-near-medoid"}, "select")):
        r = pg_service.post("/v1/jobs", json={"kind": "cluster", "grasp_set": src, "params": {"k1": 2, **params}})
        assert r.status_code == 422 and r.json()["field"] == field, r.text
    r = pg_service.post("/v1/jobs", json={"kind": "cluster", "grasp_set": src, "params": {"density": 1000}})
    assert r.status_code == 422 and r.json()["field"] == "density", r.text
    assert pg_service.row_counts() == before
