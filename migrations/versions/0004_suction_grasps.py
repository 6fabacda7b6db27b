"""Suction cups (issue 33): a suction grasp has one contact and no width or friction margin, so grasps.width and
grasps.friction_margin_deg become nullable. Existing rows (parallel grasps) keep their values.

Revision ID: 0004
Revises: 0003
Create Date: 2026-12-06 20:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_COLUMNS = ("width", "friction_margin_deg")


def upgrade() -> None:
    with op.batch_alter_table("grasps") as batch:  # SQLite: the table is copied; PostgreSQL: ALTER COLUMN
        for name in _COLUMNS:
            batch.alter_column(name, existing_type=sa.Float(), nullable=True)


def downgrade() -> None:
    # the older schema cannot tell a suction grasp's missing width from a width: its rows go with the downgrade
    op.execute("DELETE FROM grasps WHERE width IS NULL OR friction_margin_deg IS NULL")
    with op.batch_alter_table("grasps") as batch:
        for name in _COLUMNS:
            batch.alter_column(name, existing_type=sa.Float(), nullable=False)
