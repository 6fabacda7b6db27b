"""The pick query on suction sets (CONTRACT.md "Suction cups", "Pick query"): the approach cone on the grasp's +Z,
the planes against the cup and the tool at the grasp and the pre-grasp. Known answers (a cup beside the bin floor, a
tilted cup, a tool that only the pre-grasp pushes through a ceiling, a body tool whose rolls a floor decides) and a
brute-force loop over points on the cylinders' rims and the body's vertices."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest

import graspgen
from graspgen.errors import InvalidParameterError
from graspgen.example_grippers import box, stl_bytes
from graspgen.kinds import gripper_from_dict
from graspgen.pick import PickIndex
from graspgen.suction import SuctionSpec

from ..grippers import CUP

SPEC = gripper_from_dict(CUP)
assert isinstance(SPEC, SuctionSpec)
#: a body tool 80 mm wide along the grasp's X, 20 mm along Y, from 20 to 150 mm behind the lip (mm)
BODY_BOX = ((-40.0, -10.0, -150.0), (40.0, 10.0, -20.0))
FLOOR = [{"point": [0, 0, 0], "normal": [0, 0, 1]}]


def body_spec() -> SuctionSpec:
    data = {k: v for k, v in CUP.items() if k != "tool"}
    data["geometry"] = {"units": "mm", "body": "body.stl"}
    spec = gripper_from_dict(data, files={"body.stl": stl_bytes(box(*BODY_BOX))})
    assert isinstance(spec, SuctionSpec) and not spec.round_tool
    return spec


@dataclass(frozen=True)
class Cups:
    """A suction candidate set as the NPZ holds it: one contact per candidate, its approach as `axes`."""

    contacts: np.ndarray  # (n, 1, 3)
    normals: np.ndarray  # (n, 1, 3)
    axes: np.ndarray  # (n, 3)
    free_rolls: np.ndarray  # (n, R)
    roll_angles_rad: np.ndarray
    seal_strain: np.ndarray
    tilt_deg: np.ndarray
    labels: np.ndarray
    medoids: np.ndarray
    hold_margin: np.ndarray | None = None

    @property
    def midpoints(self) -> np.ndarray:
        return self.contacts[:, 0]


def cups(contacts, approaches, rolls: int = 8, free=None, seal=None, hold=None) -> Cups:  # type: ignore[no-untyped-def]
    contacts = np.asarray(contacts, dtype=np.float64).reshape(-1, 1, 3)
    z = np.asarray(approaches, dtype=np.float64).reshape(-1, 3)
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    n = len(z)
    return Cups(
        contacts=contacts,
        normals=-z[:, None, :],
        axes=z,
        free_rolls=np.ones((n, rolls), dtype=bool) if free is None else np.asarray(free, dtype=bool),
        roll_angles_rad=2 * np.pi * np.arange(rolls) / rolls,
        seal_strain=np.zeros(n) if seal is None else np.asarray(seal, dtype=np.float64),
        tilt_deg=np.zeros(n),
        labels=np.zeros((n, 2), dtype=np.int32),
        medoids=np.array([0], dtype=np.int64),
        hold_margin=None if hold is None else np.asarray(hold, dtype=np.float64),
    )


def feasible(result) -> set[int]:  # type: ignore[no-untyped-def]
    return {g["candidate"] for g in result.grasps}


def test_a_cup_beside_the_floor_clears_it_exactly_when_its_rim_does():
    """A cup from above clears the floor at its lip; from the side its rim (radius 15 mm) reaches down 15 mm below
    the contact; from below the tool is under the floor."""
    r = SPEC.cup_radius
    c = cups(
        [(0, 0, 0.02), (0.03, 0, r - 1e-6), (0.03, 0, r + 1e-6), (0.03, 0, 0.05), (0, 0, 0.0)],
        [(0, 0, -1), (-1, 0, 0), (-1, 0, 0), (-1, 0, 0), (0, 0, 1)],
    )
    res = graspgen.pick(c, np.eye(4), planes=FLOOR, limit=100, gripper=SPEC)
    assert feasible(res) == {0, 2, 3}
    assert res.considered == 5 and res.feasible == 3  # a round tool: one pair per candidate
    assert res.removed == {"approach": 0, "planes": 2, "per_plane": [2]}
    g = next(g for g in res.grasps if g["candidate"] == 0)
    assert g["position"] == [0.0, 0.0, 0.02] and g["any_roll"] is True and g["roll_deg"] == 0.0
    assert "width" not in g and "friction_margin_deg" not in g and g["seal_strain"] == 0.0
    T = np.array(g["T_world_grasp"])
    assert np.allclose(T[:3, 2], [0, 0, -1]) and np.allclose(T[:3, 3], [0, 0, 0.02])
    assert np.allclose(np.array(g["T_world_pregrasp"])[:3, 3], [0, 0, 0.07])  # retreated along -Z: up
    # the part moved up by 10 mm: the low side cup clears too; the cup from below still does not
    lifted = np.eye(4)
    lifted[2, 3] = 0.01
    assert feasible(graspgen.pick(c, lifted, planes=FLOOR, limit=100, gripper=SPEC)) == {0, 1, 2, 3}


def test_a_tilted_cup_clears_the_floor_by_its_rim_times_the_cosine():
    """Approaching at 45 deg down, the rim's lowest point lies r / sqrt(2) below the contact (the tool, 8 mm further
    back and 12 mm in radius, stays above it; the pre-grasp is higher)."""
    edge = SPEC.cup_radius / math.sqrt(2)
    c = cups([(0, 0, edge - 1e-7), (0, 0, edge + 1e-7)], [(-1, 0, -1), (-1, 0, -1)])
    assert feasible(graspgen.pick(c, np.eye(4), planes=FLOOR, limit=10, gripper=SPEC)) == {1}


def test_the_tool_at_the_pregrasp_must_clear_a_ceiling():
    """A cup from above at 20 mm: the tool's back is 160 mm up at the grasp and 160 mm + the pre-grasp distance at
    the pre-grasp; a ceiling at 300 mm lets 50 mm through but not 150 mm."""
    c = cups([(0, 0, 0.02)], [(0, 0, -1)])
    ceiling = [{"point": [0, 0, 0.3], "normal": [0, 0, -1]}]
    top = 0.02 + SPEC.cup_height + SPEC.tool.length  # type: ignore[union-attr]
    assert top == pytest.approx(0.16)
    assert feasible(graspgen.pick(c, np.eye(4), planes=ceiling, pregrasp_distance=0.05, gripper=SPEC)) == {0}
    far = graspgen.pick(c, np.eye(4), planes=ceiling, pregrasp_distance=0.15, gripper=SPEC)
    assert far.grasps == [] and far.reason == {"candidates": 1, "approach": 0, "planes": 1, "per_plane": [1]}
    just = graspgen.pick(c, np.eye(4), planes=ceiling, pregrasp_distance=0.3 - top - 1e-9, gripper=SPEC)
    assert feasible(just) == {0}


def test_a_body_tool_fits_over_the_floor_at_the_rolls_that_turn_its_narrow_side_down():
    """A cup from the side at 30 mm with an 80 x 20 mm body: at roll psi the body reaches 40 |sin psi| + 10 |cos psi|
    mm below the axis (roll 0's X is the object's +Y here), so of 8 rolls only 0 and 180 deg clear the floor."""
    spec = body_spec()
    c = cups([(0.05, 0, 0.03)], [(-1, 0, 0)], rolls=8)
    res = graspgen.pick(c, np.eye(4), planes=FLOOR, limit=100, gripper=spec)
    assert sorted(g["roll_index"] for g in res.grasps) == [0, 4]
    assert res.considered == 8 and "any_roll" not in res.grasps[0]
    for g in res.grasps:
        T = np.array(g["T_world_grasp"])
        assert np.allclose(T[:3, 0], [0, math.cos(math.radians(g["roll_deg"])), 0], atol=1e-12)
    # without the floor every free roll comes back; a blocked roll never does
    free = np.ones((1, 8), dtype=bool)
    free[0, 4] = False
    res = graspgen.pick(replace(c, free_rolls=free), np.eye(4), planes=FLOOR, limit=100, gripper=spec)
    assert [g["roll_index"] for g in res.grasps] == [0]
    assert graspgen.pick(replace(c, free_rolls=free), np.eye(4), limit=100, gripper=spec).feasible == 7


def test_the_cone_applies_to_the_approach_and_the_order_is_the_hold_margin():
    c = cups(
        [(0, 0, 0.02), (0, 0, 0.02), (0, 0, 0.02), (0.03, 0, 0.02)],
        [(0, 0, -1), (0.2, 0, -1), (0.2, 0, -1), (-1, 0, 0)],
        hold=[1.5, 3.0, 3.0, 9.0],
        seal=[0.01, 0.02, 0.03, 0.0],
    )
    down = {"direction": [0, 0, -1], "max_angle_deg": 30}
    res = graspgen.pick(c, np.eye(4), approach=down, limit=10, gripper=SPEC)
    assert [g["candidate"] for g in res.grasps] == [1, 2, 0]  # hold margin, then the candidate index
    assert res.removed["approach"] == 1 and res.score_source == "hold_margin"
    assert [g["hold_margin"] for g in res.grasps] == [3.0, 3.0, 1.5]
    assert res.grasps[0]["approach_angle_deg"] == pytest.approx(math.degrees(math.atan(0.2)))
    # without hold margins: the smaller seal strain first
    plain = graspgen.pick(replace(c, hold_margin=None), np.eye(4), approach=down, limit=10, gripper=SPEC)
    assert [g["candidate"] for g in plain.grasps] == [0, 1, 2] and plain.score_source == "seal_strain"
    assert [g["score"] for g in plain.grasps] == [-0.01, -0.02, -0.03]
    assert "hold_margin" not in plain.grasps[0]


def test_suction_frames_follow_the_contract():
    """Origin at the contact, +Z the approach, roll 0's X the object's +X made orthogonal to Z (its +Y when
    |X . Z| > 0.9), X turning towards Y0 = Z x X0 with the roll: as graspgen.transforms.suction_frames gives them."""
    from graspgen.transforms import suction_frames

    rng = np.random.default_rng(3)
    z = rng.normal(size=(40, 3))
    z[:5] = [0.99, 0.1, 0.0]  # the reference switches to the object's +Y
    c = cups(rng.uniform(-0.05, 0.05, (40, 3)), z, rolls=6)
    index = PickIndex.build(c, body_spec())
    f = index.frames.reshape(-1, 4, 3)
    for k in range(len(index)):
        i, r = index.candidate[k], index.roll_index[k]
        zz = c.axes[i]
        ref = np.array([0.0, 1.0, 0.0]) if abs(zz[0]) > 0.9 else np.array([1.0, 0.0, 0.0])
        x0 = ref - (ref @ zz) * zz
        x0 /= np.linalg.norm(x0)
        psi = c.roll_angles_rad[r]
        x = math.cos(psi) * x0 + math.sin(psi) * np.cross(zz, x0)
        assert np.allclose(f[k], [x, np.cross(zz, x), zz, c.contacts[i, 0]], atol=1e-12)
        T = suction_frames(c.contacts[i, 0][None], zz[None], np.array([psi]))[0]
        assert np.array_equal(f[k], T[:3].T)


@pytest.fixture(scope="module")
def box_set():
    """The shipped cup on a 100 x 80 x 30 mm box of 0.2 kg: a real suction run."""
    import trimesh

    mesh = trimesh.creation.box(extents=(0.1, 0.08, 0.03))
    return graspgen.generate(mesh, SPEC, units="m", points=1500, k1=4, k2=2, mass_kg=0.2)


def test_a_suction_run_picks_with_its_own_cup_at_the_exported_poses(box_set):
    """Picking from the run itself: every candidate is a pair (a round tool), the export's grasps come back at their
    poses, the bin floor under the box keeps the cups of the top and the sides high enough, the cone keeps the
    cups from above."""
    res = graspgen.pick(box_set, np.eye(4), limit=1000)
    assert res.considered == len(box_set.candidates) and res.score_source == "hold_margin"
    by_candidate = {g["candidate"]: g for g in res.grasps}
    for g in box_set.grasps:
        assert np.allclose(by_candidate[g["candidate"]]["T_world_grasp"], g["pose"], atol=1e-12)
        assert by_candidate[g["candidate"]]["hold_margin"] == pytest.approx(g["hold_margin"], abs=1e-6)
    # the box lies on a floor 15 mm under its centre; a cup from above at 30 deg at most
    floor = [{"point": [0, 0, -0.015], "normal": [0, 0, 1]}]
    down = {"direction": [0, 0, -1], "max_angle_deg": 30}
    top = graspgen.pick(box_set, np.eye(4), approach=down, planes=floor, limit=1000)
    assert top.feasible > 0 and all(g["position"][2] == pytest.approx(0.015) for g in top.grasps)
    sides = graspgen.pick(box_set, np.eye(4), planes=floor, limit=1000)
    for g in sides.grasps:  # a cup on a side face keeps its rim (15 mm) above the floor
        z = np.array(g["T_world_grasp"])[:3, 2]
        assert g["position"][2] + 0.015 >= SPEC.cup_radius * math.hypot(z[0], z[1]) - 1e-9


def _rim_points(spec: SuctionSpec, samples: int = 720) -> np.ndarray:
    """Points of the cup's and a cylinder tool's rims (their lowest points along any direction lie on them), or the
    cup's rims and the body's vertices: (p, 3), grasp frame."""
    t = 2 * np.pi * np.arange(samples) / samples
    ring = np.column_stack([np.cos(t), np.sin(t), np.zeros(samples)])
    rims = [ring * spec.cup_radius + [0, 0, z] for z in (0.0, -spec.cup_height)]
    if spec.tool is not None:
        h, length, radius = spec.cup_height, spec.tool.length, spec.tool.radius
        rims += [ring * radius + [0, 0, z] for z in (-h, -h - length)]
    else:
        rims.append(np.asarray(spec.geometry.body.vertices))  # type: ignore[union-attr]
    return np.vstack(rims)


def brute_force(c: Cups, spec: SuctionSpec, T_wo, planes, distance):  # type: ignore[no-untyped-def]
    """{(candidate, roll): sampled lowest height over planes}: each pair's solid points moved to the world at the
    grasp and at the pre-grasp (a round tool: roll 0 only)."""
    pts = _rim_points(spec)
    out = {}
    for i in range(len(c.axes)):
        z = c.axes[i]
        ref = np.array([0.0, 1.0, 0.0]) if abs(z[0]) > 0.9 else np.array([1.0, 0.0, 0.0])
        x0 = ref - (ref @ z) * z
        x0 /= np.linalg.norm(x0)
        rolls = [0] if spec.round_tool and c.free_rolls[i].any() else np.flatnonzero(c.free_rolls[i])
        for r in rolls:
            psi = c.roll_angles_rad[r]
            x = math.cos(psi) * x0 + math.sin(psi) * np.cross(z, x0)
            R = np.column_stack([x, np.cross(z, x), z])
            world = (pts @ R.T + c.contacts[i, 0]) @ T_wo[:3, :3].T + T_wo[:3, 3]
            pre = world - distance * (T_wo[:3, :3] @ z)
            low = math.inf
            for p in planes:
                n = np.asarray(p["normal"], dtype=np.float64)
                n = n / np.linalg.norm(n)
                off = n @ np.asarray(p["point"], dtype=np.float64)
                low = min(low, float((world @ n).min() - off), float((pre @ n).min() - off))
            out[(i, int(r))] = low
    return out


@pytest.mark.parametrize("tool", ["cylinder", "body"])
@pytest.mark.parametrize("seed", range(4))
def test_pick_equals_a_brute_force_over_the_rims(tool, seed):
    rng = np.random.default_rng(seed)
    spec = SPEC if tool == "cylinder" else body_spec()
    n = 60
    c = cups(rng.uniform(-0.04, 0.04, (n, 3)), rng.normal(size=(n, 3)), rolls=8, free=rng.random((n, 8)) < 0.6)
    c = replace(c, hold_margin=np.round(rng.uniform(1, 3, n), 1))
    T_wo = np.eye(4)
    T_wo[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    if np.linalg.det(T_wo[:3, :3]) < 0:
        T_wo[:3, 0] *= -1
    T_wo[:3, 3] = [0.4, 0.0, 0.1]
    planes = [
        {"point": [0, 0, 0.02], "normal": [0, 0, 1]},
        {"point": [0.55, 0, 0], "normal": [-1, 0.1, 0]},
        {"point": [0.4, -0.12, 0], "normal": list(rng.normal(size=3) * 0.1 + [0, 1, 0])},
    ]
    low = brute_force(c, spec, T_wo, planes, 0.05)
    sag = spec.cup_radius * (1 - math.cos(math.pi / 720)) + 1e-9  # how far a sampled rim may miss the true lowest
    sure = {k for k, v in low.items() if v >= sag}
    maybe = {k for k, v in low.items() if -1e-9 <= v < sag}
    res = graspgen.pick(c, T_wo, planes=planes, limit=1000, gripper=spec)
    got = {(g["candidate"], g["roll_index"]) for g in res.grasps}
    assert sure <= got <= sure | maybe
    assert 0 < len(sure) < len(low), "the scene should keep some pairs and block others"
    assert res.considered == len(low)
    # best first: hold margin, then the candidate and roll (no cone: every approach angle is 0)
    keys = [(-g["hold_margin"], g["candidate"], g["roll_index"]) for g in res.grasps]
    assert keys == sorted(keys)


def test_a_suction_set_needs_its_cup_and_one_contact_per_candidate():
    c = cups([(0, 0, 0.02)], [(0, 0, -1)])
    with pytest.raises(InvalidParameterError) as e:
        graspgen.pick(c, np.eye(4))
    assert e.value.field == "gripper"
    two = replace(c, contacts=np.zeros((1, 2, 3)))
    with pytest.raises(InvalidParameterError, match="one contact each"):
        graspgen.pick(two, np.eye(4), gripper=SPEC)
