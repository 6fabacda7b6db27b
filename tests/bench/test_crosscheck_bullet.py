"""Known answers of the PyBullet judge (bench/crosscheck_bullet.py), the second simulator of bench_crosscheck.py.

Boxes held by the PGN-80 (20 x 30 mm pads, 20 N per finger, friction 0.5) in the grasp frame (origin at the contact
midpoint, +X closing, +Z approach, palm at -Z): a cube held across its middle stays put; a long bar held 10 mm from
one end turns out of the pads (the pads' torsional friction is far below its weight's moment); held at its middle it
holds, by friction up to 2 mu F = 20 N and no further; a grasp whose pads would start inside the part collides.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pybullet", reason="pybullet is not installed (a dev dependency: pip install -c constraints.txt)")

import trimesh  # noqa: E402

from graspgen import physics  # noqa: E402
from graspgen.gripper import GripperSpec  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def _load_judge():
    if "crosscheck_bullet" in sys.modules:
        return sys.modules["crosscheck_bullet"]
    spec = importlib.util.spec_from_file_location("crosscheck_bullet", ROOT / "bench" / "crosscheck_bullet.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["crosscheck_bullet"] = module
    spec.loader.exec_module(module)
    return module


cb = _load_judge()


@pytest.fixture(scope="module")
def gripper() -> GripperSpec:
    return GripperSpec.from_dict(json.loads((ROOT / "examples" / "pgn-80.json").read_text()))


def grasp(midpoint) -> np.ndarray:
    """T_object_grasp with the grasp frame's axes along the object's: closing along X, approach along +Z."""
    T = np.eye(4)
    T[:3, 3] = midpoint
    return T


def judge(mesh, gripper, mass, T, width, perturbation=None):
    part = cb.prepare_part(mesh, gripper, mass_kg=mass, grip_force=20.0, friction=0.5)
    assert part.geometry == "convex"
    with cb.BulletJudge(part) as j:
        return j.simulate(T, width, perturbation)


CUBE = (0.04, 0.04, 0.04)
BAR = (0.02, 0.3, 0.02)  # 300 mm along Y, closed across its 20 mm along X
#: the palm's face is at z = -15 mm of the grasp frame: a cube centred 6 mm above the contact midpoint clears it
CUBE_GRASP = (0.0, 0.0, -0.006)


def test_cube_held_across_its_middle_stays_put(gripper):
    r = judge(trimesh.creation.box(CUBE), gripper, 0.2, grasp(CUBE_GRASP), 0.04)
    assert r.success and r.reason is None, r
    assert r.contacts >= 8  # a face on each pad: a contact polygon (four corners each), not a point
    assert r.slip_mm < 0.5 and r.rotation_deg < 1.0, r  # at rest, lifted and shaken: it does not creep
    assert r.max_penetration_mm < 0.5, r


def test_bar_held_near_one_end_turns_out(gripper):
    # the weight's moment about the closing axis, 0.5 kg x 9.81 x 0.14 m = 0.69 N m, is several times what friction
    # on the pads' 20 x 20 mm patches resists (2 x 0.5 x 20 N x ~14 mm at most)
    r = judge(trimesh.creation.box(BAR), gripper, 0.5, grasp((0.0, 0.14, 0.0)), 0.02)
    assert not r.success and r.reason in ("slipped", "dropped"), r
    assert r.rotation_deg > 10.0, r


def test_bar_held_at_its_middle_holds(gripper):
    r = judge(trimesh.creation.box(BAR), gripper, 0.5, grasp((0.0, 0.0, 0.0)), 0.02)
    assert r.success, r
    assert r.slip_mm < 0.5 and r.rotation_deg < 1.0, r


@pytest.mark.parametrize(("mass", "held"), [(1.0, True), (2.0, False)])
def test_friction_carries_up_to_two_mu_f(gripper, mass, held):
    # lifted at 9.81 + 3 m/s^2, the bar at its middle loads the pads with 12.8 N (1 kg) or 25.6 N (2 kg) along Z,
    # against 2 x 0.5 x 20 N = 20 N of friction
    r = judge(trimesh.creation.box(BAR), gripper, mass, grasp((0.0, 0.0, 0.0)), 0.02)
    assert r.success is held, r


def test_pads_starting_inside_the_part_collide(gripper):
    # a contact distance of 10 mm opens the pads to 30 mm (10 + 20 mm clearance): 5 mm inside the 40 mm cube
    r = judge(trimesh.creation.box(CUBE), gripper, 0.2, grasp(CUBE_GRASP), 0.01)
    assert r.reason == "collision" and r.start_penetration_mm > 4.0, r


def test_perturbations_run_in_order(gripper):
    part = cb.prepare_part(trimesh.creation.box(CUBE), gripper, mass_kg=0.2, grip_force=20.0, friction=0.5)
    members = [physics.NOMINAL, physics.Perturbation("gravity -Y", gravity=(0.0, -1.0, 0.0))]
    with cb.BulletJudge(part) as j:
        out = j.simulate_members(grasp(CUBE_GRASP), 0.04, members)
    assert [r.member for r in out] == ["nominal", "gravity -Y"]
    assert all(r.success for r in out), out
