"""The compiled kernels against the plain-numpy reference (tests/graspgen/reference.py): exact equality."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from graspgen.antipodal import (
    antipodal_pairs,
    cone_half_angle_rad,
    friction_margin_deg,
    grid_order,
    pair_cell_size,
    pair_plan,
)
from graspgen.collision import collision_model, free_rolls, free_rolls_of_pairs
from graspgen.gripper import GripperSpec
from graspgen.params import TOLERANCES
from graspgen.transforms import roll_angles_rad

from ..conftest import SHARED_MESHES
from . import reference as ref

GRIPPER = GripperSpec(
    name="pgn-80",
    stroke=0.08,
    finger_width=0.02,
    finger_depth=0.03,
    finger_thickness=0.01,
    friction=0.5,
    pregrasp_clearance=0.02,
    palm_depth=0.02,
)


def _sample(mesh: trimesh.Trimesh, n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    pts, face = trimesh.sample.sample_surface_even(mesh, n, seed=seed)
    return np.asarray(pts), np.asarray(mesh.face_normals[face])


def _parts():
    ring = trimesh.creation.annulus(r_min=0.01, r_max=0.03, height=0.02, sections=48)
    box = trimesh.creation.box(extents=[0.05, 0.03, 0.02])
    cyl = trimesh.creation.cylinder(radius=0.015, height=0.06, sections=48)

    # a U-shaped part: a slot 6 mm wide between two prongs (narrower than two fingers)
    def block(extents, at):
        return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(at))

    u = trimesh.util.concatenate(
        [
            block([0.04, 0.02, 0.01], [0, 0, -0.015]),
            block([0.017, 0.02, 0.03], [-0.0115, 0, 0.005]),
            block([0.017, 0.02, 0.03], [0.0115, 0, 0.005]),
        ]
    )
    return {"ring": ring, "box": box, "cylinder": cyl, "u": u}


@pytest.mark.parametrize("inside", [False, True])
@pytest.mark.parametrize("name", ["ring", "box", "u"])
def test_pairs_equal_reference(name, inside):
    pts, nrm = _sample(_parts()[name], 1200)
    res = antipodal_pairs(
        pts, nrm, stroke=0.05, min_width=0.004, friction=0.5, safety_factor=1.5, inside=inside, finger_thickness=0.01
    )
    I, J, out, inn = ref.pair_criteria(
        pts, nrm, stroke=0.05, min_width=0.004, friction=0.5, safety_factor=1.5, inside=inside, finger_thickness=0.01
    )
    acc = out | inn
    assert np.array_equal(res.i, I[acc]) and np.array_equal(res.j, J[acc])
    assert np.array_equal(res.inside, inn[acc])
    assert res.pairs_total == len(I)
    assert res.rejected_stroke + res.rejected_outside + res.rejected_friction + len(res.i) == res.pairs_total
    assert len(res.i) > 0


def test_pair_counts_by_criterion_on_a_box():
    pts, nrm = _sample(_parts()["box"], 800)
    res = antipodal_pairs(
        pts, nrm, stroke=0.04, min_width=0.0, friction=0.5, safety_factor=1.5, inside=False, finger_thickness=0.01
    )
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)[np.triu_indices(len(pts), 1)]
    # the box is 50 mm long: every pair farther apart than the 40 mm stroke is a stroke rejection
    assert res.rejected_stroke == int(np.sum(d > 0.04))


def test_grid_order_gives_the_same_pairs():
    pts, nrm = _sample(_parts()["ring"], 1500)
    kw = dict(stroke=0.08, min_width=0.0, friction=0.5, safety_factor=1.5, inside=False, finger_thickness=0.01)
    a = antipodal_pairs(pts, nrm, **kw)
    o = grid_order(pts, 0.04)
    b = antipodal_pairs(pts[o], nrm[o], **kw)
    pa = {(int(i), int(j)) for i, j in zip(a.i, a.j, strict=True)}
    pb = {tuple(sorted((int(o[i]), int(o[j])))) for i, j in zip(b.i, b.j, strict=True)}
    assert pa == pb


@pytest.mark.parametrize("ordered", [True, False])
def test_pair_plan_blocks_give_exactly_the_pairs(ordered):
    """The counting pass plus blocks of rows (ragged, down to one row) equal the one-shot pairs, in any order."""
    pts, nrm = _sample(_parts()["ring"], 1200)
    kw = dict(stroke=0.08, min_width=0.0, friction=0.5, safety_factor=1.5, inside=True, finger_thickness=0.01)
    if ordered:
        o = grid_order(pts, pair_cell_size(0.08, True, 0.01))
        pts, nrm = pts[o], nrm[o]
    whole = antipodal_pairs(pts, nrm, **kw)
    plan = pair_plan(pts, nrm, **kw)
    assert plan.accepted == len(whole.i)
    assert (plan.rejected_stroke, plan.rejected_outside, plan.rejected_friction) == (
        whole.rejected_stroke,
        whole.rejected_outside,
        whole.rejected_friction,
    )
    blocks = plan.blocks(997)
    assert blocks[0][0] == 0 and blocks[-1][1] == len(pts) and len(blocks) > 3
    assert all(a[1] == b[0] for a, b in zip(blocks[:-1], blocks[1:], strict=True))
    parts = [plan.fill(r0, r1) for r0, r1 in blocks]
    assert all(len(p[0]) <= 997 or r1 - r0 == 1 for p, (r0, r1) in zip(parts, blocks, strict=True))
    i, j, ins = (np.concatenate(x) for x in zip(*parts, strict=True))
    if ordered:  # blocks concatenate to the very order of antipodal_pairs
        assert np.array_equal(i, whole.i) and np.array_equal(j, whole.j) and np.array_equal(ins, whole.inside)
    else:
        key = np.lexsort((j, i))
        assert np.array_equal(i[key], whole.i) and np.array_equal(j[key], whole.j)
        assert np.array_equal(ins[key], whole.inside)


@pytest.mark.parametrize("delta_deg, accepted", [(-0.1, True), (0.1, False)])
def test_friction_boundary(delta_deg, accepted):
    """A pair at the cone limit +- 0.1 degree is accepted / rejected."""
    limit = math.degrees(cone_half_angle_rad(0.5, 1.5))
    ang = math.radians(limit + delta_deg)
    pts = np.array([[0.0, 0.0, 0.0], [0.02, 0.0, 0.0]])
    # contact 0 normal tilted by `ang` from -x; contact 1 exactly +x
    nrm = np.array([[-math.cos(ang), math.sin(ang), 0.0], [1.0, 0.0, 0.0]])
    res = antipodal_pairs(
        pts, nrm, stroke=0.08, min_width=0.0, friction=0.5, safety_factor=1.5, inside=False, finger_thickness=0.01
    )
    assert (len(res.i) == 1) is accepted
    assert res.rejected_friction == (0 if accepted else 1)
    if accepted:
        m = friction_margin_deg(pts, nrm, res.i, res.j, res.inside, cone_half_angle_rad(0.5, 1.5))
        assert m[0] == pytest.approx(0.1, abs=1e-9)


def _candidates(pts, nrm, inside=False):
    res = antipodal_pairs(
        pts, nrm, stroke=0.08, min_width=0.0, friction=0.5, safety_factor=1.5, inside=inside, finger_thickness=0.01
    )
    d = pts[res.j] - pts[res.i]
    w = np.linalg.norm(d, axis=1)
    return (pts[res.i] + pts[res.j]) / 2, d / w[:, None], w, res.inside


@pytest.mark.parametrize("mode", ["paper", "swept"])
@pytest.mark.parametrize("name", ["ring", "cylinder", "u"])
def test_free_rolls_equal_reference(name, mode):
    pts, nrm = _sample(_parts()[name], 1200)
    mids, axes, w, inside = _candidates(pts, nrm, inside=(name == "ring"))
    fr = free_rolls(pts, nrm, mids, axes, w, inside, collision_model(GRIPPER, mode), 16)
    sel = np.random.default_rng(0).choice(len(mids), min(250, len(mids)), replace=False)
    # make sure both outcomes are in the checked sample
    sel = np.unique(np.concatenate([sel, np.nonzero(fr.any(1))[0][:50], np.nonzero(~fr.any(1))[0][:50]]))
    expect = ref.free_rolls(pts, mids[sel], axes[sel], w[sel], inside[sel], GRIPPER, mode, 16)
    assert np.array_equal(fr[sel], expect)
    assert expect.any() and not expect.all()


@pytest.mark.parametrize("name", ["ring", "u", "cylinder"])
def test_free_rolls_with_the_approach_equal_reference(name):
    """With the approach (the palm's footprint swept a part's length behind the fingers, as the pipeline runs
    criterion (d)), where the hull's support settles most free rolls before the palm's walk: the same masks as
    every point against every box at every roll."""
    from graspgen.collision import approach_reach

    pts, nrm = _sample(_parts()[name], 1200)
    reach = approach_reach(pts)
    mids, axes, w, inside = _candidates(pts, nrm, inside=(name == "ring"))
    fr = free_rolls(pts, nrm, mids, axes, w, inside, collision_model(GRIPPER, "swept", reach=reach), 16)
    n_free = fr.sum(1)
    rng = np.random.default_rng(2)
    sel = np.unique(
        np.concatenate(
            [
                rng.choice(len(mids), min(200, len(mids)), replace=False),
                np.nonzero(n_free >= 3)[0][:60],
                np.nonzero((n_free > 0) & (n_free < 3))[0][:60],
            ]
        )
    )
    expect = ref.free_rolls(pts, mids[sel], axes[sel], w[sel], inside[sel], GRIPPER, "swept", 16, reach=reach)
    assert np.array_equal(fr[sel], expect)
    assert expect.any() and not expect.all()


def test_hull_support_bounds_the_points_and_settles_rolls_exactly():
    """The palm's certificate (build_hull, hull_free): the cube map's bound is above every sample point's reach along
    random directions, and for random frames the rolls it calls free are exactly those at which no point lies
    behind the threshold (brute force over all points), with both outcomes present."""
    from graspgen.collision._frame import Rolls
    from graspgen.collision._hull import build_hull, cube_cell, hull_free

    pts, _ = _sample(_parts()["u"], 3000, seed=4)
    hull = build_hull(pts, 0.0)
    bound, info = hull.bound, hull.info
    o, n = info[:3], int(info[3])
    rng = np.random.default_rng(7)
    U = rng.normal(size=(5000, 3))
    U /= np.linalg.norm(U, axis=1)[:, None]
    reach = ((pts - o) @ U.T).max(axis=0)
    cells = np.array([cube_cell(u[0], u[1], u[2], n) for u in U])
    assert np.all(reach <= bound[cells])
    assert np.all(bound[cells] - reach < 0.01)  # a useful bound: within 1 cm on a 4 cm part
    psi = roll_angles_rad(16)
    cos_k, sin_k = np.cos(psi), np.sin(psi)
    full = np.uint64((1 << 16) - 1)
    seen = set()
    for _ in range(300):
        x = rng.normal(size=3)
        x /= np.linalg.norm(x)
        y = np.cross(x, rng.normal(size=3))
        y /= np.linalg.norm(y)
        z = np.cross(x, y)
        m = pts.min(0) + rng.random(3) * np.ptp(pts, axis=0)
        F = np.concatenate([m, x, y, z])
        thr = rng.uniform(0.0, 0.03)
        rolls = Rolls(cos_k, sin_k, 8, 0.0, full, 0.9)
        got = int(hull_free(F, hull._replace(threshold=thr), full, rolls))
        for k in range(16):
            u = sin_k[k] * y - cos_k[k] * z  # -Z at roll k
            free = ((pts - m) @ u).max() < thr
            assert bool(got >> k & 1) == free
            seen.add(free)
    assert seen == {True, False}


@pytest.mark.parametrize("points", [np.random.default_rng(0).random((50, 3)) * [1, 1, 0], np.eye(3)])
def test_hull_of_flat_or_tiny_samples_certifies_nothing(points):
    from graspgen.collision._hull import build_hull

    assert len(build_hull(points, 0.0).vertices) == 0


@pytest.mark.parametrize("rolls", [1, 5, 64])
def test_free_rolls_any_roll_count(rolls):
    pts, nrm = _sample(_parts()["ring"], 600)
    mids, axes, w, inside = _candidates(pts, nrm)
    sel = np.arange(0, len(mids), max(1, len(mids) // 150))
    fr = free_rolls(pts, nrm, mids[sel], axes[sel], w[sel], inside[sel], collision_model(GRIPPER, "swept"), rolls)
    assert fr.shape == (len(sel), rolls)
    assert np.array_equal(fr, ref.free_rolls(pts, mids[sel], axes[sel], w[sel], inside[sel], GRIPPER, "swept", rolls))


def test_slot_narrower_than_finger_rejects_grasps_across_it():
    """The U part's 6 mm slot is narrower than the 10 mm finger: no grasp may put a finger into it."""
    pts, nrm = _sample(_parts()["u"], 3000)
    mids, axes, w, inside = _candidates(pts, nrm)
    fr = free_rolls(pts, nrm, mids, axes, w, inside, collision_model(GRIPPER, "paper"), 16)
    # the pairs across one prong whose finger would sit in the slot: contacts on the prong's inner wall
    inner_wall = (np.abs(np.abs(mids[:, 0] - axes[:, 0] * w / 2) - 0.003) < 1e-4) | (
        np.abs(np.abs(mids[:, 0] + axes[:, 0] * w / 2) - 0.003) < 1e-4
    )
    across_x = np.abs(axes[:, 0]) > 0.95
    sel = inner_wall & across_x
    assert sel.sum() > 10
    assert not fr[sel].any()


def test_paper_and_swept_differ_where_the_opening_hits_a_wall():
    """Grasping one prong of the U across its width: the contacts are free in `paper` mode (fingers of 10 mm
    fit beside the prong's outer face), but the 20 mm pre-grasp opening swings the inner finger into the slot
    wall region in `swept` mode."""
    g = GripperSpec(
        name="g",
        stroke=0.08,
        finger_width=0.01,
        finger_depth=0.01,
        finger_thickness=0.002,
        friction=0.5,
        pregrasp_clearance=0.03,
        palm_depth=0.0,
    )
    pts, nrm = _sample(_parts()["u"], 3000)
    mids, axes, w, inside = _candidates(pts, nrm)
    paper = free_rolls(pts, nrm, mids, axes, w, inside, collision_model(g, "paper"), 16).any(1)
    swept = free_rolls(pts, nrm, mids, axes, w, inside, collision_model(g, "swept"), 16).any(1)
    assert not np.any(swept & ~paper)  # swept only adds volume
    assert np.sum(paper & ~swept) > 0


def _face_offsets(rolls: int, w: float, every: int) -> np.ndarray:
    """Grasp-frame positions (candidate closing along +x at the origin, so that Y0 = +y and Z0 = +z) on the
    faces of the finger and palm boxes at the rolls k = 0, every, 2 every, .., and an ulp either side. One of the
    y, z coordinates is zero, so the reference's matrix product rounds exactly like the kernel. Among them are
    points that one roll counts as inside and the opposite roll (half a turn on) as outside, although the finger
    box is symmetric."""
    psi = roll_angles_rad(rolls)
    c, s = np.cos(psi), np.sin(psi)
    hy, hz = GRIPPER.finger_width / 2, GRIPPER.finger_depth / 2
    z_hi = -hz
    z_lo = z_hi - GRIPPER.palm_depth
    a = w / 2 + TOLERANCES.inner_margin
    b = min(w + GRIPPER.pregrasp_clearance, GRIPPER.stroke) / 2 + GRIPPER.finger_thickness
    out = []
    for k in range(0, rolls, every):
        for face in (hy, hz, -z_lo, -z_hi):
            for trig in (c[k], s[k]):
                if abs(trig) < 1e-3:
                    continue
                r = face / abs(trig)
                for v in (np.nextafter(r, 0.0), r, np.nextafter(r, 1.0)):
                    for x in (a, -b, 0.0):
                        for sign in (1.0, -1.0):
                            out.append([x, sign * v, 0.0])
                            out.append([x, 0.0, sign * v])
    return np.array(out)


@pytest.mark.parametrize("rolls, every", [(16, 1), (64, 8)])
@pytest.mark.parametrize("mode", ["swept", "paper"])
def test_free_rolls_exact_on_box_faces(mode, rolls, every):
    """Ties decide like the per-roll test: the half-turn symmetry and the node bounds never round differently.

    One sample point at the origin and one candidate per offset q, at midpoint -q (so that point - midpoint is
    exactly q)."""
    w = 0.03
    q = _face_offsets(rolls, w, every)
    pts = np.zeros((1, 3))
    mids, axes = -q, np.tile([1.0, 0.0, 0.0], (len(q), 1))
    widths, inside = np.full(len(q), w), np.zeros(len(q), bool)
    got = free_rolls(pts, pts, mids, axes, widths, inside, collision_model(GRIPPER, mode), rolls)
    expect = ref.free_rolls(pts, mids, axes, widths, inside, GRIPPER, mode, rolls)
    assert np.array_equal(got, expect)
    # the sample holds points on both sides of the faces
    assert expect.any() and not expect.all()
    # and points that the two halves of a symmetric pair of rolls judge differently
    h = rolls // 2
    assert np.any(expect[:, :h] != expect[:, h:])


def _larger_parts():
    parts = {"ring64": trimesh.creation.annulus(r_min=0.01, r_max=0.03, height=0.02, sections=64)}
    path = SHARED_MESHES / "tless_04.stl"
    if path.is_file():
        mesh = trimesh.load(path, force="mesh")
        mesh.apply_scale(0.001)  # mm
        parts["tless_04"] = mesh
    return parts


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["swept", "paper"])
@pytest.mark.parametrize("name", ["ring64", "tless_04"])
def test_free_rolls_equal_reference_on_larger_samples(name, mode):
    """4000 points, every kind of outcome: ~1600 candidates checked against the brute-force reference."""
    parts = _larger_parts()
    if name not in parts:
        pytest.skip(f"{name} not available (shared meshes missing)")
    pts, nrm = _sample(parts[name], 4000, seed=3)
    pts, nrm = pts[grid_order(pts, 0.04)], nrm[grid_order(pts, 0.04)]
    mids, axes, w, inside = _candidates(pts, nrm)
    fr = free_rolls(pts, nrm, mids, axes, w, inside, collision_model(GRIPPER, mode), 16)
    n_free = fr.sum(1)
    rng = np.random.default_rng(5)

    def some(mask, k):
        idx = np.nonzero(mask)[0]
        return rng.choice(idx, min(k, len(idx)), replace=False)

    sel = np.unique(
        np.concatenate(
            [some(np.ones(len(fr), bool), 500), some(n_free == 1, 300), some(n_free >= 8, 300), some(n_free == 0, 300)]
        )
    )
    expect = ref.free_rolls(pts, mids[sel], axes[sel], w[sel], inside[sel], GRIPPER, mode, 16)
    assert np.array_equal(fr[sel], expect)
    assert ((expect.sum(1) > 0) & (expect.sum(1) < 16)).any() and expect.any() and not expect.all()


def test_free_rolls_in_batches_equal_one_call():
    """The pipeline calls free_rolls in batches on the same points: the prepared tree and the blocker memo are
    reused between calls (hints only), and the result is the same as one call, and as a fresh process would give."""
    pts, nrm = _sample(_parts()["u"], 1500)
    mids, axes, w, inside = _candidates(pts, nrm)
    model = collision_model(GRIPPER, "swept")
    whole = free_rolls(pts, nrm, mids, axes, w, inside, model, 16)
    bounds = np.linspace(0, len(mids), 7).astype(int)
    parts = [
        free_rolls(pts, nrm, mids[a:b], axes[a:b], w[a:b], inside[a:b], model, 16)
        for a, b in zip(bounds[:-1], bounds[1:], strict=True)
    ]
    assert np.array_equal(np.concatenate(parts), whole)
    # reversed order of the batches (a different memo history) and a copy of the points (same content)
    back = [
        free_rolls(pts.copy(), nrm, mids[a:b], axes[a:b], w[a:b], inside[a:b], model, 16)
        for a, b in zip(bounds[-2::-1], bounds[:0:-1], strict=True)
    ]
    assert np.array_equal(np.concatenate(back[::-1]), whole)
    sel = np.arange(0, len(mids), max(1, len(mids) // 200))
    assert np.array_equal(
        whole[sel], ref.free_rolls(pts, mids[sel], axes[sel], w[sel], inside[sel], GRIPPER, "swept", 16)
    )


@pytest.mark.parametrize("mode", ["swept", "paper"])
def test_free_rolls_of_pairs_equals_free_rolls_on_numpys_geometry(mode):
    """The pipeline's entry point (point index pairs; the kernel derives the geometry) gives the very masks of
    free_rolls on midpoints, axes and widths made by numpy, on a part with many blocked and free rolls."""
    pts, nrm = _sample(_parts()["ring"], 1500)
    res = antipodal_pairs(
        pts, nrm, stroke=0.08, min_width=0.0, friction=0.5, safety_factor=1.5, inside=True, finger_thickness=0.01
    )
    assert len(res.i) > 1000 and res.inside.any() and not res.inside.all()
    d = pts[res.j] - pts[res.i]
    w = np.linalg.norm(d, axis=1)
    model = collision_model(GRIPPER, mode)
    want = free_rolls(pts, nrm, 0.5 * (pts[res.i] + pts[res.j]), d / w[:, None], w, res.inside, model, 16)
    got = free_rolls_of_pairs(pts, res.i, res.j, res.inside, model, 16)
    assert want.any() and not want.all()
    np.testing.assert_array_equal(got, want)
    assert free_rolls_of_pairs(pts, res.i[:0], res.j[:0], res.inside[:0], model, 16).shape == (0, 16)


@pytest.mark.parametrize("mode", ["swept", "paper"])
def test_mesh_free_rolls_of_pairs_equals_mesh_free_rolls_on_numpys_geometry(mode):
    """The mesh-exact check's pipeline entry point (point index pairs; the kernel derives the geometry) gives the
    very masks of mesh_free_rolls on midpoints, axes and widths made by numpy (outside and inside grasps, the
    approach region, every roll and random subsets to test)."""
    from graspgen.collision import approach_reach, build_tree, mesh_free_rolls, mesh_free_rolls_of_pairs

    mesh = _parts()["ring"]
    pts, nrm = _sample(mesh, 1500)
    tree = build_tree(mesh.vertices, mesh.faces)
    res = antipodal_pairs(
        pts, nrm, stroke=0.08, min_width=0.0, friction=0.5, safety_factor=1.5, inside=True, finger_thickness=0.01
    )
    assert len(res.i) > 1000 and res.inside.any() and not res.inside.all()
    d = pts[res.j] - pts[res.i]
    w = np.linalg.norm(d, axis=1)
    mids, axes = 0.5 * (pts[res.i] + pts[res.j]), d / w[:, None]
    model = collision_model(GRIPPER, mode, reach=approach_reach(pts) if mode == "swept" else 0.0)
    rng = np.random.default_rng(11)
    for free in (np.ones((len(w), 16), dtype=bool), rng.random((len(w), 16)) < 0.4):
        want = mesh_free_rolls(tree, mids, axes, w, res.inside, free, model)
        got = mesh_free_rolls_of_pairs(tree, pts, res.i, res.j, res.inside, free, model)
        assert want.any() and (want != free).any()  # the triangles block some rolls and leave others
        np.testing.assert_array_equal(got, want)
    empty = np.zeros((0, 16), dtype=bool)
    assert mesh_free_rolls_of_pairs(tree, pts, res.i[:0], res.j[:0], res.inside[:0], empty, model).shape == (0, 16)
    two = np.ones((2, 16), dtype=bool)
    with pytest.raises(ValueError, match="indices"):
        mesh_free_rolls_of_pairs(tree, pts, np.array([0, len(pts)]), np.array([5, 7]), np.zeros(2, bool), two, model)
    with pytest.raises(ValueError, match="one row per candidate"):
        mesh_free_rolls_of_pairs(
            tree, pts, np.array([0, 1]), np.array([5, 7]), np.zeros(3, bool), np.ones((2, 16), bool), model
        )


@pytest.mark.parametrize("rolls", [8, 12, 16, 64])
def test_any_free_rows_equal_numpy(rolls):
    """The pipeline's row test (8-byte words OR-ed as integers where the rows allow it) against ndarray.any."""
    from graspgen.collision import any_free as _any_free

    rng = np.random.default_rng(rolls)
    free = rng.random((5000, rolls)) < 0.02  # many rows without a free roll, some with one anywhere in the row
    assert 0 < free.any(axis=1).sum() < 5000
    np.testing.assert_array_equal(_any_free(free), free.any(axis=1))
    np.testing.assert_array_equal(_any_free(free[:, ::-1]), free.any(axis=1))  # not contiguous: numpy's path
    assert _any_free(free[:0]).shape == (0,)


def test_free_rolls_of_pairs_refuses_bad_indices():
    pts, _ = _sample(_parts()["box"], 200)
    model = collision_model(GRIPPER, "swept")
    ok = np.array([0, 1]), np.array([5, 7]), np.zeros(2, dtype=bool)
    assert free_rolls_of_pairs(pts, *ok, model, 16).shape == (2, 16)
    with pytest.raises(ValueError, match="indices"):
        free_rolls_of_pairs(pts, np.array([0, 200]), np.array([5, 7]), ok[2], model, 16)
    with pytest.raises(ValueError, match="indices"):
        free_rolls_of_pairs(pts, np.array([-1, 1]), np.array([5, 7]), ok[2], model, 16)
    with pytest.raises(ValueError, match="itself"):
        free_rolls_of_pairs(pts, np.array([3, 1]), np.array([3, 7]), ok[2], model, 16)
    with pytest.raises(ValueError, match="same length"):
        free_rolls_of_pairs(pts, np.array([0]), np.array([5, 7]), ok[2], model, 16)


def test_normals_shape_the_tree_not_the_masks():
    """With the points' normals the tree splits a part's faces apart at its edges: the same masks as without
    normals and as the reference, for much less finger work on the ring (flat faces meeting at edges)."""
    from graspgen.collision import free_rolls_stats

    pts, nrm = _sample(_parts()["ring"], 4000, seed=2)
    o = grid_order(pts, 0.04)
    pts, nrm = pts[o], nrm[o]
    res = antipodal_pairs(
        pts, nrm, stroke=0.08, min_width=0.0, friction=0.5, safety_factor=1.5, inside=False, finger_thickness=0.01
    )
    model = collision_model(GRIPPER, "swept")
    plain, work_plain = free_rolls_stats(pts, None, None, None, None, res.inside, model, 16, pairs=(res.i, res.j))
    shaped, work_shaped = free_rolls_stats(pts, nrm, None, None, None, res.inside, model, 16, pairs=(res.i, res.j))
    assert plain.any() and not plain.all()
    np.testing.assert_array_equal(shaped, plain)
    np.testing.assert_array_equal(free_rolls_of_pairs(pts, res.i, res.j, res.inside, model, 16, normals=nrm), plain)
    sel = np.arange(0, len(res.i), 97)
    d = pts[res.j[sel]] - pts[res.i[sel]]
    w = np.linalg.norm(d, axis=1)
    mids, axes = 0.5 * (pts[res.i[sel]] + pts[res.j[sel]]), d / w[:, None]
    np.testing.assert_array_equal(
        shaped[sel], ref.free_rolls(pts, mids, axes, w, res.inside[sel], GRIPPER, "swept", 16)
    )
    finger = work_shaped["finger_nodes"] + work_shaped["finger_points"]
    assert finger < 0.7 * (work_plain["finger_nodes"] + work_plain["finger_points"])


def test_free_rolls_refuses_bad_normals():
    pts, nrm = _sample(_parts()["box"], 200)
    model = collision_model(GRIPPER, "swept")
    i, j, inside = np.array([0, 1]), np.array([5, 7]), np.zeros(2, dtype=bool)
    with pytest.raises(ValueError, match=r"normals must be \(200, 3\)"):
        free_rolls_of_pairs(pts, i, j, inside, model, 16, normals=nrm[:-1])
    bad = nrm.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        free_rolls_of_pairs(pts, i, j, inside, model, 16, normals=bad)


def _mesh_free_rolls_brute(tree, mids, axes, widths, inside, model, rolls):
    """mesh_free_rolls without its tree: every triangle against every region box at every roll, by the kernel's
    own arithmetic (the roll-0 frame, the rotation per roll, the separating-axis test)."""
    from numba import njit

    from graspgen.collision._frame import roll0_basis
    from graspgen.collision._regions import finger_x_ranges, fixed_x_ranges, region_table
    from graspgen.collision._triangles import region_boxes
    from graspgen.collision._tritree import tri_box
    from graspgen.transforms import ROLL_REFERENCE_SWITCH

    @njit(cache=False)
    def brute(M, A, Wd, ins, T, regions, cos_k, sin_k, switch, out):
        R = cos_k.shape[0]
        nr = regions.rows.shape[0]
        rx = np.empty((nr, 2))
        boxes_c = np.empty((nr, 3))
        boxes_e = np.empty((nr, 3))
        v = np.empty((3, 3))
        w = np.empty((3, 3))
        fixed_x_ranges(rx, regions)
        for i in range(M.shape[0]):
            ax, ay, az = A[i, 0], A[i, 1], A[i, 2]
            yx, yy, yz, zx, zy, zz = roll0_basis(ax, ay, az, switch)
            finger_x_ranges(rx, ins[i], Wd[i], regions)
            region_boxes(regions, rx, boxes_c, boxes_e)
            for r in range(nr):
                bc, be = boxes_c[r], boxes_e[r]
                for t in range(T.shape[0]):
                    for c in range(3):
                        px, py, pz = T[t, c, 0] - M[i, 0], T[t, c, 1] - M[i, 1], T[t, c, 2] - M[i, 2]
                        v[c, 0] = px * ax + py * ay + pz * az
                        v[c, 1] = px * yx + py * yy + pz * yz
                        v[c, 2] = px * zx + py * zy + pz * zz
                    for rl in range(R):
                        ck, sk = cos_k[rl], sin_k[rl]
                        for c in range(3):
                            w[c, 0] = v[c, 0]
                            w[c, 1] = v[c, 1] * ck + v[c, 2] * sk
                            w[c, 2] = -v[c, 1] * sk + v[c, 2] * ck
                        if tri_box(w, bc, be):
                            out[i, rl] = False

    out = np.ones((len(mids), rolls), dtype=bool)
    psi = 2.0 * np.pi * np.arange(rolls) / rolls
    brute(
        mids,
        axes,
        widths,
        inside,
        tree.triangles,
        region_table(model),
        np.cos(psi),
        np.sin(psi),
        ROLL_REFERENCE_SWITCH,
        out,
    )
    return out


def test_mesh_tree_lists_each_small_nodes_distinct_vertices():
    """The exact range along the axis (the triangle walk) reads a node's distinct vertices: for every node of at most
    _EXACT_TRIANGLES triangles exactly the corners of its triangles, once each, and nothing for larger nodes (also
    with degenerate triangles dropped from the tree, which shift the faces' indices)."""
    from graspgen.collision import build_tree
    from graspgen.collision._tritree import EXACT_TRIANGLES as _EXACT_TRIANGLES

    ring = _parts()["ring"]
    faces = np.vstack([ring.faces, [[0, 0, 1], [2, 2, 2]]])  # two degenerate triangles, dropped by the tree
    for vertices, fs in ((ring.vertices, faces), (trimesh.creation.icosphere(subdivisions=4).vertices, None)):
        if fs is None:
            fs = trimesh.creation.icosphere(subdivisions=4).faces
        tree = build_tree(vertices, fs)
        assert len(tree) == len(fs) - (2 if fs is faces else 0)
        small = 0
        for k in range(len(tree.nodes)):
            start, count = tree.children[k, 2], tree.children[k, 3]
            listed = tree.verts[:, tree.vstart[k] : tree.vstart[k + 1]].T
            if count > _EXACT_TRIANGLES:
                assert len(listed) == 0
                continue
            small += 1
            corners = {tuple(v) for v in tree.triangles[start : start + count].reshape(-1, 3)}
            assert len(listed) == len(corners) and {tuple(v) for v in listed} == corners
        assert small > len(tree.nodes) // 2


@pytest.mark.parametrize("name", ["ring", "u", "cylinder", "box"])
def test_mesh_free_rolls_equal_brute_force(name):
    """The mesh-exact check's tree walk (its node tests and their cuts only prune) gives what testing every
    triangle at every roll gives, with and without the approach region, outside and inside grasps, with every
    roll to test and with random subsets."""
    from graspgen.collision import approach_reach, build_tree, mesh_free_rolls

    mesh = _parts()[name]
    pts, nrm = _sample(mesh, 700, seed=3)
    tree = build_tree(mesh.vertices, mesh.faces)
    rng = np.random.default_rng(5)
    for inside in (False, True):
        mids, axes, w, ins = _candidates(pts, nrm, inside=inside)
        if not len(mids):
            continue
        sel = rng.choice(len(mids), min(150, len(mids)), replace=False)
        mids, axes, w, ins = mids[sel], axes[sel], w[sel], ins[sel]
        for model in (
            collision_model(GRIPPER, "paper"),
            collision_model(GRIPPER, "swept"),
            collision_model(GRIPPER, "swept", reach=approach_reach(pts)),
        ):
            expect = _mesh_free_rolls_brute(tree, mids, axes, w, ins, model, 16)
            every = np.ones((len(mids), 16), dtype=bool)
            np.testing.assert_array_equal(mesh_free_rolls(tree, mids, axes, w, ins, every, model), expect)
            some = rng.random((len(mids), 16)) < 0.4
            np.testing.assert_array_equal(mesh_free_rolls(tree, mids, axes, w, ins, some, model), expect & some)
            if not inside:
                assert expect.any() and not expect.all()
