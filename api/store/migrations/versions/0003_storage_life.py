"""Storage life of a job: pinned models, expiry, and the wait for disk space.

Revision ID: 0003
Revises: 0002
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    """Add ``jobs.pinned`` (false for jobs stored before it), ``jobs.expired_at`` and
    ``jobs.disk_wait_since`` (both NULL until they happen)."""
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("pinned", sa.Boolean, nullable=False, server_default=sa.false()))
        batch.add_column(sa.Column("expired_at", sa.Float))
        batch.add_column(sa.Column("disk_wait_since", sa.Float))


def downgrade() -> None:
    """Drop the three columns."""
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("disk_wait_since")
        batch.drop_column("expired_at")
        batch.drop_column("pinned")
