"""The shipped example parts, built from trimesh primitives and revolved profiles, in metres.

Every example is a closed, consistently wound surface with outward normals and positive volume, built without
booleans (no boolean engine is a dependency): single primitives, revolved 2D profiles, and, for the ring screw,
two disjoint closed bodies.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import cast

import numpy as np
import trimesh

from .errors import InvalidParameterError
from .parts import Part, load_part

__all__ = [
    "EXAMPLES",
    "EXAMPLE_GRIPPER",
    "EXAMPLE_CUP",
    "example_part",
    "ring_screw",
    "bar",
    "flanged_bushing",
    "thick_ring",
]


def ring_screw() -> trimesh.Trimesh:
    """An M8-like eye bolt, 21 x 14 x 47.5 mm: a threaded-looking shank with a collar and an eye on top.

    The shank is one revolved profile (the thread is a stack of revolved ridges, not a helix). The eye is a
    torus (centre-line radius 8 mm, wire radius 2.5 mm) standing in the xz-plane 0.5 mm above the shank's flat
    top: without a boolean union the two bodies cannot share a surface, and a small gap keeps each one closed
    without any face lying inside the other.
    """
    r_minor, r_major, pitch = 0.0034, 0.0040, 0.00125
    profile = [(0.0, 0.0), (0.0032, 0.0)]
    for k in range(31):  # ridges from z = 0.5 mm to 19.2 mm
        profile.append((r_major if k % 2 else r_minor, 0.0005 + k * pitch / 2))
    profile += [
        (r_minor, 0.020),
        (0.007, 0.020),  # collar
        (0.007, 0.023),
        (0.004, 0.023),  # neck
        (0.004, 0.026),
        (0.0, 0.026),
    ]
    shank = _revolve(np.array(profile), sections=64)
    ring_radius, wire_radius, gap = 0.008, 0.0025, 0.0005
    centre_z = 0.026 + gap + wire_radius + ring_radius
    # torus axis along +y, so the eye stands in the xz-plane like a real eye bolt's
    to_xz = trimesh.transformations.rotation_matrix(np.pi / 2, [1.0, 0.0, 0.0])
    to_xz[2, 3] = centre_z
    eye = trimesh.creation.torus(ring_radius, wire_radius, major_sections=64, minor_sections=24, transform=to_xz)
    # concatenate is typed to return any Geometry; of meshes it gives a Trimesh
    return _finish(cast(trimesh.Trimesh, trimesh.util.concatenate([shank, eye])))


def bar() -> trimesh.Trimesh:
    """A rectangular bar, 120 x 20 x 10 mm, centred at the origin."""
    return _finish(trimesh.creation.box(extents=(0.120, 0.020, 0.010)))


def flanged_bushing() -> trimesh.Trimesh:
    """A flanged bushing: bore 12 mm, body 20 mm, flange 32 x 3 mm, 20 mm long; a revolved L-shaped profile."""
    profile = np.array(
        [
            (0.006, 0.0),
            (0.010, 0.0),
            (0.010, 0.017),
            (0.016, 0.017),
            (0.016, 0.020),
            (0.006, 0.020),
            (0.006, 0.0),
        ]
    )
    return _finish(_revolve(profile, sections=96))


def thick_ring() -> trimesh.Trimesh:
    """The benchmark part: an annulus with inner radius 10 mm, outer radius 30 mm, height 20 mm."""
    return _finish(trimesh.creation.annulus(r_min=0.010, r_max=0.030, height=0.020, sections=128))


#: name -> builder of a fresh mesh in metres
#: the example gripper (metres), as in examples/pgn-80.json: the contract's PGN-80-like parallel gripper
EXAMPLE_GRIPPER: dict[str, object] = {
    "name": "pgn-80",
    "stroke": 0.08,
    "min_width": 0.0,
    "finger_width": 0.02,
    "finger_depth": 0.03,
    "finger_thickness": 0.01,
    "palm_depth": 0.02,
    "palm_width": 0.02,
    "friction": 0.5,
    "pregrasp_clearance": 0.02,
    "grip_force": 20.0,
}

#: the contract's suction cup (examples/cup-30.json): a 30 mm cup at 60 kPa on a round tool
EXAMPLE_CUP: dict[str, object] = {
    "name": "cup-30",
    "kind": "suction",
    "cup_radius": 0.015,
    "cup_height": 0.02,
    "max_strain": 0.1,
    "vacuum": 60000,
    "friction": 0.5,
    "tool": {"radius": 0.012, "length": 0.12},
    "pregrasp_clearance": 0.03,
}

EXAMPLES: dict[str, Callable[[], trimesh.Trimesh]] = {
    "ring-screw": ring_screw,
    "bar": bar,
    "flanged-bushing": flanged_bushing,
    "thick-ring": thick_ring,
}


def example_part(name: str) -> Part:
    """The example `name` as a `Part` (source units 'm', sha256 of its binary STL export; deterministic)."""
    if name not in EXAMPLES:
        raise InvalidParameterError(f"unknown example {name!r}: choose one of " + ", ".join(EXAMPLES), field="example")
    return load_part(EXAMPLES[name](), units="m", name=name)


def _revolve(profile: np.ndarray, *, sections: int) -> trimesh.Trimesh:
    """Revolve a (radius, z) profile about +z; a profile that does not end on the axis must be closed."""
    return trimesh.creation.revolve(profile, sections=sections)


def _finish(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh.merge_vertices()
    if mesh.volume < 0.0:  # revolve's orientation follows the profile's winding
        mesh.invert()
    return mesh
