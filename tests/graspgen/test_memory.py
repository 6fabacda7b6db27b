"""Memory guard (issue 16.4): the probe's candidate estimate against real runs, and the largest count that fits."""

from __future__ import annotations

import pytest

import graspgen
from graspgen import memory
from graspgen.examples import EXAMPLE_GRIPPER, example_part
from graspgen.memory import MemoryLimitError


@pytest.fixture(scope="module")
def ring():
    return example_part("thick-ring")


@pytest.fixture(scope="module")
def ring_probe(ring):
    return memory.probe(ring, EXAMPLE_GRIPPER)


@pytest.mark.slow
@pytest.mark.parametrize("points", [3000, 6000])
def test_estimated_candidates_cover_a_real_run_without_gross_excess(ring, ring_probe, points):
    real = graspgen.generate(ring, EXAMPLE_GRIPPER, points=points, k1=2, k2=1).stats
    est = ring_probe.estimate(points)
    rej = real["rejected"]
    pairs = real["pairs_total"] - rej["stroke"] - rej["outside"] - rej["friction"]
    # the probe (2,000 points) is within a few per cent; the estimate adds memory.CANDIDATE_MARGIN (15 %)
    assert real["candidates"] <= est.candidates <= 1.5 * real["candidates"]
    pairs += real.get("exact", {}).get("friction_position_tolerance", 0)  # pairs in flight, as the probe counts
    assert 0.85 * pairs <= est.pairs <= 1.15 * pairs


def test_the_estimate_grows_with_the_points_and_max_points_is_the_boundary(ring_probe):
    peaks = [ring_probe.estimate(n).peak_bytes for n in (100, 1000, 10_000, 100_000, 1_000_000)]
    assert peaks == sorted(peaks) and peaks[0] >= memory.BASE_BYTES
    budget = 2 * 2**30
    fit = ring_probe.max_points(budget)
    assert fit % 100 == 0 and 1000 < fit < 1_000_000
    assert ring_probe.estimate(fit).peak_bytes <= budget < ring_probe.estimate(fit + 100).peak_bytes
    assert ring_probe.max_points(memory.BASE_BYTES // 2) == 0
    assert ring_probe.max_points(10**15) == 1_000_000


def test_check_memory_names_the_largest_count_that_fits(ring, ring_probe):
    budget = ring_probe.estimate(20_000).peak_bytes
    ok = memory.check_memory(ring, EXAMPLE_GRIPPER, budget, points=20_000, the_probe=ring_probe)
    assert ok.peak_bytes <= budget
    with pytest.raises(MemoryLimitError) as err:
        memory.check_memory(ring, EXAMPLE_GRIPPER, budget, points=100_000, the_probe=ring_probe)
    e = err.value
    assert e.code == "memory-limit" and e.field == "points"
    assert 20_000 <= e.max_points < 20_100
    assert f"at most {e.max_points:,} points fit" in e.message and "100,000 points would need" in e.message
    assert isinstance(e, graspgen.errors.InvalidParameterError)  # CLI exit 2, API 422
