"""graspgen.recluster of a suction set (CONTRACT.md "Suction cups", API "cluster"): the stored candidates clustered
again with new k1 / k2 / seed give the export a fresh generate with those k1 / k2 / seed gives (timings aside), from
the NPZ alone; what a cup's clustering cannot use is refused with the field named."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh

import graspgen
from graspgen.errors import InvalidCandidatesError, InvalidParameterError
from graspgen.example_grippers import box, prism, stl_bytes
from graspgen.export import Candidates, npz_bytes
from graspgen.suction import SuctionGraspSet, load_suction_candidates
from tests.grippers import CUP, GRIPPER

#: an 80 x 60 x 30 mm box: the 30 mm cup seals on its faces
PART = trimesh.creation.box(extents=(0.08, 0.06, 0.03))


def _wall_part() -> trimesh.Trimesh:
    """A floor 100 x 60 x 10 mm (top at z = 0) with a wall x in [20, 30] mm rising 80 mm above it, in metres."""
    xz = [(-50, -10), (50, -10), (50, 0), (30, 0), (30, 80), (20, 80), (20, 0), (-50, 0)]
    v, f = prism([(z, x) for x, z in reversed(xz)], -30, 30, axis=1)
    return trimesh.Trimesh(np.asarray(v) * 1e-3, f, process=False)


def _without_timings(export: dict) -> str:
    """The export's canonical JSON but for the wall-clock figures."""
    out = json.loads(json.dumps(export))
    out["stats"].pop("timings_s")
    return json.dumps(out, indent=1)


def _runs(tmp_path: Path, **run: object) -> tuple[SuctionGraspSet, SuctionGraspSet, SuctionGraspSet]:
    """(a generate with k1=5, k2=1, its NPZ saved to tmp_path / "c.npz"; a fresh generate with k1=3, k2=2; the
    first's NPZ and export reclustered with k1=3, k2=2). The seed (the sample's and the clustering's) is 2 in all."""
    first = graspgen.generate(PART, CUP, units="m", points=700, k1=5, k2=1, seed=2, **run)
    first.save_candidates(tmp_path / "c.npz")
    fresh = graspgen.generate(PART, CUP, units="m", points=700, k1=3, k2=2, seed=2, **run)
    again = graspgen.recluster(tmp_path / "c.npz", first.to_json(), k1=3, k2=2, seed=2)
    return first, fresh, again


@pytest.mark.parametrize(
    "run",
    [{"mass_kg": 0.2, "friction": 0.45}, {"max_tilt_deg": 10.0}, {"density": 1000.0, "friction": 0.7}],
    ids=["mass", "tilt-no-mass", "density"],
)
def test_a_reclustered_suction_set_equals_a_fresh_generate(tmp_path, run):
    _, fresh, again = _runs(tmp_path, **run)
    assert isinstance(again, SuctionGraspSet) and len(fresh.grasps) >= 4
    assert _without_timings(again.to_json()) == _without_timings(fresh.to_json())
    assert set(again.stats["timings_s"]) == {"cluster", "total"}
    # the NPZ too: the same candidates with the new labels and medoids
    a, f = again.candidates.arrays(), fresh.candidates.arrays()
    assert a.keys() == f.keys()
    for key in a:
        assert np.array_equal(a[key], f[key]), key
    if "mass_kg" in run:  # friction and peel limits both occur: the stored codes are read back, not assumed
        assert set(np.unique(a["hold_limit"]).tolist()) == {0, 1}
        assert all(g["hold_limit"] in ("friction", "peel") for g in again.grasps)


def test_a_cup_on_a_body_mesh_reclusters_with_its_spec(tmp_path):
    """A body turns with the roll: poses at the middle of the widest run of free rolls; the spec with its file is
    given, as the export holds only its digest."""
    spec = {k: v for k, v in CUP.items() if k != "tool"} | {"geometry": {"units": "mm", "body": "body.stl"}}
    # a housing that reaches 25 mm towards +X only: beside the wall it is free at some rolls
    cup = graspgen.kinds.gripper_from_dict(spec, files={"body.stl": stl_bytes(box((-12, -12, -140), (25, 12, -20)))})
    part = _wall_part()
    first = graspgen.generate(part, cup, units="m", points=700, k1=5, k2=1, seed=3, mass_kg=0.2)
    fresh = graspgen.generate(part, cup, units="m", points=700, k1=6, k2=2, seed=3, mass_kg=0.2)
    again = graspgen.recluster(first.candidates, first.to_json(), k1=6, k2=2, seed=3, gripper=cup)
    assert _without_timings(again.to_json()) == _without_timings(fresh.to_json())
    assert any(len(g["free_rolls_deg"]) < 16 for g in again.grasps)  # the body meets the part at some rolls
    with pytest.raises(graspgen.errors.GraspgenError):  # the export names the body's file, not its triangles
        graspgen.recluster(first.candidates, first.to_json(), k1=4, k2=2)


def test_an_npz_without_hold_limits_gets_them_from_the_exports_load(tmp_path):
    """An NPZ written before hold_limit was stored: the hold kernel on the stored contacts with the load, friction
    and centre of mass of the export's stats.hold gives the run's limits (and its margins, to the bit)."""
    first, fresh, again = _runs(tmp_path, mass_kg=0.2, friction=0.45)
    old = io.BytesIO()
    with zipfile.ZipFile(tmp_path / "c.npz") as src, zipfile.ZipFile(old, "w") as dst:
        for item in src.infolist():
            if item.filename != "hold_limit.npy":
                dst.writestr(item, src.read(item))
    stored = load_suction_candidates(io.BytesIO(old.getvalue()))
    assert stored.hold_limit is None and stored.hold_margin is not None
    export = json.loads(json.dumps(first.to_json()))  # as stored: the numbers through JSON
    old_again = graspgen.recluster(stored, export, k1=3, k2=2, seed=2)
    assert _without_timings(old_again.to_json()) == _without_timings(fresh.to_json())
    assert np.array_equal(old_again.candidates.hold_limit, again.candidates.hold_limit)
    export["stats"].pop("hold")
    with pytest.raises(InvalidCandidatesError) as e:
        graspgen.recluster(stored, export, k1=3, k2=2)
    assert e.value.field == "hold_limit"


def test_the_stored_hold_limits_are_checked(tmp_path):
    gs = graspgen.generate(PART, CUP, units="m", points=400, k1=2, k2=1, mass_kg=0.2)
    arrays = gs.candidates.arrays()
    assert arrays["hold_limit"].dtype == np.int8
    arrays["hold_limit"] = np.full_like(arrays["hold_limit"], 7)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    with pytest.raises(InvalidCandidatesError) as e:
        load_suction_candidates(io.BytesIO(buf.getvalue()))
    assert e.value.field == "hold_limit"


#: (keywords, field): what a suction set's recluster refuses
REFUSED = [
    ({"validate": True}, "validate"),
    ({"select": "best-near-medoid"}, "select"),
    ({"mass_kg": 0.3}, "mass_kg"),
    ({"density": 1000.0}, "density"),
    ({"mesh": PART}, "mesh"),
    ({"gripper": graspgen.GripperSpec.from_dict(GRIPPER)}, "gripper"),
    ({"gripper": graspgen.kinds.gripper_from_dict({**CUP, "vacuum": 50000})}, "gripper"),
]


@pytest.mark.parametrize("keywords, field", REFUSED, ids=[f for _, f in REFUSED])
def test_what_a_cups_clustering_cannot_use_is_refused(tmp_path, keywords, field):
    gs = graspgen.generate(PART, CUP, units="m", points=400, k1=2, k2=1, mass_kg=0.2)
    gs.save_candidates(tmp_path / "c.npz")
    with pytest.raises(InvalidParameterError) as e:
        graspgen.recluster(tmp_path / "c.npz", gs.to_json(), k1=3, k2=1, **keywords)
    assert e.value.field == field


def _jaw_candidates(n: int = 3) -> Candidates:
    """n parallel-jaw candidates across the box's 60 mm side (the other kind's NPZ; no jaw run needed)."""
    x = np.linspace(-0.02, 0.02, n)
    contacts = np.stack([np.c_[x, np.full(n, -0.03), np.zeros(n)], np.c_[x, np.full(n, 0.03), np.zeros(n)]], axis=1)
    return Candidates(
        contacts=contacts,
        normals=np.stack([np.tile((0.0, -1.0, 0.0), (n, 1)), np.tile((0.0, 1.0, 0.0), (n, 1))], axis=1),
        free_rolls=np.ones((n, 16), dtype=bool),
        roll_angles_rad=np.arange(16) * (2 * np.pi / 16),
        friction_margin_deg=np.full(n, 20.0),
        inside=np.zeros(n, dtype=bool),
        labels=np.full((n, 2), -1, dtype=np.int32),
        medoids=np.zeros(0, dtype=np.int64),
    )


def test_candidates_of_the_other_kind_are_refused(tmp_path):
    cup = graspgen.generate(PART, CUP, units="m", points=400, k1=2, k2=1)
    jaw = _jaw_candidates()
    jaw_export = {**cup.to_json(), "gripper": GRIPPER, "params": {"k1": 2, "k2": 1}}
    for cands, export in ((jaw, cup.to_json()), (cup.candidates, jaw_export)):
        with pytest.raises(InvalidParameterError) as e:
            graspgen.recluster(cands, export, k1=2, k2=1)
        assert e.value.field == "candidates"
    with pytest.raises(InvalidParameterError) as e:  # a cup's spec for a parallel set
        graspgen.recluster(jaw, jaw_export, k1=2, k2=1, gripper=cup.gripper)
    assert e.value.field == "gripper"
    (tmp_path / "jaw.npz").write_bytes(npz_bytes(jaw.arrays()))
    with pytest.raises(InvalidCandidatesError, match="seal_strain"):  # a jaw NPZ under a suction export
        graspgen.recluster(tmp_path / "jaw.npz", cup.to_json(), k1=2, k2=1)


def test_a_reclustered_suction_set_is_recorded(tmp_path):
    gs = graspgen.generate(PART, CUP, units="m", points=400, k1=2, k2=1, mass_kg=0.2)
    again = graspgen.recluster(gs.candidates, gs.to_json(), k1=3, k2=1, recording=tmp_path / "r.rrd")
    assert again.grasps and (tmp_path / "r.rrd").stat().st_size > 0
    assert b"grasps/cups" in (tmp_path / "r.rrd").read_bytes()
