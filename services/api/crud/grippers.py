"""Grippers and their versions: validated by graspgen's spec of their kind (graspgen.kinds: a parallel gripper's
GripperSpec, a suction cup's SuctionSpec); an identical spec is not a new version.

A spec with `geometry` (CAD fingers and body, or a suction tool's body) comes with its mesh files (multipart, one
part per file name the geometry gives). The spec is checked with its files before anything is stored; its stored
form (the spec's to_dict) carries each file's sha256, so identical specs with identical files give the same digest
(the existing version) and a changed file a new one. The files go to storage content-addressed, like object files,
and into gripper_files with the version.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from graspgen.kinds import gripper_from_dict
from services.common.grippers import file_digests
from services.common.jobs import sha256_json
from services.common.models import Gripper, GripperFile, GripperVersion
from services.common.storage import Storage
from services.common.versions import GRIPPERS

from ..problems import ApiError
from .versioned import add_version, get_version, list_page, named_out

__all__ = [
    "create_gripper",
    "gripper_out",
    "get_gripper_version",
    "get_gripper_file",
    "list_grippers",
    "version_out",
]


def version_out(name: str, v: GripperVersion) -> dict[str, Any]:
    base = f"/v1/grippers/{name}/versions/{v.version}"
    files = [{"path": p, "sha256": sha, "link": f"{base}/files/{p}"} for p, sha in sorted(file_digests(v.spec).items())]
    return {
        "name": name,
        "version": v.version,
        "spec": v.spec,
        "files": files,
        "created_at": v.created_at,
        "links": {"self": base, "gripper": f"/v1/grippers/{name}"},
    }


def _find(session: Session, name: str, digest: str) -> GripperVersion | None:
    return session.execute(
        select(GripperVersion)
        .join(Gripper, Gripper.id == GripperVersion.gripper_id)
        .where(Gripper.name == name, GripperVersion.spec_sha256 == digest)
    ).scalar_one_or_none()


def create_gripper(
    session: Session,
    data: Any,
    *,
    files: dict[str, bytes] | None = None,
    storage: Storage | None = None,
    max_decoded_bytes: int | None = None,
) -> tuple[dict[str, Any], bool]:
    """Register a spec (and, with geometry, its `files` by name); returns (version view, created)."""
    # InvalidGripperError -> 422: the spec, every file (missing, extra, unreadable, not a closed solid, frames)
    spec = gripper_from_dict(data, files=files, max_decoded_bytes=max_decoded_bytes).to_dict()
    digest = sha256_json(spec)
    name = spec["name"]
    existing = _find(session, name, digest)
    if existing is not None:
        return version_out(name, existing), False
    session.rollback()  # hold no transaction (a SQLite write lock) while the files are stored
    rows: list[dict[str, Any]] = []
    digests = file_digests(spec)
    if digests and (files is None or storage is None):
        raise RuntimeError("a geometry spec is stored with its files and a storage")
    for path in digests:
        assert files is not None and storage is not None  # checked above
        blob = storage.put_bytes(files[path])  # StorageError -> 503, nothing in the database
        rows.append({"path": path, "sha256": blob.sha256, "size_bytes": blob.size, "file_key": blob.key})
    v, created = add_version(
        session,
        GRIPPERS,
        name,
        {"spec": spec, "spec_sha256": digest},
        existing=lambda: _find(session, name, digest),
        children=lambda version: [GripperFile(gripper_version_id=version.id, **row) for row in rows],
    )
    return version_out(name, v), created


def gripper_out(session: Session, name: str) -> dict[str, Any]:
    return named_out(
        session,
        GRIPPERS,
        name,
        version_out,
        links={"catalogue": f"/v1/catalogue?gripper={name}"},
        latest=lambda versions: {"spec": versions[-1].spec if versions else {}},
    )


def get_gripper_version(session: Session, name: str, version: int) -> dict[str, Any]:
    return version_out(name, get_version(session, GRIPPERS, name, version))


def get_gripper_file(session: Session, name: str, version: int, path: str) -> GripperFile:
    """The file `path` of a gripper version; 404 when the version has no such file."""
    v = get_version(session, GRIPPERS, name, version)
    f = session.execute(
        select(GripperFile).where(GripperFile.gripper_version_id == v.id, GripperFile.path == path)
    ).scalar_one_or_none()
    if f is None:
        raise ApiError(404, "not-found", f"gripper {name!r} version {version} has no file {path!r}", field="path")
    return f


def list_grippers(session: Session, *, cursor: str | None, limit: int) -> dict[str, Any]:
    return list_page(session, GRIPPERS, cursor=cursor, limit=limit)
