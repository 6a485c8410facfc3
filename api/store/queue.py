"""The queue side of the job store: claims and leases, heartbeats, ending, re-queueing.

A part of :class:`~sparsesplat.api.store.jobs.JobStore` (a base class of it), used by the
workers. A job is claimed with a lease that the worker renews by heartbeat; every write a
worker makes to a running job is conditional on still holding it, so a lost lease is harmless.
A job whose lease expired (its worker died) goes back to the queue and resumes from its last
checkpoint, until it has been attempted ``max_attempts`` times. A queued job that waits for
disk space is noted here too (the workers' disk guard decides; the claim clears the note).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import sqlalchemy as sa

from sparsesplat.api.jobs import JobState, Progress
from sparsesplat.api.store.records import append_event
from sparsesplat.api.store.tables import jobs

MAX_ATTEMPTS = 3
"""Times a job may be started before a dead worker makes it fail for good."""


@dataclass(frozen=True)
class Claim:
    """A job a worker now holds."""

    job_id: str
    """The job."""
    spec: dict[str, Any]
    """Its spec (JobSpec as JSON)."""
    attempt: int
    """1 for the first start; more after a worker died."""


class JobQueue:
    """Claims, leases and the queue's order over ``engine`` (see the module docstring)."""

    engine: sa.Engine
    max_attempts: int
    """Starts allowed before a job whose worker keeps dying fails."""

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
            append_event(conn, job_id, "warning", {"message": message})
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
            append_event(conn, job_id, "state", {"state": "failed", "message": message})
        return True

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
            return self._started(conn, row.id, dict(row.spec), int(row.attempts) + 1)

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
            return self._started(conn, job_id, dict(row.spec), int(row.attempts))

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
            append_event(conn, job_id, "state", {"state": state.value, "message": message})
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
                append_event(conn, job_id, "state", {"state": "queued", "message": message})

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
                    append_event(conn, row.id, "state", {"state": state.value, "message": msg})
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
    def _started(conn: sa.Connection, job_id: str, spec: dict[str, Any], attempt: int) -> Claim:
        """The claim of ``job_id`` (its ``attempt``-th start), with its ``running`` event."""
        message = "started" if attempt == 1 else f"resumed (attempt {attempt})"
        append_event(conn, job_id, "state", {"state": "running", "message": message})
        return Claim(job_id, spec, attempt)

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
