"""Storing how a job ended, on either backend, when the database may not take it at once."""

from __future__ import annotations

import logging
import threading
import time

import sqlalchemy as sa

from sparsesplat.api.artifacts import ArtifactStoreError
from sparsesplat.api.disk import is_disk_full
from sparsesplat.api.jobs import JobState
from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import Storage
from sparsesplat.api.store.jobs import JobStore
from sparsesplat.worker.job_runner import Outcome

log = logging.getLogger("sparsesplat.worker")


def store_outcome(
    store: JobStore,
    storage: Storage,
    worker_id: str,
    job_id: str,
    outcome: Outcome,
    settings: Settings,
    stop: threading.Event | None = None,
) -> bool:
    """Store ``outcome`` of ``job_id`` (a terminal state, or back to the queue). While the
    database cannot take it (its disk full, say) keep trying for up to ``disk_wait_s`` rather
    than end the worker: the job would otherwise stay ``running`` until its lease ran out. A
    job deleted while it ran leaves no files. False when the outcome could not be stored (the
    lease then re-queues the job)."""
    deadline = time.monotonic() + max(settings.disk_wait_s, settings.lease_s)
    pause = stop or threading.Event()
    while True:
        try:
            if outcome.state == JobState.queued:
                store.release(job_id, worker_id, outcome.message)
            else:
                store.finish(job_id, worker_id, outcome.state, outcome.message, outcome.result)
            if store.owner_of(job_id) is None:  # deleted while it ran: what it wrote goes too
                try:
                    storage.delete_job(job_id)
                except ArtifactStoreError as exc:  # the bucket keeps them; never end the worker
                    log.error("cannot remove a deleted job's files", extra={"error": str(exc)})
            log.info("job ended", extra={"state": outcome.state.value})
            return True
        except sa.exc.OperationalError as exc:
            cause = "disk full" if is_disk_full(exc) else "database unreachable"
            if time.monotonic() > deadline:
                log.error("could not store the job's outcome; its lease will run out",
                          extra={"state": outcome.state.value, "cause": cause})  # fmt: skip
                return False
            log.error("cannot store the job's outcome yet; retrying",
                      extra={"error": str(exc.orig or exc), "cause": cause})  # fmt: skip
            if pause.wait(max(settings.poll_s, 1.0)):  # the worker is stopping: the lease
                return False  # re-queues the job, which resumes from its checkpoint
