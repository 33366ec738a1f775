"""The job graph: a job may wait for others (``after``) before the fair window sends it.

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-27
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:  # batch: SQLite cannot alter in place
        batch.add_column(sa.Column("after", sa.JSON(), nullable=True))
        batch.add_column(sa.Column("then", sa.JSON(), nullable=True))
        batch.add_column(
            sa.Column("blocked", sa.Boolean(), nullable=False, server_default=sa.false())
        )
        # each pump looks for the jobs still waiting for others
        batch.create_index("ix_jobs_blocked", ["blocked"])


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_index("ix_jobs_blocked")
        batch.drop_column("blocked")
        batch.drop_column("then")
        batch.drop_column("after")
