"""MuJoCo validation of suction grasps on parts whose outcome is known: a plate held at its centre, a vacuum too weak
for the weight, peel at the end of a long bar, friction on a vertical face, no seal over holes, edges and tight
spheres; the perturbation set, determinism and bad input."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from graspgen import physics
from graspgen import physics_suction as ps
from graspgen.errors import InvalidParameterError
from graspgen.gripper import GripperSpec
from graspgen.parts import load_part
from graspgen.suction import SUCTION
from tests.grippers import CUP as EXAMPLE_CUP
from tests.parts import notched_plate

#: the contract's example cup: 30 mm, 60 kPa (V = 42.4 N), mu 0.5, 10 % stretch
CUP = ps.SuctionCup(cup_radius=0.015, cup_height=0.02, vacuum=60_000.0, friction=0.5, max_strain=0.1)
ALL = (ps.SUCTION_NOMINAL, *ps.suction_perturbation_set(0))


def frame(contact, approach) -> np.ndarray:
    """T_object_grasp of a cup touching `contact` (m) with +Z along `approach` (into the part)."""
    z = np.asarray(approach, dtype=float)
    z /= np.linalg.norm(z)
    x = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x -= (x @ z) * z
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, contact
    return T


def cup(**changes: float) -> ps.SuctionCup:
    values = {k: getattr(CUP, k) for k in ("cup_radius", "cup_height", "vacuum", "friction", "max_strain")}
    return ps.SuctionCup(**{**values, **changes})


PLATE = trimesh.creation.box(extents=(0.1, 0.1, 0.01))
TOP = frame([0.0, 0.0, 0.005], [0.0, 0.0, -1.0])


def test_a_flat_plate_is_held_at_its_centre_under_every_perturbation():
    (row,) = ps.simulate_suction(PLATE, TOP[None], CUP, mass_kg=0.2, perturbations=ALL, workers=2)
    assert [r.member for r in row] == [p.name for p in ALL]
    assert all(r.success and r.reason is None for r in row), [r.to_json() for r in row if not r.success]
    assert all(r.lips == ps.SUCTION_SIM.lips for r in row)  # every lip point touches once sealed
    assert max(r.slip_mm for r in row) < 1.0 and max(r.peak_gap_mm for r in row) < 0.5
    assert ps.held([row]).tolist() == [True]
    summary = ps.summarise_suction(row)
    assert summary["tested"] == len(ALL) and summary["success_rate"] == 1.0
    assert summary["failures"] == {"no_seal": 0, "dropped": 0, "slipped": 0}


@pytest.mark.parametrize(("vacuum", "held"), [(2_000.0, False), (20_000.0, True)])
def test_the_plate_drops_when_the_vacuum_force_is_below_its_weight(vacuum, held):
    # V = vacuum x pi r^2: 1.41 N against the 0.2 kg plate's 1.96 N (2.6 N during the lift) drops it; 14.1 N holds
    (row,) = ps.simulate_suction(PLATE, TOP[None], cup(vacuum=vacuum), mass_kg=0.2)
    (r,) = row
    assert r.success is held
    if not held:
        assert r.reason == "dropped" and "seal broke" in (r.detail or "")
        assert r.time_s < 0.5  # during the lift, not after it


def test_a_heavy_bar_peels_off_a_cup_near_its_end_and_is_held_at_its_middle():
    # 1 kg, 300 mm: at 130 mm from the centre of mass the weight's moment (1.3 N m at the lift) is far beyond the
    # lip's (about half V r = 0.32 N m); at the middle there is no moment and 42 N pull against 13 N
    bar = trimesh.creation.box(extents=(0.3, 0.04, 0.02))
    poses = np.array([frame([x, 0.0, 0.01], [0.0, 0.0, -1.0]) for x in (0.0, 0.13)])
    middle, end = ps.simulate_suction(bar, poses, CUP, mass_kg=1.0, perturbations=ALL, workers=2)
    assert all(r.success for r in middle), [r.to_json() for r in middle if not r.success]
    assert all(r.reason == "dropped" for r in end)
    # it peels: the lip point farthest from the bar's centre opens (lip 8 sits at -X, away from the centre of mass)
    assert all(r.detail is not None and r.detail.startswith("lip point 8 ") for r in end)
    assert all(r.rotation_deg > 3.0 for r in end)  # the bar tilted on the lip before the seal broke


@pytest.mark.parametrize(("friction", "held"), [(0.1, False), (0.8, True)])
def test_friction_decides_a_cup_on_a_vertical_face(friction, held):
    # the robot turns the 1 kg plate until gravity lies along its face: friction mu (V - pull) against 9.81 N and
    # the shakes; 0.1 x 42 N = 4.2 N slides, 0.8 x 42 N = 34 N holds
    side = ps.SuctionPerturbation("gravity +X", gravity=(1.0, 0.0, 0.0))
    (row,) = ps.simulate_suction(PLATE, TOP[None], cup(friction=friction), mass_kg=1.0, perturbations=[side])
    (r,) = row
    assert r.success is held
    if not held:
        assert r.reason == "slipped" and r.slip_mm > physics.SIM.slip_limit * 1e3
        assert r.peak_gap_mm < ps.SUCTION_SIM.gap_limit * 1e3  # the seal held while the part slid


def test_a_perturbation_replaces_the_cups_friction():
    side = ps.SuctionPerturbation("gravity +X, friction 0.1", gravity=(1.0, 0.0, 0.0), friction=0.1)
    (row,) = ps.simulate_suction(PLATE, TOP[None], cup(friction=0.8), mass_kg=1.0, perturbations=[side])
    assert row[0].reason == "slipped"


@pytest.mark.parametrize(
    ("mesh", "contact", "detail"),
    [
        # a 40 mm hole under a 30 mm cup: the lip ring meets nothing
        (trimesh.creation.annulus(0.02, 0.05, 0.01), (0.0, 0.0, 0.005), "misses the surface at 64 of 64"),
        # a 5 mm hole inside the ring: the ring seals, the vacuum leaks through the hole
        (trimesh.creation.annulus(0.0025, 0.05, 0.01), (0.0, 0.0, 0.005), "pass through the part"),
        # 5 mm from the plate's edge: a third of the ring hangs over it
        (PLATE, (0.045, 0.0, 0.005), "misses the surface"),
        # a sphere of 16 mm radius: the 15 mm ring lies 10 mm below the top, its cone springs would stretch by 35 %
        (trimesh.creation.icosphere(4, 0.016), (0.0, 0.0, 0.016), "springs would strain"),
    ],
    ids=["hole-40mm", "hole-5mm", "across-an-edge", "sphere-16mm"],
)
def test_no_seal_over_a_hole_across_an_edge_or_on_a_tight_sphere(mesh, contact, detail):
    (row,) = ps.simulate_suction(mesh, frame(contact, (0.0, 0.0, -1.0))[None], CUP, mass_kg=0.2, perturbations=ALL)
    assert all(r.reason == "no_seal" and not r.success and r.lips == 0 for r in row)
    assert detail in (row[0].detail or "")


def test_a_sphere_much_larger_than_the_cup_seals_and_holds():
    ball = trimesh.creation.icosphere(4, 0.05)
    (row,) = ps.simulate_suction(ball, frame((0.0, 0.0, 0.05), (0.0, 0.0, -1.0))[None], CUP, mass_kg=0.2)
    assert row[0].success and 0.0 < row[0].strain < CUP.max_strain


def cone_strain(depth: float, cup: ps.SuctionCup = CUP) -> float:
    """The strain of a cone spring, mount `cup_height` behind the contact, to a lip point `depth` below it."""
    r, h = cup.cup_radius, cup.cup_height
    return math.hypot(r, h + depth) / math.hypot(r, h) - 1.0


def lying_cylinder(radius: float) -> trimesh.Trimesh:
    """A 100 mm cylinder along X, its top line at z = radius."""
    turn = trimesh.transformations.rotation_matrix(math.pi / 2, (0.0, 1.0, 0.0))
    return trimesh.creation.cylinder(radius=radius, height=0.1, sections=256, transform=turn)


@pytest.mark.parametrize(("radius", "seals"), [(0.02, False), (0.06, True)])
def test_on_a_cylinder_the_cups_cone_springs_decide_the_seal(radius, seals):
    # the lip's sides lie R - sqrt(R^2 - r^2) below the top line: 6.8 mm on a 20 mm cylinder, where the cone springs
    # from the mount 20 mm behind the contact stretch by 22.7 %; 1.9 mm on a 60 mm one (6.2 %). Measured from the
    # contact alone (no cup height) the 20 mm cylinder's lip would stretch 9.8 % and seal
    depth = radius - math.sqrt(radius**2 - CUP.cup_radius**2)
    (row,) = ps.simulate_suction(
        lying_cylinder(radius), frame((0.0, 0.0, radius), (0.0, 0.0, -1.0))[None], CUP, mass_kg=0.2, perturbations=ALL
    )
    assert all(r.success is seals for r in row)
    # the placement error (0.2 mm, 0.2 degrees) moves the lip across the cylinder: 0.8 % more on the 20 mm one
    assert row[0].strain == pytest.approx(cone_strain(depth), abs=0.01)
    if not seals:
        assert all(r.reason == "no_seal" for r in row) and "springs would strain" in (row[0].detail or "")


def test_a_step_under_the_lip_breaks_the_seal_where_the_whole_ring_would_not():
    # a plate with a 3 mm step 5 mm beside the contact: the ring crosses it twice. The cone springs to the lower side
    # stretch 9.8 %, within max_strain, and the whole ring's perimeter by 4 %; the perimeter spring across the step
    # (a chord of the 32-gon lip, c0 = 2.94 mm) by sqrt(1 + (3 / c0)^2) - 1 = 43 %
    lower = trimesh.creation.box(extents=(0.1, 0.1, 0.01))
    upper = trimesh.creation.box(extents=(0.055, 0.1, 0.003))
    upper.apply_translation((0.005 - 0.0275, 0.0, 0.0065))
    step = trimesh.util.concatenate([lower, upper])
    assert cone_strain(0.003) < CUP.max_strain
    (row,) = ps.simulate_suction(step, frame((0.0, 0.0, 0.008), (0.0, 0.0, -1.0))[None], CUP, mass_kg=0.2)
    c0 = 2 * CUP.cup_radius * math.sin(math.pi / ps.SUCTION_SIM.perimeter_springs)
    assert row[0].reason == "no_seal" and row[0].strain == pytest.approx(math.hypot(1.0, 0.003 / c0) - 1.0, abs=0.01)
    # the same plate without the step seals
    (flat,) = ps.simulate_suction(lower, TOP[None], CUP, mass_kg=0.2)
    assert flat[0].success and flat[0].strain < 0.01


@pytest.mark.parametrize(("depth_mm", "seals"), [(2.0, False), (1.2, False), (0.8, True)])
def test_a_groove_crossing_under_the_lip_is_a_leak_the_lip_does_not_bridge(depth_mm, seals):
    # the groove (0.6 mm wide) crosses the lip at 5.6 degrees: one of the 64 rays falls into it, between the ends of
    # a perimeter spring; deeper than both by more than the gap limit (1 mm) it leaks
    plate = notched_plate(depth_mm)
    top = depth_mm * 1e-3
    (row,) = ps.simulate_suction(plate, frame((0.0, 0.0, top), (0.0, 0.0, -1.0))[None], CUP, mass_kg=0.2)
    assert row[0].success is seals
    if not seals:
        assert row[0].reason == "no_seal" and "slot or pit crosses under the lip at 1 of 64" in (row[0].detail or "")
    (away,) = ps.simulate_suction(plate, frame((-0.02, 0.0, top), (0.0, 0.0, -1.0))[None], CUP, mass_kg=0.2)
    assert away[0].success


def test_the_seal_is_found_on_the_triangles_after_the_placement_error():
    part = ps.prepare_suction_part(PLATE, mass_kg=0.2)
    seal = ps.seal_at(part, TOP, CUP, seed=0, key=3)
    assert seal.ok and seal.detail is None
    assert seal.lip_points.shape == (ps.SUCTION_SIM.lips, 3) and np.allclose(seal.lip_points[:, 2], 0.005)
    assert np.allclose(seal.lip_normals, [0.0, 0.0, 1.0])  # towards the cup
    # the placement error (<= 0.2 mm, 0.2 deg) tilts the ring by a little: lip heights within 0.3 mm of the plane
    assert np.all(np.abs(seal.lip_z) < 3e-4)
    again = ps.seal_at(part, TOP, CUP, seed=0, key=3)
    assert np.array_equal(seal.lip_z, again.lip_z)
    other = ps.seal_at(part, TOP, CUP, seed=0, key=4)
    assert not np.array_equal(seal.lip_z, other.lip_z)


def test_results_do_not_depend_on_threads_or_on_what_else_runs():
    poses = np.array([TOP, frame([0.02, 0.01, 0.005], [0.0, 0.0, -1.0])])
    members = ALL[:3]
    one = ps.simulate_suction(PLATE, poses, CUP, mass_kg=0.2, perturbations=members, workers=1)
    two = ps.simulate_suction(PLATE, poses, CUP, mass_kg=0.2, perturbations=members, workers=2)
    assert one == two
    alone = ps.simulate_suction(PLATE, poses[1:], CUP, mass_kg=0.2, perturbations=members, keys=np.array([1]))
    assert alone[0] == one[1]


def test_a_suction_spec_or_any_object_with_the_fields_is_a_cup_and_a_jaw_simpart_is_a_part():
    spec = SimpleNamespace(name="cup-30", kind="suction", cup_radius=0.015, cup_height=0.02, max_strain=0.1,
                           vacuum=60_000.0, friction=0.5, pregrasp_clearance=0.03)  # fmt: skip
    assert ps.SuctionCup.of(spec) == CUP
    jaw = GripperSpec.from_dict(
        {"name": "g", "stroke": 0.08, "finger_width": 0.02, "finger_depth": 0.03, "finger_thickness": 0.01,
         "friction": 0.5, "pregrasp_clearance": 0.02, "grip_force": 20.0}
    )  # fmt: skip
    sim = physics.prepare_part(PLATE, jaw, mass_kg=0.2)
    (row,) = ps.simulate_suction(sim, TOP[None], spec)
    assert row[0].success
    # mass_kg rescales a prepared part: 0.2 kg held, 50 kg not
    (heavy,) = ps.simulate_suction(sim, TOP[None], spec, mass_kg=50.0)
    assert heavy[0].reason == "dropped"


def test_the_simulation_and_criterion_seal_model_one_cup():
    # the simulation shares no code with the criteria, so the cup model's lip polygon is declared in both: the
    # perimeter springs' rest length decides which steps seal, and the two must judge the same cup
    assert ps.SUCTION_SIM.perimeter_springs == SUCTION.lip_points


def test_the_perturbation_set():
    members = ps.suction_perturbation_set(0)
    assert len(members) == 12 and len({p.name for p in members}) == 12
    by_name = {p.name: p for p in members}
    assert by_name["mass x0.5"].mass_scale == 0.5 and by_name["mass x1.5"].mass_scale == 1.5
    assert by_name["vacuum x0.7"].vacuum_scale == 0.7
    assert by_name["friction 0.3"].friction == 0.3 and by_name["friction 0.6"].friction == 0.6
    gravities = {p.gravity for p in members if p.name.startswith("gravity")}
    assert gravities == {(0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0)}
    mixed = members[-1]
    assert 0.5 <= mixed.mass_scale <= 1.5 and 0.7 <= mixed.vacuum_scale <= 1.0
    assert mixed.friction is not None and 0.3 <= mixed.friction <= 0.6
    for u in mixed.shake_directions or ():
        assert abs(float(np.dot(u, mixed.gravity))) < 1e-9  # the shake is across gravity
    assert ps.suction_perturbation_set(0) == members and ps.suction_perturbation_set(1) != members
    with pytest.raises(InvalidParameterError):
        ps.SuctionPerturbation(vacuum_scale=0.0)
    assert ps.SuctionPerturbation(gravity=(0.0, 0.0, 2.0)).gravity == (0.0, 0.0, 1.0)  # Perturbation's checks


def test_bad_input_is_refused():
    with pytest.raises(InvalidParameterError, match="mass_kg"):
        ps.simulate_suction(PLATE, TOP[None], CUP)
    with pytest.raises(InvalidParameterError, match="poses"):
        ps.simulate_suction(PLATE, TOP, CUP, mass_kg=0.2)
    with pytest.raises(InvalidParameterError, match="vacuum"):
        cup(vacuum=-1.0)
    with pytest.raises(InvalidParameterError, match="max_strain"):
        ps.SuctionCup.of(SimpleNamespace(cup_radius=0.015, cup_height=0.02, vacuum=6e4, friction=0.5))
    with pytest.raises(InvalidParameterError, match="multiple"):
        ps.SuctionSimConstants(lips=16, ring_rays=60)
    with pytest.raises(InvalidParameterError, match="perimeter_springs"):
        ps.SuctionSimConstants(perimeter_springs=24)
    assert ps.simulate_suction(PLATE, np.zeros((0, 4, 4)), CUP, mass_kg=0.2) == []


def test_a_scanned_box_is_held_on_its_largest_face(shared_meshes):
    """The YCB sugar box (a scan: not closed, its faces a little uneven): a cup in the middle of a broad face."""
    units = json.loads((shared_meshes / "units.json").read_text())
    mesh = load_part(shared_meshes / "ycb_sugar_box.obj", units=units["ycb_sugar_box.obj"]).mesh
    obb = mesh.bounding_box_oriented
    axis = obb.primitive.transform[:3, int(np.argmin(obb.primitive.extents))]
    centre = obb.primitive.transform[:3, 3]
    start = centre + axis * 0.2
    hit, _, _ = mesh.ray.intersects_location(start[None], -axis[None])
    contact = hit[np.argmin(np.linalg.norm(hit - start, axis=1))]
    (row,) = ps.simulate_suction(mesh, frame(contact, -axis)[None], CUP, mass_kg=0.2, perturbations=ALL[:4])
    assert all(r.success for r in row), [r.to_json() for r in row]
    assert math.isfinite(row[0].strain) and row[0].strain < CUP.max_strain


# -- generate(validate=True) for a suction cup -------------------------------------------------------------------------
BAR = trimesh.creation.box((0.3, 0.04, 0.02))


def test_validate_simulates_each_exported_cup_and_repairs_one_the_simulation_drops():
    """A 300 mm bar of 0.3 kg with criterion hold off: cups far from the middle peel off in the simulation, cups near
    it hold. validate simulates every exported cup under suction_validation_set, replaces one that fails by the
    nearest member of its cluster that holds, puts each outcome in the grasp (`sim`) and counts them."""
    import graspgen

    run = {"units": "m", "points": 600, "mass_kg": 0.3, "hold": "off", "k1": 4, "k2": 1, "repair_limit": 8}
    gs = graspgen.generate(BAR, dict(EXAMPLE_CUP), validate=True, **run)
    v = gs.stats["validation"]
    assert v["members"] == [p.name for p in ps.suction_validation_set(0.5)]
    assert v["tested"] == len(gs.grasps) == 4 and v["succeeded"] == sum(g["sim"]["success"] for g in gs.grasps)
    assert v["first_pass"]["succeeded"] < v["first_pass"]["tested"] and v["repaired"] >= 1
    assert v["succeeded"] == v["first_pass"]["succeeded"] + v["repaired"]
    x = np.array([abs(g["contacts"][0][0]) for g in gs.grasps])
    ok = np.array([g["sim"]["success"] for g in gs.grasps])
    assert ok.any() and (~ok).any() and x[ok].max() < x[~ok].min()  # peel: the held cups are the middle ones
    medoids = set(gs.candidates.medoids.tolist())
    labels = gs.candidates.labels
    for g in gs.grasps:  # a repaired grasp is a member of its own cluster
        assert g["candidate"] in medoids and tuple(labels[g["candidate"]]) == tuple(g["cluster"])
    # with criterion hold on, every cup it exports also holds in the simulation
    held = graspgen.generate(BAR, dict(EXAMPLE_CUP), units="m", points=800, mass_kg=0.3, k1=4, k2=1, validate=True)
    assert held.grasps and all(g["sim"]["success"] for g in held.grasps)
    assert held.stats["validation"]["repaired"] == 0


def test_validate_needs_the_mass_and_a_suction_sets_clustering_cannot_validate(tmp_path):
    import graspgen

    with pytest.raises(InvalidParameterError) as e:
        graspgen.generate(BAR, dict(EXAMPLE_CUP), units="m", points=300, validate=True)
    assert e.value.field == "mass_kg"
    gs = graspgen.generate(BAR, dict(EXAMPLE_CUP), units="m", points=400, mass_kg=0.2, k1=2, k2=1)
    gs.save_candidates(tmp_path / "c.npz")
    with pytest.raises(InvalidParameterError) as e:
        graspgen.recluster(tmp_path / "c.npz", gs.to_json(), k1=2, k2=1, validate=True)
    assert e.value.field == "validate" and "generate it again" in str(e.value)
