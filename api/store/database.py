"""Opening the job database and bringing its schema to the newest migration."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import sqlalchemy as sa

from sparsesplat.api import faults

MIGRATIONS = Path(__file__).with_name("migrations")
_MIGRATION_LOCK = 7_274_310
"""PostgreSQL advisory-lock key held while migrating (several processes may start at once)."""


def _normalise_url(url: str) -> str:
    # Users write postgresql://…; SQLAlchemy's default driver for that is psycopg2, which we do
    # not install. psycopg (3) is the maintained one.
    if url.startswith("postgresql://") or url.startswith("postgres://"):
        return "postgresql+psycopg://" + url.split("://", 1)[1]
    return url


def make_engine(url: str) -> sa.Engine:
    """An engine for ``url`` (``sqlite:///path`` or ``postgresql://…``).

    SQLite gets WAL (readers never block the writer), a 30 s busy timeout, and ``BEGIN
    IMMEDIATE`` for every transaction, so a read-then-write (a claim) never fails half-way with
    "database is locked" when two processes race.
    """
    url = _normalise_url(url)
    if url.startswith("sqlite"):
        path = sa.engine.make_url(url).database
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        engine = sa.create_engine(url, connect_args={"timeout": 30})

        @sa.event.listens_for(engine, "connect")
        def _on_connect(dbapi_connection: Any, _record: Any) -> None:
            dbapi_connection.isolation_level = None  # we issue BEGIN ourselves
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.execute("PRAGMA busy_timeout=30000")
            cursor.close()

        @sa.event.listens_for(engine, "begin")
        def _on_begin(connection: sa.Connection) -> None:
            connection.exec_driver_sql("BEGIN IMMEDIATE")

        faults.watch_engine(engine)  # tests only: a full database on demand
        return engine
    return sa.create_engine(url, pool_pre_ping=True, pool_size=5, max_overflow=10)


def migrate(engine: sa.Engine) -> None:
    """Upgrade the schema to the newest revision (safe when several processes call it)."""
    from alembic import command
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    with engine.begin() as connection:
        if connection.dialect.name == "postgresql":
            connection.execute(sa.text(f"SELECT pg_advisory_xact_lock({_MIGRATION_LOCK})"))
        config.attributes["connection"] = connection
        command.upgrade(config, "head")


def describe(url: str) -> str:
    """``url`` with any password hidden, for messages and logs."""
    try:
        return sa.engine.make_url(_normalise_url(url)).render_as_string(hide_password=True)
    except Exception:
        return "<unparseable database URL>"
