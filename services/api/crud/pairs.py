"""Every object x gripper pair of the catalogue with what it serves, across grippers (the review page's list).

`GET /v1/catalogue` is fleet sync for one gripper; this listing is for people: every pair that has ever had a grasp
set, by object name then gripper name, with its current set (services/common/catalogue.py's rule), whether that set
is released or stale, the pair's last release or withdrawal and who made it. Keyset pages over (object, gripper)
names, so page 200 of 10,000 pairs costs what page 1 does.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import Select, and_, func, or_, select
from sqlalchemy.orm import Session

from services.common.models import CatalogueEvent, CataloguePair, GraspSet, Gripper, Job, ObjectModel

from ..pagination import decode_cursor, fetch_page, next_link
from ..problems import ApiError
from .grasp_sets import event_out, summary_out, summary_select

__all__ = ["list_pairs"]

#: names are slugs of at most 63 characters; a longer cursor key was not issued here
_NAME_MAX = 63


def _filtered(
    q: Select, *, object_contains: str | None, gripper: str | None, released: bool | None, stale: bool | None
) -> Select:
    """`q` (over catalogue pairs joined to their object and gripper) with the listing's filters."""
    if object_contains:
        q = q.where(ObjectModel.name.contains(object_contains, autoescape=True))
    if gripper:
        q = q.where(Gripper.name == gripper)
    if released is not None:
        # a released set is always the pair's current one (catalogue.py), so having one is being released
        q = q.where(CataloguePair.released_id.is_not(None) if released else CataloguePair.released_id.is_(None))
    if stale is not None:
        q = q.where(CataloguePair.stale.is_(stale))
    return q


def list_pairs(
    session: Session,
    *,
    object_contains: str | None,
    gripper: str | None,
    released: bool | None,
    stale: bool | None,
    cursor: str | None,
    limit: int,
) -> dict[str, Any]:
    """One page of pairs by (object name, gripper name), the filters applied, and how many pairs match in all."""
    key = decode_cursor(cursor, (str, str))
    if key and any(len(k) > _NAME_MAX for k in key):
        raise ApiError(422, "invalid-cursor", "the cursor is not one this endpoint issued")
    filters: dict[str, Any] = {
        "object_contains": object_contains,
        "gripper": gripper,
        "released": released,
        "stale": stale,
    }
    base = (
        select(
            CataloguePair.object_id,
            CataloguePair.gripper_id,
            CataloguePair.current_id,
            CataloguePair.released_id,
            CataloguePair.stale,
            CataloguePair.change_seq,
            CataloguePair.updated_at,
            ObjectModel.name.label("object"),
            Gripper.name.label("gripper"),
        )
        .join(ObjectModel, ObjectModel.id == CataloguePair.object_id)
        .join(Gripper, Gripper.id == CataloguePair.gripper_id)
    )
    base = _filtered(base, **filters)
    total = session.execute(select(func.count()).select_from(base.subquery())).scalar_one()
    q = base
    if key:
        after_object, after_gripper = key
        q = q.where(
            or_(ObjectModel.name > after_object, and_(ObjectModel.name == after_object, Gripper.name > after_gripper))
        )
    rows, nxt = fetch_page(session, q.order_by(ObjectModel.name, Gripper.name), limit, lambda r: [r.object, r.gripper])

    ids = [r.current_id for r in rows if r.current_id is not None]
    summaries: dict[int, dict[str, Any]] = {}
    if ids:
        q_sets = summary_select().add_columns(Job.created_by).outerjoin(Job, Job.id == GraspSet.job_id)
        for r in session.execute(q_sets.where(GraspSet.id.in_(ids))).all():
            summaries[r.id] = {**summary_out(r), "created_by": r.created_by}
    events = _last_events(session, [(r.object_id, r.gripper_id) for r in rows])

    items = [
        {
            "object": r.object,
            "gripper": r.gripper,
            "current": summaries.get(r.current_id) if r.current_id is not None else None,
            "released": r.released_id is not None and r.released_id == r.current_id,
            "released_id": r.released_id,
            "stale": bool(r.stale),
            "updated_at": r.updated_at,
            "change_seq": int(r.change_seq),
            "last_event": events.get((r.object_id, r.gripper_id)),
            "links": {
                "catalogue": f"/v1/catalogue/{r.object}/{r.gripper}",
                "history": f"/v1/catalogue/{r.object}/{r.gripper}/history",
                "grasp_sets": f"/v1/grasp-sets?object={r.object}&gripper={r.gripper}",
            },
        }
        for r in rows
    ]
    query = "".join(
        f"&{k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in filters.items() if v is not None and v != ""
    )
    return {
        "items": items,
        "total": total,
        "next_cursor": nxt,
        "links": {"next": next_link("/v1/pairs", nxt, limit, query)},
    }


def _last_events(session: Session, pairs: list[tuple[int, int]]) -> dict[tuple[int, int], dict[str, Any]]:
    """(object id, gripper id) -> the pair's newest release or withdrawal, for the pairs of one page."""
    if not pairs:
        return {}
    newest = (
        select(func.max(CatalogueEvent.id))
        .where(
            or_(*(and_(CatalogueEvent.object_id == o, CatalogueEvent.gripper_id == g) for o, g in pairs)),
        )
        .group_by(CatalogueEvent.object_id, CatalogueEvent.gripper_id)
    )
    rows = session.execute(
        select(CatalogueEvent, GraspSet.version)
        .join(GraspSet, GraspSet.id == CatalogueEvent.grasp_set_id)
        .where(CatalogueEvent.id.in_(newest))
    ).all()
    return {(e.object_id, e.gripper_id): event_out(e, v) for e, v in rows}
