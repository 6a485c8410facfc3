"""The tables, as SQLAlchemy Core metadata. Times are float seconds since the epoch (UTC):
portable across SQLite and PostgreSQL and cheap to compare for leases."""

from __future__ import annotations

import sqlalchemy as sa

metadata = sa.MetaData()

jobs = sa.Table(
    "jobs",
    metadata,
    sa.Column("id", sa.String(40), primary_key=True),
    sa.Column("owner", sa.String(64), nullable=False, index=True),
    sa.Column("state", sa.String(16), nullable=False, index=True),
    sa.Column("spec", sa.JSON, nullable=False),
    sa.Column("created_at", sa.Float, nullable=False),
    sa.Column("started_at", sa.Float),
    sa.Column("finished_at", sa.Float),
    sa.Column("attempts", sa.Integer, nullable=False, default=0),
    sa.Column("worker_id", sa.String(80)),
    sa.Column("lease_until", sa.Float),
    sa.Column("cancel_requested", sa.Boolean, nullable=False, default=False),
    sa.Column("error", sa.Text),
    sa.Column("progress", sa.JSON),
    sa.Column("result", sa.JSON),
    sa.Column("warnings", sa.JSON),  # list of str; NULL: none (migration 0002)
    sa.Column("idempotency_key", sa.String(200)),
    sa.Column("n_train_views", sa.Integer, nullable=False),
    sa.Column("n_test_views", sa.Integer, nullable=False),
    sa.Column("last_seq", sa.Integer, nullable=False, default=0),
    sa.Column("pinned", sa.Boolean, nullable=False, default=False),  # kept past expiry (0003)
    sa.Column("expired_at", sa.Float),  # when its model's files were removed (0003)
    sa.Column("disk_wait_since", sa.Float),  # first waited for disk space to start (0003)
    sa.UniqueConstraint("owner", "idempotency_key", name="uq_jobs_owner_idempotency"),
)
"""One row per job; the truth about its state."""

events = sa.Table(
    "events",
    metadata,
    sa.Column("job_id", sa.String(40), primary_key=True),
    sa.Column("seq", sa.Integer, primary_key=True),
    sa.Column("type", sa.String(16), nullable=False),
    sa.Column("time", sa.Float, nullable=False),
    sa.Column("data", sa.JSON, nullable=False),
)
"""Durable per-job event log; ``seq`` runs 1, 2, 3… without gaps (from ``jobs.last_seq``)."""

api_keys = sa.Table(
    "api_keys",
    metadata,
    sa.Column("id", sa.String(24), primary_key=True),
    sa.Column("name", sa.String(200), nullable=False),
    sa.Column("digest", sa.String(64), nullable=False, unique=True),
    sa.Column("created_at", sa.Float, nullable=False),
    sa.Column("revoked_at", sa.Float),
)
"""API keys, stored as SHA-256 digests; the key itself is shown once, at creation."""

workers = sa.Table(
    "workers",
    metadata,
    sa.Column("id", sa.String(80), primary_key=True),
    sa.Column("kind", sa.String(16), nullable=False),
    sa.Column("host", sa.String(200), nullable=False),
    sa.Column("pid", sa.Integer, nullable=False),
    sa.Column("address", sa.String(200)),
    sa.Column("job_id", sa.String(40)),
    sa.Column("started_at", sa.Float, nullable=False),
    sa.Column("heartbeat_at", sa.Float, nullable=False),
)
"""Live workers (``train`` or ``render``); a render worker's ``address`` is where it listens."""
