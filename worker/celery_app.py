"""The Celery worker of the scale-out backend (``queue=celery``): one task, ``sparsesplat.train``,
whose message carries only a job id.

Run by ``sparsesplat worker`` / ``sparsesplat serve`` (``python -m sparsesplat.worker train``
starts one Celery node), or by hand: ``celery -A sparsesplat.worker.celery_app worker -Q
sparsesplat.train``. The configuration (``sparsesplat.api.store.broker``) gives each node one
job at a time, acknowledged late, handed back when its process dies, and a fresh pool process
per job.

Processes:

- the node's main process talks to the broker only: it never opens the database nor imports
  torch, so it forks clean children;
- each pool process, as soon as it starts (before any job arrives), imports torch and the
  engine, so a job does not wait for those imports, then connects to the database and
  registers itself as a training worker (``/readyz`` and ``/metrics`` count it; its pid is
  the one running the job);
- a task claims its job in the database (``JobStore.claim_job``): a message for a job that is
  running elsewhere, finished, cancelled or deleted is dropped. Then it runs the job exactly
  as the embedded worker does (``run_job`` under a ``JobHeartbeat``).

Stopping: SIGTERM to the node (warm shutdown) is passed on to the pool process running a job,
which stops at its next iteration, keeps a checkpoint, puts the job back in the queue and
sends it again; another worker resumes it. A killed process (``kill -9``, out of memory) is
recovered by its lease: the API's reconciler re-queues and re-sends the job, which resumes
from its last checkpoint.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time
from dataclasses import dataclass, field
from types import FrameType
from typing import Any

from celery.signals import worker_process_init, worker_process_shutdown, worker_shutting_down

from sparsesplat.api.jobs import JobState
from sparsesplat.api.logs import job_context
from sparsesplat.api.settings import Settings, load_settings
from sparsesplat.api.storage import Storage
from sparsesplat.api.store.broker import TRAIN_TASK, make_celery, send_job
from sparsesplat.api.store.database import make_engine
from sparsesplat.api.store.workers import WorkerRegistry, new_worker_id
from sparsesplat.worker.disk_guard import DiskGate
from sparsesplat.worker.heartbeat import JobHeartbeat
from sparsesplat.worker.job_runner import run_job
from sparsesplat.worker.outcome import store_outcome
from sparsesplat.worker.patient_store import PatientJobStore

log = logging.getLogger("sparsesplat.worker")

settings = load_settings()
app = make_celery(settings, "sparsesplat-worker")


@dataclass
class PoolProcess:
    """What one pool process holds: its connections, its registration, the job it runs."""

    settings: Settings
    """Configuration."""
    pid: int = field(default_factory=os.getpid)
    """The process these connections belong to (never used across a fork)."""
    worker_id: str = field(default_factory=lambda: new_worker_id("train"))
    """Its id in the ``workers`` table and as the holder of a job's lease."""
    job_id: str | None = None
    """The job it runs now."""
    current: JobHeartbeat | None = None
    """That job's heartbeat."""

    def __post_init__(self) -> None:
        assert self.settings.database_url is not None
        self.engine = make_engine(self.settings.database_url)
        self.store = PatientJobStore(self.engine, self.settings.max_attempts, self.settings.lease_s)
        self.storage = Storage.for_settings(self.settings)
        self.registry = WorkerRegistry(self.engine)
        self.gate = DiskGate(self.store, self.storage, self.settings)
        self._stop = threading.Event()
        self._beats = threading.Thread(target=self._beat, name="worker-heartbeat", daemon=True)

    def start(self) -> None:
        """Register as a live training worker and keep the registration fresh."""
        try:
            self.registry.register(self.worker_id, "train")
        except Exception:  # the database may be restarting: the heartbeat thread retries
            log.warning("could not register the worker yet", exc_info=True)
        self._beats.start()

    def _beat(self) -> None:
        while not self._stop.wait(self.settings.heartbeat_s):
            try:
                self.registry.beat(self.worker_id, self.job_id)
            except Exception:
                log.warning("worker heartbeat failed", exc_info=True)
                continue
            try:  # a registration lost while the database was away is made again
                if not any(w.id == self.worker_id for w in self.registry.live("train")):
                    self.registry.register(self.worker_id, "train")
            except Exception:
                pass

    def close(self) -> None:
        """Unregister and release connections."""
        self._stop.set()
        try:
            self.registry.unregister(self.worker_id)
        except Exception:
            log.warning("could not unregister the worker", exc_info=True)
        self.engine.dispose()


_process: PoolProcess | None = None


def pool_process() -> PoolProcess:
    """This process's connections (made on first use, and again after a fork)."""
    global _process
    if _process is None or _process.pid != os.getpid():
        _process = PoolProcess(settings)
        _process.start()
    return _process


def _warm_up() -> None:
    """Import torch and the engine now, while idle, so a job does not wait for them.

    The native extensions are not loaded here, though a job would start sooner: torch's
    ``cpp_extension.load`` holds a lock file while it checks or builds them, and a process
    killed meanwhile (a pool restart, a test's teardown, ``kill -9``) leaves that file behind,
    which blocks every later load on the machine. Pool processes start after every job, so
    here the window would be hit far more often than in a job."""
    import torch

    from sparsesplat.worker.training import lower_priority

    torch.set_num_threads(settings.torch_threads)
    lower_priority(settings)  # renders on the same machine come first
    import sparsesplat.engine.datasets
    import sparsesplat.engine.train  # noqa: F401


@worker_process_init.connect
def _on_pool_process_start(**_: Any) -> None:
    _warm_up()  # first: the process counts as a live worker once it can start a job at once
    pool_process()
    log.info("training worker ready", extra={"worker": pool_process().worker_id})


@worker_process_shutdown.connect
def _on_pool_process_exit(**_: Any) -> None:
    if _process is not None and _process.pid == os.getpid():
        _process.close()


@worker_shutting_down.connect
def _on_node_shutdown(**_: Any) -> None:
    """Warm shutdown of the node: the pool processes running a job checkpoint and hand it
    back now, instead of the node waiting for the whole training to end."""
    from celery.worker import state

    for request in list(state.active_requests):
        pid = getattr(request, "worker_pid", None)
        if pid:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)


def run_delivered_job(job_id: str) -> str:
    """Claim and run ``job_id``; returns the state it ended in, or ``dropped``."""
    process = pool_process()
    if not _fits_on_disk(process, job_id):
        return "waiting for disk space"
    claim = process.store.claim_job(job_id, process.worker_id, settings.lease_s)
    if claim is None:
        log.info("message dropped: the job is not queued", extra={"job_id": job_id})
        return "dropped"

    stopping: list[int] = []

    def on_sigterm(signum: int, _frame: FrameType | None) -> None:
        log.info("stopping on signal: the job checkpoints and goes back to the queue",
                 extra={"signal": signum, "job_id": job_id})  # fmt: skip
        stopping.append(signum)
        if process.current is not None:
            process.current.request_shutdown()

    in_main_thread = threading.current_thread() is threading.main_thread()
    previous: Any = signal.signal(signal.SIGTERM, on_sigterm) if in_main_thread else None
    process.job_id = job_id
    try:
        process.registry.beat(process.worker_id, job_id)
        with job_context(job_id):
            log.info("job claimed", extra={"attempt": claim.attempt})
            beat = JobHeartbeat(process.store, job_id, process.worker_id, settings)
            process.current = beat
            if stopping:  # the signal came before the heartbeat existed
                beat.request_shutdown()
            outcome = run_job(claim, process.store, process.storage, settings, beat)
            process.current = None
            stored = store_outcome(
                process.store, process.storage, process.worker_id, job_id, outcome, settings
            )
            if stored and outcome.state == JobState.queued and beat.shutting_down:
                _send_again(job_id)
            return outcome.state.value
    finally:
        process.current = None
        process.job_id = None
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


DISK_WAIT_IN_TASK_S = 30.0
"""Seconds a task waits for disk space for its job before sending the job again (so that a
pool process is not held for the whole wait, nor a new one forked every poll)."""


def _fits_on_disk(process: PoolProcess, job_id: str) -> bool:
    """Whether ``job_id`` may start (:class:`DiskGate`): a queued job that does not fit is
    checked again for a while, then sent again (or failed by the gate after
    ``disk_wait_s``); False then. A job that is not queued passes: ``claim_job`` drops it."""
    deadline = time.monotonic() + DISK_WAIT_IN_TASK_S
    while True:
        queued = process.store.spec_of_queued(job_id)
        if queued is None:
            return True
        spec, waiting_since = queued
        if process.gate.may_start(job_id, spec, waiting_since):
            return True
        if time.monotonic() > deadline:
            if process.store.spec_of_queued(job_id) is not None:
                _send_again(job_id)
            return False
        time.sleep(settings.poll_s)


def _send_again(job_id: str) -> None:
    try:
        send_job(app, job_id)
    except Exception:  # the API's reconciler sends queued jobs the broker does not hold
        log.warning("could not send the job back; the reconciler will", extra={"job_id": job_id})


@app.task(name=TRAIN_TASK)
def train(job_id: str) -> str:
    """Run training job ``job_id`` (drop the message if the job is not queued)."""
    return run_delivered_job(job_id)
