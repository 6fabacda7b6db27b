"""`validate=True` for suction cups: every exported cup simulated in MuJoCo (graspgen.physics_suction) under
`suction_validation_set`; a cup that fails is replaced by the nearest member of its cluster that holds (up to
`repair_limit` members tried, nearest first), as the jaws' validation does (pipeline._validate). The simulation
shares no formula with the criteria: it seals a ring of lip points on the part's triangles and lifts, turns and
loads the part with its mass and the cup's vacuum (docs/HOLD.md, "Suction: physics validation")."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import trimesh

from .. import quality
from ..errors import InvalidParameterError
from ..params import QualityOptions
from ._export import SuctionCandidates
from ._spec import SuctionSpec

__all__ = ["check_validation_inputs", "suction_validator", "Validator"]

#: progress(stage, fraction), as generate() reports it
Progress = Callable[[str, float], None]

#: (candidates, labels (n, 2), selected medoids (k,), their clusters (k, 2), stats, progress) -> the selection after
#: repair and each selected cup's outcome (physics_suction.SuctionSimResult)
Validator = Callable[
    [SuctionCandidates, np.ndarray, np.ndarray, np.ndarray, dict[str, Any], Progress], tuple[np.ndarray, list[Any]]
]


def check_validation_inputs(mass: float | None) -> None:
    """InvalidParameterError naming the field when `validate` cannot run: MuJoCo missing (the `validate` extra) or
    no mass for the part."""
    try:  # the `validate` extra: the library alone does not install it
        import mujoco  # noqa: F401
    except ImportError as exc:
        raise InvalidParameterError(
            f"validate needs {exc.name}: pip install 'graspgen[validate]'", field="validate"
        ) from None
    if mass is None:
        raise InvalidParameterError("validate needs the part's mass: give mass_kg or density", field="mass_kg")


def suction_validator(
    mesh: trimesh.Trimesh,
    spec: SuctionSpec,
    *,
    mass_kg: float,
    friction: float,
    seed: int,
    options: QualityOptions,
    poses: Callable[[SuctionCandidates, np.ndarray], np.ndarray],
) -> Validator:
    """The validation step of one suction run on `mesh` (metres) with the cup `spec`, the part's mass and the run's
    friction coefficient; `poses(cands, idx)` gives the exported poses (k, 4, 4) of candidates idx."""

    def run(
        cands: SuctionCandidates,
        labels: np.ndarray,
        selected: np.ndarray,
        clusters: np.ndarray,
        stats: dict[str, Any],
        report: Progress,
    ) -> tuple[np.ndarray, list[Any]]:
        import mujoco

        from .. import physics, physics_suction

        report("validate", 0.0)
        cup = physics_suction.SuctionCup.of(spec)
        sim_part = physics_suction.prepare_suction_part(mesh, mass_kg=mass_kg)
        checks = physics_suction.suction_validation_set(friction)
        limit = options.repair_limit

        def simulate(idx: np.ndarray, lo: float, hi: float) -> list[Any]:
            grid = physics_suction.simulate_suction(
                sim_part,
                poses(cands, idx),
                cup,
                perturbations=checks,
                seed=seed,
                keys=idx,
                workers=options.sim_workers,
                progress=lambda done, total: report("validate", lo + (hi - lo) * done / max(total, 1)),
            )
            return physics.first_failures(grid, checks)

        first_hi = 0.55 if limit else 1.0
        results = simulate(selected, 0.05, first_hi)
        first = list(results)
        simulated = len(selected)
        final = selected.copy()
        alternatives: dict[int, np.ndarray] = {}
        for r, res in enumerate(results):
            if res.success or limit == 0:
                continue
            t, k = clusters[r]
            members = np.flatnonzero((labels[:, 0] == t) & (labels[:, 1] == k))
            members = members[members != selected[r]]
            ordered, _ = quality.members_by_distance(members, int(selected[r]), cands.midpoints, cands.approach)
            alternatives[r] = ordered[:limit]
        for j in range(limit):
            rows = [r for r, alts in alternatives.items() if not results[r].success and j < len(alts)]
            if not rows:
                break
            idx = np.array([alternatives[r][j] for r in rows], dtype=np.int64)
            simulated += len(idx)
            lo = first_hi + (1.0 - first_hi) * j / limit
            for r, m, res in zip(rows, idx, simulate(idx, lo, lo + (1.0 - first_hi) / limit), strict=True):
                if res.success:
                    final[r], results[r] = m, res
        report("validate", 1.0)
        stats["validation"] = {
            **physics_suction.summarise_suction(results),
            "first_pass": physics_suction.summarise_suction(first),
            "repaired": int(np.sum(final != selected)),
            "repair_limit": limit,
            "simulated": simulated,
            "members": [p.name for p in checks],
            "failed_under": {p.name: sum(not r.success and r.member == p.name for r in results) for p in checks},
            "mass_kg": mass_kg,
            "vacuum_pa": float(spec.vacuum),
            "engine": f"mujoco {mujoco.__version__}",
        }
        return final, results

    return run
