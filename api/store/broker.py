"""The Celery side of the scale-out backend, shared by the API (which sends) and the workers
(which consume): queue and task names, the one Celery configuration, and what the broker holds.

A message carries only a job id; the job record is the truth. So the configuration is about
never running a job twice at once and never losing one:

- ``acks_late`` + ``reject_on_worker_lost``: a message is acknowledged when its task ends, and
  handed back to the queue when the process running it dies;
- prefetch 1 and one task per child process: a worker holds only the job it runs, and each
  job starts in a fresh process (no state, no leaked memory from the previous job);
- a duplicate or late message is harmless: the task claims the job in the database and drops
  the message when the job is not queued (``JobStore.claim_job``);
- a lost message is harmless: the API's reconciler re-sends every queued job that has no
  message in the broker (``broker_view``), e.g. after Redis restarted without persistence.

Celery is imported lazily: this module loads without the ``distributed`` extra.
"""

from __future__ import annotations

import json
import uuid
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from celery import Celery

    from sparsesplat.api.settings import Settings

TRAIN_QUEUE = "sparsesplat.train"
"""The queue training jobs wait in (renders never go through the broker)."""
TRAIN_TASK = "sparsesplat.train"
"""The task: ``sparsesplat.train(job_id)``."""
PROC_ALIVE_TIMEOUT_S = 300.0
"""How long a fresh pool process may take to start: it imports torch and the engine before it
says it is ready (seconds on a loaded machine; Celery's default of 4 s would kill it)."""
VISIBILITY_TIMEOUT_S = 6 * 3600.0
"""Redis: a message taken by a worker that vanished returns to the queue after this long. The
database's leases recover such jobs much sooner; a long value only avoids redelivering the
message of a long training that is still running (harmless too: the claim drops it)."""
MISSING_EXTRA = (
    "SPARSESPLAT_QUEUE=celery needs the distributed extra: "
    "pip install 'sparsesplat[service,distributed]'"
)


def make_celery(settings: Settings, main: str) -> Celery:
    """A Celery app for ``settings.broker_url`` with the service's queue configuration."""
    try:
        from celery import Celery
        from kombu import Queue
    except ImportError as exc:
        raise RuntimeError(MISSING_EXTRA) from exc

    app = Celery(main, broker=settings.broker_url, set_as_current=False)
    app.conf.update(
        task_queues=[Queue(TRAIN_QUEUE, routing_key=TRAIN_QUEUE)],
        task_default_queue=TRAIN_QUEUE,
        task_routes={TRAIN_TASK: {"queue": TRAIN_QUEUE}},
        task_serializer="json",
        accept_content=["json"],
        task_ignore_result=True,
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        task_acks_on_failure_or_timeout=True,
        task_track_started=False,
        worker_prefetch_multiplier=1,
        worker_max_tasks_per_child=1,
        worker_concurrency=1,
        worker_proc_alive_timeout=PROC_ALIVE_TIMEOUT_S,
        worker_hijack_root_logger=False,
        worker_send_task_events=False,
        worker_cancel_long_running_tasks_on_connection_loss=False,
        broker_connection_retry_on_startup=True,
        broker_connection_timeout=5.0,
        broker_transport_options={"visibility_timeout": VISIBILITY_TIMEOUT_S},
    )
    return app


def task_id_for(job_id: str) -> str:
    """A fresh task id that names its job (the reconciler reads it back from the broker)."""
    return f"{job_id}.{uuid.uuid4().hex[:12]}"


def job_of_task(task_id: str) -> str:
    """The job id inside ``task_id``."""
    return task_id.rsplit(".", 1)[0]


def send_job(app: Celery, job_id: str, retries: int = 2) -> None:
    """Put ``job_id`` on the training queue (raises when the broker cannot be reached)."""
    app.send_task(
        TRAIN_TASK,
        args=[job_id],
        queue=TRAIN_QUEUE,
        task_id=task_id_for(job_id),
        retry=True,
        retry_policy={
            "max_retries": retries,
            "interval_start": 0.0,
            "interval_step": 0.2,
            "interval_max": 0.5,
        },
    )


@dataclass(frozen=True)
class BrokerView:
    """What the broker holds for the training queue (Redis only: its lists can be read
    without consuming them)."""

    waiting: set[str]
    """Jobs with a message in the queue, not yet taken by a worker."""
    taken_at: dict[str, float]
    """Jobs whose message a worker took and has not acknowledged: epoch time it was taken."""


def broker_view(app: Celery) -> BrokerView | None:
    """The training queue's messages, or None when the broker is not Redis. Raises when the
    broker cannot be reached."""
    with app.connection_for_read() as connection:
        if connection.transport.driver_type != "redis":
            return None
        channel: Any = connection.default_channel
        keys = [_priority_key(channel, TRAIN_QUEUE, p) for p in channel.priority_steps]
        pipe = channel.client.pipeline(transaction=False)
        for key in dict.fromkeys(keys):
            pipe.lrange(key, 0, -1)
        pipe.hgetall(channel.unacked_key)
        pipe.zrange(channel.unacked_index_key, 0, -1, withscores=True)
        *lists, unacked, index = pipe.execute()
    waiting = {job for messages in lists for raw in messages if (job := _job_in(raw))}
    taken_since = {_text(tag): float(score) for tag, score in index}
    taken_at: dict[str, float] = {}
    for tag, raw in unacked.items():
        try:
            job = _job_in(json.dumps(json.loads(raw)[0]))  # [message, exchange, routing key]
        except (ValueError, IndexError, TypeError):
            continue
        if job:
            at = taken_since.get(_text(tag), 0.0)
            taken_at[job] = max(at, taken_at.get(job, 0.0))
    return BrokerView(waiting, taken_at)


def pending_job_ids(app: Celery) -> set[str] | None:
    """Jobs with a message waiting in the training queue (None when the broker is not Redis)."""
    view = broker_view(app)
    return None if view is None else view.waiting


def _job_in(raw: str | bytes) -> str | None:
    """The job id a kombu message (JSON) of ours carries, else None."""
    try:
        message = json.loads(raw)
        if message["headers"]["task"] != TRAIN_TASK:
            return None
        return job_of_task(str(message["headers"]["id"]))
    except (ValueError, KeyError, TypeError):
        return None


def _text(value: str | bytes) -> str:
    return value.decode() if isinstance(value, bytes) else value


def _priority_key(channel: Any, queue: str, priority: int) -> str:
    """The Redis list kombu keeps ``queue``'s messages of ``priority`` in."""
    return f"{queue}{channel.sep}{priority}" if priority else queue
