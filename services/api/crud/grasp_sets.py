"""Grasp sets (immutable versions), their grasps, and the fleet catalogue built on them."""

from __future__ import annotations

import hashlib
import json
import uuid
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import Select, func, select
from sqlalchemy.orm import Session

from services.common.models import Grasp, GraspSet, Gripper, GripperVersion, ObjectModel, ObjectVersion

from ..pagination import decode_cursor, encode_cursor
from ..problems import ApiError
from ..schemas import ID_MAX

__all__ = [
    "summary_select",
    "summary_out",
    "list_grasp_sets",
    "get_grasp_set",
    "catalogue_entry",
    "list_catalogue",
    "list_grasps",
    "etag_of",
    "ExportRef",
    "export_ref",
    "PreviewRef",
    "preview_ref",
    "dumps",
]


@dataclass(frozen=True)
class ExportRef:
    """What serving an export needs, read in one query."""

    id: int
    version: int
    export_key: str
    export_sha256: str


def _json_default(value: Any) -> Any:
    if isinstance(value, datetime):
        return value.isoformat().replace("+00:00", "Z")
    if isinstance(value, uuid.UUID):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def dumps(body: Any) -> bytes:
    """JSON of a response body built here (hot paths skip response-model validation)."""
    return json.dumps(body, default=_json_default, separators=(",", ":")).encode()


def etag_of(sha256: str) -> str:
    return f'"{sha256}"'


def summary_select() -> Select:
    # columns, not entities: no ORM identity map and no stats JSON to decode for a list
    return (
        select(
            GraspSet.id,
            GraspSet.version,
            GraspSet.params,
            GraspSet.derived_from_id,
            GraspSet.job_id,
            GraspSet.grasp_count,
            GraspSet.export_sha256,
            GraspSet.created_at,
            ObjectModel.name.label("object"),
            ObjectVersion.version.label("object_version"),
            Gripper.name.label("gripper"),
            GripperVersion.version.label("gripper_version"),
        )
        .join(ObjectModel, ObjectModel.id == GraspSet.object_id)
        .join(ObjectVersion, ObjectVersion.id == GraspSet.object_version_id)
        .join(Gripper, Gripper.id == GraspSet.gripper_id)
        .join(GripperVersion, GripperVersion.id == GraspSet.gripper_version_id)
    )


def summary_out(row: Any) -> dict[str, Any]:
    base = f"/v1/grasp-sets/{row.id}"
    return {
        "id": row.id,
        "object": row.object,
        "object_version": row.object_version,
        "gripper": row.gripper,
        "gripper_version": row.gripper_version,
        "version": row.version,
        "params": row.params,
        "derived_from": row.derived_from_id,
        "job": row.job_id,
        "grasp_count": row.grasp_count,
        "sha256": row.export_sha256,
        "etag": etag_of(row.export_sha256),
        "created_at": row.created_at,
        "links": {
            "self": base,
            "candidates": base + "/candidates",
            "recording": base + "/recording",
            "grasps": base + "/grasps",
            "preview": base + "/preview.png",
            "catalogue": f"/v1/catalogue/{row.object}/{row.gripper}?version={row.version}",
        },
    }


def _int_cursor(cursor: str | None) -> list[Any] | None:
    """An id or rank cursor; a forged one outside the `integer` column's range is a 422, not a database error."""
    key = decode_cursor(cursor, (int,))
    if key and not 0 <= key[0] <= ID_MAX:
        raise ApiError(422, "invalid-cursor", "the cursor is not one this endpoint issued")
    return key


def _id_of(session: Session, model: type, name: str, what: str, status: int = 404) -> int:
    i = session.execute(select(model.id).where(model.name == name)).scalar_one_or_none()
    if i is None:
        raise ApiError(status, "not-found", f"no {what} named {name!r}")
    return i


def list_grasp_sets(
    session: Session, *, object: str | None, gripper: str | None, cursor: str | None, limit: int
) -> dict[str, Any]:
    key = _int_cursor(cursor)
    q = summary_select()
    if object:
        q = q.where(ObjectModel.name == object)
    if gripper:
        q = q.where(Gripper.name == gripper)
    if key:
        q = q.where(GraspSet.id < key[0])
    rows = session.execute(q.order_by(GraspSet.id.desc()).limit(limit + 1)).all()
    more = len(rows) > limit
    rows = rows[:limit]
    nxt = encode_cursor([rows[-1].id]) if more and rows else None
    query = "".join(f"&{k}={v}" for k, v in (("object", object), ("gripper", gripper)) if v)
    return {
        "items": [summary_out(r) for r in rows],
        "next_cursor": nxt,
        "links": {"next": f"/v1/grasp-sets?cursor={nxt}&limit={limit}{query}" if nxt else None},
    }


def get_grasp_set(session: Session, grasp_set_id: int) -> GraspSet:
    gs = session.get(GraspSet, grasp_set_id)
    if gs is None:
        raise ApiError(404, "not-found", f"no grasp set {grasp_set_id}")
    return gs


def export_ref(session: Session, grasp_set_id: int) -> ExportRef:
    row = session.execute(
        select(GraspSet.id, GraspSet.version, GraspSet.export_key, GraspSet.export_sha256).where(
            GraspSet.id == grasp_set_id
        )
    ).first()
    if row is None:
        raise ApiError(404, "not-found", f"no grasp set {grasp_set_id}")
    return ExportRef(*row)


@dataclass(frozen=True)
class PreviewRef:
    """What drawing a grasp set's preview needs: its export and its object version's file."""

    id: int
    export_key: str
    object_file_key: str
    object_units: str
    object_format: str


def preview_ref(session: Session, grasp_set_id: int) -> PreviewRef:
    row = session.execute(
        select(GraspSet.id, GraspSet.export_key, ObjectVersion.file_key, ObjectVersion.units, ObjectVersion.format)
        .join(ObjectVersion, ObjectVersion.id == GraspSet.object_version_id)
        .where(GraspSet.id == grasp_set_id)
    ).first()
    if row is None:
        raise ApiError(404, "not-found", f"no grasp set {grasp_set_id}")
    return PreviewRef(*row)


def catalogue_entry(session: Session, object: str, gripper: str, version: int | None) -> ExportRef:
    q = (
        select(GraspSet.id, GraspSet.version, GraspSet.export_key, GraspSet.export_sha256)
        .join(ObjectModel, ObjectModel.id == GraspSet.object_id)
        .join(Gripper, Gripper.id == GraspSet.gripper_id)
        .where(ObjectModel.name == object, Gripper.name == gripper)
    )
    q = q.where(GraspSet.version == version) if version else q.order_by(GraspSet.version.desc()).limit(1)
    row = session.execute(q).first()
    if row is None:
        # only the miss pays for saying which name is unknown
        _id_of(session, ObjectModel, object, "object")
        _id_of(session, Gripper, gripper, "gripper")
        what = f"version {version}" if version else "grasp set"
        raise ApiError(404, "not-found", f"no {what} for object {object!r} with gripper {gripper!r}")
    return ExportRef(*row)


def list_catalogue(
    session: Session, *, gripper: str, updated_since: datetime | None, cursor: str | None, limit: int
) -> tuple[dict[str, Any], str]:
    """The newest grasp set of every object for `gripper`, by object name; returns (body, strong ETag)."""
    key = decode_cursor(cursor, (str,))
    grip_id = _id_of(session, Gripper, gripper, "gripper")
    newest = (
        select(GraspSet.object_id.label("object_id"), func.max(GraspSet.version).label("version"))
        .where(GraspSet.gripper_id == grip_id)
        .group_by(GraspSet.object_id)
        .subquery()
    )
    q = (
        summary_select()
        .join(newest, (newest.c.object_id == GraspSet.object_id) & (newest.c.version == GraspSet.version))
        .where(GraspSet.gripper_id == grip_id)
    )
    if updated_since is not None:
        q = q.where(GraspSet.created_at > updated_since)
    if key:
        q = q.where(ObjectModel.name > key[0])
    rows = session.execute(q.order_by(ObjectModel.name).limit(limit + 1)).all()
    more = len(rows) > limit
    rows = rows[:limit]
    nxt = encode_cursor([rows[-1].object]) if more and rows else None
    since = f"&updated_since={updated_since.isoformat()}" if updated_since else ""
    body = {
        "gripper": gripper,
        "items": [summary_out(r) for r in rows],
        "next_cursor": nxt,
        "links": {"next": f"/v1/catalogue?gripper={gripper}{since}&cursor={nxt}&limit={limit}" if nxt else None},
    }
    # the page is a function of its grasp-set ids and export hashes, so hashing those is a strong validator
    basis = json.dumps([gripper, nxt, [(r.id, r.export_sha256) for r in rows]]).encode()
    return body, etag_of(hashlib.sha256(basis).hexdigest())


def list_grasps(
    session: Session,
    grasp_set_id: int,
    *,
    min_width: float | None,
    max_width: float | None,
    min_friction_margin_deg: float | None,
    cursor: str | None,
    limit: int,
) -> dict[str, Any]:
    get_grasp_set(session, grasp_set_id)
    key = _int_cursor(cursor)
    q = select(Grasp).where(Grasp.grasp_set_id == grasp_set_id)
    if min_width is not None:
        q = q.where(Grasp.width >= min_width)
    if max_width is not None:
        q = q.where(Grasp.width <= max_width)
    if min_friction_margin_deg is not None:
        q = q.where(Grasp.friction_margin_deg >= min_friction_margin_deg)
    if key:
        q = q.where(Grasp.rank > key[0])
    rows = session.execute(q.order_by(Grasp.rank).limit(limit + 1)).scalars().all()
    more = len(rows) > limit
    rows = rows[:limit]
    nxt = encode_cursor([rows[-1].rank]) if more and rows else None
    return {
        "items": [
            {
                "rank": g.rank,
                "pose": g.pose,
                "width": g.width,
                "contacts": g.contacts,
                "normals": g.normals,
                "friction_margin_deg": g.friction_margin_deg,
                "free_rolls_deg": g.free_rolls_deg,
                "cluster": [g.cluster_translation, g.cluster_direction],
                "cluster_size": g.cluster_size,
            }
            for g in rows
        ],
        "next_cursor": nxt,
        "links": {"next": f"/v1/grasp-sets/{grasp_set_id}/grasps?cursor={nxt}&limit={limit}" if nxt else None},
    }
