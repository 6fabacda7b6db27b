"""Grippers and their versions: validated by GripperSpec; an identical spec is not a new version."""

from __future__ import annotations

from typing import Any

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from graspgen.gripper import GripperSpec
from services.common import catalogue
from services.common.jobs import sha256_json
from services.common.models import Gripper, GripperVersion, utcnow

from ..pagination import decode_cursor, fetch_page, next_link
from ..problems import ApiError

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
    for _ in range(3):
        existing = _find(session, name, digest)
        if existing is not None:
            return version_out(name, existing), False
        try:
            g = session.execute(select(Gripper).where(Gripper.name == name).with_for_update()).scalar_one_or_none()
            if g is None:
                g = Gripper(name=name)
                session.add(g)
                session.flush()
            latest = session.execute(
                select(func.max(GripperVersion.version)).where(GripperVersion.gripper_id == g.id)
            ).scalar_one_or_none()
            v = GripperVersion(gripper_id=g.id, version=(latest or 0) + 1, spec=spec, spec_sha256=digest)
            g.updated_at = utcnow()
            session.add(v)
            session.flush()
            # sets for the older version are no longer "the newest" (a released one turns stale)
            catalogue.refresh(session, gripper_id=g.id)
            session.commit()
            return version_out(name, v), True
        except IntegrityError:
            session.rollback()
    raise ApiError(409, "conflict", "concurrent changes to this gripper; retry")


def _gripper(session: Session, name: str) -> Gripper:
    g = session.execute(select(Gripper).where(Gripper.name == name)).scalar_one_or_none()
    if g is None:
        raise ApiError(404, "not-found", f"no gripper named {name!r}")
    return g


def gripper_out(session: Session, name: str) -> dict[str, Any]:
    g = _gripper(session, name)
    versions = (
        session.execute(
            select(GripperVersion).where(GripperVersion.gripper_id == g.id).order_by(GripperVersion.version)
        )
        .scalars()
        .all()
    )
    return {
        "name": g.name,
        "latest_version": versions[-1].version if versions else 0,
        "created_at": g.created_at,
        "updated_at": g.updated_at,
        "spec": versions[-1].spec if versions else {},
        "versions": [version_out(g.name, v) for v in versions],
        "links": {"self": f"/v1/grippers/{g.name}", "catalogue": f"/v1/catalogue?gripper={g.name}"},
    }


def get_gripper_version(session: Session, name: str, version: int) -> dict[str, Any]:
    g = _gripper(session, name)
    v = session.execute(
        select(GripperVersion).where(GripperVersion.gripper_id == g.id, GripperVersion.version == version)
    ).scalar_one_or_none()
    if v is None:
        raise ApiError(404, "not-found", f"gripper {name!r} has no version {version}")
    return version_out(name, v)


def list_grippers(session: Session, *, cursor: str | None, limit: int) -> dict[str, Any]:
    key = decode_cursor(cursor, (str,))
    latest = (
        select(GripperVersion.gripper_id, func.max(GripperVersion.version).label("latest"))
        .group_by(GripperVersion.gripper_id)
        .subquery()
    )
    q = select(Gripper, latest.c.latest).join(latest, latest.c.gripper_id == Gripper.id)
    if key:
        q = q.where(Gripper.name > key[0])
    rows, nxt = fetch_page(session, q.order_by(Gripper.name), limit, lambda r: [r[0].name])
    items = [
        {"name": g.name, "latest_version": v, "updated_at": g.updated_at, "links": {"self": f"/v1/grippers/{g.name}"}}
        for g, v in rows
    ]
    return {
        "items": items,
        "next_cursor": nxt,
        "links": {"next": next_link("/v1/grippers", nxt, limit)},
    }
