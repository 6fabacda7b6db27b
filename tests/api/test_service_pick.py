"""POST /v1/pick on PostgreSQL: the same answer as graspgen.pick on the stored candidates, the catalogue's current set
by name, empty answers with a reason, refusals as problem+json, and the process cache of prepared pairs."""

from __future__ import annotations

import numpy as np
import pytest
from services_conftest import GRIPPER, seed_grasp_sets, slug

import graspgen
from graspgen.export import Candidates, npz_bytes
from graspgen.gripper import GripperSpec

pytestmark = pytest.mark.integration

FLOOR = [{"point": [0, 0, 0], "normal": [0, 0, 1]}]
DOWN = {"direction": [0, 0, -1], "max_angle_deg": 40}
T_ON_FLOOR = [[1, 0, 0, 0.4], [0, 1, 0, -0.1], [0, 0, 1, 0.03], [0, 0, 0, 1]]


def candidates(n: int = 400, rolls: int = 16, seed: int = 3) -> Candidates:
    rng = np.random.default_rng(seed)
    mid = rng.uniform(-0.02, 0.02, (n, 3))
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    half = rng.uniform(0.003, 0.03, (n, 1))
    free = rng.random((n, rolls)) < 0.5
    free[:, 0] = True
    return Candidates(
        contacts=np.stack([mid - half * axis, mid + half * axis], axis=1),
        normals=np.stack([-axis, axis], axis=1),
        free_rolls=free,
        roll_angles_rad=2 * np.pi * np.arange(rolls) / rolls,
        friction_margin_deg=rng.uniform(0, 20, n),
        inside=np.zeros(n, dtype=bool),
        labels=rng.integers(0, 4, (n, 2)).astype(np.int32),
        medoids=np.arange(8, dtype=np.int64),
        quality_terms=rng.uniform(0, 1, (n, 3)),
    )


@pytest.fixture(scope="module")
def seeded(pg_service):
    """An object and gripper with two grasp sets; the newest has a candidate NPZ in storage."""
    from sqlalchemy import update

    from services.common.models import GraspSet

    grip, obj = slug("pick-g"), slug("pick-o")
    ids = seed_grasp_sets(pg_service, grip, [obj], version_of={obj: 2})[obj]
    cands = candidates()
    blob = pg_service.app.state.storage.put_bytes(npz_bytes(cands.arrays()))
    with pg_service.app.state.db.session() as s:
        s.execute(update(GraspSet).where(GraspSet.id == ids[-1]).values(candidates_key=blob.key))
    return {"object": obj, "gripper": grip, "ids": ids, "candidates": cands}


def test_pick_by_name_equals_the_library_on_the_stored_candidates(pg_service, seeded):
    body = {
        "object": seeded["object"],
        "gripper": seeded["gripper"],
        "T_world_object": T_ON_FLOOR,
        "approach": DOWN,
        "planes": FLOOR,
        "limit": 25,
    }
    r = pg_service.post("/v1/pick", who="reader", json=body)
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["grasp_set"] == seeded["ids"][-1] and out["version"] == 2
    want = graspgen.pick(
        seeded["candidates"],
        np.array(T_ON_FLOOR, float),
        approach=DOWN,
        planes=FLOOR,
        limit=25,
        gripper=GripperSpec.from_dict({**GRIPPER, "name": seeded["gripper"]}),
    )
    assert out["considered"] == want.considered and out["feasible"] == want.feasible > 25
    assert out["removed"] == want.removed and out["score"] == "quality"
    assert [(g["candidate"], g["roll_index"]) for g in out["grasps"]] == [
        (g["candidate"], g["roll_index"]) for g in want.grasps
    ]
    np.testing.assert_allclose([g["T_world_grasp"] for g in out["grasps"]], [g["T_world_grasp"] for g in want.grasps])
    assert "reason" not in out and "T_world_flange" not in out["grasps"][0]
    # the prepared pairs stay in the process: a second query reads neither the database's NPZ nor storage
    cache = pg_service.app.state.pick_cache
    assert cache.get(out["grasp_set"]) is not None and cache.size > 0


def test_pick_by_id_with_a_flange_and_an_empty_answer(pg_service, seeded):
    gs = seeded["ids"][-1]
    flange = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -0.1], [0, 0, 0, 1]]
    r = pg_service.post(
        "/v1/pick", json={"grasp_set": gs, "T_world_object": T_ON_FLOOR, "T_tcp_flange": flange, "limit": 3}
    )
    assert r.status_code == 200, r.text
    grasps = r.json()["grasps"]
    assert len(grasps) == 3
    for g in grasps:
        np.testing.assert_allclose(g["T_world_flange"], np.asarray(g["T_world_grasp"]) @ np.asarray(flange))
    below = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -0.5], [0, 0, 0, 1]]
    r = pg_service.post("/v1/pick", json={"grasp_set": gs, "T_world_object": below, "approach": DOWN, "planes": FLOOR})
    out = r.json()
    assert r.status_code == 200 and out["grasps"] == [] and out["feasible"] == 0
    assert out["reason"]["approach"] > 0 and out["reason"]["planes"] == out["considered"] - out["reason"]["approach"]


@pytest.mark.parametrize(
    "change, field",
    [
        ({"T_world_object": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]}, "T_world_object"),
        ({"approach": {"direction": [0, 0, 0], "max_angle_deg": 10}}, "approach.direction"),
        ({"planes": [{"point": [0, 0, 0], "normal": [0, 0, 0]}]}, "planes[0].normal"),
    ],
)
def test_bad_queries_are_422_problems_and_read_nothing(pg_service, seeded, change, field):
    r = pg_service.post("/v1/pick", json={"grasp_set": seeded["ids"][-1], "T_world_object": T_ON_FLOOR, **change})
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json"
    assert r.json()["code"] == "invalid-parameter" and r.json()["field"] == field


@pytest.mark.parametrize(
    "body",
    [
        {"T_world_object": T_ON_FLOOR},  # no set named
        {"grasp_set": 1, "object": "a", "gripper": "b", "T_world_object": T_ON_FLOOR},  # both
        {"grasp_set": 1, "T_world_object": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},  # 3x3
        {"grasp_set": 1, "T_world_object": T_ON_FLOOR, "limit": 1001},
        {"grasp_set": 1, "T_world_object": T_ON_FLOOR, "colour": "red"},
    ],
)
def test_malformed_requests_are_validation_problems(pg_service, body):
    r = pg_service.post("/v1/pick", json=body)
    assert r.status_code == 422 and r.json()["code"] == "validation-error", r.text


def test_sets_without_candidates_and_unknown_names_are_404(pg_service, seeded):
    r = pg_service.post("/v1/pick", json={"grasp_set": seeded["ids"][0], "T_world_object": T_ON_FLOOR})
    assert r.status_code == 404 and r.json()["code"] == "no-candidates"
    r = pg_service.post("/v1/pick", json={"grasp_set": 2**31 - 1, "T_world_object": T_ON_FLOOR})
    assert r.status_code == 404 and r.json()["code"] == "not-found"
    r = pg_service.post(
        "/v1/pick", json={"object": slug("nope"), "gripper": seeded["gripper"], "T_world_object": T_ON_FLOOR}
    )
    assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json"


def test_pick_needs_a_token(pg_service, seeded):
    r = pg_service.client.post("/v1/pick", json={"grasp_set": seeded["ids"][-1], "T_world_object": T_ON_FLOOR})
    assert r.status_code == 401


def test_the_cache_is_bounded_by_bytes():
    from services.api.cache import SizedLRU

    lru: SizedLRU[str] = SizedLRU(100)
    lru.put("a", "A", 60)
    lru.put("b", "B", 30)
    assert lru.get("a") == "A"  # a is now the most recently used
    lru.put("c", "C", 30)  # 120 > 100: b, the least recently used, goes
    assert lru.get("b") is None and lru.get("a") == "A" and lru.get("c") == "C" and lru.size == 90
    lru.put("big", "X", 101)  # larger than the budget: never kept
    assert lru.get("big") is None and len(lru) == 2
