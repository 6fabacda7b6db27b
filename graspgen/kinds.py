"""Every gripper kind behind one entry point: a spec's `kind` picks its class (CONTRACT.md: "parallel", the
default, is a GripperSpec; "suction" a SuctionSpec)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from .errors import InvalidGripperError, InvalidParameterError
from .gripper import KIND as PARALLEL
from .gripper import GripperSpec
from .suction import KIND as SUCTION
from .suction import SuctionSpec, check_params, read_spec_json

if TYPE_CHECKING:
    from .params import Params, QualityOptions

__all__ = ["GripperKind", "KINDS", "load_gripper", "gripper_from_dict", "check_params_for_kind"]

#: a gripper spec of any kind
GripperKind: TypeAlias = GripperSpec | SuctionSpec
#: kind name -> its spec class; a spec without `kind` is "parallel"
KINDS: dict[str, type[GripperSpec] | type[SuctionSpec]] = {PARALLEL: GripperSpec, SUCTION: SuctionSpec}


def gripper_from_dict(
    data: Any,
    *,
    files: Mapping[str, bytes] | None = None,
    base_dir: str | Path | None = None,
    max_decoded_bytes: int | None = None,
) -> GripperKind:
    """The checked spec of the kind `data["kind"]` names (default "parallel"); mesh files as bytes by name
    (`files`) or read relative to `base_dir`, as the kind's `from_dict` takes them."""
    if not isinstance(data, dict):
        raise InvalidGripperError("a gripper spec must be a JSON object")
    kind = data.get("kind", PARALLEL)
    cls = KINDS.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise InvalidGripperError(
            f"unknown gripper kind {kind!r}: the kinds are " + ", ".join(repr(k) for k in KINDS), field="kind"
        )
    return cls.from_dict(data, files=files, base_dir=base_dir, max_decoded_bytes=max_decoded_bytes)


def load_gripper(
    data_or_path: Any,
    files: Mapping[str, bytes] | None = None,
    base_dir: str | Path | None = None,
) -> GripperKind:
    """A gripper spec of any kind: a ready spec as it is, a JSON object (dict) checked by its kind's class, or the
    path of a spec file (its mesh files read beside it unless `base_dir` or `files` say otherwise)."""
    if isinstance(data_or_path, (GripperSpec, SuctionSpec)):
        return data_or_path
    if isinstance(data_or_path, (str, Path)):
        path = Path(data_or_path)
        data = read_spec_json(path)
        return gripper_from_dict(
            data, files=files, base_dir=path.parent if base_dir is None and files is None else base_dir
        )
    return gripper_from_dict(data_or_path, files=files, base_dir=base_dir)


def check_params_for_kind(kind: str, params: Params, options: QualityOptions, *, recluster: bool = False) -> None:
    """InvalidParameterError naming the field when a run parameter or option has no meaning for the gripper `kind`
    (refused, not ignored): generate() and recluster() call it when a run starts, the service when a job is
    submitted. `recluster`: a new selection from a set's stored candidates (a cluster job)."""
    if kind == SUCTION:
        check_params(params, options, recluster=recluster)
    elif params.max_tilt_deg is not None:
        raise InvalidParameterError(
            "max_tilt_deg is for suction cups: a parallel gripper's approach follows from its contacts",
            field="max_tilt_deg",
        )
