"""The job store a running job writes through, on either backend (embedded or Celery)."""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable
from typing import Concatenate, ParamSpec, TypeVar

import sqlalchemy as sa

from sparsesplat.api.store.jobs import JobStore

log = logging.getLogger("sparsesplat.worker")

T = TypeVar("T")
P = ParamSpec("P")
PATIENT_RETRY_S = 0.5
"""Seconds between retries of a job's write while the database is unreachable."""


def _retried(
    method: Callable[Concatenate[JobStore, P], T],
) -> Callable[Concatenate[PatientJobStore, P], T]:
    """``method`` of :class:`JobStore` as a :class:`PatientJobStore` method: retried while the
    database is away."""

    @functools.wraps(method)
    def patient(self: PatientJobStore, /, *args: P.args, **kwargs: P.kwargs) -> T:
        return self._patiently(lambda: method(self, *args, **kwargs))

    patient.__doc__ = f"``JobStore.{method.__name__}``, retried while the database is away."
    return patient


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

    add_event = _retried(JobStore.add_event)
    finish = _retried(JobStore.finish)
    release = _retried(JobStore.release)
