"""Objects and their versions: upload (content-addressed, idempotent), lookup, listing."""

from __future__ import annotations

import hashlib
import math
import re
import tempfile
from pathlib import Path
from typing import Any, BinaryIO

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from graspgen.gripper import SLUG_PATTERN
from graspgen.units import to_metres_scale
from services.common import catalogue
from services.common.models import ObjectModel, ObjectVersion, utcnow
from services.common.settings import Settings
from services.common.storage import Storage

from ..pagination import decode_cursor, fetch_page, next_link
from ..problems import ApiError

__all__ = ["check_slug", "upload_object", "get_object", "get_version", "list_objects", "version_out", "object_out"]

_FORMAT = re.compile(r"^[a-z0-9]{1,10}$")
_CHUNK = 1024 * 1024


def check_slug(name: str, what: str) -> str:
    if not isinstance(name, str) or not SLUG_PATTERN.match(name):
        raise ApiError(
            422, "invalid-name", f"{what} name {name!r} is not a slug ([a-z0-9][a-z0-9._-]{{0,62}})", field="name"
        )
    return name


def _format(fmt: str | None, filename: str | None) -> str:
    if fmt:
        value = fmt.strip().lower().lstrip(".")
    elif filename and "." in filename:
        value = filename.rsplit(".", 1)[1].lower()
    else:
        raise ApiError(
            422,
            "invalid-format",
            "give the file format (format field) or a file name with an extension",
            field="format",
        )
    if not _FORMAT.match(value):
        raise ApiError(422, "invalid-format", f"file format {value!r} is not a file extension", field="format")
    return value


def version_out(obj_name: str, v: ObjectVersion) -> dict[str, Any]:
    base = f"/v1/objects/{obj_name}/versions/{v.version}"
    return {
        "name": obj_name,
        "version": v.version,
        "sha256": v.sha256,
        "units": v.units,
        "format": v.format,
        "size_bytes": v.size_bytes,
        "extents": v.extents,
        "watertight": v.watertight,
        "warnings": v.warnings,
        "mass_kg": v.mass_kg,
        "created_at": v.created_at,
        "links": {"self": base, "file": base + "/file", "object": f"/v1/objects/{obj_name}"},
    }


def _find(session: Session, name: str, sha256: str, units: str) -> ObjectVersion | None:
    return session.execute(
        select(ObjectVersion)
        .join(ObjectModel, ObjectModel.id == ObjectVersion.object_id)
        .where(ObjectModel.name == name, ObjectVersion.sha256 == sha256, ObjectVersion.units == units)
    ).scalar_one_or_none()


def upload_object(
    session: Session,
    storage: Storage,
    settings: Settings,
    *,
    name: str,
    units: str,
    fmt: str | None,
    filename: str | None,
    stream: BinaryIO,
    mass_kg: float | None = None,
) -> tuple[dict[str, Any], bool]:
    """Store an uploaded part; returns (version view, created). The same bytes and units return the existing one
    (a different `mass_kg` for them is a 409: a version never changes; a job can give its own mass_kg)."""
    from graspgen.parts import load_part

    check_slug(name, "object")
    mass_kg = check_mass(mass_kg)
    to_metres_scale(units)  # raises InvalidUnitsError -> 422
    units = units.strip().lower()
    fmt = _format(fmt, filename)
    with tempfile.TemporaryDirectory(prefix="graspgen-upload-") as tmp:
        path = Path(tmp) / f"upload.{fmt}"
        h = hashlib.sha256()
        size = 0
        with open(path, "wb") as out:
            while chunk := stream.read(_CHUNK):
                size += len(chunk)
                if size > settings.max_upload_bytes:
                    raise ApiError(
                        413,
                        "content-too-large",
                        f"the file is larger than the limit of {settings.max_upload_bytes} bytes",
                    )
                h.update(chunk)
                out.write(chunk)
        if size == 0:
            raise ApiError(422, "invalid-mesh", "the file is empty", field="file")
        digest = h.hexdigest()
        existing = _find(session, name, digest, units)
        session.rollback()  # hold no transaction (a SQLite write lock) while the mesh is checked
        if existing is not None:
            return _same(name, existing, mass_kg), False
        # bytes, not the path: the loader names its input in messages, and the client must not see the server's
        # temp path (load_part reads the whole file either way)
        part = load_part(  # InvalidMeshError -> 422 (also for files declaring more than max_decoded_bytes)
            path.read_bytes(), units=units, name=name, file_type=fmt, max_decoded_bytes=settings.max_decoded_bytes
        )
        blob = storage.put_file(path)
    for _ in range(3):
        try:
            obj = session.execute(
                select(ObjectModel).where(ObjectModel.name == name).with_for_update()
            ).scalar_one_or_none()
            if obj is None:
                obj = ObjectModel(name=name)
                session.add(obj)
                session.flush()
            latest = session.execute(
                select(func.max(ObjectVersion.version)).where(ObjectVersion.object_id == obj.id)
            ).scalar_one_or_none()
            v = ObjectVersion(
                object_id=obj.id,
                version=(latest or 0) + 1,
                sha256=digest,
                units=units,
                format=fmt,
                size_bytes=size,
                extents=[float(x) for x in part.extents],
                watertight=bool(part.watertight),
                warnings=[str(w) for w in (part.warnings or [])],
                file_key=blob.key,
                mass_kg=mass_kg,
            )
            obj.updated_at = utcnow()
            session.add(v)
            session.flush()
            # sets for the older version are no longer "the newest" (a released one turns stale)
            catalogue.refresh(session, object_id=obj.id)
            session.commit()
            return version_out(name, v), True
        except IntegrityError:
            # a concurrent upload took the name or the version number; the same bytes return its version
            session.rollback()
            existing = _find(session, name, digest, units)
            if existing is not None:
                return _same(name, existing, mass_kg), False
    raise ApiError(409, "conflict", "concurrent uploads under this name; retry")


#: the largest part mass accepted, kg (graspgen.Params takes the same range for a job's mass_kg)
MASS_MAX_KG = 100_000.0


def check_mass(mass_kg: float | None) -> float | None:
    """A positive finite mass in kg, or None; anything else is a 422 problem."""
    if mass_kg is None:
        return None
    if not math.isfinite(mass_kg) or not 0.0 < mass_kg <= MASS_MAX_KG:
        raise ApiError(
            422,
            "invalid-parameter",
            f"mass_kg must be a finite number of kilograms > 0 and <= {MASS_MAX_KG:g}, got {mass_kg!r}",
            field="mass_kg",
        )
    return float(mass_kg)


def _same(name: str, existing: ObjectVersion, mass_kg: float | None) -> dict[str, Any]:
    """The existing version for an identical upload, unless the upload gives it another mass."""
    if mass_kg is not None and existing.mass_kg != mass_kg:
        have = "no mass" if existing.mass_kg is None else f"mass_kg {existing.mass_kg:g}"
        raise ApiError(
            409,
            "mass-conflict",
            f"version {existing.version} of {name!r} has these bytes with {have}; a version never changes (give "
            "mass_kg in the job's params instead)",
            field="mass_kg",
            version=existing.version,
        )
    return version_out(name, existing)


def _object(session: Session, name: str) -> ObjectModel:
    obj = session.execute(select(ObjectModel).where(ObjectModel.name == name)).scalar_one_or_none()
    if obj is None:
        raise ApiError(404, "not-found", f"no object named {name!r}")
    return obj


def object_out(session: Session, name: str) -> dict[str, Any]:
    obj = _object(session, name)
    versions = (
        session.execute(select(ObjectVersion).where(ObjectVersion.object_id == obj.id).order_by(ObjectVersion.version))
        .scalars()
        .all()
    )
    return {
        "name": obj.name,
        "latest_version": versions[-1].version if versions else 0,
        "created_at": obj.created_at,
        "updated_at": obj.updated_at,
        "versions": [version_out(obj.name, v) for v in versions],
        "links": {"self": f"/v1/objects/{obj.name}", "grasp_sets": f"/v1/grasp-sets?object={obj.name}"},
    }


def get_object(session: Session, name: str) -> dict[str, Any]:
    return object_out(session, name)


def get_version(session: Session, name: str, version: int) -> ObjectVersion:
    obj = _object(session, name)
    v = session.execute(
        select(ObjectVersion).where(ObjectVersion.object_id == obj.id, ObjectVersion.version == version)
    ).scalar_one_or_none()
    if v is None:
        raise ApiError(404, "not-found", f"object {name!r} has no version {version}")
    return v


def list_objects(session: Session, *, cursor: str | None, limit: int) -> dict[str, Any]:
    key = decode_cursor(cursor, (str,))
    latest = (
        select(ObjectVersion.object_id, func.max(ObjectVersion.version).label("latest"))
        .group_by(ObjectVersion.object_id)
        .subquery()
    )
    q = select(ObjectModel, latest.c.latest).join(latest, latest.c.object_id == ObjectModel.id)
    if key:
        q = q.where(ObjectModel.name > key[0])
    rows, nxt = fetch_page(session, q.order_by(ObjectModel.name), limit, lambda r: [r[0].name])
    items = [
        {
            "name": o.name,
            "latest_version": latest_v,
            "updated_at": o.updated_at,
            "links": {"self": f"/v1/objects/{o.name}"},
        }
        for o, latest_v in rows
    ]
    return {
        "items": items,
        "next_cursor": nxt,
        "links": {"next": next_link("/v1/objects", nxt, limit)},
    }
