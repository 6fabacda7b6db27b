"""Length units: parsing and conversion to metres, in one place."""

from __future__ import annotations

import numpy as np

from .errors import InvalidUnitsError

__all__ = ["UNIT_SCALE", "to_metres_scale", "to_metres", "extents_under_each_unit"]

#: metres per unit
UNIT_SCALE: dict[str, float] = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "in": 0.0254}


def to_metres_scale(units: str | None) -> float:
    """Metres per unit for `units` (one of mm, cm, m, in); refuses anything else, never guesses."""
    if units is None:
        raise InvalidUnitsError("units are required: one of " + ", ".join(UNIT_SCALE), field="units")
    key = str(units).strip().lower()
    if key not in UNIT_SCALE:
        raise InvalidUnitsError(f"unknown units {units!r}: use one of " + ", ".join(UNIT_SCALE), field="units")
    return UNIT_SCALE[key]


#: units per metre where that is a whole number: dividing by it is correctly rounded, so 20 mm becomes exactly
#: the double nearest 0.02 (as "0.02" in a metre file does); multiplying by 0.001 would not always be
_PER_METRE = {"mm": 1000.0, "cm": 100.0, "m": 1.0}


def to_metres(values: np.ndarray, units: str) -> np.ndarray:
    """Lengths in `units` -> metres (float64); the same part in mm and in m gives the same numbers."""
    scale = to_metres_scale(units)
    key = str(units).strip().lower()
    values = np.asarray(values, dtype=np.float64)
    return values / _PER_METRE[key] if key in _PER_METRE else values * scale


def extents_under_each_unit(extents_raw: np.ndarray) -> str:
    """One line showing a part's bounding-box extents (in file units) read as each unit, in millimetres."""
    parts = []
    for name, scale in UNIT_SCALE.items():
        mm = np.asarray(extents_raw, dtype=float) * scale * 1e3
        parts.append(f"as {name}: " + " x ".join(f"{v:.4g}" for v in mm) + " mm")
    return "; ".join(parts)
