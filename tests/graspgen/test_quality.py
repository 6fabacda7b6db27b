"""Quality terms on analytic geometry, best-near-medoid selection, and its wiring into generate() / recluster()."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

import graspgen
from graspgen import quality
from graspgen.errors import InvalidParameterError
from graspgen.examples import example_part

from ..grippers import GRIPPER


def _plane(z: float, normal_z: float, n: int = 21) -> tuple[np.ndarray, np.ndarray]:
    g = np.linspace(-0.02, 0.02, n)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    return pts, np.tile([0.0, 0.0, normal_z], (len(pts), 1))


def _terms(contacts, normals, margin, com, pts, nrm, length=0.05):
    return quality.quality_terms(
        np.asarray(contacts, dtype=float),
        np.asarray(normals, dtype=float),
        np.asarray(margin, dtype=float),
        half_angle_deg=10.0,
        center_of_mass=np.asarray(com, dtype=float),
        length_scale=length,
        surface_points=pts,
        surface_normals=nrm,
        patch_radius=0.005,
    )


def test_terms_on_two_parallel_plates():
    top, ntop = _plane(0.01, 1.0)
    bottom, nbottom = _plane(-0.01, -1.0)
    pts, nrm = np.vstack([top, bottom]), np.vstack([ntop, nbottom])
    # a pair across the plates through the centre of mass: every term at its best but friction at half margin
    contacts = [[[0, 0, -0.01], [0, 0, 0.01]], [[0.02, 0, -0.01], [0.02, 0, 0.01]]]
    normals = [[[0, 0, -1], [0, 0, 1]], [[0, 0, -1], [0, 0, 1]]]
    t = _terms(contacts, normals, [5.0, 10.0], [0, 0, 0], pts, nrm)
    assert t[0] == pytest.approx([0.5, 1.0, 1.0])
    # 20 mm from the centre of mass with a 50 mm scale: 1 - 0.4; the patch at the plate's edge is still flat
    assert t[1] == pytest.approx([1.0, 0.6, 1.0])
    assert np.all((t >= 0) & (t <= 1))


def test_flatness_drops_at_an_edge_and_on_a_curve():
    box = trimesh.creation.box(extents=(0.04, 0.04, 0.04))
    pts, idx = trimesh.sample.sample_surface_even(box, 6000, seed=1)
    nrm = box.face_normals[idx]
    centre = [[[-0.02, 0, 0], [0.02, 0, 0]]]
    edge = [[[-0.02, 0, 0.0195], [0.02, 0, 0.0195]]]
    normals = [[[-1, 0, 0], [1, 0, 0]]]
    flat = _terms(centre, normals, [10.0], [0, 0, 0], pts, nrm)[0, 2]
    near_edge = _terms(edge, normals, [10.0], [0, 0, 0], pts, nrm)[0, 2]
    assert flat == pytest.approx(1.0)
    assert near_edge < 0.8
    cyl = trimesh.creation.cylinder(radius=0.006, height=0.05, sections=128)
    cp, ci = trimesh.sample.sample_surface_even(cyl, 8000, seed=1)
    curved = _terms([[[-0.006, 0, 0], [0.006, 0, 0]]], normals, [10.0], [0, 0, 0], cp, cyl.face_normals[ci])[0, 2]
    assert curved < 0.95


@pytest.mark.parametrize("radius", [0.002, 0.01, 0.05])
def test_point_flatness_equals_the_patch_flatness_at_sample_points(radius):
    """The per-point pass (used for every candidate) gives what the per-contact definition gives at each point."""
    cyl = trimesh.creation.cylinder(radius=0.012, height=0.03, sections=48)
    pts, fi = trimesh.sample.sample_surface(cyl, 3000, seed=2)
    nrm = cyl.face_normals[fi]
    got = quality.point_flatness(pts, nrm, radius)
    expect = quality._patch_flatness(pts, nrm, pts, nrm, radius)
    assert np.allclose(got, expect, rtol=0, atol=1e-12)
    if radius == 0.01:  # pads on the caps' flat faces and on the curved side differ
        assert got.min() < 0.99 < got.max()


def test_scores_weigh_the_terms():
    terms = np.array([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    assert quality.scores(terms) == pytest.approx([1.0, 0.0, quality.WEIGHTS.friction])
    assert sum(quality.WEIGHTS.to_dict().values()) == pytest.approx(1.0)


def test_best_near_medoid_stays_near_and_in_the_cluster():
    mids = np.array(
        [
            [0.0, 0.0, 0.0],  # 0: medoid of cluster (0, 0)
            [0.003, 0.0, 0.0],  # 1: near, better
            [0.004, 0.0, 0.0],  # 2: near, best
            [0.03, 0.0, 0.0],  # 3: far, even better: never chosen
            [0.001, 0.0, 0.0],  # 4: near and best of all, but another cluster
            [0.0, 0.0, 0.0],  # 5: same place, axis 40 deg off: not near
        ]
    )
    axes = np.array([[1, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [math.cos(0.7), math.sin(0.7), 0]])
    labels = np.array([[0, 0], [0, 0], [0, 0], [0, 0], [0, 1], [0, 0]])
    score = np.array([0.2, 0.5, 0.6, 0.9, 1.0, 0.95])
    out = quality.select_best_near_medoid(labels, np.array([0, 4]), np.array([[0, 0], [0, 1]]), score, mids, axes)
    assert out.tolist() == [2, 4]
    # a medoid that is already the best keeps its place
    score2 = score.copy()
    score2[0] = 0.7
    assert quality.select_best_near_medoid(labels, np.array([0]), np.array([[0, 0]]), score2, mids, axes).tolist() == [
        0
    ]


def test_generate_with_best_near_medoid_on_the_bar():
    part = example_part("bar")
    base = graspgen.generate(part, GRIPPER, points=2000, k1=6, k2=2)
    gs = graspgen.generate(part, GRIPPER, points=2000, k1=6, k2=2, select="best-near-medoid")
    # the default export keeps the paper's medoids, scored (the score orders them), with no stand-ins or simulation
    assert all(not ({"sim", "medoid"} & set(g)) and "quality" in g for g in base.grasps)
    assert "selection" not in base.stats and "validation" not in base.stats
    assert np.array_equal(base.candidates.quality_terms, gs.candidates.quality_terms)
    assert len(gs.grasps) == len(base.grasps)
    sel = gs.stats["selection"]
    assert sel["mode"] == "best-near-medoid" and sel["replaced"] >= 1
    assert sel["mean_score_selected"] > sel["mean_score_medoids"]
    c = gs.candidates
    score = quality.scores(c.quality_terms)
    base_medoids = dict(zip(map(tuple, (g["cluster"] for g in base.grasps)), base.candidates.medoids, strict=True))
    for g in gs.grasps:
        m = g["candidate"]
        assert tuple(c.labels[m]) == tuple(g["cluster"])  # still a member of its cluster
        assert g["quality"]["score"] == pytest.approx(score[m], abs=1e-6)
        assert score[m] >= score[base_medoids[tuple(g["cluster"])]]
        if "medoid" in g:
            assert g["medoid"] == base_medoids[tuple(g["cluster"])]
    # best first within each translation cluster by the score
    for t in {g["cluster"][0] for g in gs.grasps}:
        s = [g["quality"]["score"] for g in gs.grasps if g["cluster"][0] == t]
        assert s == sorted(s, reverse=True)
    # the torque term follows the distance of the closing axis from the centre of the bar
    mid = c.midpoints
    far = np.abs(mid[:, 0]) > 0.05
    near = np.abs(mid[:, 0]) < 0.005
    assert c.quality_terms[far, 1].max() < c.quality_terms[near, 1].min()


def test_recluster_with_quality(tmp_path):
    part = example_part("bar")
    gs = graspgen.generate(part, GRIPPER, points=1500, k1=4, k2=2, select="best-near-medoid")
    gs.save_candidates(tmp_path / "c.npz")
    again = graspgen.recluster(tmp_path / "c.npz", gs.to_json(), k1=4, k2=2, select="best-near-medoid")
    assert [g["candidate"] for g in again.grasps] == [g["candidate"] for g in gs.grasps]
    plain = graspgen.generate(part, GRIPPER, points=1500, k1=4, k2=2)
    # candidates stored without quality terms (an NPZ written before every candidate was scored)
    np.savez(tmp_path / "p.npz", **{k: v for k, v in plain.candidates.arrays().items() if k != "quality_terms"})
    unscored = graspgen.recluster(tmp_path / "p.npz", plain.to_json(), k1=4, k2=2)
    assert unscored.stats["export_order"] == "friction_margin" and "quality" not in unscored.grasps[0]
    with pytest.raises(InvalidParameterError, match="need the part"):
        graspgen.recluster(tmp_path / "p.npz", plain.to_json(), k1=4, k2=2, select="best-near-medoid")
    with_mesh = graspgen.recluster(
        tmp_path / "p.npz", plain.to_json(), k1=4, k2=2, select="best-near-medoid", mesh=part
    )
    assert with_mesh.stats["selection"]["mean_score_selected"] >= with_mesh.stats["selection"]["mean_score_medoids"]
    assert with_mesh.stats["export_order"] == "quality"


def test_bad_select_is_refused():
    with pytest.raises(InvalidParameterError, match="select"):
        graspgen.generate(trimesh.creation.box(extents=(0.03, 0.03, 0.03)), GRIPPER, units="m", select="best")
