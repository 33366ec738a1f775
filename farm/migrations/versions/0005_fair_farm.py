"""A fair farm: each job's cost estimate and priority, and a tile's forest job (``parent``),
so a tiled forest's tiles are found, counted and canceled by one indexed statement.

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-27
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:  # batch: SQLite cannot alter in place
        batch.add_column(sa.Column("parent", sa.String(32), nullable=True))
        batch.add_column(sa.Column("priority", sa.Integer(), nullable=False, server_default="5"))
        batch.add_column(sa.Column("cost", sa.BigInteger(), nullable=False, server_default="0"))
        batch.add_column(sa.Column("tiles", sa.Integer(), nullable=False, server_default="0"))
        batch.add_column(sa.Column("estimate", sa.JSON(), nullable=True))
        # a forest's tiles by state, and those not sent yet (enqueued_at null): the fair
        # window's and the join's lookups, and cancel's one update
        batch.create_index("ix_jobs_parent_state", ["parent", "state", "enqueued_at"])


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_index("ix_jobs_parent_state")
        for name in ("estimate", "tiles", "cost", "priority", "parent"):
            batch.drop_column(name)
