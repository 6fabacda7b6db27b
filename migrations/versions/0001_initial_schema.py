"""Initial schema: objects, grippers, jobs, grasp sets and grasps (services/common/models.py).

Revision ID: 0001
Revises:
Create Date: 2026-11-23 16:22:21.354988
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = "0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# frozen here rather than imported from the models: a migration must not change when the models do
_JSON = sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql")


def upgrade() -> None:
    op.create_table(
        "grippers",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=63), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_grippers")),
        sa.UniqueConstraint("name", name=op.f("uq_grippers_name")),
    )
    op.create_table(
        "objects",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=63), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_objects")),
        sa.UniqueConstraint("name", name=op.f("uq_objects_name")),
    )
    op.create_table(
        "gripper_versions",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("gripper_id", sa.Integer(), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("spec", _JSON, nullable=False),
        sa.Column("spec_sha256", sa.String(length=64), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["gripper_id"], ["grippers.id"], name=op.f("fk_gripper_versions_gripper_id"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_gripper_versions")),
        sa.UniqueConstraint("gripper_id", "spec_sha256", name=op.f("uq_gripper_versions_gripper_id_spec_sha256")),
        sa.UniqueConstraint("gripper_id", "version", name=op.f("uq_gripper_versions_gripper_id_version")),
    )
    op.create_table(
        "object_versions",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("object_id", sa.Integer(), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("units", sa.String(length=8), nullable=False),
        sa.Column("format", sa.String(length=16), nullable=False),
        sa.Column("size_bytes", sa.BigInteger(), nullable=False),
        sa.Column("extents", _JSON, nullable=False),
        sa.Column("watertight", sa.Boolean(), nullable=False),
        sa.Column("warnings", _JSON, nullable=False),
        sa.Column("file_key", sa.String(length=200), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["object_id"], ["objects.id"], name=op.f("fk_object_versions_object_id"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_object_versions")),
        sa.UniqueConstraint("object_id", "sha256", "units", name=op.f("uq_object_versions_object_id_sha256_units")),
        sa.UniqueConstraint("object_id", "version", name=op.f("uq_object_versions_object_id_version")),
    )
    op.create_table(
        "grasp_sets",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("object_id", sa.Integer(), nullable=False),
        sa.Column("gripper_id", sa.Integer(), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("object_version_id", sa.Integer(), nullable=False),
        sa.Column("gripper_version_id", sa.Integer(), nullable=False),
        sa.Column("params", _JSON, nullable=False),
        sa.Column("params_key", sa.String(length=64), nullable=False),
        sa.Column("derived_from_id", sa.Integer(), nullable=True),
        sa.Column("job_id", sa.Uuid(), nullable=False),
        sa.Column("stats", _JSON, nullable=False),
        sa.Column("grasp_count", sa.Integer(), nullable=False),
        sa.Column("export_key", sa.String(length=200), nullable=False),
        sa.Column("export_sha256", sa.String(length=64), nullable=False),
        sa.Column("export_size", sa.BigInteger(), nullable=False),
        sa.Column("candidates_key", sa.String(length=200), nullable=True),
        sa.Column("recording_key", sa.String(length=200), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["derived_from_id"], ["grasp_sets.id"], name=op.f("fk_grasp_sets_derived_from_id")),
        sa.ForeignKeyConstraint(["gripper_id"], ["grippers.id"], name=op.f("fk_grasp_sets_gripper_id")),
        sa.ForeignKeyConstraint(
            ["gripper_version_id"], ["gripper_versions.id"], name=op.f("fk_grasp_sets_gripper_version_id")
        ),
        sa.ForeignKeyConstraint(["object_id"], ["objects.id"], name=op.f("fk_grasp_sets_object_id")),
        sa.ForeignKeyConstraint(
            ["object_version_id"], ["object_versions.id"], name=op.f("fk_grasp_sets_object_version_id")
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_grasp_sets")),
        sa.UniqueConstraint("job_id", name=op.f("uq_grasp_sets_job_id")),
        sa.UniqueConstraint(
            "object_id", "gripper_id", "version", name=op.f("uq_grasp_sets_object_id_gripper_id_version")
        ),
        sa.UniqueConstraint(
            "object_version_id",
            "gripper_version_id",
            "params_key",
            name=op.f("uq_grasp_sets_object_version_id_gripper_version_id_params_key"),
        ),
    )
    op.create_index(op.f("ix_grasp_sets_created_at"), "grasp_sets", ["created_at"], unique=False)
    op.create_index(
        op.f("ix_grasp_sets_gripper_id_object_id_version"),
        "grasp_sets",
        ["gripper_id", "object_id", "version"],
        unique=False,
    )
    op.create_table(
        "grasps",
        sa.Column("id", sa.BigInteger().with_variant(sa.Integer(), "sqlite"), nullable=False),
        sa.Column("grasp_set_id", sa.Integer(), nullable=False),
        sa.Column("rank", sa.Integer(), nullable=False),
        sa.Column("pose", _JSON, nullable=False),
        sa.Column("width", sa.Float(), nullable=False),
        sa.Column("contacts", _JSON, nullable=False),
        sa.Column("normals", _JSON, nullable=False),
        sa.Column("friction_margin_deg", sa.Float(), nullable=False),
        sa.Column("free_rolls_deg", _JSON, nullable=False),
        sa.Column("cluster_translation", sa.Integer(), nullable=False),
        sa.Column("cluster_direction", sa.Integer(), nullable=False),
        sa.Column("cluster_size", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["grasp_set_id"], ["grasp_sets.id"], name=op.f("fk_grasps_grasp_set_id"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_grasps")),
        sa.UniqueConstraint("grasp_set_id", "rank", name=op.f("uq_grasps_grasp_set_id_rank")),
    )
    op.create_table(
        "jobs",
        sa.Column("id", sa.Uuid(), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("stage", sa.String(length=32), nullable=True),
        sa.Column("progress", sa.Float(), nullable=False),
        sa.Column("request", _JSON, nullable=False),
        sa.Column("params", _JSON, nullable=True),
        sa.Column("object_version_id", sa.Integer(), nullable=True),
        sa.Column("gripper_version_id", sa.Integer(), nullable=True),
        sa.Column("source_grasp_set_id", sa.Integer(), nullable=True),
        sa.Column("grasp_set_id", sa.Integer(), nullable=True),
        sa.Column("parent_id", sa.Uuid(), nullable=True),
        sa.Column("item_index", sa.Integer(), nullable=True),
        sa.Column("error", _JSON, nullable=True),
        sa.Column("attempts", sa.Integer(), nullable=False),
        sa.Column("cancel_requested", sa.Boolean(), nullable=False),
        sa.Column("idempotency_key", sa.String(length=255), nullable=True),
        sa.Column("request_sha256", sa.String(length=64), nullable=True),
        sa.Column("created_by", sa.String(length=100), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["grasp_set_id"], ["grasp_sets.id"], name=op.f("fk_jobs_grasp_set_id")),
        sa.ForeignKeyConstraint(
            ["gripper_version_id"], ["gripper_versions.id"], name=op.f("fk_jobs_gripper_version_id")
        ),
        sa.ForeignKeyConstraint(["object_version_id"], ["object_versions.id"], name=op.f("fk_jobs_object_version_id")),
        sa.ForeignKeyConstraint(["parent_id"], ["jobs.id"], name=op.f("fk_jobs_parent_id"), ondelete="CASCADE"),
        sa.ForeignKeyConstraint(["source_grasp_set_id"], ["grasp_sets.id"], name=op.f("fk_jobs_source_grasp_set_id")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_jobs")),
        sa.UniqueConstraint("created_by", "idempotency_key", name=op.f("uq_jobs_created_by_idempotency_key")),
    )
    op.create_index(op.f("ix_jobs_parent_id_item_index"), "jobs", ["parent_id", "item_index"], unique=False)
    op.create_index(op.f("ix_jobs_state_created_at"), "jobs", ["state", "created_at"], unique=False)


def downgrade() -> None:
    op.drop_index(op.f("ix_jobs_state_created_at"), table_name="jobs")
    op.drop_index(op.f("ix_jobs_parent_id_item_index"), table_name="jobs")
    op.drop_table("jobs")
    op.drop_table("grasps")
    op.drop_index(op.f("ix_grasp_sets_gripper_id_object_id_version"), table_name="grasp_sets")
    op.drop_index(op.f("ix_grasp_sets_created_at"), table_name="grasp_sets")
    op.drop_table("grasp_sets")
    op.drop_table("object_versions")
    op.drop_table("gripper_versions")
    op.drop_table("objects")
    op.drop_table("grippers")
