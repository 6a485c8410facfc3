"""Warnings on a job: what training found that the upload could not (an empty model).

Revision ID: 0002
Revises: 0001
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    """Add ``jobs.warnings`` (a JSON list of strings; NULL for jobs stored before it)."""
    with op.batch_alter_table("jobs") as batch:
        batch.add_column(sa.Column("warnings", sa.JSON))


def downgrade() -> None:
    """Drop ``jobs.warnings``."""
    with op.batch_alter_table("jobs") as batch:
        batch.drop_column("warnings")
