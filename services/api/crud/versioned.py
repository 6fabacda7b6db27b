"""Objects and grippers alike (services/common/versions.py): finding one and its versions, adding the next version,
the thing with its versions and the keyset-paged list, once for both (crud/objects.py, crud/grippers.py)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from services.common import catalogue
from services.common.models import utcnow
from services.common.versions import Versioned

from ..pagination import decode_cursor, fetch_page, next_link
from ..problems import ApiError

__all__ = ["get_named", "versions_of", "get_version", "add_version", "named_out", "list_page"]

#: attempts at adding a version when a concurrent writer took the name or the number
_ATTEMPTS = 3


def get_named(session: Session, kind: Versioned, name: str) -> Any:
    row = session.execute(select(kind.table).where(kind.table.name == name)).scalar_one_or_none()
    if row is None:
        raise ApiError(404, "not-found", f"no {kind.what} named {name!r}")
    return row


def versions_of(session: Session, kind: Versioned, row: Any) -> list[Any]:
    """Every version of `row`, oldest first."""
    q = select(kind.versions).where(kind.link == row.id).order_by(kind.versions.version)
    return list(session.execute(q).scalars().all())


def get_version(session: Session, kind: Versioned, name: str, version: int) -> Any:
    row = get_named(session, kind, name)
    v = session.execute(
        select(kind.versions).where(kind.link == row.id, kind.versions.version == version)
    ).scalar_one_or_none()
    if v is None:
        raise ApiError(404, "not-found", f"{kind.what} {name!r} has no version {version}")
    return v


def add_version(
    session: Session,
    kind: Versioned,
    name: str,
    columns: dict[str, Any],
    *,
    existing: Callable[[], Any],
    children: Callable[[Any], list[Any]] = lambda version: [],
) -> tuple[Any, bool]:
    """Commit the next version of `name` (created with it when new) with `columns`, and refresh the catalogue (sets
    for the older version are no longer "the newest"; a released one turns stale). `children(version)` gives rows
    that belong to the new version (a gripper's files), added in the same transaction. Returns (version, True), or
    (the version `existing()` finds, False) when a concurrent writer committed the same content first."""
    for _ in range(_ATTEMPTS):
        try:
            row = session.execute(
                select(kind.table).where(kind.table.name == name).with_for_update()
            ).scalar_one_or_none()
            if row is None:
                row = kind.table(name=name)
                session.add(row)
                session.flush()
            latest = session.execute(select(func.max(kind.versions.version)).where(kind.link == row.id)).scalar()
            v = kind.versions(**{f"{kind.what}_id": row.id}, version=(latest or 0) + 1, **columns)
            row.updated_at = utcnow()
            session.add(v)
            session.flush()
            session.add_all(children(v))
            session.flush()
            catalogue.refresh(session, **{f"{kind.what}_id": row.id})
            session.commit()
            return v, True
        except IntegrityError:
            # a concurrent writer took the name or the version number; the same content returns its version
            session.rollback()
            found = existing()
            if found is not None:
                return found, False
    raise ApiError(409, "conflict", f"concurrent changes to this {kind.what}; retry")


def named_out(
    session: Session,
    kind: Versioned,
    name: str,
    version_out: Callable[[str, Any], dict[str, Any]],
    *,
    links: dict[str, str],
    latest: Callable[[list[Any]], dict[str, Any]] = lambda versions: {},
) -> dict[str, Any]:
    """The thing called `name` with every version (`version_out` of each, oldest first): `latest(versions)` adds fields
    of the newest version after `updated_at` (a gripper's spec), `links` come after its own."""
    row = get_named(session, kind, name)
    versions = versions_of(session, kind, row)
    return {
        "name": row.name,
        "latest_version": versions[-1].version if versions else 0,
        "created_at": row.created_at,
        "updated_at": row.updated_at,
        **latest(versions),
        "versions": [version_out(row.name, v) for v in versions],
        "links": {"self": f"{kind.path}/{row.name}", **links},
    }


def list_page(session: Session, kind: Versioned, *, cursor: str | None, limit: int) -> dict[str, Any]:
    """One page of the things that have a version, by name, with their latest version number."""
    key = decode_cursor(cursor, (str,))
    latest = (
        select(kind.link.label("id"), func.max(kind.versions.version).label("latest")).group_by(kind.link).subquery()
    )
    q = select(kind.table, latest.c.latest).join(latest, latest.c.id == kind.table.id)
    if key:
        q = q.where(kind.table.name > key[0])
    rows, nxt = fetch_page(session, q.order_by(kind.table.name), limit, lambda r: [r[0].name])
    items = [
        {
            "name": row.name,
            "latest_version": latest_version,
            "updated_at": row.updated_at,
            "links": {"self": f"{kind.path}/{row.name}"},
        }
        for row, latest_version in rows
    ]
    return {"items": items, "next_cursor": nxt, "links": {"next": next_link(kind.path, nxt, limit)}}
