"""The pick query against a brute-force loop: every (candidate, free roll), the 8 corners of every box, a sort."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import graspgen
from graspgen.errors import InvalidParameterError
from graspgen.examples import example_part
from graspgen.export import Candidates
from graspgen.gripper import GripperSpec
from graspgen.pick import PickIndex
from graspgen.quality import scores
from graspgen.transforms import grasp_frames, quaternion_xyzw_to_matrix

from .. import grippers

GRIPPER = GripperSpec.from_dict(grippers.GRIPPER)


def synthetic(n: int = 300, rolls: int = 8, *, seed: int = 0, quality: bool = False) -> Candidates:
    """Random pairs on a 60 mm part around the origin, random free rolls (some axes near the object's Z)."""
    rng = np.random.default_rng(seed)
    mid = rng.uniform(-0.03, 0.03, (n, 3))
    axis = rng.normal(size=(n, 3))
    axis[: n // 10] = [0.05, 0.0, 1.0]  # |X . Z_object| > 0.9: the roll reference switches to object +X
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    half = rng.uniform(0.002, 0.035, (n, 1))
    contacts = np.stack([mid - half * axis, mid + half * axis], axis=1)
    normals = np.stack([-axis, axis], axis=1)
    free = rng.random((n, rolls)) < 0.6
    free[np.arange(n), rng.integers(0, rolls, n)] = True
    margin = np.round(rng.uniform(0, 20, n), 1)  # rounded: equal scores, so the tie-breaks matter
    labels = np.column_stack([rng.integers(0, 5, n), rng.integers(0, 3, n)]).astype(np.int32)
    return Candidates(
        contacts=contacts,
        normals=normals,
        free_rolls=free,
        roll_angles_rad=2 * np.pi * np.arange(rolls) / rolls,
        friction_margin_deg=margin,
        inside=np.zeros(n, dtype=bool),
        labels=labels,
        medoids=np.array([3, 1, 7], dtype=np.int64),
        quality_terms=rng.uniform(0, 1, (n, 3)) if quality else None,
    )


def _corners(box) -> np.ndarray:  # type: ignore[no-untyped-def]
    c, e = np.asarray(box.center), np.asarray(box.extents) / 2
    return np.array([c + np.array(s) * e for s in itertools.product((-1, 1), repeat=3)])


def brute_force(cands, gripper, T_wo, direction, max_angle_deg, planes, distance, limit):  # type: ignore[no-untyped-def]
    """The contract's pick, spelled out: returns [(candidate, roll, T_world_grasp, approach angle)] best first,
    and the numbers the cone and the planes removed."""
    per_cand = scores(cands.quality_terms) if cands.quality_terms is not None else cands.friction_margin_deg
    rows, cone_out, planes_out = [], 0, 0
    d = None if direction is None else np.asarray(direction, float) / np.linalg.norm(direction)
    for c in range(len(cands)):
        w = float(np.linalg.norm(cands.contacts[c, 1] - cands.contacts[c, 0]))
        mid = cands.contacts[c].mean(axis=0)
        axis = (cands.contacts[c, 1] - cands.contacts[c, 0]) / w
        for r in np.flatnonzero(cands.free_rolls[c]):
            T_og = grasp_frames(mid[None], axis[None], np.array([cands.roll_angles_rad[r]]))[0]
            T_wg = T_wo @ T_og
            angle = 0.0
            if d is not None:
                angle = math.degrees(math.acos(max(-1.0, min(1.0, float(T_wg[:3, 2] @ d)))))
                if angle > max_angle_deg + 1e-9:
                    cone_out += 1
                    continue
            T_wp = T_wg.copy()
            T_wp[:3, 3] -= distance * T_wg[:3, 2]
            boxes = [(T_wg, b) for b in gripper.boxes(w)] + [(T_wp, b) for b in gripper.boxes(gripper.open_width(w))]
            clear = True
            for p in planes:
                n = np.asarray(p["normal"], float) / np.linalg.norm(p["normal"])
                for T, b in boxes:
                    world = _corners(b) @ T[:3, :3].T + T[:3, 3]
                    if np.any((world - np.asarray(p["point"], float)) @ n < -1e-9):
                        clear = False
            if not clear:
                planes_out += 1
                continue
            rows.append((-per_cand[c], round(angle, 9), c, r, T_wg))
    rows.sort(key=lambda t: t[:4])
    return [(c, r, T, a) for _, a, c, r, T in rows[:limit]], len(rows), cone_out, planes_out


SCENES = [
    # part lying 20 mm above a floor, approach from above within 30 degrees
    dict(
        T=[[1, 0, 0, 0.4], [0, 1, 0, 0], [0, 0, 1, 0.02], [0, 0, 0, 1]],
        direction=[0, 0, -1],
        angle=30.0,
        planes=[{"point": [0, 0, 0], "normal": [0, 0, 1]}],
    ),
    # turned part in a bin corner (floor and two walls), wide cone, unnormalised normals
    dict(
        T=None,
        direction=[0.3, -0.2, -2.0],
        angle=70.0,
        planes=[
            {"point": [0, 0, -0.01], "normal": [0, 0, 3]},
            {"point": [-0.05, 0, 0], "normal": [1, 0, 0]},
            {"point": [0, 0.06, 0], "normal": [0, -0.5, 0]},
        ],
    ),
    # no cone, no planes: every pair is feasible, the order is the score's
    dict(T=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], direction=None, angle=180.0, planes=[]),
]


def _turned() -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [20, -35, 110], degrees=True).as_matrix()
    T[:3, 3] = [0.1, -0.2, 0.05]
    return T


@pytest.mark.parametrize("quality", [False, True])
@pytest.mark.parametrize("scene", range(len(SCENES)))
def test_pick_equals_brute_force(scene, quality):
    s = SCENES[scene]
    cands = synthetic(quality=quality, seed=scene)
    T_wo = _turned() if s["T"] is None else np.asarray(s["T"], float)
    approach = None if s["direction"] is None else {"direction": s["direction"], "max_angle_deg": s["angle"]}
    limit = 40
    result = graspgen.pick(
        cands, T_wo, approach=approach, planes=s["planes"], pregrasp_distance=0.05, limit=limit, gripper=GRIPPER
    )
    want, feasible, cone_out, planes_out = brute_force(
        cands, GRIPPER, T_wo, s["direction"], s["angle"], s["planes"], 0.05, limit
    )
    assert result.considered == int(cands.free_rolls.sum())
    assert result.feasible == feasible > 0
    assert result.removed["approach"] == cone_out and result.removed["planes"] == planes_out
    if scene < 2:
        assert cone_out > 0 and (planes_out > 0 or not s["planes"])
    got = [(g["candidate"], g["roll_index"]) for g in result.grasps]
    assert got == [(c, r) for c, r, _, _ in want]
    for g, (c, r, T, angle) in zip(result.grasps, want, strict=True):
        np.testing.assert_allclose(g["T_world_grasp"], T, atol=1e-12)
        assert g["approach_angle_deg"] == pytest.approx(angle, abs=1e-6)
        assert g["position"] == pytest.approx(list(T[:3, 3]))
        np.testing.assert_allclose(quaternion_xyzw_to_matrix(g["quaternion_xyzw"]), T[:3, :3], atol=1e-12)
        assert g["quaternion_xyzw"][3] >= 0
        assert g["cluster"] == list(cands.labels[c]) and g["medoid"] == (c in (3, 1, 7))
        assert g["roll_deg"] == pytest.approx(360.0 * r / cands.free_rolls.shape[1])
        np.testing.assert_allclose(np.asarray(g["T_world_pregrasp"])[:3, 3], T[:3, 3] - 0.05 * T[:3, 2], atol=1e-12)
        assert g["open_width"] == pytest.approx(min(g["width"] + 0.02, 0.08))
    assert result.score_source == ("quality" if quality else "friction_margin_deg")


def test_flange_poses_compose_on_the_right():
    cands = synthetic(n=40)
    T_tf = np.eye(4)
    T_tf[:3, :3] = quaternion_xyzw_to_matrix([0, 0, math.sin(math.pi / 8), math.cos(math.pi / 8)])
    T_tf[:3, 3] = [0.0, 0.01, -0.1]
    r = graspgen.pick(cands, np.eye(4), T_tcp_flange=T_tf, limit=5, gripper=GRIPPER)
    for g in r.grasps:
        np.testing.assert_allclose(g["T_world_flange"], np.asarray(g["T_world_grasp"]) @ T_tf, atol=1e-12)
        np.testing.assert_allclose(g["T_world_preflange"], np.asarray(g["T_world_pregrasp"]) @ T_tf, atol=1e-12)
    assert "T_world_flange" not in graspgen.pick(cands, np.eye(4), limit=1, gripper=GRIPPER).grasps[0]


def test_an_empty_answer_says_what_removed_the_pairs():
    cands = synthetic(n=60)
    # the part lies below the floor: every pair that passes the cone hits the plane
    T = np.eye(4)
    T[2, 3] = -0.2
    r = graspgen.pick(
        cands,
        T,
        approach={"direction": [0, 0, -1], "max_angle_deg": 45},
        planes=[{"point": [0, 0, 0], "normal": [0, 0, 1]}],
        gripper=GRIPPER,
    )
    assert r.grasps == [] and r.feasible == 0
    assert r.reason == {
        "candidates": r.considered,
        "approach": r.removed["approach"],
        "planes": r.considered - r.removed["approach"],
        "per_plane": [r.considered - r.removed["approach"]],
    }
    assert r.removed["approach"] > 0 and r.to_json()["reason"] == r.reason


def test_pregrasp_alone_can_block_a_grasp():
    """A grasp whose fingers clear a wall but whose retreat along -Z passes through it is removed."""
    n = 1
    contacts = np.array([[[-0.01, 0, 0], [0.01, 0, 0]]])
    cands = Candidates(
        contacts=contacts,
        normals=np.array([[[-1.0, 0, 0], [1.0, 0, 0]]]),
        free_rolls=np.array([[True, False, False, False]]),
        roll_angles_rad=np.arange(4) * np.pi / 2,
        friction_margin_deg=np.array([5.0]),
        inside=np.zeros(n, dtype=bool),
        labels=np.zeros((n, 2), np.int32),
        medoids=np.array([0]),
    )
    # roll 0 of axis +X: Z0 = object +Z, so the approach is +Z and the pre-grasp lies 50 mm below the grasp
    wall = [{"point": [0, 0, -0.04], "normal": [0, 0, 1]}]  # fingers (|z| <= 15 mm) and palm (to -35 mm) clear it
    assert graspgen.pick(cands, np.eye(4), planes=wall, gripper=GRIPPER, pregrasp_distance=0.0).feasible == 1
    r = graspgen.pick(cands, np.eye(4), planes=wall, gripper=GRIPPER, pregrasp_distance=0.05)
    assert r.feasible == 0 and r.reason["planes"] == 1


@pytest.mark.slow
def test_a_grasp_set_picks_with_its_own_gripper():
    """A real set from generate(): the same answer as the brute-force loop, with the set's own gripper."""
    part = example_part("ring-screw")
    gs = graspgen.generate(part.mesh, GRIPPER, units="m", points=1500, k1=4, k2=2, rolls=8)
    T = _turned()
    planes = [{"point": [0, 0, 0.03], "normal": [0, 0, 1]}]
    r = graspgen.pick(gs, T, approach={"direction": [0, 0, -1], "max_angle_deg": 90}, planes=planes, limit=1000)
    want, feasible, cone_out, planes_out = brute_force(gs.candidates, gs.gripper, T, [0, 0, -1], 90, planes, 0.05, 1000)
    assert r.considered == int(gs.candidates.free_rolls.sum()) > 0
    assert (r.feasible, r.removed["approach"], r.removed["planes"]) == (feasible, cone_out, planes_out)
    assert [(g["candidate"], g["roll_index"]) for g in r.grasps] == [(c, k) for c, k, _, _ in want]
    assert r.score_source == ("quality" if gs.candidates.quality_terms is not None else "friction_margin_deg")


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(T_world_object=np.diag([1, 1, -1, 1.0])), "T_world_object"),  # a reflection
        (dict(T_world_object=np.diag([1, 1, 1.001, 1.0])), "T_world_object"),  # not orthonormal
        (dict(T_world_object=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]), "T_world_object"),
        (dict(T_world_object=[[1, 0, 0, math.nan], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), "T_world_object"),
        (dict(T_world_object=np.eye(3)), "T_world_object"),
        (dict(T_tcp_flange=np.eye(4) * 2), "T_tcp_flange"),
        (dict(approach={"direction": [0, 0, 0], "max_angle_deg": 10}), "approach.direction"),
        (dict(approach={"direction": [0, 0, 1], "max_angle_deg": 181}), "approach.max_angle_deg"),
        (dict(approach={"direction": [0, 0, 1]}), "approach.max_angle_deg"),
        (dict(planes=[{"point": [0, 0, 0], "normal": [0, 0, 0]}]), "planes[0].normal"),
        (dict(planes=[{"point": [0, 0], "normal": [0, 0, 1]}]), "planes[0].point"),
        (dict(limit=0), "limit"),
        (dict(limit=1001), "limit"),
        (dict(pregrasp_distance=-0.01), "pregrasp_distance"),
    ],
)
def test_bad_queries_are_refused_with_the_field(kwargs, field):
    args = {"T_world_object": np.eye(4), **kwargs}
    with pytest.raises(InvalidParameterError) as info:
        graspgen.pick(synthetic(n=10), args.pop("T_world_object"), gripper=GRIPPER, **args)
    assert info.value.field == field


def test_candidates_need_a_gripper():
    with pytest.raises(InvalidParameterError):
        graspgen.pick(synthetic(n=10), np.eye(4))


def test_index_frames_equal_the_contract_frames():
    cands = synthetic(n=50)
    index = PickIndex.build(cands, GRIPPER)
    T = grasp_frames(
        cands.midpoints[index.candidate], cands.axes[index.candidate], cands.roll_angles_rad[index.roll_index]
    )
    np.testing.assert_allclose(index.frames[:, 0:3], T[:, :3, 0], atol=1e-15)
    np.testing.assert_allclose(index.frames[:, 3:6], T[:, :3, 1], atol=1e-15)
    np.testing.assert_allclose(index.frames[:, 6:9], T[:, :3, 2], atol=1e-15)
    np.testing.assert_allclose(index.frames[:, 9:12], T[:, :3, 3], atol=1e-15)
    np.testing.assert_array_equal(index.approach, index.frames[:, 6:9].T.astype(np.float32))
    in_order = np.argsort(index.rank)
    assert sorted(index.rank) == list(range(len(index))) and np.all(np.diff(index.score[in_order]) <= 0)
    assert index.nbytes > index.frames.nbytes


def test_hold_margins_of_the_set_come_with_the_grasps():
    from dataclasses import replace

    cands = synthetic(n=30)
    margins = np.linspace(1.0, 4.0, len(cands))
    r = graspgen.pick(replace(cands, hold_margin=margins), np.eye(4), limit=5, gripper=GRIPPER)
    assert [g["hold_margin"] for g in r.grasps] == [margins[g["candidate"]] for g in r.grasps]
    assert "hold_margin" not in graspgen.pick(cands, np.eye(4), limit=1, gripper=GRIPPER).grasps[0]


@pytest.mark.parametrize("limit", [1, 7, 300])
def test_the_walk_down_the_quality_order_keeps_ties(limit):
    """Most pairs feasible and many equal scores (margins rounded to 0.1 degree): the top found by walking the
    quality order in steps must equal the full sort, ties at the cut broken by the approach angle."""
    cands = synthetic(n=2500, rolls=8, seed=7)
    T = _turned()
    approach = {"direction": [0.2, 0.1, -1.0], "max_angle_deg": 150}
    r = graspgen.pick(cands, T, approach=approach, limit=limit, gripper=GRIPPER)
    want, feasible, _, _ = brute_force(cands, GRIPPER, T, approach["direction"], 150, [], 0.05, limit)
    assert r.feasible == feasible > 4096
    assert [(g["candidate"], g["roll_index"]) for g in r.grasps] == [(c, k) for c, k, _, _ in want]
