"""The constants of the suction criteria in one place, and the probe layout of the seal test.

docs/HOLD.md "Suction cups: the model" explains each constant's role; the kernels read them from here only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SuctionModel", "SUCTION", "lip_points", "lip_slot_probes", "inner_probes", "depth_limits"]


@dataclass(frozen=True)
class SuctionModel:
    """Every tolerance and resolution of the suction criteria (metres unless named otherwise)."""

    #: points on the lip ring (the perimeter springs run between neighbours): 32 keeps a spring 2.9 mm long on a
    #: 30 mm cup, so a depth step of 1.35 mm between neighbours (an edge) already strains it by 10 %
    lip_points: int = 32
    #: the spacing of the interior probes (rings between the centre and the lip): a hole of diameter above about
    #: 1.5 x this is always hit by a probe (the probes' covering radius is about 0.71 x the spacing)
    probe_spacing: float = 2.5e-3
    #: at most this many interior rings (a large cup gets a coarser grid rather than thousands of probes)
    max_rings: int = 12
    #: the surface inside the ring may lie this far beyond the deepest lip point (an engraving, a shallow dimple);
    #: deeper is a hole, a slot or a gap under the cup (blind or through: the mesh cannot always tell, and the
    #: vacuum model needs the part's face under the cup)
    recess_depth: float = 1.0e-3
    #: the spacing of the probes on the lip circle between its points: the surface there may lie at most
    #: `recess_depth` beyond the deeper of the two neighbouring lip points (the lip, about 1 mm thick, bridges a
    #: shallower groove). Deeper is a slot, a groove or a pit under the lip: a channel the air leaks through,
    #: narrower than the lip points' spacing (2.9 mm on a 30 mm cup); one 0.5 mm wide or wider crossing the lip
    #: meets at least one probe
    lip_slot_spacing: float = 0.5e-3
    #: the cup's solid in criterion collision starts this far behind the lip's shallowest point (the lip itself
    #: touches the part, and the bellows follow it)
    lip_clearance: float = 0.5e-3
    #: tilted approaches per point with max_tilt_deg, evenly around the cone
    tilt_azimuths: int = 6
    #: radians: a tilt within this of max_tilt_deg still passes (rounding of the lip plane's fit)
    tilt_slack: float = 1.0e-9
    #: relative guard band of the exact tests (far beyond the rounding of their arithmetic)
    guard: float = 1.0e-9


SUCTION = SuctionModel()


def lip_points(radius: float, model: SuctionModel = SUCTION) -> np.ndarray:
    """(N, 2) float64: the lip ring's points in the cup's (x, y) plane, at angles 2 pi k / N from +X, metres."""
    n = model.lip_points
    k = np.arange(n, dtype=np.float64)
    ang = 2.0 * math.pi * k / n
    return np.column_stack([[radius * math.cos(t) for t in ang], [radius * math.sin(t) for t in ang]])


def lip_slot_probes(radius: float, model: SuctionModel = SUCTION) -> np.ndarray:
    """(N m, 2) float64: probes on the lip circle at angles 2 pi q / (N m) from +X, metres: m per arc between
    neighbouring lip points (N = lip_points), m = ceil(chord / lip_slot_spacing); every m-th is a lip point."""
    n = model.lip_points
    chord = 2.0 * radius * math.sin(math.pi / n)
    per = max(math.ceil(chord / model.lip_slot_spacing), 1)
    ang = [2.0 * math.pi * q / (n * per) for q in range(n * per)]
    return np.column_stack([[radius * math.cos(t) for t in ang], [radius * math.sin(t) for t in ang]])


def inner_probes(radius: float, model: SuctionModel = SUCTION) -> np.ndarray:
    """(M, 2) float64: the interior probes, metres: the centre and J rings at radii j r / (J + 1), j = 1..J,
    J = min(ceil(r / spacing) - 1, max_rings), each with ceil(2 pi rho / spacing) points (at least 6), every other
    ring turned by half a step so that the gaps do not line up."""
    rings = max(min(math.ceil(radius / model.probe_spacing) - 1, model.max_rings), 1)
    step = radius / (rings + 1)
    out = [(0.0, 0.0)]
    for j in range(1, rings + 1):
        rho = j * step
        count = max(math.ceil(2.0 * math.pi * rho / max(step, model.probe_spacing)), 6)
        turn = 0.5 if j % 2 else 0.0
        for k in range(count):
            t = 2.0 * math.pi * (k + turn) / count
            out.append((rho * math.cos(t), rho * math.sin(t)))
    return np.asarray(out, dtype=np.float64)


def depth_limits(radius: float, height: float, max_strain: float) -> tuple[float, float]:
    """(lo, hi) metres: the depths d (along the approach, from the contact's plane) at which a lip point keeps its
    cone spring within max_strain. The spring runs from the cup's apex, `height` behind the contact on the axis,
    to the lip point: rest length l0 = sqrt(r^2 + h^2), length sqrt(r^2 + (h + d)^2), so
    (1 - e) l0 <= sqrt(r^2 + (h + d)^2) <= (1 + e) l0. When the cone can shorten by e without reaching the flat
    (the lower root is imaginary) the lip may rise up to the apex: lo = -h."""
    l0 = math.hypot(radius, height)
    hi = math.sqrt(((1.0 + max_strain) * l0) ** 2 - radius**2) - height
    short = ((1.0 - max_strain) * l0) ** 2 - radius**2
    lo = (math.sqrt(short) - height) if short > 0 else -height
    return lo, hi
