"""Grippers and their versions: validated by GripperSpec; an identical spec is not a new version."""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from graspgen.gripper import GripperSpec
from services.common.jobs import sha256_json
from services.common.models import Gripper, GripperVersion
from services.common.versions import GRIPPERS

from .versioned import add_version, get_version, list_page, named_out

__all__ = ["create_gripper", "gripper_out", "get_gripper_version", "list_grippers", "version_out"]


def version_out(name: str, v: GripperVersion) -> dict[str, Any]:
    return {
        "name": name,
        "version": v.version,
        "spec": v.spec,
        "created_at": v.created_at,
        "links": {"self": f"/v1/grippers/{name}/versions/{v.version}", "gripper": f"/v1/grippers/{name}"},
    }


def _find(session: Session, name: str, digest: str) -> GripperVersion | None:
    return session.execute(
        select(GripperVersion)
        .join(Gripper, Gripper.id == GripperVersion.gripper_id)
        .where(Gripper.name == name, GripperVersion.spec_sha256 == digest)
    ).scalar_one_or_none()


def create_gripper(session: Session, data: Any) -> tuple[dict[str, Any], bool]:
    spec = GripperSpec.from_dict(data).to_dict()  # InvalidGripperError -> 422
    digest = sha256_json(spec)
    name = spec["name"]
    existing = _find(session, name, digest)
    if existing is not None:
        return version_out(name, existing), False
    v, created = add_version(
        session, GRIPPERS, name, {"spec": spec, "spec_sha256": digest}, existing=lambda: _find(session, name, digest)
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


def list_grippers(session: Session, *, cursor: str | None, limit: int) -> dict[str, Any]:
    return list_page(session, GRIPPERS, cursor=cursor, limit=limit)
