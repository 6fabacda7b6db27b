"""A job's peak memory, estimated before it runs (issue 16.4), and the largest point count that fits a budget.

Memory is dominated by the candidates: pairs passing criteria (a)-(d) are kept (contacts, normals, free rolls,
quality terms; clustering, coverage and the NPZ export work on all of them), and their number grows with the square
of the points, since the points within one stroke of each other are what pairs are made of. Pairs passing (a)-(c)
are collision-checked in blocks of at most 4 M (pipeline._PAIR_BLOCK), a bounded term; sampling is linear in the
points (weighted sample elimination keeps several candidates per point). The three phases follow each other, so
the estimate is the process's base plus the largest of them.

`probe()` runs the real pipeline once at `PROBE_POINTS` evenly spaced points (about 0.3 s warm) and keeps the
candidates and (a)-(c) pairs per point squared; `Probe.estimate(n)` scales them to n points and applies the byte
costs below, which were fitted to measured peaks (bench/bench_memory.py, docs/benchmarks.md; refit them when the
pipeline's arrays change) and err on the high side. The probe's own peak growth stands for what the part costs
whatever the point count (its triangle tree). Given a probe, everything is a pure function of the point count,
so the count `max_points()` names is one that `estimate()` accepts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from .errors import InvalidParameterError
from .gripper import GripperSpec
from .params import Params, QualityOptions, from_keywords, param_option
from .parts import Part

__all__ = [
    "Probe",
    "MemoryEstimate",
    "MemoryLimitError",
    "probe",
    "probe_params",
    "DENSITY_FIELDS",
    "estimate_peak_bytes",
    "check_memory",
    "PROBE_POINTS",
]

#: points of the probe run
PROBE_POINTS = 2000
#: a process running one job before it holds any of the job's arrays: interpreter, numpy/scipy, numba's compiled
#: kernels and LLVM, trimesh (measured 250-290 MB)
BASE_BYTES = 300 * 2**20
#: sampling, per point: weighted sample elimination's candidate points and neighbour lists (1.6 KB measured at
#: 100 k and 1 M points); freed before the pairs are made
BYTES_PER_SAMPLED_POINT = 1_700
#: the candidate phase (quality terms, clustering, coverage, export), per kept candidate at 16 rolls (344-374 B
#: measured from 30 k to 100 k points) and per roll beyond (the free-roll masks), plus the points' own arrays
BYTES_PER_CANDIDATE = 332
BYTES_PER_CANDIDATE_ROLL = 3
BYTES_PER_POINT = 100
#: the collision phase: per (a)-(c) pair in flight, at most `_BLOCK_PAIRS` of them (115-120 B measured), plus the
#: candidates kept so far (index pairs, roll masks)
BYTES_PER_PAIR = 125
BYTES_PER_KEPT_PAIR = 40
_BLOCK_PAIRS = 4_000_000
#: the probe's candidates per point squared are raised by this much: it can under-count by a few per cent
CANDIDATE_MARGIN = 1.15
#: the smallest and largest point counts Params accepts
_POINTS = param_option(Params, "points")
assert _POINTS.ge is not None and _POINTS.le is not None  # Params declares both bounds of `points`
_MIN_POINTS, _MAX_POINTS = int(_POINTS.ge), int(_POINTS.le)
#: the Params fields that change the candidates per point squared; the probe runs with these and the defaults of
#: the others (points, k1, k2 and seed do not change it; criterion (e) only removes candidates after the collision
#: stage, so leaving it out over-estimates both phases)
DENSITY_FIELDS = ("friction", "safety_factor", "rolls", "inside", "collision")


class MemoryLimitError(InvalidParameterError):
    """The job would need more memory than its budget; `max_points` is the largest point count that fits (0: none)."""

    code = "memory-limit"

    def __init__(self, message: str, *, max_points: int, estimate: MemoryEstimate, budget_bytes: int) -> None:
        super().__init__(message, field="points")
        self.max_points = max_points
        self.estimate = estimate
        self.budget_bytes = budget_bytes


@dataclass(frozen=True)
class MemoryEstimate:
    points: int
    peak_bytes: int  #: estimated peak resident memory of a process running the job
    candidates: int  #: expected collision-free candidates
    pairs: int  #: expected pairs passing (a)-(c)

    def to_dict(self) -> dict[str, Any]:
        return {
            "points": self.points,
            "peak_bytes": self.peak_bytes,
            "candidates": self.candidates,
            "pairs": self.pairs,
        }


@dataclass(frozen=True)
class Probe:
    """What one probe run found, per point squared; `estimate()` scales it to any point count."""

    probe_points: int
    candidates_per_n2: float
    pairs_per_n2: float
    rolls: int
    #: what the part itself costs, whatever the point count (its triangle tree, normal spreads): the peak growth of
    #: the probe run, measured where Linux lets a process reset its peak (/proc/self/clear_refs), else 0
    part_bytes: int = 0

    def estimate(self, points: int) -> MemoryEstimate:
        n = int(points)
        candidates = math.ceil(self.candidates_per_n2 * n * n)
        pairs = math.ceil(self.pairs_per_n2 * n * n)
        # the phases follow each other, each freeing the last one's arrays: the peak is the largest of them
        sampling = BYTES_PER_SAMPLED_POINT * n
        collision = BYTES_PER_PAIR * min(pairs, _BLOCK_PAIRS) + BYTES_PER_KEPT_PAIR * candidates
        kept = (BYTES_PER_CANDIDATE + BYTES_PER_CANDIDATE_ROLL * self.rolls) * candidates + BYTES_PER_POINT * n
        peak = BASE_BYTES + self.part_bytes + max(sampling, collision, kept)
        return MemoryEstimate(n, int(peak), candidates, pairs)

    def max_points(self, budget_bytes: int) -> int:
        """The largest point count (a multiple of 100 within Params' range of points) whose estimate fits; 0 when none
        does."""
        if self.estimate(_MIN_POINTS).peak_bytes > budget_bytes:
            return 0
        lo, hi = _MIN_POINTS // 100, _MAX_POINTS // 100  # in hundreds: the estimate grows with n
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if self.estimate(mid * 100).peak_bytes <= budget_bytes:
                lo = mid
            else:
                hi = mid - 1
        return lo * 100


def probe_params(params: Params) -> Params:
    """The parameters a probe for a run with `params` runs with: PROBE_POINTS points, one cluster, seed 0, the
    DENSITY_FIELDS of `params` and the defaults of the others. Two runs whose probe parameters are equal share a
    probe (services/common/memory_guard.py keys its cache on them)."""
    return Params(points=PROBE_POINTS, k1=1, k2=1, seed=0, **{k: getattr(params, k) for k in DENSITY_FIELDS})


def probe(
    part: Part,
    gripper: GripperSpec | dict[str, Any],
    params: Params | None = None,
    **run_params: Any,
) -> Probe:
    """Run the pipeline at PROBE_POINTS points of `part` and keep its candidate and pair counts per point squared.

    `params` (or generate()'s run-parameter keywords: the fields of Params and QualityOptions) are the run's; only
    their DENSITY_FIELDS change the probe (probe_params).
    """
    from .pipeline import generate

    params, _ = from_keywords("probe", run_params, (Params, params), (QualityOptions, None))
    run = probe_params(params)
    rss0 = _reset_peak()
    gs = generate(part, gripper, params=run)
    s = gs.stats
    m = max(int(s["points"]), 2)
    rej = s["rejected"]
    # the pairs streamed through the collision stage: those passing (a)-(c), before the position tolerance's
    # finer test of (c) removes some of them inside the stage (counted in rejected.friction and stats.exact)
    pairs = int(s["pairs_total"]) - int(rej["stroke"]) - int(rej["outside"]) - int(rej["friction"])
    pairs += int(s.get("exact", {}).get("friction_position_tolerance", 0))
    part_bytes = max(_status_bytes("VmHWM") - rss0, 0) if rss0 else 0
    # a point cloud with fewer points than asked gives m < PROBE_POINTS; scaling from it stays an over-estimate
    return Probe(m, CANDIDATE_MARGIN * int(s["candidates"]) / (m * m), pairs / (m * m), run.rolls, int(part_bytes))


def _status_bytes(field: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    return 0


def _reset_peak() -> int:
    """Reset this process's peak RSS to its current RSS and return that (0 where the system does not allow it)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return _status_bytes("VmRSS")
    except OSError:
        return 0


def estimate_peak_bytes(
    part: Part, gripper: GripperSpec | dict[str, Any], *, points: int, **params: Any
) -> MemoryEstimate:
    """The estimated peak memory of `generate(part, gripper, points=points, **params)` (see the module docstring)."""
    return probe(part, gripper, **params).estimate(points)


def check_memory(
    part: Part,
    gripper: GripperSpec | dict[str, Any],
    budget_bytes: int,
    *,
    points: int,
    the_probe: Probe | None = None,
    **params: Any,
) -> MemoryEstimate:
    """The estimate, or `MemoryLimitError` naming the largest point count that fits when it exceeds `budget_bytes`."""
    pr = the_probe if the_probe is not None else probe(part, gripper, **params)
    est = pr.estimate(points)
    if est.peak_bytes <= budget_bytes:
        return est
    raise limit_error(pr, est, budget_bytes)


def limit_error(pr: Probe, est: MemoryEstimate, budget_bytes: int) -> MemoryLimitError:
    fit = pr.max_points(budget_bytes)
    gib = 2**30
    advice = (
        f"at most {fit:,} points fit: use points <= {fit}"
        if fit
        else f"not even {_MIN_POINTS} points fit: raise the worker's memory budget"
    )
    return MemoryLimitError(
        f"{est.points:,} points would need about {est.peak_bytes / gib:.1f} GiB at the peak (about "
        f"{est.candidates:,} candidates), more than this worker's budget of {budget_bytes / gib:.1f} GiB; {advice}",
        max_points=fit,
        estimate=est,
        budget_bytes=budget_bytes,
    )
