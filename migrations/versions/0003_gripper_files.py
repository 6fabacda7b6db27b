"""Gripper geometry from CAD (issue 32): gripper_files, the mesh files of a gripper version whose spec has
`geometry`. Additive: existing gripper versions (box specs) have no files.

Revision ID: 0003
Revises: 0002
Create Date: 2026-12-06 14:30:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "gripper_files",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("gripper_version_id", sa.Integer(), nullable=False),
        sa.Column("path", sa.String(length=255), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("size_bytes", sa.BigInteger(), nullable=False),
        sa.Column("file_key", sa.String(length=200), nullable=False),
        sa.ForeignKeyConstraint(
            ["gripper_version_id"],
            ["gripper_versions.id"],
            name=op.f("fk_gripper_files_gripper_version_id"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_gripper_files")),
        sa.UniqueConstraint("gripper_version_id", "path", name=op.f("uq_gripper_files_gripper_version_id_path")),
    )


def downgrade() -> None:
    op.drop_table("gripper_files")
