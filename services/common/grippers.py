"""A stored gripper spec as graspgen's spec of its kind (CONTRACT.md "Gripper spec", "Gripper geometry from CAD",
"Suction cups"), with its meshes: for the worker's jobs, the memory guard, previews and the pick query, which get the
spec as the version row stores it.

A spec with `geometry` (a parallel gripper's fingers and body, or a suction tool's body) names its files and gives
each one's sha256 (spec.geometry.sha256); their bytes are in storage under blob_key(sha256) (the API stored them
there with the version, and gripper_files lists them), and the spec's from_dict checks each file's digest again while
it loads them.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from graspgen.kinds import KINDS, GripperKind, gripper_from_dict

from .storage import Storage, blob_key

__all__ = ["stored_gripper_spec", "file_digests", "gripper_kind"]


def file_digests(spec: dict[str, Any]) -> dict[str, str]:
    """{file name: sha256} of a stored spec's mesh files; empty for a spec without geometry."""
    geometry = spec.get("geometry")
    return dict(geometry.get("sha256") or {}) if isinstance(geometry, dict) else {}


def gripper_kind(spec: dict[str, Any]) -> str:
    """The kind of a stored spec: its `kind`, "parallel" when it has none (the contract's default)."""
    kind = spec.get("kind")
    return kind if isinstance(kind, str) else "parallel"


def stored_gripper_spec(storage: Storage, spec: dict[str, Any], *, max_decoded_bytes: int | None = None) -> GripperKind:
    """The spec of a stored spec dict, of its kind (graspgen.kinds): a GripperSpec or a SuctionSpec. Without
    geometry: its fields that this graspgen knows (a spec stored by a newer version may carry more). With geometry:
    its files read from storage (FileNotFoundError when one is missing). Raises InvalidGripperError when the stored
    spec or a file does not check (e.g. a digest differs)."""
    digests = file_digests(spec)
    if not digests:
        cls = KINDS.get(gripper_kind(spec))
        known = {f.name for f in fields(cls)} if cls is not None else set(spec)
        return gripper_from_dict({k: v for k, v in spec.items() if k in known})
    files = {name: storage.get_bytes(blob_key(sha)) for name, sha in digests.items()}
    return gripper_from_dict(spec, files=files, max_decoded_bytes=max_decoded_bytes)
