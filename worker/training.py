"""A training worker process: claim a job, run it, store the outcome, repeat.

Started by ``sparsesplat serve`` (embedded) or ``sparsesplat worker`` (workers alone). SIGTERM
and SIGINT stop it gracefully: a running job checkpoints and goes back to the queue.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
from types import FrameType

import sqlalchemy as sa

from sparsesplat.api.disk import is_disk_full
from sparsesplat.api.logs import job_context
from sparsesplat.api.settings import Settings
from sparsesplat.api.storage import Storage
from sparsesplat.api.store.database import make_engine
from sparsesplat.api.store.jobs import Claim
from sparsesplat.api.store.workers import WorkerRegistry, new_worker_id
from sparsesplat.worker.disk_guard import DiskGate
from sparsesplat.worker.heartbeat import JobHeartbeat
from sparsesplat.worker.job_runner import run_job
from sparsesplat.worker.kernels import prepare_kernels
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


class TrainingWorker:
    """Claims and runs jobs one at a time until stopped."""

    def __init__(self, settings: Settings) -> None:
        """A worker over the database and storage ``settings`` name."""
        assert settings.database_url is not None
        self.settings = settings
        self.engine = make_engine(settings.database_url)
        # A running job's writes wait out a database outage (up to its lease) instead of
        # failing the attempt: the same store the Celery worker uses.
        self.store = PatientJobStore(self.engine, settings.max_attempts, settings.lease_s)
        self.storage = Storage.for_settings(settings)
        self.registry = WorkerRegistry(self.engine)
        self.gate = DiskGate(self.store, self.storage, settings)
        self.worker_id = new_worker_id("train")
        self.current: JobHeartbeat | None = None
        self._stop = threading.Event()

    def stop(self, *_: object) -> None:
        """Finish gracefully: the running job checkpoints and returns to the queue."""
        self._stop.set()
        if self.current is not None:
            self.current.request_shutdown()

    def run(self, max_jobs: int | None = None) -> int:
        """Serve jobs until stopped (or ``max_jobs`` were run); returns how many ran."""
        self._prepare_process()
        # No claim before the kernels are built: a job claimed now would wait on the compiler.
        prepare_kernels(self.settings)
        self.registry.register(self.worker_id, "train")
        log.info("training worker ready", extra={"worker": self.worker_id})
        done = 0
        parent = os.getppid()
        try:
            while not self._stop.is_set() and (max_jobs is None or done < max_jobs):
                if os.getppid() != parent:  # the supervisor died: do not linger as an orphan
                    log.warning("parent process gone; stopping")
                    break
                try:
                    self.registry.beat(self.worker_id)
                    claim = self._claim_next()
                except sa.exc.OperationalError as exc:
                    # The database is restarting (or its disk is full): wait and poll again
                    # rather than exit (the supervisor would restart the process, paying
                    # torch's import again).
                    if is_disk_full(exc):
                        log.error("cannot claim: the disk holding the job database is full")
                    else:
                        log.warning("database unreachable; waiting to claim", exc_info=True)
                    self._stop.wait(self.settings.poll_s)
                    continue
                if claim is None:
                    self._stop.wait(self.settings.poll_s)
                    continue
                done += 1
                with contextlib.suppress(sa.exc.OperationalError):
                    self.registry.beat(self.worker_id, claim.job_id)
                with job_context(claim.job_id):
                    log.info("job claimed", extra={"attempt": claim.attempt})
                    self.current = JobHeartbeat(
                        self.store, claim.job_id, self.worker_id, self.settings
                    )
                    outcome = run_job(claim, self.store, self.storage, self.settings, self.current)
                    self.current = None
                    store_outcome(
                        self.store, self.storage, self.worker_id, claim.job_id, outcome,
                        self.settings, self._stop,
                    )  # fmt: skip
        finally:
            try:
                self.registry.unregister(self.worker_id)
            except sa.exc.OperationalError:  # its registration expires by itself
                log.warning("could not unregister the worker", exc_info=True)
        return done

    def _claim_next(self) -> Claim | None:
        """The oldest queued job, if its expected bytes fit on the disk (:class:`DiskGate`);
        None when the queue is empty or its head waits for space."""
        self.store.requeue_expired()
        head = self.store.oldest_queued()
        if head is None:
            return None
        job_id, spec, waiting_since = head
        if not self.gate.may_start(job_id, spec, waiting_since):
            return None
        # Claim that very job (the one whose size was checked); another worker may take it
        # first, and then this one looks again after its poll.
        return self.store.claim_job(job_id, self.worker_id, self.settings.lease_s)

    def _prepare_process(self) -> None:
        import torch

        torch.set_num_threads(self.settings.torch_threads)
        if threading.current_thread() is threading.main_thread():
            lower_priority(self.settings)
            signal.signal(signal.SIGTERM, self._on_signal)
            signal.signal(signal.SIGINT, self._on_signal)

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        log.info("stopping on signal", extra={"signal": signum})
        self.stop()
