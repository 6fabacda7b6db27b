"""Quality options through the runner: validate / select / density reach graspgen as keyword arguments, the export
carries per-grasp `sim` and `quality` and `stats.validation`, progress passes the "validate" stage, and the preview
of the result renders."""

from __future__ import annotations

import io

import pytest
from services_conftest import slug

from services.jobkinds import RUNNABLE
from services.worker.runner import JobRunner

pytestmark = [pytest.mark.integration, pytest.mark.slow]

QUALITY = {"validate": True, "select": "best-near-medoid", "points": 600, "k1": 2, "k2": 1}


@pytest.fixture
def pair(pg_service):
    obj, grip = slug("part"), slug("grip")
    assert pg_service.upload(obj).status_code == 201
    assert pg_service.gripper(grip, grip_force=20.0).status_code == 201  # validation needs the grip force
    return obj, grip


class _Recording(JobRunner):
    stages: list[str]

    def write_progress(self, job_id, stage, progress):  # type: ignore[no-untyped-def]
        self.stages.append(stage)
        return super().write_progress(job_id, stage, progress)


@pytest.fixture
def runner(pg_service):
    state = pg_service.app.state
    r = _Recording(state.db, state.storage, pg_service.settings)
    r.stages = []
    return r


def test_stage_weights_sum_to_one_with_and_without_validation():
    for kind in RUNNABLE.values():
        with_v, without = kind.progress_weights(validate=True), kind.progress_weights(validate=False)
        assert "validate" in with_v and "validate" not in without
        assert abs(sum(with_v.values()) - 1) < 1e-9 and abs(sum(without.values()) - 1) < 1e-9
        names = list(with_v)
        assert names.index("cluster") < names.index("validate") < names.index("export")


def test_validated_best_near_medoid_job(pg_service, runner, pair):
    from PIL import Image

    obj, grip = pair
    r = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {**QUALITY, "density": 2700}})
    assert r.status_code == 202, r.text
    jid = r.json()["id"]
    assert runner.run(jid) == "succeeded"
    assert "validate" in runner.stages
    job = pg_service.get(f"/v1/jobs/{jid}").json()
    assert job["state"] == "succeeded" and job["params"]["validate"] is True
    assert job["params"]["select"] == "best-near-medoid" and job["params"]["density"] == 2700.0
    export = pg_service.get(f"/v1/grasp-sets/{job['grasp_set']}").json()
    assert export["grasps"] and all("sim" in g and "quality" in g for g in export["grasps"])
    assert "validation" in export["stats"] and export["stats"]["selection"]["mode"] == "best-near-medoid"
    # the picture of the result
    png = pg_service.get(f"/v1/grasp-sets/{job['grasp_set']}/preview.png?size=400x300")
    assert png.status_code == 200 and Image.open(io.BytesIO(png.content)).size == (400, 300)

    # re-clustering with validation: the runner hands recluster the part
    runner.stages.clear()
    r = pg_service.post(
        "/v1/jobs",
        json={"kind": "cluster", "grasp_set": job["grasp_set"], "params": {"k1": 3, "k2": 1, "validate": True}},
    )
    assert r.status_code == 202, r.text
    cid = r.json()["id"]
    assert runner.run(cid) == "succeeded", pg_service.get(f"/v1/jobs/{cid}").json()
    assert "validate" in runner.stages
    cjob = pg_service.get(f"/v1/jobs/{cid}").json()
    assert cjob["params"]["validate"] is True and "select" not in cjob["params"]  # not inherited
    cexport = pg_service.get(f"/v1/grasp-sets/{cjob['grasp_set']}").json()
    assert cexport["grasps"] and all("sim" in g for g in cexport["grasps"]) and "validation" in cexport["stats"]


def test_best_near_medoid_recluster_of_a_plain_set(pg_service, runner, pair):
    obj, grip = pair
    r = pg_service.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": {"points": 600, "k1": 2, "k2": 1}})
    jid = r.json()["id"]
    assert runner.run(jid) == "succeeded"
    src = pg_service.get(f"/v1/jobs/{jid}").json()["grasp_set"]
    plain = pg_service.get(f"/v1/grasp-sets/{src}").json()
    assert "validation" not in plain["stats"] and not any("sim" in g for g in plain["grasps"])
    r = pg_service.post(
        "/v1/jobs",
        json={"kind": "cluster", "grasp_set": src, "params": {"k1": 2, "k2": 1, "select": "best-near-medoid"}},
    )
    cid = r.json()["id"]
    assert runner.run(cid) == "succeeded", pg_service.get(f"/v1/jobs/{cid}").json()
    cjob = pg_service.get(f"/v1/jobs/{cid}").json()
    export = pg_service.get(f"/v1/grasp-sets/{cjob['grasp_set']}").json()
    assert export["stats"]["selection"]["mode"] == "best-near-medoid"
    assert all("quality" in g for g in export["grasps"]) and "validate" not in runner.stages
