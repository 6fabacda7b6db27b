"""GraspSet: the result of a run, its grasp_set/1 JSON export and the candidate NPZ (CONTRACT.md)."""

from __future__ import annotations

import io
import json
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import IO, Any

import numpy as np

from .errors import InvalidCandidatesError, InvalidParameterError
from .gripper import GripperSpec
from .params import Params

__all__ = ["FORMAT", "WHOLE_ARRAYS", "Candidates", "GraspSet", "candidate_view", "load_candidates", "write_atomic"]

FORMAT = "graspgen.grasp_set/1"


@dataclass(frozen=True)
class Candidates:
    """The pairs that passed (a)-(c) and have at least one collision-free roll (arrays over n candidates)."""

    contacts: np.ndarray  # (n, 2, 3) float64, metres, object frame
    normals: np.ndarray  # (n, 2, 3) float64, outward unit normals
    free_rolls: np.ndarray  # (n, R) bool
    roll_angles_rad: np.ndarray  # (R,)
    friction_margin_deg: np.ndarray  # (n,)
    inside: np.ndarray  # (n,) bool
    labels: np.ndarray  # (n, 2) int32 (translation cluster, direction cluster); -1 before clustering
    medoids: np.ndarray  # (m,) int64, export order
    #: optional, present when quality was scored (quality.py): (n, 3) terms and the part's centre of mass (3,)
    quality_terms: np.ndarray | None = None
    center_of_mass: np.ndarray | None = None
    #: optional, present when criterion (e) ran (hold.py): (n,) the load each candidate resists over the load required
    hold_margin: np.ndarray | None = None

    # derived once per instance (clustering, coverage, quality and the export each read them; the arrays are
    # large): cached_property writes the instance __dict__ directly, which a frozen dataclass allows
    @cached_property
    def midpoints(self) -> np.ndarray:
        mid: np.ndarray = 0.5 * (self.contacts[:, 0] + self.contacts[:, 1])
        return mid

    @cached_property
    def widths(self) -> np.ndarray:
        width: np.ndarray = np.linalg.norm(self.contacts[:, 1] - self.contacts[:, 0], axis=1)
        return width

    @cached_property
    def axes(self) -> np.ndarray:
        d = self.contacts[:, 1] - self.contacts[:, 0]
        axis: np.ndarray = d / np.linalg.norm(d, axis=1, keepdims=True)
        return axis

    def __len__(self) -> int:
        return len(self.contacts)

    def arrays(self) -> dict[str, np.ndarray]:
        extra = {
            k: getattr(self, k).astype(np.float64)
            for k in ("quality_terms", "center_of_mass", "hold_margin")
            if getattr(self, k) is not None
        }
        return {
            "contacts": self.contacts,
            "normals": self.normals,
            "midpoints": self.midpoints,
            "axes": self.axes,
            "free_rolls": self.free_rolls,
            "roll_angles_rad": self.roll_angles_rad,
            "friction_margin_deg": self.friction_margin_deg,
            "labels": self.labels.astype(np.int32),
            "medoids": self.medoids.astype(np.int64),
            "inside": self.inside,
            **extra,
        }


def load_candidates(path: str | os.PathLike[str] | IO[bytes]) -> Candidates:
    """Read a candidate NPZ back, checking shapes so that a damaged file fails with a clear reason."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise InvalidCandidatesError(f"cannot read candidates {path}: {exc}") from None
    required = ("contacts", "normals", "free_rolls", "roll_angles_rad", "friction_margin_deg")
    missing = [k for k in required if k not in data]
    if missing:
        raise InvalidCandidatesError(f"candidates {path} lack " + ", ".join(missing))
    n = len(data["contacts"])
    R = len(data["roll_angles_rad"])
    if data["contacts"].shape != (n, 2, 3) or data["normals"].shape != (n, 2, 3):
        raise InvalidCandidatesError("contacts and normals must be (n, 2, 3)")
    if data["free_rolls"].shape != (n, R) or data["friction_margin_deg"].shape != (n,):
        raise InvalidCandidatesError("free_rolls must be (n, R) and friction_margin_deg (n,)")
    if not np.all(np.isfinite(data["contacts"])):
        raise InvalidCandidatesError("contacts hold non-finite values")
    return Candidates(
        contacts=data["contacts"].astype(np.float64),
        normals=data["normals"].astype(np.float64),
        free_rolls=data["free_rolls"].astype(bool),
        roll_angles_rad=data["roll_angles_rad"].astype(np.float64),
        friction_margin_deg=data["friction_margin_deg"].astype(np.float64),
        inside=data.get("inside", np.zeros(n, dtype=bool)).astype(bool),
        labels=data.get("labels", np.full((n, 2), -1, dtype=np.int32)).astype(np.int32),
        medoids=data.get("medoids", np.zeros(0, dtype=np.int64)).astype(np.int64),
        quality_terms=_optional(data, "quality_terms", (n, 3)),
        center_of_mass=_optional(data, "center_of_mass", (3,)),
        hold_margin=_optional(data, "hold_margin", (n,)),
    )


#: arrays of the candidate NPZ that are not over its candidates: candidate_view keeps them whole
WHOLE_ARRAYS = frozenset({"roll_angles_rad", "medoids", "center_of_mass"})


def candidate_view(
    npz: bytes, *, arrays: Sequence[str] | None = None, max_rows: int | None = None
) -> dict[str, np.ndarray]:
    """Some arrays of the candidate NPZ `npz` (its bytes), over at most `max_rows` of its `n` candidates.

    `arrays`: the names to return, in this order (None: every array of the NPZ); names the NPZ lacks are left out.
    `max_rows` (>= 1; None: every row): rows 0, s, 2s, ... are kept, s = ceil(n / max_rows), so k = ceil(n / s) <=
    `max_rows` rows (all of them when n <= max_rows). Every array over the candidates (leading axis of length n) is cut
    to those rows; `roll_angles_rad`, `medoids` (rows of the full NPZ) and `center_of_mass` are kept whole. With
    `max_rows` the result adds `rows (k,) int64`, the kept rows' indices in the full NPZ, and `row_count () int64`, n.
    Only the members returned are inflated (and `contacts`' header is read for n).
    """
    if max_rows is not None and max_rows < 1:
        raise InvalidParameterError(f"max_rows must be at least 1, got {max_rows}")
    try:
        with np.load(io.BytesIO(npz), allow_pickle=False) as z:
            names = list(dict.fromkeys(a for a in (z.files if arrays is None else arrays) if a in z.files))
            if max_rows is None:
                return {a: z[a] for a in names}
            n = _leading_length(z, "contacts")
            step = max(1, -(-n // max_rows))
            out: dict[str, np.ndarray] = {}
            for a in names:
                v = z[a]
                cut = a not in WHOLE_ARRAYS and v.ndim >= 1 and v.shape[0] == n
                out[a] = np.ascontiguousarray(v[::step]) if cut and step > 1 else v
    except (OSError, ValueError, KeyError) as exc:
        raise InvalidCandidatesError(f"cannot read the candidate NPZ: {exc}") from None
    out["rows"] = np.arange(0, n, step, dtype=np.int64)
    out["row_count"] = np.array(n, dtype=np.int64)
    return out


def _leading_length(z: Any, name: str) -> int:
    """The first dimension of member `name` of an open NpzFile, from its .npy header alone."""
    with z.zip.open(f"{name}.npy") as f:
        version = np.lib.format.read_magic(f)
        read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape = read(f)[0]
    if not shape:
        raise InvalidCandidatesError(f"{name} of the candidate NPZ is a scalar")
    return int(shape[0])


def _optional(data: dict[str, np.ndarray], key: str, shape: tuple[int, ...]) -> np.ndarray | None:
    if key not in data:
        return None
    if data[key].shape != shape:
        raise InvalidCandidatesError(f"{key} must have shape {shape}, got {data[key].shape}")
    return data[key].astype(np.float64)


def write_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write to a temporary file beside `path` and rename it, so no reader ever sees half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual permissions
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class ExportMethods:
    """The grasp_set/1 export of a run's result, for either gripper kind (GraspSet, suction.SuctionGraspSet): both
    hold the same fields, their gripper spec and candidates differ."""

    object: dict[str, Any]
    gripper: Any  # a spec with to_dict(): GripperSpec or SuctionSpec
    params: Params
    friction: float
    stats: dict[str, Any]
    grasps: list[dict[str, Any]]
    candidates: Any  # the kind's candidates, with arrays() for the NPZ
    mass_kg: float | None

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "units": "m",
            "object": dict(self.object),
            "gripper": self.gripper.to_dict(),
            "params": self.params.to_dict(friction=self.friction, mass_kg=self.mass_kg),
            "stats": self.stats,
            "grasps": self.grasps,
        }

    def to_json_bytes(self) -> bytes:
        """Canonical bytes: the same inputs, parameters and seed give the same bytes (but for timings)."""
        return (json.dumps(self.to_json(), indent=1, allow_nan=False) + "\n").encode("utf-8")

    def save(self, path: str | os.PathLike[str]) -> None:
        write_atomic(path, self.to_json_bytes())

    def save_candidates(self, path: str | os.PathLike[str]) -> None:
        write_atomic(path, self.candidates_npz_bytes())

    def candidates_npz_bytes(self) -> bytes:
        """The candidate NPZ (CONTRACT.md) as bytes, as save_candidates writes it."""
        return npz_bytes(self.candidates.arrays())


@dataclass
class GraspSet(ExportMethods):
    """The result of a parallel-jaw run: the export (to_json) and its candidates (save_candidates)."""

    object: dict[str, Any]
    gripper: GripperSpec
    params: Params
    friction: float
    stats: dict[str, Any]
    grasps: list[dict[str, Any]]
    candidates: Candidates
    warnings: list[str] = field(default_factory=list)
    #: the part's mass (kg) that criterion (e) used: given, or density x volume
    mass_kg: float | None = None


#: deflate level of the candidate NPZ, through ISA-L (the `isal` package): its level 1 compresses the float arrays
#: as well as zlib's level 1 (55.6 against 56.1 MB for 144 MB of arrays) about 8x faster (0.23 against 1.75 s), and
#: its output is ordinary deflate that `np.load` reads with zlib
NPZ_DEFLATE_LEVEL = 1


def npz_bytes(arrays: dict[str, np.ndarray], *, deflate: bool = True) -> bytes:
    """An NPZ (read by `np.load`) of `arrays`, deflated by ISA-L at `NPZ_DEFLATE_LEVEL` (stored as they are when
    `deflate` is false: no inflating for the reader), with fixed member timestamps: the same arrays give the same
    bytes (numpy's savez stamps the current time)."""
    import zipfile

    from isal import isal_zlib

    method = zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name, a in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = method
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as f:
                if deflate:
                    # the member's raw deflate stream from ISA-L instead of zlib (zipfile has no hook for the
                    # compressor; _ZipWriteFile of Python 3.11 calls only compress() and flush() on it)
                    f._compressor = isal_zlib.compressobj(  # type: ignore[attr-defined]  # IO[bytes] is a _ZipWriteFile
                        NPZ_DEFLATE_LEVEL, isal_zlib.DEFLATED, -15
                    )
                np.lib.format.write_array(f, np.asanyarray(a), allow_pickle=False)
    return buf.getvalue()
