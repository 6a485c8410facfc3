"""Scale-out dispatch (``queue=celery``): job ids go to the Celery training queue on Redis,
and a reconciler keeps the broker in step with the job records.

The API sends a job's id once, right after storing it. If that send fails (the broker is
down), the submission still succeeds: the job is stored, and the reconciler sends it later.
The reconciler is a thread of the API process, started and stopped with the dispatcher (so
with the application's lifespan). Every ``interval`` seconds it:

1. re-queues running jobs whose lease expired (their worker was killed, or its machine
   vanished) and sends them at once: they resume from their last checkpoint;
2. re-sends every queued job the broker has had no message for during ``grace`` seconds
   (neither waiting in the queue nor taken by a worker in the last ``TAKEN_GRACE_S``): Redis
   restarted without persistence, a send failed, a worker's node died holding the message.

Both are safe to repeat and to run in several API processes: a job's claim in the database
(``JobStore.claim_job``) decides who runs it, and a message for a job that is running or done
is dropped. It lives in the API process rather than in Celery beat because the API is
always there when jobs are, and a beat task would wait in a queue behind training jobs.
"""

from __future__ import annotations

import logging
import threading
import time

from sparsesplat.api.settings import Settings
from sparsesplat.api.store.broker import broker_view, make_celery, send_job
from sparsesplat.api.store.database import make_engine
from sparsesplat.api.store.jobs import JobStore

log = logging.getLogger("sparsesplat.dispatch")

RESEND_UNINSPECTABLE_S = 300.0
"""Brokers whose queue cannot be read (not Redis): a queued job is re-sent this often."""
TAKEN_GRACE_S = 120.0
"""A queued job whose message a worker took this long ago without claiming the job is sent
again (that worker's node died holding it). Normally a claim follows within the time a fresh
pool process takes to import torch; a slower one at worst gets a duplicate, which is dropped."""


def reconcile_interval(settings: Settings) -> float:
    """Seconds between reconciler passes: a quarter lease, between 0.5 and 5 s."""
    return max(0.5, min(5.0, settings.lease_s / 4))


class CeleryDispatcher:
    """Sends job ids to the training queue; reconciles queue and records in the background."""

    def __init__(self, settings: Settings, reconcile: bool = True) -> None:
        """Connect lazily to ``settings.broker_url``; start the reconciler unless told not to."""
        assert settings.database_url is not None
        self.settings = settings
        self.app = make_celery(settings, "sparsesplat-api")
        self.engine = make_engine(settings.database_url)
        self.store = JobStore(self.engine, settings.max_attempts)
        self.interval = reconcile_interval(settings)
        self.grace = 2 * self.interval
        self._lock = threading.Lock()
        self._sent: dict[str, float] = {}  # job id -> monotonic time of our last send
        self._first_queued: dict[str, float] = {}  # job id -> when we first saw it queued
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if reconcile:
            self._thread = threading.Thread(
                target=self._loop, name="celery-reconciler", daemon=True
            )
            self._thread.start()

    def enqueue(self, job_id: str) -> None:
        """Send ``job_id`` to the training queue; never fails the submission (a job the
        broker did not take is sent again by the reconciler)."""
        if self._send(job_id, retries=1):
            log.info("job sent", extra={"job_id": job_id})

    def _send(self, job_id: str, retries: int = 2) -> bool:
        try:
            send_job(self.app, job_id, retries)
        except Exception as exc:
            log.warning("broker unreachable; the reconciler will send the job",
                        extra={"job_id": job_id, "error": repr(exc)[:300]})  # fmt: skip
            return False
        with self._lock:
            self._sent[job_id] = time.monotonic()
        return True

    def reconcile_once(self) -> list[str]:
        """One pass (see the module doc); returns the ids it sent."""
        sent: list[str] = []
        requeued = set(self.store.requeue_expired())
        queued = self.store.queued_ids()
        now = time.monotonic()
        with self._lock:
            self._first_queued = {j: self._first_queued.get(j, now) for j in queued}
            self._sent = {j: t for j, t in self._sent.items() if j in self._first_queued}
        for job_id in queued:
            if job_id in requeued and self._send(job_id):
                sent.append(job_id)
                log.info("job re-queued after its lease expired; sent again",
                         extra={"job_id": job_id})  # fmt: skip
        waiting = [j for j in queued if j not in requeued]
        if not waiting:
            return sent
        view = broker_view(self.app)
        epoch = time.time()
        for job_id in waiting:
            with self._lock:
                since = max(self._first_queued[job_id], self._sent.get(job_id, -1e18))
            if view is None:
                due = now - since >= RESEND_UNINSPECTABLE_S
            else:
                taken = view.taken_at.get(job_id)
                held = taken is not None and epoch - taken < TAKEN_GRACE_S
                due = job_id not in view.waiting and not held and now - since >= self.grace
            if due and self._send(job_id):
                sent.append(job_id)
                log.warning("queued job had no message in the broker; sent again",
                            extra={"job_id": job_id})  # fmt: skip
        return sent

    def _loop(self) -> None:
        while not self._stop.wait(self.interval):
            try:
                self.reconcile_once()
            except Exception as exc:  # database or broker restarting: try again next pass
                log.warning("reconciler pass failed", extra={"error": repr(exc)[:300]})

    def close(self) -> None:
        """Stop the reconciler and release connections."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        self.engine.dispose()
        self.app.close()
