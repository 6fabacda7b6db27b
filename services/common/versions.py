"""Objects and grippers alike: a named thing kept in numbered versions that never change. Which tables hold each and
the lookups that the API (services/api/crud/versioned.py, crud/jobs.py) and the job kinds (services/jobkinds) share;
the API's errors are raised by the callers, so the worker can import this without the API."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from .models import Gripper, GripperVersion, ObjectModel, ObjectVersion

__all__ = ["Versioned", "OBJECTS", "GRIPPERS", "find_version", "name_and_version"]


@dataclass(frozen=True)
class Versioned:
    """The table of the named things, the table of their versions (linked by `<what>_id`) and their API path."""

    what: str  # "object" | "gripper": messages, the link column, catalogue.refresh's keyword
    table: type[Any]  # the mapped classes: ObjectModel or Gripper
    versions: type[Any]  # ObjectVersion or GripperVersion
    path: str

    @property
    def link(self) -> Any:
        return getattr(self.versions, f"{self.what}_id")


OBJECTS = Versioned("object", ObjectModel, ObjectVersion, "/v1/objects")
GRIPPERS = Versioned("gripper", Gripper, GripperVersion, "/v1/grippers")


def find_version(session: Session, kind: Versioned, name: str, version: int | None) -> Any | None:
    """Version `version` of the thing called `name`, or its newest when `version` is None; None when there is none."""
    q = select(kind.versions).join(kind.table, kind.table.id == kind.link).where(kind.table.name == name)
    q = q.where(kind.versions.version == version) if version else q.order_by(kind.versions.version.desc()).limit(1)
    return session.execute(q).scalars().first()


def name_and_version(session: Session, kind: Versioned, version_id: int) -> tuple[str, int]:
    """(name, version number) of the version row `version_id`, which exists."""
    name, version = session.execute(
        select(kind.table.name, kind.versions.version)
        .join(kind.versions, kind.link == kind.table.id)
        .where(kind.versions.id == version_id)
    ).one()
    return name, version
