"""API keys: created and revoked by an operator (``sparsesplat keys``), verified per request.

Only a SHA-256 digest of each key is stored; the key is shown once, when it is created. A key's
``id`` is its owner name for jobs, so revoking a key hides nothing that was stored.
"""

from __future__ import annotations

import hashlib
import secrets
import time
from dataclasses import dataclass

import sqlalchemy as sa

from sparsesplat.api.store.tables import api_keys

KEY_PREFIX = "ssk_"
"""Every key starts with this, so a leaked one is recognisable in logs and scanners."""


def digest(key: str) -> str:
    """SHA-256 hex digest of a key (what the table stores)."""
    return hashlib.sha256(key.encode()).hexdigest()


def owner_for(key: str) -> str:
    """Owner id of a key given in the settings rather than the table (stable across restarts)."""
    return "env_" + digest(key)[:16]


@dataclass(frozen=True)
class KeyInfo:
    """A stored key, without the key."""

    id: str
    """Key id (the owner of the jobs submitted with it)."""
    name: str
    """What the operator called it."""
    created_at: float
    """Creation time (epoch seconds)."""
    revoked: bool
    """Whether it no longer works."""


class KeyStore:
    """The ``api_keys`` table."""

    def __init__(self, engine: sa.Engine) -> None:
        """Keys in ``engine``'s database."""
        self.engine = engine

    def create(self, name: str) -> tuple[KeyInfo, str]:
        """A new key; returns (its record, the key itself — shown only now)."""
        key = KEY_PREFIX + secrets.token_urlsafe(32)
        info = KeyInfo("key_" + secrets.token_hex(8), name, time.time(), False)
        with self.engine.begin() as conn:
            conn.execute(
                api_keys.insert().values(
                    id=info.id, name=name, digest=digest(key), created_at=info.created_at
                )
            )
        return info, key

    def all(self) -> list[KeyInfo]:
        """Every key, oldest first."""
        with self.engine.begin() as conn:
            rows = conn.execute(sa.select(api_keys).order_by(api_keys.c.created_at)).all()
        return [KeyInfo(r.id, r.name, r.created_at, r.revoked_at is not None) for r in rows]

    def revoke(self, key_id: str) -> bool:
        """Revoke a key; False when no such (unrevoked) key exists."""
        with self.engine.begin() as conn:
            updated = conn.execute(
                api_keys.update()
                .where(api_keys.c.id == key_id, api_keys.c.revoked_at.is_(None))
                .values(revoked_at=time.time())
            )
        return updated.rowcount == 1

    def verify(self, key: str) -> str | None:
        """The id of the live key ``key``, or None."""
        with self.engine.begin() as conn:
            return conn.execute(
                sa.select(api_keys.c.id).where(
                    api_keys.c.digest == digest(key), api_keys.c.revoked_at.is_(None)
                )
            ).scalar_one_or_none()

    def any_configured(self) -> bool:
        """Whether any key was ever created. Revoked keys count: revoking the last key must
        not turn the service back into an anonymous one."""
        with self.engine.begin() as conn:
            return conn.execute(sa.select(api_keys.c.id).limit(1)).first() is not None
