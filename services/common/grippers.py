"""A stored gripper spec as graspgen's GripperSpec, with its meshes (CONTRACT.md "Gripper geometry from CAD"): for
the worker's jobs, the memory guard and the pick query, which get the spec as the version row stores it.

A spec with `geometry` names its files and gives each one's sha256 (spec.geometry.sha256); their bytes are in
storage under blob_key(sha256) (the API stored them there with the version, and gripper_files lists them), and
GripperSpec.from_dict checks each file's digest again while it loads them.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from graspgen.gripper import GripperSpec

from .storage import Storage, blob_key

__all__ = ["stored_gripper_spec", "file_digests"]


def file_digests(spec: dict[str, Any]) -> dict[str, str]:
    """{file name: sha256} of a stored spec's mesh files; empty for a box spec."""
    geometry = spec.get("geometry")
    return dict(geometry.get("sha256") or {}) if isinstance(geometry, dict) else {}


def stored_gripper_spec(storage: Storage, spec: dict[str, Any], *, max_decoded_bytes: int | None = None) -> GripperSpec:
    """The GripperSpec of a stored spec dict. A box spec: its fields that this graspgen knows (a spec stored by a
    newer version may carry more). A geometry spec: with its files read from storage (FileNotFoundError when one is
    missing). Raises InvalidGripperError when the stored spec or a file does not check (e.g. a digest differs)."""
    digests = file_digests(spec)
    if not digests:
        known = {f.name for f in fields(GripperSpec)}
        return GripperSpec.from_dict({k: v for k, v in spec.items() if k in known})
    files = {name: storage.get_bytes(blob_key(sha)) for name, sha in digests.items()}
    return GripperSpec.from_dict(spec, files=files, max_decoded_bytes=max_decoded_bytes)
