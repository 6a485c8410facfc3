"""Job rows as records: a row read as a wire ``Job``, one event appended, a page cursor.

What every part of the job store (the API side in ``jobs.py``, the queue in ``queue.py``, the
storage life in ``expiry.py``) writes and reads the same way, so each has one definition here:
the numbered event append (the one place ``last_seq`` moves), a row turned into a ``Job``
(queue position, model expiry) and the opaque cursor of a job listing.
"""

from __future__ import annotations

import base64
import json
import time
from datetime import UTC, datetime
from typing import Any

import sqlalchemy as sa

from sparsesplat.api.jobs import Job, JobSpec, JobState, Progress
from sparsesplat.api.store.tables import events, jobs


def utc(value: float) -> datetime:
    """A stored epoch time as an aware UTC datetime."""
    return datetime.fromtimestamp(value, UTC)


def _dt(value: float | None) -> datetime | None:
    return None if value is None else utc(value)


def select_jobs(owner: str | None) -> sa.Select[Any]:
    """All job columns, of ``owner``'s jobs only unless None."""
    query = sa.select(jobs)
    return query if owner is None else query.where(jobs.c.owner == owner)


def append_event(conn: sa.Connection, job_id: str, type_: str, data: dict[str, Any]) -> int:
    """Store one event; its sequence number, or 0 when the job is gone (deleted while its
    worker ran: the worker learns it from its heartbeat and stops; its last reports go
    nowhere rather than ending the worker process)."""
    seq = conn.execute(
        jobs.update()
        .where(jobs.c.id == job_id)
        .values(last_seq=jobs.c.last_seq + 1)
        .returning(jobs.c.last_seq)
    ).scalar_one_or_none()
    if seq is None:
        return 0
    conn.execute(
        events.insert().values(
            job_id=job_id, seq=seq, type=type_, time=time.time(), data=json_safe(data)
        )
    )
    return int(seq)


def expires_at(model_ttl_s: float, pinned: bool, finished_at: float | None) -> float | None:
    """When a succeeded job's model expires (None: pinned, or no expiry is set)."""
    if pinned or model_ttl_s <= 0 or finished_at is None:
        return None
    return finished_at + model_ttl_s


def is_expired(
    model_ttl_s: float,
    pinned: bool,
    expired_at: float | None,
    finished_at: float | None,
    now: float,
) -> bool:
    """Whether a succeeded job's model has expired (swept already, or past its time)."""
    if expired_at is not None:
        return True
    until = expires_at(model_ttl_s, pinned, finished_at)
    return until is not None and until <= now


def to_job(conn: sa.Connection, row: sa.Row[Any], model_ttl_s: float) -> Job:
    """The wire ``Job`` of a job row, with its queue position read in ``conn``'s transaction
    and its model's expiry from ``model_ttl_s``."""
    position = None
    if row.state == JobState.queued.value:
        position = int(
            conn.execute(
                sa.select(sa.func.count())
                .select_from(jobs)
                .where(
                    jobs.c.state == JobState.queued.value,
                    sa.or_(
                        jobs.c.created_at < row.created_at,
                        sa.and_(jobs.c.created_at == row.created_at, jobs.c.id < row.id),
                    ),
                )
            ).scalar_one()
        )
    succeeded = row.state == JobState.succeeded.value
    expired = succeeded and is_expired(
        model_ttl_s, row.pinned, row.expired_at, row.finished_at, time.time()
    )
    return Job(
        id=row.id,
        state=JobState(row.state),
        spec=JobSpec.model_validate(row.spec),
        created_at=utc(row.created_at),
        started_at=_dt(row.started_at),
        finished_at=_dt(row.finished_at),
        queue_position=position,
        progress=Progress.model_validate(row.progress) if row.progress else None,
        error=row.error,
        attempts=row.attempts,
        n_train_views=row.n_train_views,
        n_test_views=row.n_test_views,
        has_model=succeeded and not expired,
        warnings=list(row.warnings or []),
        disk_bytes=(row.result or {}).get("disk_bytes"),
        pinned=bool(row.pinned),
        expires_at=_dt(expires_at(model_ttl_s, row.pinned, row.finished_at)) if succeeded else None,
        expired=succeeded and expired,
    )


def json_safe(data: Any) -> Any:
    """Replace non-finite floats by None: JSON has no NaN/Infinity."""
    if isinstance(data, float):
        return data if data == data and abs(data) != float("inf") else None
    if isinstance(data, dict):
        return {str(k): json_safe(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [json_safe(v) for v in data]
    return data


def encode_cursor(created_at: float, job_id: str) -> str:
    """The opaque cursor of a job listing: the last job's creation time and id."""
    raw = json.dumps([created_at, job_id]).encode()
    return base64.urlsafe_b64encode(raw).decode().rstrip("=")


def decode_cursor(cursor: str) -> tuple[float, str]:
    """(creation time, id) of a cursor :func:`encode_cursor` issued; ValueError otherwise."""
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        created, job_id = json.loads(raw)
        return float(created), str(job_id)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"cursor {cursor!r} is not one this server issued") from exc
