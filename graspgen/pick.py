"""The pick query (CONTRACT.md, "Pick query"): world-frame grasps of a candidate set that fit a scene.

Every candidate of the set at every free roll is one *pair*. A query keeps the pairs whose approach axis (the grasp's
+Z in the world) lies within `approach.max_angle_deg` of `approach.direction`, and whose fingers and palm at the
grasp, and open fingers and palm at the pre-grasp (the grasp retreated `pregrasp_distance` along its -Z), lie on the
normal side of every plane. The survivors come best first in the set's quality order:

- `score`: the quality score (graspgen.quality.scores of the NPZ's `quality_terms`) when the set has quality terms,
  else the friction margin in degrees; higher is better;
- ties by the smaller approach angle (to 1e-9 degrees), then the smaller candidate index, then the smaller roll
  index.

`T_world_grasp = T_world_object @ T_object_grasp(candidate, roll)`, with the contract's grasp frame and roll basis
(graspgen.transforms).

A suction set (CONTRACT.md "Suction cups"; a SuctionSpec and candidates with one contact each) is queried the same
way: the cone applies to the grasp's +Z (the approach, into the part), the planes to the cup (a cylinder of
`cup_radius` from the lip at z = 0 back to -cup_height) and the tool behind it (a cylinder on the Z axis, or a body
mesh) at the grasp and at the pre-grasp. The lowest point of a cylinder of radius r from z0 to z1 along a unit
direction m of the grasp frame lies on a rim: min(z0 m_z, z1 m_z) - r sqrt(m_x^2 + m_y^2), exact; a body mesh's is
a vertex of its convex hull. The cup and tool keep their shape on the way in, and a point's height above a plane is
linear along the straight way in, so the grasp and the pre-grasp bound the whole approach. Scores: the hold margin
when criterion hold ran, else minus the seal strain (the export's order). A round tool is the same solid at every
roll: a candidate is then one pair, at roll 0 (the export's), with `any_roll` true (the robot may turn the tool
about +Z as it likes). `PickIndex` holds the pairs' object-frame axes once per set; a query turns the world-frame
direction and planes into the object frame and is then a few vector operations: the cone over every pair, the planes
over the pairs inside the cone. A box lies on the normal side of a plane exactly when its lowest corner does, and the
lowest corner's height is the centre's height minus the half extents weighted by |m|, where m is the plane normal in
the grasp frame (the brute-force test checks the 8 corners).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import libm
from .errors import InvalidParameterError
from .export import Candidates, GraspSet
from .gripper import GripperSpec
from .suction import SuctionSpec
from .transforms import approach_basis, matrix_to_quaternion_xyzw, roll_basis

__all__ = [
    "pick",
    "PickIndex",
    "PickQuery",
    "PickResult",
    "validate_pose",
    "DEFAULT_LIMIT",
    "MAX_LIMIT",
    "MAX_PLANES",
    "DEFAULT_PREGRASP_DISTANCE",
    "POSE_TOLERANCE",
    "PLANE_TOLERANCE",
]

DEFAULT_LIMIT = 10
MAX_LIMIT = 1000
MAX_PLANES = 64
#: metres the pre-grasp lies behind the grasp, along the grasp's -Z
DEFAULT_PREGRASP_DISTANCE = 0.05
#: a pose's rotation must be orthonormal with det +1 and its last row 0 0 0 1 within this
POSE_TOLERANCE = 1e-6
#: approach angles are compared rounded to this many decimals of a degree (the tie-break after the score)
ANGLE_DECIMALS = 9
#: metres a box corner may lie on the wrong side of a plane and still count as on it (rounding, not clearance)
PLANE_TOLERANCE = 1e-9


@dataclass(frozen=True, eq=False)
class PickIndex:
    """Every (candidate, free roll) pair of a candidate set, in the set's quality order (object frame).

    `frames` (k, 12) holds each pair's grasp axes X, Y, Z and origin P (object frame, metres) side by side, so that
    gathering the pairs inside a cone reads whole cache lines; `approach` (3, k) repeats the Z axes in float32 as
    contiguous component rows: the cone test over every pair is three multiply-adds over 12 bytes a pair (and no
    BLAS call, whose threads only contend on a busy host), with a slack that float32 cannot exceed; the pairs it
    keeps are then tested exactly in float64.

    A parallel set has `width` (k,) per pair; a suction set has none (None) and `cup` (its cup and tool). `columns`
    holds the per-candidate values each grasp reports (friction_margin_deg and hold_margin for jaws; hold_margin,
    seal_strain and tilt_deg for a cup), in the response's order.
    """

    gripper: GripperSpec | SuctionSpec
    candidate: np.ndarray  # (k,) int64, index into the candidate NPZ
    roll_index: np.ndarray  # (k,) int16, index into roll_angles_rad
    roll_angles_rad: np.ndarray  # (R,)
    frames: np.ndarray  # (k, 12) float64
    approach: np.ndarray  # (3, k) float32, the Z axes (a conservative prefilter)
    width: np.ndarray | None  # (k,) contact distance, metres; None for a suction set
    score: np.ndarray  # (k,)
    rank: np.ndarray  # (k,) int64, position in the quality order (score, candidate, roll)
    by_rank: np.ndarray  # (k,) int64, the pairs in the quality order (the inverse of rank)
    labels: np.ndarray  # (n, 2) int32 per candidate
    medoid: np.ndarray  # (n,) bool per candidate: an exported representative
    columns: dict[str, np.ndarray]  # name -> (n,) per candidate, reported with each grasp
    score_source: str  # "quality" | "friction_margin_deg" | "hold_margin" | "seal_strain"
    candidates_total: int
    cup: _Cup | None = None  # a suction set's cup and tool

    @classmethod
    def build(cls, candidates: Any, gripper: GripperSpec | SuctionSpec) -> PickIndex:
        """The pairs of `candidates` (graspgen.export.Candidates for a parallel gripper; a suction set's candidates,
        with one contact each, for a SuctionSpec)."""
        if isinstance(gripper, SuctionSpec):
            return cls._build_suction(candidates, gripper)
        ci, ri = np.nonzero(np.asarray(candidates.free_rolls, dtype=bool))
        if candidates.quality_terms is not None:
            from .quality import scores

            per_candidate = scores(candidates.quality_terms)
            source = "quality"
        else:
            per_candidate = np.asarray(candidates.friction_margin_deg, dtype=np.float64)
            source = "friction_margin_deg"
        axes = candidates.axes
        y0, z0 = roll_basis(axes)  # per candidate; the pairs combine them with their roll
        psi = np.asarray(candidates.roll_angles_rad, dtype=np.float64)[ri][:, None]
        c, s = libm.cos(psi), libm.sin(psi)
        y = c * y0[ci] + s * z0[ci]
        z = -s * y0[ci] + c * z0[ci]
        columns = {"friction_margin_deg": np.asarray(candidates.friction_margin_deg, dtype=np.float64)}
        hold = getattr(candidates, "hold_margin", None)
        if hold is not None:
            columns["hold_margin"] = np.asarray(hold, dtype=np.float64)
        return cls._of_pairs(
            gripper,
            candidates,
            ci,
            ri,
            np.stack([axes[ci], y, z, candidates.midpoints[ci]], axis=1),
            per_candidate,
            source,
            columns,
            candidates.widths,
            None,
        )

    @classmethod
    def _build_suction(cls, candidates: Any, spec: SuctionSpec) -> PickIndex:
        contacts = np.asarray(candidates.contacts, dtype=np.float64)
        if contacts.ndim != 3 or contacts.shape[1] != 1:
            raise InvalidParameterError(
                f"a suction cup picks from candidates with one contact each, got contacts of shape {contacts.shape}",
                field="grasp_set",
            )
        free = np.asarray(candidates.free_rolls, dtype=bool)
        if spec.round_tool:  # the same solid at every roll: one pair per candidate that has a free roll, at roll 0
            ci = np.flatnonzero(free.any(axis=1))
            ri = np.zeros(len(ci), dtype=np.int64)
        else:
            ci, ri = np.nonzero(free)
        z = np.asarray(candidates.axes, dtype=np.float64)
        x0, y0 = approach_basis(z)
        psi = np.asarray(candidates.roll_angles_rad, dtype=np.float64)[ri][:, None]
        x = libm.cos(psi) * x0[ci] + libm.sin(psi) * y0[ci]
        zc = z[ci]
        hold = getattr(candidates, "hold_margin", None)
        seal = np.asarray(candidates.seal_strain, dtype=np.float64)
        columns = {} if hold is None else {"hold_margin": np.asarray(hold, dtype=np.float64)}
        columns["seal_strain"] = seal
        columns["tilt_deg"] = np.asarray(candidates.tilt_deg, dtype=np.float64)
        per_candidate, source = (columns["hold_margin"], "hold_margin") if hold is not None else (-seal, "seal_strain")
        return cls._of_pairs(
            spec,
            candidates,
            ci,
            ri,
            np.stack([x, np.cross(zc, x), zc, contacts[ci, 0]], axis=1),
            per_candidate,
            source,
            columns,
            None,
            _Cup.of(spec),
        )

    @classmethod
    def _of_pairs(
        cls,
        gripper: GripperSpec | SuctionSpec,
        candidates: Any,
        ci: np.ndarray,
        ri: np.ndarray,
        axes: np.ndarray,
        per_candidate: np.ndarray,
        source: str,
        columns: dict[str, np.ndarray],
        widths: np.ndarray | None,
        cup: _Cup | None,
    ) -> PickIndex:
        """The index of the pairs (candidate `ci`, roll `ri`) whose grasp axes X, Y, Z and origin are `axes`
        (k, 4, 3), scored by `per_candidate` (n,)."""
        score = per_candidate[ci]
        rank = np.empty(len(ci), dtype=np.int64)
        rank[np.lexsort((ri, ci, -score))] = np.arange(len(ci))  # position in the quality order
        z = axes[:, 2]
        # stored by approach direction (a 32 x 64 grid over cos(polar) and azimuth), so that the pairs inside a cone
        # lie in runs and gathering them reads memory in order; in the quality order within a cell
        polar = np.clip(((z[:, 2] + 1) * 16).astype(np.int64), 0, 31)
        azimuth = ((libm.arctan2(z[:, 1], z[:, 0]) + np.pi) * (64 / (2 * np.pi))).astype(np.int64) % 64
        order = np.lexsort((rank, polar * 64 + azimuth))
        frames = np.ascontiguousarray(axes[order].reshape(len(order), 12))
        ci, ri, score, rank = ci[order].astype(np.int64), ri[order].astype(np.int16), score[order], rank[order]
        n = len(candidates.free_rolls)
        medoid = np.zeros(n, dtype=bool)
        medoid[np.asarray(candidates.medoids, dtype=np.int64)] = True
        return cls(
            gripper=gripper,
            candidate=ci,
            roll_index=ri,
            roll_angles_rad=np.asarray(candidates.roll_angles_rad, dtype=np.float64),
            frames=frames,
            approach=np.ascontiguousarray(frames[:, 6:9].T, dtype=np.float32),
            width=None if widths is None else np.asarray(widths)[ci],
            score=score,
            rank=rank,
            by_rank=np.argsort(rank),
            labels=np.asarray(candidates.labels, dtype=np.int32),
            medoid=medoid,
            columns=columns,
            score_source=source,
            candidates_total=n,
            cup=cup,
        )

    def __len__(self) -> int:
        return len(self.candidate)

    @property
    def nbytes(self) -> int:
        arrays: tuple[np.ndarray, ...]
        arrays = (self.candidate, self.roll_index, self.frames, self.approach, self.score, self.rank, self.by_rank)
        arrays = (*arrays, *(() if self.width is None else (self.width,)))
        per_candidate = self.labels.nbytes + self.medoid.nbytes + sum(c.nbytes for c in self.columns.values())
        cup = 0 if self.cup is None or self.cup.hull is None else self.cup.hull.nbytes
        return sum(a.nbytes for a in arrays) + per_candidate + cup + 1024


@dataclass(frozen=True)
class _Cup:
    """A suction cup and its tool in the grasp frame, as the plane test reads them: cylinders on the Z axis
    (radius, z0, z1) with z0 < z1 <= 0 (the cup, then a cylinder tool), and a body tool's convex hull vertices
    (h, 3), metres."""

    cylinders: tuple[tuple[float, float, float], ...]
    hull: np.ndarray | None

    @classmethod
    def of(cls, spec: SuctionSpec) -> _Cup:
        h = spec.cup_height
        cylinders = [(spec.cup_radius, -h, 0.0)]
        hull = None
        if spec.tool is not None:
            cylinders.append((spec.tool.radius, -h - spec.tool.length, -h))
        else:
            assert spec.geometry is not None  # a suction spec has a tool or a body
            hull = np.ascontiguousarray(spec.geometry.body.convex_hull.vertices, dtype=np.float64)
        return cls(tuple(cylinders), hull)

    def lowest(self, mx: np.ndarray, my: np.ndarray, mz: np.ndarray) -> np.ndarray:
        """(k,): the smallest m . p over every point p of the cup and tool, for unit directions m = (mx, my, mz), each
        (k,), of the grasp frame (a plane's normal): exact for the cylinders (a rim's lowest point) and the hull."""
        side = np.sqrt(mx * mx + my * my)
        out = np.full(len(mz), np.inf)
        for r, z0, z1 in self.cylinders:
            out = np.minimum(out, np.minimum(z0 * mz, z1 * mz) - r * side)
        if self.hull is not None:
            hx, hy, hz = (self.hull[:, j : j + 1] for j in range(3))
            block = max(1024, _HULL_BLOCK // len(self.hull))
            for a in range(0, len(mz), block):
                sl = slice(a, a + block)
                # (h, block) heights as multiply-adds reduced over the vertices (contiguous rows): a (k, 3) x (3, h)
                # product is slow in BLAS with an inner size of 3, and a minimum along a short last axis in numpy
                heights = hx * mx[sl]
                heights += hy * my[sl]
                heights += hz * mz[sl]
                out[sl] = np.minimum(out[sl], heights.min(axis=0))
        return out


#: heights computed at once by the hull test ((hull vertices) x (pairs) floats)
_HULL_BLOCK = 1 << 20


@dataclass(frozen=True)
class PickResult:
    considered: int  # (candidate, free roll) pairs of the set
    feasible: int  # pairs that pass the cone and every plane
    grasps: list[dict[str, Any]]  # up to `limit`, best first
    removed: dict[str, Any]  # {"approach": n, "planes": n, "per_plane": [...]}
    score_source: str

    @property
    def reason(self) -> dict[str, Any] | None:
        """Why nothing came back: how many pairs each filter removed (None when grasps were found)."""
        if self.grasps:
            return None
        return {"candidates": self.considered, **self.removed}

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "considered": self.considered,
            "feasible": self.feasible,
            "score": self.score_source,
            "removed": self.removed,
            "grasps": self.grasps,
        }
        if not self.grasps:
            out["reason"] = self.reason
        return out


# -- validation ------------------------------------------------------------------------------------------------------
def validate_pose(value: Any, field: str) -> np.ndarray:
    """A 4x4 homogeneous pose: finite, rotation orthonormal with det +1, last row 0 0 0 1 (within POSE_TOLERANCE)."""
    try:
        T = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{field} must be a 4x4 matrix of numbers", field=field) from None
    if T.shape != (4, 4):
        raise InvalidParameterError(f"{field} must be a 4x4 matrix, got shape {T.shape}", field=field)
    if not np.all(np.isfinite(T)):
        raise InvalidParameterError(f"{field} holds non-finite numbers", field=field)
    if np.max(np.abs(T[3] - (0.0, 0.0, 0.0, 1.0))) > POSE_TOLERANCE:
        raise InvalidParameterError(f"{field}'s last row must be [0, 0, 0, 1]", field=field)
    R = T[:3, :3]
    if np.max(np.abs(R.T @ R - np.eye(3))) > POSE_TOLERANCE or abs(np.linalg.det(R) - 1.0) > POSE_TOLERANCE:
        raise InvalidParameterError(
            f"{field}'s rotation must be orthonormal with determinant +1 (within {POSE_TOLERANCE})", field=field
        )
    return T


def _vector(value: Any, field: str, *, unit: bool) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"{field} must be 3 numbers", field=field) from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InvalidParameterError(f"{field} must be 3 finite numbers", field=field)
    if unit:
        norm = float(np.linalg.norm(v))
        if norm < 1e-12:
            raise InvalidParameterError(f"{field} must not be the zero vector", field=field)
        v = v / norm
    return v


def _number(value: Any, field: str, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidParameterError(f"{field} must be a finite number, got {value!r}", field=field)
    if not lo <= value <= hi:
        raise InvalidParameterError(f"{field} must be between {lo} and {hi}, got {value}", field=field)
    return float(value)


def _mapping(value: Any, field: str, keys: Sequence[str], required: Sequence[str]) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise InvalidParameterError(f"{field} must be an object with {', '.join(keys)}", field=field)
    unknown = sorted(set(value) - set(keys))
    if unknown:
        raise InvalidParameterError(f"{field} has unknown fields {', '.join(unknown)}", field=f"{field}.{unknown[0]}")
    missing = [k for k in required if value.get(k) is None]
    if missing:
        raise InvalidParameterError(f"{field} lacks {', '.join(missing)}", field=f"{field}.{missing[0]}")
    return value


# -- the query -------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PickQuery:
    """A validated pick query (world frame, metres): what `pick` checks before it touches any candidate."""

    T_world_object: np.ndarray  # (4, 4)
    direction: np.ndarray | None  # (3,) unit, world frame; None: any approach
    cos_max: float  # cos of approach.max_angle_deg
    normals: np.ndarray  # (P, 3) unit, world frame
    offsets: np.ndarray  # (P,) normal . point
    pregrasp_distance: float
    T_tcp_flange: np.ndarray | None
    limit: int

    @classmethod
    def parse(
        cls,
        T_world_object: Any,
        *,
        approach: Mapping[str, Any] | None = None,
        planes: Sequence[Mapping[str, Any]] | None = None,
        pregrasp_distance: float = DEFAULT_PREGRASP_DISTANCE,
        T_tcp_flange: Any = None,
        limit: int = DEFAULT_LIMIT,
    ) -> PickQuery:
        T_wo = validate_pose(T_world_object, "T_world_object")
        T_tf = None if T_tcp_flange is None else validate_pose(T_tcp_flange, "T_tcp_flange")
        if isinstance(limit, bool) or not isinstance(limit, int) or not 1 <= limit <= MAX_LIMIT:
            raise InvalidParameterError(
                f"limit must be an integer between 1 and {MAX_LIMIT}, got {limit!r}", field="limit"
            )
        distance = _number(pregrasp_distance, "pregrasp_distance", 0.0, 2.0)
        direction, cos_max = None, -1.0
        if approach is not None:
            a = _mapping(approach, "approach", ("direction", "max_angle_deg"), ("direction", "max_angle_deg"))
            direction = _vector(a["direction"], "approach.direction", unit=True)
            cos_max = math.cos(math.radians(_number(a["max_angle_deg"], "approach.max_angle_deg", 0.0, 180.0)))
        if planes is not None and not isinstance(planes, Sequence):
            raise InvalidParameterError("planes must be a list of {point, normal}", field="planes")
        plane_list = list(planes or [])
        if len(plane_list) > MAX_PLANES:
            raise InvalidParameterError(f"at most {MAX_PLANES} planes, got {len(plane_list)}", field="planes")
        normals, offsets = np.zeros((len(plane_list), 3)), np.zeros(len(plane_list))
        for j, p in enumerate(plane_list):
            p = _mapping(p, f"planes[{j}]", ("point", "normal"), ("point", "normal"))
            normals[j] = _vector(p["normal"], f"planes[{j}].normal", unit=True)
            offsets[j] = normals[j] @ _vector(p["point"], f"planes[{j}].point", unit=False)
        return cls(T_wo, direction, cos_max, normals, offsets, distance, T_tf, limit)

    def run(self, index: PickIndex) -> PickResult:
        T_wo = self.T_world_object
        ok, cos_z, removed = _filter(
            index,
            T_wo[:3, :3],
            T_wo[:3, 3],
            self.direction,
            self.cos_max,
            self.normals,
            self.offsets,
            self.pregrasp_distance,
        )
        chosen = _best(index, ok, cos_z, self.limit)
        grasps = _grasps_out(index, chosen, cos_z, T_wo, self.pregrasp_distance, self.T_tcp_flange)
        return PickResult(
            considered=len(index),
            feasible=int(np.count_nonzero(ok)),
            grasps=grasps,
            removed=removed,
            score_source=index.score_source,
        )


def pick(
    grasp_set_or_candidates: Any,
    T_world_object: Any,
    *,
    approach: Mapping[str, Any] | None = None,
    planes: Sequence[Mapping[str, Any]] | None = None,
    pregrasp_distance: float = DEFAULT_PREGRASP_DISTANCE,
    T_tcp_flange: Any = None,
    limit: int = DEFAULT_LIMIT,
    gripper: GripperSpec | SuctionSpec | None = None,
) -> PickResult:
    """World-frame grasps of a set that fit the scene, best first (module docstring, CONTRACT.md).

    `grasp_set_or_candidates`: a grasp set of either kind (GraspSet, or a suction run's set: it carries its gripper),
    its candidates (graspgen.export.Candidates, or a suction set's candidates; these need `gripper`), or a PickIndex.

    `T_world_object` (4, 4): where the part lies. `approach`: `{"direction": (3,), "max_angle_deg": float}`, the
    grasp's +Z in the world must lie within the cone (None: any direction). `planes`: `[{"point": (3,), "normal":
    (3,)}]` in the world frame, metres; fingers and palm (a suction cup and its tool) at the grasp and at the
    pre-grasp stay on the normal side. `T_tcp_flange` (4, 4): the flange relative to the TCP (grasp frame); adds
    `T_world_flange` and `T_world_preflange`.
    """
    query = PickQuery.parse(
        T_world_object,
        approach=approach,
        planes=planes,
        pregrasp_distance=pregrasp_distance,
        T_tcp_flange=T_tcp_flange,
        limit=limit,
    )
    return query.run(_index_of(grasp_set_or_candidates, gripper))


def _index_of(source: Any, gripper: GripperSpec | SuctionSpec | None) -> PickIndex:
    if isinstance(source, PickIndex):
        return source
    if isinstance(source, GraspSet):
        return PickIndex.build(source.candidates, gripper or source.gripper)
    own = getattr(source, "gripper", None)
    if isinstance(own, SuctionSpec):  # a suction run's grasp set
        return PickIndex.build(source.candidates, gripper or own)
    if isinstance(source, Candidates) or hasattr(source, "free_rolls"):  # candidates of either kind
        if gripper is None:
            raise InvalidParameterError("picking from candidates needs the gripper spec", field="gripper")
        return PickIndex.build(source, gripper)
    raise InvalidParameterError(f"cannot pick from a {type(source).__name__}", field="grasp_set")


#: float32 dot products of unit vectors stay within ~1e-6 of the float64 ones; the prefilter keeps this much more
_PREFILTER_SLACK = 1e-5


def _dot(rows: np.ndarray, v: np.ndarray) -> np.ndarray:
    """rows (3, k) . v (3,) -> (k,), as multiply-adds (no BLAS)."""
    out: np.ndarray = rows[0] * v[0]
    out += rows[1] * v[1]
    out += rows[2] * v[2]
    return out


def _filter(
    index: PickIndex,
    R_wo: np.ndarray,
    t_wo: np.ndarray,
    direction: np.ndarray | None,
    cos_max: float,
    normals: np.ndarray,
    offsets: np.ndarray,
    distance: float,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Feasibility mask (k,), cos of the approach angle (k,) and how many pairs each filter removed.

    The cone first, over every pair (the object-frame direction against each Z); the planes only over the pairs
    inside the cone, which a typical approach cone keeps a small share of."""
    k, P = len(index), len(normals)
    if direction is not None:
        d_obj = R_wo.T @ direction
        rough = _dot(index.approach, d_obj.astype(np.float32))  # float32: within 1e-6 of the exact cosine
        maybe = np.flatnonzero(rough >= cos_max - _PREFILTER_SLACK)
        near = index.frames[maybe]
        exact = _dot(near.T[6:9], d_obj)
        keep = exact >= cos_max - 1e-12
        inside_cone = maybe[keep]
        cos_z = rough.astype(np.float64)
        cos_z[maybe] = exact
        ok = np.zeros(k, dtype=bool)
        ok[inside_cone] = True
        near = near[keep]
    else:
        cos_z, ok, inside_cone, near = np.ones(k), np.ones(k, dtype=bool), None, index.frames
    n_cone = k if inside_cone is None else len(inside_cone)
    removed_cone = k - n_cone
    if P == 0 or n_cone == 0:
        return ok, cos_z, {"approach": removed_cone, "planes": 0, "per_plane": [0] * P}
    sub = near.T  # (12, k') view
    lowest_of = (
        _cup_lowest(index, sub, distance) if index.cup is not None else _jaws_lowest(index, sub, inside_cone, distance)
    )
    clear = np.ones(n_cone, dtype=bool)
    per_plane: list[int] = []
    for j in range(P):
        n_obj = R_wo.T @ normals[j]  # the plane normal in the object frame; m = (X.n, Y.n, Z.n) in the grasp frame
        h0 = _dot(sub[9:12], n_obj)
        h0 += normals[j] @ t_wo - offsets[j]  # the grasp origin's height above the plane
        inside = lowest_of(n_obj, h0) >= -PLANE_TOLERANCE
        per_plane.append(n_cone - int(np.count_nonzero(inside)))
        clear &= inside
    if inside_cone is None:
        ok = clear
    else:
        ok[inside_cone[~clear]] = False
    removed = {"approach": removed_cone, "planes": n_cone - int(np.count_nonzero(clear)), "per_plane": per_plane}
    return ok, cos_z, removed


#: (plane normal in the object frame (3,), grasp origins' heights above the plane (k,)) -> lowest heights (k,)
_Lowest = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _cup_lowest(index: PickIndex, sub: np.ndarray, distance: float) -> _Lowest:
    """(n_obj (3,), h0 (k,)) -> (k,): the height above the plane of the lowest point of the cup and tool at the grasp
    (origin height h0) and at the pre-grasp, for the pairs whose frames are `sub` (12, k)."""
    cup = index.cup
    assert cup is not None  # a suction index

    def lowest(n_obj: np.ndarray, h0: np.ndarray) -> np.ndarray:
        mx, my, mz = _dot(sub[0:3], n_obj), _dot(sub[3:6], n_obj), _dot(sub[6:9], n_obj)
        out: np.ndarray = np.minimum(h0, h0 - distance * mz) + cup.lowest(mx, my, mz)
        return out

    return lowest


def _jaws_lowest(index: PickIndex, sub: np.ndarray, inside_cone: np.ndarray | None, distance: float) -> _Lowest:
    """(n_obj (3,), h0 (k,)) -> (k,): the height above the plane of the lowest point of the fingers and palm at the
    grasp and of the open fingers and palm at the pre-grasp, for the pairs whose frames are `sub` (12, k)."""
    gripper = index.gripper
    assert isinstance(gripper, GripperSpec) and index.width is not None  # a parallel index
    solids = gripper.solids()
    ft = solids.finger_thickness
    width = index.width if inside_cone is None else index.width[inside_cone]
    grasp_reach = width / 2 + ft  # outer face of a finger at the grasp, along X
    open_reach = solids.open_width(width) / 2 + ft  # and at the pre-grasp

    def lowest(n_obj: np.ndarray, h0: np.ndarray) -> np.ndarray:
        if solids.meshes is not None:
            m = np.stack([_dot(sub[0:3], n_obj), _dot(sub[3:6], n_obj), _dot(sub[6:9], n_obj)], axis=1)
            return _lowest_of_meshes(solids, m, h0, h0 - distance * m[:, 2], width / 2, solids.open_width(width) / 2)
        mx, my, mz = np.abs(_dot(sub[0:3], n_obj)), np.abs(_dot(sub[3:6], n_obj)), _dot(sub[6:9], n_obj)
        h_pre = h0 - distance * mz  # the pre-grasp origin's
        side, palm = solids.plane_offsets(mx, my, mz)
        out: np.ndarray = np.minimum(h0 - mx * grasp_reach, h_pre - mx * open_reach) - side
        if palm is not None:
            out = np.minimum(out, np.minimum(h0, h_pre) + palm)
        return out

    return lowest


#: pairs per block of the mesh gripper's lowest-point products ((block, hull vertices) floats each)
_MESH_BLOCK = 65_536


def _lowest_of_meshes(
    solids: Any, m: np.ndarray, h0: np.ndarray, h_pre: np.ndarray, half: np.ndarray, half_open: np.ndarray
) -> np.ndarray:
    """The height above a plane of the lowest point of a gripper from CAD, per pair (k,): the fingers at the grasp
    (origin height h0, half width `half`) and at the pre-grasp (h_pre, half the opening), the body at both. m (k, 3):
    the plane's normal along the grasp frame's X, Y, Z. A mesh's lowest point along a direction is a vertex of its
    convex hull: the minimum over those, exact."""
    left, right = solids.finger_hulls()
    body = solids.meshes.body.hull_vertices if solids.meshes.body is not None else None
    flip = np.array([-1.0, -1.0, 1.0])  # the -X finger is turned half a turn about Z
    out = np.empty(len(m))
    for a in range(0, len(m), _MESH_BLOCK):
        mb = m[a : a + _MESH_BLOCK]
        r = (mb @ right.T).min(axis=1)
        lf = ((mb * flip) @ left.T).min(axis=1)
        mx = mb[:, 0]
        sl = slice(a, a + len(mb))
        at = np.minimum(mx * half[sl] + r, -mx * half[sl] + lf)
        opened = np.minimum(mx * half_open[sl] + r, -mx * half_open[sl] + lf)
        low = np.minimum(h0[sl] + at, h_pre[sl] + opened)
        if body is not None:
            b = (mb @ body.T).min(axis=1)
            low = np.minimum(low, np.minimum(h0[sl], h_pre[sl]) + b)
        out[sl] = low
    return out


def _best(index: PickIndex, ok: np.ndarray, cos_z: np.ndarray, limit: int) -> np.ndarray:
    """Up to `limit` feasible pairs: by score, then approach angle, candidate, roll.

    Only the feasible pairs scoring at least the limit-th feasible one's score are sorted. When feasible pairs are
    common the quality order is walked from its top until `limit` of them turn up; otherwise the feasible pairs'
    ranks are partitioned."""
    n_ok = int(np.count_nonzero(ok))
    if n_ok <= limit:
        idx = np.flatnonzero(ok)
    elif n_ok * 16 >= len(ok):
        take = min(len(ok), max(4096, 4 * limit * len(ok) // n_ok))
        while True:
            top = index.by_rank[:take]
            hits = top[ok[top]]
            if len(hits) >= limit:
                cut = index.score[hits[limit - 1]]
                # the walk must reach past every pair scoring `cut`: equal scores are sorted below, not by rank
                if take == len(ok) or index.score[index.by_rank[take - 1]] < cut:
                    break
            if take == len(ok):
                break
            take = min(len(ok), take * 4)
        idx = hits[index.score[hits] >= cut]
    else:
        idx = np.flatnonzero(ok)
        kth = idx[np.argpartition(index.rank[idx], limit - 1)[limit - 1]]
        idx = idx[index.score[idx] >= index.score[kth]]
    # angles equal to 1e-9 degrees are a tie (pairs of parallel candidates differ in the last bits), broken by index
    angle = np.round(np.degrees(libm.arccos(np.clip(cos_z[idx], -1.0, 1.0))), ANGLE_DECIMALS)
    order = np.lexsort((index.roll_index[idx], index.candidate[idx], angle, -index.score[idx]))
    return idx[order[:limit]]


def _grasps_out(
    index: PickIndex, chosen: np.ndarray, cos_z: np.ndarray, T_wo: np.ndarray, distance: float, T_tf: np.ndarray | None
) -> list[dict[str, Any]]:
    """The chosen pairs as response dicts, the poses computed for all of them at once."""
    m = len(chosen)
    if m == 0:
        return []
    f = index.frames[chosen].T
    T_og = np.zeros((m, 4, 4))
    T_og[:, :3, 0], T_og[:, :3, 1], T_og[:, :3, 2], T_og[:, :3, 3] = f[0:3].T, f[3:6].T, f[6:9].T, f[9:12].T
    T_og[:, 3, 3] = 1.0
    T_wg = T_wo @ T_og
    T_wp = T_wg.copy()
    T_wp[:, :3, 3] -= distance * T_wg[:, :3, 2]
    cand = index.candidate[chosen]
    g = index.gripper
    columns: dict[str, list[Any]] = {
        "T_world_grasp": T_wg.tolist(),
        "position": T_wg[:, :3, 3].tolist(),
        "quaternion_xyzw": [matrix_to_quaternion_xyzw(R).tolist() for R in T_wg[:, :3, :3]],
        "T_world_pregrasp": T_wp.tolist(),
    }
    if index.width is not None and isinstance(g, GripperSpec):
        width = index.width[chosen]
        columns["width"] = width.tolist()
        columns["open_width"] = g.solids().open_width(width).tolist()
    columns |= {
        "roll_deg": np.degrees(index.roll_angles_rad[index.roll_index[chosen]]).tolist(),
        "roll_index": index.roll_index[chosen].tolist(),
        "approach_angle_deg": np.degrees(libm.arccos(np.clip(cos_z[chosen], -1.0, 1.0))).tolist(),
        "candidate": cand.tolist(),
        "cluster": index.labels[cand].tolist(),
        "medoid": index.medoid[cand].tolist(),
        "score": index.score[chosen].tolist(),
    }
    if isinstance(g, SuctionSpec) and g.round_tool:
        columns["any_roll"] = [True] * m
    columns |= {name: values[cand].tolist() for name, values in index.columns.items()}
    if T_tf is not None:
        columns["T_world_flange"] = (T_wg @ T_tf).tolist()
        columns["T_world_preflange"] = (T_wp @ T_tf).tolist()
    names = list(columns)
    return [dict(zip(names, row, strict=True)) for row in zip(*columns.values(), strict=True)]
