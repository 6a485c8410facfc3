"""The job repository: every read and write of job records and their events.

Used by the API (create, read, cancel, delete) and by the workers (claim, heartbeat, progress,
finish). Each method is one short transaction. A job is claimed with a lease that the worker
renews by heartbeat; a job whose lease expired (its worker died) goes back to the queue and
resumes from its last checkpoint, until it has been attempted ``max_attempts`` times.
"""

from __future__ import annotations

import base64
import json
import time
import uuid
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import sqlalchemy as sa

from sparsesplat.api.jobs import Event, Job, JobSpec, JobState, Progress
from sparsesplat.api.store.tables import events, jobs

MAX_ATTEMPTS = 3
"""Times a job may be started before a dead worker makes it fail for good."""


def new_job_id() -> str:
    """A fresh, URL-safe job id."""
    return "job_" + uuid.uuid4().hex[:20]


def _dt(value: float | None) -> datetime | None:
    return None if value is None else _utc(value)


def _utc(value: float) -> datetime:
    return datetime.fromtimestamp(value, UTC)


@dataclass(frozen=True)
class Claim:
    """A job a worker now holds."""

    job_id: str
    """The job."""
    spec: dict[str, Any]
    """Its spec (JobSpec as JSON)."""
    attempt: int
    """1 for the first start; more after a worker died."""


class JobStore:
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
                    self._select(owner).where(jobs.c.idempotency_key == idempotency_key)
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
            self._append(conn, job_id, "state", {"state": "queued", "message": "submitted"})
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
            row = conn.execute(self._select(owner).where(jobs.c.idempotency_key == key)).first()
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
        query = self._select(owner)
        if state is not None:
            query = query.where(jobs.c.state == state.value)
        if cursor:
            created, job_id = _decode_cursor(cursor)
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
            _encode_cursor(rows[limit - 1].created_at, rows[limit - 1].id) if more else None
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
                self._append(conn, job_id, "state", {"state": "cancelled", "message": "cancelled"})
            elif state == JobState.running.value:
                conn.execute(jobs.update().where(jobs.c.id == job_id).values(cancel_requested=True))
            return self._read(conn, job_id)

    def delete(self, job_id: str) -> None:
        """Remove the job and its events (files are the storage's business)."""
        with self.engine.begin() as conn:
            conn.execute(events.delete().where(events.c.job_id == job_id))
            conn.execute(jobs.delete().where(jobs.c.id == job_id))

    # -- storage life --------------------------------------------------------------------------
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
        models = [r for r in rows if r.state == JobState.succeeded.value
                  and not self._expired(r.pinned, r.expired_at, r.finished_at, now)]  # fmt: skip
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
                conn.execute(
                    sa.select(jobs.c.id).where(
                        jobs.c.state == JobState.succeeded.value,
                        jobs.c.pinned.is_(False),
                        jobs.c.expired_at.is_(None),
                        jobs.c.finished_at < time.time() - self.model_ttl_s,
                    )
                ).scalars()
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
                .where(
                    jobs.c.id == job_id,
                    jobs.c.state == JobState.succeeded.value,
                    jobs.c.pinned.is_(False),
                    jobs.c.expired_at.is_(None),
                    jobs.c.finished_at < now - self.model_ttl_s,
                )
                .values(expired_at=now)
            )
            if updated.rowcount != 1:
                return False
            self._append(conn, job_id, "warning", {"message": "the model expired"})
        return True

    # -- waiting for disk space -------------------------------------------------------------
    def oldest_queued(self) -> tuple[str, dict[str, Any], float | None] | None:
        """The job the next claim would take: (id, spec, since when it waits for disk space or
        None), or None when the queue is empty."""
        with self.engine.begin() as conn:
            row = conn.execute(
                sa.select(jobs.c.id, jobs.c.spec, jobs.c.disk_wait_since)
                .where(jobs.c.state == JobState.queued.value)
                .order_by(jobs.c.created_at, jobs.c.id)
                .limit(1)
            ).first()
        return None if row is None else (row.id, dict(row.spec), row.disk_wait_since)

    def running_specs(self) -> list[tuple[str, dict[str, Any]]]:
        """(id, spec) of every running job (their disk use still grows)."""
        with self.engine.begin() as conn:
            rows = conn.execute(
                sa.select(jobs.c.id, jobs.c.spec).where(jobs.c.state == JobState.running.value)
            ).all()
        return [(r.id, dict(r.spec)) for r in rows]

    def spec_of_queued(self, job_id: str) -> tuple[dict[str, Any], float | None] | None:
        """(spec, waiting-for-disk-since) of ``job_id`` if it is queued, else None."""
        with self.engine.begin() as conn:
            row = conn.execute(
                sa.select(jobs.c.spec, jobs.c.disk_wait_since).where(
                    jobs.c.id == job_id, jobs.c.state == JobState.queued.value
                )
            ).first()
        return None if row is None else (dict(row.spec), row.disk_wait_since)

    def note_disk_wait(self, job_id: str, message: str) -> float | None:
        """Record that the queued ``job_id`` waits for disk space (a ``warning`` event with
        ``message`` the first time); returns since when it waits (None: it is not queued)."""
        now = time.time()
        with self.engine.begin() as conn:
            row = conn.execute(
                sa.select(jobs.c.disk_wait_since, jobs.c.warnings).where(
                    jobs.c.id == job_id, jobs.c.state == JobState.queued.value
                )
            ).first()
            if row is None:
                return None
            if row.disk_wait_since is not None:
                return float(row.disk_wait_since)
            conn.execute(
                jobs.update()
                .where(jobs.c.id == job_id)
                .values(disk_wait_since=now, warnings=[*(row.warnings or []), message])
            )
            self._append(conn, job_id, "warning", {"message": message})
        return now

    def fail_queued(self, job_id: str, message: str) -> bool:
        """Fail a job that never started (it waited too long for disk space); False when it
        is no longer queued."""
        with self.engine.begin() as conn:
            updated = conn.execute(
                jobs.update()
                .where(jobs.c.id == job_id, jobs.c.state == JobState.queued.value)
                .values(state=JobState.failed.value, finished_at=time.time(), error=message)
            )
            if updated.rowcount != 1:
                return False
            self._append(conn, job_id, "state", {"state": "failed", "message": message})
        return True

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
            Event(seq=r.seq, job_id=r.job_id, type=r.type, time=_utc(r.time), data=r.data)
            for r in rows
        ]

    def last_seq(self, job_id: str) -> int:
        """Sequence number of the job's newest event (0 if none or no such job)."""
        with self.engine.begin() as conn:
            value = conn.execute(
                sa.select(jobs.c.last_seq).where(jobs.c.id == job_id)
            ).scalar_one_or_none()
        return int(value or 0)

    # -- worker side -------------------------------------------------------------------------
    def claim(self, worker_id: str, lease_s: float) -> Claim | None:
        """Take the oldest queued job (expired leases are re-queued first), or None."""
        self.requeue_expired()
        now = time.time()
        with self.engine.begin() as conn:
            query = (
                sa.select(jobs.c.id, jobs.c.spec, jobs.c.attempts)
                .where(jobs.c.state == JobState.queued.value)
                .order_by(jobs.c.created_at, jobs.c.id)
                .limit(1)
            )
            if conn.dialect.name == "postgresql":
                query = query.with_for_update(skip_locked=True)
            row = conn.execute(query).first()
            if row is None:
                return None
            updated = conn.execute(
                jobs.update()
                .where(jobs.c.id == row.id, jobs.c.state == JobState.queued.value)
                .values(**self._claim_values(worker_id, now + lease_s, now))
            )
            if updated.rowcount != 1:
                return None
            attempt = int(row.attempts) + 1
            message = "started" if attempt == 1 else f"resumed (attempt {attempt})"
            self._append(conn, row.id, "state", {"state": "running", "message": message})
        return Claim(row.id, dict(row.spec), attempt)

    def claim_job(self, job_id: str, worker_id: str, lease_s: float) -> Claim | None:
        """Take ``job_id`` itself (a broker delivered its id) if it is queued, else None.

        None means the job runs under another worker, has ended, was cancelled or deleted: a
        duplicate or late message is dropped here, so delivering one twice never runs a job
        twice. One conditional UPDATE: of two workers racing for the job, exactly one wins
        (on PostgreSQL the loser waits for the winner's commit, then matches no row)."""
        now = time.time()
        with self.engine.begin() as conn:
            row = conn.execute(
                jobs.update()
                .where(jobs.c.id == job_id, jobs.c.state == JobState.queued.value)
                .values(**self._claim_values(worker_id, now + lease_s, now))
                .returning(jobs.c.spec, jobs.c.attempts)
            ).first()
            if row is None:
                return None
            attempt = int(row.attempts)
            message = "started" if attempt == 1 else f"resumed (attempt {attempt})"
            self._append(conn, job_id, "state", {"state": "running", "message": message})
        return Claim(job_id, dict(row.spec), attempt)

    def heartbeat(
        self, job_id: str, worker_id: str, lease_s: float, progress: Progress | None = None
    ) -> tuple[bool, bool]:
        """Renew the lease (and store ``progress``); returns (still ours, cancel requested).
        Not ours any more means the lease expired and the job went to another worker: stop."""
        values: dict[str, Any] = {"lease_until": time.time() + lease_s}
        if progress is not None:
            values["progress"] = progress.model_dump(mode="json")
        with self.engine.begin() as conn:
            held = self._update_held(conn, job_id, worker_id, values)
            cancel = conn.execute(
                sa.select(jobs.c.cancel_requested).where(jobs.c.id == job_id)
            ).scalar_one_or_none()
        return held, bool(cancel)

    def add_event(self, job_id: str, type_: str, data: dict[str, Any]) -> int:
        """Append one event; returns its sequence number (0: the job no longer exists)."""
        with self.engine.begin() as conn:
            return self._append(conn, job_id, type_, data)

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
            return self._append(conn, job_id, "warning", {"message": message})

    def finish(
        self,
        job_id: str,
        worker_id: str,
        state: JobState,
        message: str = "",
        result: dict[str, Any] | None = None,
    ) -> bool:
        """Move a job this worker holds to a terminal state; False if it no longer held it."""
        values: dict[str, Any] = {
            "state": state.value,
            "finished_at": time.time(),
            "lease_until": None,
            "error": message if state == JobState.failed else None,
        }
        if result is not None:
            values["result"] = result
        with self.engine.begin() as conn:
            if not self._update_held(conn, job_id, worker_id, values):
                return False
            self._append(conn, job_id, "state", {"state": state.value, "message": message})
        return True

    def release(self, job_id: str, worker_id: str, message: str) -> None:
        """Hand a running job back to the queue (a worker shutting down gracefully)."""
        with self.engine.begin() as conn:
            updated = conn.execute(
                jobs.update()
                .where(jobs.c.id == job_id, jobs.c.worker_id == worker_id)
                .where(jobs.c.state == JobState.running.value)
                .values(state=JobState.queued.value, worker_id=None, lease_until=None)
            )
            if updated.rowcount == 1:
                self._append(conn, job_id, "state", {"state": "queued", "message": message})

    def requeue_expired(self) -> list[str]:
        """Running jobs whose lease ran out (worker died): back to the queue, or failed after
        ``max_attempts`` starts. Returns the affected ids."""
        return self._requeue(jobs.c.lease_until < time.time())

    def requeue_of_workers(self, worker_ids: list[str]) -> list[str]:
        """The running jobs of workers known to be dead (their supervisor saw them exit), at
        once rather than when their lease runs out: a re-queued job keeps its place (the oldest
        is claimed first), where waiting out the lease let later jobs start ahead of it."""
        if not worker_ids:
            return []
        return self._requeue(jobs.c.worker_id.in_(worker_ids))

    def _requeue(self, which: sa.ColumnElement[bool]) -> list[str]:
        """Running jobs matching ``which``: back to the queue, cancelled when a cancel was
        asked for, or failed after ``max_attempts`` starts. Returns the affected ids."""
        now = time.time()
        touched = []
        with self.engine.begin() as conn:
            rows = conn.execute(
                sa.select(jobs.c.id, jobs.c.attempts, jobs.c.cancel_requested).where(
                    jobs.c.state == JobState.running.value, which
                )
            ).all()
            for row in rows:
                if row.cancel_requested:
                    state, msg = JobState.cancelled, "cancelled (its worker stopped)"
                elif row.attempts >= self.max_attempts:
                    state = JobState.failed
                    msg = (
                        f"the worker running this job stopped answering {row.attempts} times "
                        "(killed or out of memory?); try fewer iterations or smaller images"
                    )
                else:
                    state, msg = JobState.queued, "its worker stopped answering; re-queued"
                values: dict[str, Any] = {"state": state.value, "worker_id": None}
                values["lease_until"] = None
                if state != JobState.queued:
                    values["finished_at"] = now
                if state == JobState.failed:
                    values["error"] = msg
                updated = conn.execute(
                    jobs.update()
                    .where(jobs.c.id == row.id, jobs.c.state == JobState.running.value)
                    .where(which)
                    .values(**values)
                )
                if updated.rowcount == 1:
                    self._append(conn, row.id, "state", {"state": state.value, "message": msg})
                    touched.append(row.id)
        return touched

    def queued_ids(self) -> list[str]:
        """Ids of queued jobs, oldest first (for re-dispatching to a broker)."""
        with self.engine.begin() as conn:
            return list(
                conn.execute(
                    sa.select(jobs.c.id)
                    .where(jobs.c.state == JobState.queued.value)
                    .order_by(jobs.c.created_at)
                ).scalars()
            )

    # -- helpers -----------------------------------------------------------------------------
    @staticmethod
    def _select(owner: str | None) -> sa.Select[Any]:
        query = sa.select(jobs)
        return query if owner is None else query.where(jobs.c.owner == owner)

    @staticmethod
    def _claim_values(worker_id: str, lease_until: float, now: float) -> dict[str, Any]:
        """The columns a claim sets on a queued job: running, held by ``worker_id`` until
        ``lease_until``, one more attempt, started now unless it had started before."""
        return {
            "state": JobState.running.value,
            "worker_id": worker_id,
            "lease_until": lease_until,
            "attempts": jobs.c.attempts + 1,
            "started_at": sa.func.coalesce(jobs.c.started_at, now),
            "disk_wait_since": None,
        }

    @staticmethod
    def _update_held(
        conn: sa.Connection, job_id: str, worker_id: str, values: dict[str, Any]
    ) -> bool:
        """Set ``values`` on a running job only while ``worker_id`` holds it (the conditional
        UPDATE that makes a lost lease harmless); True if the row was updated."""
        updated = conn.execute(
            jobs.update()
            .where(
                jobs.c.id == job_id,
                jobs.c.worker_id == worker_id,
                jobs.c.state == JobState.running.value,
            )
            .values(**values)
        )
        return updated.rowcount == 1

    @staticmethod
    def _append(conn: sa.Connection, job_id: str, type_: str, data: dict[str, Any]) -> int:
        """Store one event; its sequence number, or 0 when the job is gone (deleted while its
        worker ran: the worker learns it from its heartbeat and stops; its last reports go
        nowhere rather than ending the worker process)."""
        seq = conn.execute(
            jobs.update()
            .where(jobs.c.id == job_id)
            .values(last_seq=jobs.c.last_seq + 1)
            .returning(jobs.c.last_seq)
        ).scalar_one_or_none()
        if seq is None:
            return 0
        conn.execute(
            events.insert().values(
                job_id=job_id, seq=seq, type=type_, time=time.time(), data=_json_safe(data)
            )
        )
        return int(seq)

    def _read(self, conn: sa.Connection, job_id: str, owner: str | None = None) -> Job | None:
        """The job as ``conn``'s transaction sees it (None if absent or another owner's)."""
        row = conn.execute(self._select(owner).where(jobs.c.id == job_id)).first()
        return None if row is None else self._to_job(conn, row)

    def expires_at(self, pinned: bool, finished_at: float | None) -> float | None:
        """When a succeeded job's model expires (None: pinned, or no expiry is set)."""
        if pinned or self.model_ttl_s <= 0 or finished_at is None:
            return None
        return finished_at + self.model_ttl_s

    def _expired(
        self, pinned: bool, expired_at: float | None, finished_at: float | None, now: float
    ) -> bool:
        """Whether a succeeded job's model has expired (swept already, or past its time)."""
        if expired_at is not None:
            return True
        until = self.expires_at(pinned, finished_at)
        return until is not None and until <= now

    def _to_job(self, conn: sa.Connection, row: sa.Row[Any]) -> Job:
        position = None
        if row.state == JobState.queued.value:
            position = int(
                conn.execute(
                    sa.select(sa.func.count())
                    .select_from(jobs)
                    .where(
                        jobs.c.state == JobState.queued.value,
                        sa.or_(
                            jobs.c.created_at < row.created_at,
                            sa.and_(jobs.c.created_at == row.created_at, jobs.c.id < row.id),
                        ),
                    )
                ).scalar_one()
            )
        succeeded = row.state == JobState.succeeded.value
        expired = succeeded and self._expired(
            row.pinned, row.expired_at, row.finished_at, time.time()
        )
        return Job(
            id=row.id,
            state=JobState(row.state),
            spec=JobSpec.model_validate(row.spec),
            created_at=_utc(row.created_at),
            started_at=_dt(row.started_at),
            finished_at=_dt(row.finished_at),
            queue_position=position,
            progress=Progress.model_validate(row.progress) if row.progress else None,
            error=row.error,
            attempts=row.attempts,
            n_train_views=row.n_train_views,
            n_test_views=row.n_test_views,
            has_model=succeeded and not expired,
            warnings=list(row.warnings or []),
            disk_bytes=(row.result or {}).get("disk_bytes"),
            pinned=bool(row.pinned),
            expires_at=_dt(self.expires_at(row.pinned, row.finished_at)) if succeeded else None,
            expired=succeeded and expired,
        )


def _json_safe(data: Any) -> Any:
    """Replace non-finite floats by None: JSON has no NaN/Infinity."""
    if isinstance(data, float):
        return data if data == data and abs(data) != float("inf") else None
    if isinstance(data, dict):
        return {str(k): _json_safe(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_json_safe(v) for v in data]
    return data


def _encode_cursor(created_at: float, job_id: str) -> str:
    raw = json.dumps([created_at, job_id]).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def _decode_cursor(cursor: str) -> tuple[float, str]:
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        created, job_id = json.loads(raw)
        return float(created), str(job_id)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"cursor {cursor!r} is not one this server issued") from exc
