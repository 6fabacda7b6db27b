"""Catalogue releases and fleet sync (issue 15), the part's mass (issue 14), request ids on jobs (issue 16).

catalogue_pairs (what each object x gripper pair serves), catalogue_events (releases, withdrawals), change_counter
(the change sequence); grasp_sets.withdrawn_at, object_versions.mass_kg, jobs.request_id and an index for the job
listing. Existing grasp sets are entered into catalogue_pairs under the "newest versions" rule.

Revision ID: 0002
Revises: 0001
Create Date: 2026-12-02 12:10:00
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column("object_versions", sa.Column("mass_kg", sa.Float(), nullable=True))
    op.add_column("jobs", sa.Column("request_id", sa.String(length=64), nullable=True))
    op.create_index(op.f("ix_jobs_created_by_created_at"), "jobs", ["created_by", "created_at"], unique=False)
    op.add_column("grasp_sets", sa.Column("withdrawn_at", sa.DateTime(timezone=True), nullable=True))
    op.create_table(
        "change_counter",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("value", sa.BigInteger(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_change_counter")),
    )
    op.create_table(
        "catalogue_pairs",
        sa.Column("object_id", sa.Integer(), nullable=False),
        sa.Column("gripper_id", sa.Integer(), nullable=False),
        sa.Column("released_id", sa.Integer(), nullable=True),
        sa.Column("current_id", sa.Integer(), nullable=True),
        sa.Column("stale", sa.Boolean(), nullable=False),
        sa.Column("change_seq", sa.BigInteger(), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["current_id"], ["grasp_sets.id"], name=op.f("fk_catalogue_pairs_current_id")),
        sa.ForeignKeyConstraint(
            ["gripper_id"], ["grippers.id"], name=op.f("fk_catalogue_pairs_gripper_id"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(
            ["object_id"], ["objects.id"], name=op.f("fk_catalogue_pairs_object_id"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(["released_id"], ["grasp_sets.id"], name=op.f("fk_catalogue_pairs_released_id")),
        sa.PrimaryKeyConstraint("object_id", "gripper_id", name=op.f("pk_catalogue_pairs")),
    )
    op.create_index(
        op.f("ix_catalogue_pairs_gripper_id_change_seq"), "catalogue_pairs", ["gripper_id", "change_seq"], unique=False
    )
    op.create_table(
        "catalogue_events",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("object_id", sa.Integer(), nullable=False),
        sa.Column("gripper_id", sa.Integer(), nullable=False),
        sa.Column("grasp_set_id", sa.Integer(), nullable=False),
        sa.Column("action", sa.String(length=16), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("by", sa.String(length=100), nullable=False),
        sa.Column("replaced_id", sa.Integer(), nullable=True),
        sa.ForeignKeyConstraint(
            ["grasp_set_id"], ["grasp_sets.id"], name=op.f("fk_catalogue_events_grasp_set_id"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(
            ["gripper_id"], ["grippers.id"], name=op.f("fk_catalogue_events_gripper_id"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(
            ["object_id"], ["objects.id"], name=op.f("fk_catalogue_events_object_id"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(["replaced_id"], ["grasp_sets.id"], name=op.f("fk_catalogue_events_replaced_id")),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_catalogue_events")),
    )
    op.create_index(
        op.f("ix_catalogue_events_object_id_gripper_id_id"),
        "catalogue_events",
        ["object_id", "gripper_id", "id"],
        unique=False,
    )
    _fill_pairs()


def _fill_pairs() -> None:
    """Every pair with a grasp set gets a row: its newest set made for the newest object and gripper versions (None
    when there is none), numbered 1, 2, ... in the change sequence."""
    conn = op.get_bind()
    current = dict(
        ((o, g), i)
        for o, g, i in conn.execute(
            sa.text(
                "SELECT gs.object_id, gs.gripper_id, gs.id FROM grasp_sets gs "
                "JOIN object_versions ov ON ov.id = gs.object_version_id "
                "JOIN gripper_versions gv ON gv.id = gs.gripper_version_id "
                "WHERE ov.version = (SELECT max(version) FROM object_versions WHERE object_id = gs.object_id) "
                "AND gv.version = (SELECT max(version) FROM gripper_versions WHERE gripper_id = gs.gripper_id) "
                "ORDER BY gs.version"
            )
        )
    )  # ordered by version: the newest wins
    pairs = conn.execute(
        sa.text("SELECT DISTINCT object_id, gripper_id FROM grasp_sets ORDER BY object_id, gripper_id")
    ).all()
    now = datetime.now(UTC)
    table = sa.table(
        "catalogue_pairs",
        sa.column("object_id", sa.Integer),
        sa.column("gripper_id", sa.Integer),
        sa.column("released_id", sa.Integer),
        sa.column("current_id", sa.Integer),
        sa.column("stale", sa.Boolean),
        sa.column("change_seq", sa.BigInteger),
        sa.column("updated_at", sa.DateTime(timezone=True)),
    )
    rows = [
        {
            "object_id": o,
            "gripper_id": g,
            "released_id": None,
            "current_id": current.get((o, g)),
            "stale": False,
            "change_seq": seq,
            "updated_at": now,
        }
        for seq, (o, g) in enumerate(pairs, start=1)
    ]
    if rows:
        op.bulk_insert(table, rows)
    counter = sa.table("change_counter", sa.column("id", sa.Integer), sa.column("value", sa.BigInteger))
    op.bulk_insert(counter, [{"id": 1, "value": len(rows)}])


def downgrade() -> None:
    op.drop_index(op.f("ix_catalogue_events_object_id_gripper_id_id"), table_name="catalogue_events")
    op.drop_table("catalogue_events")
    op.drop_index(op.f("ix_catalogue_pairs_gripper_id_change_seq"), table_name="catalogue_pairs")
    op.drop_table("catalogue_pairs")
    op.drop_table("change_counter")
    op.drop_index(op.f("ix_jobs_created_by_created_at"), table_name="jobs")
    # plain ALTER TABLE ... DROP COLUMN (SQLite >= 3.35 has it for columns without constraints): a batch copy of the
    # table would have to drop it, which SQLite's enforced foreign keys refuse while other tables refer to its rows
    for table, column in (("grasp_sets", "withdrawn_at"), ("jobs", "request_id"), ("object_versions", "mass_kg")):
        op.execute(f"ALTER TABLE {table} DROP COLUMN {column}")
