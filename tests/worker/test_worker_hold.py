"""The part's mass and the hold parameters through the runner (issue 14, service side): the object version's
mass_kg, or the job's own, reaches graspgen.generate, which applies criterion (e) and records it in the export."""

from __future__ import annotations

import pytest
from services_conftest import box_stl, slug

from services.worker.runner import JobRunner

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # runs the core

SMALL = {"points": 500, "k1": 2, "k2": 1}


@pytest.fixture
def runner(pg_service):
    state = pg_service.app.state
    return JobRunner(state.db, state.storage, pg_service.settings)


def run(svc, runner, obj: str, grip: str, params: dict) -> tuple[dict, dict]:
    r = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": params})
    assert r.status_code == 202, r.text
    jid = r.json()["id"]
    assert runner.run(jid) == "succeeded", svc.get(f"/v1/jobs/{jid}").json()["error"]
    job = svc.get(f"/v1/jobs/{jid}").json()
    return job, svc.get(f"/v1/grasp-sets/{job['grasp_set']}").json()


def test_object_mass_and_hold_params_reach_the_core(pg_service, runner):
    svc = pg_service
    obj, grip = slug("mass"), slug("grip")
    up = svc.post(
        "/v1/objects",
        files={"file": ("part.stl", box_stl((40.0, 30.0, 20.0)), "model/stl")},
        data={"name": obj, "units": "mm", "mass_kg": "0.2"},
    )
    assert up.status_code == 201 and up.json()["mass_kg"] == 0.2
    assert svc.gripper(grip, grip_force=20.0).status_code == 201

    job, export = run(svc, runner, obj, grip, SMALL)
    assert job["params"]["mass_kg"] == 0.2
    assert export["params"]["mass_kg"] == 0.2 and export["params"]["hold"] == "any"
    assert "hold" in export["stats"]["rejected"]

    # the job's own values win; hold "off" switches criterion (e) off
    _, heavy = run(svc, runner, obj, grip, {**SMALL, "mass_kg": 3.0, "accel": 5.0, "position_tolerance": 0.0005})
    assert (heavy["params"]["mass_kg"], heavy["params"]["accel"], heavy["params"]["position_tolerance"]) == (
        3.0,
        5.0,
        0.0005,
    )
    # 3 kg at 5 m/s^2 on top of gravity is more than two 20 N contacts with friction 0.5 can hold
    assert heavy["stats"]["rejected"]["hold"] > export["stats"]["rejected"]["hold"]
    assert len(heavy["grasps"]) < len(export["grasps"])
    _, off = run(svc, runner, obj, grip, {**SMALL, "hold": "off", "seed": 5})
    assert off["params"]["hold"] == "off" and off["stats"]["rejected"].get("hold", 0) == 0
