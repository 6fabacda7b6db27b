"""Coverage and diversity of a selection on hand-checkable candidate sets."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

import graspgen
from graspgen.coverage import LEVELS, axis_angles_deg, combined_distance, coverage, coverage_shares

from ..grippers import GRIPPER


def _axis(deg: float) -> list[float]:
    return [math.cos(math.radians(deg)), math.sin(math.radians(deg)), 0.0]


def test_shares_on_six_candidates():
    # selected: candidate 0 at the origin with axis +x
    mids = np.array(
        [
            [0.0, 0.0, 0.0],  # itself
            [0.009, 0.0, 0.0],  # 9 mm, same axis: covered at both levels
            [0.015, 0.0, 0.0],  # 15 mm: only at 2 cm
            [0.0, 0.0, 0.0],  # 40 deg: only at 45 deg
            [0.0, 0.0, 0.0],  # 170 deg = the reversed axis at 10 deg: covered at both
            [0.05, 0.0, 0.0],  # far away: never
        ]
    )
    axes = np.array([_axis(0), _axis(0), _axis(0), _axis(40), _axis(170), _axis(0)])
    shares = coverage_shares(mids, axes, np.array([0]))
    assert shares == pytest.approx((3 / 6, 5 / 6))


def test_everything_selected_covers_everything_and_nothing_selected_covers_nothing():
    rng = np.random.default_rng(3)
    mids = rng.uniform(-0.05, 0.05, size=(50, 3))
    axes = rng.normal(size=(50, 3))
    assert coverage_shares(mids, axes, np.arange(50)) == (1.0, 1.0)
    assert coverage_shares(mids, axes, np.array([], dtype=np.int64)) == (0.0, 0.0)


def test_coverage_grows_with_the_level_and_with_the_selection():
    rng = np.random.default_rng(4)
    mids = rng.uniform(-0.03, 0.03, size=(400, 3))
    axes = rng.normal(size=(400, 3))
    small = coverage_shares(mids, axes, np.arange(10))
    large = coverage_shares(mids, axes, np.arange(40))
    assert small[0] <= small[1] and large[0] <= large[1]
    assert large[0] >= small[0] and large[1] >= small[1]
    assert small[0] < 1.0


def test_diversity_figures():
    mids = np.array([[0.0, 0.0, 0.0], [0.004, 0.0, 0.0], [0.0, 0.03, 0.0]])
    axes = np.array([_axis(0), _axis(60), _axis(-5)])
    rep = coverage(mids, axes, np.array([0, 1, 2]))
    assert rep.min_pair_translation == pytest.approx(0.004)
    assert rep.min_pair_angle_deg == pytest.approx(5.0)
    # combined = max(dt / 1 cm, angle / 30 deg): pair (0,1) 2.0, (0,2) 3.0, (1,2) ~3.4
    assert rep.min_pair_combined == pytest.approx(2.0)
    assert combined_distance(mids[:1], axes[:1], mids[1:2], axes[1:2])[0, 0] == pytest.approx(2.0)
    js = rep.to_json()
    assert [lv["radius"] for lv in js["levels"]] == [r for r, _ in LEVELS]
    assert js["selected"] == 3 and js["candidates"] == 3
    one = coverage(mids, axes, np.array([0]))
    assert one.min_pair_translation is None and one.to_json()["min_pair_combined"] is None


def test_axis_angle_is_sign_invariant():
    a = np.array([_axis(20)])
    assert axis_angles_deg(a, -a)[0, 0] == pytest.approx(0.0, abs=1e-6)
    assert axis_angles_deg(a, np.array([_axis(110)]))[0, 0] == pytest.approx(90.0)


def test_generate_reports_coverage_in_stats():
    gs = graspgen.generate(
        trimesh.creation.box(extents=(0.04, 0.03, 0.02)), GRIPPER, units="m", points=1200, k1=4, k2=2
    )
    cov = gs.stats["coverage"]
    c = gs.candidates
    expected = coverage_shares(c.midpoints, c.axes, c.medoids)
    assert [lv["share"] for lv in cov["levels"]] == pytest.approx(expected)
    assert cov["selected"] == len(gs.grasps) and cov["candidates"] == len(c)
    assert 0.0 < cov["levels"][0]["share"] <= cov["levels"][1]["share"] <= 1.0
