"""`validate=True` for suction cups: every exported cup simulated in MuJoCo (graspgen.physics_suction) under
`suction_validation_set`; a cup that fails is replaced by the nearest member of its cluster that holds (up to
`repair_limit` members tried, nearest first), as the jaws' validation does (pipeline._validate). The simulation
shares no code with the criteria: it seals the cup's springs on the part's triangles with its own rays (the spring
model is criterion seal's) and lifts, turns and loads the part with its mass and the cup's vacuum, without hold's
wrench model (docs/HOLD.md, "Suction: physics validation")."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import trimesh

from .. import quality
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
    """InvalidParameterError naming the field when `validate` cannot run for a cup: MuJoCo missing (the `validate`
    extra) or no mass for the part."""
    from ..physics import check_validation_inputs as check

    check(mass, engines=("mujoco",))


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

        geometry = (cands.midpoints, cands.approach)
        rep = quality.repair_by_simulation(selected, clusters, labels, geometry, limit, simulate, start=0.05)
        final, results, first, simulated = rep.selected, rep.results, rep.first, rep.simulated
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
