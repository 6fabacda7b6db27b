"""The service's tables (SQLAlchemy 2 typed models). Lengths are metres, as everywhere in graspgen.

objects 1-n object_versions      grippers 1-n gripper_versions 1-n gripper_files (the meshes of a spec with geometry)
jobs (of a kind registered in services/jobkinds; a bulk job is the parent of its items)
grasp_sets: one immutable version per object version x gripper version x parameters, numbered per
            (object, gripper) pair; grasps: one row per exported grasp, so the catalogue is queryable without files.
catalogue_pairs: what the catalogue serves for each (object, gripper) pair, kept by services/common/catalogue.py;
catalogue_events: the releases and withdrawals (who, when); change_counter: the one row that numbers changes.
"""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    TypeDecorator,
    UniqueConstraint,
    Uuid,
)
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

__all__ = [
    "Base",
    "ObjectModel",
    "ObjectVersion",
    "Gripper",
    "GripperVersion",
    "GripperFile",
    "Job",
    "GraspSet",
    "Grasp",
    "CataloguePair",
    "CatalogueEvent",
    "ChangeCounter",
    "JOB_STATES",
    "TERMINAL_STATES",
    "utcnow",
]

JOB_STATES = ("queued", "running", "succeeded", "failed", "cancelled")
TERMINAL_STATES = frozenset({"succeeded", "failed", "cancelled"})

JSONType = JSON().with_variant(JSONB(), "postgresql")
#: SQLite only auto-increments an INTEGER PRIMARY KEY
BigId = BigInteger().with_variant(Integer(), "sqlite")


def utcnow() -> datetime:
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """Timestamps stored with time zone and always returned aware (SQLite forgets the zone)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is None:
            raise ValueError("naive datetime given to a UTC column")
        return value.astimezone(UTC) if value is not None else None

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is None:
            return value.replace(tzinfo=UTC)
        return value


class Base(DeclarativeBase):
    metadata = MetaData(
        naming_convention={
            "ix": "ix_%(table_name)s_%(column_0_N_name)s",
            "uq": "uq_%(table_name)s_%(column_0_N_name)s",
            "ck": "ck_%(table_name)s_%(constraint_name)s",
            "fk": "fk_%(table_name)s_%(column_0_name)s",
            "pk": "pk_%(table_name)s",
        }
    )
    type_annotation_map = {datetime: UTCDateTime(), dict[str, Any]: JSONType, list[Any]: JSONType}


class _Timestamps:
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class ObjectModel(_Timestamps, Base):
    __tablename__ = "objects"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(63), unique=True)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow)

    versions: Mapped[list[ObjectVersion]] = relationship(
        back_populates="object", order_by="ObjectVersion.version", lazy="raise"
    )


class ObjectVersion(_Timestamps, Base):
    __tablename__ = "object_versions"
    __table_args__ = (
        UniqueConstraint("object_id", "version"),
        UniqueConstraint("object_id", "sha256", "units"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id", ondelete="CASCADE"))
    version: Mapped[int]
    sha256: Mapped[str] = mapped_column(String(64))
    units: Mapped[str] = mapped_column(String(8))
    format: Mapped[str] = mapped_column(String(16))
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    #: bounding-box extents in metres, (3,)
    extents: Mapped[list[Any]]
    watertight: Mapped[bool] = mapped_column(Boolean)
    warnings: Mapped[list[Any]]
    #: the part's mass in kg when the uploader gave it (a job without mass_kg or density uses it)
    mass_kg: Mapped[float | None] = mapped_column(Float)
    #: storage key of the uploaded bytes (content-addressed)
    file_key: Mapped[str] = mapped_column(String(200))

    object: Mapped[ObjectModel] = relationship(back_populates="versions", lazy="raise")


class Gripper(_Timestamps, Base):
    __tablename__ = "grippers"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(63), unique=True)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow)


class GripperVersion(_Timestamps, Base):
    __tablename__ = "gripper_versions"
    __table_args__ = (
        UniqueConstraint("gripper_id", "version"),
        UniqueConstraint("gripper_id", "spec_sha256"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    gripper_id: Mapped[int] = mapped_column(ForeignKey("grippers.id", ondelete="CASCADE"))
    version: Mapped[int]
    #: the validated spec (CONTRACT.md gripper spec), as GripperSpec.to_dict() gives it (with geometry: each file's
    #: sha256 in spec.geometry.sha256, so the spec's digest changes when a file does)
    spec: Mapped[dict[str, Any]]
    spec_sha256: Mapped[str] = mapped_column(String(64))


class GripperFile(Base):
    """One mesh file of a gripper version whose spec has `geometry`: the path the spec names, stored
    content-addressed (its key is storage.blob_key(sha256)). Written with the version, never changed."""

    __tablename__ = "gripper_files"
    __table_args__ = (UniqueConstraint("gripper_version_id", "path"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    gripper_version_id: Mapped[int] = mapped_column(ForeignKey("gripper_versions.id", ondelete="CASCADE"))
    #: the file name as the spec's geometry gives it (a relative path)
    path: Mapped[str] = mapped_column(String(255))
    sha256: Mapped[str] = mapped_column(String(64))
    size_bytes: Mapped[int] = mapped_column(BigInteger)
    #: storage key of the bytes (content-addressed)
    file_key: Mapped[str] = mapped_column(String(200))


class Job(_Timestamps, Base):
    __tablename__ = "jobs"
    __table_args__ = (
        UniqueConstraint("created_by", "idempotency_key"),
        Index(None, "parent_id", "item_index"),
        Index(None, "state", "created_at"),
        Index(None, "created_by", "created_at"),
    )

    id: Mapped[uuid.UUID] = mapped_column(Uuid, primary_key=True, default=uuid.uuid4)
    kind: Mapped[str] = mapped_column(String(16))
    state: Mapped[str] = mapped_column(String(16), default="queued")
    stage: Mapped[str | None] = mapped_column(String(32))
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    #: the request as submitted (a bulk item for a child), shown back to the client
    request: Mapped[dict[str, Any]]
    #: the effective run parameters (graspgen Params, friction resolved) once the inputs are known
    params: Mapped[dict[str, Any] | None] = mapped_column(JSONType)
    object_version_id: Mapped[int | None] = mapped_column(ForeignKey("object_versions.id"))
    gripper_version_id: Mapped[int | None] = mapped_column(ForeignKey("gripper_versions.id"))
    #: cluster jobs: the grasp set whose candidates are re-clustered
    source_grasp_set_id: Mapped[int | None] = mapped_column(ForeignKey("grasp_sets.id"))
    grasp_set_id: Mapped[int | None] = mapped_column(ForeignKey("grasp_sets.id"))
    parent_id: Mapped[uuid.UUID | None] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"))
    item_index: Mapped[int | None]
    #: problem details {type, title, detail, code} of a failed job
    error: Mapped[dict[str, Any] | None] = mapped_column(JSONType)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    idempotency_key: Mapped[str | None] = mapped_column(String(255))
    #: sha256 of the canonical request, to refuse an Idempotency-Key reused for another request
    request_sha256: Mapped[str | None] = mapped_column(String(64))
    #: name of the token that submitted the job (never the token)
    created_by: Mapped[str] = mapped_column(String(100))
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]
    #: the X-Request-Id of the submitting request (issue 16)
    request_id: Mapped[str | None] = mapped_column(String(64))


class GraspSet(_Timestamps, Base):
    __tablename__ = "grasp_sets"
    __table_args__ = (
        UniqueConstraint("object_id", "gripper_id", "version"),
        UniqueConstraint("object_version_id", "gripper_version_id", "params_key"),
        UniqueConstraint("job_id"),
        Index(None, "gripper_id", "object_id", "version"),
        Index(None, "created_at"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id"))
    gripper_id: Mapped[int] = mapped_column(ForeignKey("grippers.id"))
    #: numbered per (object, gripper) pair, 1, 2, ...: the highest is the newest
    version: Mapped[int]
    object_version_id: Mapped[int] = mapped_column(ForeignKey("object_versions.id"))
    gripper_version_id: Mapped[int] = mapped_column(ForeignKey("gripper_versions.id"))
    params: Mapped[dict[str, Any]]
    #: sha256 over params and derived_from: equal inputs give the same grasp set, never a second version
    params_key: Mapped[str] = mapped_column(String(64))
    derived_from_id: Mapped[int | None] = mapped_column(ForeignKey("grasp_sets.id"))
    #: the job that computed it (a redelivered job finds its set through this unique column)
    job_id: Mapped[uuid.UUID] = mapped_column(Uuid)
    stats: Mapped[dict[str, Any]]
    grasp_count: Mapped[int]
    export_key: Mapped[str] = mapped_column(String(200))
    export_sha256: Mapped[str] = mapped_column(String(64))
    export_size: Mapped[int] = mapped_column(BigInteger)
    candidates_key: Mapped[str | None] = mapped_column(String(200))
    recording_key: Mapped[str | None] = mapped_column(String(200))
    #: set when withdrawn: the catalogue never serves it again (unless it is released anew)
    withdrawn_at: Mapped[datetime | None]


class Grasp(Base):
    __tablename__ = "grasps"
    __table_args__ = (UniqueConstraint("grasp_set_id", "rank"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    grasp_set_id: Mapped[int] = mapped_column(ForeignKey("grasp_sets.id", ondelete="CASCADE"))
    #: position in the export's grasps list, 0 = first
    rank: Mapped[int]
    #: T_object_grasp, 4x4 row-major
    pose: Mapped[list[Any]]
    #: a parallel grasp's contact distance; None for a suction grasp (one contact)
    width: Mapped[float | None] = mapped_column(Float)
    #: the two contacts of a parallel grasp, the one contact of a suction grasp
    contacts: Mapped[list[Any]]
    normals: Mapped[list[Any]]
    #: a parallel grasp's friction margin; None for a suction grasp
    friction_margin_deg: Mapped[float | None] = mapped_column(Float)
    free_rolls_deg: Mapped[list[Any]]
    cluster_translation: Mapped[int]
    cluster_direction: Mapped[int]
    cluster_size: Mapped[int]


class CataloguePair(Base):
    """What `GET /v1/catalogue/{object}/{gripper}` serves, recomputed in the transaction of every change that can
    alter it (a new grasp set, object version or gripper version; a release; a withdrawal)."""

    __tablename__ = "catalogue_pairs"
    __table_args__ = (Index(None, "gripper_id", "change_seq"),)

    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id", ondelete="CASCADE"), primary_key=True)
    gripper_id: Mapped[int] = mapped_column(ForeignKey("grippers.id", ondelete="CASCADE"), primary_key=True)
    #: the released set, if any (one per pair)
    released_id: Mapped[int | None] = mapped_column(ForeignKey("grasp_sets.id"))
    #: the set served now: the released one, else the newest for the newest object and gripper versions; None: none
    current_id: Mapped[int | None] = mapped_column(ForeignKey("grasp_sets.id"))
    #: the current set was made for an older object or gripper version (only a released set can be)
    stale: Mapped[bool] = mapped_column(Boolean, default=False)
    #: change_counter value of the last change of what this pair serves (fleet sync's `since`)
    change_seq: Mapped[int] = mapped_column(BigInteger)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow)


class CatalogueEvent(Base):
    """One release or withdrawal: the history of a pair."""

    __tablename__ = "catalogue_events"
    __table_args__ = (Index(None, "object_id", "gripper_id", "id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    object_id: Mapped[int] = mapped_column(ForeignKey("objects.id", ondelete="CASCADE"))
    gripper_id: Mapped[int] = mapped_column(ForeignKey("grippers.id", ondelete="CASCADE"))
    grasp_set_id: Mapped[int] = mapped_column(ForeignKey("grasp_sets.id", ondelete="CASCADE"))
    #: "release" | "withdraw"
    action: Mapped[str] = mapped_column(String(16))
    at: Mapped[datetime] = mapped_column(default=utcnow)
    #: name of the token (never the token)
    by: Mapped[str] = mapped_column(String(100))
    #: a release: the set it replaced as released, if any
    replaced_id: Mapped[int | None] = mapped_column(ForeignKey("grasp_sets.id"))


class ChangeCounter(Base):
    """A single row (id 1): the last change sequence number handed out. Changes lock it until they commit, so
    sequence numbers become visible in order (docs/SERVICE.md, fleet sync)."""

    __tablename__ = "change_counter"

    id: Mapped[int] = mapped_column(primary_key=True)
    value: Mapped[int] = mapped_column(BigInteger)
