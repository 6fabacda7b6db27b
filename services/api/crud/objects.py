"""Objects and their versions: upload (content-addressed, idempotent), lookup, listing."""

from __future__ import annotations

import hashlib
import math
import re
import tempfile
from pathlib import Path
from typing import Any, BinaryIO

from sqlalchemy import select
from sqlalchemy.orm import Session

from graspgen.gripper import SLUG_PATTERN
from graspgen.units import to_metres_scale
from services.common.models import ObjectModel, ObjectVersion
from services.common.settings import Settings
from services.common.storage import Storage
from services.common.versions import OBJECTS

from ..problems import ApiError
from . import versioned
from .versioned import add_version, list_page, named_out

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
    columns = {
        "sha256": digest,
        "units": units,
        "format": fmt,
        "size_bytes": size,
        "extents": [float(x) for x in part.extents],
        "watertight": bool(part.watertight),
        "warnings": [str(w) for w in (part.warnings or [])],
        "file_key": blob.key,
        "mass_kg": mass_kg,
    }
    v, created = add_version(session, OBJECTS, name, columns, existing=lambda: _find(session, name, digest, units))
    return (version_out(name, v), True) if created else (_same(name, v, mass_kg), False)


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


def object_out(session: Session, name: str) -> dict[str, Any]:
    return named_out(session, OBJECTS, name, version_out, links={"grasp_sets": f"/v1/grasp-sets?object={name}"})


def get_object(session: Session, name: str) -> dict[str, Any]:
    return object_out(session, name)


def get_version(session: Session, name: str, version: int) -> ObjectVersion:
    return versioned.get_version(session, OBJECTS, name, version)


def list_objects(session: Session, *, cursor: str | None, limit: int) -> dict[str, Any]:
    return list_page(session, OBJECTS, cursor=cursor, limit=limit)
