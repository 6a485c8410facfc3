"""What a training worker process holds and how it runs a job it claimed, on either backend.

The embedded worker (:mod:`sparsesplat.worker.training`, which polls the database for the
oldest queued job) and the Celery task (:mod:`sparsesplat.worker.celery_app`, which is handed
a job id by the broker) differ only in how a job reaches them. Both build one
:class:`JobWorker` and, once a job is claimed, call :meth:`JobWorker.run_claimed`: the job's
heartbeat, its training (:func:`~sparsesplat.worker.job_runner.run_job`) and the storing of
how it ended (:func:`~sparsesplat.worker.outcome.store_outcome`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from dataclasses import dataclass

import sqlalchemy as sa

from sparsesplat.api.logs import job_context
from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import Storage
from sparsesplat.api.store.database import make_engine
from sparsesplat.api.store.jobs import Claim
from sparsesplat.api.store.workers import WorkerRegistry, new_worker_id
from sparsesplat.worker.disk_guard import DiskGate
from sparsesplat.worker.heartbeat import JobHeartbeat
from sparsesplat.worker.job_runner import Outcome, run_job
from sparsesplat.worker.outcome import store_outcome
from sparsesplat.worker.patient_store import PatientJobStore

log = logging.getLogger("sparsesplat.worker")


def lower_priority(settings: Settings) -> None:
    """Raise this training process's niceness by ``settings.train_nice`` (once per process),
    so that renders sharing its cores run first."""
    global _niced
    if not _niced and settings.train_nice > 0:
        os.nice(settings.train_nice)
        _niced = True


_niced = False
"""Whether :func:`lower_priority` already ran in this process (niceness adds up)."""


@dataclass
class Ended:
    """How :meth:`JobWorker.run_claimed` left a job."""

    outcome: Outcome
    """How the job ended in this worker."""
    stored: bool
    """Whether the outcome was stored (else the job's lease re-queues it)."""
    shut_down: bool
    """Whether the job stopped because this worker was asked to stop."""


class JobWorker:
    """One training worker's connections, its id as a lease holder, and the job it runs."""

    def __init__(self, settings: Settings) -> None:
        """A worker over the database and storage ``settings`` name."""
        assert settings.database_url is not None
        self.settings = settings
        self.worker_id = new_worker_id("train")
        """Its id in the ``workers`` table and as the holder of a job's lease."""
        self.engine = make_engine(settings.database_url)
        # A running job's writes wait out a database outage (up to its lease) instead of
        # failing the attempt.
        self.store = PatientJobStore(self.engine, settings.max_attempts, settings.lease_s)
        self.storage = Storage.for_settings(settings)
        self.registry = WorkerRegistry(self.engine)
        self.gate = DiskGate(self.store, self.storage, settings)
        """Whether a queued job's expected bytes fit on the disk now."""
        self.stopping = threading.Event()
        """Set once the worker was asked to stop."""
        self.job_id: str | None = None
        """The job it runs now."""
        self.current: JobHeartbeat | None = None
        """That job's heartbeat."""

    def request_shutdown(self) -> None:
        """Stop gracefully: the running job (or the one about to start) checkpoints and goes
        back to the queue."""
        self.stopping.set()
        if self.current is not None:
            self.current.request_shutdown()

    def run_claimed(self, claim: Claim, pause: threading.Event | None) -> Ended:
        """Run the job of ``claim`` (held by this worker) to its end under a heartbeat, and
        store how it ended. While the database cannot take the outcome, storing retries until
        ``pause`` is set (None: up to the lease)."""
        job_id = claim.job_id
        self.job_id = job_id
        try:
            with contextlib.suppress(sa.exc.OperationalError):
                self.registry.beat(self.worker_id, job_id)
            with job_context(job_id):
                log.info("job claimed", extra={"attempt": claim.attempt})
                beat = JobHeartbeat(self.store, job_id, self.worker_id, self.settings)
                self.current = beat
                if self.stopping.is_set():  # asked to stop before the heartbeat existed
                    beat.request_shutdown()
                try:
                    outcome = run_job(claim, self.store, self.storage, self.settings, beat)
                finally:
                    self.current = None
                stored = store_outcome(
                    self.store, self.storage, self.worker_id, job_id, outcome, self.settings,
                    pause,
                )  # fmt: skip
                return Ended(outcome, stored, beat.shutting_down)
        finally:
            self.job_id = None
