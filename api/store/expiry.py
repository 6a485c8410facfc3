"""The storage life of jobs in the store: what an owner keeps, pins, and which models expired.

A part of :class:`~sparsesplat.api.store.jobs.JobStore` (a base class of it): the reads the
per-key quotas and the stray-file sweep need, pinning, and the expiry of unpinned models
``model_ttl_s`` after their job finished. Files are the storage's business (``api/storage.py``).
"""

from __future__ import annotations

import time

import sqlalchemy as sa

from sparsesplat.api.jobs import JobState
from sparsesplat.api.store.records import append_event, expires_at, is_expired
from sparsesplat.api.store.tables import jobs


class StorageLife:
    """Owners' holdings, pins and model expiry over ``engine`` (see the module docstring)."""

    engine: sa.Engine
    model_ttl_s: float
    """Seconds an unpinned model is kept after its job finished (0: for good)."""

    def ids_of_owner(self, owner: str) -> list[str]:
        """Every job id ``owner`` has stored (any state)."""
        with self.engine.begin() as conn:
            return list(conn.execute(sa.select(jobs.c.id).where(jobs.c.owner == owner)).scalars())

    def all_ids(self) -> set[str]:
        """Every stored job id (to find files whose record is gone)."""
        with self.engine.begin() as conn:
            return set(conn.execute(sa.select(jobs.c.id)).scalars())

    def counts_of_owner(self, owner: str) -> dict[str, int]:
        """``owner``'s jobs: ``jobs`` (all), ``active`` (queued or running), ``models``
        (succeeded, not expired) and ``pinned`` (of those, pinned)."""
        now = time.time()
        with self.engine.begin() as conn:
            rows = conn.execute(
                sa.select(jobs.c.state, jobs.c.pinned, jobs.c.expired_at, jobs.c.finished_at)
                .where(jobs.c.owner == owner)
            ).all()  # fmt: skip
        ttl = self.model_ttl_s
        models = [
            r
            for r in rows
            if r.state == JobState.succeeded.value
            and not is_expired(ttl, r.pinned, r.expired_at, r.finished_at, now)
        ]
        return {
            "jobs": len(rows),
            "active": sum(r.state in (JobState.queued.value, JobState.running.value) for r in rows),
            "models": len(models),
            "pinned": sum(bool(r.pinned) for r in models),
        }

    def set_pinned(self, job_id: str, pinned: bool) -> bool:
        """Pin (keep past expiry) or unpin a job's model; False when the job does not exist."""
        with self.engine.begin() as conn:
            updated = conn.execute(jobs.update().where(jobs.c.id == job_id).values(pinned=pinned))
        return updated.rowcount == 1

    def expired_unswept(self) -> list[str]:
        """Succeeded, unpinned jobs past the model expiry whose files were not removed yet."""
        if self.model_ttl_s <= 0:
            return []
        with self.engine.begin() as conn:
            return list(
                conn.execute(sa.select(jobs.c.id).where(*self._past_expiry(time.time()))).scalars()
            )

    def mark_expired(self, job_id: str) -> bool:
        """Record that ``job_id``'s model expired (its files go next); False when it is not
        (or no longer) an unpinned, unexpired model past the expiry (a pin won the race)."""
        if self.model_ttl_s <= 0:
            return False
        now = time.time()
        with self.engine.begin() as conn:
            updated = conn.execute(
                jobs.update()
                .where(jobs.c.id == job_id, *self._past_expiry(now))
                .values(expired_at=now)
            )
            if updated.rowcount != 1:
                return False
            append_event(conn, job_id, "warning", {"message": "the model expired"})
        return True

    def expires_at(self, pinned: bool, finished_at: float | None) -> float | None:
        """When a succeeded job's model expires (None: pinned, or no expiry is set)."""
        return expires_at(self.model_ttl_s, pinned, finished_at)

    def _past_expiry(self, now: float) -> tuple[sa.ColumnElement[bool], ...]:
        """The conditions of a model due to expire at ``now``: succeeded, unpinned, not yet
        marked expired, finished more than ``model_ttl_s`` ago (one definition for the list
        and the conditional mark, so a pin between the two wins)."""
        return (
            jobs.c.state == JobState.succeeded.value,
            jobs.c.pinned.is_(False),
            jobs.c.expired_at.is_(None),
            jobs.c.finished_at < now - self.model_ttl_s,
        )
