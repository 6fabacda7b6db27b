"""The MuJoCo validation of grippers from CAD (CONTRACT.md "Gripper geometry from CAD"): fingers and body as the
convex pieces of their meshes, the approach tested against the exact meshes (graspgen.meshsweep), and the box
spec's outcome reproduced by box meshes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

import graspgen
from graspgen import physics
from graspgen.example_grippers import box, prism, stl_bytes, union_of_shells
from graspgen.examples import EXAMPLE_GRIPPER, example_part
from graspgen.gripper import GripperSpec
from graspgen.meshsweep import SweptMesh
from graspgen.transforms import grasp_frames

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
CAD_EXAMPLES = ("pgn-80-vgroove", "pgn-80-stepped", "pgn-80-housing")
BOX_SPEC = GripperSpec.from_dict(EXAMPLE_GRIPPER)
_BOX_FIELDS = ("finger_width", "finger_depth", "finger_thickness", "palm_depth", "palm_width")


def _cad(finger, body, **extra) -> GripperSpec:
    """The example box gripper (pgn-80) with `finger` and `body` (millimetre solids) as its geometry."""
    data = {k: v for k, v in EXAMPLE_GRIPPER.items() if k not in _BOX_FIELDS}
    data.update(extra)
    data["geometry"] = {"units": "mm", "finger": "finger.stl", "body": "body.stl"}
    return GripperSpec.from_dict(data, files={"finger.stl": stl_bytes(finger), "body.stl": stl_bytes(body)})


#: the contract's box finger (10 x 20 x 30 mm) and palm (x within the stroke plus both fingers, 20 mm wide, 20 mm
#: deep behind the fingers) of pgn-80 as meshes
BOXES_AS_MESHES = _cad(box((0, -10, -15), (10, 10, 15)), box((-50, -10, -35), (50, 10, -15)))


def _example(name: str) -> GripperSpec:
    return GripperSpec.load(EXAMPLES / f"{name}.json")


def _frame(roll_rad: float = 0.0, axis=(1.0, 0.0, 0.0), mid=(0.0, 0.0, 0.0)) -> np.ndarray:
    return grasp_frames(np.array([mid], float), np.array([axis], float), np.array([roll_rad]))[0]


# --------------------------------------------------------------------------------------------------------------------
# the swept mesh against a brute force


def _winding(tri: np.ndarray, p: np.ndarray) -> float:
    """Generalised winding number of the closed triangles (m, 3, 3) at p (3,)."""
    a, b, c = tri[:, 0] - p, tri[:, 1] - p, tri[:, 2] - p
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    det = np.einsum("ij,ij->i", a, np.cross(b, c))
    div = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb
    div += np.einsum("ij,ij->i", b, c) * la
    return float(np.sum(2.0 * np.arctan2(det, div)) / (4.0 * np.pi))


def _depth(tri: np.ndarray, p: np.ndarray) -> float:
    """Signed distance of p from the closed triangles' surface: positive inside."""
    nearest = trimesh.triangles.closest_point(tri, np.repeat(p[None], len(tri), axis=0))
    d = float(np.linalg.norm(nearest - p, axis=1).min())
    return d if _winding(tri, p) > 0.5 else -d


_SOLIDS = {
    "box": lambda: trimesh.creation.box(extents=(0.01, 0.02, 0.03)),
    "sphere": lambda: trimesh.creation.icosphere(subdivisions=2, radius=0.01),
    "v-groove finger": lambda: _example("pgn-80-vgroove").geometry.finger,
    "stepped finger (two shells)": lambda: _example("pgn-80-stepped").geometry.finger,
}


@pytest.mark.parametrize("tolerance", [0.0, 1e-3])
@pytest.mark.parametrize("solid", list(_SOLIDS))
def test_the_swept_mesh_agrees_with_a_brute_force(solid, tolerance):
    """A point meets the solid eroded by the tolerance, moving 8 mm along +Z into place, exactly when the largest
    signed depth along the segment q + u Z, u in [0, 8 mm], exceeds the tolerance. The brute force samples u every
    0.2 mm (winding number and distance to every triangle); the depth is 1-Lipschitz, so the points within 0.1 mm
    of the threshold are left out as undecided."""
    mesh = _SOLIDS[solid]()
    tri = np.asarray(mesh.triangles)
    swept = SweptMesh.of(tri, tolerance)
    lo, hi = mesh.bounds
    points = np.random.default_rng(7).uniform(lo - 0.004, hi + 0.004, size=(160, 3))
    D, step = 0.008, 2e-4
    got = swept.hits(points, D)
    decided = 0
    for q, hit in zip(points, got, strict=True):
        best = max(_depth(tri, q + np.array([0.0, 0.0, u])) for u in np.arange(0.0, D + step / 2, step))
        if best > tolerance:
            assert hit, (q, best)
        elif best < tolerance - step / 2:
            assert not hit, (q, best)
        else:
            continue
        decided += 1
    assert decided >= 150 and 20 <= got.sum() <= 140  # both outcomes, most points decided
    # without a way in, the erosion alone: inside and farther than the tolerance from the surface
    still = swept.hits(points, 0.0)
    expected = np.array([_depth(tri, q) > tolerance for q in points])
    assert (still == expected).mean() > 0.98 and not np.any(still & ~got)


def test_contains_agrees_with_trimesh_and_counts_a_line_through_an_edge_once():
    """Points inside agree with the generalised winding number and, on one shell, with trimesh's ray test (rtree, a
    test dependency; it miscounts where two shells touch, as the stepped finger's tip and root do: 131 of 20,000
    points). Points whose vertical line passes exactly through the meshes' edges and vertices (whole millimetres:
    their vertices, the midpoints between them) are inside exactly when a point nudged off the edge in one of five
    directions is: a line through a shared edge or vertex is counted once, neither twice nor not at all."""
    rng = np.random.default_rng(3)
    for name in _SOLIDS:
        mesh = _SOLIDS[name]()
        swept = SweptMesh.of(mesh.triangles)
        lo, hi = mesh.bounds
        points = rng.uniform(lo - 0.002, hi + 0.002, size=(1000, 3))
        got = swept.contains(points)
        winding = np.array([_winding(np.asarray(mesh.triangles), p) > 0.5 for p in points])
        assert np.array_equal(got, winding), name
        if len(mesh.split(only_watertight=True)) == 1:
            assert np.array_equal(got, mesh.contains(points)), name
    for spec in map(_example, CAD_EXAMPLES):
        for mesh in (spec.geometry.finger, spec.geometry.body):
            v = np.asarray(mesh.vertices)
            axes = []
            for k in range(2):
                u = np.unique(v[:, k])
                axes.append(np.unique(np.concatenate([u, (u[:-1] + u[1:]) / 2])))
            zs = np.unique(v[:, 2])
            grid = np.stack(np.meshgrid(*axes, (zs[:-1] + zs[1:]) / 2, indexing="ij"), axis=-1).reshape(-1, 3)
            swept = SweptMesh.of(mesh.triangles)
            exact = swept.contains(grid)
            nudged = [swept.contains(grid + 1e-9 * np.array([dx, dy, 0.0])) for dx, dy in _NUDGES]
            assert np.all(np.any(np.stack(nudged) == exact, axis=0)), spec.name
            assert 0 < exact.sum() < len(grid)


_NUDGES = ((1.0, 0.37), (-1.0, 0.37), (0.37, -1.0), (-0.37, -1.0), (1.0, -0.37))


def test_a_swept_mesh_refuses_bad_input():
    with pytest.raises(ValueError, match="triangles"):
        SweptMesh.of(np.zeros((0, 3, 3)))
    with pytest.raises(ValueError, match="tolerance"):
        SweptMesh.of(trimesh.creation.box().triangles, -1.0)


# --------------------------------------------------------------------------------------------------------------------
# the model


def _finger_vertices(sim: physics.SimPart, width: float) -> list[np.ndarray]:
    """The world vertices (grasp frame) of the -X and the +X finger's geoms in MuJoCo at closing width `width`."""
    import mujoco

    m = sim.model
    d = mujoco.MjData(m)
    for j in ("close0", "close1"):
        d.qpos[m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)]] = (sim.spec.stroke - width) / 2
    mujoco.mj_kinematics(m, d)
    out = []
    for name in ("finger0", "finger1"):
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        rows = []
        for g in np.flatnonzero(m.geom_bodyid == b):
            assert m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
            k = m.geom_dataid[g]
            v = m.mesh_vert[m.mesh_vertadr[k] : m.mesh_vertadr[k] + m.mesh_vertnum[k]]
            rows.append(v @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g])
        out.append(np.concatenate(rows))
    return out


@pytest.mark.parametrize("name", CAD_EXAMPLES)
def test_the_pieces_of_each_finger_and_of_the_body_lie_where_their_meshes_are(name):
    """In the MuJoCo model at closing width 30 mm, every vertex of a finger's pieces lies within its mesh's bounds in
    the grasp frame (GripperSolids.trimeshes), and on or inside the mesh; the pieces fill the mesh and no more (CoACD
    cuts the V-groove finger into two convex halves that do not bridge the groove; the stepped finger's tip and root
    and the housing's two blocks are convex shells, each one piece), and so do the body's."""
    spec = _example(name)
    sim = physics.prepare_part(trimesh.creation.box(extents=(0.02, 0.02, 0.02)), spec, mass_kg=0.1)
    width = 0.03
    meshes = spec.solids().trimeshes(width)
    for vertices, mesh in zip(_finger_vertices(sim, width), meshes[:2], strict=True):
        lo, hi = mesh.bounds
        assert np.all(vertices >= lo - 1e-6) and np.all(vertices <= hi + 1e-6), name
        assert np.all(trimesh.proximity.signed_distance(mesh, vertices) > -1e-6)  # not outside the finger
    g = spec.geometry
    for pieces, mesh in ((sim.gripper.fingers[1], g.finger), (sim.gripper.body, g.body)):
        assert sum(p.volume for p in pieces) == pytest.approx(mesh.volume, rel=1e-4)
    pieces = {"finger_pieces": [1, 1], "body_pieces": 2} if name == "pgn-80-housing" else None
    assert sim.describe()["gripper"] == (pieces or {"finger_pieces": [2, 2], "body_pieces": 1})
    plain = physics.prepare_part(trimesh.creation.box(extents=(0.02, 0.02, 0.02)), BOX_SPEC, mass_kg=0.1)
    assert "gripper" not in plain.describe() and plain.gripper is None


def test_a_finger_that_is_not_convex_is_decomposed_and_the_left_finger_is_its_own_mesh():
    """A one-shell finger with a notch (not convex) goes through CoACD, whose pieces cover it without bridging the
    notch by more than CoACD's concavity; a spec's finger_left is simulated with its own mesh, turned."""
    notched = prism([(0, -10), (10, -10), (10, 10), (0, 10), (0, 3), (4, 3), (4, -3), (0, -3)], -15, 15, axis=2)
    left = box((0, -6, -15), (6, 6, 15))
    data = {k: v for k, v in EXAMPLE_GRIPPER.items() if k not in _BOX_FIELDS}
    data["geometry"] = {"units": "mm", "finger": "f.stl", "finger_left": "l.stl"}
    spec = GripperSpec.from_dict(data, files={"f.stl": stl_bytes(notched), "l.stl": stl_bytes(left)})
    sim = physics.prepare_part(trimesh.creation.box(extents=(0.02,) * 3), spec, mass_kg=0.1)
    left_pieces, right_pieces = sim.gripper.fingers
    assert len(right_pieces) >= 2 and sim.note is None
    volume = spec.geometry.finger.volume
    assert volume <= sum(p.volume for p in right_pieces) <= 1.05 * volume
    assert len(left_pieces) == 1
    assert np.allclose(left_pieces[0].bounds, [[-0.006, -0.006, -0.015], [0.0, 0.006, 0.015]])
    assert sim.gripper.body == [] and sim.gripper.swept[2] is None
    assert sim.gripper.top_z == pytest.approx(0.015)


def test_a_finger_with_a_cavity_is_simulated_as_its_outer_shell():
    """A closed cavity (an inward shell) inside a box finger cannot be reached: the finger is one piece, the box; the
    exact mesh of the approach test keeps the cavity."""
    outer = box((0, -10, -15), (10, 10, 15))
    cavity_vertices, cavity_faces = box((3, -5, -5), (7, 5, 5))
    cavity = (cavity_vertices, cavity_faces[:, ::-1])  # facing inwards
    data = {k: v for k, v in EXAMPLE_GRIPPER.items() if k not in _BOX_FIELDS}
    data["geometry"] = {"units": "mm", "finger": "f.stl"}
    spec = GripperSpec.from_dict(data, files={"f.stl": stl_bytes(union_of_shells(outer, cavity))})
    assert spec.geometry.finger.volume == pytest.approx(5.6e-6)
    sim = physics.prepare_part(trimesh.creation.box(extents=(0.02, 0.02, 0.02)), spec, mass_kg=0.1)
    (piece,) = sim.gripper.fingers[1]
    assert piece.volume == pytest.approx(6e-6) and sim.note is None
    assert not sim.gripper.swept[1].contains(np.array([[0.005, 0.0, 0.0]]))[0]  # in the cavity
    assert sim.gripper.swept[1].contains(np.array([[0.001, 0.0, 0.0]]))[0]  # in the wall


def test_inside_grasps_are_refused_for_a_cad_gripper():
    sim = physics.prepare_part(trimesh.creation.box(extents=(0.02,) * 3), BOXES_AS_MESHES, mass_kg=0.1)
    with pytest.raises(graspgen.InvalidParameterError, match="inside"):
        physics.simulate_grasp(sim, _frame(), 0.02, inside=True)


# --------------------------------------------------------------------------------------------------------------------
# outcomes


@pytest.mark.slow
def test_box_meshes_simulate_as_the_box_spec():
    """The contract's boxes given as meshes (finger and palm) give the box spec's outcome on the ring screw: five
    candidates at four rolls each (some collide on the way in: the path test then reads the exact meshes), at 0.2 kg
    (held) and 1.5 kg (turned out of the pads); slip within 0.05 mm and rotation within 0.1 degree (measured: equal to
    within 1e-5)."""
    part = example_part("ring-screw")
    gs = graspgen.generate(part, EXAMPLE_GRIPPER, points=1500, k1=4, k2=2, mass_kg=0.2)
    c = gs.candidates
    idx = np.random.default_rng(0).choice(len(c.widths), 5, replace=False)
    rolls = np.tile(np.deg2rad([0.0, 90.0, 180.0, 270.0]), len(idx))
    poses = grasp_frames(np.repeat(c.midpoints[idx], 4, axis=0), np.repeat(c.axes[idx], 4, axis=0), rolls)
    widths = np.repeat(c.widths[idx], 4)
    reasons = set()
    for mass in (0.2, 1.5):
        boxes = physics.prepare_part(part.mesh, BOX_SPEC, mass_kg=mass)
        meshes = physics.prepare_part(part.mesh, BOXES_AS_MESHES, mass_kg=mass)
        assert boxes.geometry == "coacd" and meshes.gripper is not None and boxes.gripper is None
        a = physics.simulate_grasps(boxes, poses, widths, workers=2)
        b = physics.simulate_grasps(meshes, poses, widths, workers=2)
        for ra, rb in zip(a, b, strict=True):
            assert (ra.success, ra.reason) == (rb.success, rb.reason), (ra, rb)
            assert rb.slip_mm == pytest.approx(ra.slip_mm, abs=0.05)
            assert rb.rotation_deg == pytest.approx(ra.rotation_deg, abs=0.1)
            reasons.add(ra.reason)
    assert reasons == {None, "collision", "slipped"}


@pytest.mark.slow
def test_the_vgroove_fingers_seat_a_cylinder_and_hold_it():
    """A cylinder of 8 mm radius, 0.2 kg, standing along the approach and gripped across its diameter at mid-height
    by the V-groove fingers (20 N): it seats on both flanks of each groove, so the fingers' frames close to
    2 (8 sqrt(2) - 8) = 6.6 mm apart (flat pads would stop 16 mm apart), and it holds under the validation's
    members and the standard perturbations."""
    spec = _example("pgn-80-vgroove")
    cylinder = trimesh.creation.cylinder(radius=0.008, height=0.024, sections=128)
    sim = physics.prepare_part(cylinder, spec, mass_kg=0.2)
    T = _frame(0.0)
    assert np.allclose(T[:3, :3], np.eye(3), atol=1e-12)  # the cylinder's axis is the approach
    run = physics._Grasp(sim, T, 0.016, False, np.random.default_rng(0))
    assert run.run().success
    gap = run.d.xpos[run.finger_bodies[1]][0] - run.d.xpos[run.finger_bodies[0]][0]
    assert gap == pytest.approx(2 * (0.008 * np.sqrt(2) - 0.008), abs=3e-4)
    mine, other = run._part_contacts()
    geoms = run.d.contact.geom1[: run.d.ncon][mine].tolist() + run.d.contact.geom2[: run.d.ncon][mine].tolist()
    flanks = {g for g in geoms if run.m.geom_bodyid[g] in run.finger_bodies}
    assert len(flanks) == 4  # both flanks (pieces) of both fingers bear
    members = [*physics.validation_set(spec.friction), *physics.perturbation_set(0)]
    held = physics.simulate_perturbed(sim, T[None], np.array([0.016]), members)[0]
    assert all(r.success for r in held), [(p.name, r.reason) for p, r in zip(members, held, strict=True)]


def _hook(post_y_mm: float) -> trimesh.Trimesh:
    """A 20 mm block (x, y, z within +-10 mm) under a 4 mm plate reaching out along +y to a 10 mm post that stands
    from y = post_y_mm to post_y_mm + 10 down to z = -40 mm: behind the contact, along the palm's side."""
    y0, y1 = post_y_mm, post_y_mm + 10
    section = [(-10, -10), (10, -10), (10, 10), (y0, 10), (y0, -40), (y1, -40), (y1, 14), (-10, 14)]
    v, f = prism(section, -10, 10, axis=0)
    return trimesh.Trimesh(v * 1e-3, f)


@pytest.mark.slow
def test_a_wide_body_meets_a_tall_part_on_the_way_in_where_the_palm_does_not():
    """The hook's post stands 17-27 mm to the side of the contact and reaches 40 mm behind it: clear of the box
    palm (20 mm wide), in the way of the housing (60 mm wide). Both models' pieces reach into the gripper on the
    way in; the path test on the exact meshes decides: a collision for the housing only. A post 47-57 mm out is
    clear of the housing and its 90 mm adapter plate too."""
    T = np.eye(4)  # gripped across x at the block's centre, coming in along +z from below
    housing = _example("pgn-80-housing")
    for spec, post, collides in ((BOX_SPEC, 17, False), (housing, 17, True), (housing, 47, False)):
        sim = physics.prepare_part(_hook(post), spec, mass_kg=0.1)
        run = physics._Grasp(sim, T, 0.02, False, np.random.default_rng(0))
        assert run.approach_distance > 0.055  # from below the post's foot
        assert run.approach_collides() == collides, (spec.name, post)
        r = physics.simulate_grasp(sim, T, 0.02)
        assert (r.reason == "collision") == collides, (spec.name, post, r)


@pytest.mark.slow
def test_an_approach_into_a_convex_piece_but_not_into_the_part_is_no_collision_for_cad_fingers(monkeypatch):
    """test_physics's upside-down U channel, simulated as its hull, with the box fingers given as meshes: the inner
    finger passes into the channel's gap, inside the piece but clear of the part (free); a third wall in that gap is
    a collision. The path test reads the finger meshes."""

    def channel(*walls):
        boxes = [trimesh.creation.box(extents=(0.06, 0.03, 0.01), transform=_at(0.0, 0.035))]
        boxes += [trimesh.creation.box(extents=(0.01, 0.03, 0.04), transform=_at(x, 0.01)) for x in walls]
        return trimesh.util.concatenate(boxes)

    def _at(x, z):
        T = np.eye(4)
        T[:3, 3] = (x, 0.0, z)
        return T

    monkeypatch.setattr(physics, "_decompose", lambda mesh, c, seed: ([mesh.convex_hull], "coacd", None))
    rolls = 2 * np.pi * np.arange(16) / 16
    frames = grasp_frames(np.tile([[-0.025, 0.0, 0.0]], (16, 1)), np.tile([[1.0, 0.0, 0.0]], (16, 1)), rolls)
    T = frames[int(np.argmax(frames[:, 2, 2]))]
    spec = _cad(box((0, -10, -15), (10, 10, 15)), box((-50, -10, -35), (50, 10, -15)))
    free = physics.simulate_grasp(physics.prepare_part(channel(-0.025, 0.025), spec, mass_kg=0.1), T, 0.01)
    assert free.reason != "collision"
    blocked = physics.simulate_grasp(physics.prepare_part(channel(-0.025, 0.025, -0.006), spec, mass_kg=0.1), T, 0.01)
    assert blocked.reason == "collision"


@pytest.mark.slow
def test_a_piece_reaching_into_a_body_of_two_shells_lets_the_grasp_go_on_without_the_body(monkeypatch):
    """test_physics's block with an extra piece reaching 2.5 mm into the palm, the palm given as two shells 2 mm
    apart (two body geoms): the piece meets both, the grasp goes on in the model where no body piece collides, and
    it holds."""
    block = trimesh.creation.box(extents=(0.02, 0.03, 0.02))
    extra = trimesh.creation.box(extents=(0.018, 0.02, 0.0075))
    extra.apply_translation([0.0, 0.0, -0.01 - 0.0075 / 2])  # z from -17.5 mm to -10 mm
    monkeypatch.setattr(physics, "_decompose", lambda mesh, c, seed: ([block, extra], "coacd", None))
    halves = union_of_shells(box((-50, -10, -35), (-1, 10, -15)), box((1, -10, -35), (50, 10, -15)))
    spec = _cad(box((0, -10, -15), (10, 10, 15)), halves)
    sim = physics.prepare_part(block, spec, mass_kg=0.1)
    assert len(sim.gripper.body) == 2
    T = np.eye(4)
    run = physics._Grasp(sim, T, 0.02, False, np.random.default_rng(0))
    assert len(run.palm_geoms) == 2
    assert run.run().success
    quiet = sim.model_for(physics.NOMINAL, palm=False)
    assert run.m is quiet
    assert np.all(quiet.geom_contype[run.palm_geoms] == 0) and np.all(quiet.geom_conaffinity[run.palm_geoms] == 0)
    g = physics._Grasp(sim, T, 0.02, False, np.random.default_rng(0))
    assert not g.approach_collides()  # the part's own surface is clear of the body
    g.mj.mj_forward(g.m, g.d)
    assert g._palm_penetration() == pytest.approx(0.0025, abs=3e-4)


@pytest.mark.slow
def test_generate_validates_with_a_cad_gripper():
    gs = graspgen.generate(
        trimesh.creation.box(extents=(0.03, 0.02, 0.015)),
        _example("pgn-80-vgroove"),
        units="m",
        points=800,
        k1=3,
        k2=2,
        validate=True,
        mass_kg=0.1,
        sim_workers=2,
    )
    v = gs.stats["validation"]
    assert v["tested"] == len(gs.grasps) == 6
    assert v["succeeded"] == sum(g["sim"]["success"] for g in gs.grasps) >= 5
    assert v["part"]["gripper"] == {"finger_pieces": [2, 2], "body_pieces": 1}
