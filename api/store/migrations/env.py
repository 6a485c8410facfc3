"""Alembic environment: runs on the connection the caller put in ``config.attributes``."""

from __future__ import annotations

from alembic import context

from sparsesplat.api.store.tables import metadata

connection = context.config.attributes["connection"]
context.configure(connection=connection, target_metadata=metadata, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
