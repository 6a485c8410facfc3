"""The worker registry: who is alive (heartbeats), and where render workers listen."""

from __future__ import annotations

import os
import socket
import time
from dataclasses import dataclass

import sqlalchemy as sa

from sparsesplat.api.store.tables import workers

WorkerKind = str
"""``train`` or ``render``."""


@dataclass(frozen=True)
class WorkerInfo:
    """One registered worker."""

    id: str
    """Unique id (host, pid and a random part)."""
    kind: WorkerKind
    """``train`` or ``render``."""
    address: str | None
    """``host:port`` a render worker listens on."""
    job_id: str | None
    """The job a training worker runs now."""
    heartbeat_age_s: float
    """Seconds since its last heartbeat."""


def new_worker_id(kind: WorkerKind) -> str:
    """``kind-host-pid-random``: unique and readable in logs."""
    return f"{kind}-{socket.gethostname()}-{os.getpid()}-{os.urandom(3).hex()}"


class WorkerRegistry:
    """The ``workers`` table."""

    def __init__(self, engine: sa.Engine) -> None:
        """Workers in ``engine``'s database."""
        self.engine = engine

    def register(self, worker_id: str, kind: WorkerKind, address: str | None = None) -> None:
        """Add (or refresh) a worker."""
        now = time.time()
        with self.engine.begin() as conn:
            conn.execute(workers.delete().where(workers.c.id == worker_id))
            conn.execute(
                workers.insert().values(
                    id=worker_id,
                    kind=kind,
                    host=socket.gethostname(),
                    pid=os.getpid(),
                    address=address,
                    started_at=now,
                    heartbeat_at=now,
                )
            )

    def beat(self, worker_id: str, job_id: str | None = None) -> None:
        """Record that the worker is alive (and which job it runs)."""
        with self.engine.begin() as conn:
            conn.execute(
                workers.update()
                .where(workers.c.id == worker_id)
                .values(heartbeat_at=time.time(), job_id=job_id)
            )

    def unregister(self, worker_id: str) -> None:
        """Remove a worker that is shutting down."""
        with self.engine.begin() as conn:
            conn.execute(workers.delete().where(workers.c.id == worker_id))

    def ids_of_process(self, pid: int, host: str | None = None) -> list[str]:
        """Registered workers of process ``pid`` on ``host`` (default: this machine)."""
        with self.engine.begin() as conn:
            return list(
                conn.execute(
                    sa.select(workers.c.id).where(
                        workers.c.pid == pid, workers.c.host == (host or socket.gethostname())
                    )
                ).scalars()
            )

    def live(self, kind: WorkerKind | None = None, max_age_s: float = 30.0) -> list[WorkerInfo]:
        """Workers whose last heartbeat is at most ``max_age_s`` old (stale rows are removed)."""
        now = time.time()
        with self.engine.begin() as conn:
            conn.execute(workers.delete().where(workers.c.heartbeat_at < now - 10 * max_age_s))
            query = sa.select(workers).where(workers.c.heartbeat_at >= now - max_age_s)
            if kind is not None:
                query = query.where(workers.c.kind == kind)
            rows = conn.execute(query.order_by(workers.c.id)).all()
        return [WorkerInfo(r.id, r.kind, r.address, r.job_id, now - r.heartbeat_at) for r in rows]
