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

from services.common import catalogue
from services.common.models import (
    CatalogueEvent,
    CataloguePair,
    Grasp,
    GraspSet,
    Gripper,
    GripperVersion,
    ObjectModel,
    ObjectVersion,
)

from ..pagination import decode_cursor, fetch_page, next_link
from ..problems import ApiError
from ..schemas import ID_MAX

__all__ = [
    "summary_select",
    "summary_out",
    "list_grasp_sets",
    "get_grasp_set",
    "catalogue_entry",
    "list_catalogue",
    "catalogue_history",
    "release",
    "withdraw",
    "list_grasps",
    "etag_of",
    "ExportRef",
    "export_ref",
    "grasp_set_row",
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
    #: catalogue lookups: the set is the released one of its pair; it was made for an older object/gripper version
    released: bool = False
    stale: bool = False


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
    return _with_names(
        select(
            GraspSet.id,
            GraspSet.version,
            GraspSet.params,
            GraspSet.derived_from_id,
            GraspSet.job_id,
            GraspSet.grasp_count,
            GraspSet.export_sha256,
            GraspSet.created_at,
            GraspSet.withdrawn_at,
            ObjectModel.name.label("object"),
            ObjectVersion.version.label("object_version"),
            Gripper.name.label("gripper"),
            GripperVersion.version.label("gripper_version"),
        )
    )


def _with_names(q: Select) -> Select:
    """`q` over grasp sets joined to their object and gripper and the versions they were made for."""
    return (
        q.join(ObjectModel, ObjectModel.id == GraspSet.object_id)
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
        "withdrawn_at": row.withdrawn_at,
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


def _id_of(session: Session, model: type[Any], name: str, what: str, status: int = 404) -> int:
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
    rows, nxt = fetch_page(session, q.order_by(GraspSet.id.desc()), limit, lambda r: [r.id])
    query = "".join(f"&{k}={v}" for k, v in (("object", object), ("gripper", gripper)) if v)
    return {
        "items": [summary_out(r) for r in rows],
        "next_cursor": nxt,
        "links": {"next": next_link("/v1/grasp-sets", nxt, limit, query)},
    }


def get_grasp_set(session: Session, grasp_set_id: int) -> GraspSet:
    gs = session.get(GraspSet, grasp_set_id)
    if gs is None:
        raise ApiError(404, "not-found", f"no grasp set {grasp_set_id}")
    return gs


def grasp_set_row(session: Session, grasp_set_id: int, q: Select) -> Any:
    """The row of `q` (columns of grasp sets and what it joins) for the grasp set `grasp_set_id`; 404 without it."""
    row = session.execute(q.where(GraspSet.id == grasp_set_id)).first()
    if row is None:
        raise ApiError(404, "not-found", f"no grasp set {grasp_set_id}")
    return row


def export_ref(session: Session, grasp_set_id: int) -> ExportRef:
    q = select(GraspSet.id, GraspSet.version, GraspSet.export_key, GraspSet.export_sha256)
    return ExportRef(*grasp_set_row(session, grasp_set_id, q))


@dataclass(frozen=True)
class PreviewRef:
    """What drawing a grasp set's preview needs: its export and its object version's file."""

    id: int
    export_key: str
    object_file_key: str
    object_units: str
    object_format: str


def preview_ref(session: Session, grasp_set_id: int) -> PreviewRef:
    q = select(
        GraspSet.id, GraspSet.export_key, ObjectVersion.file_key, ObjectVersion.units, ObjectVersion.format
    ).join(ObjectVersion, ObjectVersion.id == GraspSet.object_version_id)
    return PreviewRef(*grasp_set_row(session, grasp_set_id, q))


def catalogue_entry(session: Session, object: str, gripper: str, version: int | None) -> ExportRef:
    """The set the catalogue serves for the pair (services/common/catalogue.py), or its numbered `version` (which is
    served whatever the rule says, unless it was withdrawn)."""
    if version is None:
        row = session.execute(
            select(
                GraspSet.id,
                GraspSet.version,
                GraspSet.export_key,
                GraspSet.export_sha256,
                (CataloguePair.released_id == GraspSet.id).label("released"),
                CataloguePair.stale,
            )
            .select_from(CataloguePair)
            .join(ObjectModel, ObjectModel.id == CataloguePair.object_id)
            .join(Gripper, Gripper.id == CataloguePair.gripper_id)
            .join(GraspSet, GraspSet.id == CataloguePair.current_id)
            .where(ObjectModel.name == object, Gripper.name == gripper)
        ).first()
        if row is None:
            _pair_ids(session, object, gripper)  # only the miss pays for saying which name is unknown
            raise ApiError(
                404,
                "not-found",
                f"no grasp set of object {object!r} with gripper {gripper!r} is released or was made for the newest "
                "object and gripper versions",
            )
        return ExportRef(row.id, row.version, row.export_key, row.export_sha256, bool(row.released), bool(row.stale))
    q = _with_names(
        select(
            GraspSet.id,
            GraspSet.version,
            GraspSet.export_key,
            GraspSet.export_sha256,
            GraspSet.withdrawn_at,
            GraspSet.object_id,
            GraspSet.gripper_id,
            ObjectVersion.version.label("ov"),
            GripperVersion.version.label("gv"),
        )
    )
    row = session.execute(
        q.where(ObjectModel.name == object, Gripper.name == gripper, GraspSet.version == version)
    ).first()
    if row is None:
        _pair_ids(session, object, gripper)
        raise ApiError(404, "not-found", f"no version {version} for object {object!r} with gripper {gripper!r}")
    if row.withdrawn_at is not None:
        raise ApiError(
            404, "withdrawn", f"version {version} of object {object!r} with gripper {gripper!r} was withdrawn"
        )
    released = session.execute(
        select(CataloguePair.released_id).where(
            CataloguePair.object_id == row.object_id, CataloguePair.gripper_id == row.gripper_id
        )
    ).scalar_one_or_none()
    newest_ov = session.execute(
        select(func.max(ObjectVersion.version)).where(ObjectVersion.object_id == row.object_id)
    ).scalar_one()
    newest_gv = session.execute(
        select(func.max(GripperVersion.version)).where(GripperVersion.gripper_id == row.gripper_id)
    ).scalar_one()
    return ExportRef(
        row.id,
        row.version,
        row.export_key,
        row.export_sha256,
        released == row.id,
        (row.ov, row.gv) != (newest_ov, newest_gv),
    )


def _pair_ids(session: Session, object: str, gripper: str) -> tuple[int, int]:
    return _id_of(session, ObjectModel, object, "object"), _id_of(session, Gripper, gripper, "gripper")


#: change numbers are PostgreSQL bigint; a forged cursor beyond them is a 422, not a database error
SEQ_MAX = 2**62


def _catalogue_item(row: Any, summary: dict[str, Any] | None, gripper: str) -> dict[str, Any]:
    """A fleet-sync entry: the current set's summary with the pair's state, or, when the pair serves nothing any
    more (its set was withdrawn, or a newer object or gripper version has no set yet), `id: null, withdrawn: true`."""
    pair = {
        "released": row.released_id is not None and row.released_id == row.current_id,
        "stale": bool(row.stale),
        "withdrawn": row.current_id is None,
        "change_seq": int(row.change_seq),
    }
    if summary is not None:
        return {**summary, **pair}
    return {
        "id": None,
        "object": row.object,
        "gripper": gripper,
        **pair,
        "links": {"catalogue": f"/v1/catalogue/{row.object}/{gripper}"},
    }


def list_catalogue(
    session: Session,
    *,
    gripper: str,
    since: int | None = None,
    updated_since: datetime | None = None,
    cursor: str | None = None,
    limit: int,
) -> tuple[dict[str, Any], str]:
    """Fleet sync for `gripper`; returns (body, strong ETag).

    Without `since`: the current set of every object (pairs serving nothing are left out), by object name.
    With `since`: every pair whose served set changed after that change number, in change order, including pairs
    that serve nothing now (`withdrawn: true`), so a robot drops them. Either way `next_since` is the watermark to
    send as `since` next time: every change up to it is in what this listing returned (docs/SERVICE.md).
    """
    grip_id = _id_of(session, Gripper, gripper, "gripper")
    by_seq = since is not None
    key = decode_cursor(cursor, (int, int) if by_seq else (str, int))
    if since is not None and since < 0:
        raise ApiError(422, "validation-error", "since must be >= 0", field="since")
    if key:
        after, mark = key
        if not 0 <= mark <= SEQ_MAX or (by_seq and not 0 <= after <= SEQ_MAX):
            raise ApiError(422, "invalid-cursor", "the cursor is not one this endpoint issued")
    else:
        after = since if by_seq else None
        # read before the rows: every change numbered up to the mark committed before it (the counter lock), so the
        # rows, read later, contain them all
        mark = session.execute(
            select(func.coalesce(func.max(CataloguePair.change_seq), 0)).where(CataloguePair.gripper_id == grip_id)
        ).scalar_one()
        mark = max(int(mark), since or 0)
    pairs = (
        select(
            CataloguePair.object_id,
            CataloguePair.current_id,
            CataloguePair.released_id,
            CataloguePair.stale,
            CataloguePair.change_seq,
            ObjectModel.name.label("object"),
        )
        .join(ObjectModel, ObjectModel.id == CataloguePair.object_id)
        .where(CataloguePair.gripper_id == grip_id)
    )
    if by_seq:
        pairs = pairs.where(CataloguePair.change_seq > after).order_by(CataloguePair.change_seq)
    else:
        pairs = pairs.where(CataloguePair.current_id.is_not(None)).order_by(ObjectModel.name)
        if after is not None:
            pairs = pairs.where(ObjectModel.name > after)
        if updated_since is not None:
            # compatibility: the current set was created after that instant (the worker's clock; prefer `since`)
            pairs = pairs.join(GraspSet, GraspSet.id == CataloguePair.current_id).where(
                GraspSet.created_at > updated_since
            )
    rows, nxt = fetch_page(session, pairs, limit, lambda r: [r.change_seq, mark] if by_seq else [r.object, mark])
    more = nxt is not None
    ids = [r.current_id for r in rows if r.current_id is not None]
    summaries = (
        {r.id: summary_out(r) for r in session.execute(summary_select().where(GraspSet.id.in_(ids))).all()}
        if ids
        else {}
    )
    items = [_catalogue_item(r, summaries.get(r.current_id), gripper) for r in rows]
    if by_seq:
        delivered = max((int(r.change_seq) for r in rows), default=0)
        # a page cut short resumes after its last item; the last page after everything seen so far
        next_since = delivered if more else max(mark, delivered)
    else:
        next_since = mark
    query = f"&since={since}" if by_seq else ""
    query += f"&updated_since={updated_since.isoformat()}" if updated_since else ""
    body = {
        "gripper": gripper,
        "items": items,
        "next_cursor": nxt,
        "next_since": next_since,
        "links": {
            "next": f"/v1/catalogue?gripper={gripper}{query}&cursor={nxt}&limit={limit}" if nxt else None,
            "sync": f"/v1/catalogue?gripper={gripper}&since={next_since}",
        },
    }
    # the page is a function of its content: hashing it is a strong validator
    return body, etag_of(hashlib.sha256(dumps(body)).hexdigest())


def catalogue_history(session: Session, object: str, gripper: str, *, cursor: str | None, limit: int) -> dict[str, Any]:
    """Releases and withdrawals of a pair, newest first."""
    object_id, gripper_id = _pair_ids(session, object, gripper)
    key = _int_cursor(cursor)
    q = (
        select(CatalogueEvent, GraspSet.version)
        .join(GraspSet, GraspSet.id == CatalogueEvent.grasp_set_id)
        .where(CatalogueEvent.object_id == object_id, CatalogueEvent.gripper_id == gripper_id)
    )
    if key:
        q = q.where(CatalogueEvent.id < key[0])
    rows, nxt = fetch_page(session, q.order_by(CatalogueEvent.id.desc()), limit, lambda r: [r[0].id])
    return {
        "object": object,
        "gripper": gripper,
        "items": [event_out(e, v) for e, v in rows],
        "next_cursor": nxt,
        "links": {
            "next": next_link(f"/v1/catalogue/{object}/{gripper}/history", nxt, limit),
            "catalogue": f"/v1/catalogue/{object}/{gripper}",
        },
    }


def event_out(e: CatalogueEvent, version: int) -> dict[str, Any]:
    return {
        "grasp_set": e.grasp_set_id,
        "version": version,
        "action": e.action,
        "at": e.at,
        "by": e.by,
        "replaced": e.replaced_id,
        "links": {"grasp_set": f"/v1/grasp-sets/{e.grasp_set_id}"},
    }


def _change(session: Session, grasp_set_id: int, by: str, action: str) -> dict[str, Any]:
    do = catalogue.release if action == "release" else catalogue.withdraw
    try:
        state, event = do(session, grasp_set_id, by)
    except catalogue.CatalogueError as exc:
        session.rollback()
        raise ApiError(exc.status, exc.code, exc.detail) from None
    session.commit()
    names = session.execute(
        select(ObjectModel.name, Gripper.name, GraspSet.version)
        .join(Gripper, Gripper.id == GraspSet.gripper_id)
        .join(ObjectModel, ObjectModel.id == GraspSet.object_id)
        .where(GraspSet.id == grasp_set_id)
    ).one()
    obj, grip, version = names
    return {
        "grasp_set": grasp_set_id,
        "version": version,
        "object": obj,
        "gripper": grip,
        "action": action,
        "changed": event is not None,
        "event": event_out(event, version) if event is not None else None,
        "current": state.current_id,
        "released": state.released_id,
        "stale": state.stale,
        "change_seq": state.change_seq,
        "links": {
            "grasp_set": f"/v1/grasp-sets/{grasp_set_id}",
            "catalogue": f"/v1/catalogue/{obj}/{grip}",
            "history": f"/v1/catalogue/{obj}/{grip}/history",
        },
    }


def release(session: Session, grasp_set_id: int, by: str) -> dict[str, Any]:
    return _change(session, grasp_set_id, by, "release")


def withdraw(session: Session, grasp_set_id: int, by: str) -> dict[str, Any]:
    return _change(session, grasp_set_id, by, "withdraw")


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
    rows, nxt = fetch_page(session, q.order_by(Grasp.rank), limit, lambda g: [g.rank], scalars=True)
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
        "links": {"next": next_link(f"/v1/grasp-sets/{grasp_set_id}/grasps", nxt, limit)},
    }
