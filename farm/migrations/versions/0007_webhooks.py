"""Webhooks: a job's URL to call when it ends, and its delivery's state (pending, attempts,
next try, delivered, last error).

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-27
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("jobs") as batch:  # batch: SQLite cannot alter in place
        batch.add_column(sa.Column("webhook_url", sa.String(2048), nullable=True))
        batch.add_column(
            sa.Column("webhook_pending", sa.Boolean(), nullable=False, server_default=sa.false())
        )
        batch.add_column(
            sa.Column("webhook_attempts", sa.Integer(), nullable=False, server_default="0")
        )
        batch.add_column(sa.Column("webhook_next_at", sa.DateTime(), nullable=True))
        batch.add_column(sa.Column("webhook_done_at", sa.DateTime(), nullable=True))
        batch.add_column(sa.Column("webhook_error", sa.Text(), nullable=True))
        # the deliveries' scan: pending ones only (few), whatever the table's size
        batch.create_index("ix_jobs_webhook_pending", ["webhook_pending", "webhook_next_at"])


def downgrade() -> None:
    with op.batch_alter_table("jobs") as batch:
        batch.drop_index("ix_jobs_webhook_pending")
        for name in (
            "webhook_error", "webhook_done_at", "webhook_next_at", "webhook_attempts",
            "webhook_pending", "webhook_url",
        ):  # fmt: skip
            batch.drop_column(name)
