"""generate() / recluster() on analytic parts: box, cylinder, too-wide part; frame, determinism, units."""

from __future__ import annotations

import json
import math
import time
import zipfile

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import graspgen
from graspgen.errors import Cancelled, InvalidParameterError, InvalidUnitsError
from graspgen.parts import load_part
from graspgen.pipeline import choose_roll
from graspgen.sampling import sample_surface
from graspgen.transforms import roll_basis

from ..grippers import GRIPPER
from . import reference as ref

ALPHA = math.atan(0.5) / 1.5


def _box(extents=(0.04, 0.03, 0.02)):
    return trimesh.creation.box(extents=list(extents))


def test_box_grasps_only_across_opposite_faces():
    gs = graspgen.generate(_box(), GRIPPER, units="m", points=1500, k1=4, k2=2)
    c = gs.candidates
    assert len(c) > 100 and len(gs.grasps) == 8
    # opposite faces: the contact normals are exactly antiparallel and the axis is within the cone of both
    n0, n1 = c.normals[:, 0], c.normals[:, 1]
    assert np.allclose(np.sum(n0 * n1, axis=1), -1.0, atol=1e-9)
    assert np.all(np.degrees(np.arccos(np.clip(np.sum(c.axes * n1, axis=1), -1, 1))) <= math.degrees(ALPHA) + 1e-9)
    # widths are the box's extents (30 mm or 40 mm; 20 mm fails: the 30 mm deep fingers would hit... no: all fit)
    widths = np.round(c.widths, 6)
    assert set(np.unique(np.round(widths / 0.01))) <= {2.0, 3.0, 4.0}


def test_no_grasp_from_a_face_to_an_adjacent_face():
    # an adjacent face pair has perpendicular normals: 90 deg is far outside the 17.7 deg cone
    gs = graspgen.generate(_box(), GRIPPER, units="m", points=1200, k1=2, k2=2)
    dots = np.sum(gs.candidates.normals[:, 0] * gs.candidates.normals[:, 1], axis=1)
    assert not np.any(np.abs(dots) < 0.5)


def test_cylinder_gives_diameter_grasps():
    d = 0.03
    cyl = trimesh.creation.cylinder(radius=d / 2, height=0.12, sections=96)  # 120 mm: caps beyond the stroke
    gs = graspgen.generate(cyl, GRIPPER, units="m", points=3000, k1=6, k2=2)
    w = gs.candidates.widths
    assert len(w) > 100
    # chords within the friction cone: d cos(alpha) <= w <= d / cos(alpha) (axis tilted along the cylinder)
    assert np.all(w >= d * math.cos(ALPHA) - 1e-3) and np.all(w <= d / math.cos(ALPHA) + 1e-3)
    assert np.median(w) == pytest.approx(d, rel=0.02)
    best = max(gs.grasps, key=lambda g: g["friction_margin_deg"])
    assert best["width"] == pytest.approx(d, rel=0.01)


def test_part_wider_than_the_stroke_everywhere():
    gs = graspgen.generate(_box((0.1, 0.1, 0.1)), GRIPPER, units="m", points=600)
    assert gs.grasps == []
    st_ = gs.stats
    assert st_["candidates"] == 0
    assert st_["rejected"]["friction"] + st_["rejected"]["outside"] + st_["rejected"]["stroke"] == st_["pairs_total"]
    assert st_["empty_reason"]["criterion"] == "stroke"
    assert "wider than the stroke" in st_["empty_reason"]["message"]
    assert st_["empty_reason"]["narrowest_antipodal_width"] == pytest.approx(0.1, abs=2e-3)


def test_export_matches_the_contract():
    gs = graspgen.generate(_box(), GRIPPER, units="m", points=800, k1=3, k2=2)
    d = json.loads(gs.to_json_bytes())
    assert d["format"] == "graspgen.grasp_set/1" and d["units"] == "m"
    assert set(d["object"]) >= {"name", "version", "sha256", "source_units"}
    assert set(d["params"]) == {
        "mass_kg",
        "density",
        "accel",
        "hold",
        "position_tolerance",
        "points",
        "friction",
        "safety_factor",
        "rolls",
        "k1",
        "k2",
        "inside",
        "collision",
        "seed",
    }
    assert d["params"]["friction"] == 0.5
    assert set(d["stats"]) >= {"points", "pairs_total", "rejected", "candidates", "timings_s"}
    assert set(d["stats"]["timings_s"]) >= {"sample", "pairs", "collision", "cluster"}
    assert d["stats"]["pairs_total"] == d["stats"]["points"] * (d["stats"]["points"] - 1) // 2
    for g in d["grasps"]:
        assert set(g) >= {
            "pose",
            "width",
            "contacts",
            "normals",
            "friction_margin_deg",
            "free_rolls_deg",
            "cluster",
            "cluster_size",
        }
        assert g["friction_margin_deg"] >= 0
    # best first within each translation cluster, by the quality score (docs/QUALITY.md), which every grasp carries
    assert d["stats"]["export_order"] == "quality"
    by_cluster: dict[int, list[float]] = {}
    for g in d["grasps"]:
        assert set(g["quality"]) >= {"score", "friction", "torque", "flatness"}
        by_cluster.setdefault(g["cluster"][0], []).append(g["quality"]["score"])
    assert all(v == sorted(v, reverse=True) for v in by_cluster.values())


def test_candidate_npz_is_byte_identical_for_the_same_run(tmp_path):
    kw = dict(units="m", points=600, k1=3, k2=2)
    graspgen.generate(_box(), GRIPPER, **kw).save_candidates(tmp_path / "a.npz")
    time.sleep(2.1)  # zip timestamps have a 2 s resolution: numpy's savez would differ by now
    graspgen.generate(_box(), GRIPPER, **kw).save_candidates(tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    with zipfile.ZipFile(tmp_path / "a.npz") as z:
        assert all(i.compress_type == zipfile.ZIP_DEFLATED for i in z.infolist())
        assert z.testzip() is None  # every member inflates with the standard zlib and matches its CRC


def test_candidate_npz_round_trip_and_recluster(tmp_path):
    gs = graspgen.generate(_box(), GRIPPER, units="m", points=800, k1=3, k2=2)
    gs.save_candidates(tmp_path / "c.npz")
    with np.load(tmp_path / "c.npz") as z:
        n = len(gs.candidates)
        assert z["contacts"].shape == (n, 2, 3) and z["free_rolls"].shape == (n, 16)
        assert z["labels"].dtype == np.int32 and z["medoids"].dtype == np.int64
        assert np.allclose(np.linalg.norm(z["axes"], axis=1), 1.0)
        # medoids are in export order
        exported = np.array([g["contacts"] for g in gs.grasps])
        assert np.allclose(z["contacts"][z["medoids"]], exported)
    again = graspgen.recluster(tmp_path / "c.npz", gs.to_json(), k1=3, k2=2, seed=0)
    assert again.grasps == gs.grasps
    other = graspgen.recluster(tmp_path / "c.npz", gs.to_json(), k1=2, k2=1, seed=5)
    assert len(other.grasps) == 2 and other.params.k1 == 2


def test_same_inputs_give_a_byte_identical_export():
    kw = dict(units="m", points=900, k1=3, k2=2, seed=7)
    a = graspgen.generate(_box(), GRIPPER, **kw).to_json()
    b = graspgen.generate(_box(), GRIPPER, **kw).to_json()
    a["stats"].pop("timings_s")
    b["stats"].pop("timings_s")
    assert json.dumps(a) == json.dumps(b)


def test_units_mm_and_m_give_identical_exports(tmp_path):
    # OBJ text with coordinates exact in both units
    box = _box((0.04, 0.03, 0.02))
    (tmp_path / "m.obj").write_text(
        "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in box.vertices.tolist())
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in box.faces.tolist())
    )
    (tmp_path / "mm.obj").write_text(
        "".join(f"v {x * 1000!r} {y * 1000!r} {z * 1000!r}\n" for x, y, z in box.vertices.tolist())
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in box.faces.tolist())
    )
    kw = dict(points=700, k1=3, k2=2)
    a = graspgen.generate(tmp_path / "m.obj", GRIPPER, units="m", object_name="box", **kw).to_json()
    b = graspgen.generate(tmp_path / "mm.obj", GRIPPER, units="mm", object_name="box", **kw).to_json()
    for d in (a, b):
        d["stats"].pop("timings_s")
        d.pop("object")
    assert json.dumps(a) == json.dumps(b)


def test_progress_reports_every_stage_and_cancel_stops():
    seen = []
    graspgen.generate(_box(), GRIPPER, units="m", points=500, k1=2, k2=1, progress=lambda s, f: seen.append((s, f)))
    stages = [s for s, f in seen if f == 1.0]
    assert stages == ["load", "sample", "pairs", "collision", "cluster", "export"]

    def cancel(stage, fraction):
        if stage == "collision":
            raise Cancelled()

    with pytest.raises(Cancelled):
        graspgen.generate(_box(), GRIPPER, units="m", points=500, progress=cancel)


def test_bad_parameters_and_units_are_refused():
    with pytest.raises(InvalidUnitsError):
        graspgen.generate(_box(), GRIPPER, units="furlong", points=500)
    with pytest.raises(InvalidParameterError):
        graspgen.generate(_box(), GRIPPER, units="m", points=50)
    with pytest.raises(InvalidParameterError):
        graspgen.generate(_box(), GRIPPER, units="m", safety_factor=0.5)
    with pytest.raises(InvalidParameterError):
        graspgen.generate(_box(), GRIPPER, units="m", collision="magic")


@pytest.mark.parametrize(
    "free, expected",
    [
        ([1, 1, 0, 0, 0, 0, 0, 0], 0),  # run {0,1}: middle index (length-1)//2 -> 0
        ([0, 1, 1, 1, 0, 0, 0, 0], 2),
        ([1, 0, 0, 0, 0, 0, 1, 1], 7),  # wraps: run 6,7,0 -> middle 7
        ([1, 1, 1, 1, 1, 1, 1, 1], 4),  # all free: half a turn
        ([1, 0, 0, 0, 1, 0, 0, 0], 4),  # tie of single rolls: closest to half a turn
    ],
)
def test_choose_roll(free, expected):
    assert choose_roll(np.array(free, dtype=bool)) == expected


def _check_grasp(g, gs, pts_ref=None):
    T = np.array(g["pose"])
    R = T[:3, :3]
    assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    c0, c1 = np.array(g["contacts"])
    n0, n1 = np.array(g["normals"])
    x = (c1 - c0) / np.linalg.norm(c1 - c0)
    assert np.allclose(T[:3, 3], (c0 + c1) / 2, atol=1e-15)
    assert np.allclose(R[:, 0], x, atol=1e-12)
    assert np.allclose(R[:, 1], np.cross(R[:, 2], R[:, 0]), atol=1e-12)
    # roll: Z = -sin(psi) Y0 + cos(psi) Z0 with the contract's Z0
    y0, z0 = roll_basis(x[None])
    psi = math.radians(g["roll_deg"])
    assert np.allclose(R[:, 2], -math.sin(psi) * y0[0] + math.cos(psi) * z0[0], atol=1e-12)
    assert round(g["roll_deg"], 6) in [round(v, 6) for v in g["free_rolls_deg"]]
    spec = gs.gripper
    alpha = math.atan(gs.friction) / gs.params.safety_factor
    w = np.linalg.norm(c1 - c0)
    assert g["width"] == pytest.approx(w, abs=1e-15)
    if g["mode"] == "outside":
        assert spec.min_width <= w <= spec.stroke
        assert n0 @ x < 0 < n1 @ x
        worst = max(math.acos(np.clip(-n0 @ x, -1, 1)), math.acos(np.clip(n1 @ x, -1, 1)))
    else:
        assert n0 @ x > 0 > n1 @ x
        worst = max(math.acos(np.clip(n0 @ x, -1, 1)), math.acos(np.clip(-n1 @ x, -1, 1)))
    assert worst <= alpha + 1e-12
    assert g["friction_margin_deg"] == pytest.approx(math.degrees(alpha - worst), abs=1e-9)


PARTS = {
    "box": lambda: _box((0.05, 0.03, 0.025)),
    "cylinder": lambda: trimesh.creation.cylinder(radius=0.012, height=0.05, sections=40),
    "ring": lambda: trimesh.creation.annulus(r_min=0.008, r_max=0.02, height=0.015, sections=40),
    "capsule": lambda: trimesh.creation.capsule(height=0.04, radius=0.01),
}


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    part=st.sampled_from(sorted(PARTS)),
    friction=st.floats(0.2, 1.0),
    safety=st.floats(1.0, 2.0),
    rolls=st.sampled_from([4, 8, 16]),
    mode=st.sampled_from(["paper", "swept"]),
    inside=st.booleans(),
    seed=st.integers(0, 5),
)
def test_every_exported_grasp_satisfies_all_criteria(part, friction, safety, rolls, mode, inside, seed):
    gs = graspgen.generate(
        PARTS[part](),
        GRIPPER,
        units="m",
        points=500,
        friction=friction,
        safety_factor=safety,
        rolls=rolls,
        collision=mode,
        inside=inside,
        k1=4,
        k2=2,
        seed=seed,
    )
    for g in gs.grasps:
        _check_grasp(g, gs)
    if gs.grasps:
        # free rolls recomputed by brute force against the same (deterministic) sample of the part
        sample = sample_surface(load_part(PARTS[part](), units="m"), 500, seed=seed)
        c = gs.candidates
        m = c.medoids
        expect = ref.free_rolls(
            sample.points, c.midpoints[m], c.axes[m], c.widths[m], c.inside[m], gs.gripper, mode, rolls
        )
        # the mesh-exact check (graspgen.collision) may only take rolls away from the point test's
        assert not np.any(c.free_rolls[m] & ~expect)
        assert c.free_rolls[m].any(axis=1).all()
    assert gs.stats["candidates"] == len(gs.candidates)
    rej = gs.stats["rejected"]
    assert sum(rej.values()) + gs.stats["candidates"] == gs.stats["pairs_total"]


def test_too_many_candidates_is_a_clear_error(monkeypatch):
    import graspgen.pipeline as pipeline

    monkeypatch.setattr(pipeline, "MAX_CANDIDATES", 100)
    monkeypatch.setattr(pipeline, "_PAIR_BLOCK", 500)
    seen = []
    with pytest.raises(InvalidParameterError, match=r"more than 100 collision-free candidates at 500 points") as e:
        graspgen.generate(_box(), GRIPPER, units="m", points=500, progress=lambda s, f: seen.append((s, f)))
    assert e.value.field == "points"
    assert "use fewer points" in str(e.value)
    # stopped within the collision stage, after the first block that crossed the limit
    coll = [f for s, f in seen if s == "collision"]
    assert coll and max(coll) < 1.0
    assert "cluster" not in [s for s, _ in seen]


def test_streaming_pairs_through_collision_in_blocks_changes_nothing(monkeypatch):
    """Blocks of a few hundred pairs (many blocks, ragged ends) give the very same candidates and grasps."""
    import graspgen.pipeline as pipeline

    kw = dict(units="m", points=600, k1=4, k2=2)
    whole = graspgen.generate(_box(), GRIPPER, **kw)
    monkeypatch.setattr(pipeline, "_PAIR_BLOCK", 337)
    seen = []
    blocked = graspgen.generate(_box(), GRIPPER, progress=lambda s, f: seen.append((s, f)), **kw)
    rej = whole.stats["rejected"]
    accepted = whole.stats["pairs_total"] - rej["stroke"] - rej["outside"] - rej["friction"]
    assert accepted > 337 * 3 and whole.stats["candidates"] > 0  # really several blocks
    for name in ("contacts", "normals", "free_rolls", "friction_margin_deg", "inside", "labels", "medoids"):
        assert np.array_equal(getattr(whole.candidates, name), getattr(blocked.candidates, name)), name
    assert whole.stats["rejected"] == blocked.stats["rejected"]
    assert [g["pose"] for g in whole.grasps] == [g["pose"] for g in blocked.grasps]
    coll = [f for s, f in seen if s == "collision"]
    assert len(coll) >= 11 and coll == sorted(coll) and coll[-1] == 1.0


def test_collision_reports_by_time_and_segments_change_nothing(monkeypatch):
    """The collision kernel runs in segments sized by its measured rate (a report about every _COLLISION_REPORT_S
    seconds): at a report interval of 0 every segment is the smallest, the reports come in order, and the
    candidates are the very same as in one call."""
    import graspgen.pipeline as pipeline

    kw = dict(units="m", points=600, k1=4, k2=2)
    whole = graspgen.generate(_box(), GRIPPER, **kw)
    monkeypatch.setattr(pipeline, "_COLLISION_REPORT_S", 0.0)
    monkeypatch.setattr(pipeline, "_MIN_SEGMENT", 100)
    seen = []
    cut = graspgen.generate(_box(), GRIPPER, progress=lambda s, f: seen.append((s, f)), **kw)
    coll = [f for s, f in seen if s == "collision"]
    # the first tenth in one call, then 100 pairs per call: several times the ten reports of a tenth each
    assert len(coll) > 3 * pipeline._COLLISION_BATCHES and coll == sorted(coll) and coll[-1] == 1.0
    for name in ("contacts", "free_rolls", "labels", "medoids"):
        assert np.array_equal(getattr(whole.candidates, name), getattr(cut.candidates, name)), name


def test_a_point_cloud_is_validated_as_the_convex_hull_of_its_points(monkeypatch):
    from graspgen import physics

    box = _box()
    points, faces = trimesh.sample.sample_surface_even(box, 3000, seed=0)
    part = load_part(_npz_bytes(points=points, normals=box.face_normals[faces]), units="m", file_type="npz")
    simulated = []
    prepare = physics.prepare_part

    def spy(mesh, *args, **kwargs):
        simulated.append(mesh)
        return prepare(mesh, *args, **kwargs)

    monkeypatch.setattr(physics, "prepare_part", spy)
    gs = graspgen.generate(part, GRIPPER | {"grip_force": 20.0}, points=800, k1=2, k2=1, validate=True, mass_kg=0.2)
    (mesh,) = simulated
    assert mesh.is_watertight and mesh.volume == pytest.approx(box.volume, rel=0.02)
    note = "a point cloud has no surface to simulate: simulated as the convex hull of its points"
    assert f"validation: {note}" in gs.stats["warnings"] and note in gs.stats["validation"]["part"]["note"]


def _npz_bytes(**arrays) -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()
