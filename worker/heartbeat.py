"""The thread beside a running job: lease renewal, live progress, cancellation.

It runs while the trainer computes (torch releases the GIL in its kernels), so the lease stays
fresh through long iterations, the service sees the iteration count move, and a cancel takes
effect within one heartbeat plus one iteration. If the trainer does not stop within the grace
period after a cancel, the process ends itself (the supervisor starts a fresh worker).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from typing import Any

from sparsesplat.api.camera_estimation import CameraEstimation
from sparsesplat.api.disk import is_disk_full
from sparsesplat.api.jobs import JobState, Progress, Record
from sparsesplat.api.settings import Settings
from sparsesplat.api.store.jobs import JobStore

log = logging.getLogger("sparsesplat.worker")

HARD_KILL_EXIT_CODE = 75
"""Exit status of a worker that ended itself because a cancelled job did not stop in time."""


class JobHeartbeat:
    """Renews one job's lease every ``settings.heartbeat_s`` and publishes its progress."""

    def __init__(self, store: JobStore, job_id: str, worker_id: str, settings: Settings) -> None:
        """Heartbeat for ``job_id`` held by ``worker_id``."""
        self.store = store
        self.job_id = job_id
        self.worker_id = worker_id
        self.settings = settings
        self.cancel_requested = False
        """Set once the job's owner asked to cancel."""
        self.lost = False
        """Set when the lease went to another worker (this one was presumed dead)."""
        self.shutting_down = False
        """Set when the worker process was asked to stop (the job goes back to the queue)."""
        self._trainer: Any = None
        self._total: int | None = None
        self._budget_s: float | None = None
        self._phase = "preparing"
        self._record: Record | None = None
        self._preset: tuple[str, str | None] | None = None
        self._cameras: CameraEstimation | None = None
        self._last_iteration = -1
        self._cancel_seen_at: float | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"heartbeat-{job_id}", daemon=True)
        self.on_phase: Callable[[str], None] | None = None
        """Called with each new phase (the job runner follows what the job writes)."""

    def start(self) -> None:
        """Start beating (the first beat happens at once)."""
        self._thread.start()

    def stop(self) -> None:
        """Stop beating (the job is over in this worker), after one last beat so the stored
        progress shows where training ended rather than the previous beat's iteration."""
        self._stop.set()
        self._thread.join(timeout=10)
        try:
            self._beat()
        except Exception:  # the outcome is stored next; a stale progress is not worth failing it
            log.warning("final heartbeat failed", exc_info=True, extra={"job_id": self.job_id})

    def attach(self, trainer: Any, total: int | None, budget_s: float | None = None) -> None:
        """Follow ``trainer`` (reads its iteration and seconds; sets its stop flag). ``total``:
        the iterations it will do; None under a time budget of ``budget_s`` seconds."""
        self._trainer = trainer
        self._total = total
        self._budget_s = budget_s
        if self.cancel_requested or self.lost or self.shutting_down:
            self._request_stop()

    def request_shutdown(self) -> None:
        """Stop the trainer at the next iteration, keeping a checkpoint to resume from."""
        self.shutting_down = True
        self._request_stop()

    def set_phase(self, phase: str) -> None:
        """What the worker does now (shown in the job's progress)."""
        self._phase = phase
        if self.on_phase is not None:
            self.on_phase(phase)

    @property
    def trainer(self) -> Any:
        """The trainer followed (None before :meth:`attach`)."""
        return self._trainer

    def set_preset(self, name: str, reason: str | None) -> None:
        """The recipe in use and, when chosen from the scene, why."""
        self._preset = (name, reason)

    def set_cameras(self, cameras: CameraEstimation) -> None:
        """How the cameras were estimated (photos-only uploads)."""
        self._cameras = cameras

    def set_record(self, record: Record) -> None:
        """The newest held-out record."""
        self._record = record

    def progress(self) -> Progress:
        """The job's progress as of now."""
        trainer = self._trainer
        iteration = int(getattr(trainer, "iteration", 0)) if trainer is not None else 0
        elapsed = float(getattr(trainer, "elapsed_s", 0.0)) if trainer is not None else 0.0
        eta = None
        if self._budget_s is not None:  # a deadline: the training seconds left
            eta = max(self._budget_s - elapsed, 0.0)
        elif self._total and iteration > 0:
            eta = elapsed / iteration * max(self._total - iteration, 0)
        return Progress(
            iteration=iteration,
            total=self._total,
            elapsed_s=elapsed,
            eta_s=eta,
            phase=self._phase,
            last_record=self._record,
            preset=self._preset[0] if self._preset else None,
            preset_reason=self._preset[1] if self._preset else None,
            cameras=self._cameras,
        )

    def _loop(self) -> None:
        while True:
            try:
                self._beat()
            except Exception as exc:  # the database may be restarting: keep trying until the
                # lease ends. A full disk is the operator's to fix: said loudly, not as a blip.
                if is_disk_full(exc):
                    log.error("heartbeat failed: the disk holding the job database is full; "
                              "the job's lease runs out unless space returns",
                              extra={"job_id": self.job_id, "error": str(exc)})  # fmt: skip
                else:
                    log.warning("heartbeat failed", exc_info=True, extra={"job_id": self.job_id})
            if self._stop.wait(self.settings.heartbeat_s):
                return

    def _beat(self) -> None:
        progress = self.progress()
        ours, cancel = self.store.heartbeat(
            self.job_id, self.worker_id, self.settings.lease_s, progress
        )
        if progress.iteration != self._last_iteration and progress.iteration > 0:
            self._last_iteration = progress.iteration
            self.store.add_event(self.job_id, "progress", progress.model_dump(mode="json"))
        if not ours and not self._stop.is_set():
            self.lost = True  # deleted, or taken by another worker: its files are not ours
            self._request_stop()
        if cancel and not self.cancel_requested:
            self.cancel_requested = True
            self._cancel_seen_at = time.monotonic()
            self._request_stop()
            log.info("cancel requested", extra={"job_id": self.job_id})
        if (
            self._cancel_seen_at is not None
            and time.monotonic() - self._cancel_seen_at > self.settings.cancel_grace_s
            and not self._stop.is_set()
        ):
            log.warning("cancelled job did not stop in time: ending the worker",
                        extra={"job_id": self.job_id})  # fmt: skip
            self.store.finish(
                self.job_id, self.worker_id, JobState.cancelled, "cancelled (worker stopped hard)"
            )
            os._exit(HARD_KILL_EXIT_CODE)

    def _request_stop(self) -> None:
        if self._trainer is not None:
            self._trainer.discard_outputs = self.lost
            self._trainer.stop_requested = True
