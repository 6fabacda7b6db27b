"""The part's mass through the service (issue 14, service side): `mass_kg` on upload, stored on the object version,
and the hold parameters of a job, with the object's mass used when the job gives neither mass_kg nor density."""

from __future__ import annotations

import pytest
from services_conftest import box_stl, slug

pytestmark = pytest.mark.integration

PROBLEM = "application/problem+json"


@pytest.fixture(params=["pg_service", "sqlite_service"])
def svc(request):  # type: ignore[no-untyped-def]
    """PostgreSQL + Redis, and the embedded default (SQLite)."""
    return request.getfixturevalue(request.param)


def upload(svc, name: str, data: bytes, **form: str):  # type: ignore[no-untyped-def]
    return svc.post(
        "/v1/objects", files={"file": ("part.stl", data, "model/stl")}, data={"name": name, "units": "mm", **form}
    )


def test_mass_is_stored_on_the_version_and_a_conflicting_mass_is_refused(svc):
    name = slug("heavy")
    data = box_stl((40.0, 30.0, 20.0))
    r = upload(svc, name, data, mass_kg="0.25")
    assert r.status_code == 201 and r.json()["mass_kg"] == 0.25
    assert svc.get(f"/v1/objects/{name}/versions/1").json()["mass_kg"] == 0.25
    assert svc.get(f"/v1/objects/{name}").json()["versions"][0]["mass_kg"] == 0.25
    assert upload(svc, name, data, mass_kg="0.25").status_code == 200  # identical upload
    assert upload(svc, name, data).status_code == 200  # no mass given: the existing version
    before = svc.row_counts()
    conflict = upload(svc, name, data, mass_kg="0.3")
    assert conflict.status_code == 409 and conflict.headers["content-type"] == PROBLEM
    assert conflict.json()["field"] == "mass_kg" and conflict.json()["version"] == 1
    assert svc.row_counts() == before
    light = slug("light")
    assert upload(svc, light, data).json()["mass_kg"] is None


@pytest.mark.parametrize("bad", ["0", "-1", "nan", "inf", "-inf", "1e9", "heavy"])
def test_bad_mass_is_422_and_stores_nothing(svc, bad):
    before = svc.row_counts()
    r = upload(svc, slug("bad"), box_stl(), mass_kg=bad)
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM, (bad, r.text)
    assert svc.row_counts() == before


def test_job_takes_the_objects_mass_unless_it_gives_mass_or_density(pg_service):
    svc = pg_service
    obj, grip = slug("m"), slug("g")
    assert upload(svc, obj, box_stl(), mass_kg="0.5").status_code == 201
    assert svc.gripper(grip, grip_force=30.0).status_code == 201

    def params(p: dict | None) -> dict:
        r = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": p})
        assert r.status_code == 202, r.text
        return r.json()["params"]

    got = params(None)
    assert got["mass_kg"] == 0.5 and got["density"] is None and got["hold"] == "any" and got["accel"] == 9.81
    assert params({"mass_kg": 2.0})["mass_kg"] == 2.0
    dense = params({"density": 7850})
    assert dense["mass_kg"] is None and dense["density"] == 7850.0
    tuned = params({"accel": 3.0, "hold": "off", "position_tolerance": 0.0005})
    assert (tuned["accel"], tuned["hold"], tuned["position_tolerance"], tuned["mass_kg"]) == (3.0, "off", 0.0005, 0.5)

    before = svc.row_counts()
    for bad, field in (
        ({"mass_kg": 1.0, "density": 1000}, "density"),
        ({"mass_kg": 0}, "mass_kg"),
        ({"hold": "maybe"}, "hold"),
        ({"accel": -1}, "accel"),
        ({"position_tolerance": "x"}, "position_tolerance"),
    ):
        r = svc.post("/v1/jobs", json={"object": obj, "gripper": grip, "params": bad})
        assert r.status_code == 422 and r.json()["field"] == field, (bad, r.text)
    assert svc.row_counts() == before
