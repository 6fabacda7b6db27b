"""Test parts with a known feature, built from boxes (metres)."""

from __future__ import annotations

import trimesh


def notched_plate(depth_mm: float = 2.0) -> trimesh.Trimesh:
    """A 100 x 100 mm plate, its top at z = depth_mm, with a groove 0.6 mm wide and depth_mm deep running along X
    from x = 13 to 20 mm at y = 1.17-1.77 mm: a cup of 30 mm centred at the origin has it crossing under its lip at
    5.6 degrees, midway between its lip points at 0 and 11.25 degrees, and no interior probe (at most 12.5 mm out)
    meets it. The top layer's boxes reach 0.1 mm into the base, so the groove's floor is the base's top face."""

    def slab(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> trimesh.Trimesh:
        b = trimesh.creation.box(extents=(x1 - x0, y1 - y0, z1 - z0))
        b.apply_translation(((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2))
        return b

    mm = [
        slab(-50, 50, -50, 50, -8, 0),
        slab(-50, 13, -50, 50, -0.1, depth_mm),
        slab(13, 50, -50, 1.17, -0.1, depth_mm),
        slab(13, 50, 1.77, 50, -0.1, depth_mm),
        slab(20, 50, 1.17, 1.77, -0.1, depth_mm),
    ]
    plate = trimesh.util.concatenate(mm)
    plate.apply_scale(1e-3)
    return plate
