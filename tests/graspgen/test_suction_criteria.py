"""Suction criteria with known answers (CONTRACT.md "Suction cups", docs/HOLD.md "Suction cups: the model"): seal on
plates, rods, spheres, holes, edges and steps; hold on a bar and on a face; collision of a tool beside a wall; the
hold margins against a brute-force evaluation of the same model."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

import graspgen
from graspgen import InvalidMeshError, InvalidParameterError, SuctionSpec
from graspgen.example_grippers import box, prism, stl_bytes
from graspgen.suction import SUCTION, judge_cups
from tests.grippers import CUP
from tests.parts import notched_plate

SPEC = SuctionSpec.from_dict(CUP)
DOWN = (0.0, 0.0, -1.0)


def _mesh(solid: tuple[np.ndarray, np.ndarray], scale: float = 1e-3) -> trimesh.Trimesh:
    v, f = solid
    return trimesh.Trimesh(np.asarray(v) * scale, f, process=False)


def _profile(xz: list[tuple[float, float]], y0: float, y1: float) -> trimesh.Trimesh:
    """A closed prism, mm -> m: the counter-clockwise polygon `xz` in the x-z plane extruded from y0 to y1 (prism's
    plane for axis 1 is (z, x): the coordinates swapped, so the order reversed)."""
    return _mesh(prism([(z, x) for x, z in reversed(xz)], y0, y1, axis=1))


def _judge(mesh, points, approach, spec=SPEC, **kw):
    return judge_cups(mesh, spec, np.atleast_2d(points), np.atleast_2d(approach), **kw)


def test_flat_plate_seals_and_holds_at_its_centre():
    plate = trimesh.creation.box((0.1, 0.1, 0.01))
    j = _judge(plate, (0, 0, 0.005), DOWN, mass_kg=0.2)
    assert j.seal[0] == "pass" and j.seal_strain[0] == pytest.approx(0.0, abs=1e-12)
    assert j.tilt_deg[0] == pytest.approx(0.0, abs=1e-9)
    assert j.hold_margin is not None and j.hold_margin[0] > 1 and j.free_rolls[0].all()
    # the whole run: grasps on the plate's two large faces, away from their edges
    gs = graspgen.generate(plate, SPEC, units="m", points=1500, mass_kg=0.2, k1=4, k2=2)
    assert gs.to_json()["gripper"]["kind"] == "suction" and gs.grasps
    c = gs.candidates.contacts[:, 0]
    assert np.all(np.abs(c[:, 2]) == pytest.approx(0.005))  # never on the 10 mm sides
    assert np.all(np.max(np.abs(c[:, :2]), axis=1) <= 0.05 - 0.015 + 1e-9)  # the lip stays on the face


def test_rod_thinner_than_the_cup_does_not_seal():
    rod = trimesh.creation.cylinder(radius=0.005, height=0.1, sections=64)
    j = _judge(rod, (0.005, 0, 0), (-1, 0, 0))
    assert j.seal[0] == "reach"
    gs = graspgen.generate(rod, SPEC, units="m", points=800)
    assert not gs.grasps and gs.stats["empty_reason"]["criterion"] == "seal"
    assert "smaller cup" in gs.stats["empty_reason"]["message"]


def test_sphere_close_to_the_cup_radius_does_not_seal_and_a_large_one_does():
    near = trimesh.creation.icosphere(subdivisions=5, radius=0.016)
    # the lip would land 10 mm down a steep flank: beyond its cone springs' reach
    assert _judge(near, (0, 0, 0.016), DOWN).seal[0] in ("reach", "depth")
    large = trimesh.creation.icosphere(subdivisions=5, radius=0.1)
    j = _judge(large, (0, 0, 0.1), DOWN)
    assert j.seal[0] == "pass" and 0 < j.seal_strain[0] < 0.1


@pytest.mark.parametrize("sections", [64, 128])
def test_a_lip_probe_on_an_edge_between_two_triangles_meets_the_face(sections):
    """A revolved part has a seam under every 2 pi / sections: with the cup on the axis, the lip's 32 probes lie
    exactly on seams. Each probe must meet the face (closed triangles, within a band beyond rounding), not fall
    between the seam's two triangles to nothing (which reads as the lip running off the part). The part: a conical
    roof falling 0.16 mm per mm (9 degrees) from a boss 4.5 mm in radius, 1.2 mm high; the lip lands 2.9 mm below
    the contact, within the cone springs' reach."""
    roof = [(0.0, 0.0), (40.0, 0.0), (40.0, 20.0 - 40 * 0.16), (4.5, 20.0 - 4.5 * 0.16), (4.5, 20.5), (0.0, 20.5)]
    part = trimesh.creation.revolve(np.array(roof) * 1e-3, sections=sections)
    assert part.is_watertight
    j = _judge(part, (0, 0, 0.0205), DOWN, position_tolerance=0.0)
    assert j.seal[0] == "pass" and j.seal_strain[0] < 0.1


@pytest.mark.parametrize(("depth_mm", "seal"), [(2.0, "hole"), (1.2, "hole"), (0.8, "pass")])
def test_a_groove_crossing_under_the_lip_between_its_points_is_a_leak(depth_mm, seal):
    # a groove 0.6 mm wide crossing under the lip leaks when deeper than recess_depth (1 mm), the lip's thickness
    plate = notched_plate(depth_mm)
    top = depth_mm * 1e-3
    assert _judge(plate, (0, 0, top), DOWN, position_tolerance=0.0).seal[0] == seal
    # moved away along -x, the groove lies outside the lip: a seal
    j = _judge(plate, (-0.02, 0, top), DOWN, position_tolerance=0.0)
    assert j.seal[0] == "pass" and j.seal_strain[0] == pytest.approx(0.0, abs=1e-12)


def test_a_5mm_hole_between_the_samples_is_found():
    washer = trimesh.creation.annulus(r_min=0.0025, r_max=0.05, height=0.01, sections=96)
    assert washer.is_watertight
    # a cup whose contact lies 6 mm beside the hole: the contact is on the face, the hole under the cup
    j = _judge(washer, (0.006, 0, 0.005), DOWN)
    assert j.seal[0] == "hole"
    j = _judge(washer, (0.03, 0, 0.005), DOWN)  # the hole outside the lip
    assert j.seal[0] == "pass"
    # sampled sparsely, the hole falls between the samples; no exported candidate covers it
    gs = graspgen.generate(washer, SPEC, units="m", points=400)
    assert gs.stats["spacing_mean"] > 0.005 and gs.stats["seal"]["hole"] > 0
    c = gs.candidates.contacts[:, 0]
    assert len(c) and np.all(np.hypot(c[:, 0], c[:, 1]) > 0.015 - 0.0025)


def test_across_an_edge_or_a_step_the_seal_fails():
    block = trimesh.creation.box((0.1, 0.1, 0.04))
    assert _judge(block, (0.045, 0, 0.02), DOWN).seal[0] == "reach"  # 5 mm from the edge
    assert _judge(block, (0.03, 0, 0.02), DOWN).seal[0] == "pass"  # 20 mm from it
    # a 3 mm step across the top (an L profile in x-z, extruded along y), the cup centred 2 mm from the riser
    step = _profile([(-50, 0), (50, 0), (50, 20), (0, 20), (0, 23), (-50, 23)], -50, 50)
    assert step.is_watertight and step.volume > 0
    j = _judge(step, (0.002, 0, 0.02), DOWN)
    assert j.seal[0] in ("stretch", "depth")
    assert _judge(step, (0.03, 0, 0.02), DOWN).seal[0] == "pass"


def test_a_bar_peels_near_its_end_and_holds_in_the_middle():
    bar = trimesh.creation.box((0.3, 0.04, 0.02))  # 40 mm wide: the 30 mm cup fits across
    pts = [(0.0, 0, 0.01), (0.13, 0, 0.01)]
    j = _judge(bar, pts, [DOWN, DOWN], mass_kg=0.2)
    assert all(j.seal == "pass") and j.hold_margin is not None and j.hold_limit is not None
    assert j.hold_margin[0] > 1 and j.hold_margin[1] < 1
    assert j.hold_limit[1] == "peel"
    gs = graspgen.generate(bar, SPEC, units="m", points=1500, mass_kg=0.2)
    x = np.abs(gs.candidates.contacts[:, 0, 0])
    assert gs.stats["rejected"]["hold"] > 0 and len(x) and x.max() < 0.13


def test_friction_decides_on_a_vertical_face():
    # a plate standing on its edge, the cup on its broad face: the centre of mass 5 mm behind the contact
    plate = trimesh.creation.box((0.01, 0.1, 0.1))
    mass, mu = 1.0, SPEC.friction
    j = _judge(plate, (0.005, 0, 0), (-1, 0, 0), mass_kg=mass)
    load = 1.5 * mass * (9.81 + 9.81)
    expected = mu * SPEC.vacuum_force / (load * math.sqrt(1 + mu * mu))
    assert j.hold_limit is not None and j.hold_limit[0] == "friction"
    assert j.hold_margin is not None and j.hold_margin[0] == pytest.approx(expected, rel=1e-9) and expected < 1
    assert SPEC.vacuum_force / load > 1  # the pull alone would hold: friction decides
    grippy = _judge(plate, (0.005, 0, 0), (-1, 0, 0), mass_kg=mass, friction=1.5).hold_margin
    assert grippy is not None and grippy[0] > 1


def _wall_part() -> trimesh.Trimesh:
    """A floor 100 x 60 x 10 mm (top at z = 0) with a wall x in [20, 30] mm rising 80 mm above it."""
    return _profile([(-50, -10), (50, -10), (50, 0), (30, 0), (30, 80), (20, 80), (20, 0), (-50, 0)], -30, 30)


def test_a_tool_that_meets_a_wall_beside_the_contact_fails_collision():
    part = _wall_part()
    assert part.is_watertight
    slim = _judge(part, (0, 0, 0), DOWN)
    assert slim.seal[0] == "pass" and slim.free_rolls[0].all()
    wide = _judge(part, (0, 0, 0), DOWN, spec=SuctionSpec.from_dict({**CUP, "tool": {"radius": 0.025, "length": 0.1}}))
    assert wide.seal[0] == "pass" and not wide.free_rolls[0].any()
    # a housing that reaches 25 mm towards +X only: free where it points away from the wall
    housing = box((-12, -12, -140), (25, 12, -20))
    spec = SuctionSpec.from_dict(
        {k: v for k, v in CUP.items() if k != "tool"} | {"geometry": {"units": "mm", "body": "body.stl"}},
        files={"body.stl": stl_bytes(housing)},
    )
    j = _judge(part, (0, 0, 0), DOWN, spec=spec)
    free = j.free_rolls[0]
    assert free.any() and not free.all()
    # roll 0 turns the housing's +X towards the object's +X (the wall): blocked; half a turn away: free
    assert not free[0] and free[8]


def test_tilted_approaches_and_criterion_tilt():
    plate = trimesh.creation.box((0.1, 0.1, 0.01))
    tilt10 = (math.sin(math.radians(10)), 0.0, -math.cos(math.radians(10)))
    j = _judge(plate, [(0, 0, 0.005), (0, 0, 0.005)], [tilt10, (math.sin(math.radians(20)), 0, -math.cos(0.349))])
    assert j.seal[0] == "pass" and j.tilt_deg[0] == pytest.approx(10.0, abs=1e-6)
    assert j.seal[1] in ("reach", "depth")  # 20 deg strains the cone springs beyond 10 %
    gs = graspgen.generate(plate, SPEC, units="m", points=600, max_tilt_deg=10)
    n = gs.stats["points"]
    assert gs.stats["candidates_total"] == n * (1 + SUCTION.tilt_azimuths)
    assert gs.to_json()["params"]["max_tilt_deg"] == 10
    assert np.max(gs.candidates.tilt_deg) == pytest.approx(10.0, abs=1e-6)
    strict = graspgen.generate(plate, SPEC, units="m", points=600, max_tilt_deg=5)
    assert strict.stats["rejected"]["tilt"] == 0  # the 5 deg cone's approaches lie within 5 deg of the face


def _brute_margin(c, a, com, spec, load, mu, directions):
    """The hold model evaluated directly: for every load direction the largest scale each constraint allows."""
    r, V = spec.cup_radius, spec.vacuum_force
    rho = com - c
    f = -load * directions
    tau = -load * np.cross(rho, directions)
    fz = f @ a
    ft = np.linalg.norm(f - fz[:, None] * a, axis=1)
    tz = tau @ a
    tt = np.linalg.norm(tau - tz[:, None] * a, axis=1)
    bounds = []
    for den, cap in ((np.sqrt(ft**2 + (tz / r) ** 2) - mu * fz, mu * V), (tt - 0.5 * r * fz, 0.5 * r * V), (-fz, V)):
        bounds.append(np.where(den > 0, cap / np.where(den > 0, den, 1.0), np.inf))
    return float(np.min(np.minimum.reduce(bounds)))


def test_hold_margins_equal_a_brute_force_evaluation_of_the_model():
    rng = np.random.default_rng(3)
    part = trimesh.creation.box((0.12, 0.05, 0.03))
    pts, _ = trimesh.sample.sample_surface(part, 40, seed=4)
    app = rng.normal(size=(40, 3))
    app /= np.linalg.norm(app, axis=1, keepdims=True)
    com = np.array([0.01, -0.005, 0.002])
    j = _judge(part, pts, app, mass_kg=0.3, center_of_mass=com, accel=5.0, safety_factor=2.0)
    k = 100_000
    i = np.arange(k) + 0.5
    phi, th = np.arccos(1 - 2 * i / k), math.pi * (1 + 5**0.5) * i
    dirs = np.column_stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)])
    load = 2.0 * 0.3 * (9.81 + 5.0)
    brute = np.array([_brute_margin(pts[n], app[n], com, SPEC, load, 0.5, dirs) for n in range(40)])
    assert j.hold_margin is not None
    assert np.all(j.hold_margin <= brute * (1 + 1e-12))  # the exact minimum lies below any direction tried
    np.testing.assert_allclose(j.hold_margin, brute, rtol=2e-4)


def test_bad_inputs_are_refused():
    plate = trimesh.creation.box((0.1, 0.1, 0.01))
    with pytest.raises(InvalidParameterError) as e:
        graspgen.generate(plate, SPEC, units="m", points=300, inside=True)
    assert e.value.field == "inside"
    with pytest.raises(InvalidParameterError) as e:
        graspgen.generate(plate, graspgen.examples.EXAMPLE_GRIPPER, units="m", points=300, max_tilt_deg=5)
    assert e.value.field == "max_tilt_deg"
    pts, faces = trimesh.sample.sample_surface_even(plate, 500, seed=0)
    buf = io.BytesIO()
    np.savez(buf, points=pts, normals=plate.face_normals[faces])
    cloud = graspgen.load_part(buf.getvalue(), units="m", file_type="npz")
    with pytest.raises(InvalidMeshError):
        graspgen.generate(cloud, SPEC, points=300)
    # a spec dict of kind suction runs the suction method
    assert graspgen.generate(plate, CUP, units="m", points=300).to_json()["gripper"] == CUP


def _reference_seal(mesh: trimesh.Trimesh, spec: SuctionSpec, p: np.ndarray, a: np.ndarray) -> str:
    """The seal model written out plainly: every probe against every triangle (numpy), the rules of
    docs/HOLD.md "seal" in the order the kernel applies them."""
    from graspgen.suction._model import depth_limits, inner_probes, lip_points, lip_slot_probes

    r, h, e = spec.cup_radius, spec.cup_height, spec.max_strain
    lo, hi = depth_limits(r, h, e)
    recess = SUCTION.recess_depth
    ref = np.array([0.0, 1.0, 0.0]) if abs(a[0]) > 0.9 else np.array([1.0, 0.0, 0.0])
    x0 = ref - (ref @ a) * a
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(a, x0)
    loc = (mesh.triangles - p) @ np.column_stack([x0, y0, a])  # (m, 3, 3): x, y, depth
    front = mesh.face_normals @ a < 0

    def first_hit(x: float, y: float, z1: float) -> tuple[float, bool]:
        v0, v1, v2 = loc[:, 0], loc[:, 1], loc[:, 2]
        area = (v1[:, 0] - v0[:, 0]) * (v2[:, 1] - v0[:, 1]) - (v1[:, 1] - v0[:, 1]) * (v2[:, 0] - v0[:, 0])
        w0 = (v2[:, 0] - v1[:, 0]) * (y - v1[:, 1]) - (v2[:, 1] - v1[:, 1]) * (x - v1[:, 0])
        w1 = (v0[:, 0] - v2[:, 0]) * (y - v2[:, 1]) - (v0[:, 1] - v2[:, 1]) * (x - v2[:, 0])
        w2 = (v1[:, 0] - v0[:, 0]) * (y - v0[:, 1]) - (v1[:, 1] - v0[:, 1]) * (x - v0[:, 0])
        s = np.sign(area)
        band = 1e-9 * r * r  # the kernel's band: a probe on an edge shared by two triangles lies in both
        inside = (np.abs(area) > band) & (w0 * s >= -band) & (w1 * s >= -band) & (w2 * s >= -band)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = (w0 * v0[:, 2] + w1 * v1[:, 2] + w2 * v2[:, 2]) / area
        ok = inside & (d >= lo) & (d <= z1)
        if not ok.any():
            return math.inf, False
        best = d[ok].min()
        return float(best), bool(front[ok & (d == best)].any())

    depths = []
    for x, y in lip_points(r):
        d, facing = first_hit(x, y, hi + recess)
        if d == math.inf:
            return "reach"
        if not facing or d > hi:
            return "depth"
        depths.append(d)
    d = np.array(depths)
    c0 = 2 * r * math.sin(math.pi / len(d))
    cone = np.abs(np.hypot(r, h + d) / math.hypot(r, h) - 1)
    perimeter = np.sqrt(1 + ((np.roll(d, -1) - d) / c0) ** 2) - 1
    if max(cone.max(), perimeter.max()) > e:
        return "stretch"
    slot = lip_slot_probes(r)
    per = len(slot) // len(d)
    for q, (x, y) in enumerate(slot):
        if q % per:
            k = q // per
            depth, facing = first_hit(x, y, max(d[k], d[(k + 1) % len(d)]) + recess)
            if depth == math.inf or not facing:
                return "hole"
    for x, y in inner_probes(r):
        depth, facing = first_hit(x, y, d.max() + recess)
        if depth == math.inf or not facing:
            return "hole"
    return "pass"


@pytest.mark.parametrize("name", ["tless_20", "washer"])
def test_seal_equals_a_brute_force_evaluation_on_random_candidates(name):
    if name == "washer":
        mesh = trimesh.creation.annulus(r_min=0.004, r_max=0.04, height=0.012, sections=48)
    else:
        path = Path(__file__).resolve().parents[3] / "shared" / "meshes" / "paper" / "tless_20.stl"
        if not path.exists():
            pytest.skip(f"shared mesh {path} not found")
        mesh = graspgen.load_part(path, units="mm").mesh
    rng = np.random.default_rng(11)
    pts, faces = trimesh.sample.sample_surface(mesh, 300, seed=12)
    tilt = rng.normal(scale=0.12, size=(300, 3))
    app = -mesh.face_normals[faces] + tilt
    app /= np.linalg.norm(app, axis=1, keepdims=True)
    got = judge_cups(mesh, SPEC, pts, app, position_tolerance=0.0).seal  # the seal where the cup lies
    want = np.array([_reference_seal(mesh, SPEC, p, a) for p, a in zip(pts, app, strict=True)])
    # the kernel names the failure of the first lip probe it tests; the verdict pass / fail is the model's
    np.testing.assert_array_equal(got == "pass", want == "pass")
    passed = got == "pass"
    assert passed.any() and (~passed).any()
    same_reason = np.mean(got[~passed] == want[~passed])
    assert same_reason > 0.8


def test_empty_reason_names_the_last_criterion_and_what_would_change_it():
    plate = trimesh.creation.box((0.1, 0.1, 0.01))
    heavy = graspgen.generate(plate, SPEC, units="m", points=600, mass_kg=6.0)
    why = heavy.stats["empty_reason"]
    assert not heavy.grasps and why["criterion"] == "hold" and why["limit"] in ("friction", "peel", "pull")
    # the margin is proportional to the vacuum and inversely to the mass: the best cup holds at exactly these
    best = why["best_margin"]
    assert why["vacuum_needed"] == pytest.approx(SPEC.vacuum / best) and why["max_mass_kg"] == pytest.approx(6 * best)
    lighter = graspgen.generate(plate, SPEC, units="m", points=600, mass_kg=why["max_mass_kg"] * 0.99)
    assert lighter.grasps
    # a pot: a sphere of 25 mm (too curved to seal on) with a pocket 36 mm wide and 30 mm deep, whose floor is the
    # only place the cup seals; a tool wider than the pocket meets its wall on the way in
    pot = _pot()
    assert pot.is_watertight
    slim = graspgen.generate(pot, SPEC, units="m", points=4000)
    assert slim.grasps and slim.stats["rejected"]["collision"] == 0
    np.testing.assert_allclose(slim.candidates.approach, np.tile([0.0, 0.0, -1.0], (len(slim.candidates), 1)))
    wide = SuctionSpec.from_dict({**CUP, "tool": {"radius": 0.02, "length": 0.1}})
    walled = graspgen.generate(pot, wide, units="m", points=4000)
    why = walled.stats["empty_reason"]
    assert why["criterion"] == "collision" and "tool" in why["message"]
    assert walled.stats["rejected"]["collision"] == len(slim.candidates)


def _pot() -> trimesh.Trimesh:
    """A sphere of radius 25 mm cut at z = 15 mm, with a pocket of radius 18 mm down to z = -15 mm (revolved)."""
    R, top, floor, pocket = 0.025, 0.015, -0.015, 0.018
    outer = [(R * math.cos(t), R * math.sin(t)) for t in np.linspace(-math.pi / 2, math.asin(top / R), 40)]
    profile = [(0.0, -R), *outer[1:], (pocket, top), (pocket, floor), (0.0, floor)]
    return trimesh.creation.revolve(np.array(profile), sections=96)


def test_a_cup_that_seals_only_where_it_lies_fails_within_the_position_tolerance():
    """A lip 0.5 mm inside an edge seals where it lies, but not when the robot places it 1 mm off (the default
    position tolerance): `position`. 5 mm inside, it seals anywhere within the tolerance; generate() counts the
    position failures under seal."""
    block = trimesh.creation.box((0.1, 0.1, 0.04))
    near = (0.05 - 0.015 - 0.0005, 0, 0.02)
    assert _judge(block, near, DOWN, position_tolerance=0.0).seal[0] == "pass"
    assert _judge(block, near, DOWN).seal[0] == "position"
    assert _judge(block, near, DOWN, position_tolerance=0.0004).seal[0] == "pass"
    assert _judge(block, (0.03, 0, 0.02), DOWN).seal[0] == "pass"
    gs = graspgen.generate(block, SPEC, units="m", points=1500)
    assert gs.stats["seal"]["position"] > 0
    x = np.abs(gs.candidates.contacts[:, 0, :2]).max(axis=1)
    top = gs.candidates.approach[:, 2] < -0.99
    assert x[top].max() <= 0.05 - 0.015 - 0.001 + 1e-4  # every cup on the top face seals 1 mm further out
