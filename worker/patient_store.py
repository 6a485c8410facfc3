"""The job store a running job writes through, on either backend (embedded or Celery)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, TypeVar

import sqlalchemy as sa

from sparsesplat.api.jobs import JobState
from sparsesplat.api.store.jobs import JobStore

log = logging.getLogger("sparsesplat.worker")

T = TypeVar("T")
PATIENT_RETRY_S = 0.5
"""Seconds between retries of a job's write while the database is unreachable."""


class PatientJobStore(JobStore):
    """A job store whose writes for a running job wait out a database outage.

    A write that fails because the database cannot be reached is retried for up to
    ``patience_s`` (the lease), so a restart or fail-over of PostgreSQL (or a SQLite file
    locked past its busy timeout) pauses the job rather than failing its attempt. Past the
    lease the job has been re-queued anyway, and the write fails as before.
    """

    def __init__(self, engine: sa.Engine, max_attempts: int, patience_s: float) -> None:
        """Retry writes for up to ``patience_s`` seconds."""
        super().__init__(engine, max_attempts)
        self.patience_s = patience_s

    def _patiently(self, write: Callable[[], T]) -> T:
        deadline = time.monotonic() + self.patience_s
        while True:
            try:
                return write()
            except sa.exc.OperationalError:
                if time.monotonic() > deadline:
                    raise
                log.warning("database unreachable; retrying the write")
                time.sleep(PATIENT_RETRY_S)

    def add_event(self, job_id: str, type_: str, data: dict[str, Any]) -> int:
        """``JobStore.add_event``, retried while the database is away."""
        return self._patiently(lambda: JobStore.add_event(self, job_id, type_, data))

    def finish(
        self,
        job_id: str,
        worker_id: str,
        state: JobState,
        message: str = "",
        result: dict[str, Any] | None = None,
    ) -> bool:
        """``JobStore.finish``, retried while the database is away."""
        return self._patiently(
            lambda: JobStore.finish(self, job_id, worker_id, state, message, result)
        )

    def release(self, job_id: str, worker_id: str, message: str) -> None:
        """``JobStore.release``, retried while the database is away."""
        self._patiently(lambda: JobStore.release(self, job_id, worker_id, message))
