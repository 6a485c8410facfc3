"""The job repository: every read and write of job records and their events.

Used by the API (create, read, cancel, delete) and by the workers (claim, heartbeat, progress,
finish). Each method is one short transaction. The store is one class made of three parts, one
concept each: the records and events the API reads and writes (here), the queue the workers
claim from under a lease (``queue.py``: claims, heartbeats, re-queueing a dead worker's job,
waiting for disk space) and the storage life of finished jobs (``expiry.py``: pins, model
expiry, owners' holdings). How a row reads as a ``Job`` and how an event is numbered is in
``records.py``.
"""

from __future__ import annotations

import time
import uuid
from typing import Any

import sqlalchemy as sa

from sparsesplat.api.jobs import Event, Job, JobSpec, JobState
from sparsesplat.api.store.expiry import StorageLife
from sparsesplat.api.store.queue import MAX_ATTEMPTS, Claim, JobQueue
from sparsesplat.api.store.records import (
    append_event,
    decode_cursor,
    encode_cursor,
    select_jobs,
    to_job,
    utc,
)
from sparsesplat.api.store.tables import events, jobs

__all__ = ["MAX_ATTEMPTS", "Claim", "JobStore", "new_job_id"]


def new_job_id() -> str:
    """A fresh, URL-safe job id."""
    return "job_" + uuid.uuid4().hex[:20]


class JobStore(JobQueue, StorageLife):
    """Job records over one SQLAlchemy engine (SQLite or PostgreSQL)."""

    def __init__(
        self, engine: sa.Engine, max_attempts: int = MAX_ATTEMPTS, model_ttl_s: float = 0.0
    ) -> None:
        """``max_attempts``: starts allowed before a job whose worker keeps dying fails;
        ``model_ttl_s``: seconds an unpinned model is kept after its job finished (0: for
        good)."""
        self.engine = engine
        self.max_attempts = max_attempts
        self.model_ttl_s = model_ttl_s

    # -- API side ----------------------------------------------------------------------------
    def create(
        self,
        job_id: str,
        owner: str,
        spec: JobSpec,
        n_train_views: int,
        n_test_views: int,
        idempotency_key: str | None = None,
    ) -> tuple[Job, bool]:
        """Insert a queued job; returns (job as created, True). With an ``idempotency_key``
        already used by ``owner``, returns (that first job as it is now, False) instead."""
        now = time.time()
        with self.engine.begin() as conn:
            if idempotency_key is not None:
                existing = conn.execute(
                    select_jobs(owner).where(jobs.c.idempotency_key == idempotency_key)
                ).first()
                if existing is not None:
                    return self._to_job(conn, existing), False
            conn.execute(
                jobs.insert().values(
                    id=job_id,
                    owner=owner,
                    state=JobState.queued.value,
                    spec=spec.model_dump(mode="json"),
                    created_at=now,
                    attempts=0,
                    cancel_requested=False,
                    idempotency_key=idempotency_key,
                    n_train_views=n_train_views,
                    n_test_views=n_test_views,
                    last_seq=0,
                )
            )
            append_event(conn, job_id, "state", {"state": "queued", "message": "submitted"})
            # Read inside the transaction: embedded workers poll the table and may claim the
            # job the moment it commits, and the submitter is answered with the job as created.
            created = self._read(conn, job_id, owner)
            assert created is not None
            return created, True

    def get(self, job_id: str, owner: str | None = None) -> Job | None:
        """The job, or None when it does not exist (or belongs to another owner)."""
        with self.engine.begin() as conn:
            return self._read(conn, job_id, owner)

    def find_by_idempotency_key(self, owner: str, key: str) -> Job | None:
        """The job ``owner`` submitted with idempotency ``key``, if any."""
        with self.engine.begin() as conn:
            row = conn.execute(select_jobs(owner).where(jobs.c.idempotency_key == key)).first()
            return None if row is None else self._to_job(conn, row)

    def owner_of(self, job_id: str) -> str | None:
        """Owner of a job (None if it does not exist)."""
        with self.engine.begin() as conn:
            return conn.execute(
                sa.select(jobs.c.owner).where(jobs.c.id == job_id)
            ).scalar_one_or_none()

    def result(self, job_id: str) -> dict[str, Any] | None:
        """What the worker stored when the job succeeded (metrics, sizes), else None."""
        with self.engine.begin() as conn:
            value = conn.execute(
                sa.select(jobs.c.result).where(jobs.c.id == job_id)
            ).scalar_one_or_none()
        return dict(value) if value else None

    def page(
        self, owner: str, state: JobState | None = None, cursor: str | None = None, limit: int = 20
    ) -> tuple[list[Job], str | None]:
        """The owner's jobs, newest first, one page; returns (jobs, next cursor or None)."""
        query = select_jobs(owner)
        if state is not None:
            query = query.where(jobs.c.state == state.value)
        if cursor:
            created, job_id = decode_cursor(cursor)
            query = query.where(
                sa.or_(
                    jobs.c.created_at < created,
                    sa.and_(jobs.c.created_at == created, jobs.c.id < job_id),
                )
            )
        query = query.order_by(jobs.c.created_at.desc(), jobs.c.id.desc()).limit(limit + 1)
        with self.engine.begin() as conn:
            rows = conn.execute(query).all()
            page = [self._to_job(conn, r) for r in rows[:limit]]
        more = len(rows) > limit
        next_cursor = (
            encode_cursor(rows[limit - 1].created_at, rows[limit - 1].id) if more else None
        )
        return page, next_cursor

    def count_active(self, owner: str) -> int:
        """Queued or running jobs of ``owner`` (for the per-key queue limit)."""
        with self.engine.begin() as conn:
            return int(
                conn.execute(
                    sa.select(sa.func.count())
                    .select_from(jobs)
                    .where(
                        jobs.c.owner == owner,
                        jobs.c.state.in_([JobState.queued.value, JobState.running.value]),
                    )
                ).scalar_one()
            )

    def counts_by_state(self) -> dict[str, int]:
        """Number of jobs in each state (every state present, zeros included)."""
        counts = {s.value: 0 for s in JobState}
        with self.engine.begin() as conn:
            for state, n in conn.execute(
                sa.select(jobs.c.state, sa.func.count()).group_by(jobs.c.state)
            ):
                counts[state] = int(n)
        return counts

    def request_cancel(self, job_id: str) -> Job | None:
        """Cancel: a queued job at once; a running one is flagged and its worker stops at the
        next progress report. Returns the job as the request left it, read in the same
        transaction (a worker may stop it the moment the flag commits); None if it does not
        exist."""
        with self.engine.begin() as conn:
            state = conn.execute(
                sa.select(jobs.c.state).where(jobs.c.id == job_id)
            ).scalar_one_or_none()
            if state is None:
                return None
            if state == JobState.queued.value:
                conn.execute(
                    jobs.update()
                    .where(jobs.c.id == job_id)
                    .values(state=JobState.cancelled.value, finished_at=time.time())
                )
                append_event(conn, job_id, "state", {"state": "cancelled", "message": "cancelled"})
            elif state == JobState.running.value:
                conn.execute(jobs.update().where(jobs.c.id == job_id).values(cancel_requested=True))
            return self._read(conn, job_id)

    def delete(self, job_id: str) -> None:
        """Remove the job and its events (files are the storage's business)."""
        with self.engine.begin() as conn:
            conn.execute(events.delete().where(events.c.job_id == job_id))
            conn.execute(jobs.delete().where(jobs.c.id == job_id))

    def events_after(self, job_id: str, after: int = 0, limit: int = 500) -> list[Event]:
        """Stored events with ``seq > after``, oldest first."""
        with self.engine.begin() as conn:
            rows = conn.execute(
                sa.select(events)
                .where(events.c.job_id == job_id, events.c.seq > after)
                .order_by(events.c.seq)
                .limit(limit)
            ).all()
        return [
            Event(seq=r.seq, job_id=r.job_id, type=r.type, time=utc(r.time), data=r.data)
            for r in rows
        ]

    def last_seq(self, job_id: str) -> int:
        """Sequence number of the job's newest event (0 if none or no such job)."""
        with self.engine.begin() as conn:
            value = conn.execute(
                sa.select(jobs.c.last_seq).where(jobs.c.id == job_id)
            ).scalar_one_or_none()
        return int(value or 0)

    def add_event(self, job_id: str, type_: str, data: dict[str, Any]) -> int:
        """Append one event; returns its sequence number (0: the job no longer exists)."""
        with self.engine.begin() as conn:
            return append_event(conn, job_id, type_, data)

    def add_warning(self, job_id: str, message: str) -> int:
        """Append ``message`` to the job's warnings and store it as a ``warning`` event (one
        transaction); returns the event's sequence number. A message already there is not
        added twice (a resumed run may find the same problem again)."""
        with self.engine.begin() as conn:
            current = conn.execute(
                sa.select(jobs.c.warnings).where(jobs.c.id == job_id)
            ).scalar_one_or_none()
            warnings = list(current or [])
            if message in warnings:
                return 0
            conn.execute(
                jobs.update().where(jobs.c.id == job_id).values(warnings=[*warnings, message])
            )
            return append_event(conn, job_id, "warning", {"message": message})

    # -- helpers -----------------------------------------------------------------------------
    def _read(self, conn: sa.Connection, job_id: str, owner: str | None = None) -> Job | None:
        """The job as ``conn``'s transaction sees it (None if absent or another owner's)."""
        row = conn.execute(select_jobs(owner).where(jobs.c.id == job_id)).first()
        return None if row is None else self._to_job(conn, row)

    def _to_job(self, conn: sa.Connection, row: sa.Row[Any]) -> Job:
        return to_job(conn, row, self.model_ttl_s)
