"""How a newly stored job reaches a worker: one interface, one implementation per backend.

Embedded (``queue=local``): nothing to send — training workers poll the job table and claim
the oldest queued job. Scale-out (``queue=celery``): the job id is sent to the training queue.
Either way the job record is the truth; a lost message never loses a job (the reconciler
re-sends queued jobs).
"""

from __future__ import annotations

from typing import Protocol

from sparsesplat.api.settings import QueueBackend, Settings


class JobDispatcher(Protocol):
    """Tells workers that a job is waiting."""

    def enqueue(self, job_id: str) -> None:
        """Announce ``job_id`` (already stored as queued)."""

    def close(self) -> None:
        """Release connections."""


class TableQueue:
    """Embedded backend: the job table is the queue; workers poll it."""

    def enqueue(self, job_id: str) -> None:
        """Nothing to do: the next idle worker claims it from the table."""

    def close(self) -> None:
        """Nothing to release."""


def make_dispatcher(settings: Settings) -> JobDispatcher:
    """The dispatcher for ``settings.queue``."""
    if settings.queue == QueueBackend.local:
        return TableQueue()
    from sparsesplat.server.celery_dispatch import CeleryDispatcher

    dispatcher: JobDispatcher = CeleryDispatcher(settings)
    return dispatcher
